#!/usr/bin/env python3
"""Metrics for folders of reconstructions made by scripts/gpu_eval.sh (or any folder of NAME.glb +
NAME.log): prints one markdown table per size with CD1 x100 / F-score / NC per method, and a JSON
line per mesh to stdout's end.
  python scripts/eval_collect.py ROOT TAG [TAG ...]     (folders ROOT/TAG-SIZE/NAME.glb)"""
import json
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from eval_metrics import metrics  # noqa: E402

EVAL = Path(__file__).resolve().parent.parent / "tests" / "data" / "eval"


def log_info(log):
    t = log.read_text() if log.exists() else ""
    info = {}
    m = re.search(r"training error ([0-9.e+-]+) -> ([0-9.e+-]+)", t)
    if m:
        info["err0"], info["err"] = float(m.group(1)), float(m.group(2))
    m = re.search(r"\(total ([0-9.]+)s\)", t)
    if m:
        info["time"] = float(m.group(1))
    return info


def main():
    root, tags = Path(sys.argv[1]), sys.argv[2:]
    rows = {}
    for d in sorted(root.iterdir()):
        if not d.is_dir() or "-" not in d.name:
            continue
        tag, size = d.name.rsplit("-", 1)
        if tag not in tags:
            continue
        for glb in sorted(d.glob("*.glb")):
            r = metrics(str(EVAL / f"{glb.stem}.obj"), str(glb))
            r.update(log_info(glb.with_suffix(".log")))
            rows[(size, glb.stem, tag)] = r
            print(json.dumps({"size": size, "shape": glb.stem, "method": tag, **r}), file=sys.stderr)
    for size in sorted({k[0] for k in rows}, key=lambda s: -len(s)):
        print(f"\n{size} points (CD1 x100 / F-score / NC; time s):\n")
        print("| shape | " + " | ".join(tags) + " |")
        print("| --- |" + " --- |" * len(tags))
        shapes = sorted({k[1] for k in rows if k[0] == size})
        means = {t: [] for t in tags}
        for s in shapes:
            cells = []
            for t in tags:
                r = rows.get((size, s, t))
                if r is None:
                    cells.append("-")
                    continue
                means[t].append((r["cd1x100"], r["fscore"], r["nc"]))
                wt = "" if r["watertight"] else " (open)"
                cells.append(f"{r['cd1x100']:.3f} / {r['fscore']:.3f} / {r['nc']:.3f}{wt}; {r.get('time', 0):.1f}")
            print(f"| {s} | " + " | ".join(cells) + " |")
        cells = []
        for t in tags:
            v = means[t]
            cells.append(" / ".join(f"{sum(x[i] for x in v) / len(v):.3f}" for i in range(3)) if v else "-")
        print("| **mean** | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
