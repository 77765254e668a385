# Two entry points for a fresh machine: `make run` (the default graph) and `make test`.
PY := .venv/bin/python
VENV_STAMP := .venv/.installed

.PHONY: run test test-fast lint format check venv clean

$(VENV_STAMP): pyproject.toml
	python3 -m venv .venv
	# torch first, pinned: a bare `torch` requirement would pull the CUDA build.
	$(PY) -m pip install --quiet torch==2.13.0
	# Editable as a plain path (.pth), not setuptools' import hook: the hook costs every
	# process 25 ms at start, and a graph starts a dozen.
	$(PY) -m pip install --quiet -e '.[dev]' --config-settings editable_mode=compat
	touch $(VENV_STAMP)

venv: $(VENV_STAMP)

run: $(VENV_STAMP)
	$(PY) launch.py graph.yaml

check: $(VENV_STAMP)
	$(PY) launch.py graph.yaml --check

lint: $(VENV_STAMP)
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .
	$(PY) -m mypy messages runtime cli nodes perception

format: $(VENV_STAMP)
	$(PY) -m ruff format .
	$(PY) -m ruff check --fix .

# The one gate: lint and every test.
test: $(VENV_STAMP) lint
	$(PY) -m pytest --durations=25

# The loop to run every few minutes: the unit tests, no process started (under a minute).
test-fast: $(VENV_STAMP)
	$(PY) -m pytest -m "not spawns and not slow"

clean:
	rm -rf .venv
