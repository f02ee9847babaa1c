#!/usr/bin/env bash
# Total time and per-job overhead of one config run four ways, in one run (Release build):
#   local              build/ibmr run CONFIG
#   snakemake          ibmr export snakemake CONFIG, then snakemake --cores N on this machine
#   slurm              build/ibmr run CONFIG --executor slurm (job arrays for per-view stages)
#   snakemake_slurm    the same Snakefile with snakemake --cluster sbatch
# on a single-node Slurm started for the benchmark (scripts/local_slurm.sh; needs root, slurm-wlm,
# munge, snakemake). Each engine starts from an empty workspace. Its added seconds per job are
# (its wall time - the local wall time) / its number of jobs (Slurm jobs or array tasks, or
# Snakemake jobs). Every workspace is checked against the local one (outputs byte for byte).
# Usage: scripts/bench_workflow_engines.sh [CONFIG] [BENCH_DIR]
#   (default configs/middlebury_temple_sparse.yaml and build/bench_workflow_engines;
#    writes bench_workflow_engines.json there)
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
CONFIG="$(realpath "${1:-$ROOT/configs/middlebury_temple_sparse.yaml}")"
BENCH="$(realpath -m "${2:-$ROOT/build/bench_workflow_engines}")"
IBMR="$ROOT/build/ibmr"
CORES=$(nproc)
rm -rf "$BENCH"
mkdir -p "$BENCH"

now() { date +%s.%N; }
elapsed() { python3 -c "print(round($(now) - $1, 3))"; }
same_outputs() {  # REFERENCE OTHER: 1 when every output file is identical
  (cd "$1" && find . -type f -not -path './records/*' -not -path './logs/*' -not -path './.snakemake/*' | sort) |
    while read -r f; do cmp -s "$1/$f" "$2/$f" || { echo 0; return; }; done | grep -q 0 && echo 0 || echo 1
}

echo "bench_workflow_engines: local"
start=$(now)
"$IBMR" run "$CONFIG" --workspace "$BENCH/local" >"$BENCH/local.log" 2>&1
local_wall=$(elapsed "$start")
stages=$(ls "$BENCH/local/records/"*.json | wc -l)

echo "bench_workflow_engines: snakemake --cores $CORES"
"$IBMR" export snakemake "$CONFIG" --workspace "$BENCH/snakemake" >"$BENCH/Snakefile.local"
mkdir -p "$BENCH/snakemake"
start=$(now)
(cd "$BENCH" && snakemake -s "$BENCH/Snakefile.local" --cores "$CORES" >"$BENCH/snakemake.log" 2>&1)
snakemake_wall=$(elapsed "$start")
snakemake_jobs=$(grep -c '^Finished job' "$BENCH/snakemake.log" || true)

eval "$("$ROOT/scripts/local_slurm.sh" start "$BENCH/cluster")"
trap '"$ROOT/scripts/local_slurm.sh" stop "$BENCH/cluster"' EXIT

echo "bench_workflow_engines: --executor slurm"
start=$(now)
"$IBMR" run "$CONFIG" --workspace "$BENCH/slurm" --executor slurm >"$BENCH/slurm.log" 2>&1
slurm_wall=$(elapsed "$start")
slurm_jobs=$(python3 - "$BENCH/slurm.log" <<'PY'
import re, sys
jobs = 0
for line in open(sys.argv[1]):
    m = re.search(r"\] \S+: (\d+) view\(s\) as array job", line)
    jobs += int(m.group(1)) if m else (1 if re.search(r"\] \S+: (stage|merge) as job", line) else 0)
print(jobs)
PY
)

echo "bench_workflow_engines: snakemake --cluster sbatch"
"$IBMR" export snakemake "$CONFIG" --workspace "$BENCH/snakemake_slurm" >"$BENCH/Snakefile.slurm"
mkdir -p "$BENCH/snakemake_slurm"
start=$(now)
(cd "$BENCH" && snakemake -s "$BENCH/Snakefile.slurm" --cores "$CORES" --jobs 32 --latency-wait 5 \
  --cluster-cancel scancel \
  --cluster "sbatch --parsable --cpus-per-task={threads} --mem={resources.mem_mb} --output=.snakemake/slurm-%j.out" \
  >"$BENCH/snakemake_slurm.log" 2>&1)
snakemake_slurm_wall=$(elapsed "$start")
snakemake_slurm_jobs=$(grep -c '^Finished job' "$BENCH/snakemake_slurm.log" || true)

python3 - "$BENCH" "$CONFIG" "$CORES" "$stages" "$local_wall" \
  "$snakemake_wall" "$snakemake_jobs" "$(same_outputs "$BENCH/local" "$BENCH/snakemake")" \
  "$slurm_wall" "$slurm_jobs" "$(same_outputs "$BENCH/local" "$BENCH/slurm")" \
  "$snakemake_slurm_wall" "$snakemake_slurm_jobs" "$(same_outputs "$BENCH/local" "$BENCH/snakemake_slurm")" <<'PY'
import json, sys
bench, config, cores, stages, local = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), float(sys.argv[5])
rows = {"local": {"wall_seconds": local, "jobs": stages, "same_outputs_as_local": True}}
for i, name in enumerate(["snakemake", "slurm", "snakemake_slurm"]):
    wall, jobs, same = float(sys.argv[6 + 3 * i]), int(sys.argv[7 + 3 * i]), sys.argv[8 + 3 * i] == "1"
    rows[name] = {"wall_seconds": wall, "jobs": jobs, "same_outputs_as_local": same,
                  "ratio_to_local": round(wall / local, 3),
                  "added_seconds_per_job": round((wall - local) / jobs, 3) if jobs else None}
result = {"config": config, "cores": cores, "engines": rows}
json.dump(result, open(f"{bench}/bench_workflow_engines.json", "w"), indent=2)
for name, row in rows.items():
    extra = f", {row['ratio_to_local']}x local, +{row['added_seconds_per_job']} s/job" if name != "local" else ""
    print(f"  {name:16s} {row['wall_seconds']:8.1f} s  {row['jobs']:3d} jobs  same outputs: {row['same_outputs_as_local']}{extra}")
print(f"bench_workflow_engines: {bench}/bench_workflow_engines.json")
PY
