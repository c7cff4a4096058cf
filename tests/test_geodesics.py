"""Geodesics: great-circle ground truth on the unit sphere, k-rings, ring maxima, relative
r-neighbourhoods (thesis 7.5.2), caching and error cases."""

from __future__ import annotations

import numpy as np
import pytest

from shape_toolkit.core.shape import Shape
from shape_toolkit.data.generate import icosphere
from shape_toolkit.errors import InvalidShapeError, ParameterError
from shape_toolkit.features import geodesics as g

SOURCES = [0, 37, 200, 641]


@pytest.fixture(scope="module")
def sphere3() -> Shape:
    return icosphere(3)


def _great_circle(shape: Shape, src) -> np.ndarray:
    V = shape.vertices / np.linalg.norm(shape.vertices, axis=1, keepdims=True)
    return np.arccos(np.clip(V[src] @ V.T, -1.0, 1.0))


@pytest.mark.parametrize("method, tol", [("exact", 0.01), ("fmm", 0.04), ("heat", 0.04)])
def test_sphere_great_circle(sphere3, method, tol):
    d = g.geodesic_distances(sphere3, SOURCES, method=method, cache=False)
    gt = _great_circle(sphere3, SOURCES)
    assert d.shape == (len(SOURCES), sphere3.n_vertices) and d.dtype == np.float64
    far = gt > 0.2
    rel = np.abs(d - gt)[far] / gt[far]
    assert rel.mean() < tol
    np.testing.assert_allclose(d[np.arange(len(SOURCES)), SOURCES], 0.0, atol=1e-12)


def test_exact_is_within_one_percent_everywhere(sphere3):
    d = g.geodesic_distances(sphere3, [5], method="exact")
    gt = _great_circle(sphere3, [5])
    far = gt > 0.2
    assert np.max(np.abs(d - gt)[far] / gt[far]) < 0.01


def test_dijkstra_is_an_upper_bound_of_exact(sphere3):
    de = g.geodesic_distances(sphere3, SOURCES, method="exact")
    dd = g.geodesic_distances(sphere3, SOURCES, method="dijkstra")
    assert np.all(dd >= de - 1e-9)
    assert np.mean(dd - de) > 0  # and strictly worse on average (paths along edges)


def test_targets_cache_and_symmetry(sphere3):
    g.clear_geodesic_cache()
    full = g.geodesic_distances(sphere3, [3, 10], method="exact")
    sub = g.geodesic_distances(sphere3, [10, 3], targets=[3, 10, 500], method="exact")
    np.testing.assert_allclose(sub, full[[1, 0]][:, [3, 10, 500]])
    np.testing.assert_allclose(sub[0, 0], sub[1, 1], rtol=1e-9)  # d(10, 3) == d(3, 10)
    again = g.geodesic_distances(sphere3, [3], method="exact")
    np.testing.assert_array_equal(again[0], full[0])
    # rows from the cache are copies, not views the caller could corrupt
    again[0, :] = -1
    assert g.geodesic_distances(sphere3, [3], method="exact")[0, 1] > 0
    assert g.geodesic_distances(sphere3, [], method="exact").shape == (0, sphere3.n_vertices)


def test_distance_to_set_is_the_row_minimum(sphere3):
    for method in ("fmm", "dijkstra", "heat", "exact"):
        rows = g.geodesic_distances(sphere3, [0, 300], method=method)
        d = g.geodesic_distance_to_set(sphere3, [0, 300], method=method)
        assert d.shape == (sphere3.n_vertices,)
        tol = 1e-9 if method in ("dijkstra", "exact") else 0.08
        assert np.all(np.abs(d - rows.min(axis=0)) <= tol * (1 + rows.min(axis=0)))


def test_point_cloud_needs_faces_except_heat_and_dijkstra(sphere3):
    cloud = Shape(sphere3.vertices)
    for method in ("exact", "fmm"):
        with pytest.raises(InvalidShapeError, match="point cloud.*'heat'"):
            g.geodesic_distances(cloud, [0], method=method)
    d = g.geodesic_distances(cloud, [0], method="dijkstra")
    chord = np.linalg.norm(sphere3.vertices - sphere3.vertices[0], axis=1)
    assert np.all(np.isfinite(d)) and np.all(d >= chord - 1e-9)  # paths of chords
    assert np.mean(d[0] / np.maximum(_great_circle(sphere3, [0])[0], 1e-9)) < 1.3


