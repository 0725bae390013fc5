#!/usr/bin/env python3
"""Fuzzes nkrr's cloud readers (PLY, text XYZ/CSV/PTS, LAS, LAZ, E57) against an oracle.

What it does, per batch of cases:
  1. writes random VALID clouds in every format with writers independent of nkrr: laspy + lazrs
     for LAS/LAZ, pye57 (libE57Format) for E57, and this script's own writers for PLY and text;
  2. derives cases from each valid file: valid variants, cut files, targeted damage and random
     byte/line mutations;
  3. writes a manifest (one JSON object per line: case, file, format, expect, points, what) and
     runs the Rust checker, examples/read_oracle.rs, on it; the checker reads every file with
     nkrr::io::read_cloud and judges the result against the expectation;
  4. records the checker's verdicts, keeps the files of failing cases, deletes the batch.
While the checker reads one batch (one core), the next batch is generated (the other core).

The oracle (what each expectation means; the checker applies them):
  exact           a valid file: nkrr must read exactly the points written (count, order, positions
                  within f32 precision); `points` is a little-endian float64 x y z file of them.
                  Every freshly written file, and valid variants of it, is an exact case.
  prefix          the file cut at a byte offset: nkrr may refuse, or read the first k <= n points,
                  the last of which may differ only if nkrr warned.
  refuse_or_warn  damage nkrr must notice (a value too many on a line, a point count larger than
                  the data, a bad E57 checksum, ...): refuse with an error, or warn.
  any             random damage: no panic, no hang, every error has a message.
A case FAILS when the checker says ok=false, when it hangs on it (> --case-timeout s) or when
the checker dies on it (crash). Exit status 1 if any case failed, else 0.

    .venv-formats/bin/python scripts/fuzz_readers.py --cases 3000            # CI
    .venv-formats/bin/python scripts/fuzz_readers.py --cases 100000 --seed 7 # full run
    .venv-formats/bin/python scripts/fuzz_readers.py --cases 2000 --no-check --self-check
        (generator only; --self-check re-reads every exact case with laspy / pye57 / this
        script's own PLY and text parsers, to test the generator's side of the oracle)

Output under --out (default target/fuzz-readers): summary.md, summary.json, failures/ (the
manifest and verdict line of every failing case in failures/failures.jsonl, and the files of
the first few failures of each kind, of all with --keep-failures; failures/manifest.jsonl
points at the kept files, so `read_oracle failures/manifest.jsonl` replays them).

Deterministic for a given --seed: each batch's numpy Generator is seeded from (seed, batch
index), E57 GUIDs come from a fixed sequence and the LAS creation date is fixed.
"""

from __future__ import annotations

import argparse
import datetime
import io
import json
import os
import re
import shutil
import struct
import subprocess
import sys
import time
import uuid
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import laspy
import pye57
import pye57.e57
from pye57 import libe57

REPO = Path(__file__).resolve().parents[1]
FORMATS = ["ply", "text", "las", "laz", "e57"]
EXPECTS = ["exact", "prefix", "refuse_or_warn", "any"]

# Mix of derived cases (the exact share comes from the group sizes below): about 8 % prefix,
# 7 % refuse_or_warn and 70 % any over all cases, i.e. these weights over the derived ones.
DERIVED_KINDS = ["prefix", "refuse_or_warn", "any"]
DERIVED_WEIGHTS = np.array([8.0, 7.0, 70.0]) / 85.0
# Derived cases per valid file. pye57 is the slowest writer, so an E57 file feeds more cases;
# PLY and text files also get a cheap valid variant, which lifts their exact share. Overall
# about 15 % exact: (2/9 + 2/9 + 1/8 + 1/8 + 1/15) / 5.
DERIVED_PER_BASE = {"ply": 7, "text": 7, "las": 7, "laz": 7, "e57": 14}
VARIANTS_PER_BASE = {"ply": 1, "text": 1, "las": 0, "laz": 0, "e57": 0}

# nkrr keeps positions as f32, relative to an origin taken from the first point when a
# coordinate is at least this large (src/cloud.rs, FAR_COORDINATE); see storable().
FAR_COORDINATE = 1e4
LAS_DATE = datetime.date(2026, 11, 23)  # laspy would write today's date
E57_PAGE, E57_PAGE_DATA = 1024, 1020    # E57 physical page: 1020 data bytes + CRC-32C (big endian)


# --------------------------------------------------------------------------- cases

@dataclass
class Base:
    """A valid file as written, and what the derivations need to know about it."""
    fmt: str
    ext: str
    data: bytes
    points: np.ndarray          # (n, 3) float64: what nkrr must read
    what: str
    hot: list = field(default_factory=list)  # byte ranges worth mutating more (headers, E57 XML)
    meta: dict = field(default_factory=dict)
    points_path: str | None = None


@dataclass
class Case:
    fmt: str
    expect: str
    ext: str
    data: bytes
    what: str
    base: Base


# --------------------------------------------------------------------------- random clouds

def pick(rng, seq, p=None):
    """One element of `seq`, as the Python object (rng.choice would make numpy scalars)."""
    return seq[int(rng.choice(len(seq), p=p))]


def integer_cloud(rng, n: int) -> tuple[np.ndarray, str]:
    """The fallback when no random cloud of a kind suits a reader: whole numbers near 0, which
    every encoding and nkrr's f32 storage hold exactly."""
    return rng.integers(-1000, 1001, (n, 3)).astype(np.float64), "integer grid (fallback)"


def round_half_away(v):
    """Rust's f64::round (half away from zero), which nkrr's origin_for uses."""
    return np.sign(v) * np.floor(np.abs(v) + 0.5)


def storable(p: np.ndarray, recentre: bool) -> bool:
    """Whether nkrr's f32 storage keeps `p` within the checker's tolerance. nkrr stores
    f32(p - origin), origin = round(first point) per axis where |coordinate| >= 1e4 (when the
    reader recentres) else 0; the checker allows 1e-6 of the extent + 1e-9 (1 + |p|). A cloud
    at 5000 that is 1 m wide loses 2e-4 m to f32 and would read as a misread: a documented
    precision limit of nkrr, not a reader bug, so such clouds are not written for readers that
    store f64 input (double PLY, text, LAS, E57)."""
    first = p[0]
    o = np.where(recentre & (np.abs(first) >= FAR_COORDINATE), round_half_away(first), 0.0)
    with np.errstate(over="ignore", invalid="ignore"):
        stored = (p - o).astype(np.float32)
    if not np.isfinite(stored).all():
        return False
    got = o + stored.astype(np.float64)
    ext = float((p.max(axis=0) - p.min(axis=0)).max())
    return bool(np.all(np.abs(got - p) <= 1e-6 * ext + 1e-9 * (1.0 + np.abs(p))))


def point_count(rng) -> int:
    """1-3000 points, mostly 50-500 (small files keep the fuzzer fast)."""
    r = rng.random()
    if r < 0.05:
        return int(rng.integers(1, 4))
    if r < 0.15:
        return int(rng.integers(4, 50))
    if r < 0.90:
        return int(rng.integers(50, 501))
    return int(rng.integers(501, 3001))


def random_shape(rng, n: int) -> tuple[np.ndarray, str]:
    """n points of a random shape of size about 1, centred at 0."""
    k = rng.choice(6, p=[0.40, 0.20, 0.15, 0.10, 0.07, 0.08])
    if k == 0:
        s = rng.uniform(0.1, 1.0, 3)
        return rng.uniform(-0.5, 0.5, (n, 3)) * s, "box"
    if k == 1:
        v = rng.normal(size=(n, 3))
        v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
        return 0.5 * v, "sphere"
    if k == 2:
        return rng.normal(scale=0.2, size=(n, 3)), "blob"
    if k == 3:
        p = rng.uniform(-0.5, 0.5, (n, 3))
        p[:, rng.integers(3)] *= pick(rng, [0.0, 1e-3])
        return p, "plane"
    if k == 4:
        t = rng.uniform(-0.5, 0.5, (n, 1))
        return t * rng.normal(size=3) + rng.normal(scale=1e-3, size=(n, 3)), "line"
    few = rng.uniform(-0.5, 0.5, (int(rng.integers(1, 5)), 3))
    return few[rng.integers(len(few), size=n)], "repeats"


def random_cloud(rng, n: int, anywhere: bool = False) -> tuple[np.ndarray, str]:
    """n random points: a shape of size 1e-6..1e3, near 0 or far from it (1e4..5e6, per axis,
    either sign). `anywhere` (f32 coordinates, stored exactly) also allows clouds far from 0
    relative to their size but closer than 1e4."""
    shape, name = random_shape(rng, n)
    size = 10 ** rng.uniform(-3, 3) if rng.random() < 0.9 else 10 ** rng.uniform(-6, -3)
    place = pick(rng, ["near", "far", "mixed", "medium"], p=[0.5, 0.25, 0.15, 0.10] if anywhere
                       else [0.55, 0.27, 0.18, 0.0])
    if place == "near":
        centre = rng.uniform(-2, 2, 3) * size
    elif place == "medium":
        centre = rng.choice([-1, 1], 3) * 10 ** rng.uniform(0, 4, 3)
    else:
        far = 10 ** rng.uniform(np.log10(2e4), np.log10(5e6), 3)  # every point beyond 1e4
        centre = rng.choice([-1, 1], 3) * far
        if place == "mixed":  # some axes near 0 (e.g. georeferenced x y, local z)
            near = rng.random(3) < 0.5
            centre[near] = rng.uniform(-2, 2, near.sum()) * size
    return centre + shape * size, f"{name}, size {size:.0e}, {place}"


# --------------------------------------------------------------------------- formatting

def fmt_float32(vals: np.ndarray, style: str) -> list[str]:
    """float32 values as text that parses back (as f32) to the same float32."""
    if style == "str":      # numpy's shortest float32 repr: '0.1', '1e-05'
        return [str(v) for v in vals.astype(np.float32)]
    if style == "g9":       # 9 significant digits always round-trip a float32
        return ["%.9g" % v for v in vals.tolist()]
    return [repr(v) for v in vals.astype(np.float64).tolist()]  # exact decimal of the f32


def fmt_float64(vals: np.ndarray, style: str) -> list[str]:
    if style == "e":
        return ["%.17e" % v for v in vals.tolist()]
    return [repr(v) for v in vals.tolist()]


def fmt_int(vals: np.ndarray) -> list[str]:
    return [str(v) for v in vals.astype(np.int64).tolist()]


WORDS = ("scan export laser station tripod north survey calibrated range mm metres intensity "
         "colour room facade bridge tree statue vertex point cloud georef epsg utm zone").split()


