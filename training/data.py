"""Shape cache (chunks of generated shapes on disk) and training-batch sampling.

Layout: training/cache/train/chunk_XXXXX.npz holds CHUNK shapes with seeds
chunk*CHUNK .. chunk*CHUNK+CHUNK-1 of the training stream (shapes.make_shape(seed, kind=1));
so any process that writes chunk i writes the same content, and generation is resumable.
Held-out shapes use kind=2 (a separate seed space) and live in training/cache/heldout_<n>.npz.
"""
from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from .shapes import make_shape

CACHE = Path(__file__).resolve().parent / "cache"
CHUNK = 16
KEYS = ("surf", "normals", "quni", "qnear", "occ_uni", "occ_near")


def chunk_path(i, cache=CACHE):
    return Path(cache) / "train" / f"chunk_{i:05d}.npz"


def _save_npz(path, arrays):
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"tmp_{path.stem}_{os.getpid()}.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)


def stack_shapes(shapes):
    out = {k: np.stack([s[k] for s in shapes]) for k in KEYS}
    out["occ_uni"] = np.packbits(out["occ_uni"], axis=1)
    out["occ_near"] = np.packbits(out["occ_near"], axis=1)
    out["seed"] = np.array([s["seed"] for s in shapes])
    out["family"] = np.array([s["family"] for s in shapes])
    out["n_uni"] = np.array(shapes[0]["quni"].shape[0])
    out["n_near"] = np.array(shapes[0]["qnear"].shape[0])
    return out


def gen_chunk(i, cache=CACHE, kind=1):
    """Chunk i of training stream `kind` (1: the first prior's shapes, 3: the second stream with
    the new families; shapes.STREAMS). One cache folder holds one stream."""
    p = chunk_path(i, cache)
    if p.exists():
        return False
    shapes = [make_shape(i * CHUNK + j, kind=kind) for j in range(CHUNK)]
    _save_npz(p, stack_shapes(shapes))
    return True


def missing_chunks(n_chunks, cache=CACHE):
    return [i for i in range(n_chunks) if not chunk_path(i, cache).exists()]


def load_chunk(path):
    z = np.load(path)
    d = {k: z[k] for k in z.files}
    d["occ_uni"] = np.unpackbits(d["occ_uni"], axis=1, count=int(d["n_uni"])).astype(bool)
    d["occ_near"] = np.unpackbits(d["occ_near"], axis=1, count=int(d["n_near"])).astype(bool)
    return d


class Pool:
    """All shapes of the cache in memory, as a list of per-chunk dicts."""

    def __init__(self, cache=CACHE):
        self.cache = Path(cache)
        self.chunks = {}
        self.index = []  # (chunk id, row)
        self.refresh()

    def refresh(self):
        for p in sorted((self.cache / "train").glob("chunk_*.npz")):
            i = int(p.stem.split("_")[1])
            if i in self.chunks:
                continue
            try:
                d = load_chunk(p)
            except Exception:
                continue
            self.chunks[i] = d
            self.index += [(i, r) for r in range(len(d["seed"]))]
        return len(self.index)

    def __len__(self):
        return len(self.index)

    def get(self, k):
        i, r = self.index[k]
        return {key: self.chunks[i][key][r] for key in KEYS}


class InlineGenerator:
    """Generates the next missing chunk one shape per call (from inside the training loop)."""

    def __init__(self, cache=CACHE, limit_chunks=100000, kind=1):
        self.cache = Path(cache)
        self.kind = kind
        self.limit = limit_chunks
        self.cur = None
        self.buf = []

    def step(self):
        """Generate one shape; returns True when a chunk was completed (and written)."""
        if self.cur is None or chunk_path(self.cur, self.cache).exists():
            self.buf = []
            self.cur = next((i for i in range(self.limit) if not chunk_path(i, self.cache).exists()), None)
            if self.cur is None:
                return False
        j = len(self.buf)
        self.buf.append(make_shape(self.cur * CHUNK + j, kind=self.kind))
        if len(self.buf) == CHUNK:
            p = chunk_path(self.cur, self.cache)
            if not p.exists():
                _save_npz(p, stack_shapes(self.buf))
            self.cur, self.buf = None, []
            return True
        return False


def cube_symmetry(rng):
    """Random element of the 48 symmetries of the cube (signed permutation matrix)."""
    return (np.eye(3)[rng.permutation(3)] * rng.choice([-1.0, 1.0], 3)).astype(np.float32)


def normalise(cloud, *others):
    lo, hi = cloud.min(0), cloud.max(0)
    c = (lo + hi) / 2
    s = 1.0 / max(float((hi - lo).max()), 1e-6)
    return [(cloud - c) * s] + [(o - c) * s for o in others]


class Scan:
    """How a sample's cloud is degraded beyond noise: the probability of each degradation per
    sample (issue 14 items 6 and 7; all 0 is the first prior's recipe). Each mimics a failure of
    real scans that the eval's harder set (scripts/hard_clouds.py) also has."""

    def __init__(self, falloff=0.0, outliers=0.0, onesided=0.0, falloff_max=60.0, outliers_max=0.1, fixed=False):
        self.falloff, self.outliers, self.onesided = falloff, outliers, onesided
        self.falloff_max, self.outliers_max = falloff_max, outliers_max
        # fixed: always the largest falloff (held-out sets), not a random one up to it
        self.fixed = fixed


