#!/usr/bin/env bash
# Kill-anywhere soak test of the runner: N times, re-run the config from a random stage with
# --force, SIGKILL it at a random moment, then run it plainly; that run must succeed, leave no
# temporary file, and every output (all but records/ and logs/, which hold timings) must be
# byte-identical to an uninterrupted run's.
# Usage: scripts/soak.sh N [CONFIG]   (default config: configs/demo.yaml; needs build/ibmr)
set -euo pipefail
trap 'echo "$(basename "$0"): failed at line $LINENO: $BASH_COMMAND" >&2' ERR
cd "$(dirname "$0")/.."
N="${1:?usage: scripts/soak.sh N [CONFIG]}"
CONFIG="${2:-configs/demo.yaml}"
IBMR="$(pwd)/build/ibmr"
[ -x "$IBMR" ] || { echo "soak: $IBMR missing; run scripts/setup.sh first" >&2; exit 1; }
WORK="$(mktemp -d /tmp/ibmr_soak.XXXXXX)"
trap 'rm -rf "$WORK"' EXIT
STAGES=($(grep -E '^  - [a-z_]+:' "$CONFIG" | sed -E 's/^  - ([a-z_]+):.*/\1/'))

IBMR_WORKSPACE="$WORK/reference" "$IBMR" run "$CONFIG" >"$WORK/reference.log" 2>&1
# Seconds a forced run from stage i takes: its and the later stages' wall time (from the
# reference records) plus half a second of start-up; the kill falls uniformly inside it.
declare -A FROM
total=0.5
for ((k = ${#STAGES[@]} - 1; k >= 0; k--)); do
  wall=$(grep -o '"wall_seconds": *[0-9.e+-]*' "$WORK/reference/records/${STAGES[$k]}.json" | awk '{print $2}')
  total=$(awk -v a="$total" -v b="${wall:-0}" 'BEGIN {print a + b}')
  FROM[${STAGES[$k]}]=$total
done
echo "soak: uninterrupted run of $CONFIG: ${FROM[${STAGES[0]}]} s, stages: ${STAGES[*]}"

outputs() {  # every output file with its checksum, relative to the workspace
  (cd "$1" && find . -type f ! -path './records/*' ! -path './logs/*' -print0 | sort -z | xargs -0 sha256sum)
}
outputs "$WORK/reference" >"$WORK/reference.sums"

WS="$WORK/soak"
IBMR_WORKSPACE="$WS" "$IBMR" run "$CONFIG" >/dev/null 2>&1
kills=0 resumes=0
for i in $(seq 1 "$N"); do
  stage="${STAGES[$((RANDOM % ${#STAGES[@]}))]}"
  delay=$(awk -v t="${FROM[$stage]}" -v r="$RANDOM" 'BEGIN {printf "%.3f", t * r / 32768}')
  IBMR_WORKSPACE="$WS" setsid "$IBMR" run "$CONFIG" --from "$stage" --force >"$WORK/killed.log" 2>&1 &
  pid=$!
  sleep "$delay"
  how="finished before its kill at ${delay} s"  # the delay can outlast the run
  if kill -0 "$pid" 2>/dev/null; then
    kill -KILL -- -"$pid" 2>/dev/null || kill -KILL "$pid" 2>/dev/null || true
    kills=$((kills + 1))
    how="killed after ${delay} s"
  fi
  wait "$pid" 2>/dev/null || true
  if ! IBMR_WORKSPACE="$WS" "$IBMR" run "$CONFIG" >"$WORK/resume.log" 2>&1; then
    echo "soak: round $i (run from $stage $how): the plain run failed:" >&2
    tail -20 "$WORK/resume.log" >&2
    exit 1
  fi
  resumes=$((resumes + 1))
  leftovers=$(find "$WS" -regextype posix-extended -regex '.*\.tmp\.?[0-9]+(\.[^./]+)?$' | head -5 || true)
  if [ -n "$leftovers" ]; then
    echo "soak: round $i (run from $stage $how): temporaries left: $leftovers" >&2
    exit 1
  fi
  if ! outputs "$WS" | diff -q - "$WORK/reference.sums" >/dev/null; then
    echo "soak: round $i (run from $stage $how): outputs differ from the uninterrupted run:" >&2
    outputs "$WS" | diff - "$WORK/reference.sums" | head -10 >&2
    exit 1
  fi
  echo "soak: round $i: run from $stage $how, resumed, outputs identical"
done
echo "soak: $N rounds, $kills kills, $resumes successful resumes, outputs identical, no temporary left"
