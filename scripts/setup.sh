#!/usr/bin/env bash
# Everything a fresh machine needs: system libraries (open3d wants libgomp1 and libusb;
# fault-injection tests want iproute2; deployment tests want openssl and docker-compose to
# validate the compose file), then a virtualenv in .venv with riskfield and its
# extras, then the nodes' compiled kernels (numba) into the cache the nodes load them from, so that
# no node compiles at its first start. Re-running is cheap: each step is skipped when already done
# (the warm-up by a stamp of the sources, numba and the CPU it compiled for).
set -euo pipefail
cd "$(dirname "$0")/.."

APT_PACKAGES=(libgomp1 libusb-1.0-0 libgl1 iproute2 openssl docker-compose)
missing=()
for p in "${APT_PACKAGES[@]}"; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
if [ ${#missing[@]} -gt 0 ]; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  echo "setup: installing system packages: ${missing[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
stamp=.venv/.riskfield-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ setup.py -nt "$stamp" ]; then
  echo "setup: installing riskfield[all,dev] into .venv"
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -e ".[all,dev]"
  touch "$stamp"
fi

# Tens of seconds to minutes the first time (once per checkout, and again for the kernels whose
# sources changed); a second or two when done. NUMBA_CACHE_DIR, if set, must be the nodes' too.
.venv/bin/riskfield warmup
