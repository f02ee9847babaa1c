#!/usr/bin/env bash
# Fuzzes every reader of outside data with libFuzzer for SECONDS each (default 60): builds the
# harnesses of tests/fuzz with clang-14, AddressSanitizer and UndefinedBehaviorSanitizer into
# build-fuzz/, seeds each corpus from ../shared/datasets and from the project's own outputs (a
# demo run), then runs the harnesses one after another. Crashes are written to
# build-fuzz/crashes/<harness>/ and make the script fail; the corpora grow run after run.
# Usage: scripts/fuzz.sh [SECONDS] [HARNESS...]
set -euo pipefail
trap 'echo "$(basename "$0"): failed at line $LINENO: $BASH_COMMAND" >&2' ERR
cd "$(dirname "$0")/.."
SECONDS_EACH="${1:-60}"
shift || true
scripts/install_packages.sh clang-14 libclang-rt-14-dev
ROOT="$(pwd)"
OUT="$ROOT/build-fuzz"
CC=clang-14 CXX=clang++-14 cmake -S . -B "$OUT" -G Ninja -DIBMR_FUZZ=ON -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
if ! cmake --build "$OUT" --target fuzz_all -j "$(nproc)" >"$OUT/build.log" 2>&1; then
  grep -E 'error|Error' "$OUT/build.log" | head -20 || true
  echo "fuzz: the harnesses did not build with clang-14 (log: $OUT/build.log); no harness ran"
  exit 1
fi
grep -vE '^\[[0-9]+/[0-9]+\] ' "$OUT/build.log" || true

# Seeds: the data sets' own files and what the project writes (a demo workspace).
SEEDS="$OUT/seeds"
DATA="$ROOT/../shared/datasets"
if [ ! -d "$SEEDS" ]; then
  set +o pipefail  # `find | head` ends find with SIGPIPE: not a failure here
  mkdir -p "$SEEDS"/{ply,colmap_text,colmap_array,pfm,image,middlebury_par,strecha_camera,octree,record,config}
  cp "$ROOT"/configs/*.yaml "$SEEDS/config/"
  if [ -d "$DATA" ]; then
    find "$DATA" -name '*_par.txt' -size -20k -exec cp {} "$SEEDS/middlebury_par/" \;
    find "$DATA" -name '*.camera' | head -3 | xargs -r -I{} cp {} "$SEEDS/strecha_camera/"
    find "$DATA" -name '*.pfm' -size -400k | head -2 | xargs -r -I{} cp {} "$SEEDS/pfm/"
    find "$DATA" \( -name '*.png' -o -name '*.ppm' \) -size -120k | head -4 | xargs -r -I{} cp {} "$SEEDS/image/"
  fi
  if [ -x "$ROOT/build/ibmr" ]; then
    WS="$OUT/seed_workspace"
    IBMR_WORKSPACE="$WS" "$ROOT/build/ibmr" run configs/demo.yaml >/dev/null 2>&1 || true
    find "$WS" -name '*.ply' -size -2M | head -4 | xargs -r -I{} cp {} "$SEEDS/ply/"
    find "$WS/dense" -name '*.bin' | head -3 | xargs -r -I{} cp {} "$SEEDS/colmap_array/"
    [ -f "$WS/hull/octree.bin" ] && cp "$WS/hull/octree.bin" "$SEEDS/octree/"
    cp "$WS"/records/*.json "$SEEDS/record/" 2>/dev/null || true
    find "$WS/images" -name '*.png' | head -2 | xargs -r -I{} cp {} "$SEEDS/image/"
    "$ROOT/build/ibmr" export-transforms "$WS" "$SEEDS/transforms/demo_transforms.json" >/dev/null 2>&1 || true
    if [ -d "$WS/sparse" ]; then
      { cat "$WS/sparse/cameras.txt"; printf '\n%%%%\n'; head -c 4000 "$WS/sparse/images.txt"; printf '\n%%%%\n';
        head -c 2000 "$WS/sparse/points3D.txt"; } > "$SEEDS/colmap_text/demo_model"
    fi
  fi
  set -o pipefail
fi

mkdir -p "$SEEDS"/{transforms,poses_bounds}  # harnesses added later seed from scratch or from a demo
HARNESSES=("$@")
[ ${#HARNESSES[@]} -eq 0 ] && HARNESSES=(ply colmap_text colmap_array pfm image middlebury_par strecha_camera octree record config
                                         transforms poses_bounds)
failed=()
for name in "${HARNESSES[@]}"; do
  corpus="$OUT/corpus/$name"
  crashes="$OUT/crashes/$name"
  mkdir -p "$corpus" "$crashes"
  start=$(date +%s)
  if "$OUT/tests/fuzz/fuzz_$name" "$corpus" "$SEEDS/$name" -max_total_time="$SECONDS_EACH" -timeout=10 \
       -rss_limit_mb=2048 -artifact_prefix="$crashes/" -print_final_stats=1 >"$OUT/fuzz_$name.log" 2>&1; then
    runs=$(grep -m1 'stat::number_of_executed_units' "$OUT/fuzz_$name.log" | awk '{print $2}')
    echo "fuzz $name: ok, $((  $(date +%s) - start )) s, ${runs:-?} runs, corpus $(ls "$corpus" | wc -l)"
  else
    echo "fuzz $name: FAILED (see $OUT/fuzz_$name.log; inputs in $crashes)"
    grep -m3 -E 'ERROR|runtime error|SUMMARY' "$OUT/fuzz_$name.log" || true
    failed+=("$name")
  fi
done
if [ ${#failed[@]} -gt 0 ]; then
  echo "fuzz: ${#failed[@]} harnesses found crashes: ${failed[*]}"
  exit 1
fi
echo "fuzz: ${#HARNESSES[@]} harnesses, $SECONDS_EACH s each, no crash"
