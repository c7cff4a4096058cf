"""Per-vertex colours (issue 14 item 4, thesis 7.2.2): ``Shape.colors``, the readers and writers that
keep them (PLY, OFF/COFF, OBJ with vertex colours, texture-mapped OBJ sampled with Pillow), and the
``photometric`` seed matcher that uses them, alone and as the seed stage of a pipeline."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from PIL import Image

from shape_toolkit.cli import main
from shape_toolkit.core.shape import Shape, check_colors
from shape_toolkit.core.spectrum import is_cached
from shape_toolkit.data.corruptions import glue
from shape_toolkit.data.generate import icosphere
from shape_toolkit.data.synthetic import synthetic_dataset
from shape_toolkit.errors import InvalidShapeError, ParameterError, ShapeFileError
from shape_toolkit.features.geodesics import geodesic_distances
from shape_toolkit.io.mesh import ColorWarning, load_shape, save_shape
from shape_toolkit.pipeline import PRESETS, load_pipeline
from shape_toolkit.plugins.keypoints.adf_maxima import ADFMaxima
from shape_toolkit.plugins.matching.sparse.photometric import PhotometricMatcher
from shape_toolkit.spectra import build_graph, default_spec


@pytest.fixture(scope="module")
def small():
    return icosphere(1)  # 42 vertices, 80 faces


@pytest.fixture(scope="module")
def rgb8(small):
    return np.random.default_rng(0).integers(0, 256, (small.n_vertices, 3)).astype(np.uint8)


@pytest.fixture(scope="module")
def textured_pair():
    """Two poses of the generated shape (2,562 vertices) carrying their procedural texture."""
    p = synthetic_dataset(3, subdivisions=4, random_state=3)
    return p[1].shape.with_colors(p[1].colors), p[2].shape.with_colors(p[2].colors)


# -- Shape ----------------------------------------------------------------------------------------------
def test_shape_colors_are_validated_and_read_only(small, rgb8):
    s = small.with_colors(rgb8)
    assert s.colors.dtype == np.float64 and s.colors.shape == (small.n_vertices, 3)
    np.testing.assert_array_equal(s.colors * 255, rgb8)  # uint8 is scaled by 255
    with pytest.raises(ValueError):
        s.colors[0, 0] = 0.5
    assert s.has_colors and not small.has_colors and "coloured" in repr(s)
    np.testing.assert_array_equal(check_colors(np.full((2, 3), 65535, np.uint16), 2), 1.0)
    np.testing.assert_array_equal(check_colors(np.array([[1 + 1e-9, -1e-9, 0.5]]), 1), [[1.0, 0.0, 0.5]])
    n = small.n_vertices
    for bad in (np.full((n, 3), 1.5), np.full((n, 3), -0.1), np.full((n, 3), np.nan), np.zeros((n, 4)),
                np.zeros((n - 1, 3)), np.full((n, 3), 256), np.full((n, 3), -1), np.zeros((n, 3), bool),
                np.full((n, 3), "a")):
        with pytest.raises(InvalidShapeError):
            Shape(small.vertices, small.faces, colors=bad)


def test_colors_follow_derived_shapes(small, rgb8):
    s = small.with_colors(rgb8)
    np.testing.assert_array_equal(s.with_vertices(2 * s.vertices).colors, s.colors)
    np.testing.assert_array_equal(s.normalized()[0].colors, s.colors)
    sub, keep = s.submesh(np.arange(0, s.n_vertices, 2))
    np.testing.assert_array_equal(sub.colors, s.colors[keep])
    assert s.with_colors(None).colors is None


def test_recolouring_keeps_the_hash_and_the_cached_spectrum(small, rgb8):
    s = small.with_colors(rgb8)
    assert s.content_hash == small.content_hash  # colours are not geometry
    spec = default_spec(8)
    first = spec.compute(small)
    g = build_graph(s.with_colors(rgb8[::-1].copy()), "cotangent")
    assert is_cached(g, 8, use_mass=True)
    assert spec.compute(s) is first  # served from the cache, not recomputed


# -- readers and writers --------------------------------------------------------------------------------
@pytest.mark.parametrize("name,binary", [("a.ply", False), ("b.ply", True), ("c.off", False), ("d.obj", False),
                                         ("e.xyz", False), ("f.pcd", False)])
def test_8bit_colours_round_trip_exactly(small, rgb8, tmp_path, name, binary):
    s = small.with_colors(rgb8)
    save_shape(s, tmp_path / name, binary=binary)
    back = load_shape(tmp_path / name)
    np.testing.assert_array_equal(back.vertices, s.vertices)
    np.testing.assert_array_equal(back.colors, s.colors)
    assert load_shape(tmp_path / name, colors=False).colors is None
    assert load_shape(tmp_path / name, kind="points").colors is not None


def test_writers_formats(small, tmp_path):
    c = np.random.default_rng(1).random((small.n_vertices, 3))
    s = small.with_colors(c)
    for name in ("a.off", "a.obj"):  # text floats: exact
        save_shape(s, tmp_path / name)
        np.testing.assert_array_equal(load_shape(tmp_path / name).colors, c)
    assert (tmp_path / "a.off").read_text().startswith("COFF\n")
    save_shape(s, tmp_path / "a.ply", binary=True)  # PLY stores uchar: within half a step
    assert b"property uchar red" in (tmp_path / "a.ply").read_bytes()[:300]
    assert np.abs(load_shape(tmp_path / "a.ply").colors - c).max() <= 0.5 / 255 + 1e-12
    save_shape(small, tmp_path / "plain.off")
    assert (tmp_path / "plain.off").read_text().startswith("OFF\n")
    save_shape(s, tmp_path / "a.xyz")  # x y z r g b floats: exact
    np.testing.assert_array_equal(load_shape(tmp_path / "a.xyz").colors, c)
    save_shape(s, tmp_path / "a.pcd")  # packed rgb: 8 bits
    assert np.abs(load_shape(tmp_path / "a.pcd").colors - c).max() <= 0.5 / 255 + 1e-12
    save_shape(s, tmp_path / "a.stl")  # geometry-only formats just drop them
    assert load_shape(tmp_path / "a.stl").colors is None


TRI = "3 0 1 2\n"


@pytest.mark.parametrize("text,expected", [
    ("COFF\n3 1 0\n0 0 0 255 0 0\n1 0 0 0 128 0\n0 1 0 0 0 255\n" + TRI, [[1, 0, 0], [0, 128 / 255, 0], [0, 0, 1]]),
    ("COFF\n3 1 0\n0 0 0 255 0 0 255\n1 0 0 0 128 0 0\n0 1 0 0 0 255 7\n" + TRI,
     [[1, 0, 0], [0, 128 / 255, 0], [0, 0, 1]]),  # RGBA: alpha dropped
    ("COFF\n3 1 0\n0 0 0 1 0 0 1\n1 0 0 0 .5 0 1\n0 1 0 0 0 0.25 1\n" + TRI, [[1, 0, 0], [0, .5, 0], [0, 0, .25]]),
    ("COFF\n3 1 0\n0 0 0 1 0 0\n1 0 0 0 1 0\n0 1 0 0 0 1\n" + TRI, np.eye(3)),  # 0/1 only: floats
    ("CNOFF\n3 1 0\n0 0 0 0 0 1 1 0 0\n1 0 0 0 0 1 0 1 0\n0 1 0 0 0 1 0 0 1\n" + TRI, np.eye(3)),
])
def test_off_colour_variants(tmp_path, text, expected):
    (tmp_path / "a.off").write_text(text)
    np.testing.assert_allclose(load_shape(tmp_path / "a.off").colors, expected, atol=1e-15)


XYZ3 = ["0 0 0", "1 0 0", "0 1 0"]
NORMALS3 = ["0 0 -1", "0 1 0", "0.6 -0.8 0"]  # unit vectors
NINE = [  # colours with NORMALS3; the third are unit vectors too: then the normals come first
    (["255 0 0", "0 128 0", "0 0 51"], [[1, 0, 0], [0, 128 / 255, 0], [0, 0, .2]]),
    (["1 0 0", "0 .5 0", "0 0 0.25"], [[1, 0, 0], [0, .5, 0], [0, 0, .25]]),
    (["1 0 0", "0 1 0", "0 0 1"], np.eye(3)),
]


@pytest.mark.parametrize("rows,expected", [
    (["255 0 0", "0 128 0", "0 0 51"], [[1, 0, 0], [0, 128 / 255, 0], [0, 0, .2]]),  # 8-bit
    (["1 0 0", "0 .5 0", "0 0 0.25"], [[1, 0, 0], [0, .5, 0], [0, 0, .25]]),  # [0, 1] floats
    (["1 0 0", "0 1 0", "0 0 1"], np.eye(3)),  # 0/1 only: floats
    (["255.0 0 0", "0 255 0", "0 0 255"], np.eye(3)),  # integral floats above 1: 8-bit
    (["0 0 -1", "0 1 0", "0.6 -0.8 0"], None),  # x y z nx ny nz: unit normals, not colours
    # nine columns: x y z nx ny nz r g b, or x y z r g b nx ny nz (the unit-normal triple is ignored)
    *[([f"{n} {c}" for n, c in zip(NORMALS3, rows)], expected) for rows, expected in NINE],
    *[([f"{c} {n}" for n, c in zip(NORMALS3, rows)], expected) for rows, expected in NINE[:2]],
])
def test_xyz_colour_columns(tmp_path, rows, expected):
    p = tmp_path / "a.xyz"
    p.write_text("".join(f"{x} {r}\n" for x, r in zip(XYZ3, rows)))
    s = load_shape(p)
    np.testing.assert_array_equal(s.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    if expected is None:
        assert s.colors is None
    else:
        np.testing.assert_allclose(s.colors, expected, atol=1e-15)
    assert load_shape(p, colors=False).colors is None
    p.write_text("".join(f"{x},{r.replace(' ', ',')}\n" for x, r in zip(XYZ3, rows)))  # comma-separated
    assert (load_shape(p).colors is None) == (expected is None)


@pytest.mark.parametrize("rows,problem", [
    (["255 0 0", "0 300 0", "0 0 1"], "outside the 8-bit range"),
    (["1 0 0", "0 1.5 0", "0 0 1"], r"outside \[0, 1\]"),
    (["1 0 0", "0 -0.5 0", "0 0 1"], r"outside \[0, 1\]"),  # negative, but not unit normals
    (["1 0 0", "0 1", "0 0 1"], "needs 6 numbers"),
    # nine columns: x y z nx ny nz r g b
    ([f"{n} {c}" for n, c in zip(NORMALS3, ["255 0 0", "0 300 0", "0 0 1"])], "outside the 8-bit range"),
    ([f"{n} {c}" for n, c in zip(NORMALS3, ["1 0 0", "0 1.5 0", "0 0 1"])], r"outside \[0, 1\]"),
    (["0 0 -1 255 0 0", "0 1 0 0 128", "0.6 -0.8 0 0 0 51"], "line 2: .*needs 9 numbers, found 8"),
    (["0 0 -1 255 0 0", "0 1 0 0 128 0 1", "0.6 -0.8 0 0 0 51"], "line 2: .*needs 9 numbers, found 10"),
    (["0 0 -1", "0 1 0 0 128 0", "0.6 -0.8 0"], "line 2: .*needs 6 numbers, found 9"),  # 6, then 9
    (["0 0 -1 255 0 0", "0 1 0 0 128 x", "0.6 -0.8 0 0 0 51"], "line 2: non-numeric .* 'x'"),
])
def test_xyz_bad_colours_are_file_errors(tmp_path, rows, problem):
    p = tmp_path / "a.xyz"
    p.write_text("".join(f"{x} {r}\n" for x, r in zip(XYZ3, rows)))
    with pytest.raises(ShapeFileError, match=problem) as e:
        load_shape(p)
    assert "a.xyz" in str(e.value)


def test_xyz_nine_columns_without_unit_normals_warn_and_read_the_points(tmp_path):
    p = tmp_path / "a.xyz"
    p.write_text("".join(f"{x} 5 6 7 0.5 0.5 0.5\n" for x in XYZ3))  # x y z + six scalar fields
    with pytest.warns(ColorWarning, match="a.xyz: nine columns.*without colour"):
        s = load_shape(p)
    assert s.colors is None
    np.testing.assert_array_equal(s.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])


def _pcd(fields: str, size: str, typ: str, rows: list[str]) -> str:
    n = len(rows)
    return (f"VERSION 0.7\nFIELDS x y z {fields}\nSIZE 4 4 4 {size}\nTYPE F F F {typ}\n"
            f"COUNT 1 1 1 {' '.join('1' * len(fields.split()))}\nWIDTH {n}\nHEIGHT 1\nPOINTS {n}\nDATA ascii\n"
            + "".join(f"{x} {r}\n" for x, r in zip(XYZ3, rows)))


@pytest.mark.parametrize("text,expected", [
    (_pcd("rgba", "4", "U", [str(0xFF_FF0000), str(0x00_008000), str(0x7F_000033)]),
     [[1, 0, 0], [0, 128 / 255, 0], [0, 0, .2]]),  # packed uint32, alpha ignored
    (_pcd("rgb", "4", "F", [repr(float(np.array(v, np.uint32).view(np.float32))) for v in (0xFF0000, 0x8000, 0x33)]),
     [[1, 0, 0], [0, 128 / 255, 0], [0, 0, .2]]),  # PCL's packed float
    (_pcd("r g b", "1 1 1", "U U U", ["255 0 0", "0 128 0", "0 0 51"]), [[1, 0, 0], [0, 128 / 255, 0], [0, 0, .2]]),
    (_pcd("r g b", "4 4 4", "F F F", ["1 0 0", "0 .5 0", "0 0 .25"]), [[1, 0, 0], [0, .5, 0], [0, 0, .25]]),
])
def test_pcd_colour_fields(tmp_path, text, expected):
    p = tmp_path / "a.pcd"
    p.write_text(text)
    np.testing.assert_allclose(load_shape(p).colors, expected, atol=1e-7)
    assert load_shape(p, colors=False).colors is None


@pytest.mark.parametrize("text,problem", [
    (_pcd("r g b", "1 1 1", "U U U", ["255 0 0", "0 300 0", "0 0 51"]), "not an integer in 0..255"),
    (_pcd("r g b", "4 4 4", "F F F", ["1 0 0", "0 1.5 0", "0 0 1"]), r"outside \[0, 1\]"),
    (_pcd("rgb", "8", "F", ["1", "2", "3"]), "must be one 4-byte value"),
])
def test_pcd_bad_colours_are_file_errors(tmp_path, text, problem):
    p = tmp_path / "a.pcd"
    p.write_text(text)
    with pytest.raises(ShapeFileError, match=problem):
        load_shape(p)


def test_pcd_colours_interoperate_with_open3d(small, rgb8, tmp_path):
    """Open3D's PCD files (ascii, binary, LZF-compressed) read with their colours, and ours read
    in Open3D with the same colours: the packed-rgb convention is PCL's."""
    o3d = pytest.importorskip("open3d")
    c = rgb8 / 255.0
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(small.vertices.copy()))
    pc.colors = o3d.utility.Vector3dVector(c)
    for name, kw in [("a.pcd", {"write_ascii": True}), ("b.pcd", {}), ("c.pcd", {"compressed": True})]:
        o3d.io.write_point_cloud(str(tmp_path / name), pc, **kw)
        back = load_shape(tmp_path / name)
        np.testing.assert_allclose(back.colors, c, atol=1e-12, err_msg=name)
    save_shape(small.with_colors(rgb8), tmp_path / "ours.pcd")
    theirs = o3d.io.read_point_cloud(str(tmp_path / "ours.pcd"))
    np.testing.assert_allclose(np.asarray(theirs.colors), c, atol=1e-12)
    np.testing.assert_allclose(np.asarray(theirs.points), small.vertices)


