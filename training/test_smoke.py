"""Smoke test of the training pipeline (< 2 min on 2 cores):
    .venv/bin/python -m pytest -q training/test_smoke.py     (or: .venv/bin/python -m training.test_smoke)
"""
from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np
import torch

import training  # noqa: F401  (sets OMP_WAIT_POLICY)
from training import data, export, shapes, train
from training.model import Config, ConvONet


def test_shapes_labels_consistent():
    # kind 9: the first recipe's families; kind 4: the second stream's new ones (revolution,
    # tubes, flaps, machined parts: seeds 0-7 cover all four)
    cases = [(3, 9), (11, 9)] + [(i, 4) for i in range(8)]
    fams = set()
    for seed, kind in cases:
        s = shapes.make_shape(seed, kind=kind, grid=96, n_surf=4000, n_uni=4000, n_near=4000)
        fams.add(s["family"])
        sh = s["shape"]
        surf = s["surf"].astype(np.float32)
        nrm = s["normals"].astype(np.float32)
        # normalised: bbox centred, longest side 1
        lo, hi = surf.min(0), surf.max(0)
        # (thin tips of the new families get few of 4000 samples, so the samples' box is looser)
        tol = 0.02 if kind == 9 else 0.04
        assert np.abs((lo + hi) / 2).max() < tol and abs((hi - lo).max() - 1) < tol, (seed, kind, lo, hi)
        # surface points have near-zero SDF (marching cubes on a 96 grid: < ~1 voxel)
        d = np.abs(sh.sdf(surf))
        # (flaps: the flat-ellipsoid bound is far from Lipschitz, so marching cubes places some
        # rim vertices up to a few voxels off; the labels stay exact)
        q99 = 0.03 if s["family"] == "flaps" else 0.02
        assert np.median(d) < 0.004 and np.quantile(d, 0.99) < q99, (s["family"], np.median(d), d.max())
        # normals point outward: a step along +n is outside, along -n is inside (most points)
        # (flaps are a few voxels thick: a step of 0.003 from a misplaced rim vertex can cross one)
        share = 0.85 if s["family"] == "flaps" else 0.9
        assert np.mean(sh.sdf(surf + 0.003 * nrm) > 0) > share
        assert np.mean(sh.sdf(surf - 0.003 * nrm) < 0) > share
        # labels are the SDF sign of the stored (f16) coordinates
        assert np.array_equal(s["occ_uni"], sh.sdf(s["quni"].astype(np.float32)) < 0)
        assert 0 < s["occ_near"].mean() < 1
        assert np.abs(s["quni"].astype(np.float32)).max() <= 0.55 + 1e-3
    assert {"lathe", "tube", "flaps", "cad"} <= fams, fams


def test_degraded_clouds():
    """Scan: the falloff thins one end, stray points land off the surface, one-sided keeps the
    side facing the view."""
    s = shapes.make_shape(5, kind=9, grid=64, n_surf=6000, n_uni=1000, n_near=1000)
    rng = np.random.default_rng(0)
    flat = data._draw_points(s, rng, 2000, data.Scan())
    fall = data._draw_points(s, rng, 2000, data.Scan(falloff=1.0, falloff_max=55.0, fixed=True))
    assert len(flat) == len(fall) == 2000
    # along some axis the falloff cloud is much denser at one end than the uniform one
    ratios = []
    for d in np.eye(3):
        t = s["surf"].astype(np.float32) @ d
        lo, hi = np.quantile(t, 0.2), np.quantile(t, 0.8)
        a = lambda p: max(1, np.sum(p @ d <= lo)) / max(1, np.sum(p @ d >= hi))  # noqa: E731
        ratios.append(max(a(fall) / a(flat), a(flat) / a(fall)))
    assert max(ratios) > 3, ratios
    # stray points: isolated (their nearest neighbour far off), where the clean cloud has none
    from scipy.spatial import cKDTree

    def isolated(p):
        d, _ = cKDTree(p).query(p, k=2)
        return int(np.sum(d[:, 1] > 0.05))

    clean, _, _ = data.make_sample(s, rng, 1000, 0.0, 64, augment=False)
    stray = [data.make_sample(s, rng, 1000, 0.0, 64, augment=False,
                              scan=data.Scan(outliers=1.0, outliers_max=0.1))[0] for _ in range(8)]
    assert isolated(clean) <= 10, isolated(clean)
    assert max(isolated(p) for p in stray) >= 30, [isolated(p) for p in stray]


