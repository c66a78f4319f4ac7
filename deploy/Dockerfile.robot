# syntax=docker/dockerfile:1.7
# riskfield robot image: the safety filter and the hardware bridges (LIMO serial, joystick,
# MAVLink) and the camera node, with the robot site's extras only (deploy/requirements.py SITES):
# `robot` — numpy, scipy, numba (the filter's compiled step; aarch64 wheels exist), pyserial,
# pymavlink, evdev — and `camera` (PyAV). No open3d, no torch: it fits a Jetson or a
# Raspberry Pi. Multi-arch with BuildKit, or with the classic builder on each architecture:
#
#   docker buildx build --platform linux/arm64,linux/amd64 -f deploy/Dockerfile.robot \
#       -t REGISTRY/riskfield-robot:TAG --push .
#   make images       # no registry: a local Debian base and the host's wheelhouse (docs/deployment.md)
#
# Build context: the repository root (the root .dockerignore keeps it small; the classic
# builder reads only that one). Builds with BuildKit and with the classic builder alike.
# Layers, cheapest to rebuild last: the dependencies (from pyproject.toml only), then the
# project's own install and the kernels' warm-up (any source edit rebuilds only these).

ARG PYTHON_IMAGE=python:3.11-slim-bookworm

# -- the dependencies, in a virtualenv the runtime stage copies --------------------------------
FROM ${PYTHON_IMAGE} AS deps
# pipefail: the install check below pipes `pip show` into grep.
SHELL ["/bin/bash", "-o", "pipefail", "-c"]
ENV PATH=/opt/venv/bin:$PATH PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1
# The host's wheelhouse (scripts/wheelhouse.sh); empty when the build reaches the package index.
COPY deploy/wheels /wheels
# Compilers only in this stage and only without a wheelhouse, for a dependency without a wheel
# on this platform. Debian package versions follow the base image's suite (security updates).
# hadolint ignore=DL3008
RUN if ! ls /wheels/*.whl >/dev/null 2>&1; then \
      apt-get update && apt-get install -y --no-install-recommends build-essential \
      && rm -rf /var/lib/apt/lists/*; fi \
 && python -m venv /opt/venv
WORKDIR /deps
COPY pyproject.toml deploy/requirements.py ./
# With a wheelhouse nothing comes from the index (--no-index), as on an air-gapped site.
# setuptools + wheel: the runtime stage builds the project itself without build isolation.
# Then: no torch, no open3d; the test suites shipped inside numpy, scipy and numba trimmed.
# hadolint ignore=DL3013
RUN set --; if ls /wheels/*.whl >/dev/null 2>&1; then set -- --no-index --find-links /wheels; fi; \
    python requirements.py robot-site > requirements.txt \
 && pip install "$@" --upgrade setuptools wheel \
 && pip install "$@" -r requirements.txt \
 && ! pip show open3d torch 2>/dev/null | grep -q '^Name:' \
 && rm -rf /opt/venv/lib/python3.11/site-packages/scipy/*/tests /opt/venv/lib/python3.11/site-packages/scipy/*/*/tests \
           /opt/venv/lib/python3.11/site-packages/numpy/*/tests /opt/venv/lib/python3.11/site-packages/numba/tests
# pymavlink ships ~40 generated dialects, twice (MAVLink 1 and 2), with their bytecode: 90 MB. Kept:
# all (mavutil's default), ardupilotmega (ArduPilot), common (PX4), minimal and standard; another one
# needs MAVLINK_DIALECT and a build without this line.
WORKDIR /opt/venv/lib/python3.11/site-packages/pymavlink/dialects
RUN find v10 v20 -maxdepth 2 -type f \
      ! -name '__init__*' ! -name 'all*' ! -name 'ardupilotmega*' ! -name 'common*' ! -name 'minimal*' ! -name 'standard*' -delete \
 && python -c "from pymavlink.dialects.v20 import all, ardupilotmega, common; from pymavlink import mavutil"

# -- runtime ------------------------------------------------------------------------------------
FROM ${PYTHON_IMAGE}
# Debian/Ubuntu package versions follow the base image's suite (security updates); exact pins
# break as soon as the mirror moves on.
# hadolint ignore=DL3008
RUN apt-get update \
 && apt-get install -y --no-install-recommends libusb-1.0-0 \
 && rm -rf /var/lib/apt/lists/*
# dialout owns serial ports (the LIMO's /dev/ttyTHS1); input owns /dev/input/event*.
RUN useradd --system --create-home --uid 10001 --groups dialout riskfield \
 && (getent group input >/dev/null || groupadd --system input) \
 && usermod -aG input riskfield \
 && install -d -o 10001 -g 10001 /opt/riskfield
COPY --from=deps /opt/venv /opt/venv
# The same cache path and CPU target at build and run time: numba keys its cache on both.
ENV PATH=/opt/venv/bin:$PATH PYTHONUNBUFFERED=1 RISKFIELD_MODE=client PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 NUMBA_CACHE_DIR=/opt/riskfield/numba-cache NUMBA_CPU_NAME=generic
COPY pyproject.toml setup.py README.md /src/
COPY riskfield /src/riskfield
COPY protocol /src/protocol
COPY services /src/services
COPY edge /src/edge
# The project only (its dependencies are above); the source copy goes, so nothing shadows it.
RUN pip install --no-deps --no-build-isolation --no-index /src && rm -rf /src
COPY deploy/warm-kernels.sh /opt/riskfield/
# Numeric: a host or orchestrator (runAsNonRoot) can check it without the image's passwd.
USER 10001
# The filter's compiled step into NUMBA_CACHE_DIR, as the image's user (numba uses a cache folder
# only where it can write): a container's first start loads it instead of compiling for 20 s.
RUN /opt/riskfield/warm-kernels.sh safety-filter
# After the warm-up: an edit of the check does not compile the kernels again.
COPY deploy/healthcheck.py /opt/riskfield/
WORKDIR /home/riskfield
ENTRYPOINT ["riskfield"]
CMD ["services"]