def _ply(body: str, props: str) -> str:
    head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    return head + props + "element face 1\nproperty list uchar int vertex_indices\nend_header\n" + body + TRI


@pytest.mark.parametrize("props,rows,expected", [
    ("property uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar alpha\n",
     ["255 0 0 9", "0 255 0 9", "0 0 51 9"], [[1, 0, 0], [0, 1, 0], [0, 0, .2]]),
    ("property float r\nproperty float g\nproperty float b\n", ["1 0 0", "0 .5 0", "0 0 1"],
     [[1, 0, 0], [0, .5, 0], [0, 0, 1]]),
    ("property ushort red\nproperty ushort green\nproperty ushort blue\n", ["65535 0 0", "0 0 0", "0 0 65535"],
     [[1, 0, 0], [0, 0, 0], [0, 0, 1]]),
])
def test_ply_colour_variants(tmp_path, props, rows, expected):
    body = "".join(f"{x} {r}\n" for x, r in zip(["0 0 0", "1 0 0", "0 1 0"], rows))
    (tmp_path / "a.ply").write_text(_ply(body, props))
    np.testing.assert_allclose(load_shape(tmp_path / "a.ply").colors, expected)


def test_obj_vertex_colours_8bit_integers(tmp_path):
    (tmp_path / "a.obj").write_text("v 0 0 0 255 0 0\nv 1 0 0 0 255 0\nv 0 1 0 0 0 255\nf 1 2 3\n")
    np.testing.assert_array_equal(load_shape(tmp_path / "a.obj").colors, np.eye(3))


