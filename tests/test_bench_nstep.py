"""Smoke test of bench/nstep.py: a tiny run whose last line is the JSON result with both rates
present and positive. No timing assertions."""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_bench_nstep_prints_both_rates_as_json():
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
    proc = subprocess.run(
        [sys.executable, str(ROOT / "bench" / "nstep.py"), "--rounds", "1", "--per-round", "2", "--threads", "1"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    for key in ("updates_per_s_1_step", "updates_per_s_5_step", "ratio"):
        assert isinstance(result[key], float) and math.isfinite(result[key]) and result[key] > 0, key
    assert result["n_step"] == 5 and isinstance(result["meets_limit"], bool)
