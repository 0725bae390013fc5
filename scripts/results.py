"""Generates docs/results.md and docs/img/results-*.png (issue 6, items 4-5): nkrr against the
network alone and screened Poisson (tests/peers/spsr.py) on the eval clouds at 500 / 3k / 10k
points, the paper's ablations at 3k, a re-run of one slice to see the run-to-run noise, and time
and peak memory against cloud size. Run through scripts/results.sh, which builds the clouds and
the Python environment first.

Every phase writes its raw output under WORK (target/results) and is skipped when that output is
already there, so a second run only redoes the report; --fresh redoes everything and --redo
PHASE one phase. Phases: main, spsr, rerun, scaling, ablations, levers (issue 14: each lever
turned back, and the paper's method whole), hard (the harder clouds), prior (lever 6: another
prior, --other-prior), render, bench, scenes, sparse (1k and 1,500 points), thin (the thin-walled
cups); then the report.

    .venv-peers/bin/python scripts/results.py [--work target/results] [--fresh] [--redo PHASE]
        [--ablation-shapes A,B,...] [--scale-nkrr-max 1000000]
"""
import argparse
import datetime
import glob
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

NKRR = "target/release/nkrr"
SIZES = ["500", "3k", "10k"]
SIZE_N = {"500": 500, "3k": 3000, "10k": 10000}
ABLATIONS = ["nkrr-no-tune", "nkrr-no-theta", "nkrr-no-z", "nkrr-euclidean", "nkrr-m1000"]
RERUN_SHAPES = ["cow", "spot"]
SCALE_SIZES = [1000, 3000, 10000, 30000, 100000, 300000, 1000000]
# The sparse clouds of scripts/results_clouds.py (issue 26: never worse than the network alone at
# any size); the regression is tuned on every cloud under 2,000 points.
SPARSE_SIZES = ["1k", "1500"]
SPARSE_METHODS = "network,nkrr,nkrr-zero-mean"
# The thin-walled cups of scripts/thin_clouds.py (issue 26 item 3: never worse than the network
# on thin walls); aimed at, not part of the eval set.
THIN_SIZES = ["3k", "10k"]
IMG = "docs/img"


