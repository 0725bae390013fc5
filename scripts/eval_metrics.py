"""Surface metrics of a reconstruction against its ground-truth mesh, by the protocol of
tests/data/eval/README.md: normalise the ground truth to the unit cube (bounding-box centre
at the origin, longest side 1), apply the same transform to the reconstruction, 100k samples on
each surface; CD1 = mean of the two nearest-neighbour mean distances (x100); F-score at
tau = 0.01; normal consistency = mean |n . n_nearest| both ways.

The error split (issue 26): each side's distances cut at the F-score's tau. The precision side is
reconstruction -> truth (the reconstruction's samples, far from the truth where the surface is
extra, merged or displaced), the completeness side truth -> reconstruction (the truth's samples,
far from the reconstruction where a part is missing or displaced). Per side (prefix `precision_`,
`completeness_`) and both sides pooled (no prefix; the two sides have as many samples each, so
the pooled numbers recombine to CD1 the same way):

  mean_x100          the side's mean distance x100 (per side only; CD1 x100 = their average)
  beyond_share       share of the samples at distance >= tau (precision side: 1 - precision)
  within_mean_x100   mean distance of the samples within tau, x100 (null when there are none)
  beyond_mean_x100   mean distance of the samples beyond tau, x100 (null when there are none)
  beyond_cd_share    share of the mean distance (of CD1, pooled) that the beyond samples carry

so mean = (1 - beyond_share) * within_mean + beyond_share * beyond_mean, and
beyond_cd_share = beyond_share * beyond_mean / mean. scripts/error_map.py renders where the
beyond-tau samples sit.

An independent Python measurement (trimesh + scipy): `nkrr metrics` reports the same split
under the same names (src/eval/mod.rs), and scripts/error_map.py draws from this one's samples.

    .venv/bin/python scripts/eval_metrics.py GT.obj RECON.glb [RECON.glb ...]   -> one JSON line each

By import: metrics(gt, rec) -> dict (paths or trimesh meshes); metrics(gt, rec, samples=True)
-> (dict, the samples and their distances, for rendering); split(distances) -> one side's split.
"""
import json
import sys

import numpy as np
import trimesh
from scipy.spatial import cKDTree

N = 100_000
TAU = 0.01


def load(path):
    if isinstance(path, trimesh.Trimesh):
        return path.copy()
    m = trimesh.load(path, force="mesh", process=False)
    return m


def sample(mesh, n, seed):
    pts, faces = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return pts, mesh.face_normals[faces]


def split(d, tau=TAU):
    """One side's distances cut at tau (within: d < tau, as the F-score counts), unrounded and in
    the distances' units: mean, beyond_share, within_mean, beyond_mean (None where that part is
    empty) and beyond_cd_share (the beyond samples' share of the sum of distances)."""
    d = np.asarray(d, dtype=np.float64)
    beyond = d >= tau
    total = float(d.sum())
    nb = int(beyond.sum())
    nw = len(d) - nb
    return {
        "mean": total / max(len(d), 1),
        "beyond_share": nb / max(len(d), 1),
        "within_mean": float(d[~beyond].mean()) if nw else None,
        "beyond_mean": float(d[beyond].mean()) if nb else None,
        "beyond_cd_share": float(d[beyond].sum()) / total if total > 0 else 0.0,
    }


def _split_keys(prefix, s, with_mean):
    def x100(v):
        return None if v is None else round(100 * v, 4)

    out = {}
    if with_mean:
        out[prefix + "mean_x100"] = x100(s["mean"])
    out[prefix + "beyond_share"] = round(s["beyond_share"], 5)
    out[prefix + "within_mean_x100"] = x100(s["within_mean"])
    out[prefix + "beyond_mean_x100"] = x100(s["beyond_mean"])
    out[prefix + "beyond_cd_share"] = round(s["beyond_cd_share"], 4)
    return out


def metrics(gt_path, rec_path, samples=False):
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
    row = {
        "gt": "<mesh>" if isinstance(gt_path, trimesh.Trimesh) else gt_path,
        "recon": "<mesh>" if isinstance(rec_path, trimesh.Trimesh) else rec_path,
        "cd1x100": round(100 * cd1, 4),
        "fscore": round(float(f), 4),
        "nc": round(float(nc), 4),
        "watertight": bool(rec.is_watertight),
        "faces": int(len(rec.faces)),
    }
    row.update(_split_keys("precision_", split(d_rg), True))
    row.update(_split_keys("completeness_", split(d_gr), True))
    row.update(_split_keys("", split(np.concatenate([d_rg, d_gr])), False))
    if not samples:
        return row
    return row, {
        "gt_mesh": gt, "rec_mesh": rec,  # both in the normalised frame
        "center": center, "scale": scale,  # normalised = (original - center) / scale
        "gt_points": pg, "gt_normals": ng, "rec_points": pr, "rec_normals": nr,
        "gt_to_rec": d_gr,  # per truth sample: distance to the nearest reconstruction sample
        "rec_to_gt": d_rg,  # per reconstruction sample: distance to the nearest truth sample
    }


if __name__ == "__main__":
    gt = sys.argv[1]
    for r in sys.argv[2:]:
        print(json.dumps(metrics(gt, r)))
