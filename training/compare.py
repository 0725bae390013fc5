"""Held-out IoU of network priors on the procedural held-out shapes, clean and degraded
(issue 14 item 6): which prior to ship, measured apart from the eval meshes.

  python -m training.compare PRIOR [PRIOR ...] [--tta] [--n 32] [--out FILE.json]

PRIOR: a safetensors file (assets/prior.safetensors, or one exported by training/export.py) or a
training checkpoint (training/runs/NAME/ckpt.pt). Sets (3000 points, noise 0.005, 10k uniform
queries each, seeds apart from every training stream):
  clean     the first prior's held-out shapes (kind 2)
  falloff   the same shapes, density falling 55x along a random direction
  outliers  the same shapes, 10 % of the points replaced by points uniform in the box
  new       the second stream's new families (kind 4: revolution, tubes, flaps, machined parts)
--tta also scores each prior with its logits averaged over the 8 cube rotations about the axes
(item 6's "test-time rotation averaging", one measurement).
"""
from __future__ import annotations

import argparse
import json

import numpy as np
import torch

from .data import CACHE, Scan, heldout_set
from .export import load_ckpt, load_weights

SETS = {
    "clean": dict(kind=2),
    "falloff": dict(kind=2, scan=Scan(falloff=1.0, falloff_max=55.0, fixed=True), name="falloff"),
    "outliers": dict(kind=2, scan=Scan(outliers=1.0, outliers_max=0.1), name="outliers"),
    "new": dict(kind=4, name="new"),
}


def load(path):
    return load_weights(path)[0] if path.endswith(".safetensors") else load_ckpt(path)[0]


def rotations():
    """The 8 proper rotations of the cube that keep each axis an axis and the y axis vertical
    up to sign (the 4 yaws, and each flipped upside down)."""
    out = []
    for flip in (1.0, -1.0):
        for k in range(4):
            c, s = [(1, 0), (0, 1), (-1, 0), (0, -1)][k]
            R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], np.float32)
            if flip < 0:
                R = R @ np.diag([1.0, -1.0, -1.0]).astype(np.float32)
            out.append(R)
    return out


@torch.no_grad()
def iou(model, held, tta=False, bs=4):
    rots = rotations() if tta else [np.eye(3, dtype=np.float32)]
    ious = []
    for i in range(0, len(held["cloud"]), bs):
        p, q = held["cloud"][i:i + bs], held["q"][i:i + bs]
        lg = sum(model(torch.from_numpy(p @ R), torch.from_numpy(q @ R)) for R in rots) / len(rots)
        pr, yt = (lg > 0).numpy(), held["occ"][i:i + bs].astype(bool)
        ious += list((pr & yt).sum(1) / np.maximum((pr | yt).sum(1), 1))
    return float(np.mean(ious))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("priors", nargs="+")
    ap.add_argument("--tta", action="store_true")
    ap.add_argument("--n", type=int, default=32)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--cache", default=str(CACHE))
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    sets = {k: heldout_set(a.n, cache=a.cache, **v) for k, v in SETS.items()}
    rows = []
    for path in a.priors:
        model = load(path)
        for tta in ([False, True] if a.tta else [False]):
            r = {"prior": path, "tta": tta}
            r.update({k: round(iou(model, h, tta), 4) for k, h in sets.items()})
            rows.append(r)
            print(json.dumps(r), flush=True)
    if a.out:
        json.dump(rows, open(a.out, "w"), indent=1)


if __name__ == "__main__":
    main()
