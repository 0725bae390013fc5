#!/usr/bin/env python3
"""Clouds whose density is uneven in other ways than the harder set's falloff (issue 26 item 4):
from each eval mesh DATA/NAME.obj, in the harder set's conventions (scripts/hard_clouds.py: the
mesh's own coordinates, sigma 0.005 x the longest side, uniform surface samples thinned by a
keep probability along the bounding box's longest axis, t in [0, 1] from its low end; binary
little-endian PLY), written as OUT/NAME-SIZE.ply beside a symlink OUT/NAME.obj:

  f1k, f1500, f10k  density falling 55x as the harder set's falloff (55^-t), 1,000, 1,500 and
                    10,000 points
  f200, f500x       falling 200x and 500x (200^-t, 500^-t), 3,000 points
  fstep, fstep1k,   a step: the low half kept whole, the high half 1 in 55 (one side seen from
  fstep10k          near, the other from far), 3,000, 1,000 and 10,000 points; about 2 % of the
                    points lie on the sparse half

Seed 11 for every cloud (each draws its own generator). Then

    target/release/nkrr eval OUT --sizes f1k,f1500,f10k,f200,f500x,fstep,fstep1k,fstep10k

scores them. They showed where the sparse side went (docs/poisson.md, "Uneven density"); the
stray-point filter's edge test was chosen on the fstep clouds (all six shapes, with the harder
set's stray-point clouds), the rest chose nothing.

    .venv-peers/bin/python scripts/uneven_clouds.py [--data target/results/data] [--out target/results/uneven]
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from hard_clouds import SHAPES, ObjMesh  # noqa: E402
from results_clouds import noise_sigma, surface_samples, write_ply  # noqa: E402

SEED = 11
SIGMA = 0.005
# name: (points, kind, ratio)
CLOUDS = {
    "f1k": (1000, "falloff", 55.0),
    "f1500": (1500, "falloff", 55.0),
    "f10k": (10000, "falloff", 55.0),
    "f200": (3000, "falloff", 200.0),
    "f500x": (3000, "falloff", 500.0),
    "fstep": (3000, "step", 55.0),
    "fstep1k": (1000, "step", 55.0),
    "fstep10k": (10000, "step", 55.0),
}


def cloud(mesh, n, kind, ratio):
    rng = np.random.default_rng(SEED)
    axis = int(np.argmax(mesh.bounds[1] - mesh.bounds[0]))
    lo, hi = mesh.bounds[0][axis], mesh.bounds[1][axis]
    got = []
    while sum(len(g) for g in got) < n:
        p = surface_samples(mesh, 20000, rng)
        t = np.clip((p[:, axis] - lo) / (hi - lo), 0.0, 1.0)
        keep = np.exp(-np.log(ratio) * t) if kind == "falloff" else np.where(t < 0.5, 1.0, 1.0 / ratio)
        got.append(p[rng.random(len(p)) < keep])
    pts = np.concatenate(got)[:n]
    return pts + rng.normal(0.0, noise_sigma(mesh, SIGMA), pts.shape)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default="target/results/data")
    ap.add_argument("--out", default="target/results/uneven")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    for shape in SHAPES:
        obj = os.path.join(args.data, shape + ".obj")
        link = os.path.join(args.out, shape + ".obj")
        if not os.path.exists(link):
            os.symlink(os.path.abspath(obj), link)
        mesh = ObjMesh(obj)
        for name, (n, kind, ratio) in CLOUDS.items():
            path = os.path.join(args.out, f"{shape}-{name}.ply")
            if not os.path.exists(path):
                write_ply(path, cloud(mesh, n, kind, ratio))
                print(path)


if __name__ == "__main__":
    main()
