#!/usr/bin/env bash
# Fault drill: a robot and a server in two network namespaces, the safety filter on the robot
# side, mapping on the server side; the link is cut (twice), mapping is killed and restarted,
# packets are lost (50 %, 90 %) and delayed (where the kernel has netem). Prints, per fault, how
# long after the last map the robot side braked and how soon it moved again; fails if a moving
# command was ever published on a map older than the timeout.
#
#   sudo deploy/faults/drill.sh [esdf|mapping]
#
# esdf (default): a free-space ESDF publisher stands in for mapping; mapping: the real mapping
# service, fed with a pointmap of a wall by a stand-in for perception. Needs root and iproute2;
# everything it creates is removed at the end.
set -euo pipefail
cd "$(dirname "$0")/../.."
[ "$(id -u)" -eq 0 ] || { echo "drill: needs root (network namespaces)" >&2; exit 3; }
[ -x .venv/bin/python ] || { echo "drill: run scripts/setup.sh first (.venv)" >&2; exit 3; }
RF_FAULTS_SOURCE=${1:-esdf} exec .venv/bin/python -m pytest -p no:cacheprovider -q -s -rs tests/deploy/test_faults.py
