"""Shape graphs, Laplacians and spectra: analytic answers, identities and invariances."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import scipy.linalg as la
import scipy.sparse as sp

from shape_toolkit import (
    DisconnectedGraphError,
    InvalidShapeError,
    ParameterError,
    PluginError,
    Shape,
    build_graph,
    compute_spectrum,
    laplacian_matrix,
)
from shape_toolkit.core.graph import ShapeGraph, epsilon_edges, knn_edges
from shape_toolkit.core.spectrum import (
    Spectrum,
    clear_cache,
    component_spectra,
    fix_signs,
    is_cached,
    set_cache_dir,
)
from shape_toolkit.data.generate import icosphere
from shape_toolkit.data.synthetic import articulated_shape
from shape_toolkit.errors import NumericallyDisconnectedGraphError


@pytest.fixture(scope="module")
def sphere4() -> Shape:
    return icosphere(4)


def _rotation(seed: int) -> np.ndarray:
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def test_unit_sphere_cotangent_eigenvalues_are_l_l_plus_1(sphere4):
    spec = compute_spectrum(build_graph(sphere4, "cotangent"), 16)
    assert spec.generalized
    expected = np.array([0.0] + [2.0] * 3 + [6.0] * 5 + [12.0] * 7)
    assert abs(spec.eigenvalues[0]) < 1e-8
    np.testing.assert_allclose(spec.eigenvalues[1:], expected[1:], rtol=1e-2)
    # multiplicities 2l+1: the gaps between consecutive groups are large, within groups tiny
    groups = np.split(spec.eigenvalues[1:], [3, 8])
    assert [len(g) for g in groups] == [3, 5, 7]
    assert all(np.ptp(g) < 0.01 * g.mean() for g in groups)


def test_intrinsic_delaunay_matches_cotangent_on_good_mesh(sphere4):
    a = compute_spectrum(build_graph(sphere4, "cotangent"), 10).eigenvalues
    b = compute_spectrum(build_graph(sphere4, "intrinsic-delaunay"), 10).eigenvalues
    np.testing.assert_allclose(a[1:], b[1:], rtol=5e-3)


def test_mass_matrix_eigenvectors_are_mass_orthonormal(sphere):
    spec = compute_spectrum(build_graph(sphere, "cotangent"), 8)
    U = spec.eigenvectors
    np.testing.assert_allclose(U.T @ (spec.mass[:, None] * U), np.eye(8), atol=1e-8)
    assert spec.mass.sum() == pytest.approx(sphere.area, rel=1e-9)


def test_cotangent_reports_and_clamps_negative_weights():
    shape = articulated_shape(random_state=3).shape
    g = build_graph(shape, "cotangent")
    assert g.info["negative_weights"] > 0
    gc = build_graph(shape, "cotangent", clamp_negative=True)
    assert gc.info["clamped"] and (gc.W.data >= 0).all()
    assert (g.W.data < 0).sum() == 2 * g.info["negative_weights"]


def test_gaussian_weights_eq_3_7_default_and_local_bandwidths(sphere):
    e, length = sphere.edges, sphere.edge_lengths
    # default: eq. 3.7 with one sigma, the mean edge length on a regular mesh
    g = build_graph(sphere, "gaussian")
    w = np.asarray(g.W[e[:, 0], e[:, 1]]).ravel()
    assert length.max() < 4.29 * length.mean()
    np.testing.assert_allclose(w, np.exp(-(length**2) / (2 * length.mean() ** 2)))
    assert g.info["bandwidth"] == pytest.approx(length.mean())
    # scaling the shape does not change default weights
    g2 = build_graph(sphere.with_vertices(sphere.vertices * 7.0), "gaussian")
    np.testing.assert_allclose(g2.W.toarray(), g.W.toarray(), atol=1e-12)
    # an irregular mesh: one long edge raises sigma until every weight is >= MIN_WEIGHT
    from shape_toolkit.plugins.weightings.gaussian import MIN_WEIGHT

    v = sphere.vertices.copy()
    v[0] *= 6.0  # a spike: its edges are many times the mean length
    spiky = sphere.with_vertices(v)
    ls = spiky.edge_lengths
    gs = build_graph(spiky, "gaussian")
    ws = np.asarray(gs.W[spiky.edges[:, 0], spiky.edges[:, 1]]).ravel()
    assert ws.min() == pytest.approx(MIN_WEIGHT, rel=1e-9) and ls.max() > 4.29 * ls.mean()
    with pytest.raises(ParameterError, match="numerically disconnected"):  # the plain mean underflows
        build_graph(spiky, "gaussian", bandwidth="mean")
    # local scaling (Zelnik-Manor & Perona): sigma_ij = sqrt(sigma_i sigma_j), weights in [exp(-1/2), 1]
    gl = build_graph(sphere, "gaussian", bandwidth="local")
    sigma_v = np.zeros(sphere.n_vertices)
    np.maximum.at(sigma_v, e[:, 0], length)
    np.maximum.at(sigma_v, e[:, 1], length)
    wl = np.asarray(gl.W[e[:, 0], e[:, 1]]).ravel()
    np.testing.assert_allclose(wl, np.exp(-(length**2) / (2 * sigma_v[e[:, 0]] * sigma_v[e[:, 1]])))
    assert gl.info["bandwidth"] == "local" and (wl >= np.exp(-0.5) - 1e-15).all() and (wl <= 1).all()
    # the former global default and an explicit global bandwidth follow eq. 3.7 with one sigma
    gm = build_graph(sphere, "gaussian", bandwidth="mean")
    assert gm.info["bandwidth"] == pytest.approx(length.mean())
    wm = np.asarray(gm.W[e[:, 0], e[:, 1]]).ravel()
    np.testing.assert_allclose(wm, np.exp(-(length**2) / (2 * length.mean() ** 2)))
    g3 = build_graph(sphere, "gaussian", bandwidth=0.3)
    np.testing.assert_allclose(np.asarray(g3.W[e[:, 0], e[:, 1]]).ravel(), np.exp(-(length**2) / 0.18))
    for bad in (-1.0, 0.0, np.inf, "wide", True):
        with pytest.raises(ParameterError):
            build_graph(sphere, "gaussian", bandwidth=bad)
    with pytest.raises(ParameterError, match="bandwidth_scale"):
        build_graph(sphere, "gaussian", bandwidth_scale=0)


def test_tiny_user_bandwidth_is_refused_with_what_to_do(sphere):
    with pytest.raises(ParameterError, match=r"numerically disconnected.*Use bandwidth >= ") as exc:
        build_graph(sphere, "gaussian", bandwidth=1e-300)
    safe = float(str(exc.value).split("bandwidth >= ")[1].split(",")[0])
    g = build_graph(sphere, "gaussian", bandwidth=safe)  # the advertised bound is enough
    assert g.W.data.min() >= 1e-8 * 0.99
    assert compute_spectrum(g, 4, cache=False).n_null == 1
    with pytest.raises(ParameterError, match="bandwidth_scale >= "):
        build_graph(_horse_like(), "gaussian", bandwidth="local", bandwidth_scale=0.05)
    with pytest.raises(ParameterError, match="numerically disconnected.*Use bandwidth >= "):
        build_graph(_horse_like(), "gaussian", bandwidth_scale=0.05)


def _horse_like(stretch: float = 40.0, z0: float = 0.7) -> Shape:
    """An icosphere whose cap z > z0 is stretched into a long, sparsely sampled spike (edges up to
    ~15x the mean length): like a leg or tail of an irregular remeshing (the TOSCA horse)."""
    s = icosphere(4)
    v = s.vertices.copy()
    top = v[:, 2] > z0
    v[top, 2] = z0 + (v[top, 2] - z0) * stretch
    return Shape(v, s.faces)


def test_irregular_mesh_stays_connected_with_default_bandwidth():
    shape = _horse_like()
    lengths = shape.edge_lengths
    assert lengths.max() / lengths.mean() > 10
    g = build_graph(shape, "gaussian")
    from shape_toolkit.plugins.weightings.gaussian import MIN_WEIGHT

    assert g.W.data.min() >= MIN_WEIGHT * (1 - 1e-9)  # the automatic bandwidth's floor
    spec = compute_spectrum(g, 11, cache=False)
    assert spec.n_null == 1 and spec.eigenvalues[1] > 1e-4 * g.degrees.max()
    # the former default (one bandwidth, the mean edge length) underflows on the spike: the graph is
    # numerically disconnected, which compute_spectrum refuses instead of returning two null eigenpairs
    old = build_graph(shape, "gaussian", bandwidth="mean")
    assert old.components[0] == 1 and old.W.data.min() < 1e-20
    with pytest.raises(NumericallyDisconnectedGraphError, match="numerically disconnected") as exc:
        compute_spectrum(old, 11, cache=False)
    assert isinstance(exc.value, DisconnectedGraphError)
    assert "bandwidth" in str(exc.value) and "component_spectra" in str(exc.value)


def test_numerically_disconnected_graph_is_refused_whatever_the_weighting(sphere):
    g = build_graph(sphere, "binary")
    W = g.W.tocoo()
    z = sphere.vertices[:, 2]
    cut = (z[W.row] > 0) != (z[W.col] > 0)
    for factor, refused in ((1e-14, True), (1e-3, False)):
        data = np.where(cut, W.data * factor, W.data)
        weak = ShapeGraph(sphere, sp.csr_matrix((data, (W.row, W.col)), shape=W.shape), weighting="binary")
        assert weak.components[0] == 1
        for kind in ("combinatorial", "normalized", "random-walk"):
            if refused:
                with pytest.raises(NumericallyDisconnectedGraphError, match="2 eigenvalues that are zero") as exc:
                    compute_spectrum(weak, 6, laplacian=kind, cache=False)
                assert exc.value.n_null == 2 and exc.value.n_components == 1
                assert "components='largest'" in str(exc.value)
            else:  # a bottleneck, not a break: its small lambda_2 is resolved and kept
                spec = compute_spectrum(weak, 6, laplacian=kind, cache=False)
                assert spec.n_null == 1 and spec.eigenvalues[1] > 0
    # the error survives pickling (benchmark workers send errors across processes)
    err = NumericallyDisconnectedGraphError("msg", 3, 1, [10])
    back = pickle.loads(pickle.dumps(err))
    assert str(back) == "msg" and back.n_null == 3


def test_knn_connectivity_on_a_mesh_is_honoured_or_refused(sphere):
    g = build_graph(sphere, "gaussian", connectivity="knn", n_neighbors=8)
    assert g.info["connectivity"] == "knn"
    assert g.n_edges == len(knn_edges(sphere.vertices, 8)) != len(sphere.edges)
    g = build_graph(sphere, "binary", connectivity="knn", n_neighbors=8)
    assert g.n_edges == len(knn_edges(sphere.vertices, 8))
    with pytest.raises(ParameterError, match="cannot use connectivity='knn'.*intrinsic-delaunay"):
        build_graph(sphere, "cotangent", connectivity="knn")
    with pytest.raises(ParameterError, match="cannot use connectivity='epsilon'"):
        build_graph(sphere, "cotangent", connectivity="epsilon", radius=0.3)
    with pytest.raises(ParameterError, match="cannot use connectivity='epsilon'"):
        build_graph(sphere, "intrinsic-delaunay", connectivity="epsilon", radius=0.3)
    # intrinsic Delaunay honours knn by treating the vertices as a point cloud
    gk = build_graph(sphere, "intrinsic-delaunay", connectivity="knn", n_neighbors=12)
    cloud = build_graph(Shape(sphere.vertices), "intrinsic-delaunay", n_neighbors=12)
    assert gk.info["connectivity"] == "knn" and gk.params["n_neighbors"] == 12
    np.testing.assert_allclose(gk.W.toarray(), cloud.W.toarray())
    np.testing.assert_allclose(gk.mass, cloud.mass)
    assert build_graph(sphere, "intrinsic-delaunay").info["connectivity"] == "mesh"


def test_multi_component_errors_name_the_options():
    a, b = icosphere(2), icosphere(1)
    two = Shape(np.vstack([a.vertices, b.vertices + [5.0, 0, 0]]), np.vstack([a.faces, b.faces + a.n_vertices]))
    for weighting in ("gaussian", "cotangent", "intrinsic-delaunay", "binary"):
        with pytest.raises(DisconnectedGraphError, match="2 connected components") as exc:
            compute_spectrum(build_graph(two, weighting), 5)
        msg = str(exc.value)
        assert "components='largest'" in msg and "component_spectra" in msg and "keep_largest_component" in msg
    back = pickle.loads(pickle.dumps(exc.value))
    assert str(back) == msg and back.sizes == [a.n_vertices, b.n_vertices]
    assert "lie on another vertex" not in msg  # two pieces apart: nothing to weld


def test_an_unwelded_mesh_is_told_to_merge_its_vertices():
    """A triangle soup (every face with its own three corners, as an STL or a careless export) is 1,280 pieces of
    three vertices: keeping the largest would keep one triangle. The error counts the vertices that lie on another
    one and names the cleanup that merges them, which gives the sphere's spectrum back."""
    from shape_toolkit.core.cleanup import clean_shape
    from shape_toolkit.spectra import SpectrumSpec

    s = icosphere(3)
    corners = np.asarray(s.vertices)[np.asarray(s.faces)].reshape(-1, 3)
    soup = Shape(corners, np.arange(len(corners)).reshape(-1, 3), "soup")
    with pytest.raises(DisconnectedGraphError, match="1280 connected components") as exc:
        SpectrumSpec(k=5).compute(soup)
    msg = str(exc.value)
    assert f"{len(corners) - s.n_vertices} vertices lie on another vertex" in msg and "shape-toolkit clean" in msg
    assert exc.value.coincident == len(corners) - s.n_vertices and "'soup' (3840 vertices)" in msg
    assert pickle.loads(pickle.dumps(exc.value)).coincident == exc.value.coincident
    welded = clean_shape(soup)[0]
    np.testing.assert_allclose(SpectrumSpec(k=5).compute(welded).eigenvalues[1:4], 2.0, rtol=0.01)


