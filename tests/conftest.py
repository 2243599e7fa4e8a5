"""Shared test settings: keep torch to one thread so parallel test processes don't oversubscribe 2 cores."""

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
