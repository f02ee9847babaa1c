#!/usr/bin/env bash
# Set-up, then the whole test suite with ctest (real-data tests read ../shared/datasets and
# skip with a message where it is absent), then the reliability checks: three kill-anywhere soak
# rounds and a short fuzzing pass of every harness (test-only packages: chromium, clang-14,
# libclang-rt-14-dev; assimp-utils, whose `assimp info` reads the textured OBJ and GLB;
# snakemake, slurm-wlm and munge for the workflow-engine tests, which start their own
# single-node Slurm).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
scripts/install_packages.sh chromium   # test-only: headless checks of the report pages
scripts/install_packages.sh assimp-utils   # test-only: `assimp info` on textured mesh.obj / mesh.glb
scripts/install_packages.sh snakemake slurm-wlm munge   # test-only: Snakefile and Slurm runs
ctest --test-dir build --output-on-failure -j "$(nproc)" --timeout 600 "$@"
scripts/soak.sh 3
scripts/fuzz.sh "${IBMR_FUZZ_SECONDS:-10}"