def test_binary_trace_is_mean_neighbourhood_size_eq_3_8(sphere):
    g = build_graph(sphere, "binary")
    L = laplacian_matrix(g.W)
    valence = np.bincount(sphere.edges.ravel(), minlength=sphere.n_vertices)
    assert L.diagonal().sum() / sphere.n_vertices == pytest.approx(valence.mean())
    assert L.diagonal().sum() / sphere.n_vertices == pytest.approx(2 * len(sphere.edges) / 642)


def test_laplacian_relations_eq_2_66_to_2_68(sphere):
    W = build_graph(sphere, "gaussian").W
    d = np.asarray(W.sum(1)).ravel()
    L, Ln, Lr = (laplacian_matrix(W, k).toarray() for k in ("combinatorial", "normalized", "random-walk"))
    Dh = np.diag(np.sqrt(d))
    np.testing.assert_allclose(L, Dh @ Ln @ Dh, atol=1e-12)
    np.testing.assert_allclose(L, np.diag(d) @ Lr, atol=1e-12)
    np.testing.assert_allclose(L.sum(axis=1), 0.0, atol=1e-12)
    with pytest.raises(ParameterError):
        laplacian_matrix(W, "signless")


@pytest.mark.parametrize("kind", ["combinatorial", "normalized", "random-walk"])
def test_spectra_match_dense_solution(kind):
    shape = icosphere(2)  # 162 vertices, dense reference is cheap
    g = build_graph(shape, "gaussian")
    spec = compute_spectrum(g, 12, laplacian=kind, cache=False)
    W = g.W.toarray()
    d = W.sum(1)
    L = np.diag(d) - W
    ref = la.eigh(L, None if kind == "combinatorial" else np.diag(d), eigvals_only=True)[:12]
    np.testing.assert_allclose(spec.eigenvalues, ref, atol=1e-9, rtol=1e-7)
    U = spec.eigenvectors
    if kind == "combinatorial":
        np.testing.assert_allclose(U.T @ U, np.eye(12), atol=1e-8)
        np.testing.assert_allclose(L @ U, U * spec.eigenvalues, atol=1e-8)
    elif kind == "normalized":
        Ln = laplacian_matrix(g.W, "normalized").toarray()
        np.testing.assert_allclose(Ln @ U, U * spec.eigenvalues, atol=1e-8)
        np.testing.assert_allclose(U.T @ U, np.eye(12), atol=1e-8)
    else:  # random walk: t_i^T D t_j = delta_ij (Table 2.1) and D^-1 L t = lambda t
        np.testing.assert_allclose(U.T @ (d[:, None] * U), np.eye(12), atol=1e-8)
        np.testing.assert_allclose((L @ U) / d[:, None], U * spec.eigenvalues, atol=1e-8)
        np.testing.assert_allclose(U[:, 0] / U[0, 0], 1.0, atol=1e-8)  # t_1 = 1 (up to scale)


