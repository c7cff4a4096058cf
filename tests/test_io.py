"""Shape file I/O: round trips, triangulation, STL welding, and one test per error case."""

from __future__ import annotations

import json

import numpy as np
import pytest

import shape_toolkit.io.mesh as tio
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError, ShapeFileError
from shape_toolkit.io.mesh import load_shape, save_shape


def _write(path, text: str):
    path.write_text(text)
    return path


# -- round trips ------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "name,binary", [("a.off", False), ("a.ply", False), ("b.ply", True), ("a.obj", False)]
)
def test_mesh_round_trip_is_exact(sphere, tmp_mesh_dir, name, binary):
    p = tmp_mesh_dir / name
    save_shape(sphere, p, binary=binary)
    back = load_shape(p)
    assert np.array_equal(back.vertices, sphere.vertices)
    assert np.array_equal(back.faces, sphere.faces)
    assert back.name == "a" or back.name == "b"


def test_binary_and_ascii_ply_agree(sphere, tmp_mesh_dir):
    save_shape(sphere, tmp_mesh_dir / "a.ply")
    save_shape(sphere, tmp_mesh_dir / "b.ply", binary=True)
    assert (tmp_mesh_dir / "b.ply").read_bytes()[:40].startswith(b"ply\nformat binary_")
    a, b = load_shape(tmp_mesh_dir / "a.ply"), load_shape(tmp_mesh_dir / "b.ply")
    assert a.content_hash == b.content_hash


@pytest.mark.parametrize("name", ["p.xyz", "p.pcd", "p.ply", "p.off"])
def test_point_cloud_round_trip(sphere, tmp_mesh_dir, name):
    cloud = Shape(sphere.vertices)
    save_shape(cloud, tmp_mesh_dir / name)
    back = load_shape(tmp_mesh_dir / name)
    assert not back.is_mesh
    assert np.array_equal(back.vertices, cloud.vertices)


@pytest.mark.parametrize("binary", [False, True])
def test_stl_welding_recovers_the_closed_mesh(sphere, tmp_mesh_dir, binary):
    p = tmp_mesh_dir / "s.stl"
    save_shape(sphere, p, binary=binary)
    back = load_shape(p)
    assert back.n_vertices == sphere.n_vertices and back.n_faces == sphere.n_faces
    # STL stores float32: match welded vertices to the originals, then compare connectivity
    v32 = sphere.vertices.astype(np.float32).astype(np.float64)
    lookup = {tuple(x): i for i, x in enumerate(v32)}
    to_orig = np.array([lookup[tuple(x)] for x in back.vertices])
    assert np.array_equal(to_orig[back.faces], sphere.faces)
    # deterministic: vertex order is first occurrence in the soup
    assert np.array_equal(load_shape(p).vertices, back.vertices)


def test_binary_files_written_by_open3d_are_read(sphere, tmp_mesh_dir):
    o3d = pytest.importorskip("open3d")
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(sphere.vertices.copy()),
        o3d.utility.Vector3iVector(sphere.faces.copy()),
    )
    o3d.io.write_triangle_mesh(str(tmp_mesh_dir / "o.ply"), mesh, write_ascii=False)
    back = load_shape(tmp_mesh_dir / "o.ply")
    assert np.array_equal(back.vertices, sphere.vertices)
    assert np.array_equal(back.faces, sphere.faces)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(sphere.vertices.copy()))
    for name, kw in [("b.pcd", {}), ("c.pcd", {"compressed": True})]:
        o3d.io.write_point_cloud(str(tmp_mesh_dir / name), pc, write_ascii=False, **kw)
        back = load_shape(tmp_mesh_dir / name)
        assert np.allclose(back.vertices, sphere.vertices, atol=1e-6)  # float32 storage


def test_polygon_faces_are_fan_triangulated(tmp_mesh_dir):
    p = _write(tmp_mesh_dir / "q.off", "OFF\n5 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n0 2 0\n"
               "4 0 1 2 3\n3 3 2 4\n")  # fmt: skip
    s = load_shape(p)
    assert s.faces.tolist() == [[0, 1, 2], [0, 2, 3], [3, 2, 4]]
    assert s.area == pytest.approx(1.5)


def test_obj_quads_relative_indices_and_slashes(tmp_mesh_dir):
    p = _write(tmp_mesh_dir / "q.obj", "# quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
               "vt 0 0\nf 1/1 2/1 3/1 -1/1\n")  # fmt: skip
    assert load_shape(p).faces.tolist() == [[0, 1, 2], [0, 2, 3]]


