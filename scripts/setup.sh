#!/usr/bin/env bash
# Everything a fresh machine needs for one command, each step skipped when already done:
#
#   scripts/setup.sh test   (default; make test, make check, make lint) everything the tests use
#   scripts/setup.sh demo   (make demo) only what the embedded demo runs
#
# 1. system packages: python3-venv (Debian ships `python3 -m venv` without ensurepip), the
#    libraries open3d loads (libgomp1, libusb-1.0-0, libgl1); for `test` also iproute2 (fault
#    injection), openssl (the deployment's certificates) and docker-compose (the compose files'
#    validation and the container tests);
# 2. a virtualenv in .venv;
# 3. riskfield and its extras into it: `demo` pip install -e ".[all]", `test` ".[all,dev]";
# 4. riskfield's bytecode, and the nodes' compiled kernels (numba) into the cache the nodes load
#    them from (`riskfield warmup`), so that no node compiles at its first start.
#
# Every step says what it does; pip and apt-get print their own progress (minutes on a fresh
# machine). Re-running is cheap: the install is stamped per command (and redone when pyproject.toml
# or setup.py changed), the warm-up by a stamp of the sources, numba and the CPU it compiled for.
set -euo pipefail
cd "$(dirname "$0")/.."

MODE=${1:-test}
APT_PACKAGES=(libgomp1 libusb-1.0-0 libgl1)
case "$MODE" in
  test) EXTRAS="all,dev"; APT_PACKAGES+=(iproute2 openssl docker-compose) ;;
  demo) EXTRAS="all" ;;
  *) echo "usage: scripts/setup.sh [test|demo]  (test: what the test suite needs; demo: the embedded demo)" >&2
     exit 2 ;;
esac
PY=${PYTHON:-python3}
step() { echo "setup ($MODE): $*"; }

if command -v dpkg >/dev/null 2>&1; then
  # A Debian/Ubuntu system Python creates a venv only with python3-venv (its ensurepip).
  if [ ! -x .venv/bin/python ] && [ "$("$PY" -c 'import sys; print(sys.base_prefix)')" = /usr ]; then
    APT_PACKAGES+=(python3-venv)
  fi
  missing=()
  for p in "${APT_PACKAGES[@]}"; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
  if [ ${#missing[@]} -gt 0 ]; then
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    step "[1/4] installing system packages: ${missing[*]}"
    $SUDO apt-get update -q
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
  else
    step "[1/4] system packages: all present (${APT_PACKAGES[*]})"
  fi
else
  step "[1/4] no dpkg: install ${APT_PACKAGES[*]} (or your system's equivalents) yourself"
fi

if [ -x .venv/bin/python ]; then
  step "[2/4] virtualenv: .venv exists"
else
  step "[2/4] creating the virtualenv .venv with $PY"
  "$PY" -m venv .venv
fi

# A `test` install is a superset of a `demo` one: either stamp serves `demo`.
stamp=.venv/.riskfield-installed-$MODE
fresh() { [ -f "$1" ] && [ ! pyproject.toml -nt "$1" ] && [ ! setup.py -nt "$1" ]; }
if fresh "$stamp" || { [ "$MODE" = demo ] && fresh .venv/.riskfield-installed-test; }; then
  step "[3/4] riskfield[$EXTRAS]: installed"
else
  step "[3/4] installing riskfield[$EXTRAS] into .venv (pip prints each package; minutes the first time)"
  .venv/bin/python -m pip install --progress-bar on --upgrade pip
  .venv/bin/python -m pip install --progress-bar on -e ".[$EXTRAS]"
  touch "$stamp"
fi

# Tens of seconds to minutes the first time (once per checkout, and again for the kernels whose
# sources changed); a second or two when done. NUMBA_CACHE_DIR, if set, must be the nodes' too.
# The sources' bytecode too: compileall writes it even where PYTHONDONTWRITEBYTECODE is set (as on
# this kind of machine), and every process then reads it instead of compiling the sources again.
step "[4/4] compiling riskfield's bytecode and the nodes' kernels (riskfield warmup; a second when done)"
.venv/bin/python -m compileall -q protocol services edge riskfield
.venv/bin/riskfield warmup
