"""Geodesics on meshes the native solvers cannot take (found by fuzzing): libigl's exact geodesics crash (SIGSEGV) on
a face with a repeated vertex or a non-manifold edge and loop forever on zero-area or sliver faces; fast marching
raises an untyped RuntimeError on a repeated vertex, a non-manifold edge or a non-manifold vertex. Each is refused
before the solver with a one-line InvalidShapeError naming the repair; the heat method and Dijkstra, which cope, are
not refused.

A regression must not crash or hang pytest: in this process libigl's ``exact_geodesic`` is replaced by a tripwire
that fails the test, and the real, unguarded calls run in a child process with a timeout."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest
from helpers import run_cli

from shape_toolkit.core.cleanup import clean_shape
from shape_toolkit.core.shape import Shape
from shape_toolkit.data.generate import icosphere
from shape_toolkit.errors import InvalidShapeError, SolverError
from shape_toolkit.features import geodesics as g
from shape_toolkit.io.mesh import save_shape

TET_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
TET_F = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])


def _repeated() -> Shape:
    """The fuzzer's tet_rep.off: a tetrahedron whose last face repeats a vertex."""
    return Shape(TET_V, np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 0]]), name="repeated")


def _non_manifold_edge() -> Shape:
    """The fuzzer's tet_nm.off: a tetrahedron with a fifth face on its edge (0, 1)."""
    return Shape(np.vstack([TET_V, [[1, 1, 1]]]), np.vstack([TET_F, [[0, 1, 4]]]), name="nm-edge")


def _duplicate_face() -> Shape:
    """A closed sphere with one face twice: its three edges are on three faces."""
    s = icosphere(2)
    return Shape(s.vertices, np.vstack([s.faces, s.faces[:1]]), name="dup-face")


def _non_manifold_vertex() -> Shape:
    """Two tetrahedra touching at vertex 0 (a bow-tie)."""
    m = np.array([0, 4, 5, 6])
    return Shape(np.vstack([TET_V, -TET_V[1:]]), np.vstack([TET_F, m[TET_F]]), name="bow-tie")


def _zero_area() -> Shape:
    """As the fuzzer's zeroarea.off: a closed sphere with 10 edges collapsed (coincident vertices), 20 faces of zero
    area."""
    s = icosphere(2)
    v = np.array(s.vertices)
    v[s.faces[:10, 1]] = v[s.faces[:10, 0]]
    return Shape(v, s.faces, name="zero-area")


def _sliver() -> Shape:
    """A closed sphere with one face flattened to altitude 1e-7 of its longest edge (not zero area: plain clean
    keeps it)."""
    s = icosphere(2)
    v = np.array(s.vertices)
    a, b, c = s.faces[0]
    mid = 0.5 * (v[a] + v[b])
    v[c] = mid + 1e-7 * (v[c] - mid) / np.linalg.norm(v[c] - mid) * np.linalg.norm(v[b] - v[a])
    return Shape(v, s.faces, name="sliver")


def _far() -> Shape:
    """A unit sphere 1e10 from the origin: its edges are below 2.2e-10 of its coordinates."""
    s = icosphere(1)
    return Shape(s.vertices + 1e10, s.faces, name="far")


MESHES = {
    "repeated": _repeated,
    "nm-edge": _non_manifold_edge,
    "dup-face": _duplicate_face,
    "bow-tie": _non_manifold_vertex,
    "zero-area": _zero_area,
    "sliver": _sliver,
    "far": _far,
}
#: (mesh, method) pairs the solver cannot take, and a phrase the message must hold
REFUSED = [
    ("repeated", "exact", "1 face with a repeated vertex"),
    ("repeated", "fmm", "1 face with a repeated vertex"),
    ("nm-edge", "exact", "1 non-manifold edge (first: edge [0, 1] on 3 faces)"),
    ("nm-edge", "fmm", "1 non-manifold edge"),
    ("dup-face", "exact", "3 non-manifold edges"),
    ("dup-face", "fmm", "3 non-manifold edges"),
    ("bow-tie", "fmm", "1 non-manifold vertex (first: vertex 0"),
    ("zero-area", "exact", "20 faces of zero or near-zero area"),
    ("sliver", "exact", "1 face of zero or near-zero area"),
    ("far", "exact", "faces too small for their coordinates"),
]
#: (mesh, method) pairs the solver takes (checked against the libraries): not refused
ACCEPTED = [
    ("bow-tie", "exact"), ("zero-area", "fmm"), ("sliver", "fmm"), ("far", "fmm"),
    *((name, m) for name in MESHES for m in ("heat", "dijkstra")),
]


