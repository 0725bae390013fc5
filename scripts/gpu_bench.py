#!/usr/bin/env python3
"""The GPU benchmark (issue 27): the native CLI and the web page (headless Chromium, WebGPU) on the
same clouds of 500 / 3k / 10k / 100k points, each method, with stage times, inside one deadline.

    scripts/gpu_bench.sh [--nkrr BIN] [--dist DIR] [--clouds DIR] [--out DIR]
                         [--sizes 500,3k,10k,100k] [--methods network,nkrr] [--deadline-s 280]
                         [--gpu real|swiftshader] [--chromium PATH] [--node PATH] [--dry-run]

For each size (small first) and method: one `nkrr reconstruct` (its wall time: the whole process,
start-up, reading, adapter, stages and writing; the stage times are the CLI's own summary line,
parsed by scripts/bench.py), then the same cloud and method in the page (scripts/gpu_bench_page.mjs:
wall from pressing Reconstruct to idle; the stages are the worker's own). A run is skipped, with a
note, when the deadline would pass before it ends (estimated from the last run of the same half
and method, scaled by the square root of the points); a run still going at the deadline is
stopped. Writes OUT/gpu-bench.md (a Markdown table, for docs/speed.md) and OUT/gpu-bench.json;
prints the table.

The browser half needs Node, playwright-core (the repository's node_modules) and a Chromium: with
none found it is skipped with a note saying what to set (CHROMIUM=/path/to/chrome, NODE=...), and
the native half still runs. --dry-run: sizes 500 and 3k, SwiftShader in Chromium (the wrapper picks
lavapipe for the CLI): a check of the script on a CPU-only machine, not a GPU measurement.
"""
import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench import cloud_path as bench_cloud, parse_summary  # noqa: E402  (the CPU benchmark's clouds and parsing)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
POINTS = {"500": 500, "3k": 3000, "10k": 10000, "100k": 100000}
# Columns, in pipeline order: the page's worker adds setup and glb around the shared stages. A
# stage reported by the CLI or the page and missing here still gets a column (`columns`), so a
# new stage never silently drops out of the table's times.
STAGES = ["setup", "outliers", "features", "pairs", "tuning", "mesh", "poisson", "fit", "glb"]
DATA_PREFIX = "target/results/data/"
PLAYWRIGHT = os.path.join(ROOT, "node_modules/playwright-core")


def log(msg):
    print(f"[gpu-bench] {msg}", file=sys.stderr, flush=True)


def cloud_path(clouds, size):
    """The cloud of SIZE points: CLOUDS/… as laid out by scripts/results_clouds.py (bench.py's
    clouds of spot, relative to its data folder), else the committed eval cloud (3k, 10k)."""
    full = bench_cloud("spot", size)
    rel = full[len(DATA_PREFIX):] if full.startswith(DATA_PREFIX) else full
    for p in (os.path.join(clouds, rel), os.path.join(ROOT, "tests/data/eval", os.path.basename(rel))):
        if os.path.isfile(p):
            return p
    return None


def native_adapter(nkrr):
    try:
        p = subprocess.run([nkrr, "gpu"], capture_output=True, text=True, timeout=60)
        lines = (p.stdout + p.stderr).strip().splitlines()
        return lines[0] if lines else f"(nkrr gpu printed nothing, exit {p.returncode})"
    except (OSError, subprocess.TimeoutExpired) as e:
        return f"(nkrr gpu failed: {e})"


def run_native(nkrr, cloud, method, timeout, tmp):
    out = os.path.join(tmp, "out.glb")
    cmd = [nkrr, "reconstruct", cloud, "-o", out, "--method", method]
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"ok": False, "note": f"stopped at the deadline after {time.perf_counter() - t0:.0f} s"}
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        return {"ok": False, "wall_s": wall, "note": f"exit {p.returncode}: {(p.stderr.strip().splitlines() or [''])[-1][:200]}"}
    stages = parse_summary(p.stdout + p.stderr)
    return {"ok": True, "wall_s": wall, "total_s": stages.pop("total", None), "stages": stages}


def run_page(node, chromium, dist, cloud, method, gpu, timeout):
    cmd = [node, os.path.join(ROOT, "scripts/gpu_bench_page.mjs"), "--dist", dist, "--cloud", cloud,
           "--method", method, "--gpu", gpu, "--chromium", chromium, "--timeout-s", str(max(1, int(timeout) - 5))]
    env = dict(os.environ)
    if gpu == "swiftshader":
        env.pop("VK_DRIVER_FILES", None)  # Chromium's own SwiftShader, as in the browser tests
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=ROOT, env=env)
    except subprocess.TimeoutExpired:
        return {"ok": False, "note": f"stopped at the deadline after {time.perf_counter() - t0:.0f} s"}
    process_s = time.perf_counter() - t0
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
    if not lines:
        return {"ok": False, "process_s": process_s, "note": f"no result (exit {p.returncode}): {p.stderr.strip()[-300:]}"}
    r = json.loads(lines[-1])
    r["process_s"] = process_s
    if not r.get("ok"):
        r["note"] = r.get("message") or "failed"
    if r.get("errors"):
        r["errors"] = r["errors"][:5]
    return r


