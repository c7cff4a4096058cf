"""Segmenting large meshes through a proxy (issue 29, item 1: every pipeline at 10^5-10^6 vertices): the labels of
a proxy's segmentation carried to every vertex, faces for segmenters of faces, constraints kept exactly."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import run_cli
from sklearn.metrics import adjusted_rand_score

from shape_toolkit.api.registry import create_seeded
from shape_toolkit.data.corruptions import subdivide
from shape_toolkit.data.synthetic import articulated_shape
from shape_toolkit.io.mesh import save_shape
from shape_toolkit.plugins.segmenters.multires import segment_through_proxy
from shape_toolkit.results.labels import ConstraintError, Constraints
from shape_toolkit.spectra import compute_declared, declared_specs


@pytest.fixture(scope="module")
def shapes():
    small = articulated_shape(subdivisions=3, random_state=1).shape  # 642 vertices
    big, vmap = subdivide(small, splits=3)  # the same surface, 5,762 vertices; the first 642 are small's
    assert np.array_equal(vmap[: small.n_vertices], np.arange(small.n_vertices))
    return small, big


def _direct(seg, shape):
    specs = declared_specs(seg)
    return seg.segment(shape, spectrum=compute_declared(shape, specs) if specs else None)


def test_a_proxy_segmentation_carried_to_every_vertex_is_the_small_shapes(shapes):
    # the proxy of the subdivided shape is about the small shape itself: ncut's labels (it segments faces) carried
    # back must agree with segmenting the small shape directly, on its vertices
    small, big = shapes
    seg = create_seeded("segmenters", "ncut", None, 0, n_segments=6)
    out = segment_through_proxy(seg, big, proxy=600)
    assert out.labels.shape == (big.n_vertices,) and out.face_labels.shape == (big.n_faces,)
    assert out.n_segments == 6 and out.info["proxy"]["vertices"] == big.n_vertices
    assert out.info["proxy"]["proxy_vertices"] < big.n_vertices / 4
    assert adjusted_rand_score(_direct(seg, small).labels, out.labels[: small.n_vertices]) > 0.9


def test_vertex_labels_are_the_proxys_at_its_vertices_and_its_nearest_elsewhere(shapes):
    from scipy.spatial import cKDTree

    from shape_toolkit.plugins.matching.multires import make_proxy

    _, big = shapes
    seg = create_seeded("segmenters", "spectral-clustering", None, 0, n_segments=6)
    out = segment_through_proxy(seg, big, proxy=600)
    ps, ids = make_proxy(big, 600)  # the same proxy (deterministic)
    inner = _direct(seg, ps)
    assert out.info["per"] == "vertex"
    np.testing.assert_array_equal(out.labels[ids], inner.labels)
    nearest = inner.labels[cKDTree(big.vertices[ids]).query(big.vertices)[1]]
    assert np.mean(out.labels == nearest) > 0.9


def test_constraints_are_kept_on_the_full_mesh(shapes):
    small, big = shapes
    # ends where the label carried on the triangles differs from the nearest proxy vertex's (segment borders), so
    # that the constraint vertices' own rule is what keeps them
    seg = create_seeded("segmenters", "csc", None, 0, n_segments=6)
    from scipy.spatial import cKDTree

    from shape_toolkit.plugins.matching.multires import make_proxy
    from shape_toolkit.plugins.segmenters.multires import _proxy_constraints

    ps, ids = make_proxy(big, 600)  # the same proxy as inside (deterministic)
    nearest = cKDTree(big.vertices[ids]).query(big.vertices)[1]
    free = segment_through_proxy(seg, big, proxy=600).labels
    border = np.flatnonzero(free != _direct(seg, ps).labels[nearest])
    ends = border[np.linspace(0, len(border) - 1, 8).astype(int)]
    c = Constraints(must_link=[[ends[0], ends[1]], [ends[2], ends[3]]], cannot_link=[[ends[0], ends[2]],
                                                                                       [ends[4], ends[5]]])
    out = segment_through_proxy(seg, big, proxy=600, constraints=c)
    # what the segmenter kept on the proxy (csc shapes its clustering by the constraints, without enforcing
    # them) is kept on the full mesh: the constraint vertices take their proxy vertex's label exactly
    report, on_proxy = out.info["constraints"], out.info["proxy"]["constraints"]
    assert report["must_link"] == 2 and report["cannot_link"] == 2
    for key in ("must_link_broken", "cannot_link_broken"):
        assert report[key] == on_proxy[key], (report, on_proxy)
    inner = seg.segment(ps, spectrum=compute_declared(ps, declared_specs(seg)),
                        constraints=_proxy_constraints(c, nearest))
    np.testing.assert_array_equal(out.labels[ends[:6]], inner.labels[nearest[ends[:6]]])
    # two cannot-link ends on one proxy vertex cannot be kept apart there: said, not silently broken
    v = int(ends[6])
    twin = int(np.argsort(np.linalg.norm(big.vertices - big.vertices[v], axis=1))[1])
    with pytest.raises(ConstraintError, match="proxy"):
        segment_through_proxy(seg, big, proxy=600, constraints=Constraints(cannot_link=[[v, twin]]))


def test_cli_segments_a_large_mesh_through_a_proxy(shapes, capsys, tmp_path, monkeypatch):
    _, big = shapes
    save_shape(big, tmp_path / "big.off")
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(capsys, "segment", tmp_path / "big.off", "-k", "5", "--proxy", "600", "--faces",
                             "--json")
    assert code == 0, err
    res = json.loads(out)
    assert res["proxy"]["vertices"] == big.n_vertices and res["n_segments"] == 5
    assert len(np.loadtxt(tmp_path / "big.ncut.seg")) == big.n_faces
    code, out, err = run_cli(capsys, "segment", tmp_path / "big.off", "-k", "5", "--proxy", "0", "--json")
    assert code == 0, err and json.loads(out)["proxy"] is None
    code, out, err = run_cli(capsys, "segment", tmp_path / "big.off", "-k", "5", "--proxy", "10")
    assert code == 2 and err.count("\n") == 1 and "proxy" in err


@pytest.mark.parametrize("pairs, match", [
    ({"must_link": [[0, 10**6]]}, "out of range"),
    ({"must_link": [[0, -1]]}, "out of range"),
    ({"cannot_link": [[3, 3]]}, "itself"),
])
def test_constraints_through_a_proxy_are_validated_against_the_full_mesh(shapes, pairs, match):
    """Constraints the segmenter would refuse are refused through the proxy too, as a ConstraintError: an id past
    the mesh was an IndexError, a negative one indexed from the end and a self-pair passed, silently."""
    _, big = shapes
    seg = create_seeded("segmenters", "csc", None, 0, n_segments=4)
    with pytest.raises(ConstraintError, match=match):
        segment_through_proxy(seg, big, proxy=600, constraints=Constraints(**pairs))


def test_a_cannot_link_the_proxy_must_links_join_is_refused_naming_the_users_pair(shapes):
    """Valid on the full mesh, contradictory on the proxy: a must-link and a cannot-link whose ends pairwise share
    a proxy vertex. Refused naming the user's cannot-link and the way out (it was refused naming proxy ids the
    user never gave, 'pair [0, 5] is both a must-link and a cannot-link')."""
    from scipy.spatial import cKDTree

    from shape_toolkit.plugins.matching.multires import make_proxy

    _, big = shapes
    ps, ids = make_proxy(big, 600)  # the same proxy as inside (deterministic)
    nearest = cKDTree(big.vertices[ids]).query(big.vertices)[1]
    shared = [np.flatnonzero(nearest == p) for p in range(ps.n_vertices)]
    (a, c), (b, d), (e, f) = [g[:2] for g in shared if len(g) >= 2][:3]
    seg = create_seeded("segmenters", "csc", None, 0, n_segments=4)
    for ml, cl in (([[a, b]], [[c, d]]), ([[a, b], [d, e]], [[c, f]])):  # directly, and through a chain
        with pytest.raises(ConstraintError, match=rf"cannot-link \[{cl[0][0]}, {cl[0][1]}\] .*must-links.*--proxy 0"):
            segment_through_proxy(seg, big, proxy=600, constraints=Constraints(must_link=ml, cannot_link=cl))


def test_empty_constraints_through_a_proxy_report_nothing_as_at_full_resolution(shapes):
    """An empty constraints file gave info['constraints'] (all zeros) through the proxy and None directly."""
    small, big = shapes
    seg = create_seeded("segmenters", "csc", None, 0, n_segments=4)
    empty = Constraints()
    assert "constraints" not in seg.segment(small, constraints=empty).info
    through = segment_through_proxy(seg, big, proxy=600, constraints=empty)
    assert "constraints" not in through.info and "constraints" not in through.info["proxy"]


def test_cli_diagnostics_of_a_proxy_segmentation_are_the_proxys(shapes, capsys, tmp_path, monkeypatch):
    """segment --json put ncut's cut_labels_ (one per proxy face) in 'diagnostics' beside the mesh's n_faces: they
    are the fitted segmenter's, on the proxy, so they go with the proxy."""
    _, big = shapes
    save_shape(big, tmp_path / "big.off")
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(capsys, "segment", tmp_path / "big.off", "-k", "5", "--proxy", "600", "--json")
    assert code == 0, err
    res = json.loads(out)
    assert res["diagnostics"] == {} and res["n_faces"] == big.n_faces
    cut = res["proxy"]["diagnostics"]["cut_labels_"]
    assert len(cut) < big.n_faces / 4 and res["proxy"]["proxy_vertices"] < big.n_vertices / 4


