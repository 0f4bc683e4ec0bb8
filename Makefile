# The two commands of the README.  Both set up everything they need first (idempotent).
PY := .venv/bin/python

.PHONY: setup motionplanning demo test test-fast lint bench docs
setup:
	bash scripts/setup.sh

motionplanning:      ## also ManiSkill's motion planners (policy=motion_planner): numpy 1.26 for their workers
	bash scripts/setup.sh --motionplanning

demo: setup          ## red-team the default object (grasp task, budget=quick)
	$(PY) -m grt.run

test: motionplanning ## the whole test suite (what CI runs; with the motion planners' numpy, ~4 s and 79 MB), two files at a time
	$(PY) -m pytest -q -n 2 --dist loadfile

test-fast: motionplanning  ## skip the slow simulation tests
	$(PY) -m pytest -q -n 2 --dist loadfile -m "not slow"

lint:
	$(PY) -m ruff check grt tests scripts

bench: setup
	$(PY) -m grt.bench deform
	$(PY) -m grt.bench grasp

docs: setup          ## regenerate the results tables of experiments/*/README.md from their files
	$(PY) -m grt.report experiments --update-readmes
