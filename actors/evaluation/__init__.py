"""Evaluation: the paper's driving metrics, episodes without exploration noise, reports."""
