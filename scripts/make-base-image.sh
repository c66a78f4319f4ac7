#!/usr/bin/env bash
# A local Debian bookworm + Python 3.11 base image, for machines where the registry's
# python:3.11-slim-bookworm cannot be pulled (no registry reachable, air-gapped sites):
#
#   scripts/make-base-image.sh [TAG]          # default TAG: riskfield-base:bookworm
#   docker build --build-arg PYTHON_IMAGE=riskfield-base:bookworm -f deploy/Dockerfile.robot .
#
# debootstrap (minbase) from the Debian archive, python3 + venv added in the chroot, then
# `docker import`. Needs root and a running engine (scripts/docker-engine.sh). `python` is
# Debian's python3 (python-is-python3), so the Dockerfiles' `python -m venv` works as on the
# official image. Skipped when TAG exists already (FORCE=1 rebuilds). ~1 min, ~200 MB.
set -euo pipefail
tag=${1:-riskfield-base:bookworm}
mirror=${DEBIAN_MIRROR:-http://deb.debian.org/debian}

if [ -z "${FORCE:-}" ] && docker image inspect "$tag" >/dev/null 2>&1; then
  echo "make-base-image: $tag exists (FORCE=1 rebuilds)"; exit 0
fi
[ "$(id -u)" -eq 0 ] || { echo "make-base-image: debootstrap needs root" >&2; exit 1; }
if ! command -v debootstrap >/dev/null; then
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends debootstrap >/dev/null
fi

root=$(mktemp -d /tmp/riskfield-base.XXXXXX)
# debootstrap mounts proc/sys in the chroot: unmount whatever is left before removing it, and
# never cross into another file system while removing.
cleanup() {
  grep -o " $root/[^ ]*" /proc/mounts | sort -r | xargs -r -n1 umount -l 2>/dev/null || true
  rm -rf --one-file-system "$root" "$root.log"
}
trap cleanup EXIT
echo "make-base-image: debootstrap bookworm (minbase) into $root"
debootstrap --variant=minbase \
  --include=python3,python3-venv,python-is-python3,ca-certificates \
  bookworm "$root" "$mirror" >"$root.log" 2>&1 || { tail -n 20 "$root.log" >&2; exit 1; }
# What the official slim images do too: no apt lists, no docs beyond copyright, no locales.
rm -rf "$root"/var/lib/apt/lists/* "$root"/var/cache/apt/*.bin "$root"/var/cache/apt/archives/*.deb \
       "$root"/usr/share/doc/*/[!c]* "$root"/usr/share/man/* "$root"/usr/share/info/* \
       "$root"/usr/share/locale/[!C]*
echo "deb $mirror bookworm main" > "$root/etc/apt/sources.list"
echo "deb $mirror bookworm-updates main" >> "$root/etc/apt/sources.list"
echo "deb http://security.debian.org/debian-security bookworm-security main" >> "$root/etc/apt/sources.list"

tar -C "$root" --one-file-system -c . | docker import \
  --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
  --change 'ENV LANG=C.UTF-8' \
  --change 'CMD ["python3"]' \
  - "$tag" >/dev/null
echo "make-base-image: $tag ($(docker image inspect -f '{{.Size}}' "$tag" | awk '{printf "%.0f MB", $1/1e6}'))"
