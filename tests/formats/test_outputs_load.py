"""nkrr's output meshes (GLB, PLY, OBJ, STL) load in an independent library (trimesh, and
Open3D where it is importable) and agree with each other and with the input cloud.

    .venv-formats/bin/python -m pytest -q tests/formats

NKRR_BIN picks the binary (default target/debug/nkrr, relative to the repository root). A
missing binary or missing tests/data/eval/spot-3k.ply fails the tests; it does not skip them.
"""

from __future__ import annotations

import json
import os
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest
import trimesh

REPO = Path(__file__).resolve().parents[2]
SPOT = REPO / "tests" / "data" / "eval" / "spot-3k.ply"
FORMATS = ("glb", "ply", "obj", "stl")
RESOLUTION = "48"
BOUNDS_TOLERANCE = 0.05  # of the cloud's largest extent
COLOUR_TOLERANCE = 8.0  # mean |error| per channel, in 0..255 units


def nkrr_bin() -> Path:
    raw = os.environ.get("NKRR_BIN", "target/debug/nkrr")
    p = Path(raw)
    if not p.is_absolute():
        p = p if p.exists() else REPO / p
    return p


def read_ply_points(path: Path) -> np.ndarray:
    """x, y, z of a binary little-endian float PLY such as spot-3k.ply."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").split("\n")
    assert "format binary_little_endian 1.0" in header, header
    n = int(next(l for l in header if l.startswith("element vertex")).split()[2])
    props = [l.split()[2] for l in header if l.startswith("property")]
    assert props[:3] == ["x", "y", "z"] and all(l.split()[1] == "float" for l in header if l.startswith("property")), header
    return np.frombuffer(data, "<f4", count=n * len(props), offset=end).reshape(n, -1)[:, :3].astype(np.float64)


def colour_formula(p: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The fixtures' colour (tests/fixtures/formats/manifest.json): 255 * (p - lo) / (hi - lo)
    per axis (x->r, y->g, z->b), rounded; clipped to 0..255 for points outside the bounds."""
    return np.clip(np.rint(255.0 * (p - lo) / (hi - lo)), 0, 255)


def write_coloured_ply(path: Path, xyz: np.ndarray, rgb: np.ndarray) -> None:
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(xyz)}\n"
              "property float x\nproperty float y\nproperty float z\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n")
    rec = np.empty(len(xyz), dtype=[("p", "<f4", 3), ("c", "u1", 3)])
    rec["p"], rec["c"] = xyz, rgb
    path.write_bytes(header.encode("ascii") + rec.tobytes())


def glb_json(path: Path) -> dict:
    data = path.read_bytes()
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    assert magic == b"glTF" and version == 2 and length == len(data)
    chunk_len, chunk_type = struct.unpack_from("<II", data, 12)
    assert chunk_type == 0x4E4F534A  # JSON
    return json.loads(data[20:20 + chunk_len])


def glb_attributes(path: Path) -> set[str]:
    return {a for m in glb_json(path)["meshes"] for p in m["primitives"] for a in p["attributes"]}


def reconstruct(cloud: Path, out: Path) -> subprocess.CompletedProcess:
    cmd = [str(nkrr_bin()), "reconstruct", str(cloud), "--method", "network",
           "--resolution", RESOLUTION, "-o", str(out)]
    r = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, f"{' '.join(cmd)} exited {r.returncode}\n{r.stdout}\n{r.stderr}"
    assert out.is_file() and out.stat().st_size > 0, out
    return r


def load(path: Path, process: bool = False) -> trimesh.Trimesh:
    m = trimesh.load(str(path), force="mesh", process=process)
    assert isinstance(m, trimesh.Trimesh), type(m)
    assert len(m.faces) > 0
    return m


