#!/usr/bin/env python3
"""Where a reconstruction's error beyond the F-score's tau sits (issue 26): one PNG, two rows in
render.py's views (front, side, top, 3/4) and framing (the ground truth's).

  (a) the ground truth coloured by its distance to the reconstruction (the completeness side:
      missing or displaced parts);
  (b) the reconstruction coloured by its distance to the ground truth (the precision side: extra,
      merged or displaced surface).

Grey: within tau (counted by the F-score); beyond tau a ramp from yellow at tau through red to
purple at --vmax (default 5 tau) and above. Distances are those of scripts/eval_metrics.py: in the
ground truth's unit-cube frame, to the nearest of the other surface's 100k metric samples; the
drawn samples (--samples per surface, denser than the metric's so the splats close) are measured
against the same 100k. Each row's caption gives its side of the split (eval_metrics' keys).

usage: scripts/error_map.py GT.obj RECON.glb -o OUT.png [--size 320] [--samples 400000]
       [--vmax 0.05]
needs: numpy, scipy, trimesh, pillow
"""
import argparse
import os
import sys

import numpy as np
import trimesh
from PIL import Image, ImageDraw
from scipy.spatial import cKDTree

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from eval_metrics import TAU, metrics  # noqa: E402
from render import VIEWS, draw  # noqa: E402

GREY = np.array([0.80, 0.80, 0.80])
# beyond tau: yellow at tau, red at the middle of the ramp, purple at vmax and above
RAMP = np.array([[1.00, 0.85, 0.10], [0.90, 0.10, 0.05], [0.50, 0.00, 0.55]])


def colours(d, tau, vmax):
    """RGB in 0..1 per distance: GREY below tau, RAMP from tau to vmax (clamped above)."""
    t = np.clip((np.asarray(d) - tau) / max(vmax - tau, 1e-12), 0.0, 1.0) * (len(RAMP) - 1)
    k = np.minimum(t.astype(int), len(RAMP) - 2)
    f = (t - k)[:, None]
    c = RAMP[k] * (1 - f) + RAMP[k + 1] * f
    return np.where((np.asarray(d) < tau)[:, None], GREY, c)


def dense(mesh, n, seed, others):
    """n samples on mesh (normalised frame), their normals and distances to the points others."""
    pts, fi = trimesh.sample.sample_surface(mesh, n, seed=seed)
    pts = np.asarray(pts)
    return pts, np.asarray(mesh.face_normals[fi]), cKDTree(others).query(pts)[0]


def legend(width, tau, vmax, height=34):
    img = Image.new("RGB", (width, height), (255, 255, 255))
    d = ImageDraw.Draw(img)
    x0, x1, y0, y1 = 10, width - 10, 4, 16
    grey_w = (x1 - x0) // 6  # the "within tau" swatch
    d.rectangle([x0, y0, x0 + grey_w - 4, y1], fill=tuple(int(255 * v) for v in GREY))
    d.text((x0, y1 + 3), f"< tau = {tau:g}", fill=(0, 0, 0))
    r0 = x0 + grey_w
    ds = tau + (vmax - tau) * np.linspace(0, 1, x1 - r0)
    for i, c in enumerate(colours(ds, tau, vmax)):
        d.line([(r0 + i, y0), (r0 + i, y1)], fill=tuple(int(255 * v) for v in c))
    for frac in np.linspace(0, 1, 5):
        x = int(r0 + frac * (x1 - r0 - 1))
        v = tau + frac * (vmax - tau)
        label = f"{v / tau:g} tau" + (" and above" if frac == 1 else "")
        d.line([(x, y1), (x, y1 + 2)], fill=(0, 0, 0))
        d.text((min(x, x1 - 6 * len(label)), y1 + 3), label, fill=(0, 0, 0))
    return img


def caption(row, side):
    s = lambda k: row[f"{side}_{k}"]  # noqa: E731
    fmt = lambda v: "-" if v is None else f"{v:.3f}"  # noqa: E731
    return (f"distances x100: this side's mean {s('mean_x100'):.3f}; beyond tau {100 * s('beyond_share'):.1f}% "
            f"of the samples, mean {fmt(s('beyond_mean_x100'))}, carrying {100 * s('beyond_cd_share'):.0f}% of "
            f"the side's mean; within tau: mean {fmt(s('within_mean_x100'))}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("gt")
    ap.add_argument("recon")
    ap.add_argument("-o", "--out", required=True)
    ap.add_argument("--size", type=int, default=320)
    ap.add_argument("--samples", type=int, default=400_000)
    ap.add_argument("--vmax", type=float, default=5 * TAU, help="distance at the ramp's end")
    a = ap.parse_args()
    row, S = metrics(a.gt, a.recon, samples=True)
    rows = [
        ("ground truth by distance to the reconstruction (completeness side: missing)", "completeness",
         dense(S["gt_mesh"], a.samples, 11, S["rec_points"])),
        ("reconstruction by distance to the ground truth (precision side: extra)", "precision",
         dense(S["rec_mesh"], a.samples, 12, S["gt_points"])),
    ]
    lo, hi = rows[0][2][0].min(0), rows[0][2][0].max(0)  # render.py's framing: the first row's
    centre, scale = (lo + hi) / 2, 1.0 / max(float((hi - lo).max()), 1e-12)

    head_h, label_h, legend_h = 18, 32, 34
    W = a.size * len(VIEWS)
    sheet = Image.new("RGB", (W, head_h + (a.size + label_h) * len(rows) + legend_h), (255, 255, 255))
    d = ImageDraw.Draw(sheet)
    d.text((4, 3), f"{os.path.basename(a.recon)} against {os.path.basename(a.gt)}: CD1 x100 "
           f"{row['cd1x100']:.3f} ({100 * row['beyond_cd_share']:.0f}% of it beyond tau), F {row['fscore']:.3f}, "
           f"NC {row['nc']:.3f}", fill=(0, 0, 0))
    for r, (title, side, (pts, nrm, dist)) in enumerate(rows):
        y0 = head_h + r * (a.size + label_h)
        d.text((4, y0 + 3), f"({'ab'[r]}) {title}", fill=(0, 0, 0))
        d.text((4, y0 + 17), caption(row, side), fill=(60, 60, 60))
        col = colours(dist, TAU, a.vmax)
        for c, view in enumerate(VIEWS):
            tile = Image.fromarray(draw(pts, nrm, centre, scale, view, a.size, color=col))
            sheet.paste(tile, (c * a.size, y0 + label_h))
            d.text((c * a.size + 4, y0 + label_h + 3), view, fill=(90, 90, 90))
    sheet.paste(legend(W, TAU, a.vmax, legend_h), (0, head_h + (a.size + label_h) * len(rows)))
    sheet.save(a.out)
    print(a.out)


if __name__ == "__main__":
    main()
