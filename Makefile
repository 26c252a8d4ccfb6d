# Two entry points that set themselves up from nothing: `make test` and `make demo`.
SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# Keep DDS traffic of tests and demo on this machine and away from other graphs.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export PYTHONDONTWRITEBYTECODE = 1

.PHONY: venv test demo bench clean lint

venv: $(STAMP)

$(STAMP): requirements.txt constraints.txt setup.py
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -r requirements.txt -c constraints.txt
	$(PY) -m pip install -q --no-deps --no-build-isolation -e .
	touch $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -q -n 2 test

# ruff (config: ruff.toml) and mypy (config: setup.cfg [mypy]); no formatter.
lint: $(STAMP)
	$(PY) -m ruff check imu_calib_ros msg_adapters bench test
	$(PY) -m mypy imu_calib_ros msg_adapters

demo: $(STAMP)
	$(PY) -m imu_calib_ros.demo

bench: $(STAMP)
	for b in bench/*.py; do echo "== $$b"; $(PY) $$b || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info out .mypy_cache .ruff_cache
