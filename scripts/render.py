#!/usr/bin/env python3
"""Render meshes or point clouds to one PNG, to look at results without a GPU or a display.

Each input is a row; each column is a view (front, side, top, and a 3/4 view). Meshes are drawn by
splatting dense surface samples into a z-buffer with Lambert shading; point clouds (.ply without
faces) as shaded dots. All rows share the first input's framing, so a reconstruction and its ground
truth line up when the first row is the ground truth.

usage: scripts/render.py INPUT [INPUT ...] -o OUT.png [--size 320] [--samples 400000]
needs: numpy, trimesh, pillow
"""
import argparse

import numpy as np
import trimesh
from PIL import Image, ImageDraw

VIEWS = {  # (yaw, pitch) in degrees
    "front": (0, 0),
    "side": (90, 0),
    "top": (0, 90),
    "3/4": (35, 25),
}


def load(path, samples, rng):
    g = trimesh.load(path, process=False)
    if isinstance(g, trimesh.Scene):
        g = trimesh.util.concatenate([m for m in g.dump() if isinstance(m, trimesh.Trimesh)] or [trimesh.Trimesh()])
    if isinstance(g, trimesh.Trimesh) and len(g.faces):
        pts, fi = trimesh.sample.sample_surface(g, samples, seed=int(rng.integers(1 << 31)))
        return np.asarray(pts), np.asarray(g.face_normals[fi]), True
    pts = np.asarray(g.vertices if hasattr(g, "vertices") else g)
    return pts, None, False


def rotation(yaw, pitch):
    y, p = np.radians(yaw), np.radians(pitch)
    ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    rx = np.array([[1, 0, 0], [0, np.cos(p), -np.sin(p)], [0, np.sin(p), np.cos(p)]])
    return rx @ ry


def draw(pts, nrm, centre, scale, view, size, color=None):
    """One view of the samples as a size x size uint8 image: grey levels, or with color (one RGB
    row in 0..1 per sample) an RGB image of the colours times the shading, on white."""
    r = rotation(*VIEWS[view])
    q = (pts - centre) @ r.T * scale  # in [-0.5, 0.5] roughly
    px = np.clip(((q[:, 0] + 0.55) / 1.1 * size).astype(int), 0, size - 1)
    py = np.clip(((0.55 - q[:, 1]) / 1.1 * size).astype(int), 0, size - 1)
    depth = q[:, 2]  # larger = closer to the viewer
    if nrm is not None:  # 2x2 splats close the gaps between surface samples
        px = np.concatenate([px, np.minimum(px + 1, size - 1), px, np.minimum(px + 1, size - 1)])
        py = np.concatenate([py, py, np.minimum(py + 1, size - 1), np.minimum(py + 1, size - 1)])
        depth, nrm = np.tile(depth, 4), np.tile(nrm, (4, 1))
        if color is not None:
            color = np.tile(color, (4, 1))
    if nrm is None:
        shade = 0.35 + 0.65 * (depth - depth.min()) / max(np.ptp(depth), 1e-9)
    else:
        n = nrm @ r.T
        light = np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8])
        shade = 0.25 + 0.75 * np.abs(n @ light)  # unoriented normals: two-sided
    if color is not None:
        shade = np.asarray(color, dtype=np.float64) * shade[:, None]
    img = np.full((size, size) + shade.shape[1:], 1.0)
    zbuf = np.full(size * size, -np.inf)
    idx = py * size + px
    order = np.argsort(depth)  # far to near: nearer samples overwrite
    zbuf[idx[order]] = depth[order]
    val = np.full((size * size,) + shade.shape[1:], np.nan)
    val[idx[order]] = shade[order]
    hit = ~np.isnan(val.reshape(size * size, -1)[:, 0])
    img.reshape((size * size,) + shade.shape[1:])[hit] = val[hit]
    return (img * 255).astype(np.uint8)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("inputs", nargs="+")
    ap.add_argument("-o", "--out", required=True)
    ap.add_argument("--size", type=int, default=320)
    ap.add_argument("--samples", type=int, default=400_000)
    a = ap.parse_args()
    rng = np.random.default_rng(0)
    data = [load(p, a.samples, rng) for p in a.inputs]
    lo, hi = data[0][0].min(0), data[0][0].max(0)
    centre, scale = (lo + hi) / 2, 1.0 / max(float((hi - lo).max()), 1e-12)
    label_h = 18
    sheet = Image.new("L", (a.size * len(VIEWS), (a.size + label_h) * len(data)), 255)
    d = ImageDraw.Draw(sheet)
    for row, (path, (pts, nrm, _)) in enumerate(zip(a.inputs, data)):
        y0 = row * (a.size + label_h)
        d.text((4, y0 + 3), f"{path.split('/')[-1]}  ({len(pts)} samples)", fill=0)
        for col, view in enumerate(VIEWS):
            tile = Image.fromarray(draw(pts, nrm, centre, scale, view, a.size))
            sheet.paste(tile, (col * a.size, y0 + label_h))
            d.text((col * a.size + 4, y0 + label_h + 3), view, fill=90)
    sheet.save(a.out)
    print(a.out)


if __name__ == "__main__":
    main()