@pytest.mark.parametrize("name,text,match", [
    ("a.off", "COFF\n3 1 0\n0 0 0 300 0 0\n1 0 0 0 0 0\n0 1 0 0 0 0\n" + TRI, "0..255"),
    ("a.off", "COFF\n3 1 0\n0 0 0 1.5 0 0\n1 0 0 0 0 0\n0 1 0 0 0 0\n" + TRI, r"outside \[0, 1\]"),
    ("a.off", "COFF\n3 1 0\n0 0 0 1 0 0\n1 0 0\n0 1 0 0 0 0\n" + TRI, "line 4"),
    ("a.off", "COFF\n3 1 0\n0 0 0 nan 0 0\n1 0 0 0 0 0\n0 1 0 0 0 0\n" + TRI, "finite"),
    ("a.obj", "v 0 0 0 1 0 0\nv 1 0 0\nv 0 1 0 0 0 1\nf 1 2 3\n", "line 2"),
    ("a.obj", "v 0 0 0 0.5 0 0\nv 1 0 0 2 0 0\nv 0 1 0 0 0 1\nf 1 2 3\n", r"outside \[0, 1\]"),
    ("a.ply", _ply("0 0 0 2 0 0\n1 0 0 0 0 0\n0 1 0 0 0 0\n",
                   "property float red\nproperty float green\nproperty float blue\n"), r"outside \[0, 1\]"),
    ("a.ply", _ply("0 0 0 2.5 0 0\n1 0 0 0 0 0\n0 1 0 0 0 0\n",
                   "property uchar red\nproperty uchar green\nproperty uchar blue\n"), "not an integer"),
])
def test_malformed_colours_are_typed_errors(tmp_path, name, text, match):
    (tmp_path / name).write_text(text)
    with pytest.raises(ShapeFileError, match=match):
        load_shape(tmp_path / name)
    assert load_shape(tmp_path / name, colors=False).n_vertices == 3  # the geometry alone still loads


