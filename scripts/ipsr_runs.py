#!/usr/bin/env python3
"""iPSR (Hou et al., SIGGRAPH 2022; github.com/houfei0801/ipsr, MIT) on the report's clouds, scored
by `nkrr metrics`: the rows that scripts/results.py reads as its iPSR peer.

    .venv-peers/bin/python scripts/ipsr_runs.py --ipsr ../ipsr/ipsr --data target/results/data \
        --sizes 500,3k,10k --out target/results/ipsr
    .venv-peers/bin/python scripts/ipsr_runs.py --ipsr ../ipsr/ipsr --data target/results/hard \
        --sizes noise,outliers,falloff,onesided --out target/results/hard/ipsr

iPSR is fetched and built beside the repository, never inside it (its own makefile:
`git clone https://github.com/houfei0801/ipsr ../ipsr && make -C ../ipsr`, commit 0cf5932 for
the report). It runs with its defaults (30 iterations, point weight 10, depth 10, 10 neighbours)
on one core (OMP_THREAD_LIMIT=1) so that its seconds are comparable from run to run; each cloud
has --timeout seconds, after which its row says so (an "error" row, which the report leaves out).

Writes OUT/NAME-SIZE.obj (iPSR writes ASCII PLY; `nkrr metrics` reads OBJ) and appends one JSON
line per cloud to OUT/ipsr.jsonl (method, shape, size, points, total_s, the metrics). Resumable:
a cloud with a row already in OUT/ipsr.jsonl is skipped, so an interrupted run goes on.
"""
import argparse
import json
import os
import subprocess
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests", "peers"))
from spsr import emit, eval_clouds, run_metrics  # noqa: E402  (the same clouds, scoring and rows as SPSR's)


def ply_to_obj(ply, obj):
    """iPSR's ASCII PLY (vertex x y z, face list) as OBJ; returns (vertices, faces)."""
    with open(ply) as f:
        nv = nf = 0
        for line in f:
            w = line.split()
            if w[:2] == ["element", "vertex"]:
                nv = int(w[2])
            elif w[:2] == ["element", "face"]:
                nf = int(w[2])
            elif w and w[0] == "end_header":
                break
        with open(obj, "w") as o:
            for _ in range(nv):
                o.write("v " + " ".join(f.readline().split()[:3]) + "\n")
            for _ in range(nf):
                w = f.readline().split()
                o.write("f " + " ".join(str(int(i) + 1) for i in w[1:1 + int(w[0])]) + "\n")
    return nv, nf


def ply_points(path):
    """The vertex count of a PLY header (the cloud's points)."""
    with open(path, "rb") as f:
        for line in f:
            w = line.split()
            if w[:2] == [b"element", b"vertex"]:
                return int(w[2])
            if w[:1] == [b"end_header"]:
                return None


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ipsr", required=True, help="the built iPSR binary (beside the repository)")
    ap.add_argument("--data", required=True, help="DATA/NAME-SIZE.ply clouds and DATA/NAME.obj truths")
    ap.add_argument("--sizes", required=True, help="comma-separated SIZEs")
    ap.add_argument("--shapes", default="", help="comma-separated NAMEs (all when empty)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--timeout", type=float, default=900, help="seconds per cloud")
    ap.add_argument("--metrics-cmd", default="target/release/nkrr metrics")
    a = ap.parse_args()
    if not os.access(a.ipsr, os.X_OK):
        sys.exit(f"ipsr_runs: {a.ipsr} is not an executable iPSR build (see this script's doc)")
    os.makedirs(a.out, exist_ok=True)
    jl = os.path.join(a.out, "ipsr.jsonl")
    done = set()
    if os.path.exists(jl):
        done = {(r["shape"], r["size"]) for r in map(json.loads, open(jl))}
    env = dict(os.environ, OMP_THREAD_LIMIT="1", OMP_NUM_THREADS="1")
    with open(jl, "a") as log:
        for size, name, cloud in eval_clouds(a.data, a.sizes, a.shapes):
            if (name, size) in done:
                continue
            ply = os.path.join(a.out, f"{name}-{size}.ply")
            row = {"method": "ipsr", "shape": name, "size": size, "points": ply_points(cloud),
                   "iters": 30, "point_weight": 10, "depth": 10, "neighbors": 10, "cores": 1}
            t0 = time.perf_counter()
            try:
                p = subprocess.run([a.ipsr, "--in", cloud, "--out", ply], env=env,
                                   capture_output=True, text=True, timeout=a.timeout)
                row["total_s"] = round(time.perf_counter() - t0, 3)
                if p.returncode != 0 or not os.path.exists(ply):
                    row["error"] = f"exit {p.returncode}: {(p.stderr or p.stdout).strip()[-300:]}"
            except subprocess.TimeoutExpired:
                row["error"] = f"no mesh within {a.timeout:.0f} s"
            if "error" not in row:
                recon = os.path.join(a.out, f"{name}-{size}.obj")
                row["vertices"], row["faces"] = ply_to_obj(ply, recon)
                os.remove(ply)
                row["recon"] = recon
                row.update(run_metrics(a.metrics_cmd, os.path.join(a.data, f"{name}.obj"), recon))
            emit(row, log)


if __name__ == "__main__":
    main()