def log(msg):
    print(f"[results {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def sh(cmd, **kw):
    log("$ " + " ".join(cmd))
    t0 = time.time()
    out = subprocess.run(cmd, text=True, capture_output=True, **kw)
    if out.returncode != 0:
        sys.stderr.write(out.stdout[-3000:] + out.stderr[-3000:])
        raise SystemExit(f"failed ({out.returncode}): {' '.join(cmd)}")
    return out, time.time() - t0


def eval_phase(work, name, args, data="data"):
    """nkrr eval of WORK/DATA into WORK/NAME.{md,json}; the wall time goes to WORK/NAME.wall,
    written only when the run has finished (nkrr eval rewrites NAME.json after every cloud, so a
    .json alone may be a partial run, which is then run again)."""
    prefix = os.path.join(work, name)
    if not os.path.exists(prefix + ".wall"):
        _, wall = sh([NKRR, "eval", os.path.join(work, data), "--out", prefix] + args)
        open(prefix + ".wall", "w").write(f"{wall:.1f}\n")
    return load_eval(prefix)


def load_eval(prefix):
    d = json.load(open(prefix + ".json"))
    wall = open(prefix + ".wall").read().strip() if os.path.exists(prefix + ".wall") else None
    d["wall_s"] = float(wall) if wall else None
    return d


def seeds_phase(work):
    """The protocol's own sampling noise: nkrr metrics --seed 2 on the re-run slice's meshes
    from the main run (seed 1 is the default that nkrr eval uses)."""
    path = os.path.join(work, "seeds.jsonl")
    if not os.path.exists(path):
        rows = []
        for shape in RERUN_SHAPES:
            for m in ("network", "nkrr"):
                out, _ = sh([NKRR, "metrics", os.path.join(work, "data", f"{shape}.obj"),
                             os.path.join(work, f"main-{shape}-3k-{m}.glb"), "--seed", "2"])
                r = json.loads(out.stdout.strip().splitlines()[-1])
                r.update(shape=shape, method=m, size="3k", seed=2)
                rows.append(json.dumps(r))
        open(path, "w").write("\n".join(rows) + "\n")
    return [json.loads(x) for x in open(path)]


def ablations_phase(work, shapes, run):
    """The ablations at 3k: WORK/ablations.json (one run over several shapes, from an earlier
    version of this script) and WORK/ablations-SHAPE.json for each shape it lacks; with RUN,
    the missing shapes are run. Returns the finished runs merged, or None."""
    parts = []
    if os.path.exists(os.path.join(work, "ablations.wall")):
        parts.append(load_eval(os.path.join(work, "ablations")))
    have = {r["shape"] for p in parts for r in p["runs"]}
    for shape in shapes:
        if shape in have:
            continue
        prefix = os.path.join(work, f"ablations-{shape}")
        if run:
            eval_phase(work, f"ablations-{shape}", ["--sizes", "3k", "--methods",
                                                     ",".join(ABLATIONS), "--shapes", shape] + FIELD)
        if os.path.exists(prefix + ".wall"):
            parts.append(load_eval(prefix))
    if not parts:
        return None
    return {"runs": [r for p in parts for r in p["runs"]],
            "wall_s": sum(p["wall_s"] or 0 for p in parts)}


# The levers beyond the paper (issue 14), each turned back on its own, against the defaults of
# the main run; and the paper's method whole.
LEVERS = [
    ("nkrr-paper-pairs", "3: training pairs that follow density", "one extra point per input point at one scale (the paper's pairs)"),
    ("nkrr-select-training", "4: held-out iterate selection", "the iterate with the lowest training error (the paper's)"),
    ("nkrr-no-fit", "5: the last fit of the mesh to the points", "the field's level set as it is (the paper's output)"),
    ("nkrr-keep-outliers", "7: stray points and unsupported pieces", "every point and every piece kept"),
    ("nkrr-zero-mean", "1: the network as the prior mean", "the regression alone as the field (the paper's zero prior mean; the network's logit is the default since issue 26's guard)"),
]
# Levers measured in a second run (added later, so the first run's output stays valid).
LEVERS2 = [
    ("nkrr-position", "2: the position in the kernel", "the kernel sees [F(q), q], turned on (not a default)"),
    ("nkrr-position-zero-mean", "2 with 1: the position in the kernel, with the paper's zero prior mean", "the position turned on and the zero prior mean (neither a default)"),
]
# A third run: the pairs across the surface (src/orient.rs), 0.5 chosen on cow, fandisk, suzanne.
LEVERS3 = [
    ("nkrr-no-across", "8: pairs across the surface (thin parts)", "no points across the surface (`--no-across`; "
     "the default puts two at each input point, `--across 0.5`, labelled by the network's ordering)"),
]
# A fourth run: the last fit's neighbourhood widened on noisy clouds (src/mesh/fit.rs), chosen on
# noisy clouds of cow, fandisk and suzanne (scripts/hard_clouds.py --noise-tuning); not yet a
# default. Also run on the harder set, where it matters (the eval clouds are below its threshold,
# so there it changes nothing).
LEVERS4 = [
    ("nkrr-fit-noise", "5 on noisy clouds: the fit's neighbourhood follows the noise",
     "the fit's neighbourhood widened on clouds noisier than the eval clouds, turned on (`--fit-noise`; not a default)"),
]
# Issue 26: the Poisson surface through the field's normals, the default from 2,000 points. Its
# variant is in the main run (nkrr-field: the tuned field's level set, the default before).
LEVERS5 = [
    ("nkrr-field", "9: the Poisson surface oriented by the field (issue 26)",
     "the tuned field's level set (`--surface field`, the default before; at 500 points both are the field)"),
]
# The levers of the regression itself (its pairs, the iterate it keeps, its prior mean, its
# kernel) act only where the field's level set is the mesh: with the Poisson surface the
# regression is not tuned (the network's field orients the normals). They run on the field
# surface (`--surface field`) against nkrr-field, as do the paper's ablations.
FIELD_LEVERS = {"nkrr-paper-pairs", "nkrr-select-training", "nkrr-zero-mean", "nkrr-position",
                "nkrr-position-zero-mean", "nkrr-no-across"}
FIELD = ["--surface", "field"]
# Every lever with its own run, split by the surface it runs on.
ALL_LEVERS = LEVERS + LEVERS2 + LEVERS3 + LEVERS4
FIELD_RUN = [m for m, _, _ in ALL_LEVERS if m in FIELD_LEVERS]
DEFAULT_RUN = [m for m, _, _ in ALL_LEVERS if m not in FIELD_LEVERS]
HARD_KINDS = ["noise", "outliers", "falloff", "onesided"]


def levers_phase(work):
    """Every lever's variant at 500 / 3k / 10k (WORK/levers.json) and the paper's
    method whole at 500 and 3k (WORK/paper.json, meshes kept: the before of the renders)."""
    field = eval_phase(work, "levers-field", ["--sizes", ",".join(SIZES), "--methods", ",".join(FIELD_RUN)] + FIELD)
    rest = eval_phase(work, "levers", ["--sizes", ",".join(SIZES), "--methods", ",".join(DEFAULT_RUN)])
    levers = {"runs": field["runs"] + rest["runs"], "wall_s": sum(x["wall_s"] or 0 for x in (field, rest))}
    # The paper's method has the field's level set as its mesh (nkrr-paper sets it).
    paper = eval_phase(work, "paper", ["--sizes", "500,3k", "--methods", "nkrr-paper", "--keep-meshes"])
    return levers, paper


def prior_phase(work, other):
    """Lever 6: the network and nkrr with another prior (`--weights OTHER`) on the eval clouds
    (WORK/prior.json) and the harder clouds (WORK/prior-hard.json), and both priors' held-out
    IoU on the procedural shapes, clean and degraded, with and without rotation averaging
    (training/compare.py: WORK/prior-compare.json). None when OTHER is not there."""
    if not os.path.exists(other):
        return None
    ev = eval_phase(work, "prior", ["--sizes", ",".join(SIZES), "--methods", "network,nkrr", "--weights", other])
    hard = eval_phase(work, "prior-hard", ["--sizes", ",".join(HARD_KINDS), "--methods", "network,nkrr",
                                           "--weights", other], data="hard")
    cmp_path = os.path.join(work, "prior-compare.json")
    if not os.path.exists(cmp_path):
        sh([".venv/bin/python", "-m", "training.compare", "assets/prior.safetensors", other, "--tta",
            "--cache", os.path.join(work, "prior-cache"), "--out", cmp_path])
    return {"other": other, "eval": ev, "hard": hard, "compare": json.load(open(cmp_path))}


HARD_METHODS = "network,nkrr,network-keep-outliers,nkrr-keep-outliers," + ",".join(m for m, _, _ in LEVERS4 + LEVERS5)


def sparse_phase(work, run):
    """The network, nkrr and the paper's zero mean on the 1k and 1,500-point clouds
    (WORK/sparse.json); None when not run."""
    if run:
        return eval_phase(work, "sparse", ["--sizes", ",".join(SPARSE_SIZES), "--methods", SPARSE_METHODS])
    prefix = os.path.join(work, "sparse")
    return load_eval(prefix) if os.path.exists(prefix + ".wall") else None


def sparse_section(sparse, main_runs):
    """Per size from 500 to 1,500 points: the mean CD1 x100 / F / NC of the network, nkrr and
    nkrr with the zero mean, and nkrr's worst gap to the network on a shape (issue 26's bound:
    0.01)."""
    runs = [r for r in main_runs if r["size"] == "500" and r["method"] in ("network", "nkrr")] + sparse["runs"]
    L = ["| points | network CD1 / F / NC | nkrr CD1 / F / NC | nkrr-zero-mean CD1 / F / NC | nkrr's worst gap to the network (shape) |",
         "|---|---|---|---|---|"]
    for size in ["500"] + SPARSE_SIZES:
        by = {(r["method"], r["shape"]): r for r in runs if r["size"] == size}
        cells = []
        for m in ("network", "nkrr", "nkrr-zero-mean"):
            rows = [r for (mm, _), r in by.items() if mm == m]
            a = mean_metrics(rows) if rows else None
            cells.append(f"{fmt(a[0])} / {fmt(a[1])} / {fmt(a[2])}" if a else "-")
        gaps = [(by[("nkrr", sh_)]["cd1x100"] - by[("network", sh_)]["cd1x100"], sh_)
                for (mm, sh_) in by if mm == "nkrr" and ("network", sh_) in by]
        worst = max(gaps) if gaps else None
        gap = f"{worst[0]:+.4f} ({worst[1]})" if worst else "-"
        L.append(f"| {size} | " + " | ".join(cells) + f" | {gap} |")
    return "\n".join(L) + "\n"


def thin_phase(work, run):
    """The cups (scripts/thin_clouds.py into WORK/thin): the network and nkrr (WORK/thin-eval.json),
    screened Poisson (WORK/thin/spsr) and, where scripts/ipsr_runs.py was run on them,
    iPSR (WORK/thin/ipsr/ipsr.jsonl); None when not run."""
    data = os.path.join(work, "thin")
    prefix = os.path.join(work, "thin-eval")
    if run:
        sh([".venv/bin/python", "scripts/thin_clouds.py", data])  # trimesh: the main .venv
        eval_phase(work, "thin-eval", ["--sizes", ",".join(THIN_SIZES), "--methods", "network,nkrr"], data="thin")
        if not os.path.exists(os.path.join(data, "spsr", "spsr.jsonl")):
            run_spsr(data, THIN_SIZES, os.path.join(data, "spsr"))
    if not os.path.exists(prefix + ".wall"):
        return None
    return (load_eval(prefix), spsr_rows(os.path.join(data, "spsr", "spsr.jsonl")),
            ipsr_rows(os.path.join(data, "ipsr", "ipsr.jsonl")))


def thin_section(thin):
    """Per cup and size: CD1 x100 / F-score of the network, nkrr, SPSR and iPSR, and nkrr's gap
    to the network (issue 26's bound: 0.01)."""
    ev, spsr, ipsr = thin
    rows = ev["runs"] + spsr + ipsr
    by = {(r["shape"], r["size"], r.get("method")): r for r in rows}
    L = ["| cloud | network | nkrr | SPSR (depth 8) | iPSR | nkrr − network |", "|---|---|---|---|---|---|"]
    for shape in sorted({r["shape"] for r in ev["runs"]}, reverse=True):
        for size in THIN_SIZES:
            cells = []
            for m in ("network", "nkrr", "spsr", "ipsr"):
                r = by.get((shape, size, m))
                cells.append(f"{fmt(r['cd1x100'])} / {fmt(r['fscore'])}" if r else "-")
            a, b = by.get((shape, size, "nkrr")), by.get((shape, size, "network"))
            gap = f"{a['cd1x100'] - b['cd1x100']:+.4f}" if a and b else "-"
            L.append(f"| {shape}-{size} | " + " | ".join(cells) + f" | {gap} |")
    return "\n".join(L) + "\n"


def hard_phase(work):
    """The harder clouds (scripts/hard_clouds.py: noise 0.02, 10 % stray points, 55x density
    falloff, one-sided, 3000 points each), screened Poisson on them, and the network and nkrr
    with and without the stray-point handling (WORK/hard.json)."""
    sh([sys.executable, "scripts/hard_clouds.py", "--spsr"])
    runs = eval_phase(work, "hard-eval", ["--sizes", ",".join(HARD_KINDS), "--methods",
                                          HARD_METHODS], data="hard")
    spsr = spsr_rows(os.path.join(work, "hard", "spsr", "spsr.jsonl"))
    return runs, spsr


SCENES = [("room1", ["room"]), ("street1", ["street"])]
SCENE_METHODS = [("nkrr", "nkrr in tiles (the network per tile)", ["--method", "network"]),
                 ("cube", "nkrr in one cube (`--tiles off`)", ["--method", "network", "--tiles", "off"]),
                 ("spsr", "screened Poisson (depth 10, 5 % trimmed)", None)]
FORMATS_PY = ".venv-formats/bin/python"
PEERS_PY = ".venv-peers/bin/python"


def timed(cmd):
    """Runs cmd under /usr/bin/time -v: its output, the wall seconds and the peak RSS in MiB."""
    out, _ = sh(["/usr/bin/time", "-v"] + cmd)
    err = out.stderr + out.stdout
    rss_kb = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", err).group(1))
    el = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): ([0-9:.]+)", err).group(1)
    secs = 0.0
    for part in el.split(":"):
        secs = secs * 60 + float(part)
    return out, secs, rss_kb / 1024


def scenes_phase(work, run):
    """Issue 25's scenes: the generated 1M-point room and street (scripts/scenes.py, seed 1),
    each reconstructed in tiles, in one cube and by screened Poisson (scripts/scene_spsr.py),
    scored in metres by scripts/scene_metrics.py, and the tiled mesh's objects against the same
    objects alone (scripts/scene_objects.py). Every step is skipped when its output is there
    (WORK/scenes/); without `run`, only what is there is read. None when nothing is."""
    d = os.path.join(work, "scenes")
    if run:
        os.makedirs(d, exist_ok=True)
    out = {}
    for name, kind in SCENES:
        prefix = os.path.join(d, name)
        if run and not os.path.exists(prefix + "-objects.json"):
            sh([FORMATS_PY, "scripts/scenes.py"] + kind + ["--seed", "1", "--points", "1000000", "--no-e57", "--out", prefix])
        rows = {}
        for key, label, args in SCENE_METHODS:
            mesh = f"{prefix}-{key}." + ("ply" if key == "spsr" else "glb")
            scored = f"{prefix}-spsr-trim5.ply" if key == "spsr" else mesh
            metrics, timing = f"{prefix}-{key}-metrics.json", f"{prefix}-{key}-time.json"
            if run and not os.path.exists(timing):
                if key == "spsr":
                    cmd = [PEERS_PY, "scripts/scene_spsr.py", prefix + ".laz", "-o", mesh]
                else:
                    cmd = [NKRR, "reconstruct", prefix + ".laz", "-o", mesh] + args
                o, wall, rss = timed(cmd)
                open(f"{prefix}-{key}.log", "w").write(o.stdout + o.stderr)
                json.dump({"wall_s": wall, "peak_rss_mib": rss}, open(timing, "w"))
            if run and not os.path.exists(metrics):
                o, _ = sh([FORMATS_PY, "scripts/scene_metrics.py", prefix + "-gt.ply", prefix + "-objects.json", scored])
                open(metrics, "w").write(o.stdout.strip().splitlines()[-1])
            if os.path.exists(metrics) and os.path.exists(timing):
                rows[key] = {"label": label, **json.load(open(timing)), "metrics": json.load(open(metrics))}
        objects = os.path.join(d, f"{name}-objects", "objects.json")
        if run and not os.path.exists(objects) and os.path.exists(prefix + "-nkrr.glb"):
            sh([FORMATS_PY, "scripts/scene_objects.py", prefix, prefix + "-nkrr.glb", "--out", os.path.dirname(objects)])
        # The street is open to the sky: scripts/render.py's views show it whole (z is up, so its
        # "front" looks down on it). The room is closed: its render (a cut at 2.2 m) is scenes.md's.
        png = os.path.join(IMG, f"scene-{name}.png")
        meshes = [prefix + "-gt.ply", prefix + "-nkrr.glb", prefix + "-spsr-trim5.ply"]
        if run and name == "street1" and not os.path.exists(png) and all(map(os.path.exists, meshes)):
            sh([".venv/bin/python", "scripts/render.py"] + meshes + ["-o", png, "--size", "300", "--samples", "600000"])
        if rows:
            out[name] = {"rows": rows, "objects": json.load(open(objects)) if os.path.exists(objects) else None,
                         "png": png if name == "street1" and os.path.exists(png) else None}
    return out or None