# -- texture-mapped OBJ ---------------------------------------------------------------------------------
IMG = np.array([[[255, 0, 0], [0, 255, 0]],
                [[0, 0, 255], [255, 255, 255]]], dtype=np.uint8)  # row 0 is the top of the image


def _textured(d, *, image=True, extra_faces=""):
    if image:
        Image.fromarray(IMG).save(d / "tex.png")
    mtl = "newmtl skin\nKd 0.2 0.4 0.6\nmap_Kd -s 1 1 1 tex.png\nnewmtl plain\nKd 0 1 0\nnewmtl bare\n"
    (d / "m.mtl").write_text(mtl)
    uv = [(0.25, 0.75), (0.75, 0.75), (0.25, 0.25), (0.75, 0.25), (0.5, 0.75)]  # pixel centres, then a midpoint
    lines = ["mtllib m.mtl", "v 0 0 0", "v 1 0 0", "v 0 1 0", "v 1 1 0", "v 2 2 0"]
    lines += [f"vt {u} {v}" for u, v in uv]
    lines += ["usemtl skin", "f 1/1 2/2 3/3", "f 2/5 4/4 3/3", extra_faces]
    (d / "t.obj").write_text("\n".join(lines) + "\n")
    return d / "t.obj"


def test_textured_obj_is_sampled_bilinearly(tmp_path):
    s = load_shape(_textured(tmp_path, extra_faces="usemtl plain\nf 5 4 2"))
    c = s.colors
    np.testing.assert_allclose(c[0], [1, 0, 0])  # top-left pixel (v = 0.75 is the upper row)
    np.testing.assert_allclose(c[2], [0, 0, 1])  # bottom-left
    np.testing.assert_allclose(c[3], ([1, 1, 1] + np.array([0, 1, 0])) / 2)  # its texture sample + plain Kd
    # vertex 2 has two UVs: the green pixel centre and the red-green midpoint -> their mean
    green, mid = np.array([0, 1, 0]), np.array([0.5, 0.5, 0])
    np.testing.assert_allclose(c[1], (green + mid + [0, 1, 0]) / 3)  # ... and the plain face's Kd
    np.testing.assert_allclose(c[4], [0, 1, 0])  # only in the untextured material: its Kd