def test_errors(sphere3):
    with pytest.raises(ParameterError, match="method"):
        g.geodesic_distances(sphere3, [0], method="magic")
    with pytest.raises(ParameterError):
        g.geodesic_distances(sphere3, [sphere3.n_vertices], method="fmm")
    with pytest.raises(ParameterError):
        g.geodesic_distances(sphere3, [-1], method="exact")
    with pytest.raises(ParameterError):
        g.geodesic_distances(sphere3, [0.5], method="exact")
    with pytest.raises(ParameterError):
        g.geodesic_distances(sphere3, [0], targets=[9999], method="dijkstra")
    with pytest.raises(ParameterError):
        g.k_ring(sphere3, 0, -1)
    with pytest.raises(ParameterError):
        g.relative_geodesic_neighbourhood(sphere3, 0, 0.0)
    with pytest.raises(ParameterError):
        g.relative_geodesic_neighbourhood(sphere3, 0, 150.0)
    with pytest.raises(ParameterError):
        g.ring_maxima(np.zeros(3), sphere3, 1)


def test_k_rings_on_icosphere(sphere3):
    # vertex 0 is an icosahedron corner (valence 5); a subdivision vertex has valence 6
    valence = np.bincount(sphere3.edges.ravel())
    corner = 0
    regular = int(np.flatnonzero(valence == 6)[0])
    assert valence[corner] == 5
    assert g.k_ring(sphere3, corner, 0).tolist() == [corner]
    assert g.k_ring(sphere3, corner, 1).size == 6
    assert g.k_ring(sphere3, regular, 1).size == 7
    assert g.k_ring(sphere3, regular, 2).size == 19
    assert g.k_ring(sphere3, corner, 2).size == 16
    R = g.k_ring_all(sphere3, 2)
    for v in (corner, regular, 100):
        np.testing.assert_array_equal(R[v].indices[np.argsort(R[v].indices)], g.k_ring(sphere3, v, 2))
    # the k-ring of k >= diameter is everything
    assert g.k_ring(sphere3, 0, 100).size == sphere3.n_vertices
    # the rings of some vertices at several radii: each row the BFS ring of its vertex, repeats and order kept
    rows = np.array([regular, corner, regular, 7])
    for k, B in zip((0, 1, 3, 3, 1000), g.k_rings(sphere3, [0, 1, 3, 3, 1000], rows)):
        assert B.shape == (4, sphere3.n_vertices) and B.dtype == bool
        for i, v in enumerate(rows):
            np.testing.assert_array_equal(np.sort(B[i].indices), g.k_ring(sphere3, int(v), k))
    with pytest.raises(ParameterError):
        g.k_rings(sphere3, [2, 1])  # radii must increase


def test_ring_maxima(sphere3):
    z = sphere3.vertices[:, 2]
    peaks = g.ring_maxima(z, sphere3, 2)
    assert peaks.tolist() == [int(np.argmax(z))]
    # two bumps -> two maxima, strongest first
    v = sphere3.vertices
    f = np.exp(-20 * np.sum((v - [0, 0, 1]) ** 2, 1)) + 0.5 * np.exp(-20 * np.sum((v - [1, 0, 0]) ** 2, 1))
    peaks = g.ring_maxima(f, sphere3, 2)
    assert len(peaks) == 2
    assert np.allclose(v[peaks[0]], [0, 0, 1], atol=1e-9) and np.allclose(v[peaks[1]], [1, 0, 0], atol=1e-9)
    # constant values: ties broken by vertex id, so exactly one maximum per plateau
    assert g.ring_maxima(np.ones(sphere3.n_vertices), sphere3, 100).tolist() == [0]


def test_relative_geodesic_neighbourhood(sphere3):
    n = sphere3.n_vertices
    nb = g.relative_geodesic_neighbourhood(sphere3, 17, 5.0, method="exact")
    assert nb.size == int(np.ceil(0.05 * n)) and nb[0] == 17
    d = g.geodesic_distances(sphere3, [17], method="exact")[0]
    assert d[nb].max() <= np.min(np.delete(d, nb)) + 1e-12
    assert np.all(np.diff(d[nb]) >= 0)
    assert g.relative_geodesic_neighbourhood(sphere3, 17, 100.0).size == n
    assert g.relative_geodesic_neighbourhood(sphere3, 17, 0.01).tolist() == [17]


