# The two commands of the README. Both do their set-up first (scripts/setup.sh: system packages,
# .venv, riskfield's extras and the nodes' compiled kernels, `riskfield warmup`; each step skipped
# when done): `setup-demo` only what the demo runs, `setup` everything the tests use (Docker's
# compose tooling, iproute2, openssl and the dev extra too).
.PHONY: setup setup-demo demo test check lint bench images

# pytest-xdist workers for the tests not marked `slow` (each its own session router on a free port).
# Three on two cores: the tests spend much of their time waiting on the processes and sockets they
# start, and a third worker fills that (make check 3 min 10 s on two workers, 2 min 49 s on three).
CHECK_JOBS ?= 3

# pytest keeps the test modules it rewrote for its assertions as bytecode, also where the environment
# says PYTHONDONTWRITEBYTECODE (this kind of machine does): each worker re-rewrote every module at
# each run, 9 s of CPU a run against 4 s. The empty value unsets it for pytest and what it spawns.
PYTEST = PYTHONDONTWRITEBYTECODE= .venv/bin/python -m pytest -q -p no:cacheprovider

setup:
	@bash scripts/setup.sh test

setup-demo:
	@bash scripts/setup.sh demo

# The main job: the embedded full stack on this machine (no Docker, no GPU).
demo: setup-demo
	.venv/bin/riskfield demo --out out/demo

# The test suite (what CI runs): everything, in two runs. The tests not marked `slow` on CHECK_JOBS
# pytest-xdist workers, then the `slow` full-stack tests one at a time (their wall-clock bounds are
# for one test at a time). pytest exits non-zero (5) when a run collects nothing, so an empty run fails
# too. --durations names the slowest tests, so a CI run that grows says where.
test: setup
	.venv/bin/ruff check .
	$(PYTEST) -m "not slow" -n $(CHECK_JOBS) --dist loadgroup
	$(PYTEST) -m slow --durations=15

# The development loop: lint plus every test not marked `slow` (under 3 minutes here), on CHECK_JOBS
# pytest-xdist workers (each its own session router on a free port; a module whose fixtures are costly
# stays on one worker, pytest.mark.xdist_group). Not `make test`: the slow tests' wall-clock bounds are
# for one test at a time.
check: setup
	.venv/bin/ruff check .
	$(PYTEST) -m "not slow" -n $(CHECK_JOBS) --dist loadgroup

lint: setup
	.venv/bin/ruff check .

# The container images this machine can build (robot, cpu), with or without an image registry:
# scripts/images.sh (docs/deployment.md). Needs a Docker engine; as root on Debian it starts one.
images:
	@bash scripts/images.sh
