"""The error split of scripts/eval_metrics.py on synthetic cases whose answer is known.

    .venv-formats/bin/python -m pytest -q -p no:cacheprovider scripts/test_eval_metrics.py

The ground truth is a closed cube (side 0.5, x in [-0.5, 0]) and an open square sheet (side 0.5)
in the plane x = 0.5, facing it: its bounding box is already the unit cube's normalisation
(centre 0, longest side 1), so distances here are the metric's. The sheet is 0.25 of the 1.75
of area (1/7). Moved along its normal by 3 tau, every point of the sheet is 3 tau from where it
was and far from the cube; the cube's samples stay within tau of each other (100k samples on
1.75: about 0.002 apart).
"""
import json
import os
import subprocess
import sys

import numpy as np
import pytest
import trimesh

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from eval_metrics import TAU, metrics, split  # noqa: E402

SHEET_SHARE = 0.25 / 1.75
SIDES = ("precision", "completeness")


def cube():
    return trimesh.creation.box(extents=(0.5, 0.5, 0.5),
                                transform=trimesh.transformations.translation_matrix((-0.25, 0, 0)))


def sheet(x):
    v = np.array([[x, -0.25, -0.25], [x, 0.25, -0.25], [x, 0.25, 0.25], [x, -0.25, 0.25]])
    return trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False)


def scene(sheet_x=0.5, with_sheet=True):
    parts = [cube()] + ([sheet(sheet_x)] if with_sheet else [])
    return trimesh.util.concatenate(parts)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("split")
    out = {}
    for name, mesh in {
        "gt": scene(),
        "moved": scene(sheet_x=0.5 - 3 * TAU),  # the sheet displaced by 3 tau along its normal
        "missing": scene(with_sheet=False),  # the sheet left out of the reconstruction
    }.items():
        out[name] = str(d / f"{name}.obj")
        mesh.export(out[name])
    return out


@pytest.fixture(scope="module")
def runs(files):
    return {k: metrics(files["gt"], files[k], samples=True) for k in ("gt", "moved", "missing")}


def test_the_frame_is_the_unit_cube(files):
    lo, hi = trimesh.load(files["gt"], force="mesh", process=False).bounds
    assert np.allclose(lo, [-0.5, -0.25, -0.25]) and np.allclose(hi, [0.5, 0.25, 0.25])


def test_truth_against_itself(runs):
    row, _ = runs["gt"]
    for p in ("precision_", "completeness_", ""):
        # 0 with these seeds; a gap of tau in 100k samples (at the sheet's corners) is possible
        assert row[p + "beyond_share"] <= 1e-4, row
        assert row[p + "beyond_cd_share"] < 0.01, row
        # only the sampling's spacing: well inside tau
        assert 0 < row[p + "within_mean_x100"] < 0.3 * 100 * TAU, row
    assert row["fscore"] == 1.0


def test_one_part_displaced_by_three_tau(runs):
    row, S = runs["moved"]
    for side in SIDES:  # the displaced sheet is extra (precision) and its place empty (completeness)
        assert abs(row[side + "_beyond_share"] - SHEET_SHARE) < 0.01, (side, row)
        # beyond: the displacement (nearest samples: a little more); within: the spacing
        assert 3 * TAU <= row[side + "_beyond_mean_x100"] / 100 < 3.3 * TAU, (side, row)
        assert row[side + "_within_mean_x100"] / 100 < 0.3 * TAU, (side, row)
        assert row[side + "_beyond_cd_share"] > 0.6, (side, row)
    assert abs(row["beyond_share"] - SHEET_SHARE) < 0.01, row
    assert row["beyond_cd_share"] > 0.6, row
    # the samples that are beyond tau are the ones on the sheet, on both surfaces
    on_sheet = S["rec_points"][:, 0] > 0.25
    assert np.array_equal(S["rec_to_gt"] >= TAU, on_sheet)
    assert np.array_equal(S["gt_to_rec"] >= TAU, S["gt_points"][:, 0] > 0.25)