def find_browser(a):
    """(node, chromium, why-not): the browser half's programs, or why it cannot run."""
    node = a.node or shutil.which("node")
    chromium = a.chromium
    if not chromium:
        for c in ("/usr/bin/chromium", "chromium", "chromium-browser", "google-chrome", "chrome"):
            chromium = shutil.which(c) if not c.startswith("/") else (c if os.path.exists(c) else None)
            if chromium:
                break
    missing = []
    if not node:
        missing.append("no Node (set NODE=/path/to/node)")
    if not chromium or not os.path.exists(chromium):
        missing.append("no Chromium (set CHROMIUM=/path/to/chrome)")
    if not os.path.isdir(PLAYWRIGHT):
        missing.append("no node_modules/playwright-core in the repository (npm ci, or carry that folder)")
    if not os.path.isfile(os.path.join(a.dist, "index.html")):
        missing.append(f"no built web app at {a.dist} (NKRR_BUILD_ONLY=1 scripts/serve.sh)")
    return node, chromium, "; ".join(missing)


def page_adapter_name(r):
    """The page's adapter: wgpu's description (a browser's adapter is "unnamed adapter (…)")
    with WebGPU's GPUAdapterInfo (vendor, architecture, description) after it."""
    ad = r.get("adapter_worker") or r.get("adapter_page")
    info = r.get("adapter_info") or {}
    words = " ".join(v for v in (info.get("vendor"), info.get("architecture"), info.get("description")) if v)
    if not ad:
        return None
    return f"{words}: {ad}" if words else ad


def fmt(v, digits=2):
    return "-" if v is None else f"{v:.{digits}f}"


def short(adapter):
    return (adapter or "?").split(" (")[0].split(":")[0]


def columns(rows):
    """STAGES, then any other stage some run reported, in the order first seen."""
    cols = list(STAGES)
    for r in rows:
        for res in (r["native"], r["page"]):
            for k in res.get("stages", {}) if res.get("ok") else ():
                if k not in cols:
                    cols.append(k)
    return cols


