#!/usr/bin/env python3
"""The trim check of issue 8 on a one-sided scan: the points of spot-10k whose ground-truth
surface faces +x (what a scanner on the +x side sees), reconstructed at the defaults (nkrr) with
and without --trim, then rendered with scripts/render.py: points, the default (closed but where
the fill between sheets is opened, docs/poisson.md "Open shells"), the faces
--trim removes, trimmed. Writes docs/img/trim-facing-x.png and prints the numbers.

usage: .venv/bin/python scripts/trim_facing.py [NKRR_BIN]   (needs trimesh, scipy, pillow)
"""
import pathlib
import subprocess
import sys
import tempfile

import numpy as np
import trimesh
from scipy.spatial import cKDTree

ROOT = pathlib.Path(__file__).resolve().parent.parent
EVAL = ROOT / "tests" / "data" / "eval"
BIN = sys.argv[1] if len(sys.argv) > 1 else str(ROOT / "target/release/nkrr")

mesh = trimesh.load(EVAL / "spot.obj", process=False)
data = (EVAL / "spot-10k.ply").read_bytes()
end = data.index(b"end_header\n") + len(b"end_header\n")
n = int([l for l in data[:end].decode().splitlines() if l.startswith("element vertex")][0].split()[2])
pts = np.frombuffer(data[end:end + 12 * n], dtype="<f4").reshape(n, 3).astype(np.float64)
samples, faces = trimesh.sample.sample_surface(mesh, 400_000, seed=1)
_, nearest = cKDTree(samples).query(pts)
keep = pts[mesh.face_normals[faces[nearest]][:, 0] > 0.2]
print(f"{len(keep)} of {n} points face +x")

with tempfile.TemporaryDirectory() as tmp:
    tmp = pathlib.Path(tmp)
    cloud = tmp / "spot-facing-x.ply"
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(keep)}\n"
              "property float x\nproperty float y\nproperty float z\nend_header\n")
    cloud.write_bytes(header.encode() + keep.astype("<f4").tobytes())
    default, trimmed = tmp / "default.ply", tmp / "trimmed.ply"
    subprocess.run([BIN, "reconstruct", str(cloud), "-o", str(default)], check=True)
    subprocess.run([BIN, "reconstruct", str(cloud), "--trim", "-o", str(trimmed)], check=True)
    tree = cKDTree(keep)
    spacing = np.mean(tree.query(keep, k=2)[0][:, 1])
    removed = tmp / "removed-by-trim.ply"
    for name, path in [("default", default), ("trimmed", trimmed)]:
        m = trimesh.load(path, process=False)
        d = tree.query(m.triangles_center)[0] / spacing
        far = d > 3
        boundary = len(trimesh.grouping.group_rows(m.edges_sorted, require_count=1))
        print(f"{name}: {len(m.faces)} faces, {m.area_faces[far].sum() / m.area:.1%} of the area farther than "
              f"3 spacings (at most {d.max():.1f}), {boundary} boundary edges")
        if name == "default":
            m.submesh([np.nonzero(far)[0]], append=True).export(removed)
    subprocess.run([sys.executable, str(ROOT / "scripts" / "render.py"), str(cloud), str(default), str(removed),
                    str(trimmed), "-o", str(ROOT / "docs/img/trim-facing-x.png"), "--size", "260"], check=True)
