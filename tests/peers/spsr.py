"""Peer baseline: Screened Poisson surface reconstruction (Kazhdan & Hoppe 2013, Open3D's build
of Kazhdan's PoissonRecon) with PCA normals, on the evaluation clouds of tests/data/eval.

For each cloud DATA/NAME-SIZE.ply (unoriented, noisy; see DATA/README.md):
  1. normals by PCA of the k nearest neighbours (k = 30), then a consistent orientation by
     propagation over a k-NN Riemannian graph (Hoppe et al. 1992, Open3D's
     orient_normals_consistent_tangent_plane), then one global sign flip if most normals point
     inwards (the propagation fixes orientation only up to a global sign);
  2. screened Poisson at octree depth 8 (--depth); no density trimming by default (--trim 0),
     so the surface is meant to stay closed (it is open only where the implicit surface runs
     into the side of Poisson's bounding cube, which misoriented normals can cause); --trim X
     removes the vertices of the lowest X % density, as people usually do, which opens the
     surface where the samples are sparse;
  3. writes OUT/NAME-SIZE.obj and one JSON line per cloud (stdout and OUT/spsr.jsonl): the
     timings in seconds (normals_s = PCA + orientation, poisson_s = Poisson + trimming; file
     I/O excluded; Open3D uses every core; with --repeat N the fastest of N runs, and runs_s
     each run's whole time), vertex and
     face counts, connected components, two watertight tests (closed_manifold: every edge in
     exactly two triangles, as `nkrr metrics`'s watertight, which also asks the two to agree
     on orientation; o3d_watertight: Open3D's is_watertight, which also rejects
     self-intersecting triangles) and, with --metrics-cmd, that command's metrics against
     DATA/NAME.obj.

Orientation is the hard part: SPSR needs an oriented normal per point and the clouds have
none, so everything depends on step 1 getting a consistent inside/outside from unoriented
noisy points; a flipped patch becomes a dent, a hole or a sheet in the Poisson surface. nkrr
needs no normals at all (its field comes from the network prior and the KRR on positions).

    tests/peers/setup.sh     # makes .venv-peers (tests/peers/requirements.txt)
    .venv-peers/bin/python tests/peers/spsr.py --data tests/data/eval --sizes 3k,10k \
        --out /tmp/spsr [--depth 8] [--trim 0] [--k 30] [--repeat 1] \
        [--metrics-cmd 'target/release/nkrr metrics']

--metrics-cmd is run as `CMD GT.obj RECON.obj` and must print one JSON object per line (the
last line is used): `target/release/nkrr metrics` (the same metrics as `nkrr eval`) or
`.venv/bin/python scripts/eval_metrics.py`.
"""
import argparse
import glob
import json
import os
import shlex
import subprocess
import sys
import time

import numpy as np
import open3d as o3d


def normals(pcd, k):
    """PCA normals, then orientation; returns (seconds for PCA, seconds for orientation)."""
    t0 = time.perf_counter()
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=k))
    t1 = time.perf_counter()
    # The hard part, and the one nkrr does not need: a consistent sign for every normal.
    pcd.orient_normals_consistent_tangent_plane(k)
    # The propagation leaves one global sign free; point the majority outwards (away from
    # the centroid), which holds for the closed shapes of the eval set.
    p = np.asarray(pcd.points)
    n = np.asarray(pcd.normals)
    if np.sum(np.einsum("ij,ij->i", p - p.mean(0), n) > 0) < 0.5 * len(p):
        pcd.normals = o3d.utility.Vector3dVector(-n)
    t2 = time.perf_counter()
    return t1 - t0, t2 - t1


def poisson(pcd, depth, trim):
    t0 = time.perf_counter()
    mesh, dens = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pcd, depth=depth)
    if trim > 0:
        dens = np.asarray(dens)
        mesh.remove_vertices_by_mask(dens < np.quantile(dens, trim / 100))
    return mesh, time.perf_counter() - t0


def run_metrics(cmd, gt, recon):
    out = subprocess.run(shlex.split(cmd) + [gt, recon], capture_output=True, text=True)
    if out.returncode != 0:
        return {"metrics_error": (out.stderr or out.stdout).strip()[-500:]}
    m = json.loads(out.stdout.strip().splitlines()[-1])
    for key in ("gt", "recon", "faces"):
        m.pop(key, None)
    return m