def table(rows, info):
    cols = columns(rows)
    lines = [
        f"Native adapter: {info['native_adapter']}  ",
        f"Page adapter: {info['page_adapter'] or '-'}{' (software)' if info.get('page_software') else ''}  ",
        f"Machine: {info['cores']} cores; GPU mode: {info['gpu']}{' (dry run: not a GPU measurement)' if info['dry_run'] else ''}; "
        f"deadline {info['deadline_s']:.0f} s, used {info['elapsed_s']:.0f} s",
        "",
        f"| points | method | run | adapter | {' | '.join(cols)} | wall s | page/native |",
        "|---" * (len(cols) + 6) + "|",
    ]
    for r in rows:
        nat = r["native"]
        for half, res in (("native", nat), ("page", r["page"])):
            if not res.get("ok"):
                lines.append(f"| {r['size']} | {r['method']} | {half} | - | {' | '.join('-' for _ in cols)} | - | {res.get('note', 'not run')} |")
                continue
            st = " | ".join(fmt(res["stages"].get(k)) for k in cols)
            adapter = info["native_adapter"] if half == "native" else page_adapter_name(res)
            ratio = "" if half == "native" else (f"{res['wall_s'] / nat['wall_s']:.2f}x" if nat.get("ok") else "-")
            lines.append(f"| {r['size']} | {r['method']} | {half} | {short(adapter)} | {st} | {res['wall_s']:.2f} | {ratio} |")
    notes = info.get("notes") or []
    if notes:
        lines.append("")
        lines += [f"- {n}" for n in notes]
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--nkrr", default=os.environ.get("NKRR", os.path.join(ROOT, "target/release/nkrr")))
    ap.add_argument("--dist", default=os.environ.get("DIST", os.path.join(ROOT, "dist")))
    ap.add_argument("--clouds", default=os.environ.get("CLOUDS", os.path.join(ROOT, "target/results/data")))
    ap.add_argument("--out", default=os.environ.get("OUT_DIR", os.path.join(ROOT, "target/gpu-bench")))
    ap.add_argument("--sizes", default=None, help="default 500,3k,10k,100k (dry run: 500,3k)")
    ap.add_argument("--methods", default="network,nkrr")
    ap.add_argument("--deadline-s", type=float, default=float(os.environ.get("DEADLINE_S", 280)))
    ap.add_argument("--gpu", choices=["real", "swiftshader"], default=None, help="Chromium's WebGPU adapter (dry run: swiftshader)")
    ap.add_argument("--chromium", default=os.environ.get("CHROMIUM"))
    ap.add_argument("--node", default=os.environ.get("NODE"))
    ap.add_argument("--no-page", action="store_true", help="the native half only")
    ap.add_argument("--dry-run", action="store_true", default=os.environ.get("DRY_RUN") == "1")
    a = ap.parse_args(argv)
    start = time.monotonic()
    sizes = (a.sizes or ("500,3k" if a.dry_run else "500,3k,10k,100k")).split(",")
    gpu = a.gpu or ("swiftshader" if a.dry_run else "real")
    methods = a.methods.split(",")
    for s in sizes:
        if s not in POINTS:
            ap.error(f"--sizes: {s} is not one of {', '.join(POINTS)}")
    for m in methods:
        if m not in ("network", "nkrr"):
            ap.error(f"--methods: {m} is not network or nkrr")
    if not os.access(a.nkrr, os.X_OK):
        ap.error(f"--nkrr {a.nkrr}: not an executable (build it with cargo build --release, or set NKRR=)")
    os.makedirs(a.out, exist_ok=True)
    deadline = start + a.deadline_s
    notes = []
    if a.dry_run:
        notes.append("dry run: CPU adapters (lavapipe natively, SwiftShader in Chromium); not a GPU measurement")

    native_ad = native_adapter(a.nkrr)
    log(f"native adapter: {native_ad}")
    node, chromium, why_not = (None, None, "--no-page") if a.no_page else find_browser(a)
    if why_not:
        notes.append(f"browser half not run: {why_not}")
        log(f"browser half not run: {why_not}")
    else:
        log(f"browser half: {chromium} (WebGPU on {gpu})")

    rows = []
    last = {}  # (half, method) -> (points, seconds it took)

    def budget(half, method, size):
        """Seconds left, or None when the run is estimated to end after the deadline."""
        left = deadline - time.monotonic()
        if left < 3:
            return None
        if (half, method) in last:
            pts, secs = last[(half, method)]
            # Square-root scaling: the mesh stage's time follows the resolution, not the points,
            # and the tuning's pairs are subsampled; linear scaling skipped runs that fitted.
            if secs * (POINTS[size] / pts) ** 0.5 > left:
                return None
        return left

    page_adapter, page_software = None, False
    with tempfile.TemporaryDirectory() as tmp:
        for s in sizes:
            cloud = cloud_path(a.clouds, s)
            for m in methods:
                row = {"size": s, "points": POINTS[s], "method": m, "cloud": cloud}
                if not cloud:
                    note = f"no cloud for {s} under {a.clouds} (scripts/results_clouds.py makes them)"
                    row["native"] = row["page"] = {"ok": False, "note": note}
                    rows.append(row)
                    continue
                def timed(half, run):
                    """One half's run within the deadline's budget, timed for the next estimate."""
                    left = budget(half, m, s)
                    if left is None:
                        return {"ok": False, "note": "skipped: would end after the deadline"}
                    log(f"{half} {m} on {s} points")
                    t0 = time.monotonic()
                    out = run(left)
                    last[(half, m)] = (POINTS[s], time.monotonic() - t0)
                    return out

                row["native"] = timed("native", lambda left: run_native(a.nkrr, cloud, m, left, tmp))
                if why_not:
                    row["page"] = {"ok": False, "note": "browser half not run (see below)"}
                else:
                    row["page"] = timed("page", lambda left: run_page(node, chromium, a.dist, cloud, m, gpu, left))
                    if "skipped" not in row["page"].get("note", ""):
                        page_adapter = page_adapter or page_adapter_name(row["page"])
                        page_software = page_software or bool(row["page"].get("software"))
                rows.append(row)
                for half in ("native", "page"):
                    r = row[half]
                    log(f"  {half}: " + (f"{r['wall_s']:.2f} s" if r.get("ok") else r.get("note", "")))
    if gpu == "real" and "(Cpu" in native_ad:
        notes.append("the CLI got a CPU adapter although --gpu real: wgpu found no GPU (VK_DRIVER_FILES, the Vulkan loader: docs/speed.md)")
    if gpu == "real" and page_software:
        notes.append("the page got a software adapter although --gpu real: Chromium did not reach the GPU")
    info = {"native_adapter": native_ad, "page_adapter": page_adapter, "page_software": page_software,
            "gpu": gpu, "dry_run": a.dry_run, "cores": os.cpu_count(), "deadline_s": a.deadline_s,
            "elapsed_s": time.monotonic() - start, "notes": notes, "nkrr": a.nkrr, "chromium": chromium,
            "sizes": sizes, "methods": methods}
    md = table(rows, info)
    with open(os.path.join(a.out, "gpu-bench.md"), "w") as f:
        f.write(md)
    with open(os.path.join(a.out, "gpu-bench.json"), "w") as f:
        json.dump({**info, "rows": rows}, f, indent=1)
    print(md, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
