"""Export weights + parity fixtures (docs/network.md).

  python -m training.export --run training/runs/main
      -> assets/prior.safetensors, tests/fixtures/net/*, tests/fixtures/net_tiny/*
  python -m training.export --run ... --out-dir /tmp/x   (everything under /tmp/x instead)
"""
from __future__ import annotations

import argparse
import json
import os
import math
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import load_file, save_file
from safetensors import safe_open

from .data import normalise
from .model import Config, ConvONet
from .shapes import make_shape

ROOT = Path(__file__).resolve().parent.parent
FORMAT = "nkrr-convonet-1"
META_KEYS = ("h", "c_dim", "reso", "unet_depth", "unet_filters", "h_dec", "n_blocks_dec", "padding")


def metadata(cfg: Config, step, iou):
    md = {k: str(getattr(cfg, k)) for k in META_KEYS}
    md.update(format=FORMAT, step=str(int(step)), heldout_iou=f"{float(iou):.6f}")
    return md


def save_weights(model: ConvONet, path, step, iou):
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    sd = {k: v.detach().to(torch.float32).contiguous() for k, v in model.state_dict().items()}
    save_file(sd, str(path), metadata=metadata(model.cfg, step, iou))
    os.chmod(path, 0o644)
    return path


def load_weights(path):
    """-> (model, metadata) from a safetensors file written by save_weights."""
    with safe_open(str(path), "pt") as f:
        md = f.metadata()
    assert md["format"] == FORMAT, md.get("format")
    kw = {}
    for k, v in Config().to_dict().items():
        kw[k] = type(v)(md[k])
    model = ConvONet(Config(**kw))
    model.load_state_dict(load_file(str(path)))
    model.eval()
    return model, md


def _w(path, arr):
    np.ascontiguousarray(arr, dtype="<f4").tofile(path)


