"""Surface metrics of a reconstruction against its ground-truth mesh, by the protocol of
tests/data/eval/README.md: normalise the ground truth to the unit cube (bounding-box centre
at the origin, longest side 1), apply the same transform to the reconstruction, 100k samples on
each surface; CD1 = mean of the two nearest-neighbour mean distances (x100); F-score at
tau = 0.01; normal consistency = mean |n . n_nearest| both ways.

An interim Python measurement (trimesh + scipy) until the metrics live in the Rust library.

    .venv/bin/python scripts/eval_metrics.py GT.obj RECON.glb [RECON.glb ...]   -> one JSON line each
"""
import json
import sys

import numpy as np
import trimesh
from scipy.spatial import cKDTree

N = 100_000
TAU = 0.01


def load(path):
    m = trimesh.load(path, force="mesh", process=False)
    return m


def sample(mesh, n, seed):
    pts, faces = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return pts, mesh.face_normals[faces]


def metrics(gt_path, rec_path):
    gt = load(gt_path)
    lo, hi = gt.bounds
    center, scale = (lo + hi) / 2, (hi - lo).max()
    rec = load(rec_path)
    gt.vertices = (gt.vertices - center) / scale
    rec.vertices = (rec.vertices - center) / scale
    pg, ng = sample(gt, N, 1)
    pr, nr = sample(rec, N, 2)
    d_rg, i_rg = cKDTree(pg).query(pr)  # reconstruction -> ground truth (precision)
    d_gr, i_gr = cKDTree(pr).query(pg)  # ground truth -> reconstruction (completeness)
    cd1 = 0.5 * (d_rg.mean() + d_gr.mean())
    precision = (d_rg < TAU).mean()
    recall = (d_gr < TAU).mean()
    f = 2 * precision * recall / max(precision + recall, 1e-12)
    nc = 0.5 * (np.abs((nr * ng[i_rg]).sum(1)).mean() + np.abs((ng * nr[i_gr]).sum(1)).mean())
    return {
        "gt": gt_path,
        "recon": rec_path,
        "cd1x100": round(100 * cd1, 4),
        "fscore": round(float(f), 4),
        "nc": round(float(nc), 4),
        "watertight": bool(rec.is_watertight),
        "faces": int(len(rec.faces)),
    }


if __name__ == "__main__":
    gt = sys.argv[1]
    for r in sys.argv[2:]:
        print(json.dumps(metrics(gt, r)))
