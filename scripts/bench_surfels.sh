#!/usr/bin/env bash
# Benchmark of the surfels stage against screened Poisson (COLMAP's poisson_mesher, depth 10,
# trim 7) on the same fused points, in one run (Release build):
#  1. synthetic object ring (configs/synth_dense.yaml: 640x480, 24 views, every 8th held out):
#     accuracy (distance to the true mesh at 90%) and completeness (true surface within 1% of its
#     bounding-box diagonal) of surfels/mesh.ply and of Poisson's mesh, both measured by
#     `ibmr mesh-accuracy` with the same samples, and each method's time;
#  2. templeRing (configs/middlebury_temple_ring.yaml, skipped when ../shared/datasets is absent):
#     the whole chain's wall time from images to scores (sum of the stage records), the surfels
#     stage's time and peak memory, Poisson's time, and the held-out scores of every proxy with
#     Poisson's mesh rendered by the same render stage beside them. MVE's whole chain took 139.7 s
#     on this data (measured when the surfaces issue was filed) and is printed for comparison.
# Usage: scripts/bench_surfels.sh [BENCH_DIR]   (default build/bench_surfels; writes bench_surfels.json)
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
BENCH="${1:-$ROOT/build/bench_surfels}"
IBMR="$ROOT/build/ibmr"
mkdir -p "$BENCH"
command -v colmap >/dev/null || { echo "bench_surfels: colmap is not installed (scripts/setup.sh installs it)" >&2; exit 1; }

now() { date +%s.%N; }
poisson() {  # FUSED OUT LOG: prints the seconds taken
  local start; start=$(now)
  colmap poisson_mesher --input_path "$1" --output_path "$2" --PoissonMeshing.depth 10 --PoissonMeshing.trim 7 >"$3" 2>&1
  python3 -c "print($(now) - $start)"
}

echo "bench_surfels: synthetic ring"
SYNTH="$BENCH/synth"
"$IBMR" run "$ROOT/configs/synth_dense.yaml" --workspace "$SYNTH" >"$BENCH/synth_run.log" 2>&1
mkdir -p "$SYNTH/bench"
SYNTH_POISSON_S=$(poisson "$SYNTH/dense/fused.ply" "$SYNTH/bench/poisson.ply" "$BENCH/synth_poisson.log")
"$IBMR" mesh-accuracy "$SYNTH/surfels/mesh.ply" "$SYNTH/ground_truth/mesh.ply" >"$BENCH/synth_surfels_accuracy.json"
"$IBMR" mesh-accuracy "$SYNTH/bench/poisson.ply" "$SYNTH/ground_truth/mesh.ply" >"$BENCH/synth_poisson_accuracy.json"

TEMPLE_DATA="$ROOT/../shared/datasets/middlebury_templeRing"
TEMPLE="$BENCH/temple"
TEMPLE_POISSON_S=""
if [ -f "$TEMPLE_DATA/templeR_par.txt" ]; then
  echo "bench_surfels: templeRing (whole chain, then Poisson on the same points)"
  rm -rf "$TEMPLE"
  "$IBMR" run "$ROOT/configs/middlebury_temple_ring.yaml" --workspace "$TEMPLE" >"$BENCH/temple_run.log" 2>&1
  cp "$TEMPLE/records/"*.json "$BENCH/" 2>/dev/null || true
  mkdir -p "$TEMPLE/bench" "$BENCH/temple_records"
  cp "$TEMPLE/records/"*.json "$BENCH/temple_records/"
  TEMPLE_POISSON_S=$(poisson "$TEMPLE/dense/fused.ply" "$TEMPLE/bench/poisson.ply" "$BENCH/temple_poisson.log")
  "$IBMR" run "$ROOT/configs/middlebury_temple_ring.yaml" --workspace "$TEMPLE" --from render --force \
    --set 'render.proxies=[plane, hull/hull.ply, surfels=surfels/mesh.ply, "surfels_hull=surfels/mesh.ply|hull/hull.ply", poisson=bench/poisson.ply, "poisson_hull=bench/poisson.ply|hull/hull.ply"]' \
    >"$BENCH/temple_poisson_render.log" 2>&1