def comment_text(rng, long: bool = False) -> str:
    """A comment: a few words, or a very long line (> 5000 characters; random printable text,
    without digits half of the time, as a license or a scanner's settings dump may be)."""
    if not long:
        return " ".join(rng.choice(WORDS, int(rng.integers(0, 8))).tolist())
    alphabet = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ  ,.;:-_()[]=+*/'\""
    if rng.random() < 0.5:
        alphabet += "0123456789"
    chars = np.frombuffer(alphabet.encode(), np.uint8)
    return chars[rng.integers(len(chars), size=int(rng.integers(5001, 9000)))].tobytes().decode()


EOLS = {"LF": "\n", "CRLF": "\r\n", "CR": "\r"}


def pick_eol(rng) -> str:
    return pick(rng, ["LF", "CRLF", "CR"], p=[0.7, 0.2, 0.1])


# --------------------------------------------------------------------------- PLY writer

PLY_NP = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4",
          "float": "f4", "double": "f8"}
PLY_ALIAS = {"char": "int8", "uchar": "uint8", "short": "int16", "ushort": "uint16", "int": "int32",
             "uint": "uint32", "float": "float32", "double": "float64"}
INT_RANGE = {t: (np.iinfo(PLY_NP[t]).min, np.iinfo(PLY_NP[t]).max)
             for t in ("char", "uchar", "short", "ushort", "int", "uint")}


@dataclass
class PlyModel:
    """The content of a PLY file, independent of its encoding."""
    n: int
    props: list          # (name, type, values) or (name, "list", (count type, item type, [arrays]))
    faces: list | None   # [arrays of vertex indices], or None
    face_types: tuple    # (count type, item type)
    faces_first: bool
    xyz: np.ndarray
    desc: str


def ply_model(rng) -> PlyModel:
    n = point_count(rng)
    ctype = pick(rng, ["float", "double", "int", "quantised"], p=[0.55, 0.25, 0.10, 0.10])
    if ctype == "float":  # exact in f32 whatever the magnitude: nkrr reads floats as they are
        pts, shape = random_cloud(rng, n, anywhere=True)
        xyz = pts.astype(np.float32).astype(np.float64)
    elif ctype == "double":
        for _ in range(20):
            pts, shape = random_cloud(rng, n)
            if rng.random() < 0.3:
                pts = np.round(pts, int(rng.integers(0, 7)))
            if storable(pts, True):
                break
        else:
            pts, shape = integer_cloud(rng, n)
        xyz = pts
    else:  # integer coordinates (quantised scans): int/uint are recentred, the small ones exact
        ctype = "int" if ctype == "int" else pick(rng, ["char", "uchar", "short", "ushort", "uint"])
        lo, hi = INT_RANGE[ctype]
        for _ in range(20):
            span = int(min(hi - lo, 10 ** rng.uniform(0, np.log10(hi - lo + 1))))
            start = int(rng.integers(lo, hi - span + 1))
            xyz = rng.integers(start, start + span, (n, 3), endpoint=True).astype(np.float64)
            if storable(xyz, ctype in ("int", "uint")):
                break
        else:
            xyz, span = rng.integers(0, 101, (n, 3)).astype(np.float64), 100
        shape = f"{ctype} span {span}"
    props = [("x", ctype, xyz[:, 0]), ("y", ctype, xyz[:, 1]), ("z", ctype, xyz[:, 2])]
    extras = []
    if rng.random() < 0.35:
        nrm = rng.normal(size=(n, 3))
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
        t = pick(rng, ["float", "double"], p=[0.8, 0.2])
        extras += [(f"n{a}", t, nrm[:, i]) for i, a in enumerate("xyz")]
    if rng.random() < 0.35:
        t = pick(rng, ["uchar", "ushort", "float"], p=[0.8, 0.1, 0.1])
        top = {"uchar": 255, "ushort": 65535}.get(t)
        rgb = rng.integers(0, top + 1, (n, 4)) if top else rng.random((n, 4))
        names = ["red", "green", "blue"] + (["alpha"] if rng.random() < 0.3 else [])
        if rng.random() < 0.1:
            names = ["diffuse_red", "diffuse_green", "diffuse_blue"]
        extras += [(c, t, rgb[:, i]) for i, c in enumerate(names)]
    if rng.random() < 0.2:
        t = pick(rng, ["float", "ushort", "uchar", "double", "int"])
        vals = rng.random(n) * 1000 if t in ("float", "double") else rng.integers(0, INT_RANGE[t][1] + 1, n)
        extras.append((pick(rng, ["intensity", "scalar_Intensity", "confidence", "quality"]), t, vals))
    if rng.random() < 0.08:  # a list inside vertex (some exporters put a vertex's faces there)
        ct, it = pick(rng, ["uchar", "int", "ushort"]), pick(rng, ["int", "uint", "float"])
        lists = [rng.integers(0, max(n, 1), int(rng.integers(0, 5))) for _ in range(n)]
        extras.append(("vertex_indices", "list", (ct, it, lists)))
    order = props + extras
    if extras and rng.random() < 0.2:  # x y z need not come first
        order = [order[i] for i in rng.permutation(len(order))]
    faces, face_types, faces_first = None, ("uchar", "int"), False
    if rng.random() < 0.2:
        k = int(rng.integers(1, 20))
        faces = [rng.integers(0, n, pick(rng, [3, 4])) for _ in range(k)]
        face_types = (pick(rng, ["uchar", "int", "ushort"]), pick(rng, ["int", "uint"]))
        faces_first = bool(rng.random() < 0.4)
    desc = f"{n} pts {shape}, xyz {ctype}" + "".join(f" +{p[0]}" for p in extras)
    if faces:
        desc += f", {len(faces)} faces {'before' if faces_first else 'after'} vertex"
    return PlyModel(n, order, faces, face_types, faces_first, xyz, desc)


def ply_ascii_columns(props, float_style: str) -> list[list[str]]:
    cols = []
    for name, t, vals in props:
        if t == "list":
            ct, it, lists = vals
            f = (lambda a: fmt_int(a)) if it not in ("float", "double") else (lambda a: fmt_float32(a.astype(np.float32), "repr"))
            cols.append([" ".join([str(len(a))] + f(a)) for a in lists])
        elif t == "float":
            cols.append(fmt_float32(np.asarray(vals, np.float32), float_style))
        elif t == "double":
            cols.append(fmt_float64(np.asarray(vals, np.float64), "e" if float_style == "g9" else "repr"))
        else:
            cols.append(fmt_int(np.asarray(vals)))
    return cols


def ply_binary_records(props, n: int, endian: str) -> bytes:
    """The vertex element's records: one numpy structured array when every property is a
    scalar, else record by record (list properties make records differ in size)."""
    if all(t != "list" for _, t, _ in props):
        dt = np.dtype([(f"f{i}", endian + PLY_NP[t]) for i, (_, t, _) in enumerate(props)])
        rec = np.empty(n, dt)
        for i, (_, t, vals) in enumerate(props):
            rec[f"f{i}"] = np.asarray(vals).astype(PLY_NP[t])
        return rec.tobytes()
    cols = []
    for _, t, vals in props:
        if t == "list":
            ct, it, lists = vals
            cols.append([np.array([len(a)], endian + PLY_NP[ct]).tobytes()
                         + np.asarray(a).astype(endian + PLY_NP[it]).tobytes() for a in lists])
        else:
            raw = np.asarray(vals).astype(endian + PLY_NP[t]).tobytes()
            size = np.dtype(PLY_NP[t]).itemsize
            cols.append([raw[i * size:(i + 1) * size] for i in range(n)])
    return b"".join(b"".join(r) for r in zip(*cols))


def ply_serialise(rng, m: PlyModel, fmt: str | None = None) -> Base:
    """One encoding of a PLY model: format, line endings, BOM, magic case, comments, type names
    and spacing all random; the points do not depend on them."""
    fmt = fmt or pick(rng, ["ascii", "binary_little_endian", "binary_big_endian"], p=[0.4, 0.35, 0.25])
    eol_name = pick_eol(rng)
    eol = EOLS[eol_name]
    bom = rng.random() < 0.08
    alias = rng.random() < 0.15
    hsep = " " if rng.random() < 0.85 else pick(rng, ["  ", "\t", " \t "])
    tname = (lambda t: PLY_ALIAS[t]) if alias else (lambda t: t)
    lines = ["ply" if rng.random() < 0.85 else pick(rng, ["PLY", "Ply", "ply ", "PLY\t"]),
             hsep.join(["format", fmt, "1.0"])]
    vertex = [hsep.join(["element", "vertex", str(m.n)])]
    for name, t, vals in m.props:
        if t == "list":
            vertex.append(hsep.join(["property", "list", tname(vals[0]), tname(vals[1]), name]))
        else:
            vertex.append(hsep.join(["property", tname(t), name]))
    elements = [vertex]
    if m.faces is not None:
        face = [hsep.join(["element", "face", str(len(m.faces))]),
                hsep.join(["property", "list", tname(m.face_types[0]), tname(m.face_types[1]), "vertex_indices"])]
        elements.insert(0 if m.faces_first else 1, face)
    for el in elements:
        lines += el
    # Comments and obj_info anywhere after the magic line (some writers put them mid-header).
    for _ in range(pick(rng, [0, 1, 2, 5], p=[0.4, 0.3, 0.2, 0.1])):
        kw = "comment" if rng.random() < 0.8 else "obj_info"
        lines.insert(int(rng.integers(1, len(lines) + 1)), (kw + " " + comment_text(rng)).rstrip())
    if rng.random() < 0.05:
        lines.insert(int(rng.integers(2, len(lines) + 1)), "")  # a blank header line
    lines.append("end_header")
    head = (b"\xef\xbb\xbf" if bom else b"") + (eol.join(lines) + eol).encode()
    what = f"ply {fmt}, {eol_name}{', BOM' if bom else ''}{', type aliases' if alias else ''}, {m.desc}"
    meta = {"hdr_lines": lines, "eol": eol, "bom": bom, "fmt": fmt, "vertex_last": m.faces is None or m.faces_first}
    if fmt == "ascii":
        fstyle = pick(rng, ["repr", "g9", "str"], p=[0.5, 0.35, 0.15])
        sep = " " if rng.random() < 0.8 else pick(rng, ["\t", "  ", " \t", "   "])
        trail = " " if rng.random() < 0.2 else ""
        vlines = [sep.join(r) + trail for r in zip(*ply_ascii_columns(m.props, fstyle))]
        flines = [" ".join(fmt_int(np.array([len(f)])) + fmt_int(f)) for f in (m.faces or [])]
        body = flines + vlines if m.faces_first else vlines + flines
        v0 = len(flines) if m.faces_first else 0
        final_eol = rng.random() < 0.95
        meta.update(lines=body, vrange=(v0, v0 + m.n), final_eol=final_eol, sep=sep)
        data = head + (eol.join(body) + (eol if final_eol else "")).encode()
        what += f", sep {sep!r}, floats {fstyle}" + ("" if final_eol else ", no final EOL")
    else:
        endian = "<" if fmt == "binary_little_endian" else ">"
        vbody = ply_binary_records(m.props, m.n, endian)
        fbody = b"".join(np.array([len(f)], endian + PLY_NP[m.face_types[0]]).tobytes()
                         + np.asarray(f).astype(endian + PLY_NP[m.face_types[1]]).tobytes()
                         for f in (m.faces or []))
        data = head + (fbody + vbody if m.faces_first else vbody + fbody)
    return Base("ply", "ply", data, m.xyz, what, hot=[(0, len(head))], meta=meta)