@pytest.mark.parametrize("method", g.GEODESIC_METHODS)
def test_other_components_are_unreachable(method):
    a = icosphere(2)
    n = a.n_vertices
    two = Shape(np.r_[a.vertices, a.vertices + [5.0, 0, 0]], np.r_[a.faces, a.faces + n])
    d = g.geodesic_distances(two, [0, n + 1], method=method)
    assert np.all(np.isinf(d[0, n:])) and np.all(np.isfinite(d[0, :n]))
    assert np.all(np.isinf(d[1, :n])) and np.all(np.isfinite(d[1, n:]))
    near = g.geodesic_distance_to_set(two, [0, n + 1], method=method)
    assert np.all(np.isfinite(near))
    np.testing.assert_allclose(near[:n], d[0, :n], rtol=0.1, atol=0.05)
    np.testing.assert_allclose(near[n:], d[1, n:], rtol=0.1, atol=0.05)


# -- nearest vertices, Voronoi cells, farthest points, time limit and progress -----------------
@pytest.mark.parametrize("method", ["dijkstra", "heat"])
def test_geodesic_nearest_equals_sorting_full_rows(sphere3, method):
    src = np.array([0, 37, 200, 641, 37])
    full = g.geodesic_distances(sphere3, src, method=method, cache=False)
    for count in (1, 7, 40):
        near = g.geodesic_nearest(sphere3, src, count, method=method)
        assert near.shape == (src.size, count)
        for k, s in enumerate(src):
            np.testing.assert_array_equal(near[k], g.order_by_distance(full[k], s)[:count])
            assert near[k, 0] == s


def test_geodesic_nearest_pads_small_components():
    a = icosphere(1)
    n = a.n_vertices
    two = Shape(np.r_[a.vertices, a.vertices + [5.0, 0, 0]], np.r_[a.faces, a.faces + n])
    near = g.geodesic_nearest(two, [0], n + 3)
    assert set(near[0, :n]) == set(range(n)) and (near[0, n:] == -1).all()


def test_nearest_source_is_the_geodesic_voronoi_cell(sphere3):
    src = np.array([3, 100, 400])
    owner = g.nearest_source(sphere3, src)
    rows = g.geodesic_distances(sphere3, src, method="dijkstra", cache=False)
    best = rows.min(axis=0)
    assert set(np.unique(owner)) == set(src)
    np.testing.assert_allclose(rows[np.searchsorted(src, owner), np.arange(sphere3.n_vertices)], best)


def test_geodesic_farthest_points(sphere3):
    pts = g.geodesic_farthest_points(sphere3, 6, start=5)
    assert pts[0] == 5 and np.unique(pts).size == 6
    for k in range(1, 6):  # each point is the farthest from those before it
        d = g.geodesic_distances(sphere3, pts[:k], method="dijkstra", cache=False).min(axis=0)
        assert d[pts[k]] == pytest.approx(d.max())
    assert g.geodesic_farthest_points(sphere3, 4).tolist() == g.geodesic_farthest_points(sphere3, 4).tolist()
    with pytest.raises(ParameterError):
        g.geodesic_farthest_points(sphere3, 0)


def test_progress_counts_every_solved_source(sphere3):
    seen = []
    g.geodesic_distances(sphere3, [1, 2, 3, 2], method="heat", cache=False,
                         progress=lambda done, total: seen.append((done, total)))
    assert seen == [(1, 3), (2, 3), (3, 3)]  # the repeated source is solved once
    seen.clear()
    g.geodesic_distances(sphere3, np.arange(300), method="dijkstra", cache=False,
                         progress=lambda done, total: seen.append((done, total)))
    assert seen[-1] == (300, 300) and len(seen) == 2  # blocks of 256 sources


def test_time_limit_raises_the_typed_error(sphere3):
    from shape_toolkit.errors import TimeLimitError

    with pytest.raises(TimeLimitError, match="time limit of 1e-06 s exceeded after 1 of 5 sources"):
        g.geodesic_distances(sphere3, [0, 1, 2, 3, 4], method="exact", cache=False, time_limit=1e-6)
    # a generous limit changes nothing
    d = g.geodesic_distances(sphere3, [0, 1], method="exact", cache=False, time_limit=1e6)
    np.testing.assert_allclose(d, g.geodesic_distances(sphere3, [0, 1], method="exact", cache=False))
    for bad in (0, -1.0, float("nan"), True):
        with pytest.raises(ParameterError):
            g.geodesic_distances(sphere3, [0], method="dijkstra", time_limit=bad)


