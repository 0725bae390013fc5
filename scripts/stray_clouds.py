#!/usr/bin/env python3
"""Clouds with stray points at other sizes and shares than the harder set's (issue 26 item 4):
the stray-point filter's sparse-share rule (`outliers::SPARSE_SHARE`, docs/poisson.md "A sparse
end of a few points") was set between what these drop beyond an edge and what the uneven clouds
of scripts/uneven_clouds.py drop there.

From each DATA/NAME-SIZE.ply (the eval clouds: scripts/results_clouds.py's, as
target/results/data holds them) a share of the points, chosen at random, is replaced by points
uniform in the mesh's bounding box padded by 0.05 of its longest side, exactly as
scripts/hard_clouds.py makes its stray-point clouds (there: 10 % of the 3k cloud, seed 6),
written as OUT/NAME-oSIZETAG.ply beside a symlink OUT/NAME.obj:

  TAG ''   10 % of the points, seed 6      TAG 's7', 's8'   10 %, seeds 7 and 8
  TAG 'f3'  3 %, seed 9                    TAG 'f20'        20 %, seed 10

for SIZE 500, 1k and 3k (1,500: TAG '' only). With --uneven DIR (scripts/uneven_clouds.py's
output) also OUT/NAME-fstepo5.ply and OUT/NAME-fstep1ko5.ply: its step clouds at 3k and 1k with
5 % of the points replaced the same way (seed 12), a sparse side and stray points in one cloud.

    .venv-peers/bin/python scripts/stray_clouds.py [--data target/results/data]
        [--out target/results/strays] [--uneven target/results/uneven]

The share of dropped points beyond an edge quoted in docs/poisson.md was printed by a diagnostic
build (not committed); `nkrr eval OUT --sizes o1k,o1kf3,...` scores the clouds.
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from hard_clouds import BOX_PAD, SHAPES, ObjMesh, read_points  # noqa: E402
from results_clouds import write_ply  # noqa: E402

# tag: (share of the points, seed)
VARIANTS = {"": (0.10, 6), "s7": (0.10, 7), "s8": (0.10, 8), "f3": (0.03, 9), "f20": (0.20, 10)}
SIZES = {"500": VARIANTS, "1k": VARIANTS, "3k": VARIANTS, "1500": {"": VARIANTS[""]}}
MIXED = {"fstep": "fstepo5", "fstep1k": "fstep1ko5"}
MIXED_SHARE, MIXED_SEED = 0.05, 12


def with_strays(pts, mesh, share, seed):
    pts = pts.copy()
    rng = np.random.default_rng(seed)
    k = int(round(share * len(pts)))
    idx = np.sort(rng.choice(len(pts), size=k, replace=False))
    lo = mesh.bounds[0] - BOX_PAD * mesh.scale
    hi = mesh.bounds[1] + BOX_PAD * mesh.scale
    pts[idx] = lo + rng.random((k, 3)) * (hi - lo)
    return pts


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default="target/results/data")
    ap.add_argument("--out", default="target/results/strays")
    ap.add_argument("--uneven", default=None)
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    for shape in SHAPES:
        obj = os.path.join(a.data, f"{shape}.obj")
        mesh = ObjMesh(obj)
        link = os.path.join(a.out, f"{shape}.obj")
        if not os.path.exists(link):
            os.symlink(os.path.abspath(obj), link)
        for size, variants in SIZES.items():
            pts = read_points(os.path.join(a.data, f"{shape}-{size}.ply"))
            for tag, (share, seed) in variants.items():
                write_ply(os.path.join(a.out, f"{shape}-o{size}{tag}.ply"), with_strays(pts, mesh, share, seed))
        if a.uneven:
            for src, name in MIXED.items():
                pts = read_points(os.path.join(a.uneven, f"{shape}-{src}.ply"))
                write_ply(os.path.join(a.out, f"{shape}-{name}.ply"), with_strays(pts, mesh, MIXED_SHARE, MIXED_SEED))
        print(f"{shape}: done", flush=True)


if __name__ == "__main__":
    main()
