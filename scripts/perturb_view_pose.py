#!/usr/bin/env python3
"""Turns one view of a capture by hand, for measuring the per-view agreement flag (issue 67).

Writes a copy of a Middlebury capture folder (the images linked, not copied) whose `_par.txt`
rotates one view's camera about its own centre by ANGLE degrees: R' = Q R, t' = Q t (projection
K [R t], so the centre -R^T t stays where it was), Q a turn about AXIS in the camera frame.

    scripts/perturb_view_pose.py SRC_DIR DST_DIR VIEW ANGLE_DEG [--axis X Y Z]

e.g. scripts/perturb_view_pose.py ../shared/datasets/middlebury_templeRing /work/ws-h67/rot2 \
         templeR0013.png 2
Then point a config's inputs.images at DST_DIR. With --colmap, SRC_DIR/DST_DIR are COLMAP text
model folders (cameras.txt, images.txt, points3D.txt) and images.txt is changed instead.
"""
import argparse
import math
import os
import shutil
import sys


def axis_angle(axis, degrees):
    n = math.sqrt(sum(a * a for a in axis))
    if n == 0:
        sys.exit("--axis: must not be zero")
    x, y, z = (a / n for a in axis)
    a = math.radians(degrees)
    c, s, C = math.cos(a), math.sin(a), 1 - math.cos(a)
    return [[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
            [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
            [z * x * C - y * s, z * y * C + x * s, c + z * z * C]]


def matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def matvec(a, v):
    return [sum(a[i][k] * v[k] for k in range(3)) for i in range(3)]


def quat_to_matrix(w, x, y, z):
    return [[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]]


def matrix_to_quat(r):
    t = r[0][0] + r[1][1] + r[2][2]
    if t > 0:
        s = math.sqrt(t + 1) * 2
        return [0.25 * s, (r[2][1] - r[1][2]) / s, (r[0][2] - r[2][0]) / s, (r[1][0] - r[0][1]) / s]
    i = max(range(3), key=lambda k: r[k][k])
    j, k = (i + 1) % 3, (i + 2) % 3
    s = math.sqrt(1 + r[i][i] - r[j][j] - r[k][k]) * 2
    q = [0.0] * 4
    q[0] = (r[k][j] - r[j][k]) / s
    q[1 + i] = 0.25 * s
    q[1 + j] = (r[j][i] + r[i][j]) / s
    q[1 + k] = (r[k][i] + r[i][k]) / s
    return q


def perturb_par(src, dst, view, turn):
    pars = [f for f in os.listdir(src) if f.endswith("_par.txt")]
    if len(pars) != 1:
        sys.exit(f"{src}: expected one *_par.txt, found {pars}")
    os.makedirs(dst, exist_ok=True)
    for f in os.listdir(src):
        if f != pars[0] and not os.path.exists(os.path.join(dst, f)):
            os.symlink(os.path.abspath(os.path.join(src, f)), os.path.join(dst, f))
    lines = open(os.path.join(src, pars[0])).read().splitlines()
    found = False
    for i, line in enumerate(lines[1:], start=1):
        fields = line.split()
        if not fields or fields[0] != view:
            continue
        v = [float(f) for f in fields[1:22]]
        r = [v[9:12], v[12:15], v[15:18]]
        t = v[18:21]
        r2, t2 = matmul(turn, r), matvec(turn, t)
        lines[i] = " ".join(fields[:10] + ["%.17g" % x for row in r2 for x in row] + ["%.12g" % x for x in t2])
        found = True
    if not found:
        sys.exit(f"{src}/{pars[0]}: no view named {view}")
    with open(os.path.join(dst, pars[0]), "w") as out:
        out.write("\n".join(lines) + "\n")


def perturb_colmap(src, dst, view, turn):
    os.makedirs(dst, exist_ok=True)
    for f in ("cameras.txt", "points3D.txt"):
        shutil.copyfile(os.path.join(src, f), os.path.join(dst, f))
    lines = open(os.path.join(src, "images.txt")).read().splitlines()
    found, data_line = False, 0
    for i, line in enumerate(lines):
        if line.startswith("#") or not line.strip() and data_line % 2 == 0:
            continue
        data_line += 1
        fields = line.split()
        if data_line % 2 == 1 and len(fields) >= 10 and fields[9] == view:
            q = [float(f) for f in fields[1:5]]
            t = [float(f) for f in fields[5:8]]
            r2 = matmul(turn, quat_to_matrix(*q))
            t2 = matvec(turn, t)
            lines[i] = " ".join([fields[0]] + ["%.17g" % x for x in matrix_to_quat(r2) + t2] + fields[8:])
            found = True
    if not found:
        sys.exit(f"{src}/images.txt: no image named {view}")
    with open(os.path.join(dst, "images.txt"), "w") as out:
        out.write("\n".join(lines) + "\n")


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("src")
    p.add_argument("dst")
    p.add_argument("view", help="image name, e.g. templeR0013.png")
    p.add_argument("angle_deg", type=float)
    p.add_argument("--axis", type=float, nargs=3, default=[0.6, 0.8, 0.0],
                   help="turn axis in the camera frame (default 0.6 0.8 0: moves the image diagonally)")
    p.add_argument("--colmap", action="store_true", help="SRC and DST are COLMAP text model folders")
    a = p.parse_args()
    turn = axis_angle(a.axis, a.angle_deg)
    (perturb_colmap if a.colmap else perturb_par)(a.src, a.dst, a.view, turn)


if __name__ == "__main__":
    main()