def test_kind_points_and_mesh(sphere, tmp_mesh_dir):
    save_shape(sphere, tmp_mesh_dir / "m.off")
    assert not load_shape(tmp_mesh_dir / "m.off", kind="points").is_mesh
    save_shape(Shape(sphere.vertices), tmp_mesh_dir / "p.xyz")
    with pytest.raises(ShapeFileError, match="no faces"):
        load_shape(tmp_mesh_dir / "p.xyz", kind="mesh")
    with pytest.raises(ParameterError):
        load_shape(tmp_mesh_dir / "m.off", kind="surface")


def test_off_comments_and_counts_on_first_line(tmp_mesh_dir):
    p = _write(tmp_mesh_dir / "c.off", "OFF 3 1 0 # header\n# comment\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    s = load_shape(p)
    assert s.n_vertices == 3 and s.faces.tolist() == [[0, 1, 2]]


# -- errors: each names the file ----------------------------------------------------------------
def _fails(path, match):
    with pytest.raises(ShapeFileError, match=match) as ei:
        load_shape(path)
    assert str(path) in str(ei.value)
    return ei.value


def test_missing_file(tmp_mesh_dir):
    _fails(tmp_mesh_dir / "nope.off", "no such file")


def test_directory(tmp_mesh_dir):
    d = tmp_mesh_dir / "dir.off"
    d.mkdir()
    _fails(d, "directory")


_OFF3 = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n"  # an OFF header and three vertices, for one face
_PCD = ("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 3\n"
        "HEIGHT 1\nPOINTS 3\nDATA ascii\n")  # fmt: skip


@pytest.mark.parametrize("name,text,match", [
    pytest.param("m.abc", "OFF\n", "unknown shape format '.abc'", id="unknown-extension"),
    pytest.param("e.off", "", "empty", id="empty-file"),
    pytest.param("t.off", "OFF\n100 0 0\n" + "".join(f"{i} 0 0\n" for i in range(50)), "declares 100 vertices",
                 id="truncated-off"),
    pytest.param("t.off", "OFF\n3 2 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", "2 faces", id="truncated-off-faces"),
    pytest.param("n.off", "OFF\n3 1 0\n0 0 0\n1 abc 0\n0 1 0\n3 0 1 2\n", "line 4: non-numeric vertex value 'abc'",
                 id="non-numeric-token"),
    pytest.param("n.off", "OFF\n3 1 0\n0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n", "NaN", id="nan-coordinate"),
    pytest.param("n.xyz", "0 0 0\n1 inf 0\n", "infinite", id="inf-coordinate-in-xyz"),
    pytest.param("r.off", _OFF3 + "3 0 1 3\n", "face index 3 out of range", id="face-index-out-of-range"),
    pytest.param("z.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "1-based", id="obj-index-zero"),
    pytest.param("r.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "out of range", id="obj-index-out-of-range"),
    pytest.param("f.off", _OFF3 + "2 0 1\n", "face with 2 vertices", id="two-vertex-face"),
    pytest.param("f.off", _OFF3 + "4 0 1 2\n", "declares 4 vertices but lists 3", id="face-count-mismatch"),
    pytest.param("x.off", "PLY\n1 2 3\n", "not an OFF file", id="not-an-off-file"),
    # Open3D returns uninitialised points for this file; our reader must refuse it
    pytest.param("t.pcd", _PCD + "1 2 3\n4 5\n", "declares 3 points", id="truncated-ascii-pcd"),
    pytest.param("c.xyz", "# only a comment\n", "no vertices", id="point-cloud-with-empty-content"),
])  # fmt: skip
def test_malformed_text_files(tmp_mesh_dir, name, text, match):
    _fails(_write(tmp_mesh_dir / name, text), match)


def test_truncated_binary_ply(sphere, tmp_mesh_dir):
    p = tmp_mesh_dir / "t.ply"
    save_shape(sphere, p, binary=True)
    data = p.read_bytes()
    p.write_bytes(data[: len(data) - 100])
    _fails(p, "truncated")


def test_truncated_binary_stl(sphere, tmp_mesh_dir):
    p = tmp_mesh_dir / "t.stl"
    save_shape(sphere, p, binary=True)
    p.write_bytes(p.read_bytes()[:-10])
    _fails(p, "truncated")


def test_size_and_count_limits(tmp_mesh_dir, monkeypatch):
    p = _write(tmp_mesh_dir / "big.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    monkeypatch.setattr(tio, "MAX_VERTICES", 2)
    _fails(p, "above the limit")
    monkeypatch.setattr(tio, "MAX_VERTICES", 10**9)
    monkeypatch.setattr(tio, "MAX_FILE_BYTES", 10)
    _fails(p, "above the limit")


def test_save_errors(sphere, tmp_mesh_dir):
    with pytest.raises(ShapeFileError, match="cannot write format"):
        save_shape(sphere, tmp_mesh_dir / "a.abc")
    with pytest.raises(ShapeFileError, match="point cloud"):
        save_shape(Shape(sphere.vertices), tmp_mesh_dir / "a.stl")
    with pytest.raises(ShapeFileError, match="output folder does not exist"):
        save_shape(sphere, tmp_mesh_dir / "missing_dir" / "a.off")
    (tmp_mesh_dir / "d.off").mkdir()
    with pytest.raises(ShapeFileError, match="is a directory"):
        save_shape(sphere, tmp_mesh_dir / "d.off")


def test_save_is_all_or_nothing(sphere, tmp_path, monkeypatch):
    """A writer failing half-way (here: a full disk) leaves the old file as it was and no
    temporary file behind; the same holds for maps and trajectories (one atomic_output)."""
    from shape_toolkit.results.correspondence import save_map
    from shape_toolkit.results.trajectories import Trajectories

    p = tmp_path / "a.off"
    save_shape(sphere, p)
    before = p.read_bytes()

    def full_disk(fh, shape, binary):
        fh.write(b"OFF\n")
        raise OSError(28, "No space left on device")

    monkeypatch.setitem(tio._WRITERS, ".off", full_disk)
    with pytest.raises(ShapeFileError, match="cannot write: No space left on device"):
        save_shape(sphere, p)
    assert p.read_bytes() == before
    assert sorted(x.name for x in tmp_path.iterdir()) == ["a.off"]
    for save, name in [(lambda q: save_map(q, np.arange(4)), "m.txt"),
                       (lambda q: Trajectories(np.arange(4)[:, None], (4,)).save(q), "t.npz")]:
        save(tmp_path / name)
        with pytest.raises(ShapeFileError, match="output folder does not exist"):
            save(tmp_path / "nope" / name)
        with pytest.raises(ShapeFileError, match="is a directory"):
            save(tmp_path)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["a.off", "m.txt", "t.npz"]


def test_atomic_output_interrupted_write_keeps_old_file_and_no_temp(tmp_path):
    from shape_toolkit.validation import atomic_output

    p = tmp_path / "a.txt"
    p.write_text("old")
    for exc in (RuntimeError("interrupted"), KeyboardInterrupt()):
        with pytest.raises(type(exc)):
            with atomic_output(p) as tmp:
                tmp.write_text("half written")
                raise exc
        assert p.read_text() == "old"
        assert [x.name for x in tmp_path.iterdir()] == ["a.txt"]
    # two writers of one path at once get their own temporary files: the last rename wins, never a mix
    with atomic_output(p) as t1, atomic_output(p) as t2:
        assert t1 != t2 and t1.parent == t2.parent == tmp_path
        t1.write_text("one")
        t2.write_text("two")
    assert p.read_text() == "one"  # t2's block closed first
    assert [x.name for x in tmp_path.iterdir()] == ["a.txt"]
    q = tmp_path / "x" / "y" / "b.npz"
    with atomic_output(q, suffix=".npz", make_parents=True, durable=True) as tmp:
        assert tmp.name.endswith(".npz") and tmp.parent == q.parent
        np.savez(tmp, a=np.arange(3))
    with np.load(q) as z:
        assert z["a"].tolist() == [0, 1, 2]
    assert [x.name for x in q.parent.iterdir()] == ["b.npz"]
    with pytest.raises(ShapeFileError, match="cannot create the output folder"):
        with atomic_output(p / "c.txt", make_parents=True):
            pass  # a file stands where the folder should be


def _half_then_full_disk(file, *args, **kwargs):
    """A stand-in writer that writes part of its file, then finds the disk full."""
    with open(file, "wb") as fh:
        fh.write(b"partial")
    raise OSError(28, "No space left on device")


@pytest.mark.filterwarnings("ignore:.*results.jsonl. skipped 1 invalid line")
def test_every_whole_file_writer_survives_an_interrupted_write(sphere, tmp_path, monkeypatch):
    """Labels, the spectrum cache, prepared items, method outputs, the results file and the
    prepare log all go through atomic_output: a write failing half-way leaves the old file byte
    for byte and no temporary file, as a typed error."""
    from shape_toolkit.bench import executors, store
    from shape_toolkit.bench.tasks import prepare
    from shape_toolkit.core import spectrum as spm
    from shape_toolkit.data.datasets import load_item, synthetic_refs, write_labels
    from shape_toolkit.spectra import build_graph

    row = {"key": "k", "status": "ok", "task_name": "t", "task_kind": "x", "item": "i",
           "method_label": "m", "metrics": {}}
    results = tmp_path / "run" / "results.jsonl"
    results.parent.mkdir()
    log = tmp_path / "run" / "prepare.jsonl"
    item = load_item(synthetic_refs(1, subdivisions=1)[0])
    prep = prepare(item, "none", {}, pairwise=True, random_state=0)
    spm.set_cache_dir(tmp_path / "cache")
    try:
        g = build_graph(sphere, "binary")
        spec = spm.compute_spectrum(g, 4)
        (cached,) = (tmp_path / "cache").glob("*.npz")
        key = spm.SPECTRUM_CACHE.keys()[-1]  # the key text (the file is named by its hash)
        assert spm._cache_file(tmp_path / "cache", key) == cached
        cases = [  # (file, write it, the function to break, how to break it)
            (tmp_path / "l.txt", lambda: write_labels(tmp_path / "l.txt", [1, 2]), (np, "savetxt"),
             _half_then_full_disk),
            (cached, lambda: spm._cache_put(key, spec), (np, "savez"), _half_then_full_disk),
            (tmp_path / "run" / "p.npz", lambda: store.save_prepared(tmp_path / "run" / "p.npz", prep),
             (np, "savez"), _half_then_full_disk),
            (tmp_path / "run" / "outputs" / "o.npz", lambda: store.save_output(tmp_path / "run", "o", {"a": [1]}),
             (np, "savez_compressed"), _half_then_full_disk),
            (results, lambda: store.clean_results(results), (store, "dumps_json"),
             lambda r: (_ for _ in ()).throw(OSError(28, "No space left on device"))),
            (log, lambda: executors.clean_results_log(log), (type(log), "write_bytes"), _half_then_full_disk),
        ]
        for path, write, (owner, name), broken in cases:
            if path == results:
                results.write_text(json.dumps(row) + "\n" + '{"key": "torn')
            elif path == log:
                log.write_text('{"key": "a", "spectra": []}\n{"key": "to')
            else:
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_bytes(b"old contents")
            before = path.read_bytes()
            with monkeypatch.context() as m:
                m.setattr(owner, name, broken)
                with pytest.raises(ShapeFileError, match="No space left on device"):
                    write()
            assert path.read_bytes() == before, path
            assert not [x for x in path.parent.iterdir() if ".tmp" in x.name], path
            write()  # and unbroken, the same writer replaces the file
            assert path.read_bytes() != before, path
    finally:
        spm.set_cache_dir(None)
        spm.clear_cache()


# -- real data ----------------------------------------------------------------------------------
def test_every_shared_off_file_loads(shared_data):
    files = sorted((shared_data / "tosca5k").glob("*.off")) + sorted(
        (shared_data / "psb" / "off").glob("*.off")
    )
    assert files, f"no OFF files under {shared_data}"
    for f in files:
        s = load_shape(f, kind="mesh")
        assert s.n_vertices > 1000 and s.n_faces > 1000, f
        header = f.read_text().split("\n", 2)[1].split()
        assert (s.n_vertices, s.n_faces) == (int(header[0]), int(header[1])), f


def test_ascii_ply_quad_with_extra_properties(tmp_mesh_dir):
    p = _write(tmp_mesh_dir / "q.ply", "ply\nformat ascii 1.0\ncomment hi\nelement vertex 4\n"
               "property float x\nproperty float y\nproperty float z\nproperty uchar red\n"
               "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
               "0 0 0 1\n1 0 0 2\n1 1 0 3\n0 1 0 4\n4 0 1 2 3\n")  # fmt: skip
    s = load_shape(p)
    assert s.faces.tolist() == [[0, 1, 2], [0, 2, 3]] and s.area == pytest.approx(1.0)


def test_big_endian_binary_ply_with_polygons(tmp_mesh_dir):
    head = (b"ply\nformat binary_big_endian 1.0\nelement vertex 4\nproperty float x\n"
            b"property float y\nproperty float z\nelement face 2\n"
            b"property list uchar uint vertex_indices\nend_header\n")  # fmt: skip
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=">f4").tobytes()
    f = bytes([4]) + np.array([0, 1, 2, 3], ">u4").tobytes()
    f += bytes([3]) + np.array([0, 2, 3], ">u4").tobytes()
    p = tmp_mesh_dir / "be.ply"
    p.write_bytes(head + v + f)
    _fails(p, "duplicate faces")  # the triangle repeats half of the quad
    s = load_shape(p, duplicate_faces="keep")
    assert s.vertices.tolist()[2] == [1, 1, 0]
    assert s.faces.tolist() == [[0, 1, 2], [0, 2, 3], [0, 2, 3]]
    p.write_bytes(head + v + f[:-3])
    _fails(p, "truncated")


# ------------------------------------------------------------------------------------------------
# issue 11: hostile headers and indices
# ------------------------------------------------------------------------------------------------
_HEAD = (b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
         b"property float z\nelement face %d\nproperty list %s %s vertex_indices\nend_header\n")
_TRI = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], "<f4").tobytes()


def test_ply_float_indices_only_when_integral(tmp_mesh_dir):
    p = tmp_mesh_dir / "f.ply"
    p.write_bytes(_HEAD % (1, b"uchar", b"float") + _TRI + b"\x03" + np.array([0, 1, 2], "<f4").tobytes())
    assert load_shape(p).faces.tolist() == [[0, 1, 2]]
    p.write_bytes(_HEAD % (1, b"uchar", b"float") + _TRI + b"\x03" + np.array([0, 1.5, 2], "<f4").tobytes())
    _fails(p, "not all integers")
    p.write_bytes(_HEAD % (1, b"char", b"int") + _TRI + b"\xff" + np.array([0, 1, 2], "<i4").tobytes())
    _fails(p, "-1 vertices")
    p.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                 "element face 1\nproperty list char int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n-2 0 1\n")
    _fails(p, "-2 vertices")