def ply_rebuild(base: Base, hdr_lines=None, body_lines=None) -> bytes:
    """The file again with its header lines and/or ascii body lines replaced."""
    m = base.meta
    eol = m["eol"]
    head = (b"\xef\xbb\xbf" if m["bom"] else b"") + (eol.join(hdr_lines or m["hdr_lines"]) + eol).encode()
    if m["fmt"] != "ascii":
        return head + base.data[base.hot[0][1]:]
    body = m["lines"] if body_lines is None else body_lines
    return head + (eol.join(body) + (eol if m["final_eol"] else "")).encode()


# --------------------------------------------------------------------------- text writer

TEXT_NAMES = {
    "xyz": [["x", "y", "z"], ["X", "Y", "Z"], ['"x"', '"y"', '"z"'], ["pos_x", "pos_y", "pos_z"]],
    "rgb": [["r", "g", "b"], ["red", "green", "blue"], ["R", "G", "B"]],
    "nrm": [["nx", "ny", "nz"], ["normal_x", "normal_y", "normal_z"], ["Nx", "Ny", "Nz"]],
    "int": [["intensity"], ["i"], ["Intensity"], ["scalar_Intensity"]],
}
TEXT_SEPS = {"space": " ", "tab": "\t", "comma": ",", "semicolon": ";", "comma-space": ", "}


@dataclass
class TextModel:
    """The columns of a text cloud as strings (formatting decides the points), and their names."""
    n: int
    cols: list           # [(names group, [str per point])]
    xyz: np.ndarray
    desc: str


def text_model(rng) -> TextModel:
    n = point_count(rng)
    style = pick(rng, ["repr", "fixed", "e"], p=[0.5, 0.4, 0.1])
    for attempt in range(21):
        pts, shape = random_cloud(rng, n) if attempt < 20 else integer_cloud(rng, n)
        if style == "fixed":  # a fixed number of decimals that resolves the cloud (mostly)
            ext = float((pts.max(0) - pts.min(0)).max())
            digits = int(np.clip(np.ceil(-np.log10(max(ext, 1e-12))) + rng.integers(0, 6), 0, 17))
            s = [["%.*f" % (digits, v) for v in pts[:, a].tolist()] for a in range(3)]
        else:
            s = [fmt_float64(pts[:, a], style) for a in range(3)]
        xyz = np.array([[float(v) for v in col] for col in s]).T  # what the text says, exactly
        if storable(xyz, True):
            break
    cols = [("x", s[0]), ("y", s[1]), ("z", s[2])]
    extras = pick(rng, ["", "i", "rgb", "nrm", "i rgb", "rgb nrm", "i rgb nrm", "nrm rgb"],
                            p=[0.3, 0.15, 0.2, 0.1, 0.1, 0.07, 0.05, 0.03]).split()
    for e in extras:
        if e == "i":
            vals = rng.integers(-2048, 2048, n) if rng.random() < 0.7 else rng.random(n)
            cols.append(("int", fmt_int(vals) if vals.dtype.kind == "i" else ["%.4f" % v for v in vals.tolist()]))
        elif e == "rgb":
            c = rng.integers(0, 256, (n, 3))
            cols += [(k, fmt_int(c[:, i])) for i, k in enumerate("rgb")]
        else:
            v = rng.normal(size=(n, 3))
            v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
            cols += [(k, ["%.6f" % x for x in v[:, i].tolist()]) for i, k in enumerate(["nx", "ny", "nz"])]
    desc = f"{n} pts {shape}, {style}{digits if style == 'fixed' else ''}" + "".join(f" +{e}" for e in extras)
    return TextModel(n, cols, xyz, desc)


def text_serialise(rng, m: TextModel) -> Base:
    """One layout of a text model: separator, header, PTS count, comments, line endings, BOMs."""
    sep_name = pick(rng, list(TEXT_SEPS), p=[0.45, 0.15, 0.2, 0.1, 0.1])
    sep = TEXT_SEPS[sep_name]
    if sep == " " and rng.random() < 0.1:
        sep = pick(rng, ["  ", " \t"])
    eol_name = pick_eol(rng)
    eol = EOLS[eol_name]
    header = pick(rng, ["none", "names", "cloudcompare"], p=[0.6, 0.3, 0.1])
    cols = list(m.cols)
    # Named columns may come in any order; not after '//', which is CloudCompare's header only
    # when X comes first (else it is a comment, for nkrr as for CloudCompare).
    if header == "names" and rng.random() < 0.3:
        cols = [cols[i] for i in rng.permutation(len(cols))]
    pts_count = header == "none" and rng.random() < 0.15
    lines, notes = [], []
    if rng.random() < 0.04:
        lines.append("#" + comment_text(rng, long=True))
        notes.append("long comment")
    for _ in range(pick(rng, [0, 1, 3], p=[0.7, 0.2, 0.1])):
        lines.append(pick(rng, ["#", "# ", "//"]) + comment_text(rng))
    if pts_count:
        lines.append(str(m.n))
        notes.append("PTS count")
    if header != "none":
        group = {"x": 0, "y": 1, "z": 2, "r": 0, "g": 1, "b": 2, "nx": 0, "ny": 1, "nz": 2, "int": 0}
        kind = {"x": "xyz", "y": "xyz", "z": "xyz", "r": "rgb", "g": "rgb", "b": "rgb",
                "nx": "nrm", "ny": "nrm", "nz": "nrm", "int": "int"}
        spelling = {k: int(rng.integers(len(v))) for k, v in TEXT_NAMES.items()}
        names = [TEXT_NAMES[kind[c]][spelling[kind[c]]][group[c]] for c, _ in cols]
        if header == "cloudcompare":
            names = [n.strip('"').upper() for n in names]
            lines.append("//" + sep.strip(" ").join(names) if sep.strip(" ") else "//" + " ".join(names))
        else:
            lines.append(sep.join(names))
        notes.append(f"header {header}" + (" shuffled" if cols != list(m.cols) else ""))
    lead = " " if rng.random() < 0.05 else ""
    data_idx = []
    rows = [lead + sep.join(r) for r in zip(*(c for _, c in cols))]
    interleave = rng.random() < 0.05  # comment and blank lines between points are allowed
    for i, r in enumerate(rows):
        if interleave and rng.random() < 0.05:
            lines.append(pick(rng, ["", "# " + comment_text(rng)]))
        data_idx.append(len(lines))
        lines.append(r)
    final_eol = rng.random() < 0.9
    boms = pick(rng, [0, 1, 2], p=[0.88, 0.08, 0.04])
    head = b"\xef\xbb\xbf" * boms
    data = head + (eol.join(lines) + (eol if final_eol else "")).encode()
    if pts_count:
        ext = "pts"
    elif sep_name in ("comma", "comma-space"):
        ext = "csv"
    else:
        ext = pick(rng, ["xyz", "txt", "asc", "xyz"])
    what = (f"text .{ext}, sep {sep_name}, {eol_name}" + ("" if final_eol else ", no final EOL")
            + (f", {boms} BOM" if boms else "") + "".join(", " + s for s in notes) + f", {m.desc}")
    meta = {"lines": lines, "eol": eol, "final_eol": final_eol, "data_idx": data_idx, "head": head,
            "sep": sep, "ncols": len(cols), "pts_count": pts_count}
    first_data = len(head) + sum(len(l.encode()) + len(eol) for l in lines[:data_idx[0]])
    return Base("text", ext, data, m.xyz, what, hot=[(0, max(first_data, 1))], meta=meta)


def text_rebuild(base: Base, lines: list[str]) -> bytes:
    m = base.meta
    return m["head"] + (m["eol"].join(lines) + (m["eol"] if m["final_eol"] else "")).encode()


# --------------------------------------------------------------------------- LAS / LAZ writer

LAS_FORMATS = {"1.2": [0, 1, 2, 3], "1.4": [6, 7, 8]}
COLOUR_FORMATS = {2, 3, 5, 7, 8, 10}


def las_base(rng, compress: bool) -> Base:
    """A LAS or LAZ file written by laspy (+ lazrs). The points are what laspy computes from the
    stored integers: X * scale + offset in float64."""
    n = point_count(rng)
    version = pick(rng, ["1.2", "1.4"])
    pf = pick(rng, LAS_FORMATS[version])
    for attempt in range(21):
        world, shape = random_cloud(rng, n) if attempt < 20 else integer_cloud(rng, n)
        size = float((world.max(0) - world.min(0)).max())
        scale = np.full(3, pick(rng, [0.01, 0.001, 0.0001]))
        if size > 0 and rng.random() < 0.7:  # a scale that resolves the cloud, mostly
            scale[:] = max(min(10 ** np.floor(np.log10(size / 100)), 0.01), 0.0001)
        if rng.random() < 0.15:
            scale = rng.choice([0.01, 0.001, 0.0001], 3)
        centre = (world.max(0) + world.min(0)) / 2
        how = pick(rng, ["zero", "round", "exact-ish"], p=[0.3, 0.5, 0.2])
        offset = {"zero": np.zeros(3), "round": np.round(centre, -3),
                  "exact-ish": np.round(centre, 2)}[how]
        ints = np.rint((world - offset) / scale)
        if np.abs(ints).max() >= 2**31:
            offset = np.round(centre, -3)
            ints = np.rint((world - offset) / scale)
        if np.abs(ints).max() >= 2**31:
            continue
        ints = ints.astype(np.int64)
        xyz = ints * scale + offset  # laspy's ScaledArrayView: array * scale + offset
        if storable(xyz, True):
            break
    header = laspy.LasHeader(point_format=pf, version=version)
    header.scales = scale
    header.offsets = offset
    header.creation_date = LAS_DATE
    header.system_identifier = "nkrr fuzz_readers.py"
    if pf >= 6:
        header.global_encoding.wkt = True  # required for point formats 6-10
    vlr_note = ""
    if rng.random() < 0.3:
        payload = rng.integers(0, 256, int(rng.integers(0, 200)), dtype=np.uint8).tobytes()
        header.vlrs.append(laspy.VLR(user_id="nkrr-fuzz", record_id=int(rng.integers(1, 60000)),
                                     description="fuzz payload", record_data=payload))
        vlr_note = f", custom VLR ({len(payload)} B)"
    las = laspy.LasData(header)
    las.X, las.Y, las.Z = (ints[:, a].astype(np.int32) for a in range(3))
    las.intensity = rng.integers(0, 65536, n).astype(np.uint16)
    nr = rng.integers(1, 6 if pf < 6 else 16, n)
    las.number_of_returns = nr.astype(np.uint8)
    las.return_number = np.minimum(rng.integers(1, 6 if pf < 6 else 16, n), nr).astype(np.uint8)
    las.classification = rng.integers(0, 32, n).astype(np.uint8)
    if pf in (1, 3, 6, 7, 8):
        las.gps_time = np.cumsum(rng.random(n))
    if pf in COLOUR_FORMATS:
        top = 256 if rng.random() < 0.3 else 65536  # many writers store 8-bit values
        rgb = rng.integers(0, top, (n, 3)).astype(np.uint16)
        las.red, las.green, las.blue = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    las.update_header()
    buf = io.BytesIO()
    # Lazrs, single-threaded: the chunking cannot depend on the thread count.
    las.write(buf, do_compress=compress, laz_backend=laspy.LazBackend.Lazrs)
    data = buf.getvalue()
    header_size = struct.unpack_from("<H", data, 94)[0]
    offset_to_points = struct.unpack_from("<I", data, 96)[0]
    what = (f"{'laz' if compress else 'las'} {version} pf{pf}, scale {scale.tolist()}, offset {offset.tolist()}"
            f"{vlr_note}, {n} pts {shape}")
    fmt = "laz" if compress else "las"
    return Base(fmt, fmt, data, xyz, what, hot=[(0, offset_to_points)],
                meta={"header_size": header_size, "offset_to_points": offset_to_points,
                      "version": version, "pf": pf, "n": n})


