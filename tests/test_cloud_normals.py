"""A point cloud's own outward normals (a scanner's, a mesh export's): carried by ``Shape.normals``, read from and
written to PLY, XYZ and PCD, and used instead of estimated normals by the cloud's Laplacian, its local surface, its
proxies and the orientation test of maps (issue 29, item 4: real scans come with normals)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from shape_toolkit.api.registry import create_plugin
from shape_toolkit.core.geometry import outward_vertex_normals
from shape_toolkit.core.graph import build_graph
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.surface import cloud_normals, cloud_surface
from shape_toolkit.data.corruptions import point_cloud
from shape_toolkit.data.generate import icosphere
from shape_toolkit.data.synthetic import articulated_shape
from shape_toolkit.errors import InvalidShapeError, ParameterError, ShapeFileError
from shape_toolkit.io.mesh import NormalsWarning, load_shape, save_shape


def _cloud(n: int = 40, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, 3)), rng.normal(size=(n, 3))


def test_normals_are_unit_vectors_read_only_and_part_of_the_geometry():
    P, N = _cloud()
    s = Shape(P, None, "c", normals=N * 1e-250)  # scaled far down: still a direction each
    np.testing.assert_allclose(np.linalg.norm(s.normals, axis=1), 1.0)
    np.testing.assert_allclose(s.normals, N / np.linalg.norm(N, axis=1, keepdims=True))
    assert not s.normals.flags.writeable and "with normals" in repr(s)
    bare = s.with_normals(None)
    assert bare.normals is None and bare.content_hash != s.content_hash  # cached spectra are not shared
    recoloured = s.with_colors(np.zeros((len(P), 3)))
    np.testing.assert_array_equal(recoloured.normals, s.normals)  # bit for bit: caches stay shared
    assert recoloured.content_hash == s.content_hash
    assert s.with_vertices(P + 1.0).normals is None  # moved points: the former normals no longer hold
    sub, kept = s.submesh(np.array([3, 1, 7]))
    np.testing.assert_array_equal(sub.normals, s.normals[kept])
    np.testing.assert_array_equal(s.normalized()[0].normals, s.normals)  # a uniform scale keeps directions


@pytest.mark.parametrize("bad, words", [
    (np.zeros((40, 3)), "zero vectors"),
    (np.full((40, 3), np.nan), "finite"),
    (np.ones((39, 3)), "(40, 3)"),
    (np.ones((40, 3), dtype=bool), "real numbers"),
])
def test_bad_normals_are_refused(bad, words):
    P, _ = _cloud()
    with pytest.raises(InvalidShapeError, match=words.replace("(", r"\(").replace(")", r"\)")):
        Shape(P, None, "c", normals=bad)


def test_a_mesh_refuses_given_normals():
    mesh = icosphere(1)
    with pytest.raises(InvalidShapeError, match="point clouds only"):
        Shape(mesh.vertices, mesh.faces, "m", normals=np.ones_like(mesh.vertices))


@pytest.mark.parametrize("ext, binary", [("ply", False), ("ply", True), ("xyz", False), ("pcd", False),
                                         ("off", False), ("obj", False)])
@pytest.mark.parametrize("coloured", [False, True])
def test_normals_survive_a_file_round_trip(tmp_path, ext, binary, coloured):
    P, N = _cloud()
    colors = np.random.default_rng(1).integers(0, 256, size=(len(P), 3)).astype(np.uint8) if coloured else None
    s = Shape(P, None, "c", colors=colors, normals=N)
    path = tmp_path / f"c.{ext}"
    save_shape(s, path, binary=binary)
    back = load_shape(path)
    np.testing.assert_allclose(back.normals, s.normals, atol=1e-15)
    np.testing.assert_array_equal(back.vertices, s.vertices)
    if coloured:
        np.testing.assert_allclose(back.colors, s.colors, atol=1e-12)
    assert load_shape(path, normals=False).normals is None
    assert back.content_hash == s.content_hash


def test_obj_vn_lines_are_a_clouds_normals_only_one_per_point(tmp_path):
    """MeshLab and CloudCompare write a cloud's normals as one ``vn`` per ``v``; a mesh's ``vn`` belong to face
    corners (``f 1//1``) and are not read, nor are ``vn`` lines that do not pair one to one with the points."""
    P, N = _cloud()
    rows = "".join(f"v {float(x)!r} {float(y)!r} {float(z)!r}\n" for x, y, z in P)
    normals = "".join(f"vn {float(x)!r} {float(y)!r} {float(z)!r}\n" for x, y, z in N)
    (tmp_path / "c.obj").write_text(rows + normals)
    np.testing.assert_allclose(load_shape(tmp_path / "c.obj").normals, N / np.linalg.norm(N, axis=1, keepdims=True),
                               atol=1e-15)
    (tmp_path / "short.obj").write_text(rows + normals.split("\n", 1)[1])  # one vn missing: no pairing
    assert load_shape(tmp_path / "short.obj").normals is None
    mesh = icosphere(1)
    obj = "".join(f"v {x} {y} {z}\nvn {x} {y} {z}\n" for x, y, z in mesh.vertices)
    obj += "".join(f"f {a + 1}//{a + 1} {b + 1}//{b + 1} {c + 1}//{c + 1}\n" for a, b, c in mesh.faces)
    (tmp_path / "m.obj").write_text(obj)
    m = load_shape(tmp_path / "m.obj")
    assert m.is_mesh and m.normals is None
    assert load_shape(tmp_path / "m.obj", kind="points").normals is None  # corner normals, not per point


def test_a_mesh_files_normals_are_ignored_and_a_zero_normal_drops_them_with_a_warning(tmp_path):
    mesh = icosphere(1)
    n = mesh.n_vertices
    head = ("ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
            "property float nx\nproperty float ny\nproperty float nz\n")
    rows = "".join(f"{x} {y} {z} {x} {y} {z}\n" for x, y, z in mesh.vertices)
    faced = tmp_path / "mesh.ply"
    faced.write_text(head.format(n=n) + f"element face {mesh.n_faces}\nproperty list uchar int vertex_indices\n"
                     "end_header\n" + rows + "".join(f"3 {a} {b} {c}\n" for a, b, c in mesh.faces))
    m = load_shape(faced)
    assert m.is_mesh and m.normals is None
    cloud = tmp_path / "cloud.ply"
    zero = rows.splitlines()
    zero[5] = " ".join(zero[5].split()[:3] + ["0", "0", "0"])
    cloud.write_text(head.format(n=n) + "end_header\n" + "\n".join(zero) + "\n")
    with pytest.warns(NormalsWarning, match="1 points have a zero or non-finite normal"):
        c = load_shape(cloud)
    assert not c.is_mesh and c.normals is None and c.n_vertices == n
    pcd = tmp_path / "nan.pcd"  # PCL writes NaN for a normal it did not compute
    pcd.write_text("VERSION 0.7\nFIELDS x y z normal_x normal_y normal_z\nSIZE 4 4 4 4 4 4\nTYPE F F F F F F\n"
                   "COUNT 1 1 1 1 1 1\nWIDTH 3\nHEIGHT 1\nPOINTS 3\nDATA ascii\n"
                   "0 0 0 0 0 1\n1 0 0 nan nan nan\n0 1 0 0 0 1\n")
    with pytest.warns(NormalsWarning):
        assert load_shape(pcd).normals is None


def test_given_normals_are_used_without_estimating_any(monkeypatch):
    from shape_toolkit.core import surface

    def refuse(*_a):
        raise AssertionError("normals were estimated although the cloud has its own")

    monkeypatch.setattr(surface, "_outward_normals", refuse)
    mesh = articulated_shape(subdivisions=3, random_state=0).shape
    cloud, _ = point_cloud(mesh, normals=True)
    np.testing.assert_array_equal(cloud_normals(cloud), cloud.normals)
    build_graph(cloud, create_plugin("weightings", "intrinsic-delaunay"))
    cloud_surface(cloud)
    from shape_toolkit.plugins.matching.orientation import orientation_verdict

    assert orientation_verdict(cloud, cloud, np.arange(cloud.n_vertices))["verdict"] == "preserving"


def test_normals_without_consistent_signs_are_estimated_and_inward_ones_turned():
    """Normals with random signs (PCA lines, not oriented) are replaced by the estimated outward normals, normals
    that all point inwards are turned; each with a warning. Oriented outward normals pass as they are, silently."""
    from shape_toolkit.core.shape import NormalsWarning
    from shape_toolkit.core.surface import outward_normals

    mesh = articulated_shape(subdivisions=3, random_state=4).shape
    cloud, _ = point_cloud(mesh, normals=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(cloud_normals(cloud), cloud.normals)
    with pytest.warns(NormalsWarning, match="point inwards"):
        np.testing.assert_array_equal(cloud_normals(cloud.with_normals(-cloud.normals)), cloud.normals)
    signs = np.random.default_rng(0).choice([-1.0, 1.0], size=(cloud.n_vertices, 1))
    with pytest.warns(NormalsWarning, match="not oriented"):
        np.testing.assert_array_equal(cloud_normals(cloud.with_normals(cloud.normals * signs)),
                                      outward_normals(cloud.vertices))


def test_an_open_scans_consistent_normals_are_kept_though_its_outside_is_unknown():
    """An open, wavy sheet, as one scan of a surface sees it, with the normals of one of its sides: viewpoints all
    around see it from both sides (about half its points face them), so they cannot tell its outside; its normals
    agree between neighbours, so they are kept as they are, without a warning, either way up. With random signs the
    same points have theirs estimated."""
    from shape_toolkit.core.shape import NormalsWarning
    from shape_toolkit.core.surface import CHECK_VIEWS, _visibility_vote

    x, y = (a.ravel() for a in np.meshgrid(np.linspace(-1, 1, 40), np.linspace(-1, 1, 40)))
    V = np.column_stack([x, y, 0.15 * np.sin(3 * x) * np.cos(2 * y)])
    N = np.column_stack([-0.45 * np.cos(3 * x) * np.cos(2 * y), 0.3 * np.sin(3 * x) * np.sin(2 * y), np.ones_like(x)])
    for side in (N, -N):
        scan = Shape(V, None, "sheet", normals=side)
        vote = _visibility_vote(V, scan.normals, CHECK_VIEWS)
        assert 0.3 < (vote > 0).mean() < 0.7  # the views cannot tell
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            np.testing.assert_array_equal(cloud_normals(scan), scan.normals)
    signs = np.random.default_rng(1).choice([-1.0, 1.0], size=(len(V), 1))
    with pytest.warns(NormalsWarning, match="not oriented"):
        cloud_normals(Shape(V, None, "sheet", normals=N * signs))


def test_a_rigid_motion_turns_a_clouds_normals_with_it():
    from shape_toolkit.data.corruptions import rigid_motion

    mesh = articulated_shape(subdivisions=2, random_state=5).shape
    cloud, _ = point_cloud(mesh, normals=True)
    moved, _ = rigid_motion(cloud, strength=0.5, random_state=3)
    assert not np.allclose(moved.normals, cloud.normals)
    np.testing.assert_allclose(moved.normals, outward_vertex_normals(rigid_motion(mesh, strength=0.5,
                                                                                  random_state=3)[0]), atol=1e-9)


def test_a_clouds_proxy_keeps_its_points_normals():
    from shape_toolkit.plugins.matching.multires import make_proxy

    P, N = _cloud(400)
    cloud = Shape(P, None, "c", normals=N)
    proxy, ids = make_proxy(cloud, 150)
    np.testing.assert_array_equal(proxy.normals, cloud.normals[ids])
    assert make_proxy(cloud.with_normals(None), 150)[0].normals is None


def test_the_point_cloud_corruption_carries_the_meshs_normals():
    mesh = articulated_shape(subdivisions=3, random_state=2).shape
    truth = outward_vertex_normals(mesh)
    vertices, vmap = point_cloud(mesh, normals=True)
    np.testing.assert_allclose(vertices.normals, truth[vmap], atol=1e-12)
    samples, smap = point_cloud(mesh, points=2000, strength=0.005, normals=True, random_state=3)
    # interpolated within each triangle: close to the normal of the vertex nearest the sample
    assert np.median(np.einsum("ij,ij->i", samples.normals, truth[smap])) > 0.98
    assert point_cloud(mesh, points=2000)[0].normals is None
    with pytest.raises(ParameterError, match="normals must be a bool"):
        point_cloud(mesh, normals=1)
    lone = Shape(np.vstack([mesh.vertices, [[9.0, 9.0, 9.0]]]), mesh.faces, "lone")  # a vertex on no face
    with pytest.raises(InvalidShapeError, match=rf"1 vertices are on no face \(first: vertex {mesh.n_vertices}\)"):
        point_cloud(lone, normals=True)
    assert point_cloud(lone)[0].n_vertices == mesh.n_vertices + 1  # without normals it is a point like the others


def test_a_scan_with_its_normals_links_fewer_touching_parts(shared_data):
    """A FAUST body as its vertex cloud: Laplacian edges between points more than 6 mesh rings apart (parts that
    touch in space, joined where the estimated signs go wrong in the unseen contact zones). With the mesh's normals,
    as a scanner's merged scan would carry them, there are about a quarter as many (232 against 998 measured)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import shortest_path

    mesh = load_shape(shared_data / "faust5k" / "tr_reg_007.off")
    E, n = mesh.edges, mesh.n_vertices
    rings = sp.coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n))
    weighting = create_plugin("weightings", "intrinsic-delaunay")

    def far_edges(normals: bool) -> int:
        cloud, vmap = point_cloud(mesh, normals=normals)
        W = sp.triu(build_graph(cloud, weighting).W, 1).tocoo()
        a, b = vmap[W.row], vmap[W.col]
        starts, row = np.unique(a, return_inverse=True)
        D = shortest_path(rings + rings.T, unweighted=True, indices=starts)
        return int((D[row, b] > 6).sum())

    estimated, given = far_edges(False), far_edges(True)
    assert given < 0.4 * estimated


def test_cleaning_a_cloud_keeps_its_normals_and_info_reports_them():
    from shape_toolkit.core.cleanup import clean_shape
    from shape_toolkit.core.inspect import mesh_info

    P, N = _cloud()
    doubled = Shape(np.vstack([P, P[:5]]), None, "c", normals=np.vstack([N, -N[:5]]))
    clean, report = clean_shape(doubled)
    assert clean.n_vertices == len(P) and report.duplicate_vertices_merged == 5
    np.testing.assert_array_equal(clean.normals, doubled.normals[report.vertex_map])
    assert mesh_info(clean)["has_normals"] and not mesh_info(clean.with_normals(None))["has_normals"]


@pytest.mark.parametrize("scale", [1e308, 1e-320])
def test_a_files_huge_or_subnormal_normals_are_directions_read_without_a_warning(tmp_path, scale):
    """1e308 overflowed a length (a RuntimeWarning printed by every command) and 1e-320 underflowed to a zero length,
    which dropped the file's normals as if they were missing; each is a direction."""
    P, N = _cloud()
    N = N / np.linalg.norm(N, axis=1, keepdims=True)
    path = tmp_path / "c.ply"
    path.write_text(f"ply\nformat ascii 1.0\nelement vertex {len(P)}\n" + "".join(
        f"property double {c}\n" for c in ("x", "y", "z", "nx", "ny", "nz")) + "end_header\n" + "".join(
        " ".join(repr(float(x)) for x in (*p, *(n * scale))) + "\n" for p, n in zip(P, N)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        back = load_shape(path)
    np.testing.assert_allclose(back.normals, N, atol=1e-12 if scale > 1 else 1e-2)  # subnormals hold ~11 bits


def test_a_noff_clouds_normals_are_read_and_a_meshs_are_not(tmp_path):
    cloud = tmp_path / "cloud.off"
    cloud.write_text("NOFF\n3 0 0\n0 0 0 0 0 2\n1 0 0 0 0 1\n0 1 0 0 0 1\n")
    np.testing.assert_array_equal(load_shape(cloud).normals, np.tile([0.0, 0.0, 1.0], (3, 1)))
    mesh = tmp_path / "mesh.off"  # a mesh's rows were read as coordinates only, and still are
    mesh.write_text("NOFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    assert load_shape(mesh).is_mesh
    short = tmp_path / "short.off"  # a cloud that declares normals must give them
    short.write_text("NOFF\n3 0 0\n0 0 0\n1 0 0\n0 1 0\n")
    with pytest.raises(ShapeFileError, match="NOFF vertex normal needs 6 numbers"):
        load_shape(short)


def test_a_commands_warning_is_printed_when_it_succeeds_and_not_before_its_refusal(tmp_path, capsys):
    """A cloud file with a NaN normal: `info` succeeds and prints the warning on one line; `evaluate-segmentation`
    refuses a cloud, and its one error line stands alone (the warning before it made two lines)."""
    from shape_toolkit.cli import main

    P, N = _cloud()
    N[3] = np.nan
    path = tmp_path / "nan.ply"
    path.write_text(f"ply\nformat ascii 1.0\nelement vertex {len(P)}\n" + "".join(
        f"property double {c}\n" for c in ("x", "y", "z", "nx", "ny", "nz")) + "end_header\n" + "".join(
        " ".join(repr(float(x)) for x in (*p, *n)) + "\n" for p, n in zip(P, N)))
    labels = tmp_path / "labels.txt"
    labels.write_text("0\n" * len(P))
    assert main(["info", str(path)]) == 0
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "warning" in err[0] and "non-finite normal" in err[0]
    assert main(["evaluate-segmentation", str(path), str(labels), "--truth", str(labels)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "error" in err[0] and "triangle mesh" in err[0]
    # the same file as source and target is read twice and warns twice: printed once (the adversarial corpus)
    ident, vts = tmp_path / "ident.txt", tmp_path / "a.vts"
    ident.write_text("".join(f"{i}\n" for i in range(len(P))))
    vts.write_text("".join(f"{i + 1}\n" for i in range(0, len(P), 3)))
    assert main(["evaluate-map", str(path), str(path), str(ident), "--truth-src", str(vts), "--truth-dst", str(vts),
                 "--json"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "non-finite normal" in err[0], err


def test_files_with_normals_refuse_what_they_refused_before(tmp_path):
    bad = tmp_path / "bad.ply"
    bad.write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
                   "property float nx\nproperty float ny\nproperty float nz\nend_header\n0 0 0 0 0 1\n")
    with pytest.raises(ShapeFileError):
        load_shape(bad)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a clean file warns of nothing
        P, N = _cloud()
        save_shape(Shape(P, None, "c", normals=N), tmp_path / "ok.ply")
        load_shape(tmp_path / "ok.ply")