def test_declared_counts_checked_against_the_file_size(tmp_mesh_dir):
    p = tmp_mesh_dir / "many.ply"
    p.write_bytes(_HEAD % (40_000_000, b"uchar", b"int") + _TRI + b"\x03" + np.array([0, 1, 2], "<i4").tobytes())
    _fails(p, "need at least")
    p.write_bytes(_HEAD % (2_000_000, b"uchar", b"int") + _TRI + b"\x00" * 2_000_000)  # 2M empty faces
    _fails(p, "face 0 has 0 vertices")  # the first bad face stops the read (not a row-by-row pass over 2M)
    p = tmp_mesh_dir / "many.off"
    p.write_text("OFF\n30000000 1 0\n0 0 0\n")
    _fails(p, "need at least")
    p = tmp_mesh_dir / "many.pcd"
    p.write_text("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\n"
                 "POINTS 9000000\nDATA ascii\n0 0 0\n")
    _fails(p, "need at least")


def test_huge_indices_and_pcd_count_zero(tmp_mesh_dir):
    p = tmp_mesh_dir / "h.off"
    p.write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 99999999999999999999999\n")
    _fails(p, "out of range")
    p = tmp_mesh_dir / "h.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999999\n")
    _fails(p, "out of range")
    p = tmp_mesh_dir / "c.pcd"
    p.write_text("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 0 1\nWIDTH 2\nHEIGHT 1\n"
                 "POINTS 2\nDATA ascii\n1 2 3\n4 5 6\n")
    _fails(p, "COUNT must be >= 1")


