#!/usr/bin/env bash
# Benchmark of calibration and structure from motion: runs each dataset's config (known
# intrinsics and, for the ring / fountain sets, intrinsics estimated) in a fresh workspace under
# BENCH_DIR and writes one JSON (BENCH_DIR/bench_sfm.json): per run and stage the wall and CPU time
# and peak memory (from the run records), per COLMAP step its time and peak memory (sfm metrics),
# and the pose errors (eval_poses metrics) or the calibration figures.
# Usage: scripts/bench_sfm.sh [BUILD_DIR] [BENCH_DIR] [RUN_NAME ...]   (default: every run)
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
BUILD="${1:-$ROOT/build}"
BENCH="${2:-$ROOT/../workspaces/bench_sfm}"
shift $(( $# > 2 ? 2 : $# ))
IBMR="$BUILD/ibmr"
[ -x "$IBMR" ] || { echo "bench_sfm: $IBMR not found; build the ibmr target first" >&2; exit 1; }
command -v colmap >/dev/null || { echo "bench_sfm: colmap not installed (apt-get install colmap)" >&2; exit 1; }
mkdir -p "$BENCH"

# name|config|--set overrides
RUNS=(
  "chessboard|opencv_chessboard.yaml|"
  "temple_sparse_known|middlebury_temple_sparse_sfm.yaml|"
  "temple_sparse_estimated|middlebury_temple_sparse_sfm.yaml|sfm.known_intrinsics=false"
  "fountain_known|strecha_fountain_sfm.yaml|"
  "fountain_estimated|strecha_fountain_sfm.yaml|sfm.known_intrinsics=false"
  "dino_sparse|middlebury_dino_sparse_sfm.yaml|"
  "temple_ring_known|middlebury_temple_ring_sfm.yaml|"
  "temple_ring_estimated|middlebury_temple_ring_sfm.yaml|sfm.known_intrinsics=false"
  "synth_known|synth_sfm.yaml|"
  "synth_estimated|synth_sfm.yaml|sfm.known_intrinsics=false"
)
SELECTED=("$@")
for entry in "${RUNS[@]}"; do
  IFS='|' read -r name config set <<<"$entry"
  if [ ${#SELECTED[@]} -gt 0 ] && [[ ! " ${SELECTED[*]} " =~ " $name " ]]; then continue; fi
  ws="$BENCH/$name"
  rm -rf "$ws"
  args=(run "$ROOT/configs/$config" --workspace "$ws")
  [ -n "$set" ] && args+=(--set "$set")
  echo "== $name: ibmr ${args[*]}"
  "$IBMR" "${args[@]}" > "$BENCH/$name.log" 2>&1 || echo "   (run failed; see $BENCH/$name.log)"
done

python3 - "$BENCH" <<'PY'
import json, os, sys, glob
bench = sys.argv[1]
out = {"runs": {}}
for ws in sorted(glob.glob(os.path.join(bench, "*/"))):
    name = os.path.basename(ws.rstrip("/"))
    run = {}
    for rec in sorted(glob.glob(os.path.join(ws, "records", "*.json"))):
        try:
            r = json.load(open(rec))
        except Exception:
            continue
        stage = r.get("stage", os.path.basename(rec)[:-5])
        entry = {k: r.get(k) for k in ("status", "wall_seconds", "cpu_seconds", "peak_memory_mb", "error")}
        m = r.get("metrics", {})
        if stage == "sfm":
            entry["colmap_steps"] = m.get("steps")
            entry["registered"] = m.get("registered"); entry["images"] = m.get("images")
            entry["unregistered_images"] = m.get("unregistered_images"); entry["intrinsics"] = m.get("intrinsics")
            entry["attempts"] = m.get("attempts"); entry["failure"] = m.get("failure")
        elif stage == "eval_poses":
            entry.update({k: v for k, v in m.items() if k != "cameras"})
        elif stage == "calibrate":
            entry.update({k: m.get(k) for k in ("fx", "fy", "rms_px", "rejected", "used_views")})
        run[stage] = entry
    out["runs"][name] = run
path = os.path.join(bench, "bench_sfm.json")
json.dump(out, open(path, "w"), indent=2)
print("wrote", path)
PY
