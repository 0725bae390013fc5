#!/usr/bin/env python3
"""The tuning measurements of docs/speed.md: `nkrr eval` of nkrr on the eval clouds (500 / 3k /
10k points) under each tuning configuration, then the tables, one for the shapes the settings
were chosen on (cow, fandisk, suzanne) and one for the shapes they are reported on (spot,
stanford-bunny, teapot).

    python3 scripts/speed_report.py [--work target/speed] > tables.md

Resumable: each configuration's eval is kept as WORK/NAME.json and skipped when present. Times
are left out: the evals may run beside other work; scripts/bench.sh measures time.
Needs target/release/nkrr and the clouds of scripts/results_clouds.py in target/results/data.
"""
import argparse
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TUNE = ["cow", "fandisk", "suzanne"]
REPORT = ["spot", "stanford-bunny", "teapot"]
PAPER = ["--all-pairs", "--lr", "0.1", "--steps", "100", "--select-by", "training"]
# (name, label, flags, shapes, sizes)
CONFIGS = [
    ("paper", "paper: all pairs, lr 0.1, 100 steps, lowest training error", PAPER, TUNE + REPORT, "500,3k,10k"),
    ("est4000", "4000 pairs estimating all (`full_n`), lr 0.1, 100 steps",
     ["--lr", "0.1", "--steps", "100", "--select-by", "training"], TUNE, "3k,10k"),
    ("est4000-lr03", "4000 pairs estimating all, lr 0.3, 30 steps", ["--select-by", "training"], TUNE + REPORT, "500,3k,10k"),
    ("est2000-lr03", "2000 pairs estimating all, lr 0.3, 30 steps", ["--tune-pairs", "2000", "--select-by", "training"], TUNE, "3k,10k"),
    ("default", "**default**: 4000 pairs estimating all, lr 0.3, at most 30 steps, held-out error (selection and stop)", [], TUNE + REPORT, "500,3k,10k"),
    ("default-s100", "the default with at most 100 steps", ["--steps", "100"], TUNE, "500,3k,10k"),
]


def run(work, name, flags, shapes, sizes):
    out = os.path.join(work, name)
    if os.path.exists(out + ".json"):
        return
    print(f"[speed_report] {name}: nkrr eval {' '.join(flags)}", file=sys.stderr, flush=True)
    subprocess.run(["target/release/nkrr", "eval", "target/results/data", "--sizes", sizes, "--methods", "nkrr",
                    "--shapes", ",".join(shapes), "--out", out + ".tmp"] + flags, cwd=ROOT, check=True,
                   stdout=subprocess.DEVNULL)
    os.replace(out + ".tmp.json", out + ".json")
    os.replace(out + ".tmp.md", out + ".md")


def load(work, name):
    return {(r["shape"], r["size"]): r for r in json.load(open(os.path.join(work, name + ".json")))["runs"]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", default="target/speed")
    a = ap.parse_args()
    work = os.path.join(ROOT, a.work)
    os.makedirs(work, exist_ok=True)
    for name, _, flags, shapes, sizes in CONFIGS:
        run(work, name, flags, shapes, sizes)
    paper = load(work, "paper")
    for title, shapes in [("Tuning shapes (cow, fandisk, suzanne): the settings were chosen on these", TUNE),
                          ("Report shapes (spot, stanford-bunny, teapot): measured once the default was chosen", REPORT)]:
        print(f"### {title}\n")
        print("| tuning | points | CD1 ×100 | F-score | NC | clouds worse than the paper's tuning by > 0.01 CD1 ×100 |")
        print("|---|---|---|---|---|---|")
        for name, label, _, cfg_shapes, _ in CONFIGS:
            t = load(work, name)
            for size in ["500", "3k", "10k"]:
                ks = [(s, size) for s in shapes if (s, size) in t]
                if not ks or len(ks) < len(shapes):
                    continue
                mean = lambda f: sum(t[k][f] for k in ks) / len(ks)
                worse = [k[0] for k in ks if t[k]["cd1x100"] > paper[k]["cd1x100"] + 0.01]
                print(f"| {label} | {size} | {mean('cd1x100'):.4f} | {mean('fscore'):.4f} | {mean('nc'):.4f} | "
                      f"{', '.join(worse) or '–'} |")
        print()


if __name__ == "__main__":
    main()