def test_textured_obj_without_samples_warns(tmp_path):
    p = _textured(tmp_path, extra_faces="usemtl bare\nf 5 4 2")  # neither an image nor a Kd: v5 gets nothing
    with pytest.warns(ColorWarning, match="1 of 5 vertices"):
        s = load_shape(p)
    np.testing.assert_allclose(s.colors[4], 0.5)


def test_broken_texture_references_are_typed_errors(tmp_path):
    p = _textured(tmp_path, image=False)
    with pytest.raises(ShapeFileError, match="tex.png.*not found"):
        load_shape(p)
    assert load_shape(p, colors=False).colors is None  # the geometry alone, on request
    (tmp_path / "tex.png").write_bytes(b"\x89PNG\r\n\x1a\n not an image")
    with pytest.raises(ShapeFileError, match="tex.png.*not a readable image"):
        load_shape(p)
    (tmp_path / "m.mtl").unlink()
    with pytest.raises(ShapeFileError, match="m.mtl.*not found"):
        load_shape(p)
    (tmp_path / "m.mtl").write_text("newmtl other\nmap_Kd tex.png\n")
    with pytest.raises(ShapeFileError, match="'skin'.*not defined"):
        load_shape(p)


def test_cli_broken_texture_is_one_line_exit_2(tmp_path, capsys):
    p = _textured(tmp_path, image=False)
    code = main(["info", str(p)])
    err = capsys.readouterr().err
    assert code == 2 and "tex.png" in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_obj_with_uvs_but_no_textures_has_no_colours(tmp_path):
    (tmp_path / "m.mtl").write_text("newmtl grey\nKd 0.5 0.5 0.5\n")
    (tmp_path / "a.obj").write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nusemtl grey\nf 1/1 2/1 3/1\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load_shape(tmp_path / "a.obj").colors is None


