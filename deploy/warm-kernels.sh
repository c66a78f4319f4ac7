#!/bin/sh
# Fill numba's on-disk cache (NUMBA_CACHE_DIR) with the compiled kernels of the services this
# install has, so that a container's first start loads them instead of compiling (20-40 s each).
# The Dockerfiles run it once at build time, as the image's user would see it: same cache path,
# same interpreter path, same CPU target (NUMBA_CPU_NAME) as at run time.
#
# The one place the images warm kernels: it runs `riskfield warmup` where the CLI has it (issue 24,
# item 0), and until then the same calls as tests/conftest.py (_warm_compiled_kernels) plus the
# simulated perception backend's warm-up. Each part is skipped when its extra is not installed.
set -eu
if riskfield warmup --help >/dev/null 2>&1; then
  exec riskfield warmup
fi
exec python -c '
import time
t0 = time.monotonic()
try:
    from riskfield.services.safety_filter.filter import SafetyFilter
except ImportError:
    print("warm-kernels: no safety filter in this install")
else:
    SafetyFilter()
    print(f"warm-kernels: safety filter step ready ({time.monotonic() - t0:.1f} s)")
try:
    from riskfield.services.mapping.mapper import Mapper
    from riskfield.services.mapping.settings import MappingSettings
except ImportError:
    print("warm-kernels: no mapping in this install")
else:
    for output in ("2d", "3d"):
        Mapper(MappingSettings(output=output).mapper_config(), None).warm_up()
    print(f"warm-kernels: mapping kernels ready ({time.monotonic() - t0:.1f} s)")
try:
    from riskfield.services.perception.sim_backend import SimBackend
except ImportError:
    print("warm-kernels: no simulated perception in this install")
else:
    SimBackend().warm_up()
    print(f"warm-kernels: simulated perception kernels ready ({time.monotonic() - t0:.1f} s)")
'
