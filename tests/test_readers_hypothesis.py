"""Property-based tests of every reader: random valid files round-trip, and random byte mutations
of valid files never raise anything but a ToolkitError subclass (a typed, one-line error)."""

from __future__ import annotations

import json
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ToolkitError
from shape_toolkit.io.mesh import load_shape, save_shape
from shape_toolkit.pipeline import read_seeds
from shape_toolkit.results.correspondence import load_map, save_map
from shape_toolkit.results.labels import Constraints, load_constraints, read_int_file, save_constraints

SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])

finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False, width=32)


@st.composite
def meshes(draw, min_faces: int = 1):
    n = draw(st.integers(3, 12))
    v = np.array(draw(st.lists(st.tuples(finite, finite, finite), min_size=n, max_size=n)), dtype=np.float64)
    v[:, 0] += np.arange(n)  # distinct points, so STL welding keeps every vertex
    m = draw(st.integers(min_faces, 10))
    faces = set()
    for _ in range(m):
        tri = draw(st.lists(st.integers(0, n - 1), min_size=3, max_size=3, unique=True))
        if frozenset(tri) not in {frozenset(f) for f in faces}:
            faces.add(tuple(tri))
    f = np.array(sorted(faces), dtype=np.int64)
    used = np.unique(f)
    remap = -np.ones(n, dtype=np.int64)
    remap[used] = np.arange(used.size)
    return Shape(v[used], remap[f])  # no unreferenced vertex (STL cannot store them)


def _tmp(suffix: str) -> Path:
    d = Path(tempfile.mkdtemp(prefix="hyp-readers-"))
    return d / f"x{suffix}"


def _mutate(data: bytes, draw_ops) -> bytes:
    b = bytearray(data)
    for kind, pos, val in draw_ops:
        if not b:
            b = bytearray(bytes([val]))
            continue
        i = pos % (len(b) + 1)
        if kind == "flip":
            b[min(i, len(b) - 1)] = val
        elif kind == "insert":
            b[i:i] = bytes([val]) * (1 + val % 5)
        elif kind == "delete":
            del b[i : i + 1 + val % 16]
        elif kind == "truncate":
            del b[i:]
        elif kind == "digits":
            b[i:i] = b"99999999999999999999999"
        elif kind == "minus":
            b[i:i] = b"-"
        elif kind == "dot":
            b[i:i] = b".5"
    return bytes(b)


mutations = st.lists(
    st.tuples(
        st.sampled_from(["flip", "insert", "delete", "truncate", "digits", "minus", "dot"]),
        st.integers(0, 10**6),
        st.integers(0, 255),
    ),
    min_size=1,
    max_size=4,
)