@torch.no_grad()
def write_fixtures(model: ConvONet, out_dir, cloud, queries, extra=None):
    """cloud (N, 3), queries (Q, 3), both already in normalised coordinates."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    model.eval()
    p = torch.from_numpy(np.asarray(cloud, np.float32))[None]
    q = torch.from_numpy(np.asarray(queries, np.float32))[None]
    planes = model.encode(p)  # (1, 3, C, R, R)
    feat = model.features(planes, q)  # (1, Q, C)
    logits = model.decoder(q, feat)  # (1, Q)
    cfg = model.cfg
    _w(out / "cloud.bin", p[0].numpy())
    _w(out / "queries.bin", q[0].numpy())
    _w(out / "planes.bin", planes[0].numpy())
    _w(out / "features.bin", feat[0].numpy())
    _w(out / "logits.bin", logits[0].numpy())
    info = {
        "N": int(p.shape[1]), "Q": int(q.shape[1]),
        "shapes": {"cloud": [int(p.shape[1]), 3], "queries": [int(q.shape[1]), 3],
                   "planes": [3, cfg.c_dim, cfg.reso, cfg.reso], "features": [int(q.shape[1]), cfg.c_dim],
                   "logits": [int(q.shape[1])]},
        "planes_order": ["xz", "xy", "yz"], "dtype": "f32 little-endian, no header",
        "config": cfg.to_dict(),
        "stats": {"planes_max_abs": float(planes.abs().max()), "features_max_abs": float(feat.abs().max()),
                  "logits_max_abs": float(logits.abs().max()),
                  "frac_logit_positive": float((logits > 0).float().mean())},
    }
    if extra:
        info.update(extra)
    (out / "fixture.json").write_text(json.dumps(info, indent=1) + "\n")
    return planes[0].numpy(), feat[0].numpy(), logits[0].numpy()


def fixture_inputs(n_pts, n_q, sigma=0.005, held_index=0, n_edge=0, seed=777):
    """A real cloud from held-out shape `held_index` (kind=2 seeds), normalised; queries half uniform
    in [-0.55, 0.55]^3, half near the surface; optional edge-case queries at the end."""
    s = make_shape(held_index, kind=2)
    rng = np.random.default_rng(seed)
    idx = rng.choice(len(s["surf"]), n_pts, replace=False)
    cloud = s["surf"][idx].astype(np.float32) + rng.normal(size=(n_pts, 3)).astype(np.float32) * sigma
    nq = n_q - n_edge
    nu = nq // 2
    qu = rng.uniform(-0.55, 0.55, (nu, 3)).astype(np.float32)
    jn = rng.choice(len(s["surf"]), nq - nu, replace=False)
    qn = s["surf"][jn].astype(np.float32) + rng.normal(size=(nq - nu, 3)).astype(np.float32) * 0.02
    cloud, qu, qn = normalise(cloud, qu, qn)
    q = np.concatenate([qu, qn])
    if n_edge:
        edge = np.array([[0.7, -0.7, 0.0], [-0.55, 0.55, 0.55], [0.55, 0.5499, -0.6], [0.0, 0.0, 0.0],
                         [-1.0, 1.0, 2.0], [0.25, -0.25, 0.125]], np.float32)[:n_edge]
        q = np.concatenate([q, edge])
    return cloud.astype(np.float32), q.astype(np.float32), s["family"]


def tiny_model(seed=4242):
    cfg = Config(h=12, c_dim=8, reso=8, unet_depth=2, unet_filters=4, h_dec=16, n_blocks_dec=3, padding=0.1)
    g = torch.Generator().manual_seed(seed)
    m = ConvONet(cfg)
    with torch.no_grad():
        for name, p in m.named_parameters():
            if p.dim() == 1:
                p.copy_(torch.randn(p.shape, generator=g) * 0.2)
            else:
                fan_in = int(np.prod(p.shape[1:]))
                if "upconv" in name:  # ConvTranspose2d weight [in, out, k, k]
                    fan_in = p.shape[0]
                p.copy_(torch.randn(p.shape, generator=g) * (1.5 / math.sqrt(fan_in)))
    return m.eval()


def export_tiny(out_dir):
    m = tiny_model()
    out = Path(out_dir)
    save_weights(m, out / "weights.safetensors", 0, 0.0)
    cloud, q, fam = fixture_inputs(50, 20, n_edge=6)
    write_fixtures(m, out, cloud, q, extra={"weights": "weights.safetensors", "source": f"held-out shape 0 ({fam}), "
                                            "random-init tiny model; last 6 queries are edge cases (outside the padded cube, on the border)"})


def load_ckpt(path):
    st = torch.load(path, weights_only=False, map_location="cpu")
    m = ConvONet(Config(**st["config"]))
    m.load_state_dict(st["model"])
    return m.eval(), st


def last_iou(run_dir, max_step=None):
    """Held-out IoU of the latest evaluation at or before max_step (the checkpoint's step)."""
    p = Path(run_dir) / "metrics.jsonl"
    iou = float("nan")
    if p.exists():
        for line in p.read_text().splitlines():
            try:
                d = json.loads(line)
            except json.JSONDecodeError:
                continue
            if d.get("event") == "eval" and (max_step is None or d["step"] <= max_step):
                iou = d["heldout_iou"]
    return iou


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--run", default=str(ROOT / "training" / "runs" / "main"))
    ap.add_argument("--out-dir", default=None, help="root for assets/ and tests/ (default: the repo)")
    ap.add_argument("--n-pts", type=int, default=3000)
    ap.add_argument("--n-query", type=int, default=2048)
    a = ap.parse_args(argv)
    root = Path(a.out_dir) if a.out_dir else ROOT
    model, st = load_ckpt(Path(a.run) / "ckpt.pt")
    iou = last_iou(a.run, st["step"])
    w = save_weights(model, root / "assets" / "prior.safetensors", st["step"], iou)
    # round-trip the file: fixtures are computed from the weights as stored
    model, md = load_weights(w)
    cloud, q, fam = fixture_inputs(a.n_pts, a.n_query)
    write_fixtures(model, root / "tests" / "fixtures" / "net", cloud, q,
                   extra={"weights": "assets/prior.safetensors", "step": st["step"], "heldout_iou": iou,
                          "source": f"held-out shape 0 ({fam}), {a.n_pts} points, noise 0.005, normalised; "
                                    "queries: first half uniform in [-0.55,0.55]^3, second half surface + N(0, 0.02^2)"})
    export_tiny(root / "tests" / "fixtures" / "net_tiny")
    print(f"wrote {w} ({w.stat().st_size / 1e6:.2f} MB, step {st['step']}, held-out IoU {iou:.4f}) and fixtures under "
          f"{root / 'tests' / 'fixtures'}")


if __name__ == "__main__":
    main()