def test_the_constraint_warning_through_a_proxy_counts_the_users_constraints(shapes):
    """A must-link whose two ends share a proxy vertex is not passed to the segmenter: its one-line warning said
    'broke 0 of 0 must-links' (the proxy's counts) while info['constraints'] gave the user's 1."""
    from scipy.spatial import cKDTree

    from shape_toolkit.plugins.matching.multires import make_proxy
    from shape_toolkit.plugins.segmenters.constraints import ConstraintWarning

    _, big = shapes
    ps, ids = make_proxy(big, 600)
    nearest = cKDTree(big.vertices[ids]).query(big.vertices)[1]
    a, b = next(g[:2] for g in (np.flatnonzero(nearest == p) for p in range(ps.n_vertices)) if len(g) >= 2)
    seg = create_seeded("segmenters", "csc", None, 0, n_segments=6)
    free = segment_through_proxy(seg, big, proxy=600).labels
    part = np.flatnonzero(free == (free[a] + 1) % (free.max() + 1))  # a segment without a or b
    c = Constraints(must_link=[[a, b]], cannot_link=[[part[0], part[-1]]])  # csc breaks a cannot-link in a segment
    with pytest.warns(ConstraintWarning) as caught:
        out = segment_through_proxy(seg, big, proxy=600, constraints=c)
    said = [str(w.message) for w in caught if issubclass(w.category, ConstraintWarning)]
    assert len(said) == 1 and "of 1 must-links and 1 of 1 cannot-links" in said[0], said
    assert out.info["constraints"]["must_link"] == 1 and out.info["proxy"]["constraints"]["must_link"] == 0


