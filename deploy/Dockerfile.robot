# syntax=docker/dockerfile:1.7
# riskfield robot image: the safety filter and the hardware bridges (LIMO serial, joystick,
# MAVLink) with the `robot` extra only — numpy, scipy, osqp, numba (the filter's compiled step;
# aarch64 wheels exist), pyserial, pymavlink, evdev. No open3d, no torch: it fits a Jetson or a
# Raspberry Pi. Multi-arch with BuildKit, or with the classic builder on each architecture:
#
#   docker buildx build --platform linux/arm64,linux/amd64 -f deploy/Dockerfile.robot \
#       -t REGISTRY/riskfield-robot:TAG --push .
#   make images       # no registry: a local Debian base and the host's wheelhouse (docs/deployment.md)
#
# Build context: the repository root (the root .dockerignore keeps it small; the classic
# builder reads only that one). Builds with BuildKit and with the classic builder alike.

ARG PYTHON_IMAGE=python:3.11-slim-bookworm

FROM ${PYTHON_IMAGE} AS build
# pipefail: the install check below pipes `pip show` into grep.
SHELL ["/bin/bash", "-o", "pipefail", "-c"]
# The same paths as the runtime stage: numba's cache is keyed on the source file's path.
ENV PATH=/opt/venv/bin:$PATH PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1 \
    NUMBA_CACHE_DIR=/opt/riskfield/numba-cache NUMBA_CPU_NAME=generic
# The host's wheelhouse (scripts/wheelhouse.sh); empty when the build reaches the package index.
COPY deploy/wheels /wheels
# Compilers only in the build stage and only without a wheelhouse, for a dependency without a
# wheel on this platform. Debian package versions follow the base image's suite (security
# updates); exact pins break as soon as the mirror moves on.
# hadolint ignore=DL3008
RUN if ! ls /wheels/*.whl >/dev/null 2>&1; then \
      apt-get update && apt-get install -y --no-install-recommends build-essential \
      && rm -rf /var/lib/apt/lists/*; fi \
 && python -m venv /opt/venv
WORKDIR /src
COPY pyproject.toml setup.py README.md ./
COPY riskfield riskfield
COPY protocol protocol
COPY services services
COPY edge edge
# "." is this repository: its dependencies' version ranges live in pyproject.toml. With a
# wheelhouse, nothing comes from the index (--no-index), as on an air-gapped site.
# hadolint ignore=DL3013
RUN set --; if ls /wheels/*.whl >/dev/null 2>&1; then set -- --no-index --find-links /wheels; fi; \
    pip install "$@" ".[robot]" \
 && rm -rf /src/build /src/*.egg-info
# Checks and warm-up from / : in /src the copied riskfield/ folder would shadow the installed package.
WORKDIR /
COPY deploy/warm-kernels.sh /opt/riskfield/warm-kernels.sh
# No torch, no open3d; then the filter's compiled step into NUMBA_CACHE_DIR, so a container's
# first start loads it instead of compiling for 20 s. Trimmed: the test suites shipped inside
# numpy and scipy (never run here).
RUN ! pip show open3d torch 2>/dev/null | grep -q '^Name:' \
 && /opt/riskfield/warm-kernels.sh safety-filter \
 && rm -rf /opt/venv/lib/python3.11/site-packages/scipy/*/tests /opt/venv/lib/python3.11/site-packages/scipy/*/*/tests \
           /opt/venv/lib/python3.11/site-packages/numpy/*/tests /opt/venv/lib/python3.11/site-packages/numba/tests
# pymavlink ships ~40 generated dialects, twice (MAVLink 1 and 2), with their bytecode: 90 MB. Kept:
# all (mavutil's default), ardupilotmega (ArduPilot), common (PX4), minimal and standard; another one
# needs MAVLINK_DIALECT and a build without this line.
WORKDIR /opt/venv/lib/python3.11/site-packages/pymavlink/dialects
RUN find v10 v20 -maxdepth 2 -type f \
      ! -name '__init__*' ! -name 'all*' ! -name 'ardupilotmega*' ! -name 'common*' ! -name 'minimal*' ! -name 'standard*' -delete \
 && python -c "from pymavlink.dialects.v20 import all, ardupilotmega, common; from pymavlink import mavutil"
WORKDIR /

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
 && usermod -aG input riskfield
COPY --from=build /opt/venv /opt/venv
# The warm cache, owned by the image's user: numba uses a cache folder only where it can write.
COPY --from=build --chown=10001:10001 /opt/riskfield /opt/riskfield
COPY deploy/healthcheck.py /opt/riskfield/healthcheck.py
ENV PATH=/opt/venv/bin:$PATH PYTHONUNBUFFERED=1 RISKFIELD_MODE=client \
    NUMBA_CACHE_DIR=/opt/riskfield/numba-cache NUMBA_CPU_NAME=generic
# Numeric: a host or orchestrator (runAsNonRoot) can check it without the image's passwd.
USER 10001
WORKDIR /home/riskfield
ENTRYPOINT ["riskfield"]
CMD ["services"]