def scenes_section(w, sc):
    """The scenes' tables (metres), or where they are when the phase has not run."""
    w("## Scenes (issue 25)\n")
    if not sc:
        w("Not run in this report (phase `scenes`); the measurements of the generated room and "
          "street against screened Poisson and the one-cube path, with renders, are in "
          "[scenes.md](scenes.md#measured).\n")
        return
    w("`scripts/scenes.py` (seed 1, 1M points, 3 mm noise, LAZ far from the origin), scored by "
      "`scripts/scene_metrics.py` in metres; *scanned* restricts the ground truth to surface within "
      "5 cm of an input point (what a scanner saw). Wall time and peak memory by `/usr/bin/time -v` "
      "on this machine (not a benchmark). Renders and the reading of these numbers: "
      "[scenes.md](scenes.md#measured). These scenes chose the tile rule (`TILE_POINTS`, the "
      "street's cell cap): they are not held out.\n")
    for name, s in sc.items():
        w(f"### {name}\n")
        t = ["| method | wall s | peak MiB | CD (cm) | F@1 / 2 / 5 cm | scanned: completeness, F@2 cm, CD (cm) | objects' completeness (scanned) |",
             "|---|---|---|---|---|---|---|"]
        for key, r in s["rows"].items():
            m, sc_ = r["metrics"], r["metrics"]["scanned"]
            f = m["fscore"]
            t.append(f"| {r['label']} | {fmt(r['wall_s'], 0)} | {fmt(r['peak_rss_mib'], 0)} | {fmt(m['chamfer']['mean_cm'], 2)} | "
                     f"{fmt(f['1cm']['f'], 3)} / {fmt(f['2cm']['f'], 3)} / {fmt(f['5cm']['f'], 3)} | "
                     f"{fmt(sc_['completeness'], 3)}, {fmt(sc_['fscore']['2cm']['f'], 3)}, {fmt(sc_['chamfer']['mean_cm'], 2)} | "
                     f"{fmt(sc_['objects_completeness_mean'], 2)} |")
        w("\n".join(t) + "\n")
        if s.get("png"):
            w(f"![{name}: rows ground truth, nkrr in tiles, screened Poisson; z is up, so the first view looks down](img/{os.path.basename(s['png'])})\n")
        elif name == "room1":
            w("![room1, cut at 2.2 m: ground truth; nkrr in tiles; nkrr in one cube; screened Poisson (top and 3/4 views; made 2026-12-02, before the 6k tile rule)](img/scene-room1.png)\n")
        if s["objects"]:
            o = ["| object | points | in the scene, CD (cm) | alone, CD (cm) | scene / alone |", "|---|---|---|---|---|"]
            for r in s["objects"]:
                o.append(f"| {r['object']} ({r['family']}) | {r['points']:,} | {fmt(r['scene_cd_cm'], 2)} | {fmt(r['alone_cd_cm'], 2)} | {fmt(r['ratio'], 2)} |")
            w("Each object of the tiled mesh against the same object reconstructed alone from its own points "
              "(`scripts/scene_objects.py`; the issue asks below 2):\n")
            w("\n".join(o) + "\n")


def mean_metrics(rows):
    return tuple(mean([r.get(k) for r in rows]) for k in ("cd1x100", "fscore", "nc"))


def lever_table(base_rows, var_rows, sizes, base_label, var_label):
    """Per size: the mean CD1 x100 / F / NC of the default and of the variant on the same clouds,
    and on how many clouds the default's CD1 is lower (higher) by more than the 0.01 noise."""
    by = {(r["shape"], r["size"]): r for r in var_rows}
    lines = [f"| points | {base_label} CD1 / F / NC | {var_label} CD1 / F / NC | {base_label} better / worse by > 0.01 CD1 |",
             "|---|---|---|---|"]
    for size in sizes:
        pairs = [(r, by[(r["shape"], size)]) for r in base_rows if r["size"] == size and (r["shape"], size) in by]
        if not pairs:
            continue
        a = mean_metrics([p[0] for p in pairs])
        b = mean_metrics([p[1] for p in pairs])
        better = sum(1 for x, y in pairs if y["cd1x100"] - x["cd1x100"] > 0.01)
        worse = sum(1 for x, y in pairs if x["cd1x100"] - y["cd1x100"] > 0.01)
        lines.append(f"| {size} | {fmt(a[0])} / {fmt(a[1])} / {fmt(a[2])} | {fmt(b[0])} / {fmt(b[1])} / {fmt(b[2])} | "
                     f"{better} / {worse} of {len(pairs)} |")
    return "\n".join(lines)


def lever_render(work, m, candidates):
    """Where lever `m` matters most, drawn: of `candidates` ((data, shape, size, reference
    method, reference CD1, variant CD1), over the eval clouds and the harder set where the lever
    ran there), the cloud where the reference is furthest ahead of the variant (the lever turned
    back, or a variant turned on), reconstructed again with both (meshes kept) and rendered as
    rows truth / variant / reference (docs/img/results-lever-M.png). Returns (path, that
    candidate, the one where the variant is furthest ahead) or None when it ran nowhere."""
    if not candidates:
        return None
    gain = max(candidates, key=lambda c: c[5] - c[4])
    loss = min(candidates, key=lambda c: c[5] - c[4])
    out = os.path.join(IMG, f"results-lever-{m}.png")
    if not os.path.exists(out):
        data, shape, size, ref = gain[:4]
        prefix = os.path.join(work, f"lever-render-{m}")
        args = ["--shapes", shape, "--sizes", size, "--methods", f"{ref},{m}", "--keep-meshes"]
        sh([NKRR, "eval", os.path.join(work, data), "--out", prefix] + args + (FIELD if m in FIELD_LEVERS else []))
        inputs = [os.path.join(work, data, f"{shape}.obj"), f"{prefix}-{shape}-{size}-{m}.glb",
                  f"{prefix}-{shape}-{size}-{ref}.glb"]
        tmp = prefix + ".png"
        sh([".venv/bin/python", "scripts/render.py", *inputs, "-o", tmp, "--size", "130", "--samples", "120000"])
        from PIL import Image
        Image.open(tmp).convert("RGB").quantize(colors=48).save(out, optimize=True)
    return out, gain, loss


def lever_candidates(m, ref_rows, var_rows, data):
    """(data, shape, size, reference method, reference CD1, variant CD1) for every cloud both ran."""
    ref = {(r["shape"], r["size"]): r for r in ref_rows}
    return [(data, r["shape"], r["size"], ref[(r["shape"], r["size"])]["method"], ref[(r["shape"], r["size"])]["cd1x100"],
             r["cd1x100"]) for r in var_rows if r["method"] == m and (r["shape"], r["size"]) in ref]


def spsr_phase(work):
    out = os.path.join(work, "spsr")
    jl = os.path.join(out, "spsr.jsonl")
    if not (os.path.exists(jl) and len(open(jl).read().splitlines()) == 18):
        run_spsr(os.path.join(work, "data"), SIZES, out)
    return spsr_rows(jl)


def run_spsr(data, sizes, out):
    """Screened Poisson (tests/peers/spsr.py, depth 8) on every DATA/NAME-SIZE.ply, scored by
    `nkrr metrics` against DATA/NAME.obj: OUT/NAME-SIZE.obj, OUT/spsr.jsonl, and the wall time
    in OUT/wall. Also used by scripts/hard_clouds.py."""
    t0 = time.time()
    sh([sys.executable, "tests/peers/spsr.py", "--data", data,
        "--sizes", ",".join(sizes), "--out", out, "--depth", "8",
        "--metrics-cmd", f"{NKRR} metrics"])
    open(os.path.join(out, "wall"), "w").write(f"{time.time() - t0:.1f}\n")