def test_large_sparse_path_matches_dense():
    shape = icosphere(3)  # 642 vertices: the sparse solver is used
    g = build_graph(shape, "binary")
    spec = compute_spectrum(g, 20, cache=False)
    ref = la.eigh(laplacian_matrix(g.W).toarray(), eigvals_only=True)[:20]
    np.testing.assert_allclose(spec.eigenvalues, ref, atol=1e-8)
    assert np.all(np.diff(spec.eigenvalues) >= -1e-10)


def test_proposition_1_2_3_and_theorem_3(sphere):
    from shape_toolkit.features.embedding import commute_time_embedding

    g = build_graph(sphere, "gaussian")
    spec = compute_spectrum(g, 12)
    U = spec.eigenvectors[:, 1:]
    n = sphere.n_vertices
    np.testing.assert_allclose(U.sum(axis=0), 0.0, atol=1e-8)  # eq. 2.81 / 2.86
    assert np.all(np.abs(U) < 1)  # eq. 2.82
    np.testing.assert_allclose((U**2).mean(axis=0), 1.0 / n, rtol=1e-8)  # eq. 2.87
    assert spec.eigenvalues.max() <= 2 * g.degrees.max()  # Proposition 2
    X = commute_time_embedding(spec)  # Theorem 3: zero mean, covariance Lambda^-1 / n
    np.testing.assert_allclose(X.mean(axis=0), 0.0, atol=1e-8)
    cov = X.T @ X / n
    np.testing.assert_allclose(cov, np.diag(1.0 / spec.eigenvalues[1:]) / n, atol=1e-8)
    lim = 1 / np.sqrt(spec.eigenvalues[1:])  # eq. 2.93
    assert np.all(np.abs(X) < lim)


