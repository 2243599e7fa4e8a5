"""Modules the benchmarks in bench/ share: processes, bookkeeping, summaries (no benchmark here)."""
