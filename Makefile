# The two commands of the README. Both do all set-up first (scripts/setup.sh).
.PHONY: setup demo test lint bench

setup:
	@bash scripts/setup.sh

# The main job: the embedded full stack on this machine (no Docker, no GPU).
demo: setup
	.venv/bin/riskfield demo --out out/demo

# The test suite (what CI runs). pytest exits non-zero when it collects nothing.
test: setup
	.venv/bin/ruff check .
	.venv/bin/python -m pytest -q -p no:cacheprovider

lint: setup
	.venv/bin/ruff check .