# -- photometric seeds ------------------------------------------------------------------------------------
def _precision(shape: Shape, pairs: np.ndarray, truth_of_target: np.ndarray, radius: float = 0.05) -> float:
    """Fraction of matches [a, b] whose b lies within ``radius * sqrt(area)`` (geodesic, on ``shape``)
    of a's true image (identity between the poses; ``truth_of_target`` maps glued vertices back)."""
    D = geodesic_distances(shape, pairs[:, 0])
    d = D[np.arange(len(pairs)), truth_of_target[pairs[:, 1]]]
    return float(np.mean(d <= radius * np.sqrt(shape.area)))


def test_photometric_uses_the_shapes_colours(textured_pair):
    A, B = textured_pair
    kp = np.arange(0, A.n_vertices, 97)
    m = PhotometricMatcher()
    np.testing.assert_array_equal(m.match(A, B, kp, kp), m.match(A, B, kp, kp, source_colors=A.colors,
                                                                 target_colors=B.colors))
    assert len(PhotometricMatcher(require_colors=True).match(A, B, kp, kp)) > 0
    with pytest.raises(ParameterError, match="has none"):
        m.match(A, B.with_colors(None), kp, kp)
    plain = PhotometricMatcher().match(A.with_colors(None), B.with_colors(None), kp, kp)  # geometric texture
    assert plain.shape[1] == 2