def ipsr_rows(jl):
    """A local iPSR run's rows (IPSR_HOW), or none."""
    if not os.path.exists(jl):
        return []
    rows = [json.loads(x) for x in open(jl)]
    for r in rows:
        r["times"] = {"total": r.get("total_s")}
    return [r for r in rows if "error" not in r]


def spsr_rows(jl):
    """spsr.jsonl's rows as the report reads them: method spsr and a times dict."""
    rows = [json.loads(x) for x in open(jl)]
    for r in rows:
        r["method"] = "spsr"
        r["times"] = {"normals": r["normals_s"], "poisson": r["poisson_s"],
                      "total": round(r["normals_s"] + r["poisson_s"], 3)}
    return rows


STAGE_RE = re.compile(r"([a-z][a-z ]*?) ([0-9.]+)s")


def scaling_phase(work, nkrr_max):
    """/usr/bin/time -v nkrr reconstruct on scale-N.ply: wall time, peak RSS, the stage times
    nkrr prints. The network runs at every size; nkrr at the defaults up to NKRR_MAX points
    (its tuning costs minutes per cloud on this machine)."""
    path = os.path.join(work, "scaling.jsonl")
    done = {}
    if os.path.exists(path):
        for line in open(path):
            r = json.loads(line)
            done[(r["method"], r["points"])] = r
    f = open(path, "a")
    for method in ["network", "nkrr"]:
        for n in SCALE_SIZES:
            if (method, n) in done:
                continue
            if method == "nkrr" and n > nkrr_max:
                log(f"scaling: nkrr stops at {nkrr_max} points (--scale-nkrr-max)")
                break
            cloud = os.path.join(work, "data", "scale", f"scale-{n}.ply")
            mesh = os.path.join(work, "scale-out.glb")
            out, secs, rss_mib = timed([NKRR, "reconstruct", cloud, "-o", mesh, "--method", method])
            err = out.stderr + out.stdout
            summary = [x for x in err.splitlines() if "total" in x and "watertight" in x]
            stages = {k.strip(): float(v) for k, v in STAGE_RE.findall(summary[-1].split(";", 1)[1])} if summary else {}
            r = {"method": method, "points": n, "wall_s": round(secs, 2),
                 "peak_rss_mb": round(rss_mib, 1), "stages": stages,
                 "summary": summary[-1] if summary else ""}
            f.write(json.dumps(r) + "\n")
            f.flush()
            done[(method, n)] = r
    return sorted(done.values(), key=lambda r: (r["method"], r["points"]))


def bench_phase(work, run):
    """scripts/bench.py: median end-to-end times on 500 / 3k / 10k / 100k points and the ratio to
    screened Poisson on the same clouds in the same run (the figures that survive a change of
    machine). Returns its rows, or [] when it has not run."""
    out = os.path.join(work, "bench", "bench.json")
    if run and not os.path.exists(out):
        log("bench: scripts/bench.py (3 runs per cloud and method)")
        sh(["python3", "scripts/bench.py", "--out", os.path.join(work, "bench"), "--repeat", "3"])
    return json.load(open(out))["rows"] if os.path.exists(out) else []


def render_phase(work, shapes, size):
    out = os.path.join(IMG, "results-render.png")
    if os.path.exists(out):
        return out
    for shape in shapes:
        tmp = os.path.join(work, f"render-{shape}.png")
        inputs = [os.path.join(work, "data", f"{shape}.obj")]
        inputs += [os.path.join(work, f"main-{shape}-{size}-{m}.glb") for m in ("network", "nkrr")]
        inputs += [os.path.join(work, "spsr", f"{shape}-{size}.obj")]
        sh([".venv/bin/python", "scripts/render.py", *inputs, "-o", tmp,
            "--size", "150", "--samples", "150000"])
    from PIL import Image
    ims = [Image.open(os.path.join(work, f"render-{s}.png")).convert("RGB") for s in shapes]
    w = sum(i.width for i in ims)
    h = max(i.height for i in ims)
    canvas = Image.new("RGB", (w, h), "white")
    x = 0
    for im in ims:
        canvas.paste(im, (x, 0))
        x += im.width
    canvas = canvas.quantize(colors=64)
    canvas.save(out, optimize=True)
    return out


# ---------------------------------------------------------------- report

METHOD_ORDER = ["network", "nkrr", "nkrr-field", "spsr", "ipsr"] + ABLATIONS
LABEL = {"network": "network", "nkrr": "nkrr", "nkrr-field": "nkrr, field surface", "spsr": "SPSR (depth 8)",
         "ipsr": "iPSR (defaults)"}
# iPSR (Hou et al., SIGGRAPH 2022) is built outside this repository (its code is not committed)
# and run by scripts/ipsr_runs.py: its rows are read when WORK/ipsr/ipsr.jsonl and
# WORK/hard/ipsr/ipsr.jsonl are there, in spsr.jsonl's form with total_s (see IPSR_HOW).
IPSR_HOW = ("iPSR: github.com/houfei0801/ipsr at 0cf5932 (MIT), built beside this repository with its own "
            "makefile (`g++ -std=c++11 -O3 -fopenmp`), run by `scripts/ipsr_runs.py` with its defaults (30 "
            "iterations, point weight 10, depth 10, 10 neighbours) on one core (`OMP_THREAD_LIMIT=1`), its PLY "
            "output scored by the same `nkrr metrics`; rows in `target/results/ipsr/ipsr.jsonl` and "
            "`target/results/hard/ipsr/ipsr.jsonl`. A clone's report has iPSR rows only where iPSR was built "
            "beside it and that script run first (its doc has the commands).")


def fmt(v, nd=3):
    return "-" if v is None else f"{v:.{nd}f}"


def mean(xs):
    xs = [x for x in xs if x is not None]
    return sum(xs) / len(xs) if xs else None


def table(rows, methods, shapes):
    """Markdown: shape x method, CD1 x100 / F / NC / IoU / watertight / seconds; means."""
    by = {(r["shape"], r["method"]): r for r in rows}
    lines = ["| shape | method | CD1 x100 | F-score | NC | IoU | watertight | seconds |",
             "|---|---|---|---|---|---|---|---|"]
    best = {}
    for shape in shapes:
        for key, lo in (("cd1x100", True), ("fscore", False), ("nc", False), ("iou", False)):
            vals = [by[(shape, m)].get(key) for m in methods if (shape, m) in by]
            vals = [v for v in vals if v is not None]
            if vals:
                best[(shape, key)] = min(vals) if lo else max(vals)
    for shape in shapes:
        for m in methods:
            r = by.get((shape, m))
            if r is None:
                continue
            cells = []
            for key in ("cd1x100", "fscore", "nc", "iou"):
                v = r.get(key)
                s = fmt(v)
                if v is not None and len(methods) > 1 and best.get((shape, key)) == v:
                    s = f"**{s}**"
                cells.append(s)
            lines.append(f"| {shape} | {LABEL.get(m, m)} | {' | '.join(cells)} | "
                         f"{'yes' if r.get('watertight') else 'no'} | {fmt(r['times'].get('total'), 1)} |")
    for m in methods:
        rs = [by[(s, m)] for s in shapes if (s, m) in by]
        if not rs:
            continue
        cells = [fmt(mean([r.get(k) for r in rs])) for k in ("cd1x100", "fscore", "nc", "iou")]
        wt = sum(1 for r in rs if r.get("watertight"))
        lines.append(f"| **mean** | {LABEL.get(m, m)} | {' | '.join(cells)} | {wt}/{len(rs)} | "
                     f"{fmt(mean([r['times'].get('total') for r in rs]), 1)} |")
    return "\n".join(lines)


def wins(rows, a, b, shapes, key, lower):
    by = {(r["shape"], r["method"]): r for r in rows}
    n = 0
    tot = 0
    for s in shapes:
        if (s, a) in by and (s, b) in by and by[(s, a)].get(key) is not None:
            tot += 1
            va, vb = by[(s, a)][key], by[(s, b)][key]
            n += (va < vb) if lower else (va > vb)
    return n, tot