def test_spectrum_invariant_to_permutation_rigid_motion_and_sign(sphere):
    shape = articulated_shape(random_state=2, subdivisions=3).shape
    spec = compute_spectrum(build_graph(shape, "cotangent"), 10, sign_fix=True, cache=False)
    perm = np.random.default_rng(0).permutation(shape.n_vertices)
    inv = np.argsort(perm)
    moved = Shape(shape.vertices[perm] @ _rotation(1).T * 1.0 + [3.0, -1.0, 2.0], inv[shape.faces])
    spec2 = compute_spectrum(build_graph(moved, "cotangent"), 10, sign_fix=True, cache=False)
    np.testing.assert_allclose(spec2.eigenvalues, spec.eigenvalues, rtol=1e-7, atol=1e-9)
    # the spectrum of this asymmetric pose is simple: sign fixing gives identical vectors
    gaps = np.diff(spec.eigenvalues)[1:]
    assert gaps.min() > 1e-3
    np.testing.assert_allclose(spec2.eigenvectors, spec.eigenvectors[perm], atol=1e-6)


def test_fix_signs_is_sign_invariant():
    rng = np.random.default_rng(0)
    U = rng.normal(size=(50, 4))
    flipped = U * np.array([1, -1, -1, 1])
    np.testing.assert_array_equal(fix_signs(U), fix_signs(flipped))


