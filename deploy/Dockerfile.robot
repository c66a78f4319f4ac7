# syntax=docker/dockerfile:1.7
# riskfield robot image: the safety filter and the hardware bridges (LIMO serial, joystick,
# MAVLink) with the `robot` extra only — numpy, scipy, osqp, pyserial, pymavlink, evdev.
# No open3d, no torch, no numba: it fits a Jetson or a Raspberry Pi. Multi-arch:
#
#   docker buildx build --platform linux/arm64,linux/amd64 -f deploy/Dockerfile.robot \
#       -t REGISTRY/riskfield-robot:TAG --push .
#
# Build context: the repository root (deploy/Dockerfile.robot.dockerignore keeps it small).

ARG PYTHON_IMAGE=python:3.11-slim-bookworm

FROM ${PYTHON_IMAGE} AS build
# pipefail: the install check below pipes `pip show` into grep.
SHELL ["/bin/bash", "-o", "pipefail", "-c"]
# Compilers only in the build stage, for a dependency without a wheel on this platform.
# Debian/Ubuntu package versions follow the base image's suite (security updates); exact pins
# break as soon as the mirror moves on.
# hadolint ignore=DL3008
RUN apt-get update \
 && apt-get install -y --no-install-recommends build-essential \
 && rm -rf /var/lib/apt/lists/*
RUN python -m venv /opt/venv
ENV PATH=/opt/venv/bin:$PATH PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1
WORKDIR /src
COPY pyproject.toml setup.py README.md ./
COPY riskfield riskfield
COPY protocol protocol
COPY services services
COPY edge edge
# "." is this repository: its dependencies' version ranges live in pyproject.toml.
# The filter's compiled step (numba) is built here once, into the venv's cache, so a node's first
# start does not spend 20 s compiling.
# hadolint ignore=DL3013
RUN pip install ".[robot]" \
 && ! pip show open3d torch 2>/dev/null | grep -q '^Name:' \
 && python -c "from riskfield.services.safety_filter.filter import SafetyFilter; SafetyFilter()"

FROM ${PYTHON_IMAGE}
# Debian/Ubuntu package versions follow the base image's suite (security updates); exact pins
# break as soon as the mirror moves on.
# hadolint ignore=DL3008
RUN apt-get update \
 && apt-get install -y --no-install-recommends libusb-1.0-0 \
 && rm -rf /var/lib/apt/lists/*
COPY --from=build /opt/venv /opt/venv
ENV PATH=/opt/venv/bin:$PATH PYTHONUNBUFFERED=1 RISKFIELD_MODE=client
# dialout owns serial ports (the LIMO's /dev/ttyTHS1); input owns /dev/input/event*.
RUN useradd --system --create-home --uid 10001 --groups dialout riskfield \
 && (getent group input >/dev/null || groupadd --system input) \
 && usermod -aG input riskfield
# Numeric: a host or orchestrator (runAsNonRoot) can check it without the image's passwd.
USER 10001
WORKDIR /home/riskfield
ENTRYPOINT ["riskfield"]
CMD ["services"]