def _dumbbell_cloud() -> tuple[np.ndarray, np.ndarray]:
    """6,400 points: two unit spheres 3.2 apart joined by a thin tube, and each point's sphere (by the sign of x)."""
    rng = np.random.default_rng(0)
    u = rng.normal(size=(6000, 3))
    X = u / np.linalg.norm(u, axis=1, keepdims=True) + np.where(np.arange(6000) < 3000, -1.6, 1.6)[:, None] * [1, 0, 0]
    t, th = rng.uniform(-0.7, 0.7, 400), rng.uniform(0, 2 * np.pi, 400)
    X = np.vstack([X, np.c_[t, 0.2 * np.cos(th), 0.2 * np.sin(th)]])
    return X, (X[:, 0] > 0).astype(int)


def test_a_point_cloud_is_segmented_through_a_farthest_point_proxy(capsys, tmp_path, monkeypatch):
    """A cloud above 1.5 proxy points went to the segmenter whole (segment_through_proxy needed faces): it now goes
    through the farthest-point proxy match uses, each point taking its nearest proxy point's label; on a shape of two
    clear parts the segments are the parts, as segmenting the cloud directly gives them."""
    from scipy.spatial import cKDTree

    from shape_toolkit.core.shape import Shape
    from shape_toolkit.plugins.matching.multires import make_proxy

    X, truth = _dumbbell_cloud()
    cloud, far = Shape(X, None, "dumbbell"), np.abs(X[:, 0]) > 1.0  # the spheres' far halves: away from the tube
    seg = create_seeded("segmenters", "spectral-clustering", None, 0, n_segments=2)
    out = segment_through_proxy(seg, cloud, proxy=600)
    ps, ids = make_proxy(cloud, 600)  # farthest points: a cloud of 600
    assert not ps.is_mesh and out.face_labels is None and out.info["proxy"]["proxy_vertices"] == 600
    inner = _direct(seg, ps)
    np.testing.assert_array_equal(out.labels[ids], inner.labels)
    np.testing.assert_array_equal(out.labels, inner.labels[cKDTree(X[ids]).query(X)[1]])
    assert adjusted_rand_score(truth[far], out.labels[far]) == 1.0
    assert adjusted_rand_score(truth[far], _direct(seg, cloud).labels[far]) == 1.0
    # the command line: a cloud file (no faces) through --proxy, the proxy reported
    save_shape(cloud, tmp_path / "cloud.ply")
    monkeypatch.chdir(tmp_path)
    code, text, err = run_cli(capsys, "segment", tmp_path / "cloud.ply", "--method", "spectral-clustering", "-k", "2",
                              "--proxy", "600", "--json")
    assert code == 0, err
    res = json.loads(text)
    assert res["proxy"]["proxy_vertices"] == 600 and res["proxy"]["vertices"] == len(X)
    np.testing.assert_array_equal(np.loadtxt(tmp_path / "cloud.spectral-clustering.labels.txt", dtype=int), out.labels)


