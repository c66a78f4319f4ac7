#!/usr/bin/env bash
# `make images`: every image this machine can build, in the robot/CPU split docker-compose.yml
# uses, tagged as compose names them (${RISKFIELD_IMAGE_PREFIX:-riskfield}-{robot,cpu}:${RISKFIELD_TAG:-latest}).
#
#   make images                         # robot + cpu
#   IMAGES="robot" make images          # a subset; "gpu" where CUDA base images can be pulled
#
# Works without an image registry: the Python base is python:3.11-slim-bookworm where it is
# present or can be pulled, else a local Debian one (scripts/make-base-image.sh); dependencies
# come from the host's wheelhouse (scripts/wheelhouse.sh, `pip --no-index` in the build). The
# classic builder (DOCKER_BUILDKIT=0) unless DOCKER_BUILDKIT is set; `--network host` so that
# apt-get in a build works on engines started with --iptables=false.
set -euo pipefail
cd "$(dirname "$0")/.."
prefix=${RISKFIELD_IMAGE_PREFIX:-riskfield}
tag=${RISKFIELD_TAG:-latest}
images=${IMAGES:-robot cpu}
export DOCKER_BUILDKIT=${DOCKER_BUILDKIT:-0}

bash scripts/docker-engine.sh

base=${PYTHON_IMAGE:-}
if [ -z "$base" ]; then
  base=python:3.11-slim-bookworm
  if ! docker image inspect "$base" >/dev/null 2>&1 && ! timeout 60 docker pull -q "$base" >/dev/null 2>&1; then
    echo "images: $base cannot be pulled: a local Debian base instead"
    base=riskfield-base:bookworm
    bash scripts/make-base-image.sh "$base"
  fi
fi

# The wheelhouse is rebuilt when the packaging changed since it was made (WHEELHOUSE=0: none,
# the builds use the package index).
stamp=deploy/wheels/.built
if [ "${WHEELHOUSE:-1}" != 0 ] && { [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ setup.py -nt "$stamp" ] \
    || [ deploy/requirements.py -nt "$stamp" ] || [ scripts/wheelhouse.sh -nt "$stamp" ]; }; then
  bash scripts/wheelhouse.sh && touch "$stamp"
fi

mkdir -p out
# build ROLE DOCKER-BUILD-ARGS...: one `docker build` of deploy/Dockerfile.ROLE into out/images-ROLE.log
build() {
  local role=$1; shift
  docker build --network host "$@" -f "deploy/Dockerfile.$role" . >> "out/images-$role.log" 2>&1 \
    || { tail -n 30 "out/images-$role.log" >&2; echo "images: $role failed (out/images-$role.log)" >&2; exit 1; }
}
for role in $images; do
  start=$(date +%s)
  case $role in
    gpu) args=() ;;   # its own CUDA base (CUDA_IMAGE), from a registry
    *) args=(--build-arg "PYTHON_IMAGE=$base") ;;
  esac
  echo "images: building $prefix-$role:$tag (base $base)"
  : > "out/images-$role.log"
  # The dependency stage tagged too ($prefix-$role-deps): untagged, `docker image prune` would drop
  # it and with it the cache that spares a source edit the dependencies' install.
  if grep -q '^FROM .* AS deps$' "deploy/Dockerfile.$role"; then
    build "$role" "${args[@]}" --target deps -t "$prefix-$role-deps:$tag"
  fi
  build "$role" "${args[@]}" -t "$prefix-$role:$tag"
  size=$(docker image inspect -f '{{.Size}}' "$prefix-$role:$tag" | awk '{printf "%.0f MB", $1/1e6}')
  echo "images: $prefix-$role:$tag built in $(( $(date +%s) - start )) s, $size"
done
