#!/usr/bin/env python3
"""Compares `nkrr eval` JSON files cloud by cloud: per size, the mean CD1 x100, F-score and NC of
each file's runs of one method, and how many clouds each file wins against the first by more
than the metric noise (0.01 CD1 x100).

    python3 scripts/compare_evals.py BASE.json OTHER.json [...] [--method nkrr]
"""
import json
import sys
from collections import defaultdict


def runs(path, method):
    data = json.load(open(path))
    return {(r["shape"], r["size"]): r for r in data["runs"] if r["method"] == method}


def size_key(size):
    """Point counts (500, 3k) in order, then the harder set's named clouds (falloff, noise) by name."""
    try:
        return (0, float(size.replace("k", "e3")), "")
    except ValueError:
        return (1, 0.0, size)


def main(argv):
    method = "nkrr"
    if "--method" in argv:
        i = argv.index("--method")
        method = argv[i + 1]
        argv = argv[:i] + argv[i + 2:]
    files = argv
    tables = [runs(f, method) for f in files]
    base = tables[0]
    sizes = sorted({s for (_, s) in base}, key=size_key)
    for size in sizes:
        keys = sorted(k for k in base if k[1] == size)
        print(f"## {size} ({len(keys)} clouds: {', '.join(k[0] for k in keys)})")
        print("| file | CD1 x100 | F | NC | tuning s | total s | CD won / lost vs first |")
        print("|---|---|---|---|---|---|---|")
        for f, t in zip(files, tables):
            ks = [k for k in keys if k in t]
            if not ks:
                continue
            mean = lambda field: sum(t[k][field] for k in ks) / len(ks)
            time = lambda name: sum(t[k]["times"].get(name, 0.0) for k in ks) / len(ks)
            won = sum(1 for k in ks if t[k]["cd1x100"] < base[k]["cd1x100"] - 0.01)
            lost = sum(1 for k in ks if t[k]["cd1x100"] > base[k]["cd1x100"] + 0.01)
            print(f"| {f} | {mean('cd1x100'):.4f} | {mean('fscore'):.4f} | {mean('nc'):.4f} | {time('tuning'):.1f} | {time('total'):.1f} | {won} / {lost} |")
        print()


if __name__ == "__main__":
    main(sys.argv[1:])
