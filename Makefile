# The two commands of the README.  Both set up everything they need first (idempotent).
PY := .venv/bin/python

.PHONY: setup demo test test-fast lint bench docs
setup:
	bash scripts/setup.sh

demo: setup          ## red-team the default object (grasp task, budget=quick)
	$(PY) -m grt.run

test: setup          ## the whole test suite (what CI runs)
	$(PY) -m pytest -q

test-fast: setup     ## skip the slow simulation tests
	$(PY) -m pytest -q -m "not slow"

lint:
	$(PY) -m ruff check grt tests scripts

bench: setup
	$(PY) -m grt.bench deform
	$(PY) -m grt.bench grasp

docs: setup          ## regenerate the results tables of experiments/*/README.md from their files
	$(PY) -m grt.report experiments --update-readmes
