# Two commands on a fresh machine with Python 3.11 + pip:
#   make run    set up .venv and run the main job
#   make test   set up .venv and run the test suite's fast set (the `slow` marker left out), one pytest-xdist
#               worker per core; tests/conftest.py groups the tests so that one worker builds each scene
#   make test-all   the whole suite, as CI runs it (make test, then make test-slow)
# Warp kernels compile once per scene and precision (docs/results.md, compile times) and are cached in
# ~/.cache/warp (or $WARP_CACHE_PATH), which survives fresh clones on the same machine.

PYTHON ?= python3.11
VENV ?= .venv
PY := $(VENV)/bin/python

.PHONY: setup run test test-slow test-all bench clean

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml setup.py
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# the CPU build of torch first: a bare torch requirement would pull the multi-GB CUDA build
	$(PY) -c "import torch" 2>/dev/null || $(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e ".[test]"
	touch $@

run: setup
	$(VENV)/bin/dexmots-train

test: setup
	$(PY) -m pytest -q -m "not slow" -n auto --dist loadgroup

test-slow: setup
	$(PY) -m pytest -q -m slow -n auto --dist loadgroup

test-all: test test-slow

bench: setup
	$(VENV)/bin/dexmots-bench throughput --task screw_claw --json
	$(VENV)/bin/dexmots-bench grad --task screw_claw --json
	$(VENV)/bin/dexmots-bench plan --task screw_claw --json
	$(VENV)/bin/dexmots-bench train --task screw_claw --algo ahac --json
	$(VENV)/bin/dexmots-bench train --task screw_claw --algo shac --json

clean:
	rm -rf $(VENV) *.egg-info .pytest_cache
