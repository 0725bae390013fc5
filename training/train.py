"""Train the ConvONet-lite prior on the procedural shape cache.

  python -m training.train --name main --total-minutes 90 --max-minutes 90

Resumes automatically from training/runs/<name>/ckpt.pt. `--total-minutes` is the run's full
wall-clock training budget (summed over resumes; the learning-rate schedule is a function of the
fraction of it used), `--max-minutes` bounds this invocation's wall clock.
Logs: runs/<name>/metrics.jsonl (one JSON object per line), stdout (log.txt when detached).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import random
import time
from functools import partial
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as Fn

from .data import CACHE, InlineGenerator, Pool, Scan, heldout_set, make_batch
from .model import Config, ConvONet

RUNS = Path(__file__).resolve().parent / "runs"


def lr_at(frac, base, warm=0.02, final=0.05):
    """Linear warm-up, constant to 60 % of the budget, cosine to final*base at 100 %."""
    if frac < warm:
        return base * max(frac / warm, 0.05)
    if frac < 0.6:
        return base
    t = min((frac - 0.6) / 0.4, 1.0)
    return base * (final + (1 - final) * 0.5 * (1 + math.cos(math.pi * t)))


@torch.no_grad()
def evaluate(model, held, bs=8, device="cpu"):
    model.eval()
    inter = union = 0.0
    ious, losses = [], []
    for i in range(0, len(held["cloud"]), bs):
        p = torch.from_numpy(held["cloud"][i:i + bs]).to(device)
        q = torch.from_numpy(held["q"][i:i + bs]).to(device)
        y = torch.from_numpy(held["occ"][i:i + bs].astype(np.float32)).to(device)
        lg = model(p, q)
        losses.append(Fn.binary_cross_entropy_with_logits(lg, y, reduction="none").mean(1))
        pr = lg > 0
        yt = y > 0.5
        it = (pr & yt).sum(1).float()
        un = (pr | yt).sum(1).float()
        ious.append(it / un.clamp(min=1))
        inter += it.sum().item()
        union += un.sum().item()
    model.train()
    return float(torch.cat(ious).mean()), float(torch.cat(losses).mean())


def save_ckpt(path, state):
    tmp = path.with_suffix(".tmp")
    torch.save(state, tmp)
    os.replace(tmp, path)


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--name", default="main")
    ap.add_argument("--total-minutes", type=float, default=90.0, help="wall-clock training budget over all resumes")
    ap.add_argument("--max-minutes", type=float, default=None, help="wall-clock limit of this invocation")
    ap.add_argument("--max-steps", type=int, default=None)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--n-query", type=int, default=2048)
    ap.add_argument("--pts-min", type=int, default=500)
    ap.add_argument("--pts-max", type=int, default=10000)
    ap.add_argument("--noise-max", type=float, default=0.01)
    ap.add_argument("--gen-every", type=int, default=8, help="generate one new shape every N steps (0: off)")
    ap.add_argument("--eval-every", type=int, default=100)
    ap.add_argument("--ckpt-minutes", type=float, default=5.0)
    ap.add_argument("--heldout", type=int, default=32)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cache", default=str(CACHE))
    ap.add_argument("--runs", default=str(RUNS))
    ap.add_argument("--device", default="cpu", help="torch device: cpu or cuda")
    ap.add_argument("--init", default=None, help="fresh run: start from this checkpoint's model weights")
    ap.add_argument("--gen-workers", type=int, default=0,
                    help="generate chunks in N background processes (replaces --gen-every)")
    ap.add_argument("--gen-chunks", type=int, default=2000, help="chunk ids the background workers may fill")
    ap.add_argument("--min-pool", type=int, default=32, help="with --gen-workers: wait for this many shapes")
    ap.add_argument("--shape-kind", type=int, default=1,
                    help="training stream (shapes.STREAMS): 1 the first prior's, 3 with the new families")
    ap.add_argument("--aug-falloff", type=float, default=0.0, help="share of clouds with a density falloff")
    ap.add_argument("--aug-outliers", type=float, default=0.0, help="share of clouds with stray points")
    ap.add_argument("--aug-onesided", type=float, default=0.0, help="share of clouds seen from one side")
    for k, v in Config().to_dict().items():
        ap.add_argument("--" + k.replace("_", "-"), type=type(v), default=v)
    a = ap.parse_args(argv)

    torch.set_num_threads(a.threads)
    dev = torch.device(a.device)
    workers = None
    if a.gen_workers:
        # Fork the generators before CUDA is initialised; each writes whole chunk files that the
        # pool picks up on refresh, so the training loop never waits on shape generation.
        import multiprocessing as mp
        from .data import gen_chunk, missing_chunks
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        workers = mp.get_context("fork").Pool(a.gen_workers)
        gen_async = workers.map_async(partial(gen_chunk, cache=a.cache, kind=a.shape_kind),
                                      missing_chunks(a.gen_chunks, a.cache),
                                      chunksize=1)
    run = Path(a.runs) / a.name
    run.mkdir(parents=True, exist_ok=True)
    ckpt_path = run / "ckpt.pt"
    metrics = open(run / "metrics.jsonl", "a")

    def log(**kw):
        metrics.write(json.dumps(kw) + "\n")
        metrics.flush()

    if ckpt_path.exists():
        st = torch.load(ckpt_path, weights_only=False, map_location="cpu")
        cfg = Config(**st["config"])
        model = ConvONet(cfg)
        model.load_state_dict(st["model"])
        opt = torch.optim.Adam(model.parameters(), lr=a.lr)
        opt.load_state_dict(st["opt"])
        step, elapsed = st["step"], st["elapsed"]
        args0 = st["args"]
        rng = np.random.default_rng()
        rng.bit_generator.state = st["np_rng"]
        torch.set_rng_state(st["torch_rng"])
        random.setstate(st["py_rng"])
        print(f"resumed {ckpt_path} at step {step}, {elapsed / 60:.1f} train-min", flush=True)
        a.total_minutes = args0["total_minutes"]
        a.lr = args0["lr"]
        model.to(dev)
        opt.load_state_dict(st["opt"])  # again, so the moments follow the parameters' device
    else:
        cfg = Config(**{k: getattr(a, k) for k in Config().to_dict()})
        torch.manual_seed(a.seed)
        random.seed(a.seed)
        rng = np.random.default_rng(a.seed)
        if a.init and a.init.endswith(".safetensors"):
            # the shipped prior (assets/prior.safetensors): a clone has it, not the checkpoint
            from .export import load_weights
            model, md = load_weights(a.init)
            model.train()
            cfg = model.cfg
            print(f"initialised from {a.init} (step {md['step']}, held-out IoU {md['heldout_iou']})", flush=True)
        elif a.init:
            st0 = torch.load(a.init, weights_only=False, map_location="cpu")
            cfg = Config(**st0["config"])
            model = ConvONet(cfg)
            model.load_state_dict(st0["model"])
            print(f"initialised from {a.init} (step {st0['step']})", flush=True)
        else:
            model = ConvONet(cfg)
        model.to(dev)
        opt = torch.optim.Adam(model.parameters(), lr=a.lr)
        step, elapsed = 0, 0.0
        args0 = vars(a).copy()
        log(event="start", config=cfg.to_dict(), args=args0, machine=platform.platform(),
            cpu=platform.processor() or platform.machine(), cores=os.cpu_count(),
            torch=torch.__version__, device=str(dev),
            gpu=torch.cuda.get_device_name(dev) if dev.type == "cuda" else None, params=sum(p.numel() for p in model.parameters()))

    pool = Pool(a.cache)
    while workers is not None and len(pool) < a.min_pool and not gen_async.ready():
        time.sleep(1.0)
        pool.refresh()
    gen = InlineGenerator(a.cache, kind=args0.get("shape_kind", 1))
    scan = Scan(args0.get("aug_falloff", 0.0), args0.get("aug_outliers", 0.0), args0.get("aug_onesided", 0.0))
    held = heldout_set(a.heldout, cache=a.cache)
    print(f"config {cfg.to_dict()}; params {sum(p.numel() for p in model.parameters())}; "
          f"pool {len(pool)} shapes; held-out {len(held['cloud'])}", flush=True)
    if len(pool) == 0:
        raise SystemExit("empty pool: run python -m training.gen_cache first")

    t_start = time.time()
    t_ckpt = time.time()
    budget = a.total_minutes * 60
    limit = a.max_minutes * 60 if a.max_minutes else float("inf")
    run_loss, run_n, t_last = 0.0, 0, time.time()

    def state():
        return dict(model=model.state_dict(), opt=opt.state_dict(), step=step,
                    elapsed=elapsed, config=cfg.to_dict(), args=args0, np_rng=rng.bit_generator.state,
                    torch_rng=torch.get_rng_state(), py_rng=random.getstate(), pool_size=len(pool))

    if step == 0:
        iou, hl = evaluate(model, held, device=dev)
        log(event="eval", step=0, elapsed=0.0, heldout_iou=iou, heldout_loss=hl, pool=len(pool))
    reason = "budget"
    elapsed0 = elapsed

    def next_batch():
        return make_batch(pool, rng, a.batch, n_q=a.n_query, noise_max=a.noise_max,
                          pts_range=(a.pts_min, a.pts_max), scan=scan)

    from concurrent.futures import ThreadPoolExecutor
    batcher = ThreadPoolExecutor(1)
    prefetch = None
    while True:
        elapsed = elapsed0 + (time.time() - t_start)  # wall time of training, summed over resumes
        frac = elapsed / budget
        if frac >= 1.0:
            reason = "budget"
            break
        if time.time() - t_start >= limit:
            reason = "max-minutes"
            break
        if a.max_steps is not None and step >= a.max_steps:
            reason = "max-steps"
            break
        lr = lr_at(frac, a.lr)
        for g in opt.param_groups:
            g["lr"] = lr
        if prefetch is None:
            P, Q, Y = next_batch()
        else:
            P, Q, Y = prefetch.result()
        # Build the next batch on a CPU thread while torch works on this one.
        prefetch = batcher.submit(next_batch)
        logits = model(torch.from_numpy(P).to(dev), torch.from_numpy(Q).to(dev))
        loss = Fn.binary_cross_entropy_with_logits(logits, torch.from_numpy(Y).to(dev))
        opt.zero_grad(set_to_none=True)
        loss.backward()
        gn = torch.nn.utils.clip_grad_norm_(model.parameters(), 5.0)
        opt.step()
        step += 1
        lv = loss.item()
        if not math.isfinite(lv):
            raise SystemExit(f"non-finite loss at step {step}")
        run_loss += lv
        run_n += 1
        if workers is not None:
            if step % 25 == 0:
                pool.refresh()
        elif a.gen_every and step % a.gen_every == 0:
            if gen.step():
                pool.refresh()
        if step % 10 == 0:
            now = time.time()
            sps = (now - t_last) / run_n
            log(event="train", step=step, elapsed=elapsed, loss=run_loss / run_n, lr=lr,
                grad_norm=float(gn), s_per_step=sps, n_pts=int(P.shape[1]), pool=len(pool))
            print(f"step {step} loss {run_loss / run_n:.4f} lr {lr:.2e} {sps:.2f}s/step "
                  f"pool {len(pool)} train-min {elapsed / 60:.1f}", flush=True)
            run_loss, run_n, t_last = 0.0, 0, now
        if step % a.eval_every == 0:
            te = time.time()
            iou, hl = evaluate(model, held, device=dev)
            log(event="eval", step=step, elapsed=elapsed, heldout_iou=iou, heldout_loss=hl, pool=len(pool))
            print(f"eval step {step}: held-out IoU {iou:.4f} loss {hl:.4f} ({time.time() - te:.1f}s)", flush=True)
            t_last += time.time() - te
        if time.time() - t_ckpt >= a.ckpt_minutes * 60:
            save_ckpt(ckpt_path, state())
            t_ckpt = time.time()
    elapsed = elapsed0 + (time.time() - t_start)
    iou, hl = evaluate(model, held, device=dev)
    log(event="eval", step=step, elapsed=elapsed, heldout_iou=iou, heldout_loss=hl, pool=len(pool))
    save_ckpt(ckpt_path, state())
    if workers is not None:
        workers.terminate()
    log(event="stop", step=step, elapsed=elapsed, reason=reason, heldout_iou=iou)
    print(f"stopped ({reason}) at step {step}, {elapsed / 60:.1f} train-min, held-out IoU {iou:.4f}", flush=True)


if __name__ == "__main__":
    main()
