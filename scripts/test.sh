#!/usr/bin/env bash
# Set-up, then the whole test suite with ctest (real-data tests read ../shared/datasets and
# skip with a message where it is absent), then the reliability checks: three kill-anywhere soak
# rounds and a short fuzzing pass of every harness (test-only packages: chromium, clang-14,
# libclang-rt-14-dev; assimp-utils, whose `assimp info` reads the textured OBJ and GLB;
# snakemake, slurm-wlm and munge for the workflow-engine tests, which start their own
# single-node Slurm). Ends with the wall time of each part.
set -euo pipefail
cd "$(dirname "$0")/.."
parts=()
timed() {  # timed NAME COMMAND...: runs it and notes its wall time for the summary at the end
  local name=$1 start=$SECONDS
  shift
  "$@"
  parts+=("$name $((SECONDS - start)) s")
}
timed build scripts/setup.sh
# Test-only: chromium (headless checks of the report pages), assimp-utils (`assimp info` on the
# textured mesh.obj / mesh.glb), snakemake, slurm-wlm and munge (Snakefile and Slurm runs).
timed packages scripts/install_packages.sh chromium assimp-utils snakemake slurm-wlm munge
timed ctest ctest --test-dir build --output-on-failure -j "$(nproc)" --timeout 600 "$@"
timed soak scripts/soak.sh 3
timed fuzz scripts/fuzz.sh "${IBMR_FUZZ_SECONDS:-10}"
echo "test: passed in $SECONDS s ($(IFS=,; echo "${parts[*]}" | sed 's/,/, /g'))"
