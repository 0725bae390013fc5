#!/usr/bin/env python3
"""Scene metrics: how close a reconstructed scene is to the ground truth of scripts/scenes.py.

Why: `nkrr metrics` scores one object normalised to a unit cube; a scene (a room, a street) is
metres wide, far from the origin and made of parts (floor, walls, ...) and objects whose quality
differs, so it needs metric distances and per-object numbers (issue 25, "Metrics for scenes").

usage:
  .venv-formats/bin/python scripts/scene_metrics.py GT.ply OBJECTS.json RECON.{glb,ply,obj} \
      [--cloud CLOUD.laz] [--samples 1000000] [--min-object-samples 20000] [--seed 0]

Prints one JSON line (all lengths in metres unless the key ends in _cm):
  chamfer          mean of the two directions below (gt_to_recon: accuracy of completeness,
                   recon_to_gt: accuracy), each the mean distance of a surface sample to the other
                   surface
  fscore           at 1, 2 and 5 cm: precision (share of recon samples within t of the GT),
                   recall (share of GT samples within t of the recon) and their harmonic mean
  parts, objects   per part (floor, ceiling, walls, door / ground, buildings...) and per object
                   (the triangle ranges of OBJECTS.json): completeness = share of its GT samples
                   within 2 cm of the recon, and their mean distance; "structure" aggregates all
                   parts (area-weighted)
  scanned          the same GT-side numbers restricted to the GT surface within 5 cm of an input
                   point. The GT is complete (a whole ceiling, the backs of walls, the undersides
                   of furniture) but the scanner sees only part of it; nothing can reconstruct what
                   was never scanned, so recall and completeness over the scanned GT are the fair
                   measure of a scan's reconstruction. Precision does not depend on the GT side
                   and stays as it is. The cloud is OBJECTS.json's sibling PREFIX.laz unless
                   --cloud is given (LAS/LAZ via laspy).

Sampling: both surfaces are sampled uniformly by area (--samples each; every part and object gets
its own samples, proportional to its area but at least --min-object-samples). Distances are
point-to-triangle (not point-to-sample, which would add about half the sample spacing, several mm
at these densities): candidate triangles are the 12 whose centroids are nearest (scipy cKDTree),
plus every large triangle (edge > 10 cm and > 4 times the median edge: the GT's walls and floors
are a few big triangles), and
the exact closest point on each candidate (trimesh.triangles.closest_point).

Output precision: a PLY or OBJ written with float32 coordinates far from the origin (500000,
4000000) is quantised to 3-25 cm; use a GLB from nkrr (f32 vertices relative to a float64 node
translation) or a float64 PLY. The script warns when the recon's vertices look quantised.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

THRESHOLDS = (0.01, 0.02, 0.05)
COMPLETE_AT = 0.02
SCANNED_WITHIN = 0.05
LARGE_EDGE = 0.10
K_CANDIDATES = 12


def load_mesh(path: str) -> trimesh.Trimesh:
    """The mesh with every node transform applied, in float64 (GLB scenes are concatenated)."""
    m = trimesh.load(path, force="mesh", process=False)
    return trimesh.Trimesh(np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces), process=False)


def sample(v: np.ndarray, f: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """n points uniform by area on the triangles f of vertices v."""
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if len(f) == 0 or area.sum() <= 0:
        return np.zeros((0, 3))
    idx = rng.choice(len(f), size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    flip = r1 + r2 > 1
    r1[flip], r2[flip] = 1 - r1[flip], 1 - r2[flip]
    t = tri[idx]
    return t[:, 0] + r1[:, None] * (t[:, 1] - t[:, 0]) + r2[:, None] * (t[:, 2] - t[:, 0])


def areas(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    tri = v[f]
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


class Surface:
    """Point-to-triangle distance to a mesh: k nearest triangle centroids + all large triangles."""

    def __init__(self, v: np.ndarray, f: np.ndarray):
        self.tri = v[f]
        edge = np.max(np.stack([np.linalg.norm(self.tri[:, i] - self.tri[:, (i + 1) % 3], axis=1)
                                for i in range(3)]), axis=0)
        # "large": much longer than the typical triangle (a coarse mesh is all long edges, and
        # checking every one of them against every sample would take hours)
        big = edge > max(LARGE_EDGE, 4 * float(np.median(edge)) if len(edge) else 0.0)
        self.large, self.small = np.flatnonzero(big), np.flatnonzero(~big)
        self.tree = cKDTree(self.tri[self.small].mean(1)) if len(self.small) else None

    def distance(self, q: np.ndarray, chunk: int = 50_000) -> np.ndarray:
        out = np.empty(len(q))
        for s in range(0, len(q), chunk):
            p = q[s:s + chunk]
            best = np.full(len(p), np.inf)
            if self.tree is not None:
                k = min(K_CANDIDATES, len(self.small))
                _, j = self.tree.query(p, k=k, workers=-1)
                j = self.small[j.reshape(len(p), k)]
                best = np.minimum(best, self._dist(p, j))
            for b in range(0, len(self.large), 16):
                j = np.broadcast_to(self.large[b:b + 16], (len(p), len(self.large[b:b + 16])))
                best = np.minimum(best, self._dist(p, j))
            out[s:s + chunk] = best
        return out

    def _dist(self, p: np.ndarray, j: np.ndarray) -> np.ndarray:
        n, k = j.shape
        c = trimesh.triangles.closest_point(self.tri[j.reshape(-1)], np.repeat(p, k, axis=0))
        return np.linalg.norm(c - np.repeat(p, k, axis=0), axis=1).reshape(n, k).min(1)


def load_cloud(path: str) -> np.ndarray:
    import laspy
    las = laspy.read(path)
    return np.column_stack([np.asarray(las.x, dtype=np.float64), np.asarray(las.y, dtype=np.float64),
                            np.asarray(las.z, dtype=np.float64)])


def fscores(prec_d: np.ndarray, rec_d: np.ndarray) -> dict:
    out = {}
    for t in THRESHOLDS:
        p = float(np.mean(prec_d <= t)) if len(prec_d) else 0.0
        r = float(np.mean(rec_d <= t)) if len(rec_d) else 0.0
        out[f"{round(t * 100)}cm"] = {"f": round(2 * p * r / (p + r), 4) if p + r > 0 else 0.0,
                                      "precision": round(p, 4), "recall": round(r, 4)}
    return out


def side(d: np.ndarray) -> dict:
    return {"completeness": round(float(np.mean(d <= COMPLETE_AT)), 4) if len(d) else None,
            "mean_cm": round(float(np.mean(d)) * 100, 3) if len(d) else None, "samples": int(len(d))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("gt")
    ap.add_argument("objects")
    ap.add_argument("recon")
    ap.add_argument("--cloud", help="the input cloud (LAS/LAZ) for the scanned GT (default: PREFIX.laz)")
    ap.add_argument("--samples", type=int, default=1_000_000, help="surface samples of GT and recon")
    ap.add_argument("--min-object-samples", type=int, default=20_000)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    t0 = time.perf_counter()
    rng = np.random.default_rng(a.seed)
    meta = json.loads(Path(a.objects).read_text())
    gt, rec = load_mesh(a.gt), load_mesh(a.recon)
    origin = np.floor(gt.vertices.min(0))  # work near the origin (float64 is enough anyway)
    gv, rv = gt.vertices - origin, rec.vertices - origin
    warnings = []
    # A recon written with f32 coordinates far out shows as a few distinct values per axis step.
    step = np.array([np.min(np.diff(u)) if len(u := np.unique(rec.vertices[:, i])) > 1 else 0.0 for i in range(3)])
    if np.any(step > 0.005):
        warnings.append(f"recon vertex coordinates are quantised (steps {np.round(step, 4).tolist()} m): "
                        "a float32 file far from the origin? use .glb")
        print(f"warning: {warnings[-1]}", file=sys.stderr)

    # GT samples per part/object, proportional to area, at least --min-object-samples each.
    groups = [("part", p) for p in meta["parts"]] + [("object", o) for o in meta["objects"]]
    garea = areas(gv, gt.faces)
    total = garea.sum()
    gt_pts, gt_group = [], []
    for gi, (_, g) in enumerate(groups):
        s, e = g["triangles"]
        n = max(a.min_object_samples, round(a.samples * garea[s:e].sum() / total))
        pts = sample(gv, gt.faces[s:e], n, rng)
        gt_pts.append(pts)
        gt_group.append(np.full(len(pts), gi))
    gt_pts, gt_group = np.concatenate(gt_pts), np.concatenate(gt_group)
    # area-uniform weights for the scene-level numbers: a group's samples stand for its area
    garea_g = np.array([garea[g["triangles"][0]:g["triangles"][1]].sum() for _, g in groups])
    w = garea_g[gt_group] / np.bincount(gt_group, minlength=len(groups))[gt_group]
    w /= w.sum()
    rec_pts = sample(rv, rec.faces, a.samples, rng)

    d_gt = Surface(rv, rec.faces).distance(gt_pts)   # GT sample -> recon surface
    d_rec = Surface(gv, gt.faces).distance(rec_pts)  # recon sample -> GT surface

    cloud_path = a.cloud or str(Path(a.objects).with_name(Path(a.objects).name.replace("-objects.json", ".laz")))
    scanned = None
    if Path(cloud_path).exists():
        cloud = load_cloud(cloud_path) - origin
        dc, _ = cKDTree(cloud).query(gt_pts, k=1, distance_upper_bound=SCANNED_WITHIN, workers=-1)
        scanned = np.isfinite(dc)
    else:
        warnings.append(f"no cloud at {cloud_path}: no scanned-GT numbers")

    def wmean(x, ww):
        return float(np.sum(x * ww) / np.sum(ww))

    def recall_w(mask):
        ww = w[mask]
        return {f"{round(t * 100)}cm": round(float(np.sum(ww * (d_gt[mask] <= t)) / ww.sum()), 4)
                for t in THRESHOLDS}

    def fs(mask):
        out = {}
        r = recall_w(mask)
        for t in THRESHOLDS:
            key = f"{round(t * 100)}cm"
            p = float(np.mean(d_rec <= t))
            out[key] = {"f": round(2 * p * r[key] / (p + r[key]), 4) if p + r[key] > 0 else 0.0,
                        "precision": round(p, 4), "recall": r[key]}
        return out

    def group_stats(mask_extra=None):
        parts, objects = {}, {}
        for gi, (kind, g) in enumerate(groups):
            m = gt_group == gi
            if mask_extra is not None:
                m &= mask_extra
            st = side(d_gt[m])
            if kind == "object":
                st["family"] = g.get("family")
                st["size_m"] = round(g.get("size_m", 0.0), 3)
                objects[g["name"]] = st
            else:
                parts[g["name"]] = st
        m = gt_group < len(meta["parts"])
        if mask_extra is not None:
            m &= mask_extra
        if m.any():
            parts["structure"] = {"completeness": round(float(np.sum(w[m] * (d_gt[m] <= COMPLETE_AT)) / w[m].sum()), 4),
                                  "mean_cm": round(wmean(d_gt[m], w[m]) * 100, 3), "samples": int(m.sum())}
        return parts, objects

    all_mask = np.ones(len(d_gt), bool)
    g2r = wmean(d_gt, w)
    r2g = float(np.mean(d_rec))
    parts, objects = group_stats()
    res = {
        "gt": a.gt, "recon": a.recon,
        "recon_vertices": int(len(rec.vertices)), "recon_faces": int(len(rec.faces)),
        "gt_samples": int(len(gt_pts)), "recon_samples": int(len(rec_pts)),
        "chamfer": {"mean_cm": round((g2r + r2g) / 2 * 100, 3), "gt_to_recon_cm": round(g2r * 100, 3),
                    "recon_to_gt_cm": round(r2g * 100, 3)},
        "fscore": fs(all_mask),
        "parts": parts, "objects": objects,
        "objects_completeness_mean": round(float(np.mean([o["completeness"] for o in objects.values()])), 4)
        if objects else None,
    }
    if scanned is not None:
        sp, so = group_stats(scanned)
        g2r_s = wmean(d_gt[scanned], w[scanned])
        res["scanned"] = {
            "share_of_gt_area": round(float(np.sum(w[scanned])), 4),
            "chamfer": {"mean_cm": round((g2r_s + r2g) / 2 * 100, 3), "gt_to_recon_cm": round(g2r_s * 100, 3),
                        "recon_to_gt_cm": round(r2g * 100, 3)},
            "completeness": round(float(np.sum(w[scanned] * (d_gt[scanned] <= COMPLETE_AT)) / w[scanned].sum()), 4),
            "fscore": fs(scanned), "parts": sp, "objects": so,
            "objects_completeness_mean": round(float(np.mean([o["completeness"] for o in so.values()
                                                              if o["completeness"] is not None])), 4) if so else None,
        }
    res["warnings"] = warnings
    res["seconds"] = round(time.perf_counter() - t0, 1)
    print(json.dumps(res))


if __name__ == "__main__":
    sys.exit(main())
