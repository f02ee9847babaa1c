#!/usr/bin/env bash
# Set-up, then the main job on the embedded default: a synthetic scene the project renders
# itself (configs/demo.yaml), then its report page (charts, scores, renders; opens from disk).
# A second run does no work.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh ibmr   # only what the demo runs, not the tests
build/ibmr run configs/demo.yaml --report "$@"