def emit(row, log):
    """One cloud's row as a JSON line, on stdout and appended to the open LOG (flushed, so an
    interrupted run keeps what it measured)."""
    line = json.dumps(row)
    print(line, flush=True)
    log.write(line + "\n")
    log.flush()


def eval_clouds(data, sizes, shapes=""):
    """(size, name, path) of each cloud DATA/NAME-SIZE.ply for the comma-separated SIZES and SHAPES
    (every DATA/NAME.obj when SHAPES is empty), size by size; a missing cloud is said and skipped."""
    names = [s for s in shapes.split(",") if s]
    if not names:
        names = sorted(os.path.basename(p)[:-4] for p in glob.glob(os.path.join(data, "*.obj")))
    for size in sizes.split(","):
        for name in names:
            cloud = os.path.join(data, f"{name}-{size}.ply")
            if not os.path.exists(cloud):
                print(f"skip {cloud}: missing", file=sys.stderr)
                continue
            yield size, name, cloud


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True, help="folder with NAME.obj and NAME-SIZE.ply")
    ap.add_argument("--sizes", default="3k,10k")
    ap.add_argument("--shapes", default="", help="comma-separated names (default: all)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--depth", type=int, default=8)
    ap.add_argument("--trim", type=float, default=0.0,
                    help="remove the vertices of the lowest TRIM percent of Poisson density")
    ap.add_argument("--k", type=int, default=30, help="neighbours for PCA and orientation")
    ap.add_argument("--metrics-cmd", default="", help="run as CMD GT.obj RECON.obj")
    ap.add_argument("--plain", action="store_true",
                    help="only what a user runs (read, normals, Poisson, write): no component count "
                         "or watertight tests, so the whole process can be timed (scripts/bench.py)")
    ap.add_argument("--repeat", type=int, default=1,
                    help="run each cloud N times and report the fastest times (load noise)")
    a = ap.parse_args()

    os.makedirs(a.out, exist_ok=True)
    log = open(os.path.join(a.out, "spsr.jsonl"), "w")
    for size, name, cloud in eval_clouds(a.data, a.sizes, a.shapes):
        t_pca = t_orient = t_poisson = float("inf")
        runs = []
        for _ in range(max(a.repeat, 1)):
            pcd = o3d.io.read_point_cloud(cloud)
            times = normals(pcd, a.k)
            mesh, t = poisson(pcd, a.depth, a.trim)
            t_pca, t_orient = min(t_pca, times[0]), min(t_orient, times[1])
            t_poisson = min(t_poisson, t)
            runs.append(round(times[0] + times[1] + t, 3))
        recon = os.path.join(a.out, f"{name}-{size}.obj")
        o3d.io.write_triangle_mesh(recon, mesh, write_vertex_normals=False,
                                   write_vertex_colors=False, write_triangle_uvs=False)
        row = {
            "method": "spsr", "shape": name, "size": size, "points": len(pcd.points),
            "depth": a.depth, "trim": a.trim, "k": a.k, "cores": os.cpu_count(),
            "normals_s": round(t_pca + t_orient, 3), "pca_s": round(t_pca, 3),
            "orient_s": round(t_orient, 3), "poisson_s": round(t_poisson, 3),
            "runs_s": runs,
            "vertices": len(mesh.vertices), "faces": len(mesh.triangles),
            "recon": recon,
        }
        if not a.plain:
            row.update({
                "components": int(len(np.asarray(mesh.cluster_connected_triangles()[1]))),
                # edge-manifold with no boundary edge = closed 2-manifold surface;
                # Open3D's is_watertight also asks vertex-manifold and no self-intersection.
                "closed_manifold": bool(mesh.is_edge_manifold(allow_boundary_edges=False)),
                "o3d_watertight": bool(mesh.is_watertight()),
            })
        if a.metrics_cmd:
            row.update(run_metrics(a.metrics_cmd, os.path.join(a.data, f"{name}.obj"), recon))
        emit(row, log)


if __name__ == "__main__":
    main()
