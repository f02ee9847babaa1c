#!/usr/bin/env bash
# Installs the Debian 12 packages ibmr needs (only the missing ones; quiet when all are there)
# and builds Release into build/, leaving the command-line tool at build/ibmr.
# Idempotent: a second run installs nothing and rebuilds only what changed.
set -euo pipefail
cd "$(dirname "$0")/.."

PACKAGES=(
  build-essential cmake ninja-build pkg-config
  libopencv-dev libeigen3-dev libtbb-dev libyaml-cpp-dev nlohmann-json3-dev libspdlog-dev
  libcli11-dev libgtest-dev libxxhash-dev libexif-dev libopenmesh-dev libceres-dev
  libcgal-dev libgmp-dev libmpfr-dev libnanoflann-dev
  colmap libjs-chart.js
)

scripts/install_packages.sh "${PACKAGES[@]}"

JOBS="${IBMR_BUILD_JOBS:-$(nproc)}"
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build -j "$JOBS" | grep -vE '^\[[0-9]+/[0-9]+\] ' || true
test -x build/ibmr || { echo "setup: build failed (build/ibmr missing)" >&2; exit 1; }
echo "setup: build/ibmr is ready"