else
  echo "bench_surfels: $TEMPLE_DATA is absent; templeRing skipped"
fi

python3 - "$BENCH" "$SYNTH_POISSON_S" "$TEMPLE_POISSON_S" <<'PY'
import glob, json, os, sys
bench, synth_poisson_s, temple_poisson_s = sys.argv[1], float(sys.argv[2]), sys.argv[3]
def record(ws, stage):
    path = os.path.join(ws, "records", stage + ".json")
    return json.load(open(path)) if os.path.exists(path) else {}
def stage_wall(r):
    return r.get("wall_seconds", r.get("seconds", 0.0))
synth = os.path.join(bench, "synth")
surfels = record(synth, "surfels")
out = {"synthetic_ring": {
    "fused_points": record(synth, "fuse").get("metrics", {}).get("points"),
    "surfels": json.load(open(os.path.join(bench, "synth_surfels_accuracy.json"))),
    "surfels_seconds": stage_wall(surfels),
    "poisson": json.load(open(os.path.join(bench, "synth_poisson_accuracy.json"))),
    "poisson_seconds": synth_poisson_s}}
s, p = out["synthetic_ring"]["surfels"], out["synthetic_ring"]["poisson"]
out["synthetic_ring"]["surfels_better_accuracy"] = s["accuracy_90"] < p["accuracy_90"]
out["synthetic_ring"]["surfels_better_completeness"] = s["completeness"] > p["completeness"]
temple = os.path.join(bench, "temple")
if temple_poisson_s:
    records = {os.path.basename(f)[:-5]: json.load(open(f)) for f in glob.glob(os.path.join(bench, "temple_records", "*.json"))}
    chain = sum(stage_wall(r) for r in records.values())
    scores = json.load(open(os.path.join(temple, "scores", "heldout.json")))
    per_model = {}
    for name, proxy in scores["proxies"].items():
        if proxy.get("status") != "scored":
            continue
        views = {k: v for k, v in proxy["views"].items() if "0001" not in k}  # 0001 has a twin among the training views
        mean = lambda key: sum(v[key] for v in views.values()) / len(views)
        per_model[name] = {"photo_psnr_5_views": mean("photo_psnr"), "photo_coverage": mean("photo_coverage"),
                           "covered_psnr": mean("psnr"), "ssim": mean("ssim"),
                           "photo_psnr_per_view": {k: v["photo_psnr"] for k, v in sorted(views.items())}}
    out["temple_ring"] = {
        "chain_seconds_images_to_score": chain,
        "stage_seconds": {k: stage_wall(r) for k, r in records.items()},
        "surfels_seconds": stage_wall(records.get("surfels", {})),
        "surfels_peak_mb": records.get("surfels", {}).get("peak_memory_mb", records.get("surfels", {}).get("peak_mb")),
        "surfels_metrics": records.get("surfels", {}).get("metrics", {}),
        "poisson_seconds": float(temple_poisson_s),
        "mve_chain_seconds_reported": 139.7,
        "heldout": per_model}
path = os.path.join(bench, "bench_surfels.json")
json.dump(out, open(path, "w"), indent=2)
sr = out["synthetic_ring"]
print(f"synthetic ring: surfels accuracy90 {sr['surfels']['accuracy_90']:.5f} completeness {sr['surfels']['completeness']:.3f} "
      f"({sr['surfels_seconds']:.1f} s) | poisson accuracy90 {sr['poisson']['accuracy_90']:.5f} completeness "
      f"{sr['poisson']['completeness']:.3f} ({sr['poisson_seconds']:.1f} s)")
if "temple_ring" in out:
    t = out["temple_ring"]
    print(f"templeRing: chain images->score {t['chain_seconds_images_to_score']:.1f} s (MVE reported 139.7 s); surfels "
          f"{t['surfels_seconds']:.1f} s, peak {t['surfels_peak_mb']} MB; poisson {t['poisson_seconds']:.1f} s")
    for name, m in t["heldout"].items():
        print(f"  {name:14s} photo PSNR {m['photo_psnr_5_views']:.2f} dB (lit pixels covered {m['photo_coverage']:.3f}), "
              f"covered PSNR {m['covered_psnr']:.2f} dB")
print("wrote", path)
PY