def _only_typed(fn, *args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return fn(*args, **kwargs)
        except ToolkitError:
            return None


# ------------------------------------------------------------------------------------------------
# meshes and point clouds
# ------------------------------------------------------------------------------------------------
MESH_WRITES = [(".off", False), (".ply", False), (".ply", True), (".obj", False), (".stl", True),
               (".stl", False)]


@pytest.mark.parametrize("ext,binary", MESH_WRITES)
@SETTINGS
@given(shape=meshes())
def test_mesh_round_trip(ext, binary, shape):
    p = _tmp(ext)
    save_shape(shape, p, binary=binary)
    back = load_shape(p)
    assert back.n_faces == shape.n_faces
    if ext == ".stl":  # float32 storage, vertices welded in first-occurrence order
        np.testing.assert_allclose(back.vertices[back.faces], shape.vertices[shape.faces], rtol=1e-6, atol=1e-1)
    else:
        np.testing.assert_array_equal(back.vertices, shape.vertices)
        np.testing.assert_array_equal(back.faces, shape.faces)


@st.composite
def colored_meshes(draw):
    """A mesh with per-vertex colours: 8-bit (uint8) or floats in [0, 1]."""
    shape = draw(meshes())
    n = shape.n_vertices
    if draw(st.booleans()):
        c = np.array(draw(st.lists(st.integers(0, 255), min_size=3 * n, max_size=3 * n)), dtype=np.uint8)
    else:
        unit = st.floats(0.0, 1.0, allow_nan=False, allow_subnormal=False)
        c = np.array(draw(st.lists(unit, min_size=3 * n, max_size=3 * n)), dtype=np.float64)
    return shape.with_colors(c.reshape(n, 3))


COLOR_WRITES = [(".off", False), (".ply", False), (".ply", True), (".obj", False)]


@pytest.mark.parametrize("ext,binary", COLOR_WRITES)
@SETTINGS
@given(shape=colored_meshes())
def test_colored_mesh_round_trip(ext, binary, shape):
    """OFF (as COFF) and OBJ keep colours exactly; PLY stores 8 bits (exact for 8-bit colours)."""
    p = _tmp(ext)
    save_shape(shape, p, binary=binary)
    back = load_shape(p)
    np.testing.assert_array_equal(back.vertices, shape.vertices)
    np.testing.assert_array_equal(back.faces, shape.faces)
    if ext == ".ply":
        np.testing.assert_allclose(back.colors, shape.colors, rtol=0, atol=0.5 / 255 + 1e-12)
        np.testing.assert_array_equal(back.colors, np.round(shape.colors * 255) / 255)
    else:
        np.testing.assert_array_equal(back.colors, shape.colors)


@pytest.mark.parametrize("ext,binary", COLOR_WRITES)
@SETTINGS
@given(shape=colored_meshes(), ops=mutations)
def test_mutated_colored_files_raise_only_typed_errors(ext, binary, shape, ops):
    p = _tmp(ext)
    save_shape(shape, p, binary=binary)
    p.write_bytes(_mutate(p.read_bytes(), ops))
    out = _only_typed(load_shape, p)
    if out is not None and out.colors is not None:
        assert out.colors.shape == (out.n_vertices, 3)
        assert np.isfinite(out.colors).all() and out.colors.min() >= 0 and out.colors.max() <= 1


def _textured_obj(shape: Shape) -> Path:
    """``shape`` as a texture-mapped OBJ (its own UV per vertex) with an MTL file and a 4x4 PNG."""
    from PIL import Image

    p = _tmp(".obj")
    img = (np.arange(48).reshape(4, 4, 3) * 5).astype(np.uint8)
    Image.fromarray(img).save(p.parent / "tex.png")
    (p.parent / "m.mtl").write_text("newmtl skin\nKd 1 1 1\nmap_Kd tex.png\n")
    v = shape.vertices
    uv = (v[:, :2] - v[:, :2].min(axis=0)) / np.maximum(np.ptp(v[:, :2], axis=0), 1e-9)
    lines = ["mtllib m.mtl"] + [f"v {x!r} {y!r} {z!r}" for x, y, z in v.tolist()]
    lines += [f"vt {a!r} {b!r}" for a, b in uv.tolist()] + ["usemtl skin"]
    lines += [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in shape.faces.tolist()]
    p.write_text("\n".join(lines) + "\n")
    return p


@SETTINGS
@given(shape=meshes(), ops=mutations, target=st.sampled_from(["obj", "mtl", "png"]))
def test_mutated_textured_obj_raises_only_typed_errors(shape, ops, target):
    """The OBJ, its material library or its image damaged: a ShapeFileError, never another error."""
    p = _textured_obj(shape)
    clean = load_shape(p)
    assert clean.colors is not None and np.array_equal(clean.vertices, shape.vertices)
    victim = {"obj": p, "mtl": p.parent / "m.mtl", "png": p.parent / "tex.png"}[target]
    victim.write_bytes(_mutate(victim.read_bytes(), ops))
    out = _only_typed(load_shape, p)
    if out is not None and out.colors is not None:
        assert np.isfinite(out.colors).all() and out.colors.min() >= 0 and out.colors.max() <= 1


@pytest.mark.parametrize("ext", [".xyz", ".pcd", ".ply"])
@SETTINGS
@given(shape=meshes())
def test_point_cloud_round_trip(ext, shape):
    p = _tmp(ext)
    pts = Shape(shape.vertices)
    save_shape(pts, p)
    back = load_shape(p, kind="points")
    np.testing.assert_array_equal(back.vertices, pts.vertices)


@pytest.mark.parametrize("ext,binary", MESH_WRITES + [(".xyz", False), (".pcd", False)])
@SETTINGS
@given(shape=meshes(), ops=mutations)
def test_mutated_shape_files_raise_only_typed_errors(ext, binary, shape, ops):
    p = _tmp(ext)
    save_shape(shape if ext not in (".xyz", ".pcd") else Shape(shape.vertices), p, binary=binary)
    p.write_bytes(_mutate(p.read_bytes(), ops))
    out = _only_typed(load_shape, p)
    if out is not None:
        assert np.isfinite(out.vertices).all()
        if out.faces is not None:
            assert out.faces.min() >= 0 and out.faces.max() < out.n_vertices


@SETTINGS
@given(data=st.binary(min_size=0, max_size=400), ext=st.sampled_from([".off", ".ply", ".obj", ".stl", ".xyz", ".pcd"]))
def test_random_bytes_raise_only_typed_errors(data, ext):
    p = _tmp(ext)
    p.write_bytes(data)
    _only_typed(load_shape, p)


@SETTINGS
@given(shape=meshes(), ops=mutations)
def test_mutated_ply_headers_raise_only_typed_errors(shape, ops):
    """Mutations concentrated in the header (counts, types, format line)."""
    p = _tmp(".ply")
    save_shape(shape, p, binary=True)
    data = p.read_bytes()
    end = data.index(b"end_header")
    p.write_bytes(_mutate(data[:end], ops) + data[end:])
    _only_typed(load_shape, p)


# ------------------------------------------------------------------------------------------------
# labels, maps, seeds, .vts, constraints
# ------------------------------------------------------------------------------------------------
ints = st.lists(st.integers(-(2**40), 2**40), min_size=1, max_size=30)


@SETTINGS
@given(values=ints)
def test_int_file_round_trip(values):
    p = _tmp(".labels")
    p.write_text("".join(f"{v}\n" for v in values))
    np.testing.assert_array_equal(read_int_file(p), values)


@SETTINGS
@given(values=ints, ops=mutations)
def test_mutated_int_files_raise_only_typed_errors(values, ops):
    p = _tmp(".seg")
    p.write_bytes(_mutate("".join(f"{v}\n" for v in values).encode(), ops))
    out = _only_typed(read_int_file, p)
    if out is not None:
        assert out.dtype == np.int64


@SETTINGS
@given(values=st.lists(st.integers(-1, 50), min_size=1, max_size=30))
def test_map_round_trip(values):
    p = _tmp(".map")
    save_map(p, np.array(values))
    c = load_map(p, len(values), 51)
    np.testing.assert_array_equal(c.target_of, values)


@SETTINGS
@given(values=st.lists(st.integers(-1, 50), min_size=1, max_size=30), ops=mutations)
def test_mutated_map_files_raise_only_typed_errors(values, ops):
    p = _tmp(".map")
    save_map(p, np.array(values))
    p.write_bytes(_mutate(p.read_bytes(), ops))
    _only_typed(load_map, p, None, 51)
    _only_typed(load_map, p)


@SETTINGS
@given(values=st.lists(st.integers(1, 60), min_size=1, max_size=30), ops=mutations)
def test_vts_files(values, ops):
    from shape_toolkit.results.labels import read_vertex_ids as read_ids_file

    p = _tmp(".vts")
    p.write_text("".join(f"{v}\n" for v in values))
    np.testing.assert_array_equal(read_ids_file(p, one_based=True, n_vertices=60), np.array(values) - 1)
    p.write_bytes(_mutate(p.read_bytes(), ops))
    _only_typed(read_ids_file, p, one_based=True, n_vertices=60)


pairs = st.lists(st.tuples(st.integers(0, 40), st.integers(0, 40)), min_size=1, max_size=15)


@SETTINGS
@given(rows=st.lists(st.tuples(st.integers(0, 40), st.integers(0, 40)), min_size=1, max_size=15,
                     unique_by=lambda t: t[0]))
def test_seed_round_trip(rows):
    """One target per source vertex (a source given two targets is refused: test_bad_cli_options_s39)."""
    p = _tmp(".seeds")
    p.write_text("".join(f"{a} {b}\n" for a, b in rows))
    np.testing.assert_array_equal(read_seeds(p, 41, 41), np.array(rows).reshape(-1, 2))


@SETTINGS
@given(rows=pairs, ops=mutations)
def test_mutated_seed_files_raise_only_typed_errors(rows, ops):
    p = _tmp(".seeds")
    p.write_bytes(_mutate("".join(f"{a} {b}\n" for a, b in rows).encode(), ops))
    _only_typed(read_seeds, p, 41, 41)


@SETTINGS
@given(must=pairs, cannot=pairs)
def test_constraints_round_trip(must, cannot):
    must = [(a, b) for a, b in must if a != b] or [(0, 1)]
    p = _tmp(".json")
    c = Constraints(np.array(must), np.array(cannot))
    save_constraints(p, c)
    back = load_constraints(p)
    np.testing.assert_array_equal(back.must_link, c.must_link)
    np.testing.assert_array_equal(back.cannot_link, c.cannot_link)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.sampled_from(
        ["must_link", "cannot_link", "x"]), children, max_size=3),
    max_leaves=12,
)


@SETTINGS
@given(must=pairs, ops=mutations, value=json_values)
def test_mutated_constraints_raise_only_typed_errors(must, ops, value):
    p = _tmp(".json")
    p.write_bytes(_mutate(json.dumps({"must_link": must}).encode(), ops))
    _only_typed(load_constraints, p, 41)
    p.write_text(json.dumps({"must_link": value, "cannot_link": [[0, 1]]}))
    _only_typed(load_constraints, p, 41)
    p.write_text(json.dumps(value))
    _only_typed(load_constraints, p, 41)
