#!/bin/sh
# Fill numba's on-disk cache (NUMBA_CACHE_DIR) with the compiled kernels of this image's services,
# so that a container's first start loads them instead of compiling (20-60 s each). The
# Dockerfiles run it once at build time, as the image's user would see it: same cache path, same
# interpreter path, same CPU target (NUMBA_CPU_NAME) as at run time. From / : in a source folder
# the copied riskfield/ would shadow the installed package.
#
#   warm-kernels.sh [SERVICE...]     # default: every service with kernels that this install has
#
# `riskfield warmup` (services/runtime/warmup.py) is the one place that knows which kernels a node
# loads; this only fails the build when it does.
set -eu
cd /
exec riskfield warmup "$@"