def test_a_cloud_refused_by_a_segmenter_of_faces_is_told_which_methods_take_points(capsys, tmp_path, monkeypatch):
    """ncut (the default) needs faces: on a cloud the one-line error names the methods that take points, and those
    do segment it (directly, and through a proxy)."""
    from shape_toolkit.cli.commands.segment import CLOUD_METHODS
    from shape_toolkit.core.shape import Shape
    from shape_toolkit.errors import InvalidShapeError, MeshRequiredError

    X, _ = _dumbbell_cloud()
    with pytest.raises(MeshRequiredError, match="needs a triangle mesh"):  # the type the command adds its hint to
        Shape(X, None, "dumbbell").require_faces("ncut")
    assert issubclass(MeshRequiredError, InvalidShapeError)
    save_shape(Shape(X, None, "dumbbell"), tmp_path / "cloud.ply")
    monkeypatch.chdir(tmp_path)
    code, _, err = run_cli(capsys, "segment", tmp_path / "cloud.ply", "-k", "2")
    assert code == 2 and err.count("\n") == 1 and "needs a triangle mesh" in err
    # through a proxy (--proxy below the cloud's size) the error still names the cloud given, not its proxy
    code, _, err = run_cli(capsys, "segment", tmp_path / "cloud.ply", "-k", "2", "--proxy", "600")
    assert code == 2 and "Shape('cloud', 6400 vertices" in err and "proxy" not in err, err
    assert all(f"--method {m}" in err or f" or {m}" in err for m in CLOUD_METHODS), err
    for m in CLOUD_METHODS:
        for proxy in ("0", "600"):
            code, _, err = run_cli(capsys, "segment", tmp_path / "cloud.ply", "-k", "2", "--method", m,
                                   "--proxy", proxy)
            assert code == 0, (m, proxy, err)