def plot_metrics(rows, shapes, path):
    fig, axes = plt.subplots(1, 4, figsize=(13, 3.2))
    for ax, (key, title) in zip(axes, [("cd1x100", "CD1 x100 (lower is better)"),
                                       ("fscore", "F-score @ 0.01"), ("nc", "normal consistency"),
                                       ("iou", "IoU (closed ground truths)")]):
        for m, c in (("network", "tab:blue"), ("nkrr", "tab:orange"), ("spsr", "tab:green"), ("ipsr", "tab:red")):
            xs, ys = [], []
            for size in SIZES:
                v = mean([r.get(key) for r in rows if r["method"] == m and r["size"] == size])
                if v is not None:
                    xs.append(SIZE_N[size])
                    ys.append(v)
            if xs:
                ax.plot(xs, ys, "o-", color=c, label=LABEL[m])
        ax.set_xscale("log")
        ax.set_xticks([500, 3000, 10000], ["500", "3k", "10k"])
        ax.set_title(title, fontsize=9)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("mean over the eval shapes vs input points", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def plot_stages(rows, path):
    stages = ["features", "pairs", "tuning", "mesh"]
    labels, data = [], {s: [] for s in stages}
    for size in SIZES:
        for m in ("network", "nkrr"):
            rs = [r for r in rows if r["method"] == m and r["size"] == size]
            if not rs:
                continue
            labels.append(f"{m}\n{size}")
            for s in stages:
                data[s].append(mean([r["times"].get(s, 0.0) for r in rs]) or 0.0)
    fig, ax = plt.subplots(figsize=(8, 3.4))
    bottom = [0.0] * len(labels)
    for s in stages:
        ax.bar(labels, data[s], bottom=bottom, label=s)
        bottom = [b + v for b, v in zip(bottom, data[s])]
    ax.set_ylabel("seconds (mean over shapes)")
    ax.set_title("time per stage, eval clouds, this machine (lavapipe)", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def plot_scaling(scale, path):
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.4))
    for m, c in (("network", "tab:blue"), ("nkrr", "tab:orange")):
        rs = [r for r in scale if r["method"] == m]
        axes[0].plot([r["points"] for r in rs], [r["wall_s"] for r in rs], "o-", color=c, label=m)
        axes[1].plot([r["points"] for r in rs], [r["peak_rss_mb"] for r in rs], "o-", color=c, label=m)
    for ax, t in zip(axes, ["wall time (s)", "peak RSS (MB)"]):
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.axvline(100000, color="grey", ls="--", lw=0.8)
        ax.set_xlabel("points in the cloud (encoder subsample at 100k: dashed)")
        ax.set_title(t, fontsize=10)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def machine():
    cpu = "unknown"
    for line in open("/proc/cpuinfo"):
        if line.startswith("model name"):
            cpu = line.split(":", 1)[1].strip()
            break
    mem = ""
    for line in open("/proc/meminfo"):
        if line.startswith("MemTotal"):
            mem = f"{int(line.split()[1]) / 1024 / 1024:.0f} GiB"
    gpu = subprocess.run([NKRR, "gpu"], text=True, capture_output=True)
    adapter = [x for x in (gpu.stdout + gpu.stderr).splitlines() if x.strip() and "XDG" not in x]
    return cpu, os.cpu_count(), mem, adapter


def compare_table(main_rows, rows, what, times=False):
    """Rows of the main 3k run beside the same (shape, method) from another run or scoring:
    the markdown table (`what` names the two columns, e.g. "seed 1 / seed 2") and the largest
    absolute difference per metric."""
    by = {(r["shape"], r["method"]): r for r in main_rows if r["size"] == "3k"}
    keys = ("cd1x100", "fscore", "nc", "iou")
    lines = [f"| shape | method | CD1 x100 {what} | F-score | NC | IoU |" + (" seconds |" if times else ""),
             "|---|---|---|---|---|---|" + ("---|" if times else "")]
    diffs = {k: [] for k in keys}
    for r in rows:
        a = by[(r["shape"], r["method"])]
        cells = []
        for k in keys:
            cells.append(f"{fmt(a.get(k), 4)} / {fmt(r.get(k), 4)}")
            if a.get(k) is not None:
                diffs[k].append(abs(a[k] - r[k]))
        if times:
            cells.append(f"{fmt(a['times'].get('total'), 1)} / {fmt(r['times'].get('total'), 1)}")
        lines.append(f"| {r['shape']} | {r['method']} | " + " | ".join(cells) + " |")
    return "\n".join(lines), {k: max(v) if v else None for k, v in diffs.items()}


