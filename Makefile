# The two commands of the README. Both do all set-up first (scripts/setup.sh).
.PHONY: setup demo test check lint bench images

setup:
	@bash scripts/setup.sh

# The main job: the embedded full stack on this machine (no Docker, no GPU).
demo: setup
	.venv/bin/riskfield demo --out out/demo

# The test suite (what CI runs): everything, `slow` full-stack tests included.
# pytest exits non-zero (5) when it collects nothing, so an empty run fails too.
test: setup
	.venv/bin/ruff check .
	.venv/bin/python -m pytest -q -p no:cacheprovider

# The development loop: lint plus every test not marked `slow` (under 3 minutes here).
check: setup
	.venv/bin/ruff check .
	.venv/bin/python -m pytest -q -p no:cacheprovider -m "not slow"

lint: setup
	.venv/bin/ruff check .

# The container images this machine can build (robot, cpu), with or without an image registry:
# scripts/images.sh (docs/deployment.md). Needs a Docker engine; as root on Debian it starts one.
images:
	@bash scripts/images.sh
