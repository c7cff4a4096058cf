"""Heat kernel (thesis ch. 6): identities on tiny graphs with complete spectra, limits of the
normalized embeddings, scale/dimension selection, invariances, error cases."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla
import scipy.sparse as sp

from shape_toolkit.core.graph import ShapeGraph
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum, compute_spectrum
from shape_toolkit.errors import ParameterError
from shape_toolkit.features import heat, scales
from shape_toolkit.features.descriptor_score import descriptor_matching_score


# -- tiny graphs with complete spectra ----------------------------------------------------------
def _cycle(n: int) -> np.ndarray:
    W = np.zeros((n, n))
    for i in range(n):
        W[i, (i + 1) % n] = W[(i + 1) % n, i] = 1.0
    return W


def _path(n: int) -> np.ndarray:
    W = np.zeros((n, n))
    for i in range(n - 1):
        W[i, i + 1] = W[i + 1, i] = 1.0
    return W


def _random_graph(n: int = 14, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    W = np.zeros((n, n))
    for i in range(n - 1):  # a spanning path keeps it connected
        W[i, i + 1] = W[i + 1, i] = rng.uniform(0.5, 2.0)
    for _ in range(2 * n):
        i, j = rng.choice(n, 2, replace=False)
        W[i, j] = W[j, i] = rng.uniform(0.1, 2.0)
    return W


def _full_spectrum(W: np.ndarray, kind: str = "combinatorial") -> Spectrum:
    d = W.sum(1)
    L = np.diag(d) - W
    if kind == "normalized":
        L = L / np.sqrt(d)[:, None] / np.sqrt(d)[None, :]
    lam, U = np.linalg.eigh(L)
    lam[0] = max(lam[0], 0.0)
    return Spectrum(lam, U, kind, "test", None, d)


def _lap(W: np.ndarray, kind: str = "combinatorial") -> np.ndarray:
    d = W.sum(1)
    L = np.diag(d) - W
    if kind == "normalized":
        L = L / np.sqrt(d)[:, None] / np.sqrt(d)[None, :]
    return L


def _graph(W: np.ndarray, mass: np.ndarray | None = None) -> ShapeGraph:
    n = W.shape[0]
    rng = np.random.default_rng(1)
    shape = Shape(rng.normal(size=(n, 3)))
    return ShapeGraph(shape, sp.csr_matrix(W), mass, "test")


@pytest.mark.parametrize("kind", ["combinatorial", "normalized"])
def test_kernel_matches_matrix_exponential(kind):
    W = _random_graph()
    S = _full_spectrum(W, kind)
    L = _lap(W, kind)
    for t in (0.1, 1.0, 5.0):
        H = heat.heat_kernel(S, t, dense_ok=True, deflate=False)[0]
        np.testing.assert_allclose(H, sla.expm(-t * L), atol=1e-12)
        # deflated kernel (eq. 6.18): the null eigenpair removed
        Hd = heat.heat_kernel(S, t, dense_ok=True)[0]
        u1 = S.eigenvectors[:, 0]
        np.testing.assert_allclose(Hd, sla.expm(-t * L) - np.outer(u1, u1), atol=1e-12)


@pytest.mark.parametrize("kind", ["normalized", "random-walk"])
def test_kernel_from_compute_spectrum(kind):
    W = _random_graph(12, seed=3)
    S = compute_spectrum(_graph(W), 12, laplacian=kind, cache=False)
    H = heat.heat_kernel(S, 0.7, dense_ok=True, deflate=False)[0]
    np.testing.assert_allclose(H, sla.expm(-0.7 * _lap(W, "normalized")), atol=1e-9)


def test_generalized_kernel_is_a_density():
    W = _random_graph(10, seed=4)
    mass = np.random.default_rng(0).uniform(0.5, 2.0, 10)
    S = compute_spectrum(_graph(W, mass), 10, cache=False)
    assert S.generalized
    H = heat.heat_kernel(S, 0.3, dense_ok=True, deflate=False)[0]
    np.testing.assert_allclose(H @ mass, np.ones(10), atol=1e-9)
    np.testing.assert_allclose(H, H.T, atol=1e-12)


def test_symmetry_row_sums_and_subsets():
    W = _random_graph()
    S = _full_spectrum(W)
    H = heat.heat_kernel(S, [0.5, 2.0], dense_ok=True, deflate=False)
    np.testing.assert_allclose(H, H.transpose(0, 2, 1), atol=1e-13)
    np.testing.assert_allclose(H.sum(axis=2), 1.0, atol=1e-12)  # H 1 = 1 (combinatorial)
    Hd = heat.heat_kernel(S, [0.5, 2.0], dense_ok=True)
    np.testing.assert_allclose(Hd.sum(axis=2), 0.0, atol=1e-12)  # deflated: H u_1 = 0
    rows, cols = [3, 0, 7], [1, 5]
    sub = heat.heat_kernel(S, [0.5, 2.0], rows, cols)
    assert sub.shape == (2, 3, 2)
    np.testing.assert_allclose(sub, Hd[:, rows][:, :, cols], atol=1e-13)
    one_row = heat.heat_kernel(S, 1.0, rows=[2])
    assert one_row.shape == (1, 1, W.shape[0])


def test_trace_and_determinant_identities():
    W = _random_graph()
    S = _full_spectrum(W)
    L = _lap(W)
    t = np.array([0.2, 1.0, 3.0])
    hks = heat.heat_kernel_signature(S, t)
    tr = heat.heat_trace(S, t)
    np.testing.assert_allclose(hks.sum(axis=0), tr, rtol=1e-12)  # eq. 6.34
    np.testing.assert_allclose(tr, np.exp(-np.outer(t, S.eigenvalues[1:])).sum(1), rtol=1e-12)
    np.testing.assert_allclose(
        heat.heat_trace(S, t, deflate=False), [np.trace(sla.expm(-x * L)) for x in t], rtol=1e-10
    )
    # eq. 6.35: det H = prod_{k>=2} exp(-t lambda_k) = exp(-t tr L)
    np.testing.assert_allclose(heat.heat_log_determinant(S, t), -t * np.trace(L), rtol=1e-10)
    for x in t[:2]:  # direct check where expm's smallest eigenvalues are still accurate
        sign, logdet = np.linalg.slogdet(sla.expm(-x * L))
        assert sign > 0
        np.testing.assert_allclose(logdet, -x * np.trace(L), rtol=1e-6)


def test_hks_is_the_kernel_diagonal_and_invariant():
    W = _random_graph(16, seed=5)
    S = _full_spectrum(W)
    t = [0.3, 1.0, 4.0]
    H = heat.heat_kernel(S, t, dense_ok=True)
    hks = heat.heat_kernel_signature(S, t)
    np.testing.assert_allclose(hks, np.stack([np.diag(h) for h in H], axis=1), atol=1e-13)
    # eigenvector sign flips
    flips = np.where(np.arange(S.k) % 2 == 0, -1.0, 1.0)
    S2 = Spectrum(S.eigenvalues, S.eigenvectors * flips, S.laplacian, "t", None, S.degrees)
    np.testing.assert_allclose(heat.heat_kernel_signature(S2, t), hks, atol=1e-13)
    # vertex permutation
    perm = np.random.default_rng(2).permutation(16)
    S3 = _full_spectrum(W[perm][:, perm])
    np.testing.assert_allclose(heat.heat_kernel_signature(S3, t), hks[perm], atol=1e-10)
    # selected vertices, trace scaling
    np.testing.assert_allclose(heat.heat_kernel_signature(S, t, vertices=[4, 1]), hks[[4, 1]])
    scaled = heat.heat_kernel_signature(S, t, scale="trace")
    np.testing.assert_allclose(scaled.sum(axis=0), 1.0, rtol=1e-12)


def test_truncated_hks_matches_full_sum_over_K():
    W = _random_graph(20, seed=6)
    S = _full_spectrum(W)
    K = 5
    lam, U = S.eigenvalues[1 : K + 1], S.eigenvectors[:, 1 : K + 1]
    expect = (U**2) @ np.exp(-np.outer(lam, [0.5, 2.0]))
    np.testing.assert_allclose(heat.heat_kernel_signature(S, [0.5, 2.0], K=K), expect, rtol=1e-12)
    np.testing.assert_allclose(heat.heat_kernel_signature(S.truncated(K + 1), [0.5, 2.0]), expect)


# -- distances ----------------------------------------------------------------------------------
def test_heat_distances_match_kernel_formulas():
    W = _random_graph(15, seed=7)
    S = _full_spectrum(W)
    t, K = 0.8, 6
    H = heat.heat_kernel(S, t, dense_ok=True, K=K)[0]
    h = np.diag(H)
    src = [0, 4, 9]
    # eq. 6.30
    d = heat.heat_distance(S, t, src, K=K)
    expect = np.sqrt(np.maximum(h[src, None] + h[None, :] - 2 * H[src], 0))
    np.testing.assert_allclose(d, expect, atol=1e-7)
    # eq. 6.43
    ds = heat.heat_distance(S, t, src, normalization="unit-sphere", K=K)
    cos = H[src] / np.sqrt(h[src, None] * h[None, :])
    np.testing.assert_allclose(ds, np.arccos(np.clip(cos, -1, 1)), atol=1e-6)
    # eq. 6.52
    lam, U = S.eigenvalues[1 : K + 1], S.eigenvectors[:, 1 : K + 1]
    phi = np.exp(-t * lam) / np.exp(-t * lam).sum()
    dt = heat.heat_distance(S, t, src, [1, 2, 3], normalization="trace", K=K)
    expect_t = np.sqrt(((U[src][:, None, :] - U[[1, 2, 3]][None]) ** 2 * phi).sum(-1))
    np.testing.assert_allclose(dt, expect_t, atol=1e-7)
    # eq. 6.59 and the pseudo-inverse (6.56)
    dti = heat.heat_distance(S, t, src, normalization="time-invariant")
    Lp = np.linalg.pinv(_lap(W))
    g = np.diag(Lp)
    np.testing.assert_allclose(dti, np.sqrt(np.maximum(g[src, None] + g - 2 * Lp[src], 0)), atol=1e-6)
    multi = heat.heat_distances(S, [0.5, 0.8], src, K=K)
    assert multi.shape == (2, 3, 15)
    np.testing.assert_allclose(multi[1], d)


def test_time_invariant_embedding_is_the_green_function():
    W = _random_graph(12, seed=8)
    S = _full_spectrum(W)
    X = heat.time_invariant_embedding(S)
    np.testing.assert_allclose(X @ X.T, np.linalg.pinv(_lap(W)), atol=1e-10)
    cov = heat.heat_covariance(S, 1.0, K=3)
    np.testing.assert_allclose(np.diag(cov), np.exp(-S.eigenvalues[1:4]) / 12)


# -- normalized embeddings and their limits (6.5) -----------------------------------------------
@pytest.mark.parametrize("W, m", [(_path(10), 1), (_cycle(12), 2)])
def test_unit_sphere_limits(W, m):
    S = _full_spectrum(W)
    K = 6
    U = S.eigenvectors[:, 1 : K + 1]
    X0 = heat.unit_sphere_embedding(S, 1e-9, K)  # eq. 6.44
    np.testing.assert_allclose(X0, U / np.linalg.norm(U, axis=1, keepdims=True), atol=1e-6)
    Xinf = heat.unit_sphere_embedding(S, 500.0, K)  # eq. 6.46-6.47
    Um = U[:, :m]
    np.testing.assert_allclose(np.linalg.norm(Xinf, axis=1), 1.0, atol=1e-12)
    nz = np.linalg.norm(Um, axis=1) > 1e-8
    np.testing.assert_allclose(Xinf[nz, :m], (Um / np.linalg.norm(Um, axis=1, keepdims=True))[nz], atol=1e-8)
    np.testing.assert_allclose(Xinf[:, m:], 0.0, atol=1e-8)
    if m == 1:  # eq. 6.48: every vertex at +-(1, 0, ..., 0)
        np.testing.assert_allclose(np.abs(Xinf[:, 0]), 1.0, atol=1e-8)


@pytest.mark.parametrize("W, m", [(_path(10), 1), (_cycle(12), 2)])
def test_trace_scaled_limits(W, m):
    S = _full_spectrum(W)
    K = 6
    U = S.eigenvectors[:, 1 : K + 1]
    np.testing.assert_allclose(heat.trace_scaled_embedding(S, 1e-9, K), U / np.sqrt(K), atol=1e-6)  # 6.53
    Xinf = heat.trace_scaled_embedding(S, 500.0, K)  # eq. 6.54-6.55
    np.testing.assert_allclose(Xinf[:, :m], U[:, :m] / np.sqrt(m), atol=1e-10)
    np.testing.assert_allclose(Xinf[:, m:], 0.0, atol=1e-10)
    for t in (0.1, 3.0, 500.0):  # eq. 6.50
        X = heat.trace_scaled_embedding(S, t, K)
        np.testing.assert_allclose((X**2).sum(), 1.0, rtol=1e-12)


def test_large_time_does_not_underflow_normalized_distances():
    S = _full_spectrum(_path(10))
    d = heat.heat_distance(S, 1e6, [0], normalization="unit-sphere", K=4)
    assert np.all(np.isfinite(d))
    # m = 1: the two ends of the path go to opposite poles
    np.testing.assert_allclose(d[0, 9], np.pi, atol=1e-8)
    assert heat.heat_distance(S, 1e6, [0], K=4).max() < 1e-100  # the plain one collapses to 0


# -- scale and dimension (6.4) ------------------------------------------------------------------
def test_scree_alpha_exact_and_monotone():
    W = _random_graph(30, seed=9)
    S = _full_spectrum(W)
    lam = S.eigenvalues[1:]
    for K in (1, 5, 20):
        for t in (0.1, 1.0, 10.0):
            w = np.exp(-t * lam)
            assert scales.scree_alpha(S, K, t) == pytest.approx(w[:K].sum() / w.sum(), rel=1e-12)
    a = [scales.scree_alpha(S, 5, t) for t in np.geomspace(0.01, 100, 30)]
    assert np.all(np.diff(a) >= -1e-15)
    assert scales.scree_alpha(S.eigenvalues, 5, 1.0) == pytest.approx(scales.scree_alpha(S, 5, 1.0))


def test_truncated_scree_is_a_lower_bound():
    W = _random_graph(40, seed=10)
    S = _full_spectrum(W)
    T = S.truncated(12)
    for t in (0.5, 2.0, 8.0):
        for K in (2, 6, 11):
            assert scales.scree_alpha(T, K, t, n=40) <= scales.scree_alpha(S, K, t) + 1e-12
    assert scales.scree_alpha(T, 11, 3.0) == scales.scree_alpha(T, 11, 3.0, n=40)


def test_min_time_and_dimension_selection():
    S = _full_spectrum(_random_graph(30, seed=11))
    t = scales.min_time_for_dimension(S, 4, 0.95)
    assert scales.scree_alpha(S, 4, t) >= 0.95 - 1e-9
    assert scales.scree_alpha(S, 4, 0.99 * t) < 0.95
    K = scales.dimension_for_time(S, t, 0.95)
    assert K <= 4 and scales.scree_alpha(S, K, t) >= 0.95 - 1e-9
    if K > 1:
        assert scales.scree_alpha(S, K - 1, t) < 0.95
    K2 = scales.dimension_for_time(S, 0.5 * t)
    assert K2 >= K
    # rule of 7.3.1: K on the first shape, t from it, K' on the second
    S2 = _full_spectrum(_random_graph(30, seed=12))
    tp, Kp = scales.pair_scale(S, S2, K=4)
    assert tp == pytest.approx(t)
    assert Kp == scales.dimension_for_time(S2, t)


def test_fiedler_multiplicity_bounds_the_dimension():
    # on a cycle lambda_2 has multiplicity 2: alpha(1, t) -> 1/2, alpha(2, t) -> 1 (eq. 6.45)
    S = _full_spectrum(_cycle(12))
    assert scales.scree_alpha(S, 1, 200.0) == pytest.approx(0.5, abs=1e-8)
    assert scales.scree_alpha(S, 2, 200.0) == pytest.approx(1.0, abs=1e-8)
    with pytest.raises(ParameterError):
        scales.min_time_for_dimension(S, 1, 0.95)
    assert scales.dimension_for_time(S, 200.0) == 2
    assert scales.dimension_for_time(_full_spectrum(_path(10)), 200.0) == 1


def test_default_and_multiscale_times():
    S = _full_spectrum(_random_graph(20, seed=13))
    t = scales.default_times(S, 8)
    assert t.shape == (8,) and np.all(np.diff(np.log(t)) > 0)
    np.testing.assert_allclose(np.diff(np.log(t)), np.diff(np.log(t))[0])
    lam = S.eigenvalues[1:]
    assert t[0] == pytest.approx(4 * np.log(10) / lam[-1]) and t[-1] == pytest.approx(4 * np.log(10) / lam[0])
    mt = scales.multiscale_times(S, 5, 6)
    assert mt[0] == pytest.approx(scales.min_time_for_dimension(S, 6))
    np.testing.assert_allclose(mt[1:] / mt[:-1], 2.0)


# -- descriptor matching score (eq. 6.66) -------------------------------------------------------
def test_descriptor_matching_score():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(6, 3, 4))  # n = 6 vertices, M = 3 keypoints, tau = 4 scales
    b = a + 0.0
    b[2, 1, 3] += 0.5
    b[2, 0, 0] -= 0.25
    s = descriptor_matching_score(a, b)
    expect = np.abs(a - b).max(axis=2).sum(axis=1)
    np.testing.assert_allclose(s, expect)
    assert s[2] == pytest.approx(0.75) and s[0] == 0
    flat = descriptor_matching_score(a.reshape(6, 12), b.reshape(6, 12), [2, 0], [2, 0], n_times=4)
    np.testing.assert_allclose(flat, [0.75, 0.0])
    lst = descriptor_matching_score([a[:, m] for m in range(3)], [b[:, m] for m in range(3)])
    np.testing.assert_allclose(lst, s)
    P = descriptor_matching_score(a, b, [0, 1, 2], [0, 1, 2, 3], pairwise=True)
    assert P.shape == (3, 4)
    np.testing.assert_allclose(P[2, 2], 0.75)
    np.testing.assert_allclose(P[1, 3], np.abs(a[1] - b[3]).max(axis=1).sum())
    with pytest.raises(ParameterError):
        descriptor_matching_score(a.reshape(6, 12), b.reshape(6, 12))  # n_times missing
    with pytest.raises(ParameterError):
        descriptor_matching_score(a, b[:, :2])


# -- errors -------------------------------------------------------------------------------------
@pytest.mark.parametrize("bad", [-1.0, np.nan, np.inf, [1.0, -0.5], []])
def test_negative_or_non_finite_times_raise(bad):  # t = 0 is allowed (thesis 7.5): tests/test_thesis_presets.py
    S = _full_spectrum(_random_graph())
    with pytest.raises(ParameterError):
        heat.heat_kernel_signature(S, bad)
    with pytest.raises(ParameterError):
        heat.heat_kernel(S, bad, rows=[0])


def test_error_cases():
    S = _full_spectrum(_random_graph(14))
    with pytest.raises(ParameterError, match="K must be"):
        heat.heat_kernel_signature(S, 1.0, K=14)  # only 13 non-null eigenpairs
    with pytest.raises(ParameterError, match="K must be"):
        heat.heat_distance(S, 1.0, [0], K=0)
    with pytest.raises(ParameterError, match="n x n"):
        heat.heat_kernel(S, 1.0)
    with pytest.raises(ParameterError):
        heat.heat_kernel(S, 1.0, rows=[14])
    with pytest.raises(ParameterError):
        heat.heat_distance(S, 1.0, [-1])
    with pytest.raises(ParameterError):
        heat.heat_distance(S, 1.0, [0], normalization="bogus")
    with pytest.raises(ParameterError):
        scales.scree_alpha(S, 20, 1.0)
    with pytest.raises(ParameterError):
        scales.min_time_for_dimension(S, 3, 1.5)
    with pytest.raises(ParameterError):
        scales.dimension_for_time(S.truncated(3), 1e-6, n=14)  # spectrum too short


def test_dense_refusal_on_large_shapes():
    n = heat.DENSE_MAX_N + 1
    S = Spectrum(np.array([0.0, 1.0]), np.ones((n, 2)) / np.sqrt(n), "combinatorial", "t", None, np.ones(n))
    with pytest.raises(ParameterError, match="refusing"):
        heat.heat_kernel(S, 1.0, dense_ok=True)
    assert heat.heat_kernel(S, 1.0, rows=[0, 1]).shape == (1, 2, n)


def test_pair_times_share_scales():
    S1 = _full_spectrum(_random_graph(30, seed=14))
    S2 = _full_spectrum(_random_graph(30, seed=15))
    times, K1, K2 = scales.pair_times(S1, S2, K=5, n_times=4)
    np.testing.assert_allclose(times, scales.multiscale_times(S1, 4, 5))
    assert K1 == 5 and K2 == scales.dimension_for_time(S2, times[0])
    assert scales.scree_alpha(S2, K2, times[0]) >= 0.95 - 1e-9