def report(work, main, spsr, rerun, seeds, scale, abl, abl_shapes, nkrr_max, render_png, bench, levers=None, paper=None, hard=None, before_png=None, prior=None, scenes=None, sparse=None, thin=None):
    runs = main["runs"]
    shapes = sorted({r["shape"] for r in runs})
    ipsr = ipsr_rows(os.path.join(work, "ipsr", "ipsr.jsonl"))
    rows = runs + spsr + ipsr
    peers = ["spsr"] + (["ipsr"] if ipsr else [])
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], text=True,
                            capture_output=True).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "src"],
                           text=True, capture_output=True).stdout.strip()
    cpu, cores, mem, adapter = machine()
    gt_closed = sorted({r["shape"] for r in runs if r.get("gt_watertight")})
    os.makedirs(IMG, exist_ok=True)
    plot_metrics(rows, shapes, os.path.join(IMG, "results-metrics.png"))
    plot_stages(runs, os.path.join(IMG, "results-stages.png"))
    plot_scaling(scale, os.path.join(IMG, "results-scaling.png"))

    L = []
    w = L.append
    w("# Results: nkrr vs the network alone vs screened Poisson, on this machine\n")
    w("Generated by `scripts/results.sh` (this file and `docs/img/results-*.png` are its output; "
      "do not edit by hand). Raw outputs: `target/results/` (git-ignored).\n")
    w(f"- date: {datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}")
    built = datetime.datetime.fromtimestamp(os.path.getmtime(NKRR), datetime.timezone.utc)
    version = subprocess.run([NKRR, "--version"], text=True, capture_output=True).stdout.strip()
    w(f"- commit: `{commit}` when the report was written" + (
        " (with uncommitted changes under src/)" if dirty else "") +
      f"; binary `{NKRR}` ({version}) built {built.strftime('%Y-%m-%d %H:%M UTC')}")
    w(f"- machine: {cpu}, {cores} cores, {mem} RAM; shared with other work while it ran, so "
      "times are upper bounds")
    w(f"- adapter (`nkrr gpu`): {adapter[0].split(';')[0] if adapter else 'unknown'} (a software Vulkan "
      "rasteriser on the CPU; nkrr's KRR then runs in f64 on the CPU, `--krr-backend auto`)")
    w(f"- settings (`nkrr eval`): `{main.get('settings', '')}`")
    w("- data: the six eval meshes of `tests/data/eval` (protocol in its README: ground truth "
      "normalised to the unit cube, 100k samples per surface, CD1 x100, F-score at 0.01, normal "
      f"consistency, IoU only where the ground truth is closed: {', '.join(gt_closed)}). The 3k and "
      "10k clouds are the committed ones; the 500-point clouds are made here "
      "(`scripts/results_clouds.py`: uniform on the surface, Gaussian noise sigma = 0.005 x the "
      "longest bbox side, seed 3).")
    w("- error split (issue 26): `scripts/eval_metrics.py GT.obj RECON.glb` adds to its JSON "
      "line where the error sits against the F-score's tau = 0.01, per side and pooled: "
      "`precision_*` is reconstruction -> truth (extra, merged or displaced surface), "
      "`completeness_*` truth -> reconstruction (missing or displaced parts), no prefix both "
      "sides pooled. `beyond_share` is the share of the samples at distance >= tau (on the "
      "precision side, 1 - precision), `within_mean_x100` and `beyond_mean_x100` the mean "
      "distance x100 of the samples within and beyond tau, `beyond_cd_share` the share of the "
      "side's mean distance (pooled: of CD1) that the beyond samples carry; "
      "`precision_mean_x100` and `completeness_mean_x100` average to CD1 x100, and each mean = "
      "(1 - beyond_share) x within_mean + beyond_share x beyond_mean. A lever aimed at the "
      "within part sharpens the surface where it is already right (CD1, NC); one aimed at the "
      "beyond part (missing or extra surface) moves the F-score, and most of CD1 when "
      "`beyond_cd_share` is high. `scripts/error_map.py GT.obj RECON.glb -o OUT.png` renders "
      "where the beyond-tau error sits, in `scripts/render.py`'s four views: the ground truth "
      "coloured by its distance to the reconstruction (missing parts) above the reconstruction "
      "coloured by its distance to the truth (extra surface); grey within tau, a yellow-red-"
      "purple ramp from tau to 5 tau (`--vmax`). `nkrr metrics` and `nkrr eval` report the same split "
      "in their JSON (same names; `nkrr eval`'s tables add the pooled `beyond_cd_share` as 'beyond τ') "
      "from commit 'nkrr metrics: the error split' on; the tables below are `nkrr metrics`'.")
    w("- GPU reference: the H100 numbers of [docs/krr.md](krr.md#nkrr-vs-the-network-alone-on-"
      "the-eval-clouds-h100-paper-settings) (not re-run here; the metrics there were the same "
      "protocol, the times not benchmarks).\n")
    w("Commands run (all by `scripts/results.sh`):\n")
    w("```")
    w("nkrr eval target/results/data --sizes 500,3k,10k --methods network,nkrr,nkrr-field --keep-meshes")
    w("tests/peers/spsr.py --data target/results/data --sizes 500,3k,10k --depth 8 "
      "--metrics-cmd 'target/release/nkrr metrics'")
    w(f"nkrr eval target/results/data --sizes 3k --methods {','.join(ABLATIONS)} "
      f"--shapes {','.join(abl_shapes)} --surface field   # in groups of shapes")
    w(f"nkrr eval target/results/data --sizes 3k --methods network,nkrr --shapes "
      f"{','.join(RERUN_SHAPES)}   # the re-run")
    w("/usr/bin/time -v nkrr reconstruct scale-N.ply -o out.glb --method network|nkrr")
    w("nkrr eval target/results/data --sizes 500,3k,10k --methods " + ",".join(FIELD_RUN)
      + " --surface field   # the regression's levers")
    w("nkrr eval target/results/data --sizes 500,3k,10k --methods " + ",".join(DEFAULT_RUN) + "   # the others")
    w("nkrr eval target/results/data --sizes 500,3k --methods nkrr-paper --keep-meshes")
    w("scripts/hard_clouds.py --spsr   # the harder clouds and screened Poisson on them")
    if sparse:
        w(f"nkrr eval target/results/data --sizes {','.join(SPARSE_SIZES)} --methods {SPARSE_METHODS}   # the sparse clouds")
    if thin:
        w(f"scripts/thin_clouds.py target/results/thin && nkrr eval target/results/thin --sizes {','.join(THIN_SIZES)} "
          "--methods network,nkrr   # the thin-walled cups")
    w("nkrr eval target/results/hard --sizes " + ",".join(HARD_KINDS)
      + " --methods " + HARD_METHODS)
    if scenes:
        w("scripts/scenes.py room|street --seed 1 --points 1000000 --no-e57 --out target/results/scenes/NAME")
        w("nkrr reconstruct NAME.laz -o NAME-nkrr.glb --method network   # and --tiles off; scripts/scene_spsr.py NAME.laz -o NAME-spsr.ply")
        w("scripts/scene_metrics.py NAME-gt.ply NAME-objects.json MESH; scripts/scene_objects.py NAME NAME-nkrr.glb   # the scenes")
    if prior:
        w(f"nkrr eval target/results/data --sizes {','.join(SIZES)} --methods network,nkrr --weights {prior['other']}")
        w(f"nkrr eval target/results/hard --sizes {','.join(HARD_KINDS)} --methods network,nkrr --weights {prior['other']}")
        w(f".venv/bin/python -m training.compare assets/prior.safetensors {prior['other']} --tta")
    w("```\n")
    walls = [main.get("wall_s"), abl.get("wall_s") if abl else None, rerun.get("wall_s")]
    w(f"Wall time of the runs here: main eval {fmt(walls[0], 0)} s, ablations {fmt(walls[1], 0)} s, "
      f"re-run {fmt(walls[2], 0)} s, SPSR {fmt(spsr_wall(work), 0)} s, scaling "
      f"{fmt(sum(r['wall_s'] for r in scale), 0)} s.\n")

    w("## Accuracy by input size\n")
    w(f"Per cloud: CD1 x100 / F-score / NC / IoU ({', '.join(gt_closed)}) / whether the mesh is watertight "
      "(closed and consistently oriented, as `nkrr metrics` checks) / seconds (nkrr: the whole "
      "reconstruction, features to mesh, without file I/O and metrics; SPSR: PCA normals + "
      "orientation + Poisson, Open3D multithreaded). Best per shape in bold.\n")
    for size in reversed(SIZES):
        w(f"### {size} points\n")
        w(table([r for r in rows if r["size"] == size], ["network", "nkrr", "nkrr-field"] + peers, shapes))
        w("")
    w("![metrics vs size](img/results-metrics.png)\n")
    if ipsr:
        w(IPSR_HOW + " Its seconds are one core's, measured while other work ran.\n")
    else:
        w("iPSR: not run here (no `target/results/ipsr/ipsr.jsonl`).\n")

    # reading
    w("### Reading\n")
    for size in reversed(SIZES):
        srows = [r for r in rows if r["size"] == size]
        parts = []
        for a, b in [("nkrr", "network")] + [("nkrr", p) for p in peers]:
            c = wins(srows, a, b, shapes, "cd1x100", True)
            f = wins(srows, a, b, shapes, "fscore", False)
            nc = wins(srows, a, b, shapes, "nc", False)
            parts.append(f"nkrr beats {LABEL[b]} on CD1 on {c[0]}/{c[1]} shapes, F-score "
                         f"{f[0]}/{f[1]}, NC {nc[0]}/{nc[1]}")
        wt = {m: sum(1 for r in srows if r["method"] == m and r.get("watertight")) for m in
              ("network", "nkrr", "spsr")}
        w(f"- {size}: " + "; ".join(parts) + f". Watertight meshes: network {wt['network']}/6, "
          f"nkrr {wt['nkrr']}/6, SPSR {wt['spsr']}/6.")
    w("")
    notes = "scripts/results_reading.md"
    if os.path.exists(notes):
        w(open(notes).read().strip() + "\n")

    w("## Ablations (3k points)\n")
    if abl:
        full = set(abl_shapes) == set(shapes)
        if not full:
            w(f"**Cut for time:** the ablations ran on {len(abl_shapes)} of the 6 shapes "
              f"({', '.join(abl_shapes)}), not all six; the means below are over those shapes "
              "only, with network and nkrr from the main run on the same shapes.\n")
        arows = [r for r in runs if r["size"] == "3k" and r["shape"] in abl_shapes] + abl["runs"]
        w("On the field surface (`--surface field`), where the regression's field is the mesh: with the "
          "Poisson surface (the default from 2,000 points) the regression is not tuned, so these change nothing "
          "there. `nkrr, field surface` is the main run's nkrr-field.\n")
        w(table(arows, ["nkrr-field"] + ABLATIONS, sorted(abl_shapes)))
        w("\n`nkrr-no-tune`: KRR with the initial θ and Z (no Adam); `nkrr-no-theta`: only Z "
          "tuned; `nkrr-no-z`: only θ tuned; `nkrr-euclidean`: KRR on Fourier-encoded "
          "coordinates instead of the network's features; `nkrr-m1000`: 1000 inducing points.\n")
    else:
        w("Not run.\n")

    w("## Levers beyond the paper (issue 14)\n")
    if levers:
        lv = levers["runs"]
        nk = [r for r in runs if r["method"] == "nkrr"]
        w("Each lever turned back on its own (levers 1, 2 and 5 on noisy clouds, not defaults: turned on), everything else at the "
          "defaults, on the same clouds as the main run (`nkrr eval --methods "
          + ",".join(m for m, _, _ in ALL_LEVERS) + "`). Settings were chosen on cow, fandisk and "
          "suzanne; spot, stanford-bunny and teapot were not used to choose them (per-shape rows: "
          "`target/results/levers.md`).\n")
        nkf = [r for r in runs if r["method"] == "nkrr-field"]
        for m, title, what in ALL_LEVERS + LEVERS5:
            w(f"### Lever {title}\n")
            w(f"The variant: {what}.\n")
            if m in FIELD_LEVERS:
                w("On the field surface, against nkrr-field (the regression is not tuned under the Poisson surface).\n")
                w(lever_table(nkf, [r for r in lv if r["method"] == m], SIZES, "nkrr-field", m))
            else:
                w(lever_table(nk, [r for r in lv + runs if r["method"] == m], SIZES, "default", m))
            # Where it matters most, drawn (the harder set too where the lever ran there).
            base = nkf if m in FIELD_LEVERS else nk
            cands = lever_candidates(m, base, lv + runs, "data")
            if hard and m not in FIELD_LEVERS:
                hr = hard[0]["runs"]
                cands += lever_candidates(m, [r for r in hr if r["method"] == "nkrr"], hr, "hard")
            drawn = lever_render(work, m, cands)
            if drawn:
                path, g, l = drawn
                ref = "nkrr-field" if m in FIELD_LEVERS else "the default"
                w(f"\nCD1 x100 where {ref} is furthest ahead of the variant: {g[1]}-{g[2]} ({m} {fmt(g[5])} against "
                  f"{fmt(g[4])}), drawn below (rows: the truth, {m}, {ref}); where the variant is furthest ahead: "
                  f"{l[1]}-{l[2]} ({fmt(l[5])} against {fmt(l[4])}).\n")
                w(f"![{m} on {g[1]}-{g[2]}: the truth, {m}, {ref}](img/{os.path.basename(path)})\n")
            w("")
        w("### Lever 6: another prior\n")
        if prior:
            w(prior_section(prior, runs, hard))
        else:
            w("Not run in this report (phase `prior` left out of `--phases`, or no second prior at the path given; the notes below say which).\n")
        if paper:
            w("### All of them: the paper's method\n")
            w("`nkrr-paper`: the paper's tuning (all pairs, lr 0.1, 100 steps, lowest training error), "
              "its pairs, no fit, every point and piece kept.\n")
            w(lever_table(nkf, paper["runs"], ["500", "3k"], "nkrr-field", "nkrr-paper"))
            w("")
    else:
        w("Not run (phase `levers`).\n")

    w("## The harder set\n")
    if hard:
        hruns, hspsr = hard
        hipsr = ipsr_rows(os.path.join(work, "hard", "ipsr", "ipsr.jsonl"))
        hrows = hruns["runs"] + hspsr + hipsr
        hshapes = sorted({r["shape"] for r in hruns["runs"]})
        w("3000-point clouds of the six eval meshes made by `scripts/hard_clouds.py` (seeded): "
          "`noise` (Gaussian sigma 0.02 x the longest bbox side, four times the eval clouds'), "
          "`outliers` (the clean 3k cloud with 10 % of its points replaced by points uniform in the "
          "padded box), `falloff` (density falling 55x along the longest axis), `onesided` (only "
          "what a camera on the +x+y+z diagonal sees). Screened Poisson as above. "
          "`*-keep-outliers`: without the stray-point filter and the removal of unsupported pieces. "
          "These clouds decided one thing, the form of the stray-point filter (local density instead of "
          "the textbook global filter, which took the sparse end of the falloff clouds: `src/outliers.rs`); "
          "no setting's value was tuned on them (the fit's noise rule was chosen on other noisy clouds of "
          "cow, fandisk and suzanne: `scripts/hard_clouds.py --noise-tuning`).\n")
        hpeers = ["spsr"] + (["ipsr"] if hipsr else [])
        w("| cloud | method | CD1 x100 | F-score | NC | nkrr beats SPSR on CD1 / F |"
          + (" nkrr beats iPSR on CD1 / F |" if hipsr else ""))
        w("|---|---|---|---|---|---|" + ("---|" if hipsr else ""))
        total = {peer: [0, 0] for peer in hpeers}  # clouds where nkrr wins CD1, F, over all kinds
        for kind in HARD_KINDS:
            krows = [r for r in hrows if r["size"] == kind]
            for m in ["network", "network-keep-outliers", "nkrr", "nkrr-keep-outliers"] + hpeers:
                mm = mean_metrics([r for r in krows if r["method"] == m])
                extra = [""] * len(hpeers)
                if m == "nkrr":
                    extra = []
                    for peer in hpeers:
                        c = wins(krows, "nkrr", peer, hshapes, "cd1x100", True)
                        f = wins(krows, "nkrr", peer, hshapes, "fscore", False)
                        total[peer][0] += c[0]
                        total[peer][1] += f[0]
                        extra.append(f"{c[0]}/{c[1]} / {f[0]}/{f[1]}")
                w(f"| {kind} | {LABEL.get(m, m)} | {fmt(mm[0])} | {fmt(mm[1])} | {fmt(mm[2])} | {' | '.join(extra)} |")
        n = len(HARD_KINDS) * len(hshapes)
        w(f"\nOver all {n} harder clouds nkrr beats screened Poisson on CD1 on {total['spsr'][0]} and on F-score on "
          f"{total['spsr'][1]}. Per-cloud rows: `target/results/hard-eval.md` and `target/results/hard/spsr/spsr.jsonl`.\n")
        if hipsr:
            w(f"Against iPSR (as above): nkrr's CD1 is lower on {total['ipsr'][0]} and its F-score higher on "
              f"{total['ipsr'][1]} of the {n}.\n")
        for m, title, what in LEVERS4 + LEVERS5:
            w(f"Lever {title}, on the harder set. The variant: {what}.\n")
            w(lever_table([r for r in hruns["runs"] if r["method"] == "nkrr"],
                          [r for r in hruns["runs"] if r["method"] == m], HARD_KINDS, "default", m))
            w("")
    else:
        w("Not run (phase `hard`).\n")

    w("## Sparse clouds: never worse than the network alone (issue 26)\n")
    if sparse:
        w("The regression is tuned on every cloud under 2,000 points. The 1k and 1,500-point clouds of the six "
          "shapes (`scripts/results_clouds.py`, seeds 11 and 12, the eval noise) and the 500-point ones above; "
          "`nkrr-zero-mean` is the paper's field (no prior mean). Issue 26 asks that no shape be worse than the "
          "network alone by more than 0.01 CD1 x100 at any size.\n")
        w(sparse_section(sparse, runs))
    else:
        w("Not run (phase `sparse`).\n")

    w("## Thin walls and open shells: never worse than the network alone (issue 26)\n")
    if thin:
        w("Cups whose wall and floor are 2.5 % (cup020), 1.875 % (cup015) and 1.25 % (cup010) of their height thick, "
          "and open shells, sheets with no thickness (bowl, crate: a box without its lid, shell: half an "
          "ellipsoid with windows like a car's body, tunnel: half a tube; their ground truth is the open sheet) "
          "(`scripts/thin_clouds.py`: the eval clouds' conventions and noise, seed 11), made to aim at thin "
          "walls and not part of the eval set; the shells chose `BETWEEN_SHEETS_DEPTH` (docs/poisson.md, "
          "\"Open shells\"). CD1 x100 / F-score; SPSR and iPSR run as on the other "
          "clouds (iPSR where `scripts/ipsr_runs.py --data target/results/thin --sizes 3k,10k --out "
          "target/results/thin/ipsr` was run). Issue 26 asks that nkrr be no worse than the network "
          "alone by more than 0.01 CD1 x100.\n")
        w(thin_section(thin))
    else:
        w("Not run (phase `thin`).\n")

    w("## Does a re-run reproduce the numbers?\n")
    t, d = compare_table(runs, rerun["runs"], "first / re-run", times=True)
    w(f"`network` and `nkrr` on {', '.join(RERUN_SHAPES)} at 3k, run a second time by a separate `nkrr eval` process "
      "(first run / re-run):\n")
    w(t)
    w(f"\nLargest absolute difference: CD1 x100 {fmt(d['cd1x100'], 4)}, F-score "
      f"{fmt(d['fscore'], 4)}, NC {fmt(d['nc'], 4)}, IoU {fmt(d['iou'], 4)}. " + (
        "The metrics are identical: reconstruction (seeded subsampling, Z init and Adam) and "
        "metrics (seeded samples) are deterministic here, so only the times move with the load."
        if all(v == 0 for v in d.values() if v is not None) else
        "The re-run moves the metrics by the amounts above.") + "\n")
    t, d = compare_table(runs, seeds, "seed 1 / seed 2")
    w("The metrics' own sampling noise, for scale: the same meshes from the main run scored "
      "again with other surface and volume samples (`nkrr metrics GT MESH --seed 2`; "
      "`nkrr eval` uses seed 1):\n")
    w(t)
    w(f"\nLargest absolute difference between the two samplings: CD1 x100 {fmt(d['cd1x100'], 4)}, "
      f"F-score {fmt(d['fscore'], 4)}, NC {fmt(d['nc'], 4)}, IoU {fmt(d['iou'], 4)}: differences "
      "between methods smaller than this are noise.\n")

    w("## Time per stage\n")
    w("![time per stage](img/results-stages.png)\n")
    st = ["| size | method | features | pairs | tuning | mesh | total |", "|---|---|---|---|---|---|---|"]
    for size in SIZES:
        for m in ("network", "nkrr"):
            rs = [r for r in runs if r["method"] == m and r["size"] == size]
            st.append(f"| {size} | {m} | " + " | ".join(
                fmt(mean([r["times"].get(s) for r in rs]), 1) for s in
                ("features", "pairs", "tuning", "mesh", "total")) + " |")
    w("Mean seconds over the six shapes (`nkrr eval`'s own stage times):\n")
    w("\n".join(st))
    w("")

    w("## Speed against screened Poisson\n")
    if bench:
        w("`scripts/bench.py` (also `scripts/bench.sh`): `nkrr reconstruct` three times per cloud on "
          "clouds of spot at the eval noise (500 / 3k / 10k from the eval set, 100k a scaling cloud) "
          "and screened Poisson (`tests/peers/spsr.py`, depth 8, PCA normals and orientation, "
          "reading excluded) three times on the same clouds in the same run: the median wall "
          "times, the stage times of the median nkrr run, and the ratio, which is what survives a "
          "change of machine. Run alone on the machine, unlike the evals above.\n")
        w("| points | method | features | pairs | tuning | mesh | fit | end to end s | screened Poisson s | ratio |")
        w("|---|---|---|---|---|---|---|---|---|---|")
        for r in bench:
            st = " | ".join(fmt(r["stages_s"].get(k), 2) if k in r["stages_s"] else "-"
                            for k in ("features", "pairs", "tuning", "mesh", "fit"))
            w(f"| {r['size']} | {r['method']} | {st} | {fmt(r['wall_s'], 2)} | {fmt(r['spsr_s'], 2)} | "
              f"{r['ratio']:.1f}x |")
        w("")
    else:
        w("Not run (phase `bench`).\n")

    w("## Scaling: time and peak memory vs cloud size\n")
    w("Synthetic noisy clouds: N points uniform on `spot.obj` with the eval noise (sigma = 0.005 x "
      "the longest bbox side, seed 4), `nkrr reconstruct --method network|nkrr` at the defaults "
      "(resolution 128), timed by `/usr/bin/time -v` (wall clock and peak RSS of the process, "
      "file reading and GLB writing included). The pipeline gives the encoder (and so the KRR) "
      "a uniform subsample of at most 100k points (`--max-points`), so above 100k only reading "
      "and subsampling grow.\n")
    nk = [r for r in scale if r["method"] == "nkrr"]
    st = ["| points | network s | network peak MB | nkrr s | nkrr peak MB | nkrr stages (s) |",
          "|---|---|---|---|---|---|"]
    by = {(r["method"], r["points"]): r for r in scale}
    for n in SCALE_SIZES:
        a, b = by.get(("network", n)), by.get(("nkrr", n))
        if not a and not b:
            continue
        stages = ", ".join(f"{k} {v:.1f}" for k, v in b["stages"].items()) if b else "not run"
        st.append(f"| {n:,} | {fmt(a and a['wall_s'], 1)} | {fmt(a and a['peak_rss_mb'], 0)} | "
                  f"{fmt(b and b['wall_s'], 1)} | {fmt(b and b['peak_rss_mb'], 0)} | {stages} |")
    w("\n".join(st))
    maxn = max((r["points"] for r in nk), default=0)
    if maxn < SCALE_SIZES[-1]:
        w(f"\n**Cut for time:** nkrr at the defaults was run up to {maxn:,} points only "
          f"(`--scale-nkrr-max {nkrr_max}`): on this machine one run costs minutes there, and the "
          "whole report had to fit in under an hour. Above 10k the KRR's O(n m^2) work grows with "
          "n up to the 100k subsample.")
    w("\n![scaling](img/results-scaling.png)\n")

    w("## Reconstructions beside the ground truth\n")
    w("Rows: ground truth, network, nkrr, SPSR; columns: front, side, top, 3/4 view; "
      "3k-point clouds (`scripts/render.py`).\n")
    w(f"![renders](img/{os.path.basename(render_png)})\n")
    if before_png:
        w("### The worst shape, before and after\n")
        w(f"{before_png[1]} at 500 points, where nkrr was furthest behind the network with the paper's method: "
          "rows ground truth, the network, the paper's method (`nkrr-paper`), nkrr now.\n")
        w(f"![before and after](img/{os.path.basename(before_png[0])})\n")
    scenes_section(w, scenes)
    open(os.environ.get("RESULTS_MD", "docs/results.md"), "w").write("\n".join(L) + "\n")
    log("wrote " + os.environ.get("RESULTS_MD", "docs/results.md"))