def test_a_missing_part_is_on_the_completeness_side_only(runs):
    row, _ = runs["missing"]
    assert row["precision_beyond_share"] == 0, row
    assert abs(row["completeness_beyond_share"] - SHEET_SHARE) < 0.01, row
    assert row["completeness_beyond_cd_share"] > 0.9, row  # the sheet is 0.5 from the cube
    assert abs(row["beyond_share"] - SHEET_SHARE / 2) < 0.01, row


@pytest.mark.parametrize("case", ["gt", "moved", "missing"])
def test_the_split_recombines_to_cd1(runs, case):
    row, S = runs[case]
    d = {"precision": S["rec_to_gt"], "completeness": S["gt_to_rec"]}
    cd1 = 0.5 * (d["precision"].mean() + d["completeness"].mean())
    parts = {}
    for side in SIDES:  # unrounded: to float error
        s = split(d[side])
        parts[side] = ((1 - s["beyond_share"]) * (s["within_mean"] or 0.0)
                       + s["beyond_share"] * (s["beyond_mean"] or 0.0))
        assert parts[side] == pytest.approx(d[side].mean(), rel=1e-9, abs=1e-15)
        beyond = d[side][d[side] >= TAU].sum() / d[side].sum()
        assert s["beyond_cd_share"] == pytest.approx(beyond, rel=1e-9, abs=1e-15)
        assert s["beyond_share"] == pytest.approx(1 - (d[side] < TAU).mean(), abs=1e-15)
    assert 0.5 * (parts["precision"] + parts["completeness"]) == pytest.approx(cd1, rel=1e-9)
    pooled = split(np.concatenate([d["precision"], d["completeness"]]))
    assert ((1 - pooled["beyond_share"]) * (pooled["within_mean"] or 0.0)
            + pooled["beyond_share"] * (pooled["beyond_mean"] or 0.0)) == pytest.approx(cd1, rel=1e-9)

    # the rounded JSON keys: to their rounding
    def r(k):
        return row[k] or 0.0
    for p in ("precision_", "completeness_"):
        side = p[:-1]
        assert row[p + "mean_x100"] == pytest.approx(100 * d[side].mean(), abs=1e-4)
        again = (1 - r(p + "beyond_share")) * r(p + "within_mean_x100") + r(p + "beyond_share") * r(p + "beyond_mean_x100")
        assert again == pytest.approx(row[p + "mean_x100"], abs=5e-4)
    again = (1 - r("beyond_share")) * r("within_mean_x100") + r("beyond_share") * r("beyond_mean_x100")
    assert again == pytest.approx(row["cd1x100"], abs=5e-4)
    assert row["cd1x100"] == pytest.approx(
        0.5 * (row["precision_mean_x100"] + row["completeness_mean_x100"]), abs=2e-4)
    # the F-score is counted at the same tau: from the two within shares
    prec, rec = 1 - row["precision_beyond_share"], 1 - row["completeness_beyond_share"]
    assert row["fscore"] == pytest.approx(2 * prec * rec / max(prec + rec, 1e-12), abs=2e-4)


def test_split_by_hand():
    s = split([0.0, 0.005, 0.01, 0.03], tau=0.01)  # tau itself is beyond, as the F-score counts
    assert s["beyond_share"] == 0.5
    assert s["within_mean"] == pytest.approx(0.0025)
    assert s["beyond_mean"] == pytest.approx(0.02)
    assert s["beyond_cd_share"] == pytest.approx(0.04 / 0.045)
    assert split([])["beyond_cd_share"] == 0.0


def test_cli_keeps_the_old_keys_and_prints_the_new(files):
    out = subprocess.run([sys.executable, os.path.join(HERE, "eval_metrics.py"), files["gt"], files["moved"]],
                         capture_output=True, text=True, check=True)
    row = json.loads(out.stdout.strip().splitlines()[-1])
    for k in ("gt", "recon", "cd1x100", "fscore", "nc", "watertight", "faces"):
        assert k in row
    for k in ("beyond_share", "within_mean_x100", "beyond_mean_x100", "beyond_cd_share"):
        for p in ("precision_", "completeness_", ""):
            assert p + k in row
