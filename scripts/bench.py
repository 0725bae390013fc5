#!/usr/bin/env python3
"""The speed benchmark: nkrr's per-stage times on clouds of 500, 3k, 10k and 100k points and the
ratio of its end-to-end time to screened Poisson's on the same clouds, in the same run, so the
figures survive a change of machine.

    scripts/bench.sh [--sizes 500,3k,10k,100k] [--repeat 3] [--methods nkrr,network]
                     [-- nkrr reconstruct options]

The clouds are of one eval mesh (spot, a report shape of docs/fit.md; tests/data/eval) with the
eval protocol's noise: NAME-500/3k/10k.ply of target/results/data and 100k points made the same
way (scripts/results_clouds.py's scale clouds). nkrr: `/usr/bin/time nkrr reconstruct` (a whole
process: start-up, reading, the adapter, every stage and the writing; the stage times are the
CLI's own), the median of --repeat runs. Screened Poisson: `tests/peers/spsr.py --plain` on
one cloud (Open3D, PCA normals + orientation + depth-8 Poisson), also timed as a whole process
(Python's start-up, Open3D's import, reading and writing included), run right after each nkrr
run so that the two see the same machine; the ratio is the median of the runs' ratios (issue 27).
Prints a Markdown table and writes target/bench/bench.json.
"""
import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SIZES = ["500", "3k", "10k", "100k"]


def cloud_path(shape, size):
    """The SIZE cloud of SHAPE (100k: spot's scale cloud only)."""
    if size == "100k":
        if shape != "spot":
            raise SystemExit("--sizes 100k: only spot has a 100k cloud (scripts/results_clouds.py)")
        return "target/results/data/scale/scale-100000.ply"
    return f"target/results/data/{shape}-{size}.ply"
STAGES = ["features", "pairs", "tuning", "mesh", "poisson", "fit"]


def log(msg):
    print(f"[bench] {msg}", file=sys.stderr, flush=True)


def run_nkrr(cloud, method, options, out_dir):
    """One `nkrr reconstruct`: (wall seconds, {stage: seconds})."""
    out = os.path.join(out_dir, "bench-out.glb")
    cmd = ["/usr/bin/time", "-f", "wall %e", "target/release/nkrr", "reconstruct", cloud, "-o", out,
           "--method", method] + options
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{p.stderr[-2000:]}")
    wall = float(re.findall(r"^wall ([0-9.]+)$", p.stderr, re.M)[-1])
    return wall, parse_summary(p.stdout + p.stderr)


def parse_summary(output):
    """{stage: seconds} from the summary line of `nkrr reconstruct`'s OUTPUT (stdout and stderr:
    progress goes to stderr, the summary line "OUT: … features 0.12s, … (total 1.23s); …" to
    stdout); the process's own total is under "total"."""
    summary = [line for line in output.splitlines() if "(total " in line][-1]
    return {k: float(v) for k, v in re.findall(r"\b([a-z]+) ([0-9.]+)s\b", summary)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="500,3k,10k,100k")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--methods", default="nkrr,network")
    ap.add_argument("--shapes", default="spot", help="eval shapes, each on every size (500/3k/10k)")
    ap.add_argument("--out", default="target/bench")
    ap.add_argument("options", nargs="*", help="nkrr reconstruct options (after --)")
    a = ap.parse_args()
    sizes = a.sizes.split(",")
    for s in sizes:
        if s not in SIZES:
            raise SystemExit(f"--sizes: {s} is not one of {', '.join(SIZES)}")
    shapes = a.shapes.split(",")
    out = os.path.join(ROOT, a.out)
    data = os.path.join(out, "data")
    os.makedirs(data, exist_ok=True)
    # spsr.py reads DATA/NAME-SIZE.ply: link the clouds under one name.
    for shape in shapes:
        for s in sizes:
            link = os.path.join(data, f"{shape}-{s}.ply")
            if os.path.lexists(link):
                os.remove(link)
            os.symlink(os.path.join(ROOT, cloud_path(shape, s)), link)

    def run_spsr(shape, s, tmp):
        """One whole `spsr.py --plain` process on the SIZE cloud: wall seconds."""
        cmd = ["/usr/bin/time", "-f", "wall %e", os.path.join(ROOT, ".venv-peers/bin/python"), "tests/peers/spsr.py",
               "--plain", "--data", data, "--sizes", s, "--shapes", shape, "--out", os.path.join(tmp, "spsr")]
        p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
        if p.returncode != 0:
            raise SystemExit(f"{' '.join(cmd)} failed:\n{p.stderr[-2000:]}")
        return float(re.findall(r"^wall ([0-9.]+)$", p.stderr, re.M)[-1])

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for shape, s in [(shape, s) for s in sizes for shape in shapes]:
            cloud = os.path.join(ROOT, cloud_path(shape, s))
            for method in a.methods.split(","):
                runs, spsr = [], []
                for i in range(a.repeat):
                    log(f"{method} on {shape}-{s}, then screened Poisson, run {i + 1}/{a.repeat}")
                    runs.append(run_nkrr(cloud, method, a.options, tmp))
                    spsr.append(run_spsr(shape, s, tmp))
                walls = [w for w, _ in runs]
                median = statistics.median(walls)
                stages = runs[walls.index(median)][1] if median in walls else runs[0][1]
                ratios = [w / p for w, p in zip(walls, spsr)]
                rows.append({"shape": shape, "size": s, "method": method, "wall_s": median, "runs_s": walls,
                             "stages_s": stages, "spsr_s": statistics.median(spsr), "spsr_runs_s": spsr,
                             "ratio": statistics.median(ratios), "ratios": ratios})

    print(f"| shape | points | method | {' | '.join(STAGES)} | end to end s (median of {a.repeat}) | screened Poisson end to end s | ratio (median of pairs) |")
    print("|---" * (len(STAGES) + 6) + "|")
    for r in rows:
        st = " | ".join(f"{r['stages_s'][k]:.2f}" if k in r["stages_s"] else "-" for k in STAGES)
        print(f"| {r['shape']} | {r['size']} | {r['method']} | {st} | {r['wall_s']:.2f} | {r['spsr_s']:.2f} | {r['ratio']:.1f}x |")
    with open(os.path.join(out, "bench.json"), "w") as f:
        json.dump({"options": a.options, "repeat": a.repeat, "cores": os.cpu_count(), "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