def test_disconnected_graph_is_refused_or_split():
    a, b = icosphere(2), icosphere(1)
    two = Shape(
        np.vstack([a.vertices, b.vertices + [5.0, 0, 0]]),
        np.vstack([a.faces, b.faces + a.n_vertices]),
    )
    g = build_graph(two, "binary")
    with pytest.raises(DisconnectedGraphError, match="2 connected components"):
        compute_spectrum(g, 5)
    spec = compute_spectrum(g, 5, components="largest")
    assert np.array_equal(spec.meta["vertices"], np.arange(a.n_vertices))
    ref = compute_spectrum(build_graph(a, "binary"), 5).eigenvalues
    np.testing.assert_allclose(spec.eigenvalues, ref, atol=1e-9)
    parts = component_spectra(g, 5)
    assert [len(ids) for ids, _ in parts] == [a.n_vertices, b.n_vertices]
    assert all(abs(s.eigenvalues[0]) < 1e-9 for _, s in parts)


def test_bad_parameters_raise_typed_errors(sphere):
    g = build_graph(sphere, "binary")
    for k in (0, -3, sphere.n_vertices + 1):
        with pytest.raises(ParameterError):
            compute_spectrum(g, k)
    with pytest.raises(ParameterError, match="unknown Laplacian"):
        compute_spectrum(g, 4, laplacian="magnetic")
    with pytest.raises(ParameterError, match="no mass"):
        compute_spectrum(g, 4, use_mass=True)
    with pytest.raises(PluginError, match="available: binary, cotangent"):
        build_graph(sphere, "nope")
    with pytest.raises(ParameterError, match="no parameter"):
        build_graph(sphere, "binary", sigma=2)
    cloud = Shape(sphere.vertices)
    with pytest.raises(InvalidShapeError, match="needs a triangle mesh"):
        build_graph(cloud, "cotangent")
    with pytest.raises(ParameterError):
        build_graph(sphere, "binary", connectivity="voxels")


def test_point_cloud_graphs(sphere):
    cloud = Shape(sphere.vertices)
    e = knn_edges(cloud.vertices, 6)
    assert (e[:, 0] < e[:, 1]).all() and len(np.unique(e, axis=0)) == len(e)
    g = build_graph(cloud, "gaussian", n_neighbors=6)
    assert g.info["connectivity"] == "knn" and g.components[0] == 1
    eps = epsilon_edges(cloud.vertices, 0.2)
    d = np.linalg.norm(cloud.vertices[eps[:, 0]] - cloud.vertices[eps[:, 1]], axis=1)
    assert (d < 0.2).all()
    spec = compute_spectrum(build_graph(cloud, "intrinsic-delaunay"), 10)
    ref = compute_spectrum(build_graph(sphere, "cotangent"), 10)
    np.testing.assert_allclose(spec.eigenvalues[1:4], ref.eigenvalues[1:4], rtol=0.05)



