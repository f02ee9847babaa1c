#!/usr/bin/env bash
# Set-up, then the whole test suite with ctest (real-data tests read ../shared/datasets and
# skip with a message where it is absent).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
ctest --test-dir build --output-on-failure -j "$(nproc)" --timeout 600 "$@"