def test_photometric_seed_precision_on_a_textured_pair(textured_pair):
    """ADF keypoints matched by colour: far above what random matching reaches (a geodesic disc of
    radius 0.05 sqrt(area) covers under 1% of the surface)."""
    A, B = textured_pair
    det = ADFMaxima(t=50.0, K=50, time_scale="absolute")  # the thesis's dense setting (Table 6.1)
    kpa, kpb = det.detect(A), det.detect(B)
    P = PhotometricMatcher().match(A, B, kpa, kpb)
    assert len(P) >= 5 and len(np.unique(P[:, 1])) == len(P)  # one-to-one
    assert _precision(B, P, np.arange(B.n_vertices)) >= 0.8
    # glued contacts move the heat-diffusion keypoints; refining the target by colour keeps the seeds
    G, vm = glue(B, strength=3, random_state=0)
    G = G.with_colors(B.colors[vm])
    kpg = det.detect(G)
    R = PhotometricMatcher().match(A, G, kpa, kpg)
    assert len(R) >= 3 and _precision(B, R, vm) >= 0.6
    K = PhotometricMatcher(refine_rings=0).match(A, G, kpa, kpg)
    assert set(K[:, 1]) <= set(kpg.tolist())
    with pytest.raises(ParameterError):
        PhotometricMatcher(refine_rings=-1).match(A, G, kpa, kpg)


@pytest.mark.slow  # the whole topo-robust-photometric chain; the photometric matcher has fast tests above
def test_pipeline_with_photometric_seeds(textured_pair):
    """The preset runs with colour seeds taken from the shapes. One contact: with three, the dense
    chain after the seeds (seed growing, EM) fails on this planar toy even from exact seeds."""
    assert PRESETS["topo-robust-photometric"]["sparse"]["plugin"] == "photometric"
    # colour seeds decide left and right; EM's intrinsic side check (which can mirror a map the seeds got
    # right) is off here and on in the geometry-only preset
    assert PRESETS["topo-robust-photometric"]["refine"]["params"]["orientation"] == "none"
    assert "orientation" not in PRESETS["topo-robust"]["refine"].get("params", {})
    A, B = textured_pair
    G, vm = glue(B, strength=1, random_state=0)
    G = G.with_colors(B.colors[vm])
    c = load_pipeline("topo-robust-photometric").run(A, G)
    assert c.info["seed_source"] == "photometric" and c.info["n_seeds"] >= 3
    pos = np.asarray(B.vertices)
    err = np.linalg.norm(pos[vm[c.target_of]] - pos, axis=1) / np.sqrt(B.area)
    assert np.mean(err) < 0.05


# -- generated data, corruptions and the benchmark store keep the texture -----------------------------------
def test_generated_items_corruptions_and_prepared_items_keep_colours(tmp_path):
    from shape_toolkit.bench.store import load_prepared, save_prepared
    from shape_toolkit.bench.tasks import prepare
    from shape_toolkit.data.corruptions import apply_corruption
    from shape_toolkit.data.datasets import load_item, synthetic_refs

    item = load_item(synthetic_refs(2, subdivisions=2)[0])
    assert item.shape.colors is not None
    np.testing.assert_array_equal(item.shape.colors, item.target.colors)  # the texture moves with the surface
    G, vm = apply_corruption(item.target, "glue", strength=1, random_state=0)
    assert G.n_vertices < item.target.n_vertices
    np.testing.assert_array_equal(G.colors, item.target.colors[vm])
    prep = prepare(item, "glue", {"strength": 1}, pairwise=True, random_state=0)
    save_prepared(tmp_path / "p.npz", prep)
    back = load_prepared(tmp_path / "p.npz")
    np.testing.assert_array_equal(back.source.colors, prep.source.colors)
    np.testing.assert_array_equal(back.target.colors, item.target.colors[back.vertex_map])
