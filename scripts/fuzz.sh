#!/usr/bin/env bash
# Fuzzes every reader of outside data with libFuzzer for SECONDS each (default 60): builds the
# harnesses of tests/fuzz with clang-14 into build-fuzz/ (the readers with AddressSanitizer and
# UndefinedBehaviorSanitizer), writes each harness's seed corpus (tests/fuzz/make_seeds.cc: small
# valid files of its format, plus the configs and the data sets' small camera files), then runs the
# harnesses, as many at once as there are cores. Per harness it prints the executions, executions
# per second, corpus size and coverage (libFuzzer's cov:), so that a slow or shallow harness shows.
# Crashes are written to build-fuzz/crashes/<harness>/ and make the script fail; the corpora
# (build-fuzz/corpus/<harness>/) grow run after run.
# Usage: scripts/fuzz.sh [SECONDS] [HARNESS...]
set -euo pipefail
trap 'echo "$(basename "$0"): failed at line $LINENO: $BASH_COMMAND" >&2' ERR
cd "$(dirname "$0")/.."
SECONDS_EACH="${1:-60}"
shift || true
scripts/install_packages.sh clang-14 libclang-rt-14-dev
ROOT="$(pwd)"
OUT="$ROOT/build-fuzz"
build_start=$SECONDS
# The config harness links every stage, run plain: where the gcc build (build/, as setup.sh makes
# it) is there, its stage libraries, brought up to date, rather than every stage compiled again.
PREBUILT=""
if [ -f "$ROOT/build/CMakeCache.txt" ] && cmake --build "$ROOT/build" --target ibmr >/dev/null; then
  PREBUILT="$ROOT/build"
fi
CC=clang-14 CXX=clang++-14 cmake -S . -B "$OUT" -G Ninja -DIBMR_FUZZ=ON -DCMAKE_BUILD_TYPE=None \
  -DIBMR_FUZZ_PREBUILT_STAGES="$PREBUILT" >/dev/null
if ! cmake --build "$OUT" --target fuzz_all -j "$(nproc)" >"$OUT/build.log" 2>&1; then
  grep -E 'error|Error' "$OUT/build.log" | head -20 || true
  echo "fuzz: the harnesses did not build with clang-14 (log: $OUT/build.log); no harness ran"
  exit 1
fi
grep -vE '^\[[0-9]+/[0-9]+\] ' "$OUT/build.log" || true
echo "fuzz: harnesses built in $((SECONDS - build_start)) s"

# Seeds, written afresh each time: small valid files of every format, the configs, and the data
# sets' camera files (text, a few KB).
SEEDS="$OUT/seeds"
DATA="$ROOT/../shared/datasets"
rm -rf "$SEEDS"
"$OUT/tests/fuzz/fuzz_seeds" "$SEEDS"
mkdir -p "$SEEDS/config"
cp "$ROOT"/configs/*.yaml "$SEEDS/config/"
if [ -d "$DATA" ]; then
  find "$DATA" -name '*_par.txt' -size -20k -exec cp {} "$SEEDS/middlebury_par/" \;
  find "$DATA" -name '*.camera' -size -4k -print0 | head -z -n 3 | xargs -0 -r -I{} cp {} "$SEEDS/strecha_camera/"
fi

HARNESSES=("$@")
[ ${#HARNESSES[@]} -eq 0 ] && HARNESSES=(ply colmap_text colmap_array pfm image middlebury_par strecha_camera octree record config
                                         transforms poses_bounds)
run_one() {  # runs one harness; its log is $OUT/fuzz_<name>.log, its exit status $OUT/fuzz_<name>.status
  local name=$1 corpus="$OUT/corpus/$1" crashes="$OUT/crashes/$1" status=0
  mkdir -p "$corpus" "$crashes" "$SEEDS/$name"
  "$OUT/tests/fuzz/fuzz_$name" "$corpus" "$SEEDS/$name" -max_total_time="$SECONDS_EACH" -timeout=10 \
    -rss_limit_mb=2048 -artifact_prefix="$crashes/" -print_final_stats=1 >"$OUT/fuzz_$name.log" 2>&1 || status=$?
  echo "$status" >"$OUT/fuzz_$name.status"
}
JOBS=$(nproc)
for ((i = 0; i < ${#HARNESSES[@]}; i += JOBS)); do
  for name in "${HARNESSES[@]:i:JOBS}"; do run_one "$name" & done
  wait
done

failed=()
printf '%-15s %8s %10s %8s %6s  %s\n' harness execs exec/s corpus cov result
for name in "${HARNESSES[@]}"; do
  log="$OUT/fuzz_$name.log"
  execs=$(awk '/stat::number_of_executed_units/ {print $2}' "$log" | tail -1)
  rate=$(awk '/stat::average_exec_per_sec/ {print $2}' "$log" | tail -1)
  cov=$(grep -o 'cov: [0-9]*' "$log" | tail -1 | awk '{print $2}')
  corpus=$(grep -o 'corp: [0-9]*' "$log" | tail -1 | awk '{print $2}')  # units kept: seeds and finds
  result=ok
  if [ "$(cat "$OUT/fuzz_$name.status")" != 0 ]; then
    result="FAILED (see $log; inputs in $OUT/crashes/$name)"
    failed+=("$name")
  elif [ "${execs:-0}" -lt $((100 * SECONDS_EACH)) ]; then
    result="ok, but under 100 executions a second: slow seeds or a slow reader?"
  fi
  printf '%-15s %8s %10s %8s %6s  %s\n' "$name" "${execs:-?}" "${rate:-?}" "${corpus:-?}" "${cov:-?}" "$result"
done
for name in "${failed[@]}"; do
  echo "fuzz $name:"
  grep -m3 -E 'ERROR|runtime error|SUMMARY' "$OUT/fuzz_$name.log" || true
done
if [ ${#failed[@]} -gt 0 ]; then
  echo "fuzz: ${#failed[@]} harnesses found crashes: ${failed[*]}"
  exit 1
fi
echo "fuzz: ${#HARNESSES[@]} harnesses, $SECONDS_EACH s each, no crash"
