#!/usr/bin/env python3
"""Precision and recall of multi_depth's per-view flag (issue 67) against known camera errors.

    scripts/eval_view_flags.py TRUE_SPARSE WORKSPACE [WORKSPACE ...]

TRUE_SPARSE: the COLMAP text model of the cameras that rendered the images (a clean synth run's
sparse/, or the unperturbed import of a capture). Each WORKSPACE has a perturbed sparse/ and
multi_depth's dense/stereo/view_agreement.json. Per view the true pose error is measured as the
mean image displacement (pixels) of the true sparse points (at most 2000) between the true camera
and the written one: it combines rotation, position and focal errors as the photos see them.

A view is truly "off" when its displacement stands out from the capture's others by the flag's own
rule on the bad side: robust z = (d - median) / max(1.4826 MAD, 0.5 px) > 3.5 (the 0.5 px floor:
a capture whose cameras are all exact has MAD 0, and sub-pixel differences are no pose error).
Precision: flagged views that are off / flagged; recall: off views flagged / off. Also Spearman's
rho between the figure and the displacement (negative: the figure falls as the error grows),
over the views that have both.
"""
import json
import math
import os
import sys


def read_cameras(path):
    cams = {}
    for line in open(os.path.join(path, "cameras.txt")):
        if line.startswith("#") or not line.strip():
            continue
        f = line.split()
        cams[int(f[0])] = (f[1], [float(x) for x in f[4:]])
    return cams


def read_images(path):
    images, lines = {}, [l for l in open(os.path.join(path, "images.txt")) if not l.startswith("#")]
    for i in range(0, len(lines) - 1, 2):
        f = lines[i].split()
        if len(f) < 10:
            continue
        w, x, y, z = (float(v) for v in f[1:5])
        r = [[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
             [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
             [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]]
        images[f[9]] = (r, [float(v) for v in f[5:8]], int(f[8]))
    return images


def read_points(path, limit=2000):
    pts = []
    p = os.path.join(path, "points3D.txt")
    if os.path.exists(p):
        for line in open(p):
            if line.startswith("#") or not line.strip():
                continue
            pts.append([float(v) for v in line.split()[1:4]])
    step = max(1, len(pts) // limit)
    return pts[::step]


def project(cam, image, x):
    model, params = cam
    r, t, _ = image
    c = [sum(r[i][k] * x[k] for k in range(3)) + t[i] for i in range(3)]
    if c[2] <= 0:
        return None
    if model == "SIMPLE_PINHOLE" or model == "SIMPLE_RADIAL":
        fx = fy = params[0]
        cx, cy = params[1], params[2]
    else:
        fx, fy, cx, cy = params[0], params[1], params[2], params[3]
    return fx * c[0] / c[2] + cx, fy * c[1] / c[2] + cy


def median(v):
    v = sorted(v)
    n = len(v)
    return 0.0 if n == 0 else (v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2]))


def ranks(v):
    order = sorted(range(len(v)), key=lambda i: v[i])
    r = [0.0] * len(v)
    i = 0
    while i < len(v):
        j = i
        while j + 1 < len(v) and v[order[j + 1]] == v[order[i]]:
            j += 1
        for k in range(i, j + 1):
            r[order[k]] = 0.5 * (i + j)
        i = j + 1
    return r


def spearman(a, b):
    if len(a) < 3:
        return float("nan")
    ra, rb = ranks(a), ranks(b)
    ma, mb = sum(ra) / len(ra), sum(rb) / len(rb)
    num = sum((x - ma) * (y - mb) for x, y in zip(ra, rb))
    den = math.sqrt(sum((x - ma) ** 2 for x in ra) * sum((y - mb) ** 2 for y in rb))
    return num / den if den > 0 else float("nan")


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    true_dir = sys.argv[1]
    true_cams, true_images, points = read_cameras(true_dir), read_images(true_dir), read_points(true_dir)
    if not points:
        sys.exit(f"{true_dir}/points3D.txt: no points to measure displacement with")
    for ws in sys.argv[2:]:
        cams, images = read_cameras(os.path.join(ws, "sparse")), read_images(os.path.join(ws, "sparse"))
        agreement = json.load(open(os.path.join(ws, "dense/stereo/view_agreement.json")))
        figures = {v["name"]: v for v in agreement["views"]}
        displacement = {}
        for name, v in figures.items():
            if name not in true_images or name not in images:
                continue
            ti, wi = true_images[name], images[name]
            d = []
            for x in points:
                a, b = project(true_cams[ti[2]], ti, x), project(cams[wi[2]], wi, x)
                if a and b:
                    d.append(math.hypot(a[0] - b[0], a[1] - b[1]))
            displacement[name] = sum(d) / len(d) if d else 0.0
        names = sorted(displacement)
        med = median([displacement[n] for n in names])
        scale = max(1.4826 * median([abs(displacement[n] - med) for n in names]), 0.5)
        off = {n for n in names if (displacement[n] - med) / scale > 3.5}
        flagged = set(agreement["flagged"])
        tp = len(off & flagged)
        precision = tp / len(flagged) if flagged else float("nan")
        recall = tp / len(off) if off else float("nan")
        scored = [n for n in names if figures[n]["figure"] is not None]
        rho = spearman([figures[n]["figure"] for n in scored], [displacement[n] for n in scored])
        print(f"{ws}: views {len(names)}, displacement median {med:.2f} px max {max(displacement.values()):.2f} px, "
              f"off {sorted(off)}, flagged {sorted(flagged)}, precision {precision:.2f}, recall {recall:.2f}, "
              f"figure median {agreement['median']:.3f} scale {agreement['scale']:.3f}, rho(figure, displacement) {rho:.2f}")
        worst = sorted(names, key=lambda n: -displacement[n])[:4]
        print("   worst posed: " + ", ".join(f"{n} {displacement[n]:.2f} px fig {figures[n]['figure']} z {figures[n]['z']}"
                                        for n in worst))


if __name__ == "__main__":
    main()
