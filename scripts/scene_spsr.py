#!/usr/bin/env python3
"""Peer baseline for scenes: screened Poisson (Open3D) on a LAS/LAZ scan, in the scan's own frame.

Why: tests/peers/spsr.py runs screened Poisson on the small eval objects (PLY clouds near the
origin, closed shapes, normals pointed away from the centroid). A scene scan (issue 25) is a LAZ
far from the origin, seen from inside, with open sheets (floor, walls); this script is the same
recipe on such a cloud, with the output in the cloud's absolute coordinates so that
scripts/scene_metrics.py can score it against the scene's ground truth:

  1. read the LAZ (laspy), subtract an origin (the floor of the minimum; the solver works near 0);
  2. normals by PCA of the k = 30 nearest neighbours, orientation by propagation over the k-NN
     Riemannian graph (Open3D's orient_normals_consistent_tangent_plane(k)), then one global sign:
     the propagation leaves it free, and a scan's surfaces face the scanners, which stand inside
     the scene, so --sign inward (default) points the majority of normals towards the centroid
     (the opposite of the rule for closed objects in tests/peers/spsr.py; outward and none are
     there to see what the choice does);
  3. screened Poisson at octree depth 10 (--depth; issue 25's setting);
  4. writes OUT.ply untrimmed and OUT-trim5.ply with the vertices of the lowest 5 % Poisson
     density removed (--trim; people usually trim, it opens the surface where samples are sparse),
     both binary PLY with float64 vertices (f32 would quantise 4,000,000 to 25 cm);
  5. prints one JSON line: seconds per stage (I/O included in total_s), vertices and faces, and
     the peak memory of the process (resource.getrusage ru_maxrss).

usage:
  tests/peers/setup.sh && .venv-peers/bin/pip install 'laspy[lazrs]'   # (pinned in requirements)
  .venv-peers/bin/python scripts/scene_spsr.py /tmp/room1.laz -o /tmp/eval/room1-spsr.ply \
      [--depth 10] [--trim 5] [--k 30] [--sign inward|outward|none]
"""
import argparse
import json
import os
import resource
import time

import laspy
import numpy as np
import open3d as o3d


def write_ply(path: str, v: np.ndarray, f: np.ndarray, comment: str) -> None:
    """Binary little-endian PLY, float64 vertices, int32 triangles."""
    header = (f"ply\nformat binary_little_endian 1.0\ncomment {comment}\nelement vertex {len(v)}\n"
              "property double x\nproperty double y\nproperty double z\n"
              f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n")
    faces = np.empty(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    faces["n"], faces["i"] = 3, f
    with open(path, "wb") as fh:
        fh.write(header.encode())
        fh.write(np.ascontiguousarray(v, dtype="<f8").tobytes())
        fh.write(faces.tobytes())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cloud", help="LAS/LAZ")
    ap.add_argument("-o", "--out", required=True, help="OUT.ply (and OUT-trimT.ply)")
    ap.add_argument("--depth", type=int, default=10)
    ap.add_argument("--trim", type=float, default=5.0, help="percent of lowest-density vertices removed")
    ap.add_argument("--k", type=int, default=30)
    ap.add_argument("--sign", choices=["inward", "outward", "none"], default="inward")
    a = ap.parse_args()
    t = {}
    t0 = time.perf_counter()
    las = laspy.read(a.cloud)
    p = np.column_stack([np.asarray(las.x, np.float64), np.asarray(las.y, np.float64), np.asarray(las.z, np.float64)])
    origin = np.floor(p.min(0))
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p - origin))
    t["read_s"] = time.perf_counter() - t0

    s = time.perf_counter()
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=a.k))
    t["pca_s"] = time.perf_counter() - s
    s = time.perf_counter()
    pcd.orient_normals_consistent_tangent_plane(a.k)
    q, n = np.asarray(pcd.points), np.asarray(pcd.normals)
    toward = np.einsum("ij,ij->i", q.mean(0) - q, n) > 0
    share_inward = float(toward.mean())
    if (a.sign == "inward" and share_inward < 0.5) or (a.sign == "outward" and share_inward > 0.5):
        pcd.normals = o3d.utility.Vector3dVector(-n)
    t["orient_s"] = time.perf_counter() - s

    s = time.perf_counter()
    mesh, dens = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pcd, depth=a.depth)
    t["poisson_s"] = time.perf_counter() - s
    dens = np.asarray(dens)
    v, f = np.asarray(mesh.vertices) + origin, np.asarray(mesh.triangles)
    comment = f"scene_spsr.py depth {a.depth} k {a.k} sign {a.sign} from {os.path.basename(a.cloud)}"
    write_ply(a.out, v, f, comment + " untrimmed")
    counts = {"untrimmed": {"vertices": len(v), "faces": len(f), "path": a.out}}
    if a.trim > 0:
        s = time.perf_counter()
        mesh.remove_vertices_by_mask(dens < np.quantile(dens, a.trim / 100))
        t["trim_s"] = time.perf_counter() - s
        trimmed = a.out[:-4] + f"-trim{a.trim:g}.ply"
        vt, ft = np.asarray(mesh.vertices) + origin, np.asarray(mesh.triangles)
        write_ply(trimmed, vt, ft, comment + f" trimmed {a.trim:g}%")
        counts[f"trim{a.trim:g}"] = {"vertices": len(vt), "faces": len(ft), "path": trimmed}
    t["total_s"] = time.perf_counter() - t0
    print(json.dumps({
        "method": "spsr", "cloud": a.cloud, "points": len(p), "depth": a.depth, "k": a.k, "sign": a.sign,
        "share_inward_before_sign": round(share_inward, 4), "cores": os.cpu_count(),
        **{k: round(x, 2) for k, x in t.items()}, "meshes": counts,
        "max_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }), flush=True)


if __name__ == "__main__":
    main()