@pytest.fixture(autouse=True)
def _exact_tripwire(monkeypatch):
    """No native exact solve on a refused mesh in this process: reaching libigl fails the test instead of
    crashing (or hanging) pytest. Fresh caches, so each test prepares (and checks) its solvers."""
    import igl

    real = igl.exact_geodesic

    def guarded(V, F, *args, **kwargs):
        name = getattr(guarded, "allowed", None)
        if name is None:
            raise AssertionError("libigl's exact_geodesic was reached with a mesh the check should have refused")
        return real(V, F, *args, **kwargs)

    monkeypatch.setattr(igl, "exact_geodesic", guarded)
    g.clear_geodesic_cache()
    yield guarded
    g.clear_geodesic_cache()


@pytest.mark.parametrize("name, method, phrase", REFUSED, ids=[f"{m}-{n}" for n, m, _ in REFUSED])
def test_refused_with_one_line_naming_the_fix(name, method, phrase):
    shape = MESHES[name]()
    with pytest.raises(InvalidShapeError) as info:
        g.geodesic_distances(shape, [0, 1], method=method)
    msg = str(info.value)
    assert phrase in msg and "\n" not in msg
    assert msg.startswith(f"{method} geodesics need a clean manifold mesh, but Shape('{name}'")
    assert "shape-toolkit clean" in msg and msg.rstrip().endswith("dijkstra method")
    fix = "--remesh EDGE_LEN" if name in ("sliver", "far") else "repair it with `shape-toolkit clean`"
    assert fix in msg
    # the other entry points prepare the same solver: the multi-source solve, the paired distances
    with pytest.raises(InvalidShapeError, match="need a clean manifold mesh"):
        g.geodesic_distance_to_set(shape, [0, 1], method=method)
    with pytest.raises(InvalidShapeError, match="need a clean manifold mesh"):
        g.paired_geodesic_distances(shape, np.array([0, 1]), np.array([1, 2]), method=method)


@pytest.mark.parametrize("name, method", ACCEPTED, ids=[f"{m}-{n}" for n, m in ACCEPTED])
def test_methods_that_cope_are_not_refused(name, method, _exact_tripwire):
    shape = MESHES[name]()
    _exact_tripwire.allowed = True  # the bow-tie is safe for libigl (every source tried)
    d = g.geodesic_distances(shape, [0, 1], method=method)
    assert d.shape == (2, shape.n_vertices) and np.isfinite(d).all() and (d >= 0).all()
    np.testing.assert_array_equal(d[[0, 1], [0, 1]], 0.0)
    assert np.isfinite(g.geodesic_distance_to_set(shape, [0, 1], method=method)).all()


def test_message_names_the_methods_that_work():
    """Each message offers exactly the methods that take the mesh as it is."""
    cases = {("bow-tie", "fmm"): "use the exact, heat or dijkstra method",
             ("zero-area", "exact"): "use the fmm, heat or dijkstra method",
             ("repeated", "exact"): "use the heat or dijkstra method"}
    for (name, method), offer in cases.items():
        with pytest.raises(InvalidShapeError, match=offer):
            g.check_solver_input(MESHES[name](), method)


@pytest.mark.parametrize("name", ["repeated", "nm-edge", "dup-face", "bow-tie", "zero-area"])
def test_shape_toolkit_clean_is_the_named_fix(name):
    cleaned, _ = clean_shape(MESHES[name]())
    assert not g.solver_defects(cleaned)
    for method in ("exact", "fmm"):
        g.check_solver_input(cleaned, method)