def vertex_colours(path: Path) -> np.ndarray | None:
    """(n, 4) uint8 vertex colours as trimesh reads them, or None.

    trimesh keeps a GLB primitive's material as TextureVisuals and puts COLOR_0 in
    visual.vertex_attributes["color"], which force="mesh" (scene concatenation) drops; with
    skip_materials=True it reads COLOR_0 as ordinary vertex colours. PLY colours load as such."""
    if path.suffix == ".glb":
        scene = trimesh.load(str(path), process=False)
        (g,) = scene.geometry.values()
        from_scene = g.visual.vertex_attributes.get("color") if g.visual.kind == "texture" else None
        m = trimesh.load(str(path), force="mesh", process=False, skip_materials=True)
        if m.visual.kind != "vertex":
            assert from_scene is None
            return None
        c = np.asarray(m.visual.vertex_colors)
        assert from_scene is not None and np.array_equal(np.asarray(from_scene), c)
        return c
    m = load(path)
    return np.asarray(m.visual.vertex_colors) if m.visual.kind == "vertex" else None


def merged(m: trimesh.Trimesh) -> trimesh.Trimesh:
    """Shared-position vertices merged (STL stores three per triangle; OBJ may split)."""
    m = m.copy()
    m.merge_vertices(merge_tex=True, merge_norm=True)
    return m