def _draw_points(shape, rng, n_pts, scan):
    surf = shape["surf"]
    logw = np.zeros(len(surf))
    if scan.onesided and rng.random() < scan.onesided:
        # seen from one side: points whose normal faces away from the view are rarely sampled
        # (not never: the scanner grazes them)
        v = rng.normal(size=3)
        v /= np.linalg.norm(v)
        logw += np.where(shape["normals"].astype(np.float32) @ v > -0.1, 0.0, -4.0)
    if scan.falloff and rng.random() < scan.falloff:
        # density falls by up to `falloff_max`x along a random direction, as with a scanner's range
        d = rng.normal(size=3)
        t = surf.astype(np.float32) @ (d / np.linalg.norm(d))
        t = (t - t.min()) / max(float(np.ptp(t)), 1e-6)
        logw -= t * (np.log(scan.falloff_max) if scan.fixed else rng.uniform(0, np.log(scan.falloff_max)))
    if not logw.any():
        return surf[rng.choice(len(surf), n_pts, replace=n_pts > len(surf))].astype(np.float32)
    # weighted draw without replacement (Gumbel top-k: keys log w + Gumbel noise)
    keys = logw + rng.gumbel(size=len(surf))
    n = min(n_pts, len(surf))
    idx = np.argpartition(-keys, n - 1)[:n]
    return surf[idx].astype(np.float32)


def _stray(pts, rng, k):
    """Replaces k of `pts` (in place) by points uniform in their box enlarged by 5 % a side."""
    lo, hi = pts.min(0), pts.max(0)
    pad = 0.05 * (hi - lo)
    pts[rng.choice(len(pts), k, replace=False)] = rng.uniform(lo - pad, hi + pad, (k, 3))


def make_sample(shape, rng, n_pts, sigma, n_q=2048, frac_uni=0.5, augment=True, scan=None):
    pts = _draw_points(shape, rng, n_pts, scan or Scan())
    pts += rng.normal(size=pts.shape).astype(np.float32) * sigma
    if scan is not None and scan.outliers and rng.random() < scan.outliers:
        # stray points (flying pixels, reflections): a share of the cloud replaced by points
        # uniform in its box, a little enlarged
        _stray(pts, rng, int(round(len(pts) * rng.uniform(0, scan.outliers_max))))
    nu = int(round(n_q * frac_uni))
    iu = rng.integers(0, len(shape["quni"]), nu)
    inr = rng.integers(0, len(shape["qnear"]), n_q - nu)
    q = np.concatenate([shape["quni"][iu], shape["qnear"][inr]]).astype(np.float32)
    occ = np.concatenate([shape["occ_uni"][iu], shape["occ_near"][inr]]).astype(np.float32)
    if augment:
        M = cube_symmetry(rng)
        pts, q = pts @ M, q @ M
    pts, q = normalise(pts, q)
    return pts, q, occ


def make_batch(pool, rng, B, n_pts=None, n_q=2048, noise_max=0.01, pts_range=(500, 10000), scan=None):
    if n_pts is None:
        lo, hi = np.log(pts_range[0]), np.log(pts_range[1])
        n_pts = int(round(np.exp(rng.uniform(lo, hi))))
    P, Q, Y = [], [], []
    for _ in range(B):
        s = pool.get(int(rng.integers(len(pool))))
        p, q, y = make_sample(s, rng, n_pts, float(rng.uniform(0, noise_max)), n_q, scan=scan)
        P.append(p), Q.append(q), Y.append(y)
    return np.stack(P), np.stack(Q), np.stack(Y)


# ----------------------------------------------------------------------------- held-out set

def heldout_set(n=32, n_pts=3000, sigma=0.005, n_q=10000, cache=CACHE, kind=2, scan=None, name=None):
    """Fixed held-out shapes (kind=2 seeds): input clouds + uniform labelled queries for IoU.
    With `scan` (every degradation it names applied, probabilities taken as 1) or kind 4 (the
    second stream's new families), a named variant for comparing priors (training/compare.py)."""
    path = Path(cache) / (f"heldout_{n}.npz" if name is None else f"heldout_{name}_{n}.npz")
    if path.exists():
        z = np.load(path)
        return {k: z[k] for k in z.files}
    rng = np.random.default_rng(12345)
    P, Q, Y, F = [], [], [], []
    for i in range(n):
        s = make_shape(i, kind=kind)
        if scan is None:
            idx = rng.choice(len(s["surf"]), n_pts, replace=False)
            pts = s["surf"][idx].astype(np.float32)
        else:
            pts = _draw_points(s, rng, n_pts, scan)
        pts += rng.normal(size=(n_pts, 3)).astype(np.float32) * sigma
        if scan is not None and scan.outliers:
            _stray(pts, rng, int(round(n_pts * scan.outliers_max)))
        iu = rng.choice(len(s["quni"]), n_q, replace=False)
        q = s["quni"][iu].astype(np.float32)
        y = s["occ_uni"][iu]
        pts, q = normalise(pts, q)
        P.append(pts), Q.append(q), Y.append(y), F.append(s["family"])
    d = dict(cloud=np.stack(P), q=np.stack(Q), occ=np.stack(Y), family=np.array(F))
    _save_npz(path, d)
    return d