def test_time_limit_projection_stops_hopeless_runs_early():
    from shape_toolkit.errors import TimeLimitError

    b = g.GeodesicBudget(time_limit=100.0, total=1000)
    b.t0 -= 2.0  # as if 2 s had passed: 3 sources in 2 s project 667 s for 1000, over 2 x 100 s
    b.tick()
    b.tick()
    with pytest.raises(TimeLimitError, match=r"3 of 1000 sources took .* about 6\d\d s for all"):
        b.tick()
    ok = g.GeodesicBudget(time_limit=100.0, total=10)
    ok.t0 -= 2.0
    for _ in range(10):  # 10 sources in 2 s: well inside the limit
        ok.tick()


def test_paired_distances_are_the_entries_of_the_rows(sphere3):
    """paired_geodesic_distances (the one chunked pair loop: metrics and trajectories use it) gives
    d(a_i, b_i) = geodesic_distances(a)[i, b_i] for repeated, unsorted a, across chunk borders,
    and for several partners per a_i; the exact values follow the great circle."""
    from shape_toolkit.metrics import correspondence as mc
    from shape_toolkit.results import trajectories as tj

    assert mc.paired_geodesic_distances is g.paired_geodesic_distances
    rng = np.random.default_rng(4)
    a = rng.integers(0, sphere3.n_vertices, 40)
    a[5:9] = a[0]  # repeats
    b = rng.integers(0, sphere3.n_vertices, (40, 2))
    full = g.geodesic_distances(sphere3, a, method="dijkstra", cache=False)
    d = g.paired_geodesic_distances(sphere3, a, b, method="dijkstra", chunk=3)
    np.testing.assert_array_equal(d, np.take_along_axis(full, b, axis=1))
    np.testing.assert_array_equal(tj._distances(sphere3, a, b[:, 0], "dijkstra"), d[:, 0])
    ex = g.paired_geodesic_distances(sphere3, a[:6], b[:6, 0], method="exact")
    np.testing.assert_allclose(ex, _great_circle(sphere3, a[:6])[np.arange(6), b[:6, 0]], atol=0.02)
    with pytest.raises(ParameterError):
        g.paired_geodesic_distances(sphere3, a, b[:-1], method="dijkstra")
    with pytest.raises(ParameterError):
        g.paired_geodesic_distances(sphere3, a, b + sphere3.n_vertices, method="dijkstra")


def test_vertex_ids_refuse_masks_and_can_drop_repeats(sphere3):
    """A boolean mask passed where vertex ids go used to become vertices 0 and 1 silently;
    check_vertex_ids(unique=True) keeps first occurrences in order (what keypoint lists need)."""
    from shape_toolkit.validation import check_seeds, check_vertex_ids

    mask = np.zeros(sphere3.n_vertices, dtype=bool)
    mask[[3, 9]] = True
    with pytest.raises(ParameterError, match="booleans"):
        g.geodesic_distances(sphere3, mask, method="dijkstra")
    with pytest.raises(ParameterError, match="booleans"):
        check_seeds(np.ones((2, 2), dtype=bool), 5, 5)
    np.testing.assert_array_equal(check_vertex_ids([7, 2, 7, 5, 2.0], 10, unique=True), [7, 2, 5])
    np.testing.assert_array_equal(check_vertex_ids([7, 2, 7], 10), [7, 2, 7])
    assert check_vertex_ids([], 10, unique=True).shape == (0,)


def test_dijkstra_runs_on_the_symmetric_edge_graph_as_directed(sphere3):
    """The edge graph of a mesh and the k-nearest-neighbour graph of a cloud are symmetric, so SciPy's Dijkstra run
    as directed on them (without the transpose of an undirected run) gives the undirected distances, bit for bit."""
    from scipy.sparse.csgraph import dijkstra

    rng = np.random.default_rng(0)
    cloud = Shape(rng.normal(size=(300, 3)))
    for shape in (sphere3, cloud):
        G = g._edge_graph(shape)
        assert abs(G - G.T).max() == 0.0
        src = np.arange(0, shape.n_vertices, 17)
        undirected = dijkstra(G, directed=False, indices=src)
        np.testing.assert_array_equal(g._dijkstra(G, indices=src), undirected)
        np.testing.assert_array_equal(g.geodesic_distances(shape, src, method="dijkstra", cache=False), undirected)
