# Two entry points for a fresh machine: `make demo` and `make test`. Both create .venv when missing.
SHELL := /bin/bash
VENV := .venv
PY := $(VENV)/bin/python
export HF_HUB_OFFLINE ?= 1
export MUJOCO_GL ?= egl

# A Python >= 3.12: first on PATH, then among pyenv's installed versions.
define find_python
for c in python3.13 python3.12 python3 python; do \
  p=$$(command -v $$c 2>/dev/null) && "$$p" -c 'import sys; sys.exit(sys.version_info < (3, 12))' 2>/dev/null && { echo "$$p"; exit 0; }; \
done; \
root=$$(pyenv root 2>/dev/null || echo "$$HOME/.pyenv"); \
for p in $$(ls -d "$$root"/versions/3.1[2-9]*/bin/python3 2>/dev/null | sort -rV); do \
  "$$p" -c 'import sys; sys.exit(sys.version_info < (3, 12))' 2>/dev/null && { echo "$$p"; exit 0; }; \
done; exit 1
endef

.PHONY: demo test lint format clean-venv which-python

$(VENV)/.installed: pyproject.toml
	@if [ ! -x $(PY) ]; then \
	  python=$$($(find_python)) || { echo "error: no Python >= 3.12 found on PATH or in pyenv's versions; install one (e.g. 'pyenv install 3.12')." >&2; exit 1; }; \
	  echo "creating $(VENV) with $$python"; "$$python" -m venv $(VENV); \
	fi
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[test]"
	@touch $@

# The Python a new .venv is made with (the tests check that .venv runs it).
which-python:
	@$(find_python)

demo: $(VENV)/.installed
	$(VENV)/bin/lerobot-opfa demo --output-dir outputs/demo

# One worker per core, each test file on one worker (its module fixtures are built once), the files in the
# order conftest.py gives them (the longest first, so that no worker is left alone with one at the end).
test: $(VENV)/.installed
	$(PY) -m pytest -q -n auto --dist loadfile --no-loadscope-reorder

lint: $(VENV)/.installed
	$(VENV)/bin/ruff check src tests benchmarks examples
	$(VENV)/bin/ruff format --check src tests benchmarks examples

format: $(VENV)/.installed
	$(VENV)/bin/ruff format src tests benchmarks examples
	$(VENV)/bin/ruff check --fix src tests benchmarks examples
