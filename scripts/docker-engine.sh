#!/usr/bin/env bash
# A Docker engine for `make images` and the container tests (tests/deploy/test_containers.py).
#
#   scripts/docker-engine.sh          # exit 0 once `docker info` answers; else one line why and
#                                     # 2: no engine is here and none can be had (the container tests skip)
#                                     # 1: an engine is here but does not answer (the container tests fail)
#
# Uses the engine that runs. Otherwise, as root on Debian (CI, this kind of machine): installs
# Debian's `docker.io` with apt and starts `dockerd` in the background. `--iptables=false`
# because these kernels may lack the NAT modules: containers then reach the outside only on the
# host network (the builds use `--network host`) and published ports are served by docker-proxy
# on the host, which is all the tests need. Its log: ${DOCKERD_LOG:-/var/log/riskfield-dockerd.log}.
# An engine is "here" when DOCKER_HOST names one, its socket exists or dockerd is installed: then a
# `docker info` that keeps failing is a fault to fix, not a machine without Docker.
set -euo pipefail

absent() { echo "docker-engine: $*" >&2; exit 2; }
broken() { echo "docker-engine: $*" >&2; exit 1; }
last_error() { docker info 2>&1 >/dev/null | tail -n 1; }

if docker info >/dev/null 2>&1; then exit 0; fi
[ -z "${DOCKER_HOST:-}" ] || broken "DOCKER_HOST=$DOCKER_HOST does not answer: $(last_error)"
if [ -S /var/run/docker.sock ] && ! command -v dockerd >/dev/null; then
  broken "/var/run/docker.sock is here but does not answer: $(last_error)"
fi
if ! command -v dockerd >/dev/null; then
  [ "$(id -u)" -eq 0 ] || absent "no Docker engine here, and installing one needs root"
  command -v apt-get >/dev/null || absent "no Docker engine here, and this is not Debian (no apt-get)"
  echo "docker-engine: installing docker.io (Debian) with apt" >&2
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq >/dev/null || true
  # No recommends: apparmor, cgroupfs-mount and git are not needed to run a daemon here.
  apt-get install -y -qq --no-install-recommends docker.io >/dev/null \
    || absent "no Docker engine here, and apt-get install docker.io failed"
  command -v dockerd >/dev/null || absent "no Docker engine here: docker.io installed no dockerd"
fi
[ "$(id -u)" -eq 0 ] || pgrep -x dockerd >/dev/null \
  || broken "dockerd is installed but not running, and starting it needs root"

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
broken "dockerd did not answer within 60 s: $(last_error) (see $log: $(tail -n 1 "$log" 2>/dev/null))"