# --------------------------------------------------------------------------- E57 writer

class FixedUuids:
    """Stands in for the uuid module inside pye57.e57: uuid4() returns name-based UUIDs from a
    fixed sequence (pye57 would use random ones), so a seed gives the same bytes every run."""

    def __init__(self, name: str):
        self.name, self.count = name, 0

    def uuid4(self):
        self.count += 1
        return uuid.uuid5(uuid.NAMESPACE_URL, f"nkrr-fuzz/{self.name}/{self.count}")


def quat_matrix(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def e57_scan(imf, e57, local: np.ndarray, *, name: str, encoding: str, pose, rgb, intensity,
             scaled_step: float = 1e-4) -> None:
    """One Cartesian scan through libE57Format's node API: coordinates as single or double
    floats or scaled integers (`local` already holds the values those encodings store exactly),
    optional colours, intensity and pose (as make_fixtures.py's e57_write_scan)."""
    n = len(local)
    scan = libe57.StructureNode(imf)
    scan.set("guid", libe57.StringNode(imf, "{%s}" % pye57.e57.uuid.uuid4()))
    scan.set("name", libe57.StringNode(imf, name))
    lo, hi = local.min(axis=0), local.max(axis=0)
    bb = libe57.StructureNode(imf)
    for i, a in enumerate("xyz"):
        bb.set(f"{a}Minimum", libe57.FloatNode(imf, float(lo[i])))
        bb.set(f"{a}Maximum", libe57.FloatNode(imf, float(hi[i])))
    scan.set("cartesianBounds", bb)
    if pose is not None:
        q, t = pose
        node, rot, tr = libe57.StructureNode(imf), libe57.StructureNode(imf), libe57.StructureNode(imf)
        for k, v in zip("wxyz", q):
            rot.set(k, libe57.FloatNode(imf, float(v)))
        for k, v in zip("xyz", t):
            tr.set(k, libe57.FloatNode(imf, float(v)))
        node.set("rotation", rot)
        node.set("translation", tr)
        scan.set("pose", node)
    if rgb is not None:
        cl = libe57.StructureNode(imf)
        for c in ("Red", "Green", "Blue"):
            cl.set(f"color{c}Minimum", libe57.IntegerNode(imf, 0))
            cl.set(f"color{c}Maximum", libe57.IntegerNode(imf, 255))
        scan.set("colorLimits", cl)
    proto = libe57.StructureNode(imf)
    arrays = {}
    for i, a in enumerate("XYZ"):
        f = f"cartesian{a}"
        if encoding == "scaled":
            ints = np.rint(local[:, i] / scaled_step).astype(np.int64)
            # max > min: libE57Format cannot read back a field of 0 bits (all values equal).
            proto.set(f, libe57.ScaledIntegerNode(imf, int(ints.min()), int(ints.min()), int(ints.max()) + 1, scaled_step, 0.0))
            arrays[f] = ints.astype(np.longlong)  # 'q': pye57 takes numpy's int64 'l' as 32-bit
        else:
            prec = libe57.E57_DOUBLE if encoding == "double" else libe57.E57_SINGLE
            proto.set(f, libe57.FloatNode(imf, float(lo[i]), prec, float(lo[i]), float(hi[i])))
            arrays[f] = np.ascontiguousarray(local[:, i], dtype=np.float64)
    if intensity is not None:
        il = libe57.StructureNode(imf)
        il.set("intensityMinimum", libe57.IntegerNode(imf, 0))
        il.set("intensityMaximum", libe57.IntegerNode(imf, 4095))
        scan.set("intensityLimits", il)
        proto.set("intensity", libe57.IntegerNode(imf, 0, 0, 4095))
        arrays["intensity"] = intensity.astype(np.longlong)
    if rgb is not None:
        for i, c in enumerate(("colorRed", "colorGreen", "colorBlue")):
            proto.set(c, libe57.IntegerNode(imf, 0, 0, 255))
            arrays[c] = np.ascontiguousarray(rgb[:, i], dtype=np.uint8)
    points = libe57.CompressedVectorNode(imf, proto, libe57.VectorNode(imf, True))
    scan.set("points", points)
    e57.data3d.append(scan)
    bufs = libe57.VectorSourceDestBuffer()
    for f, arr in arrays.items():
        raw = f.startswith("cartesian") and encoding == "scaled"
        bufs.append(libe57.SourceDestBuffer(imf, f, arr, n, True, not raw))
    w = points.writer(bufs)
    w.write(n)
    w.close()


def e57_base(rng, path: Path, tag: str) -> Base:
    """An E57 file: one scan (sometimes two or three, points = the scans in order, each posed),
    written with libE57Format's node API, or with pye57's write_scan_raw (single precision)."""
    pye57.e57.uuid = FixedUuids(tag)
    nscans = pick(rng, [1, 2, 3], p=[0.85, 0.12, 0.03])
    e = pye57.E57(str(path), mode="w")
    world_all, notes = [], []
    raw_writer = rng.random() < 0.15
    for s in range(nscans):
        n = point_count(rng)
        encoding = "single" if raw_writer else pick(rng, ["single", "double", "scaled"], p=[0.4, 0.4, 0.2])
        pose_kind = pick(rng, ["none", "identity", "translate", "rotate"], p=[0.3, 0.2, 0.25, 0.25])
        if raw_writer and pose_kind == "none":
            pose_kind = "identity"  # write_scan_raw always writes a pose
        for attempt in range(21):
            local, shape = random_cloud(rng, n) if attempt < 20 else integer_cloud(rng, n)
            if pose_kind == "rotate" or encoding == "scaled":
                # A rotation mixes the axes and scaled integers have 32 bits: keep such scans
                # near their own origin (the pose's translation can take them far).
                local -= np.round((local.max(0) + local.min(0)) / 2, -3)
            if encoding == "single":
                local = local.astype(np.float32).astype(np.float64)
            elif encoding == "scaled":
                step = 1e-4
                if np.abs(local).max() / step >= 2**31:
                    continue
                local = np.rint(local / step) * step
            q, t = np.array([1.0, 0, 0, 0]), np.zeros(3)
            if pose_kind == "translate":
                t = np.round(rng.uniform(-1, 1, 3) * 10 ** rng.uniform(0, 6.5), 3)
            elif pose_kind == "rotate":
                q = rng.normal(size=4)
                q /= np.linalg.norm(q)
                q = q if q[0] >= 0 else -q  # E57: w >= 0
                t = np.round(rng.uniform(-1, 1, 3) * 10 ** rng.uniform(0, 6.5), 3)
            world = local @ quat_matrix(q).T + t if pose_kind != "none" else local
            if storable(world, True):
                break
        rgb = rng.integers(0, 256, (n, 3)).astype(np.uint8) if rng.random() < 0.4 else None
        if raw_writer:
            d = {"cartesianX": local[:, 0].copy(), "cartesianY": local[:, 1].copy(), "cartesianZ": local[:, 2].copy()}
            if rgb is not None:
                d.update(colorRed=rgb[:, 0].copy(), colorGreen=rgb[:, 1].copy(), colorBlue=rgb[:, 2].copy())
            if rng.random() < 0.4:
                d["intensity"] = rng.random(n).astype(np.float32)
            rot = q if pose_kind == "rotate" else None
            e.write_scan_raw(d, name=f"scan {s}", rotation=rot, translation=t if pose_kind != "identity" else None)
        else:
            inten = rng.integers(0, 4096, n) if rng.random() < 0.3 else None
            e57_scan(e.image_file, e, local, name=f"scan {s}", encoding=encoding,
                     pose=None if pose_kind == "none" else (q, t), rgb=rgb, intensity=inten)
        world_all.append(world)
        notes.append(f"{n} pts {encoding} {pose_kind}{' rgb' if rgb is not None else ''}")
    e.close()
    data = path.read_bytes()
    xml_off, xml_len = struct.unpack_from("<QQ", data, 24)
    xml_end = e57_logical_to_physical(e57_physical_to_logical(xml_off) + xml_len)
    what = f"e57 {'write_scan_raw' if raw_writer else 'node API'}, {nscans} scan(s): " + "; ".join(notes)
    return Base("e57", "e57", data, np.concatenate(world_all), what, hot=[(0, 48), (xml_off, xml_end)],
                meta={"xml": (xml_off, xml_len)})


# --------------------------------------------------------------------------- E57 pages

def _crc32c_table() -> np.ndarray:
    t = np.arange(256, dtype=np.uint32)
    for _ in range(8):
        t = np.where(t & 1, (t >> 1) ^ np.uint32(0x82F63B78), t >> 1).astype(np.uint32)
    return t


CRC32C = _crc32c_table()


def e57_page_crcs(pages: np.ndarray) -> np.ndarray:
    """CRC-32C of the 1020 data bytes of each page (rows of `pages`), all pages at once: one
    numpy step per byte position, so a file's pages cost about as much as one."""
    crc = np.full(len(pages), 0xFFFFFFFF, np.uint32)
    for j in range(E57_PAGE_DATA):
        crc = CRC32C[(crc ^ pages[:, j]) & 0xFF] ^ (crc >> 8)
    return crc ^ np.uint32(0xFFFFFFFF)


def e57_fix_crcs(data: bytes, pages=None) -> bytes:
    """The file with the checksums of `pages` (all when None) recomputed: damage made inside a
    page then reaches the parser instead of stopping at the checksum test."""
    if len(data) % E57_PAGE:
        return data
    arr = np.frombuffer(data, np.uint8).reshape(-1, E57_PAGE).copy()
    idx = np.arange(len(arr)) if pages is None else np.unique(np.clip(np.asarray(list(pages)), 0, len(arr) - 1))
    arr[idx, E57_PAGE_DATA:] = e57_page_crcs(arr[idx]).astype(">u4").view(np.uint8).reshape(-1, 4)
    return arr.tobytes()


def e57_physical_to_logical(p: int) -> int:
    return p // E57_PAGE * E57_PAGE_DATA + p % E57_PAGE


def e57_logical_to_physical(l: int) -> int:
    return l // E57_PAGE_DATA * E57_PAGE + l % E57_PAGE_DATA


def e57_unpage(data: bytes) -> bytes:
    return np.frombuffer(data, np.uint8).reshape(-1, E57_PAGE)[:, :E57_PAGE_DATA].tobytes()


def e57_page(logical: bytes) -> bytes:
    pad = -len(logical) % E57_PAGE_DATA
    arr = np.frombuffer(logical + b"\0" * pad, np.uint8).reshape(-1, E57_PAGE_DATA)
    arr = np.concatenate([arr, np.zeros((len(arr), 4), np.uint8)], axis=1)
    return e57_fix_crcs(arr.tobytes())


def e57_replace_xml(base: Base, new_xml: bytes) -> bytes:
    """The file with its XML section replaced (any length) and the header's lengths and every
    checksum made consistent. libE57Format writes the XML last, so it can grow in place."""
    data = base.data
    xml_off, xml_len = base.meta["xml"]
    logical = bytearray(e57_unpage(data))
    start = e57_physical_to_logical(xml_off)
    logical = logical[:start] + new_xml
    logical += b"\0" * (-len(logical) % E57_PAGE_DATA)
    struct.pack_into("<QQQ", logical, 16, len(logical) // E57_PAGE_DATA * E57_PAGE, xml_off, len(new_xml))
    return e57_page(bytes(logical))


def e57_xml(base: Base) -> bytes:
    xml_off, xml_len = base.meta["xml"]
    start = e57_physical_to_logical(xml_off)
    return e57_unpage(base.data)[start:start + xml_len]


# --------------------------------------------------------------------------- derivations: prefix

def line_offsets(base: Base, lines: list[str], start: int) -> list[int]:
    """Byte offset of the start of each line (and one past the last), from `start`."""
    eol = len(base.meta["eol"])
    offs = [start]
    for l in lines:
        offs.append(offs[-1] + len(l.encode()) + eol)
    return offs


def derive_prefix(rng, base: Base) -> tuple[bytes, str]:
    """The file cut: anywhere (in the header sometimes), or for line formats at a line's end or
    inside one of its numbers (mostly the last)."""
    data = base.data
    hdr_end = base.hot[0][1]
    lines = base.meta.get("lines")
    if lines is not None and rng.random() < 0.5:
        if base.fmt == "text":
            idx = base.meta["data_idx"]
            start = len(base.meta["head"])
        else:
            v0, v1 = base.meta["vrange"]
            idx = list(range(v0, v1))
            start = hdr_end
        offs = line_offsets(base, lines, start)
        i = idx[int(rng.integers(len(idx)))]
        line = lines[i]
        if rng.random() < 0.5:
            cut = min(offs[i + 1], len(data))
            return data[:cut], f"cut after line {i + 1} of the body (at byte {cut}, a line boundary)"
        # Inside a number of that line: its last one half of the time.
        toks = [(j, len(t)) for j, t in _token_spans(line)]
        j, ln = toks[-1] if rng.random() < 0.5 else toks[int(rng.integers(len(toks)))]
        cut = offs[i] + len(line[:j].encode()) + int(rng.integers(1, ln)) if ln > 1 else offs[i] + len(line[:j].encode())
        return data[:cut], f"cut inside a number of body line {i + 1} (at byte {cut})"
    if rng.random() < 0.15:
        cut = int(rng.integers(0, max(hdr_end, 1)))
        return data[:cut], f"cut in the header at byte {cut} of {len(data)}"
    cut = int(rng.integers(min(hdr_end, len(data) - 1), len(data)))
    return data[:cut], f"cut at byte {cut} of {len(data)}"


def _token_spans(line: str):
    """(start, text) of the whitespace/comma/semicolon-separated tokens of a line."""
    out, start = [], None
    for k, ch in enumerate(line + " "):
        if ch in " \t,;":
            if start is not None:
                out.append((start, line[start:k]))
                start = None
        elif start is None:
            start = k
    return out or [(0, line)]


# --------------------------------------------------------------------------- derivations: damage nkrr must notice

def refuse_ply(rng, base: Base):
    m = base.meta
    hdr = list(m["hdr_lines"])
    options = ["dup_x"]
    if m["vertex_last"]:
        options.append("count_up")
        if base.points.shape[0] >= 2:
            options.append("count_down")
    if m["fmt"] == "ascii":
        n = base.points.shape[0]
        v0, v1 = m["vrange"]
        if n >= 2 or not m["vertex_last"]:
            options.append("extra_value")
        options.append("missing_value")
        if n >= 20:
            options.append("ascii_as_binary")
    else:
        options.append("trailing_bytes")
    kind = options[int(rng.integers(len(options)))]
    vline = next(i for i, l in enumerate(hdr) if l.split()[:2] == ["element", "vertex"])
    if kind == "dup_x":
        # The first 'property <type> x' line after the vertex element, declared twice.
        i = next(i for i in range(vline, len(hdr)) if hdr[i].split()[-1:] == ["x"] and hdr[i].startswith("property"))
        hdr.insert(i, hdr[i])
        return ply_rebuild(base, hdr_lines=hdr), "'property ... x' declared twice"
    if kind in ("count_up", "count_down"):
        n = base.points.shape[0]
        k = int(rng.integers(1, 4)) if kind == "count_up" else int(rng.integers(1, n))
        new = n + k if kind == "count_up" else n - k
        hdr[vline] = f"element vertex {new}"
        return ply_rebuild(base, hdr_lines=hdr), f"element vertex {new} but {n} records in the body"
    if kind == "trailing_bytes":
        extra = rng.integers(0, 256, int(rng.integers(1, 65)), dtype=np.uint8).tobytes()
        return base.data + extra, f"{len(extra)} bytes after the binary body"
    if kind == "ascii_as_binary":
        fmt = pick(rng, ["binary_little_endian", "binary_big_endian"], p=[0.8, 0.2])
        i = next(i for i, l in enumerate(hdr) if l.split()[:1] == ["format"])
        hdr[i] = f"format {fmt} 1.0"
        return ply_rebuild(base, hdr_lines=hdr), f"header says {fmt}, body is ascii"
    lines = list(m["lines"])
    v0, v1 = m["vrange"]
    # Not the file's last line: there a value too many would be trailing text, not a shift.
    last_ok = v1 if (kind == "missing_value" or not m["vertex_last"]) else v1 - 1
    i = int(rng.integers(v0, last_ok))
    if kind == "extra_value":
        tok = pick(rng, ["9", "0", "9.5", "-1"])
        lines[i] = lines[i].rstrip(" ") + m["sep"] + tok
        return ply_rebuild(base, body_lines=lines), f"body line {i + 1} (vertex {i - v0}) has a value too many"
    toks = lines[i].rstrip(" ").rsplit(None, 1)
    lines[i] = toks[0] if len(toks) > 1 else ""
    return ply_rebuild(base, body_lines=lines), f"body line {i + 1} (vertex {i - v0}) lacks its last value"


def refuse_text(rng, base: Base):
    m = base.meta
    idx = m["data_idx"]
    options = []
    if len(idx) >= 3:
        options += ["more", "fewer"]
    if m["pts_count"]:
        options.append("count")
    if not options:
        return None
    kind = options[int(rng.integers(len(options)))]
    lines = list(m["lines"])
    if kind == "count":
        n = len(idx)
        i = next(i for i, l in enumerate(lines) if l.strip() == str(n))
        new = n + int(rng.integers(1, 5)) if rng.random() < 0.5 or n < 2 else int(rng.integers(0, n))
        lines[i] = str(new)
        return text_rebuild(base, lines), f"PTS count line says {new}, the file holds {n} points"
    j = int(rng.integers(0, len(idx) - 1))  # not the last data line
    i = idx[j]
    sep = m["sep"]
    if kind == "more":
        lines[i] = lines[i] + sep + pick(rng, ["7", "0.5", "-3", "255"])
        return text_rebuild(base, lines), f"data line {j + 1} (file line {i + 1}) has a value too many"
    spans = _token_spans(lines[i])
    cut = spans[-1][0]
    lines[i] = lines[i][:cut].rstrip(" \t,;")
    return text_rebuild(base, lines), f"data line {j + 1} (file line {i + 1}) lacks its last value"


def refuse_las(rng, base: Base):
    """Header fields that promise more than the file holds."""
    data = bytearray(base.data)
    m = base.meta
    n = m["n"]
    nvlr = struct.unpack_from("<I", data, 100)[0]
    options = ["count_up"]
    if nvlr > 0 and len(data) - m["header_size"] - 54 < 65535:
        options.append("vlr_past_end")
    if base.fmt == "las":
        options.append("record_len_up")
    kind = options[int(rng.integers(len(options)))]
    if kind == "count_up":
        new = n + pick(rng, [1, 2, 10, 1000, 2**20])
        if m["version"] == "1.4":
            struct.pack_into("<Q", data, 247, new)
            if m["pf"] < 6:
                struct.pack_into("<I", data, 107, min(new, 2**32 - 1))
        else:
            struct.pack_into("<I", data, 107, new)
        return bytes(data), f"header point count {new}, {n} points written"
    if kind == "vlr_past_end":
        # VLR header: reserved u16, user id [16], record id u16, record length u16 (offset 20).
        at = m["header_size"] + 20
        new = int(rng.integers(len(data) - m["header_size"] - 54 + 1, 65536))
        struct.pack_into("<H", data, at, new)
        return bytes(data), f"first VLR's record length {new} runs past the file's end ({len(data)} B)"
    old = struct.unpack_from("<H", data, 105)[0]
    new = old + int(rng.integers(1, 9))
    struct.pack_into("<H", data, 105, new)
    return bytes(data), f"point record length {new}, records written are {old} bytes"


def refuse_e57(rng, base: Base):
    """A checksum that does not match its page, or a scan declaring more points than stored."""
    data = bytearray(base.data)
    kind = pick(rng, ["crc_xml", "crc_data", "count_up"], p=[0.35, 0.35, 0.3])
    xml_off = base.meta["xml"][0]
    if kind == "count_up":
        xml = e57_xml(base)
        # Every scan's points vector: <points type="CompressedVector" ... recordCount="N">.
        hits = list(re.finditer(rb'recordCount="(\d+)"', xml))
        if hits:
            h = hits[int(rng.integers(len(hits)))]
            old = int(h.group(1))
            # At least 8 more: a byte stream is padded to whole bytes, so with fields of under 8
            # bits up to 7 records more than were written fit in its last byte, and no reader can
            # tell those from real ones (nkrr refuses a count its streams cannot hold).
            new = old + pick(rng, [8, 1000])
            xml = xml[:h.start(1)] + str(new).encode() + xml[h.end(1):]
            return e57_replace_xml(base, xml), f"a scan's recordCount {new}, {old} points stored (checksums fixed)"
        kind = "crc_xml"
    if kind == "crc_xml":
        lo, hi = xml_off, base.hot[1][1]
    else:
        lo, hi = 48, xml_off
    for _ in range(50):  # a data byte, not a checksum byte (either would do; this is clearer)
        at = int(rng.integers(lo, max(hi, lo + 1)))
        if at % E57_PAGE < E57_PAGE_DATA and at < len(data):
            break
    data[at] ^= 1 << int(rng.integers(8))
    where = "XML" if kind == "crc_xml" else "binary data"
    return bytes(data), f"one bit flipped at byte {at} ({where}), page checksum not updated"


REFUSE = {"ply": refuse_ply, "text": refuse_text, "las": refuse_las, "laz": refuse_las, "e57": refuse_e57}


# --------------------------------------------------------------------------- derivations: random damage

EXTREMES = [b"\x00", b"\xff", b"\x7f\xff\xff\xff", b"\xff\xff\xff\x7f", b"\x80\x00\x00\x00", b"\x00\x00\x00\x80",
            b"\xff\xff\xff\xff\xff\xff\xff\xff", b"\x7f\xf0\x00\x00\x00\x00\x00\x00", b"\x00\x00\x00\x00\x00\x00\xf0\x7f",
            b"\x7f\xf8\x00\x00\x00\x00\x00\x00", b"\x00\x00\x80\x7f", b"\x00\x00\xc0\x7f", b"9999999999", b"-",
            b"\n", b"\r", b" ", b"\xef\xbb\xbf", b"e", b"."]


def pick_offset(rng, base: Base, size: int) -> int:
    """A byte offset: in a hot region (header, E57 XML) half of the time, else anywhere."""
    if size <= 0:
        return 0
    if rng.random() < 0.5 and base.hot:
        lo, hi = base.hot[int(rng.integers(len(base.hot)))]
        hi = min(hi, 400 if lo == 0 else hi, size)
        if hi > lo:
            return int(rng.integers(lo, hi))
    return int(rng.integers(0, size))


def byte_mutation(rng, base: Base, data: bytearray) -> str:
    """One random byte-level mutation of `data`, in place; returns what it did."""
    size = len(data)
    kind = pick(rng, ["flip", "overwrite", "extreme", "insert", "delete", "duplicate", "zero"],
                          p=[0.25, 0.15, 0.15, 0.12, 0.12, 0.11, 0.10])
    at = pick_offset(rng, base, size)
    if kind == "flip":
        k = int(rng.integers(1, 17))
        for _ in range(k):
            a = pick_offset(rng, base, size) if rng.random() < 0.3 else min(size - 1, at + int(rng.integers(0, 16)))
            if size:
                data[a] ^= 1 << int(rng.integers(8))
        return f"{k} bit flips near byte {at}"
    if kind == "overwrite":
        k = int(rng.integers(1, 17))
        data[at:at + k] = rng.integers(0, 256, k, dtype=np.uint8).tobytes()
        return f"{k} random bytes at {at}"
    if kind == "extreme":
        pat = EXTREMES[int(rng.integers(len(EXTREMES)))] * int(rng.integers(1, 5))
        pat = pat[:16]
        data[at:at + len(pat)] = pat
        return f"bytes {pat[:8].hex()} at {at}"
    if kind == "insert":
        k = int(rng.integers(1, 17))
        ins = rng.integers(0, 256, k, dtype=np.uint8).tobytes() if rng.random() < 0.5 else bytes(data[at:at + k])
        data[at:at] = ins
        return f"{len(ins)} bytes inserted at {at}"
    if kind == "delete":
        k = int(rng.integers(1, 17)) if rng.random() < 0.8 else int(rng.integers(17, 1025))
        del data[at:at + k]
        return f"{k} bytes deleted at {at}"
    if kind == "duplicate":
        k = int(rng.integers(1, 257))
        chunk = bytes(data[at:at + k])
        to = int(rng.integers(0, size + 1)) if rng.random() < 0.5 else at + len(chunk)
        data[to:to] = chunk
        return f"{len(chunk)} bytes from {at} copied to {to}"
    k = int(rng.integers(1, 1025))
    data[at:at + k] = bytes(len(data[at:at + k]))
    return f"{k} bytes zeroed at {at}"


BAD_NUMBERS = ["nan", "inf", "-inf", "1e999", "-1e999", "-0", "0x10", "1,5", "NaN", "+", "1e", "--1",
               "1.2.3", "1e-999", "infinity", "", "x", "9" * 40, "١"]


def line_mutation(rng, lines: list[str], idx: list[int]) -> tuple[list[str], str]:
    """One line-level mutation (text, ascii PLY): delete, duplicate or swap lines, insert a garbage
    token, or replace a number with an odd one."""
    lines = list(lines)
    kind = pick(rng, ["delete", "duplicate", "swap", "garbage", "number"], p=[0.15, 0.15, 0.15, 0.2, 0.35])
    i = idx[int(rng.integers(len(idx)))] if idx and rng.random() < 0.85 else int(rng.integers(len(lines)))
    if kind == "delete":
        del lines[i]
        return lines, f"line {i + 1} deleted"
    if kind == "duplicate":
        lines.insert(i, lines[i])
        return lines, f"line {i + 1} duplicated"
    if kind == "swap":
        j = int(rng.integers(len(lines)))
        lines[i], lines[j] = lines[j], lines[i]
        return lines, f"lines {i + 1} and {j + 1} swapped"
    spans = _token_spans(lines[i])
    s, tok = spans[int(rng.integers(len(spans)))]
    if kind == "garbage":
        g = pick(rng, ["abc", "#", "//", "\x00", "\x7f", "é", "1 2", "\t", ";;", ",", "ply", "end_header"])
        lines[i] = lines[i][:s] + g + " " + lines[i][s:]
        return lines, f"token {g!r} inserted in line {i + 1}"
    bad = BAD_NUMBERS[int(rng.integers(len(BAD_NUMBERS)))]
    lines[i] = lines[i][:s] + bad + lines[i][s + len(tok):]
    return lines, f"{tok[:20]!r} -> {bad!r} in line {i + 1}"


def ply_header_mutation(rng, base: Base) -> tuple[bytes, str]:
    """A header line changed in a way the syntax allows: a count, a type, a name, the format."""
    hdr = list(base.meta["hdr_lines"])
    i = int(rng.integers(1, len(hdr)))
    w = hdr[i].split()
    if w[:1] == ["element"] and len(w) == 3:
        n = int(w[2])
        w[2] = str(pick(rng, [0, 1, n - 1, n + 1, 2 * n, 2**31, 2**32, 2**63, 2**64 - 1, 2**64, -1]))
    elif w[:1] == ["property"] and len(w) >= 3:
        w[-2 if w[1] != "list" else int(rng.integers(2, 4))] = pick(rng, list(PLY_NP) + ["int64", "half", "list"])
    elif w[:1] == ["format"]:
        w[1 + int(rng.integers(2))] = pick(rng, ["ascii", "binary_little_endian", "binary_big_endian", "2.0", "1", "binary"])
    else:
        hdr.insert(i, pick(rng, ["element vertex 3", "property float x", "format ascii 1.0", "end_header", "bogus"]))
        return ply_rebuild(base, hdr_lines=hdr), f"header line inserted before line {i + 1}"
    old = hdr[i]
    hdr[i] = " ".join(w)
    return ply_rebuild(base, hdr_lines=hdr), f"header {old!r} -> {hdr[i]!r}"


LAS_FIELDS = [(24, "B", "version major"), (25, "B", "version minor"), (94, "H", "header size"),
              (96, "I", "offset to points"), (100, "I", "VLR count"), (104, "B", "point format"),
              (105, "H", "record length"), (107, "I", "legacy count"), (131, "d", "x scale"),
              (147, "d", "z scale"), (155, "d", "x offset"), (171, "d", "z offset"), (179, "d", "max x"),
              (187, "d", "min x"), (235, "Q", "first EVLR"), (243, "I", "EVLR count"), (247, "Q", "point count")]


def las_field_mutation(rng, base: Base) -> tuple[bytes, str]:
    """A public-header field set to an extreme or nearby value."""
    data = bytearray(base.data)
    fields = [f for f in LAS_FIELDS if f[0] < 235 or base.meta["version"] == "1.4"]
    at, code, name = fields[int(rng.integers(len(fields)))]
    if rng.random() < 0.3 and struct.unpack_from("<I", data, 100)[0] > 0:
        at, code, name = base.meta["header_size"] + 20, "H", "first VLR record length"
    old = struct.unpack_from("<" + code, data, at)[0]
    if code == "d":
        new = pick(rng, [0.0, -0.0, np.nan, np.inf, -np.inf, 1e308, 5e-324, -old, old * 1e6, old * 1e-6])
    else:
        top = 2 ** (8 * struct.calcsize(code)) - 1
        new = pick(rng, [0, 1, top, top // 2, top // 2 + 1, max(old - 1, 0), min(old + 1, top), min(old * 2, top)])
    struct.pack_into("<" + code, data, at, new)
    return bytes(data), f"LAS {name} {old} -> {new}"


def e57_xml_mutation(rng, base: Base) -> tuple[bytes, str]:
    """A change in the XML (a number, an attribute, a tag), with lengths and checksums fixed so
    that the XML parser and the scan reader see it."""
    xml = e57_xml(base)
    nums = list(re.finditer(rb"-?\d+(\.\d+)?([eE][-+]?\d+)?", xml))
    kind = pick(rng, ["number", "type", "delete", "byte"], p=[0.5, 0.15, 0.15, 0.2])
    if kind == "number" and nums:
        h = nums[int(rng.integers(len(nums)))]
        v = float(h.group())
        near = repr(v * 2 + 1) if abs(v) < 1e300 else "1"
        new = pick(rng, ["0", "-1", "1", "2147483648", "18446744073709551616", "1e308", "nan", "-0", near,
                         "99999999999999999999", ""]).encode()
        return e57_replace_xml(base, xml[:h.start()] + new + xml[h.end():]), f"XML number {h.group()[:20]!r} -> {new!r}"
    if kind == "type":
        types = [b"Float", b"Integer", b"ScaledInteger", b"String", b"Structure", b"Vector", b"CompressedVector", b"Blob"]
        hits = list(re.finditer(rb'type="(\w+)"', xml))
        if hits:
            h = hits[int(rng.integers(len(hits)))]
            new = types[int(rng.integers(len(types)))]
            return e57_replace_xml(base, xml[:h.start(1)] + new + xml[h.end(1):]), f"XML type {h.group(1)!r} -> {new!r}"
    if kind == "delete":
        hits = list(re.finditer(rb"<(\w+)[^>]*>[^<]*</\1>", xml))
        if hits:
            h = hits[int(rng.integers(len(hits)))]
            return e57_replace_xml(base, xml[:h.start()] + xml[h.end():]), f"XML element {h.group(1)!r} deleted"
    b = bytearray(xml)
    at = int(rng.integers(len(b)))
    b[at] = pick(rng, [0, 0x3c, 0x3e, 0x22, 0x20, 0xff, int(rng.integers(256))])
    return e57_replace_xml(base, bytes(b)), f"XML byte {at} -> 0x{b[at]:02x}"


def derive_any(rng, base: Base) -> tuple[bytes, str]:
    """Random damage: byte mutations (1-3 stacked), line mutations for line formats, and
    format-aware ones (PLY header lines, LAS header fields, E57 XML with checksums fixed)."""
    fmt = base.fmt
    r = rng.random()
    lines = base.meta.get("lines")
    if fmt == "text" and r < 0.4:
        lines, desc = line_mutation(rng, lines, base.meta["data_idx"])
        return text_rebuild(base, lines), desc
    if fmt == "ply" and lines is not None and r < 0.35:
        v0, v1 = base.meta["vrange"]
        lines, desc = line_mutation(rng, lines, list(range(v0, v1)))
        return ply_rebuild(base, body_lines=lines), "body " + desc
    if fmt == "ply" and 0.35 <= r < 0.55:
        return ply_header_mutation(rng, base)
    if fmt in ("las", "laz") and r < 0.25:
        return las_field_mutation(rng, base)
    if fmt == "e57" and r < 0.3:
        return e57_xml_mutation(rng, base)
    data = bytearray(base.data)
    k = pick(rng, [1, 2, 3], p=[0.7, 0.2, 0.1])
    descs = [byte_mutation(rng, base, data) for _ in range(k)]
    if fmt == "e57" and rng.random() < 0.5 and len(data) == len(base.data):
        # Same length: fix the checksums, so that the damage reaches the parser.
        return e57_fix_crcs(bytes(data)), "; ".join(descs) + " (checksums fixed)"
    return bytes(data), "; ".join(descs)


# --------------------------------------------------------------------------- groups and batches

def write_base(rng, fmt: str, tmp: Path, tag: str) -> Base:
    if fmt == "ply":
        return ply_serialise(rng, ply_model(rng))
    if fmt == "text":
        return text_serialise(rng, text_model(rng))
    if fmt in ("las", "laz"):
        return las_base(rng, fmt == "laz")
    return e57_base(rng, tmp / f"{tag}.e57", tag)


def make_group(rng, fmt: str, tmp: Path, tag: str) -> list[Case]:
    """A valid file, its valid variants, and the cases derived from it."""
    if fmt == "ply":
        model = ply_model(rng)
        base = ply_serialise(rng, model)
        variants = [ply_serialise(rng, model) for _ in range(VARIANTS_PER_BASE[fmt])]
    elif fmt == "text":
        model = text_model(rng)
        base = text_serialise(rng, model)
        variants = [text_serialise(rng, model) for _ in range(VARIANTS_PER_BASE[fmt])]
    else:
        base, variants = write_base(rng, fmt, tmp, tag), []
    cases = [Case(fmt, "exact", base.ext, base.data, base.what, base)]
    cases += [Case(fmt, "exact", v.ext, v.data, "variant: " + v.what, v) for v in variants]
    for _ in range(DERIVED_PER_BASE[fmt]):
        kind = pick(rng, DERIVED_KINDS, p=DERIVED_WEIGHTS)
        src = variants[0] if variants and rng.random() < 0.5 else base
        got = None
        if kind == "refuse_or_warn":
            got = REFUSE[fmt](rng, src)
            if got is None:  # no targeted damage fits this file (a text file of 2 lines)
                kind = "any"
        if kind == "prefix":
            got = derive_prefix(rng, src)
        elif kind == "any":
            got = derive_any(rng, src)
        data, what = got
        cases.append(Case(fmt, kind, src.ext, data, f"{what} | of: {src.what}", src))
    return cases


def generate_batch(seed: int, b: int, size: int, out: Path, start_index: int) -> tuple[Path, list[dict]]:
    """Writes batch b's files and manifest under out/batch-b; returns the manifest path and rows."""
    rng = np.random.default_rng([seed, b])
    bdir = out / f"batch-{b:05d}"
    if bdir.exists():
        shutil.rmtree(bdir)
    bdir.mkdir(parents=True)
    quota = [size // len(FORMATS) + (i < size % len(FORMATS)) for i in range(len(FORMATS))]
    tmp = bdir / "writer"  # pye57 writes to a path: its files, copied into the cases, go here
    tmp.mkdir()
    cases: list[Case] = []
    for fmt, q in zip(FORMATS, quota):
        got, g = [], 0
        while len(got) < q:
            got += make_group(rng, fmt, tmp, f"s{seed}-b{b}-{fmt}{g}")
            g += 1
        cases += got[:q]
    shutil.rmtree(tmp)
    # Interleave formats in the manifest, so a crash or hang costs a mixed slice of cases.
    order = rng.permutation(len(cases))
    rows = []
    for k, ci in enumerate(order):
        c = cases[ci]
        name = f"b{b}-{start_index + k}"
        path = bdir / f"{name}.{c.ext}"
        path.write_bytes(c.data)
        points = None
        if c.expect in ("exact", "prefix"):
            if c.base.points_path is None:
                p = bdir / f"{name}.f64"
                p.write_bytes(np.ascontiguousarray(c.base.points, "<f8").tobytes())
                c.base.points_path = str(p.resolve())
            points = c.base.points_path
        rows.append({"case": name, "file": str(path.resolve()), "format": c.fmt, "expect": c.expect,
                     "points": points, "what": c.what[:300]})
    manifest = bdir / "manifest.jsonl"
    manifest.write_text("".join(json.dumps(r) + "\n" for r in rows))
    return manifest, rows


# --------------------------------------------------------------------------- the checker

class CheckerRun:
    """The checker on one batch, in the background; stdout goes to a file (a pipe left unread
    while the next batch is generated would fill and block it)."""

    def __init__(self, checker: str, manifest: Path, rows: list[dict], case_timeout: float):
        self.checker, self.manifest, self.rows, self.case_timeout = checker, manifest, rows, case_timeout
        self.results: dict[str, dict] = {}
        self.restarts = 0
        self._start(0)

    def _start(self, skip: int):
        self.skip = skip
        self.out_path = self.manifest.with_name(f"results-{skip}.jsonl")
        self.out = open(self.out_path, "wb")
        self.err = open(self.manifest.with_name(f"stderr-{skip}.txt"), "wb")
        cmd = [self.checker, str(self.manifest), "--skip", str(skip), "--timeout", str(self.case_timeout)]
        self.proc = subprocess.Popen(cmd, stdout=self.out, stderr=self.err, stdin=subprocess.DEVNULL)

    def _read(self) -> list[dict]:
        got = []
        for line in self.out_path.read_bytes().splitlines():
            try:
                got.append(json.loads(line))
            except json.JSONDecodeError:
                pass  # a line cut by a crash
        return got

    def finish(self) -> dict[str, dict]:
        """Waits for the checker, restarting it after a hang (exit 3) or a crash; returns the
        verdict of every case by name."""
        while True:
            last_size, last_change, killed = -1, time.time(), False
            while self.proc.poll() is None:
                time.sleep(0.05)
                size = self.out_path.stat().st_size
                if size != last_size:
                    last_size, last_change = size, time.time()
                elif time.time() - last_change > self.case_timeout * 2 + 30:
                    self.proc.kill()  # the checker's own timeout failed: count a hang
                    self.proc.wait()
                    killed = True
            self.out.close()
            self.err.close()
            got = self._read()
            for r in got:
                self.results[r["case"]] = r
            done = self.skip + len(got)
            rc = self.proc.returncode
            if rc == 0 and done >= len(self.rows):
                return self.results
            if rc == 3 and got and got[-1].get("outcome") == "hang":
                nxt = done  # the hang is printed; carry on after it
            else:
                if done >= len(self.rows):
                    return self.results
                stderr = self.manifest.with_name(f"stderr-{self.skip}.txt").read_bytes()[-400:].decode(errors="replace")
                outcome = "hang" if killed else "crash"
                self.results[self.rows[done]["case"]] = {
                    "case": self.rows[done]["case"], "outcome": outcome, "ok": False, "ms": None,
                    "detail": (f"the checker printed nothing for {self.case_timeout * 2 + 30:.0f} s and was killed"
                               if killed else f"checker exited with status {rc} on this case; stderr: {stderr.strip()}")}
                nxt = done + 1
            self.restarts += 1
            if nxt >= len(self.rows):
                return self.results
            self._start(nxt)


def default_checker() -> str:
    for kind in ("release", "debug"):
        p = REPO / "target" / kind / "examples" / "read_oracle"
        if p.exists():
            return str(p)
    return str(REPO / "target" / "release" / "examples" / "read_oracle")


# --------------------------------------------------------------------------- self-check (no checker)

def self_check_rows(rows: list[dict]) -> dict[str, dict]:
    """Reads every exact case back with independent readers (laspy, pye57, this script's PLY
    and text parsers) and compares with the recorded points: tests the generator, not nkrr."""
    results = {}
    for r in rows:
        if r["expect"] != "exact":
            continue
        want = np.fromfile(r["points"], "<f8").reshape(-1, 3)
        try:
            got = SELF_READERS[r["format"]](Path(r["file"]).read_bytes(), r["file"])
            ok = got.shape == want.shape and bool(np.all(np.abs(got - want) <= 1e-9 * (1 + np.abs(want))))
            detail = "" if ok else f"{len(got)} read, {len(want)} written; max diff {np.abs(got - want).max() if got.shape == want.shape else '-'}"
        except Exception as e:  # noqa: BLE001 - any failure is a generator bug to report
            ok, detail = False, f"{type(e).__name__}: {e}"
        results[r["case"]] = {"case": r["case"], "outcome": "exact" if ok else "misread", "ok": ok, "detail": detail, "ms": 0.0}
    return results


def self_read_ply(data: bytes, _name) -> np.ndarray:
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    # Header lines end with LF, CRLF or CR (the writer's choices).
    end = data.index(b"end_header") + len(b"end_header")
    end += 2 if data[end:end + 2] == b"\r\n" else 1
    hdr = data[:end].decode().replace("\r\n", "\n").replace("\r", "\n").split("\n")
    fmt, elements = None, []
    for line in hdr[1:]:
        w = line.split()
        if not w or w[0] in ("comment", "obj_info"):
            continue
        if w[0] == "format":
            fmt = w[1]
        elif w[0] == "element":
            elements.append((w[1], int(w[2]), []))
        elif w[0] == "property":
            elements[-1][2].append(w[1:])
    alias = {v: k for k, v in PLY_ALIAS.items()}
    t = lambda s: PLY_NP[alias.get(s, s)]  # noqa: E731
    pos, xyz = end, None
    if fmt == "ascii":
        toks = data[end:].split()
        k = 0
        for name, n, props in elements:
            rows = []
            for _ in range(n):
                row = {}
                for p in props:
                    if p[0] == "list":
                        c = int(toks[k]); k += 1 + c
                    else:
                        row[p[1]] = float(np.float32(toks[k])) if t(p[0]) == "f4" else float(toks[k]); k += 1
                rows.append(row)
            if name == "vertex":
                xyz = np.array([[r["x"], r["y"], r["z"]] for r in rows])
        return xyz
    e = "<" if fmt == "binary_little_endian" else ">"
    for name, n, props in elements:
        if all(p[0] != "list" for p in props):
            dt = np.dtype([(p[1], e + t(p[0])) for p in props])
            rec = np.frombuffer(data, dt, n, pos)
            pos += n * dt.itemsize
            if name == "vertex":
                xyz = np.stack([rec["x"], rec["y"], rec["z"]], 1).astype(np.float64)
            continue
        rows = []
        for _ in range(n):
            row = {}
            for p in props:
                if p[0] == "list":
                    c = int(np.frombuffer(data, e + t(p[1]), 1, pos)[0])
                    pos += np.dtype(t(p[1])).itemsize + c * np.dtype(t(p[2])).itemsize
                else:
                    row[p[1]] = float(np.frombuffer(data, e + t(p[0]), 1, pos)[0])
                    pos += np.dtype(t(p[0])).itemsize
            rows.append(row)
        if name == "vertex":
            xyz = np.array([[r["x"], r["y"], r["z"]] for r in rows])
    return xyz


def self_read_text(data: bytes, _name) -> np.ndarray:
    text = data.decode().lstrip("\ufeff")
    pts, names = [], None
    for line in text.replace("\r\n", "\n").replace("\r", "\n").split("\n"):
        t = line.strip()
        if not t or t.startswith("#") or (t.startswith("//") and not t[2:3].upper() == "X"):
            continue
        toks = [x for x in t.replace(",", " ").replace(";", " ").split()]
        try:
            vals = [float(x) for x in toks]
        except ValueError:
            names = [x.strip('"/').lower() for x in toks]
            continue
        if len(vals) == 1:
            continue  # PTS count
        if names and {"x", "y", "z"} <= set(names):
            pts.append([vals[names.index(a)] for a in "xyz"])
        elif names and {"pos_x", "pos_y", "pos_z"} <= set(names):
            pts.append([vals[names.index("pos_" + a)] for a in "xyz"])
        else:
            pts.append(vals[:3])
    return np.array(pts, dtype=np.float64)


def self_read_las(data: bytes, _name) -> np.ndarray:
    las = laspy.read(io.BytesIO(data))
    return np.stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)], 1)


def self_read_e57(_data: bytes, name) -> np.ndarray:
    e = pye57.E57(name)
    parts = []
    for i in range(e.scan_count):
        d = e.read_scan(i, transform=True, ignore_missing_fields=True)
        parts.append(np.stack([d["cartesianX"], d["cartesianY"], d["cartesianZ"]], 1))
    e.close()
    return np.concatenate(parts)


SELF_READERS = {"ply": self_read_ply, "text": self_read_text, "las": self_read_las, "laz": self_read_las,
                "e57": self_read_e57}


# --------------------------------------------------------------------------- summary

def summarise(rows_by_case: dict, results: dict, elapsed: float, gen_time: float, args, failures: list) -> dict:
    table = Counter()
    for name, row in rows_by_case.items():
        r = results.get(name)
        table[(row["format"], row["expect"], r["outcome"] if r else "unchecked")] += 1
    n = len(rows_by_case)
    # A few examples of each kind of failure (one kind may have thousands).
    per_kind, examples = Counter(), []
    for f in failures:
        key = (f["format"], f["expect"], f["outcome"])
        per_kind[key] += 1
        if per_kind[key] <= 3:
            examples.append(f)
    return {
        "cases": n, "seed": args.seed, "checker": None if args.no_check else args.checker,
        "seconds": round(elapsed, 2), "cases_per_second": round(n / max(elapsed, 1e-9), 1),
        "generator_seconds": round(gen_time, 2), "generator_cases_per_second": round(n / max(gen_time, 1e-9), 1),
        "failed": len(failures),
        "by_expect": dict(Counter(r["expect"] for r in rows_by_case.values())),
        "by_format": dict(Counter(r["format"] for r in rows_by_case.values())),
        "table": [{"format": f, "expect": e, "outcome": o, "count": c} for (f, e, o), c in sorted(table.items())],
        "failure_kinds": [{"format": f, "expect": e, "outcome": o, "count": c} for (f, e, o), c in per_kind.most_common()],
        "failure_examples": examples[:60],
    }


def summary_markdown(s: dict) -> str:
    outcomes = sorted({t["outcome"] for t in s["table"]})
    counts = {(t["format"], t["expect"], t["outcome"]): t["count"] for t in s["table"]}
    lines = [f"# fuzz_readers: {s['cases']} cases, seed {s['seed']}", "",
             f"{s['failed']} failed; {s['seconds']} s in all ({s['cases_per_second']} cases/s); "
             f"generator {s['generator_seconds']} s ({s['generator_cases_per_second']} cases/s)", "",
             "| format | expect | " + " | ".join(outcomes) + " | total |",
             "|---|---|" + "---:|" * (len(outcomes) + 1)]
    for f in FORMATS:
        for e in EXPECTS:
            row = [counts.get((f, e, o), 0) for o in outcomes]
            if sum(row):
                lines.append(f"| {f} | {e} | " + " | ".join(str(c) if c else "" for c in row) + f" | {sum(row)} |")
    if s["failure_examples"]:
        lines += ["", "## Failures: up to 3 examples of each kind (all in failures/failures.jsonl)", ""]
        for f in s["failure_examples"][:30]:
            lines.append(f"- `{f['case']}` {f['format']} {f['expect']} -> **{f['outcome']}**: {f['what'][:160]} "
                         f"— {str(f.get('detail', ''))[:200]}")
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- main

def record_failures(rows: list[dict], results: dict, out: Path, keep_all: bool, kept: Counter,
                    failures: list) -> None:
    fdir = out / "failures"
    fdir.mkdir(parents=True, exist_ok=True)
    for row in rows:
        r = results.get(row["case"])
        if r is None or r.get("ok"):
            continue
        fail = {**row, "outcome": r["outcome"], "detail": r.get("detail", "")}
        failures.append(fail)
        with open(fdir / "failures.jsonl", "a") as f:
            f.write(json.dumps(fail) + "\n")
        key = (row["format"], row["expect"], r["outcome"])
        if not keep_all and kept[key] >= 10:
            continue  # the first 10 of each kind keep their files (bounded disk), all with --keep-failures
        kept[key] += 1
        kept_row = dict(row)
        src = Path(row["file"])
        dst = fdir / src.name
        shutil.copyfile(src, dst)
        kept_row["file"] = str(dst.resolve())
        if row["points"]:
            pdst = fdir / f"{row['case']}.f64"
            shutil.copyfile(row["points"], pdst)
            kept_row["points"] = str(pdst.resolve())
        with open(fdir / "manifest.jsonl", "a") as f:
            f.write(json.dumps(kept_row) + "\n")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--cases", type=int, required=True)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--checker", default=None, help="default: target/release/examples/read_oracle if it exists, else target/debug/...")
    ap.add_argument("--out", default=str(REPO / "target" / "fuzz-readers"))
    ap.add_argument("--batch", type=int, default=2000)
    ap.add_argument("--keep-failures", action="store_true", help="keep the files of every failing case (default: the first 10 of each kind)")
    ap.add_argument("--case-timeout", type=float, default=20.0, help="seconds per case before the checker calls it a hang")
    ap.add_argument("--no-check", action="store_true", help="generate only (measures the generator); with --self-check, test it")
    ap.add_argument("--self-check", action="store_true", help="re-read exact cases with laspy/pye57/own parsers")
    args = ap.parse_args()
    args.checker = args.checker or default_checker()
    if not args.no_check and not os.access(args.checker, os.X_OK):
        print(f"fuzz_readers: no checker at {args.checker}: build it with "
              f"`cargo build --release --example read_oracle`, or pass --checker", file=sys.stderr)
        return 2
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    # Failures and batches of an earlier (perhaps interrupted) run would mix with this one's.
    for old in [out / "failures", *out.glob("batch-*")]:
        if old.exists():
            shutil.rmtree(old)

    t0 = time.time()
    gen_time = 0.0
    nbatches = -(-args.cases // args.batch)
    rows_by_case: dict[str, dict] = {}
    results: dict[str, dict] = {}
    failures: list[dict] = []
    kept: Counter = Counter()
    pending = None  # (batch index, rows, CheckerRun, manifest)
    checked = [0]   # cases whose verdicts are in

    def collect(p):
        b, rows, run, manifest = p
        tc = time.time()
        got = run.finish() if run else (self_check_rows(rows) if args.self_check else {})
        results.update(got)
        record_failures(rows, got, out, args.keep_failures, kept, failures)
        shutil.rmtree(manifest.parent)
        checked[0] += len(rows)
        done = checked[0]
        bad = sum(1 for r in rows if not got.get(r["case"], {"ok": True}).get("ok"))
        print(f"batch {b + 1}/{nbatches}: {len(rows)} cases, {bad} failed "
              f"(total {len(failures)} of {done}), waited {time.time() - tc:.1f} s for the "
              f"{'checker' if run else 'self-check'}{f', {run.restarts} restarts' if run and run.restarts else ''}; "
              f"{done / (time.time() - t0):.0f} cases/s", file=sys.stderr, flush=True)

    for b in range(nbatches):
        size = min(args.batch, args.cases - b * args.batch)
        tg = time.time()
        manifest, rows = generate_batch(args.seed, b, size, out, b * args.batch)
        gen_time += time.time() - tg
        for r in rows:
            rows_by_case[r["case"]] = r
        if pending:
            collect(pending)  # the previous batch's checker ran while this one was generated
        run = None if args.no_check else CheckerRun(args.checker, manifest, rows, args.case_timeout)
        pending = (b, rows, run, manifest)
    if pending:
        collect(pending)

    elapsed = time.time() - t0
    s = summarise(rows_by_case, results, elapsed, gen_time, args, failures)
    md = summary_markdown(s)
    (out / "summary.json").write_text(json.dumps(s, indent=1) + "\n")
    (out / "summary.md").write_text(md)
    print(md)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
