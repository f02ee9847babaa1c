#!/usr/bin/env bash
# Installs the Debian 12 packages ibmr needs (only the missing ones; quiet when all are there)
# and builds Release into build/, leaving the command-line tool at build/ibmr.
# Usage: scripts/setup.sh [TARGET...]   (no target: everything, the tests included)
# Idempotent: a second run installs nothing and rebuilds only what changed.
set -euo pipefail
cd "$(dirname "$0")/.."

PACKAGES=(
  build-essential cmake ninja-build pkg-config
  libopencv-dev libeigen3-dev libtbb-dev libyaml-cpp-dev nlohmann-json3-dev libspdlog-dev
  libcli11-dev libgtest-dev libxxhash-dev libexif-dev libopenmesh-dev libceres-dev
  libcgal-dev libgmp-dev libmpfr-dev libnanoflann-dev libsqlite3-dev libtinygltf-dev libpng-dev
  libdeflate-dev
  colmap libjs-chart.js libjs-three
)

scripts/install_packages.sh "${PACKAGES[@]}"

JOBS="${IBMR_BUILD_JOBS:-$(nproc)}"
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
# Targets given as arguments (the demo builds only `ibmr`); none: everything, tests included.
TARGETS=()
for target in "$@"; do TARGETS+=(--target "$target"); done
# Progress lines are dropped; warnings and errors are shown. The build's own status decides: a
# failed build never passes for a stale build/ibmr from an earlier one.
set +e
cmake --build build -j "$JOBS" "${TARGETS[@]}" 2>&1 | grep -vE '^\[[0-9]+/[0-9]+\] '
build_status=${PIPESTATUS[0]}
set -e
[ "$build_status" -eq 0 ] || { echo "setup: the build failed (errors above)" >&2; exit 1; }
test -x build/ibmr || { echo "setup: build failed (build/ibmr missing)" >&2; exit 1; }
echo "setup: build/ibmr is ready"