def test_duplicate_faces_rule(tmp_mesh_dir):
    from shape_toolkit.io.mesh import DuplicateFacesWarning

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    f = np.array([[0, 1, 2], [0, 2, 3], [2, 1, 0]])  # face 2 is face 0 flipped
    p = tmp_mesh_dir / "dup.off"
    save_shape(Shape(v, f), p)
    err = _fails(p, "1 duplicate faces")
    assert "shape-toolkit clean" in str(err)
    assert load_shape(p, duplicate_faces="keep").n_faces == 3
    with pytest.warns(DuplicateFacesWarning, match="dropped 1 duplicate"):
        assert load_shape(p, duplicate_faces="drop").faces.tolist() == [[0, 1, 2], [0, 2, 3]]
    with pytest.raises(ParameterError):
        load_shape(p, duplicate_faces="maybe")


def test_stl_read_by_libigl_after_the_checks_is_quiet(sphere, tmp_mesh_dir, capfd):
    """libigl reads STL (the soup welded as before); its parse errors become a ShapeFileError, and what it
    prints on the C-level stdout (the CLI's JSON) is silenced."""
    p = tmp_mesh_dir / "a.stl"
    p.write_text("solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex a b c\nendloop\n"
                 "endfacet\nendsolid x\n")
    _fails(p, "libigl cannot read this ascii STL")
    out, err = capfd.readouterr()
    assert out == "" and err == ""
    save_shape(sphere, p)
    s = load_shape(p)
    assert s.n_faces == sphere.n_faces and np.abs(s.vertices[s.faces] - sphere.vertices[sphere.faces]).max() < 1e-6
