"""Embeddings and the choice of their dimension (thesis 2.6.4-2.6.6)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as la
import scipy.sparse as sp

from shape_toolkit import ParameterError, Shape, build_graph, compute_spectrum
from shape_toolkit.core.graph import ShapeGraph
from shape_toolkit.data.generate import icosphere
from shape_toolkit.features.embedding import (
    choose_dimension,
    commute_time_distance,
    commute_time_embedding,
    laplacian_eigenmap,
    scree_theta,
    theta_min,
)


def _full(shape: Shape):
    g = build_graph(shape, "gaussian")
    return g, compute_spectrum(g, shape.n_vertices, cache=False)


def test_commute_time_distance_equals_pseudo_inverse_formula_eq_2_90():
    shape = icosphere(1)  # 42 vertices: the full spectrum is available
    g, spec = _full(shape)
    L = np.diag(g.degrees) - g.W.toarray()
    Lp = la.pinvh(L)
    vol = g.degrees.sum()
    i, j = 3, 17
    ref = np.sqrt(vol * (Lp[i, i] + Lp[j, j] - 2 * Lp[i, j]))
    assert commute_time_distance(spec, i, j)[0, 0] == pytest.approx(ref, rel=1e-8)
    D = commute_time_distance(spec, [0, 1, 2])
    assert D.shape == (3, shape.n_vertices) and D[1, 1] == pytest.approx(0, abs=1e-6)


def test_commute_time_distance_satisfies_triangle_inequality():
    _, spec = _full(icosphere(1))
    D = commute_time_distance(spec, np.arange(42))
    assert np.all(D[:, :, None] <= D[:, None, :] + D.T[None, :, :] + 1e-9)


def test_scree_bound_eq_2_98_holds():
    _, spec = _full(icosphere(1))
    lam, n = spec.eigenvalues, spec.n_vertices
    for K in (1, 3, 10, 30):
        assert theta_min(lam, K, n) <= scree_theta(lam, K) + 1e-12 <= 1 + 1e-12
    K = choose_dimension(spec, 0.95)
    assert theta_min(lam, K, n) >= 0.95 > theta_min(lam, K - 1, n) if K > 1 else True
    with pytest.raises(ParameterError):
        choose_dimension(spec.truncated(3), 0.999)


def test_eigenmap_skips_null_vector_and_checks_dim(sphere):
    spec = compute_spectrum(build_graph(sphere, "binary"), 6)
    Y = laplacian_eigenmap(spec, 3)
    np.testing.assert_allclose(Y, spec.eigenvectors[:, 1:4])
    X = commute_time_embedding(spec, 3)
    np.testing.assert_allclose(X * np.sqrt(spec.eigenvalues[1:4]), Y)
    with pytest.raises(ParameterError, match="compute a larger spectrum"):
        laplacian_eigenmap(spec, 6)
    with pytest.raises(ParameterError):
        commute_time_distance(spec, [sphere.n_vertices])


def test_path_graph_eigenvalues_analytic():
    # combinatorial Laplacian of a path: lambda_k = 2 - 2 cos(pi k / n)
    n = 400
    W = sp.diags([np.ones(n - 1), np.ones(n - 1)], [-1, 1], format="csr")
    g = ShapeGraph(Shape(np.c_[np.arange(n), np.zeros(n), np.zeros(n)].astype(float)), W)
    spec = compute_spectrum(g, 8, cache=False)
    np.testing.assert_allclose(spec.eigenvalues, 2 - 2 * np.cos(np.pi * np.arange(8) / n), atol=1e-10)
