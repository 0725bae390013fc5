"""scripts/gpu_bench.py's argument handling, deadline and table, with a fake `nkrr` and a fake
browser half (no GPU, no Chromium, well under a second):
    python3 -m pytest -q scripts/test_gpu_bench.py"""
import json
import os
import stat
import sys

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import gpu_bench  # noqa: E402

FAKE_NKRR = """#!/bin/sh
if [ "$1" = gpu ]; then echo "Fake H200 (DiscreteGpu, Vulkan, driver NVIDIA 580); max buffer 1 GiB"; exit 0; fi
echo "progress" >&2
echo "$4: 10 vertices, 16 triangles, watertight: yes; outliers 0.01s, features 0.20s, pairs 0.05s, tuning 0.40s, mesh 0.30s, poisson 0.25s, fit 0.02s, widgets 0.03s (total 1.10s); 99 field evaluations"
"""
# Stands in for `node scripts/gpu_bench_page.mjs …`: one JSON line, as that script prints.
FAKE_NODE = """#!/usr/bin/env python3
import json
print(json.dumps({"ok": True, "wall_s": 2.0, "worker_s": 1.9, "software": False,
                  "stages": {"setup": 0.1, "outliers": 0.01, "features": 0.3, "mesh": 1.2, "fit": 0.05, "glb": 0.02},
                  "adapter_worker": "unnamed adapter (DiscreteGpu, BrowserWebGpu)",
                  "adapter_info": {"vendor": "nvidia", "architecture": "hopper", "description": ""}}))
"""


def exe(path, text):
    path.write_text(text)
    path.chmod(path.stat().st_mode | stat.S_IEXEC)
    return str(path)


@pytest.fixture
def setup(tmp_path, monkeypatch):
    nkrr = exe(tmp_path / "nkrr", FAKE_NKRR)
    node = exe(tmp_path / "node", FAKE_NODE)
    chromium = exe(tmp_path / "chromium", "#!/bin/sh\n")
    dist = tmp_path / "dist"
    dist.mkdir()
    (dist / "index.html").write_text("<html></html>")
    clouds = tmp_path / "clouds"
    (clouds / "scale").mkdir(parents=True)
    for f in ("spot-500.ply", "scale/scale-100000.ply"):
        (clouds / f).write_bytes(b"ply\n")
    monkeypatch.setattr(gpu_bench, "PLAYWRIGHT", str(tmp_path))
    out = tmp_path / "out"
    args = ["--nkrr", nkrr, "--node", node, "--chromium", chromium, "--dist", str(dist),
            "--clouds", str(clouds), "--out", str(out)]
    return args, out


def rows_of(md):
    return [ln for ln in md.splitlines() if ln.startswith("| ") and not ln.startswith("| points")]


def test_table_and_json(setup, capsys):
    args, out = setup
    assert gpu_bench.main(args + ["--sizes", "500,3k,100k", "--methods", "network,nkrr"]) == 0
    md = (out / "gpu-bench.md").read_text()
    assert capsys.readouterr().out == md
    header = [ln for ln in md.splitlines() if ln.startswith("| points")][0]
    ncols = header.count("|")
    rows = rows_of(md)
    assert len(rows) == 3 * 2 * 2  # sizes x methods x (native, page)
    assert all(r.count("|") == ncols for r in rows), md
    # Every stage the CLI reports has a column: a stage the table does not know ("widgets") too.
    assert header.endswith("| fit | glb | widgets | wall s | page/native |"), header
    assert "| 500 | network | native | Fake H200 | - | 0.01 | 0.20 | 0.05 | 0.40 | 0.30 | 0.25 | 0.02 | - | 0.03 |" in md
    assert "| 500 | network | page | nvidia hopper | 0.10 | 0.01 | 0.30 | - | - | 1.20 | - | 0.05 | 0.02 | - | 2.00 |" in md
    # The 3k cloud is the committed eval cloud (tests/data/eval), found without the clouds folder.
    assert "| 3k | nkrr | native | Fake H200 |" in md
    data = json.loads((out / "gpu-bench.json").read_text())
    assert data["gpu"] == "real" and not data["dry_run"]
    assert data["page_adapter"].startswith("nvidia hopper")
    r = data["rows"][0]
    assert r["native"]["ok"] and r["native"]["total_s"] == 1.10 and "total" not in r["native"]["stages"]
    assert r["page"]["wall_s"] / r["native"]["wall_s"] > 0


def test_deadline_skips_with_a_note(setup):
    args, out = setup
    gpu_bench.main(args + ["--sizes", "500", "--deadline-s", "0"])
    md = (out / "gpu-bench.md").read_text()
    assert md.count("skipped: would end after the deadline") == 4


def test_no_browser_still_runs_native(setup, monkeypatch):
    args, out = setup
    monkeypatch.setattr(gpu_bench, "PLAYWRIGHT", "/nonexistent")
    i = args.index("--chromium")
    args[i + 1] = "/nonexistent/chrome"
    gpu_bench.main(args + ["--sizes", "500", "--methods", "network", "--dry-run"])
    md = (out / "gpu-bench.md").read_text()
    assert "browser half not run: no Chromium (set CHROMIUM=/path/to/chrome)" in md
    assert "| 500 | network | native | Fake H200 |" in md
    assert json.loads((out / "gpu-bench.json").read_text())["gpu"] == "swiftshader"


def test_bad_arguments(setup):
    args, _ = setup
    with pytest.raises(SystemExit):
        gpu_bench.main(args + ["--sizes", "7"])
    with pytest.raises(SystemExit):
        gpu_bench.main(args + ["--methods", "poisson"])
    with pytest.raises(SystemExit):
        gpu_bench.main(["--nkrr", "/nonexistent"])