def _sphere_cloud(n: int, radius: float, random_state: int) -> np.ndarray:
    """``n`` points ``(n, 3)`` uniform in area on a sphere of ``radius`` about the origin (not a mesh's vertices)."""
    p = np.random.default_rng(random_state).normal(size=(n, 3))
    return radius * p / np.linalg.norm(p, axis=1, keepdims=True)


def test_a_random_sphere_cloud_has_the_laplace_beltrami_eigenvalues():
    """The point-cloud Laplacian (local Delaunay, Sharp and Crane 2020) of 3,000 points uniform in area on a
    sphere of radius 2, off the origin: eigenvalues l (l + 1) / r^2 with multiplicity 2 l + 1, total mass
    4 pi r^2. Measured: the mass within 0.1 %, the eigenvalues about 6 % low (the same for l = 1, 2, 3)."""
    r = 2.0
    spec = compute_spectrum(build_graph(Shape(_sphere_cloud(3000, r, 0) + 10.0), "intrinsic-delaunay"), 16)
    exact = np.repeat([l * (l + 1) / r**2 for l in range(4)], [2 * l + 1 for l in range(4)])
    assert abs(spec.eigenvalues[0]) < 1e-8
    np.testing.assert_allclose(spec.eigenvalues[1:], exact[1:], rtol=0.08)
    ratio = spec.eigenvalues[1:] / exact[1:]
    assert np.ptp(ratio) < 0.02  # a uniform scale, no distortion between the degrees
    assert spec.mass.sum() == pytest.approx(4 * np.pi * r**2, rel=0.01)