def test_train_export_roundtrip():
    with tempfile.TemporaryDirectory() as td:
        td = Path(td)
        cache = td / "cache"
        (cache / "train").mkdir(parents=True)
        shp = [shapes.make_shape(i, kind=9, grid=64, n_surf=3000, n_uni=2000, n_near=2000) for i in range(4)]
        data._save_npz(cache / "train" / "chunk_00000.npz", data.stack_shapes(shp))
        # tiny held-out set written in place of the default one
        d = dict(cloud=np.stack([data.normalise(s["surf"][:500].astype(np.float32))[0] for s in shp[:2]]),
                 q=np.stack([s["quni"][:1000].astype(np.float32) for s in shp[:2]]),
                 occ=np.stack([s["occ_uni"][:1000] for s in shp[:2]]), family=np.array(["a", "b"]))
        data._save_npz(cache / "heldout_2.npz", d)
        args = ["--name", "smoke", "--runs", str(td / "runs"), "--cache", str(cache), "--heldout", "2",
                "--max-steps", "4", "--batch", "2", "--pts-min", "300", "--pts-max", "600", "--n-query", "256",
                "--gen-every", "0", "--eval-every", "2", "--reso", "16", "--unet-depth", "2",
                "--unet-filters", "8", "--h", "16", "--c-dim", "8", "--h-dec", "16"]
        train.main(args)
        log = [json.loads(line) for line in (td / "runs" / "smoke" / "metrics.jsonl").read_text().splitlines()]
        assert all(np.isfinite(e["loss"]) for e in log if e["event"] == "train")
        stop = [e for e in log if e["event"] == "stop"][0]
        assert stop["step"] == 4 and np.isfinite(stop["heldout_iou"])
        # resume: runs 2 more steps from the checkpoint
        train.main(args[:9] + ["6"] + args[10:])
        log = [json.loads(line) for line in (td / "runs" / "smoke" / "metrics.jsonl").read_text().splitlines()]
        assert [e for e in log if e["event"] == "stop"][-1]["step"] == 6

        export.main(["--run", str(td / "runs" / "smoke"), "--out-dir", str(td / "out"), "--n-pts", "400",
                     "--n-query", "64"])
        w = td / "out" / "assets" / "prior.safetensors"
        model, md = export.load_weights(w)
        assert md["format"] == "nkrr-convonet-1" and md["step"] == "6"
        assert (md["reso"], md["unet_depth"], md["unet_filters"], md["c_dim"], md["h"], md["h_dec"],
                md["n_blocks_dec"], md["padding"]) == ("16", "2", "8", "8", "16", "16", "5", "0.1")
        for fx, m in (("net", model), ("net_tiny", None)):
            fdir = td / "out" / "tests" / "fixtures" / fx
            info = json.loads((fdir / "fixture.json").read_text())
            if m is None:
                m, _ = export.load_weights(fdir / "weights.safetensors")
            rd = lambda n: np.fromfile(fdir / n, dtype="<f4")  # noqa: E731
            cloud = rd("cloud.bin").reshape(info["N"], 3)
            q = rd("queries.bin").reshape(info["Q"], 3)
            with torch.no_grad():
                pl = m.encode(torch.from_numpy(cloud)[None])
                ft = m.features(pl, torch.from_numpy(q)[None])
                lg = m.decoder(torch.from_numpy(q)[None], ft)
            np.testing.assert_allclose(pl[0].numpy().ravel(), rd("planes.bin"), atol=1e-5)
            np.testing.assert_allclose(ft[0].numpy().ravel(), rd("features.bin"), atol=1e-5)
            np.testing.assert_allclose(lg[0].numpy(), rd("logits.bin"), atol=1e-5)
            assert list(pl.shape[1:]) == info["shapes"]["planes"]


def test_local_pool_and_bilinear_reference():
    """Check the vectorised scatter/gather against a naive per-point reference on the tiny model."""
    m = export.tiny_model()
    cfg = m.cfg
    rng = np.random.default_rng(0)
    p = torch.from_numpy(rng.uniform(-0.5, 0.5, (1, 40, 3)).astype(np.float32))
    R = cfg.reso
    enc = m.encoder
    with torch.no_grad():
        planes = enc(p)[0]  # (3, C, R, R)
        # naive reference
        uv = [(torch.clamp(p[0, :, a] / 1.1 + 0.5, 0, 1 - 1e-5), torch.clamp(p[0, :, b] / 1.1 + 0.5, 0, 1 - 1e-5))
              for a, b in ((0, 2), (0, 1), (1, 2))]
        cells = [(torch.floor(u * R).long(), torch.floor(v * R).long()) for u, v in uv]
        net = enc.blocks[0](enc.fc_pos(p[0]))
        for blk in enc.blocks[1:]:
            pooled = torch.zeros_like(net)
            for i in range(net.shape[0]):
                for ix, iy in cells:
                    same = (ix == ix[i]) & (iy == iy[i])
                    pooled[i] += net[same].max(0).values
            net = blk(torch.cat([net, pooled], -1))
        c = enc.fc_c(net)
        ref = torch.zeros(3, cfg.c_dim, R, R)
        for k, (ix, iy) in enumerate(cells):
            for y in range(R):
                for x in range(R):
                    s = (ix == x) & (iy == y)
                    if s.any():
                        ref[k, :, y, x] = c[s].mean(0)
    torch.testing.assert_close(planes, ref, atol=1e-5, rtol=1e-5)
    # bilinear sampling vs torch grid_sample(align_corners=True, border)
    pl = torch.randn(1, 3, cfg.c_dim, R, R)
    q = torch.from_numpy(rng.uniform(-0.6, 0.6, (1, 50, 3)).astype(np.float32))
    f = m.features(pl, q)[0]
    ref = 0
    for k, (a, b) in enumerate(((0, 2), (0, 1), (1, 2))):
        u = torch.clamp(q[0, :, a] / 1.1 + 0.5, 0, 1 - 1e-5)
        v = torch.clamp(q[0, :, b] / 1.1 + 0.5, 0, 1 - 1e-5)
        grid = torch.stack([2 * u - 1, 2 * v - 1], -1)[None, :, None]
        ref = ref + torch.nn.functional.grid_sample(pl[:, k], grid, align_corners=True,
                                                    padding_mode="border")[0, :, :, 0].T
    torch.testing.assert_close(f, ref, atol=1e-5, rtol=1e-4)


if __name__ == "__main__":
    test_shapes_labels_consistent()
    test_local_pool_and_bilinear_reference()
    test_train_export_roundtrip()
    print("ok")