def test_a_sliver_needs_the_named_remesh():
    pytest.importorskip("pymeshlab")
    sliver = MESHES["sliver"]()
    assert g.solver_defects(clean_shape(sliver)[0]).keys() == {"thin_faces"}  # plain clean keeps a sliver ...
    remeshed, _ = clean_shape(sliver, remesh_target_edge=float(sliver.mean_edge_length))
    assert not g.solver_defects(remeshed)  # ... a remesh removes it


def test_check_is_scale_free():
    """The same mesh in other units (a power of ten, not of two) has the same defects."""
    for name in ("zero-area", "sliver", "bow-tie"):
        s = MESHES[name]()
        want = g.solver_defects(s)
        for k in (1e-30, 1e30):
            assert g.solver_defects(Shape(s.vertices * k, s.faces)).keys() == want.keys()


def test_check_runs_once_per_shape(monkeypatch, _exact_tripwire):
    """The check is prepared with the cached solver: repeated calls do not repeat it."""
    calls = []
    real = g.solver_defects
    monkeypatch.setattr(g, "solver_defects", lambda *a, **k: calls.append(1) or real(*a, **k))
    _exact_tripwire.allowed = True
    s = icosphere(1)
    for _ in range(3):
        g.geodesic_distances(s, [0, 5], method="exact", cache=False)
        g.geodesic_distance_to_set(s, [3], method="exact")
    assert len(calls) == 1
    for _ in range(2):
        g.geodesic_distances(s, [0], method="fmm", cache=False)
    assert len(calls) == 2


def test_native_runtime_error_becomes_solver_error(monkeypatch):
    """A failure the check did not foresee is still one typed line, not an internal error."""

    class Broken:
        def compute_distance(self, *args):
            raise RuntimeError("handling of nonmanifold mesh\nnot yet implemented")

        compute_distance_multisource = compute_distance

    monkeypatch.setattr(g, "_solver", lambda shape, method: Broken())
    s = icosphere(1)
    for call in (lambda: g.geodesic_distances(s, [0], method="fmm"),
                 lambda: g.geodesic_distance_to_set(s, [0], method="heat")):
        with pytest.raises(SolverError, match="nonmanifold mesh not yet implemented; .*dijkstra method") as info:
            call()
        assert "\n" not in str(info.value)


def test_unguarded_native_calls_in_a_child_process():
    """The fuzzer's crash (SIGSEGV: a repeated vertex, a non-manifold edge) and hang (zero-area faces) cases with the
    real libigl, in a child process with a timeout: a regression fails this test, not pytest."""
    code = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(__import__("pathlib").Path(__file__).parent)!r})
        from test_geodesics_bad_meshes import MESHES
        from shape_toolkit.errors import InvalidShapeError
        from shape_toolkit.features.geodesics import geodesic_distances, geodesic_distance_to_set
        for name in ("repeated", "nm-edge", "zero-area", "sliver"):
            for call in (geodesic_distances, geodesic_distance_to_set):
                try:
                    call(MESHES[name](), [0, 1], method="exact")
                except InvalidShapeError:
                    print("refused", name)
    """)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.split("\n").count("refused repeated") == 2 and res.stdout.count("refused") == 8


def test_cli_exits_2_with_one_line(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for name, method, phrase in (("nm-edge", "fmm", "1 non-manifold edge"),
                                 ("repeated", "exact", "1 face with a repeated vertex"),
                                 ("zero-area", "exact", "20 faces of zero or near-zero area")):
        save_shape(MESHES[name](), tmp_path / f"{name}.off")
        code, out, err = run_cli(capsys, "geodesics", tmp_path / f"{name}.off", "--sources", "0", "--method", method)
        assert code == 2 and not out, err
        assert len(err.strip().splitlines()) == 1 and phrase in err and "shape-toolkit clean" in err
        assert "Traceback" not in err and "internal error" not in err
        assert not (tmp_path / f"{name}.geodesics.npz").exists()
    code, _, err = run_cli(capsys, "geodesics", tmp_path / "nm-edge.off", "--sources", "0", "--method", "dijkstra")
    assert code == 0, err