@pytest.fixture(scope="module")
def binary() -> Path:
    p = nkrr_bin()
    if not p.is_file():
        pytest.fail(f"nkrr binary not found at {p} (set NKRR_BIN or build it: cargo build)")
    if not SPOT.is_file():
        pytest.fail(f"input cloud not found: {SPOT}")
    r = subprocess.run([str(p), "--version"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout.startswith("nkrr "), (r.stdout, r.stderr)
    return p


@pytest.fixture(scope="module")
def cloud() -> np.ndarray:
    return read_ply_points(SPOT)


@pytest.fixture(scope="module")
def plain(binary, tmp_path_factory) -> dict[str, Path]:
    """spot-3k (no colours) reconstructed into each format."""
    d = tmp_path_factory.mktemp("plain")
    out = {}
    for f in FORMATS:
        out[f] = d / f"spot.{f}"
        reconstruct(SPOT, out[f])
    return out


@pytest.fixture(scope="module")
def coloured(binary, cloud, tmp_path_factory) -> dict[str, Path]:
    """spot-3k with the fixtures' colour formula, reconstructed into GLB and PLY."""
    d = tmp_path_factory.mktemp("coloured")
    ply = d / "spot-rgb.ply"
    lo, hi = cloud.min(axis=0), cloud.max(axis=0)
    write_coloured_ply(ply, cloud, colour_formula(cloud, lo, hi).astype(np.uint8))
    out = {}
    for f in ("glb", "ply"):
        # Not spot-rgb.ply: that is the input, which nkrr refuses to overwrite (the mesh once
        # replaced the cloud here without a word).
        out[f] = d / f"spot-rgb-mesh.{f}"
        reconstruct(ply, out[f])
    return out


def test_face_and_vertex_counts_agree(plain):
    raw = {f: load(p) for f, p in plain.items()}
    faces = {f: len(m.faces) for f, m in raw.items()}
    assert len(set(faces.values())) == 1, faces
    # GLB and PLY are indexed with one vertex per position: their raw counts agree exactly.
    assert len(raw["glb"].vertices) == len(raw["ply"].vertices), {f: len(m.vertices) for f, m in raw.items()}
    assert len(raw["stl"].vertices) == 3 * faces["stl"]
    verts = {f: len(merged(m).vertices) for f, m in raw.items()}
    assert len(set(verts.values())) == 1, verts
    assert verts["glb"] == len(raw["glb"].vertices)  # nothing in the GLB to merge


@pytest.mark.parametrize("fmt", FORMATS)
def test_watertight(plain, fmt):
    m = merged(load(plain[fmt]))
    assert m.is_watertight, fmt
    assert m.is_winding_consistent, fmt
    assert m.volume > 0, f"{fmt}: negative volume: faces wound inwards"


@pytest.mark.parametrize("fmt", FORMATS)
def test_bounds_match_cloud(plain, cloud, fmt):
    lo, hi = cloud.min(axis=0), cloud.max(axis=0)
    tol = BOUNDS_TOLERANCE * (hi - lo).max()
    b = load(plain[fmt]).bounds
    err = np.abs(b - np.stack([lo, hi])).max()
    assert err < tol, f"{fmt}: bounds {b.tolist()} vs cloud {[lo.tolist(), hi.tolist()]}: {err:.4f} >= {tol:.4f}"


def test_formats_have_the_same_geometry(plain):
    """Same surface in every format: equal bounds and volume (to float32 text/binary precision)."""
    ref = merged(load(plain["glb"]))
    for f in ("ply", "obj", "stl"):
        m = merged(load(plain[f]))
        assert np.allclose(m.bounds, ref.bounds, atol=1e-5), f
        assert abs(m.volume - ref.volume) < 1e-4 * abs(ref.volume), f


def test_ply_has_vertex_normals(plain):
    with open(plain["ply"], "rb") as fh:
        kw = trimesh.exchange.ply.load_ply(fh)
    n = kw.get("vertex_normals")
    assert n is not None, "PLY output has no nx/ny/nz"
    assert n.shape == kw["vertices"].shape
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-3)
    # They point outwards: they agree with the normals trimesh computes from the faces.
    computed = trimesh.Trimesh(kw["vertices"], kw["faces"], process=False).vertex_normals
    assert np.mean(np.sum(n * computed, axis=1)) > 0.9


def test_no_colours_without_input_colours(plain):
    assert "COLOR_0" not in glb_attributes(plain["glb"])
    assert vertex_colours(plain["glb"]) is None
    with open(plain["ply"], "rb") as fh:
        kw = trimesh.exchange.ply.load_ply(fh)
    assert kw.get("vertex_colors") is None, "PLY output has red/green/blue"
    assert vertex_colours(plain["ply"]) is None


@pytest.mark.parametrize("fmt", ("glb", "ply"))
def test_colours_follow_the_input(coloured, cloud, fmt):
    if fmt == "glb":
        assert "COLOR_0" in glb_attributes(coloured["glb"])
    m = load(coloured[fmt])
    c = vertex_colours(coloured[fmt])
    assert c is not None, f"{fmt}: no vertex colours"
    rgb = c[:, :3].astype(np.float64)
    assert rgb.shape == m.vertices.shape
    expected = colour_formula(m.vertices, cloud.min(axis=0), cloud.max(axis=0))
    err = np.abs(rgb - expected).mean(axis=0)
    assert err.max() < COLOUR_TOLERANCE, f"{fmt}: mean |colour error| per channel {err.round(2).tolist()} (of 255)"


def test_coloured_glb_and_ply_agree(coloured):
    g, p = load(coloured["glb"]), load(coloured["ply"])
    assert len(g.vertices) == len(p.vertices) and len(g.faces) == len(p.faces)
    assert np.allclose(g.vertices, p.vertices, atol=1e-6)
    assert np.array_equal(vertex_colours(coloured["glb"]), vertex_colours(coloured["ply"]))


def test_glb_loads_in_open3d(plain, coloured):
    o3d = pytest.importorskip("open3d")
    ref = load(plain["glb"])
    mesh = o3d.io.read_triangle_mesh(str(plain["glb"]))
    assert len(mesh.triangles) == len(ref.faces)
    assert len(mesh.vertices) == len(ref.vertices)
    assert mesh.has_vertex_normals()
    assert mesh.is_watertight()
    assert np.allclose(np.asarray(mesh.get_min_bound()), ref.bounds[0], atol=1e-5)
    col = o3d.io.read_triangle_mesh(str(coloured["glb"]))
    assert col.has_vertex_colors()
    ref_col = vertex_colours(coloured["glb"])[:, :3] / 255.0
    assert np.abs(np.asarray(col.vertex_colors) - ref_col).max() < 1e-3
