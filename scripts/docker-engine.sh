#!/usr/bin/env bash
# A Docker engine for `make images` and the container tests (tests/deploy/test_containers.py).
#
#   scripts/docker-engine.sh          # exit 0 once `docker info` answers; else 1, with one line why
#
# Uses the engine that runs. Otherwise, as root on Debian (CI, this kind of machine): installs
# Debian's `docker.io` with apt and starts `dockerd` in the background. `--iptables=false`
# because these kernels may lack the NAT modules: containers then reach the outside only on the
# host network (the builds use `--network host`) and published ports are served by docker-proxy
# on the host, which is all the tests need. Its log: ${DOCKERD_LOG:-/var/log/riskfield-dockerd.log}.
# Non-root, or not Debian: says why and exits 1 (the container tests then skip with that line).
set -euo pipefail

why() { echo "docker-engine: $*" >&2; exit 1; }

if docker info >/dev/null 2>&1; then exit 0; fi
[ "$(id -u)" -eq 0 ] || why "no Docker engine answers and starting one needs root"
command -v apt-get >/dev/null || why "no Docker engine answers and this is not Debian (no apt-get)"

if ! command -v dockerd >/dev/null; then
  echo "docker-engine: installing docker.io (Debian) with apt" >&2
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq >/dev/null || true
  # No recommends: apparmor, cgroupfs-mount and git are not needed to run a daemon here.
  apt-get install -y -qq --no-install-recommends docker.io >/dev/null \
    || why "apt-get install docker.io failed"
fi
command -v dockerd >/dev/null || why "dockerd is not installed"

# The Debian package's own client may be missing when another `docker` CLI sits earlier in PATH:
# either talks to the daemon's socket.
log=${DOCKERD_LOG:-/var/log/riskfield-dockerd.log}
if ! pgrep -x dockerd >/dev/null; then
  # Detached (setsid): the daemon outlives this script and the test session that started it.
  setsid dockerd --iptables=false >"$log" 2>&1 < /dev/null &
fi
for _ in $(seq 1 60); do
  if docker info >/dev/null 2>&1; then exit 0; fi
  sleep 1
done
why "dockerd did not answer within 60 s (see $log: $(tail -n 1 "$log" 2>/dev/null))"