def prior_section(prior, runs, hard):
    """Lever 6's tables: the shipped prior (default) against the other one, for the network and
    nkrr, on the eval clouds and the harder ones; then held-out IoU."""
    L = [f"`{prior['other']}` (`training/train_v2.sh`, see `training/report_v2.md`) in place of the shipped "
         "prior (`nkrr eval --weights`), everything else at the defaults, on the same clouds.\n"]
    for m in ("network", "nkrr"):
        base = [r for r in runs if r["method"] == m]
        var = [r for r in prior["eval"]["runs"] if r["method"] == m]
        L.append(f"{m}, eval clouds:\n")
        L.append(lever_table(base, var, SIZES, f"{m} (shipped prior)", f"{m} (other prior)") + "\n")
    if hard:
        for m in ("network", "nkrr"):
            base = [r for r in hard[0]["runs"] if r["method"] == m]
            var = [r for r in prior["hard"]["runs"] if r["method"] == m]
            L.append(f"{m}, harder clouds:\n")
            L.append(lever_table(base, var, HARD_KINDS, f"{m} (shipped prior)", f"{m} (other prior)") + "\n")
    L.append("Held-out IoU (`training/compare.py`: 32 procedural shapes from seeds no training saw, 3000 points, "
             "noise 0.005; `falloff`: density falling 55x, `outliers`: 10 % stray points, `new`: the second "
             "stream's new families; `8 rotations`: logits averaged over the 8 axis rotations, eight times the "
             "network's cost):\n")
    L.append("| prior | rotations | clean | falloff | outliers | new families |")
    L.append("|---|---|---|---|---|---|")
    for r in prior["compare"]:
        L.append(f"| `{r['prior']}` | {'8' if r['tta'] else '1'} | {r['clean']:.4f} | {r['falloff']:.4f} | "
                 f"{r['outliers']:.4f} | {r['new']:.4f} |")
    return "\n".join(L) + "\n"