def test_a_cloud_laplacian_does_not_depend_on_the_order_or_the_pose_of_the_points():
    """Permuting the points, rotating or moving the cloud leaves its spectrum as it was. (The weights
    themselves differ by a few % where the local triangulations have ties, which the library breaks by
    order.) Without the centring, moving the cloud by 1.6 times its size changed the eigenvalues by 22 %."""
    pts = articulated_shape(subdivisions=3, random_state=0).shape.vertices

    def spectrum(p: np.ndarray) -> np.ndarray:
        return compute_spectrum(build_graph(Shape(p), "intrinsic-delaunay"), 12, cache=False).eigenvalues[1:]

    base = spectrum(pts)
    perm = np.random.default_rng(1).permutation(len(pts))
    np.testing.assert_allclose(spectrum(pts[perm]), base, rtol=1e-2)
    np.testing.assert_allclose(spectrum(pts + np.array([3.0, -1.0, 7.0])), base, rtol=1e-2)
    q, _ = np.linalg.qr(np.random.default_rng(2).normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    np.testing.assert_allclose(spectrum(pts @ q.T + np.array([3.0, -1.0, 7.0])), base, rtol=2e-2)


def test_a_cloud_laplacian_does_not_link_the_two_faces_of_a_thin_part():
    """A thin ellipsoid (1 : 1 : 0.07, 5,000 points; its faces about three point spacings apart, closer than the
    30th neighbour): the default point-cloud Laplacian triangulates each point's own sheet, so away from the
    rim (almost) no weight joins the upper face to the lower one; all 30 neighbours (robust_laplacian) join
    them by thousands (measured: 1 against 3,093)."""
    pts = _sphere_cloud(5000, 1.0, 3) * np.array([1.0, 1.0, 0.07])
    inner = np.hypot(pts[:, 0], pts[:, 1]) < 0.8
    up, down = np.flatnonzero(inner & (pts[:, 2] > 0)), np.flatnonzero(inner & (pts[:, 2] < 0))
    sheet = build_graph(Shape(pts), "intrinsic-delaunay")
    joined = build_graph(Shape(pts), "intrinsic-delaunay", cloud_neighbors="all")
    assert sheet.components[0] == 1 and joined.W[up][:, down].nnz > 1000
    assert sheet.W[up][:, down].nnz <= 0.01 * joined.W[up][:, down].nnz

def test_cache_in_memory_and_on_disk(sphere, tmp_path):
    set_cache_dir(None)
    clear_cache()
    g = build_graph(sphere, "binary")
    assert not is_cached(g, 6)
    s1 = compute_spectrum(g, 6)
    assert is_cached(g, 6) and not is_cached(g, 6, laplacian="normalized")
    assert compute_spectrum(build_graph(sphere, "binary"), 6) is s1  # same content, same object
    set_cache_dir(tmp_path)
    try:
        s2 = compute_spectrum(g, 7)
        assert len(list(tmp_path.glob("*.npz"))) == 1
        clear_cache()
        s3 = compute_spectrum(g, 7)
        assert s3 is not s2
        np.testing.assert_array_equal(s3.eigenvectors, s2.eigenvectors)
    finally:
        set_cache_dir(None)


def test_spectrum_save_load_roundtrip(sphere, tmp_path):
    spec = compute_spectrum(build_graph(sphere, "cotangent"), 5)
    spec.save(tmp_path / "s.npz")
    back = Spectrum.load(tmp_path / "s.npz")
    np.testing.assert_array_equal(back.eigenvalues, spec.eigenvalues)
    np.testing.assert_array_equal(back.mass, spec.mass)
    assert back.laplacian == "combinatorial" and back.weighting == "cotangent"


def test_graph_repr_and_hash(sphere):
    g = build_graph(sphere, "binary")
    assert "642 vertices" in repr(g) and g.n_edges == len(sphere.edges)
    h = ShapeGraph(sphere, sp.csr_matrix(g.W * 2.0)).content_hash
    assert h != g.content_hash


def test_point_cloud_with_coincident_points_is_refused_not_crashed():
    from shape_toolkit.errors import InvalidShapeError

    pts = np.random.default_rng(0).normal(size=(60, 3))
    pts[10:20] = pts[0]  # ten copies of one point: geometry-central would abort
    with pytest.raises(InvalidShapeError, match="coincide"):
        build_graph(Shape(pts), "intrinsic-delaunay")


def test_a_planted_cache_file_is_validated_not_trusted(tmp_path, sphere):
    from shape_toolkit.core import spectrum as spm

    spm.set_cache_dir(tmp_path)
    try:
        g = build_graph(sphere, "cotangent")
        good = compute_spectrum(g, 6)
        (f,) = list(tmp_path.glob("*.npz"))
        np.savez(f, eigenvalues=np.zeros(3), eigenvectors=np.zeros((5, 2)), laplacian="combinatorial",
                 weighting="cotangent", mass=np.zeros(0), degrees=np.zeros(5), sign_fixed=False)
        spm.clear_cache()
        with pytest.warns(spm.CacheWarning):  # the inconsistent file is a miss: recomputed, reported
            again = compute_spectrum(g, 6)
        np.testing.assert_allclose(again.eigenvalues, good.eigenvalues, atol=1e-10)
    finally:
        spm.set_cache_dir(None)
        spm.clear_cache()


def test_a_flat_triangle_is_left_out_of_the_cotangent_weights():
    """A zero-area face (one vertex on the opposite edge, as a remesher left on a 100k scan) has no
    defined cotangent stiffness: with it in, weights reached 5e8 and the eigensolver crawled for
    minutes. It is left out, and the spectrum stays that of the surface."""
    from shape_toolkit.data.generate import icosphere

    sphere = icosphere(3)
    v, f = np.array(sphere.vertices), np.array(sphere.faces)
    a, b, c = f[0]
    v[c] = (v[a] + v[b]) / 2  # face 0 is now a segment
    flat = Shape(v, f, "flat")
    g = build_graph(flat, "cotangent")
    assert g.info["degenerate_faces_skipped"] == 1
    assert np.abs(g.W.data).max() < 1e3
    vals = compute_spectrum(g, 10).eigenvalues
    ref = compute_spectrum(build_graph(sphere, "cotangent"), 10).eigenvalues
    np.testing.assert_allclose(vals[1:4], ref[1:4], rtol=0.05)  # l(l+1) = 2 on the unit sphere, nearly


def test_core_build_graph_takes_a_weighting_object_and_the_facade_resolves_names(sphere4):
    from shape_toolkit.core.graph import build_graph as core_build_graph
    from shape_toolkit.plugins.weightings.cotangent import CotangentWeighting

    by_name = build_graph(sphere4, "cotangent")
    by_object = core_build_graph(sphere4, CotangentWeighting(), name="cotangent")
    assert by_object.weighting == by_name.weighting == "cotangent"
    assert by_object.content_hash == by_name.content_hash
    assert core_build_graph(sphere4, CotangentWeighting()).weighting == "CotangentWeighting"
    with pytest.raises(ParameterError, match="weighting object"):
        core_build_graph(sphere4, "cotangent")


def test_declared_spectra_have_one_eigenpair_per_analysed_vertex():
    """The one k rule (compute_declared, SpectrumSpec.compute, the benchmark's cached spectra): the solver
    returns all n eigenpairs of an n-vertex graph, so k is capped at n, not n - 1; with
    components='largest', at the largest component's size."""
    from shape_toolkit.bench.tasks import compute_spectrum_cached, received_spec
    from shape_toolkit.spectra import SpectrumSpec, compute_declared

    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    tet = Shape(corners, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    spec = SpectrumSpec(10, "binary", "combinatorial", False)
    (spectrum,) = compute_declared(tet, [spec])
    assert spectrum.k == tet.n_vertices == 4
    assert compute_spectrum_cached(spec, tet)[0].k == 4
    assert received_spec(spec, tet)["k"] == 4
    two = Shape(np.r_[tet.vertices, tet.vertices[:3] + 5.0], np.r_[tet.faces, [[4, 5, 6]]])
    assert compute_declared([two], [spec], components="largest")[0][0].k == 4


def test_compute_spectrum_takes_a_solver_object(sphere):
    from shape_toolkit.core.eigen import EigenSolver

    g = build_graph(sphere, "cotangent")  # 642 vertices: the dense solve of 2,562 took 2 s
    clear_cache()
    default = compute_spectrum(g, 12)
    assert compute_spectrum(g, 12, solver=EigenSolver()) is default  # the default solver: the same cache entry
    assert not is_cached(g, 12, solver=EigenSolver(method="dense"))
    dense = compute_spectrum(g, 12, solver=EigenSolver(method="dense"))
    assert dense is not default and is_cached(g, 12, solver=EigenSolver(method="dense"))
    np.testing.assert_allclose(dense.eigenvalues, default.eigenvalues, rtol=1e-6, atol=1e-9)
    calls = []

    def counting(A, k, M=None):
        calls.append(k)
        return EigenSolver()(A, k, M)

    compute_spectrum(g, 5, solver=counting, cache=False)
    assert calls == [5]
    with pytest.raises(ParameterError, match="method must be one of"):
        EigenSolver(method="lobpcg")


def test_core_build_graph_leaves_the_callers_weighting_object_alone():
    from shape_toolkit.core.graph import build_graph as core_build_graph
    from shape_toolkit.plugins.weightings.intrinsic_delaunay import IntrinsicDelaunayWeighting

    scheme = IntrinsicDelaunayWeighting()
    before = scheme.get_params()
    g = core_build_graph(icosphere(2), scheme, name="intrinsic-delaunay", connectivity="knn", n_neighbors=7)
    assert scheme.get_params() == before and g.params["n_neighbors"] == 7


def test_a_disconnected_shape_is_named_in_the_error(tmp_path, capsys):
    """Of two shapes matched, the one in pieces is named (by the spectrum spec that computes its spectrum), at full
    resolution and through proxies (the proxy's name says so); the named error still pickles (Dask workers)."""
    from shape_toolkit.cli import main
    from shape_toolkit.io.mesh import save_shape
    from shape_toolkit.spectra import default_spec

    s = icosphere(3)
    two = Shape(np.vstack([s.vertices, s.vertices + 3.0]), np.vstack([s.faces, s.faces + s.n_vertices]), "two")
    with pytest.raises(DisconnectedGraphError, match=r"of 'two' \(1284 vertices\) has 2 connected components") as e:
        default_spec(10).compute(two)
    back = pickle.loads(pickle.dumps(e.value))
    assert str(back) == str(e.value) and back.shape == e.value.shape and back.sizes == [642, 642]
    save_shape(s, tmp_path / "one.off")
    save_shape(two, tmp_path / "two.off")
    for extra, named in (["--proxy", "0"], "'two' (1284 vertices)"), (["--proxy", "500"], "'two-proxy'"):
        code = main(["match", str(tmp_path / "one.off"), str(tmp_path / "two.off"), "-q", "-o",
                     str(tmp_path / "m.txt"), *extra])
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1 and f"of {named}" in err and "clean --keep-largest" in err, err


@pytest.mark.parametrize("where", ["first", "last"])
def test_vertices_on_no_face_are_reported_wherever_they_are(where):
    """libigl sizes the Voronoi mass by the largest vertex id of a face: a last vertex on no face (or only on flat
    ones) once gave a mass vector one short and the error "returned an invalid mass vector". Wherever the vertex is,
    the cotangent mass has one entry per vertex (zero there), and the spectrum names the cleanup."""
    from shape_toolkit.data.generate import icosphere

    sphere = icosphere(2)
    v, f = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    far = np.array([[5.0, 5.0, 5.0], [6.0, 5.0, 5.0], [7.0, 5.0, 5.0]])  # collinear: a flat face
    if where == "first":
        shape = Shape(np.vstack([far, v]), np.vstack([f + 3, [[0, 1, 2]]]))
    else:
        n = len(v)
        shape = Shape(np.vstack([v, far]), np.vstack([f, [[n, n + 1, n + 2]]]))
    g = build_graph(shape, "cotangent")
    assert g.mass.shape == (shape.n_vertices,) and np.sum(g.mass == 0) == 3
    with pytest.raises(ParameterError, match=r"3 vertices have zero mass .*shape-toolkit clean"):
        compute_spectrum(g, 6)
