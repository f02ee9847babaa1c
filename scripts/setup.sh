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
  colmap
)

missing=()
for package in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$package" 2>/dev/null | grep -q "install ok installed" || missing+=("$package")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing ${#missing[@]} missing packages: ${missing[*]}"
  SUDO=""
  [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

JOBS="${IBMR_BUILD_JOBS:-$(nproc)}"
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build -j "$JOBS" | grep -vE '^\[[0-9]+/[0-9]+\] ' || true
test -x build/ibmr || { echo "setup: build failed (build/ibmr missing)" >&2; exit 1; }
echo "setup: build/ibmr is ready"