def spsr_wall(work):
    p = os.path.join(work, "spsr", "wall")
    return float(open(p).read()) if os.path.exists(p) else None


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", default="target/results")
    ap.add_argument("--fresh", action="store_true")
    ap.add_argument("--redo", default="")
    ap.add_argument("--ablation-shapes", default="cow,fandisk,spot,stanford-bunny,suzanne,teapot")
    ap.add_argument("--scale-nkrr-max", type=int, default=1000000,
                    help="largest scaling cloud nkrr (defaults) runs on; the network runs on all")
    ap.add_argument("--render-shapes", default="stanford-bunny,fandisk")
    ap.add_argument("--other-prior", default="training/prior-v2.safetensors",
                    help="lever 6: the prior compared with the shipped one (phase prior)")
    ap.add_argument("--phases", default="main,spsr,rerun,scaling,ablations,levers,hard,prior,render,bench,scenes,sparse,thin,report",
                    help="phases to run (others are read from WORK if there)")
    a = ap.parse_args()
    work = a.work
    redo = set(a.redo.split(",")) - {""}
    if a.fresh:
        redo = {"main", "spsr", "rerun", "scaling", "ablations", "levers", "hard", "prior", "render", "bench", "scenes", "sparse", "thin"}
    files = {"main": ["main.json", "main.wall"], "spsr": ["spsr"],
             "rerun": ["rerun.json", "rerun.wall"], "scaling": ["scaling.jsonl"],
             "ablations": ["ablations.json", "ablations.wall"], "bench": ["bench"],
             "levers": ["levers.json", "levers.wall", "levers-field.json", "levers-field.wall", "paper.json", "paper.wall"],
             "hard": ["hard-eval.json", "hard-eval.wall"],
             "prior": ["prior.json", "prior.wall", "prior-hard.json", "prior-hard.wall", "prior-compare.json"],
             "scenes": ["scenes"], "sparse": ["sparse.json", "sparse.wall"],
             "thin": ["thin-eval.json", "thin-eval.wall", "thin/spsr"]}
    for p in redo:
        for f in files.get(p, []):
            q = os.path.join(work, f)
            shutil.rmtree(q) if os.path.isdir(q) else (os.path.exists(q) and os.remove(q))
        if p == "ablations":
            # The per-shape runs too, or a redo would read them back unchanged.
            for q in glob.glob(os.path.join(work, "ablations-*")):
                os.remove(q)
        for img, phase in (("results-render.png", "render"), ("results-before-after.png", "levers")):
            if p == phase and os.path.exists(os.path.join(IMG, img)):
                os.remove(os.path.join(IMG, img))
        if p in ("levers", "main", "hard"):
            # Each lever's render follows the runs that chose its cloud.
            for q in glob.glob(os.path.join(IMG, "results-lever-*.png")):
                os.remove(q)
    phases = a.phases.split(",")
    abl_shapes = a.ablation_shapes.split(",")
    if "main" in phases:
        eval_phase(work, "main", ["--sizes", ",".join(SIZES), "--methods", "network,nkrr,nkrr-field",
                                  "--keep-meshes"])
    if "spsr" in phases:
        spsr_phase(work)
    if "rerun" in phases:
        eval_phase(work, "rerun", ["--sizes", "3k", "--methods", "network,nkrr",
                                   "--shapes", ",".join(RERUN_SHAPES)])
    if "rerun" in phases:
        seeds_phase(work)
    if "scaling" in phases:
        scaling_phase(work, a.scale_nkrr_max)
    if "ablations" in phases:
        ablations_phase(work, abl_shapes, run=True)
    if "render" in phases:
        render_phase(work, a.render_shapes.split(","), "3k")
    if "bench" in phases:
        bench_phase(work, run=True)
    levers = paper = hard = before = None
    if "levers" in phases or "report" in phases:
        if "levers" in phases or os.path.exists(os.path.join(work, "paper.wall")):
            levers, paper = levers_phase(work)
            before = before_render(work, paper)
    if "hard" in phases or ("report" in phases and os.path.exists(os.path.join(work, "hard-eval.wall"))):
        hard = hard_phase(work)
    prior = None
    if "prior" in phases or ("report" in phases and os.path.exists(os.path.join(work, "prior-compare.json"))):
        prior = prior_phase(work, a.other_prior)
    scenes = scenes_phase(work, run="scenes" in phases)
    sparse = sparse_phase(work, run="sparse" in phases)
    thin = thin_phase(work, run="thin" in phases)
    if "report" in phases:
        abl = ablations_phase(work, abl_shapes, run=False)
        if abl:
            abl_shapes = sorted({r["shape"] for r in abl["runs"]})
        report(work, load_eval(os.path.join(work, "main")), spsr_phase(work),
               load_eval(os.path.join(work, "rerun")), seeds_phase(work), scaling_phase(work, a.scale_nkrr_max),
               abl, abl_shapes, a.scale_nkrr_max, render_phase(work, a.render_shapes.split(","), "3k"),
               bench_phase(work, run=False), levers, paper, hard, before, prior, scenes, sparse, thin)


def before_render(work, paper):
    """Renders the 500-point shape where the paper's method trailed the network most: ground
    truth, network, nkrr-paper, nkrr (docs/img/results-before-after.png)."""
    main = load_eval(os.path.join(work, "main"))["runs"]
    net = {r["shape"]: r["cd1x100"] for r in main if r["size"] == "500" and r["method"] == "network"}
    gap = {r["shape"]: r["cd1x100"] - net[r["shape"]] for r in paper["runs"] if r["size"] == "500" and r["shape"] in net}
    shape = max(gap, key=gap.get)
    out = os.path.join(IMG, "results-before-after.png")
    if not os.path.exists(out):
        inputs = [os.path.join(work, "data", f"{shape}.obj"), os.path.join(work, f"main-{shape}-500-network.glb"),
                  os.path.join(work, f"paper-{shape}-500-nkrr-paper.glb"), os.path.join(work, f"main-{shape}-500-nkrr.glb")]
        sh([".venv/bin/python", "scripts/render.py", *inputs, "-o", out, "--size", "150", "--samples", "150000"])
    return out, shape

if __name__ == "__main__":
    main()
