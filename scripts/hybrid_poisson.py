#!/usr/bin/env python3
"""Experiment for issue 26 item 2 (measured, not in the product): screened Poisson with normals
oriented by nkrr's field. Poisson-style methods need a consistent inside/outside per normal,
which is what unoriented scans lack and what the field has.

For each cloud DATA/NAME-SIZE.ply and each field METHOD (network, nkrr):
  1. `nkrr reconstruct --method METHOD` (the product as it is) -> OUT/NAME-SIZE-METHOD.glb;
  2. PCA normals of the points (k = 30, as tests/peers/spsr.py), each signed by the normal of
     the nearest triangle of that mesh (outward, since the mesh is closed and oriented);
  3. Open3D's screened Poisson (Kazhdan's code) at depth 8 -> OUT/NAME-SIZE-METHOD-poisson.obj;
  4. `nkrr metrics` of both against DATA/NAME.obj.
Resumable: a file that is there is not made again. Writes OUT/hybrid.jsonl (one row per mesh) and
prints a Markdown table of the means per size and method (and per shape with --per-shape).

    .venv-peers/bin/python scripts/hybrid_poisson.py --data target/results/data \
        --sizes 500,3k,10k --out target/results/hybrid [--per-shape]

Needs target/release/nkrr and .venv-peers (Open3D; tests/peers/setup.sh). The clouds of
scripts/results_clouds.py (500 points) or tests/data/eval (3k, 10k).
"""
import argparse
import collections
import json
import os
import subprocess
import sys

import numpy as np
import open3d as o3d

# The GLB's materials draw a warning per mesh on stdout, where the table goes.
o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests/peers"))
from spsr import eval_clouds  # noqa: E402  (the peers' walk over DATA/NAME-SIZE.ply)

NKRR = os.path.join(ROOT, "target/release/nkrr")


def oriented_normals(cloud, mesh_path, k):
    """The cloud with PCA normals, each flipped to agree with the nearest face of the mesh."""
    pcd = o3d.io.read_point_cloud(cloud)
    mesh = o3d.t.geometry.TriangleMesh.from_legacy(o3d.io.read_triangle_mesh(mesh_path))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(mesh)
    pts = np.asarray(pcd.points).astype(np.float32)
    face = scene.compute_closest_points(o3d.core.Tensor(pts))["primitive_normals"].numpy()
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=k))
    n = np.asarray(pcd.normals)
    sign = np.where(np.einsum("ij,ij->i", n, face) < 0, -1.0, 1.0)
    pcd.normals = o3d.utility.Vector3dVector(n * sign[:, None])
    return pcd


def metrics(gt, recon):
    out = subprocess.run([NKRR, "metrics", gt, recon], capture_output=True, text=True, check=True)
    m = json.loads(out.stdout.strip().splitlines()[-1])
    return {k: m[k] for k in ("cd1x100", "fscore", "nc", "watertight")}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=os.path.join(ROOT, "target/results/data"))
    ap.add_argument("--sizes", default="500,3k,10k")
    ap.add_argument("--methods", default="network,nkrr")
    ap.add_argument("--out", default=os.path.join(ROOT, "target/results/hybrid"))
    ap.add_argument("--depth", type=int, default=8)
    ap.add_argument("--k", type=int, default=30)
    ap.add_argument("--per-shape", action="store_true")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    rows = []
    for size, name, cloud in eval_clouds(a.data, a.sizes):
        gt = os.path.join(a.data, f"{name}.obj")
        for method in a.methods.split(","):
            glb = os.path.join(a.out, f"{name}-{size}-{method}.glb")
            if not os.path.exists(glb):
                subprocess.run([NKRR, "reconstruct", cloud, "-o", glb, "--method", method],
                               check=True, capture_output=True)
            obj = os.path.join(a.out, f"{name}-{size}-{method}-poisson.obj")
            if not os.path.exists(obj):
                pcd = oriented_normals(cloud, glb, a.k)
                mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pcd, depth=a.depth)
                o3d.io.write_triangle_mesh(obj, mesh, write_vertex_normals=False,
                                           write_vertex_colors=False, write_triangle_uvs=False)
            for variant, path in ((method, glb), (f"{method}+poisson", obj)):
                row = {"shape": name, "size": size, "method": variant, **metrics(gt, path)}
                rows.append(row)
                print(json.dumps(row), file=sys.stderr, flush=True)
    with open(os.path.join(a.out, "hybrid.jsonl"), "w") as f:
        f.writelines(json.dumps(r) + "\n" for r in rows)
    groups = collections.defaultdict(list)
    for r in rows:
        groups[(r["size"], r["method"])].append(r)
    print("| points | method | shapes | CD1 x100 | F-score | NC | watertight |")
    print("|---|---|---|---|---|---|---|")
    for (size, method), rs in groups.items():
        mean = lambda k: sum(r[k] for r in rs) / len(rs)  # noqa: E731
        wt = sum(bool(r["watertight"]) for r in rs)
        print(f"| {size} | {method} | {len(rs)} | {mean('cd1x100'):.3f} | {mean('fscore'):.3f} | {mean('nc'):.3f} | {wt}/{len(rs)} |")
    if a.per_shape:
        print()
        print("| shape | points | method | CD1 x100 | F-score | NC | watertight |")
        print("|---|---|---|---|---|---|---|")
        for r in rows:
            print(f"| {r['shape']} | {r['size']} | {r['method']} | {r['cd1x100']:.3f} | {r['fscore']:.3f} | {r['nc']:.3f} | {'yes' if r['watertight'] else 'no'} |")


if __name__ == "__main__":
    main()
