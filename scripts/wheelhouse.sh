#!/usr/bin/env bash
# The images' wheelhouse, built on the host: every dependency of riskfield[EXTRAS] as a wheel
# in deploy/wheels/ (the Dockerfiles install from it with `pip --no-index` when it holds wheels,
# from the package index otherwise). For machines whose builds cannot reach the index, and for
# an air-gapped robot site, where the wheelhouse is carried over with the source.
#
#   scripts/wheelhouse.sh               # riskfield[robot,camera,mapping,sim]: the CPU image's and the robot's
#   EXTRAS=robot,camera scripts/wheelhouse.sh  # the robot image's only (deploy/requirements.py SITES)
#
# The host's Python must match the images' (CPython 3.11, linux x86_64 / aarch64, glibc):
# pip picks wheels for the interpreter it runs in. riskfield itself is not in the wheelhouse:
# the images build it from the source they copy, with setuptools and wheel from here.
set -euo pipefail
cd "$(dirname "$0")/.."
out=deploy/wheels
extras=${EXTRAS:-robot,camera,mapping,sim}
py=${PYTHON:-python3}
[ -x .venv/bin/python ] && py=${PYTHON:-.venv/bin/python}

ver=$("$py" -c 'import sys; print("%d.%d" % sys.version_info[:2])')
[ "$ver" = "3.11" ] || { echo "wheelhouse: $py is Python $ver; the images run 3.11" >&2; exit 1; }
mkdir -p "$out"
# Drop riskfield's own wheel at once: the image builds the copied source instead.
"$py" -m pip wheel -q --disable-pip-version-check -w "$out" setuptools wheel ".[$extras]"
rm -f "$out"/riskfield-*.whl
echo "wheelhouse: $(find "$out" -name '*.whl' | wc -l) wheels, $(du -sh "$out" | cut -f1) in $out"
