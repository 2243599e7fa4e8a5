# The README's two commands. Each bootstraps .venv with python3 -m venv + pip, so pip takes the
# pinned torch from the machine's local wheel store when it is there instead of downloading it.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: train test demo bench slurm torcs clean

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --upgrade pip
	$(PY) -m pip install -e '.[test]'
	touch $(STAMP)

# A local run: Zenoh router, learner and 2 actors on the embedded simulator, the default small CPU scale (scale=small_sn).
train: $(STAMP)
	$(VENV)/bin/gvf-train actors.count=2 $(ARGS)

# The kinematic controller driving the held-out roads, with the camera shown as text.
demo: $(STAMP)
	$(PY) -m actors.demo

# ruff (lint and format check, configured in pyproject.toml) first: it takes a second
# two pytest workers, one test file each at a time (module fixtures built once): serially the suite kept ~1 of 2 cores busy
test: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(PY) -m pytest -q -n 2 --dist loadfile

bench: $(STAMP)
	$(PY) bench/sim.py

# A one-node SLURM cluster on this machine (root, apt) and Hydra's submitit launcher, for
# deploy/slurm/ and `pytest -m slow tests/test_slurm.py`; `deploy/slurm/local_cluster.sh stop` ends it.
slurm: $(STAMP)
	deploy/slurm/local_cluster.sh
	$(PY) -m pip install -e '.[slurm]'

# TORCS 1.3.7 from Debian's source with our lockstep robot, installed under third_party/torcs (issue 15);
# apt packages only system-wide, idempotent. Not needed by train or test: the TORCS tests skip without it.
torcs:
	deploy/torcs/build.sh

clean:
	rm -rf $(VENV) *.egg-info
