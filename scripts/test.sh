#!/usr/bin/env bash
# Set-up, then the whole test suite with ctest (real-data tests read ../shared/datasets and
# skip with a message where it is absent), then the reliability checks: three kill-anywhere soak
# rounds and a short fuzzing pass of every harness (test-only packages: chromium, clang-14,
# libclang-rt-14-dev; assimp-utils, whose `assimp info` reads the textured OBJ and GLB;
# snakemake, slurm-wlm and munge for the workflow-engine tests, which start their own
# single-node Slurm). A failed part does not stop the later ones; the script ends with the wall
# time of each part and fails if any part failed.
set -euo pipefail
cd "$(dirname "$0")/.."
parts=() failed=()
timed() {  # timed NAME COMMAND...: runs it, notes its wall time and whether it failed
  local name=$1 start=$SECONDS status=0
  shift
  "$@" || status=$?
  parts+=("$name $((SECONDS - start)) s")
  [ "$status" -eq 0 ] || failed+=("$name")
}
summary() { local IFS=,; echo "${parts[*]}" | sed 's/,/, /g'; }
timed build scripts/setup.sh
[ ${#failed[@]} -eq 0 ] || { echo "test: the build failed ($(summary))" >&2; exit 1; }
# Test-only: chromium (headless checks of the report pages), assimp-utils (`assimp info` on the
# textured mesh.obj / mesh.glb), snakemake, slurm-wlm and munge (Snakefile and Slurm runs).
timed packages scripts/install_packages.sh chromium assimp-utils snakemake slurm-wlm munge
timed ctest ctest --test-dir build --output-on-failure -j "$(nproc)" --timeout 600 "$@"
timed soak scripts/soak.sh 3
timed fuzz scripts/fuzz.sh "${IBMR_FUZZ_SECONDS:-10}"
# A failed part does not stop the later ones: one run reports every failure.
if [ ${#failed[@]} -gt 0 ]; then
  echo "test: FAILED: ${failed[*]} ($SECONDS s: $(summary))" >&2
  exit 1
fi
echo "test: passed in $SECONDS s ($(summary))"
