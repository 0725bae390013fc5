#!/usr/bin/env python3
"""Prototype for issue 26 item 2 (measured, not in the product): a screened Poisson solve of our
own on a regular grid, with normals oriented by nkrr's field. The reference design for a Rust port
(docs/results.md, Lever 9).

    .venv-formats/bin/python scripts/grid_poisson.py CLOUD.ply MESH.glb OUT.obj [--res 128] [--alpha 1]

1. Normals: PCA of the k = 30 nearest neighbours, each signed by the nearest vertex normal of MESH (the
   closed, outward-oriented mesh `nkrr reconstruct` made of CLOUD: the field's inside/outside).
2. The target gradient: V = Σ_i −n_i a_i δ_i, each point's weight a_i (its share of the surface:
   0.9 × the squared mean distance to its 8 nearest neighbours) splatted trilinearly onto the
   grid's nodes (÷ h³: a density), so that χ rises by about 1 from outside to inside.
3. The screened energy over the nodes' values χ (grid of res³ cells over the cloud's bounding
   cube, padded 10 %):  Σ_edges (χ_b − χ_a − h·V̄_e)² + α Σ_i χ(p_i)²,  χ(p_i) trilinear. The
   points' term pins the zero level to the points (no iso-value to estimate); the normal
   equations (DᵀD + α SᵀS) χ = Dᵀg are solved by Jacobi-preconditioned conjugate gradients, from
   the solution at res/2 interpolated (a cascade).
4. Marching cubes of χ at 0 (χ > 0 inside): OUT.obj, triangles counter-clockwise from outside.
"""
import argparse
import sys
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spl
import trimesh
from scipy.spatial import cKDTree
from skimage.measure import marching_cubes


def read_points(path):
    return np.asarray(trimesh.load(path, process=False).vertices, dtype=np.float64)


def oriented_normals(p, mesh, k=30):
    tree = cKDTree(p)
    _, nb = tree.query(p, k=k)
    q = p[nb] - p[nb].mean(1, keepdims=True)
    _, vecs = np.linalg.eigh(np.einsum("nki,nkj->nij", q, q))
    n = vecs[:, :, 0]
    # The sign from the mesh's nearest vertex normal (its cells are 1/128 of the cloud: near
    # enough for a sign).
    _, near = cKDTree(mesh.vertices).query(p)
    face = mesh.vertex_normals[near]
    n *= np.where(np.einsum("ij,ij->i", n, face) < 0, -1.0, 1.0)[:, None]
    d, _ = tree.query(p, k=9)
    return n, 0.9 * d[:, 1:].mean(1) ** 2


def system(p, n, area, lo, h, res, alpha):
    """(A, rhs, S) of the screened energy on a res³ grid with origin lo and spacing h."""
    n1 = res + 1
    nodes = n1 ** 3
    u = (p - lo) / h
    b = np.floor(u).astype(int).clip(0, res - 1)
    f = u - b
    rows, cols, vals = [], [], []
    for c in range(8):
        dx, dy, dz = c & 1, c >> 1 & 1, c >> 2 & 1
        w = (f[:, 0] if dx else 1 - f[:, 0]) * (f[:, 1] if dy else 1 - f[:, 1]) * (f[:, 2] if dz else 1 - f[:, 2])
        rows.append(np.arange(len(p)))
        cols.append((b[:, 0] + dx) + n1 * ((b[:, 1] + dy) + n1 * (b[:, 2] + dz)))
        vals.append(w)
    S = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(len(p), nodes))
    V = np.stack([S.T @ (-n[:, a] * area) for a in range(3)], 1) / h ** 3
    idx = np.arange(nodes)
    coords = (idx % n1, idx // n1 % n1, idx // (n1 * n1))
    blocks, g = [], []
    for a, step in enumerate((1, n1, n1 * n1)):
        e = idx[coords[a] < res]
        m = len(e)
        blocks.append(sp.csr_matrix((np.r_[-np.ones(m), np.ones(m)], (np.r_[np.arange(m), np.arange(m)], np.r_[e, e + step])),
                                    shape=(m, nodes)))
        g.append(h * 0.5 * (V[e, a] + V[e + step, a]))
    D = sp.vstack(blocks).tocsr()
    return (D.T @ D + alpha * (S.T @ S)).tocsr(), D.T @ np.concatenate(g)


def upsample(chi, res):
    """Trilinear interpolation of a (res/2 + 1)³ grid onto (res + 1)³ nodes, x fastest."""
    half = res // 2
    c = chi.reshape(half + 1, half + 1, half + 1)  # [z, y, x]
    for axis in range(3):
        lo = np.take(c, range(half), axis=axis)
        hi = np.take(c, range(1, half + 1), axis=axis)
        mid = 0.5 * (lo + hi)
        shape = list(c.shape)
        shape[axis] = 2 * half + 1
        out = np.empty(shape)
        sl = [slice(None)] * 3
        sl[axis] = slice(0, None, 2)
        out[tuple(sl)] = c
        sl[axis] = slice(1, None, 2)
        out[tuple(sl)] = mid
        c = out
    return c.ravel()


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cloud")
    ap.add_argument("mesh")
    ap.add_argument("out")
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--alpha", type=float, default=1.0)
    ap.add_argument("--levels", type=int, default=2, help="grids in the cascade (res, res/2, ...)")
    a = ap.parse_args()
    t0 = time.perf_counter()
    p = read_points(a.cloud)
    n, area = oriented_normals(p, trimesh.load(a.mesh, force="mesh", process=False))
    lo, hi = p.min(0), p.max(0)
    ext = (hi - lo).max() * 1.1
    lo = (lo + hi) / 2 - ext / 2
    chi = None
    iters = []
    for res in [a.res >> i for i in reversed(range(a.levels))]:
        A, rhs = system(p, n, area, lo, ext / res, res, a.alpha)
        x0 = None if chi is None else upsample(chi, res)
        count = [0]
        chi, info = spl.cg(A, rhs, x0=x0, M=sp.diags(1 / A.diagonal()), maxiter=3000, rtol=1e-6,
                           callback=lambda _: count.__setitem__(0, count[0] + 1))
        iters.append(f"{res}: {count[0]} iterations{'' if info == 0 else ' (not converged)'}")
    n1 = a.res + 1
    verts, faces, _, _ = marching_cubes(chi.reshape(n1, n1, n1).transpose(2, 1, 0), 0.0)
    verts = lo + verts * (ext / a.res)
    with open(a.out, "w") as f:
        f.writelines(f"v {v[0]:.7g} {v[1]:.7g} {v[2]:.7g}\n" for v in verts)
        f.writelines(f"f {t[0] + 1} {t[2] + 1} {t[1] + 1}\n" for t in faces)
    print(f"{a.out}: {len(faces)} triangles; {'; '.join(iters)}; {time.perf_counter() - t0:.1f} s", file=sys.stderr)


if __name__ == "__main__":
    main()
