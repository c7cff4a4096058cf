"""Label smoothing by alpha-expansion on the dual graph (shape_toolkit.features.smoothing)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("maxflow")

from shape_toolkit.core.geometry import dual_graph  # noqa: E402
from shape_toolkit.core.shape import Shape  # noqa: E402
from shape_toolkit.errors import ParameterError  # noqa: E402
from shape_toolkit.features.smoothing import (  # noqa: E402
    alpha_expansion,
    concavity_weights,
    dihedral_edge_costs,
    dual_adjacency,
    potts_energy,
    smooth_labels,
)


def _grid(nx: int, ny: int, z=lambda x, y: 0.0 * x) -> Shape:
    """A triangulated height field over [0, 1] x [0, 1], normals +z."""
    xs, ys = np.meshgrid(np.linspace(0, 1, nx), np.linspace(0, 1, ny), indexing="ij")
    v = np.column_stack([xs.ravel(), ys.ravel(), z(xs, ys).ravel()])
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    f = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return Shape(v, f)


def _valley(nx=41, ny=11, x0=0.5):
    """A V-shaped valley (concave crease along x = x0, normals up)."""
    return _grid(nx, ny, lambda x, y: 0.6 * np.abs(x - x0))


def _ridge(nx=41, ny=11, x0=0.5):
    return _grid(nx, ny, lambda x, y: -0.6 * np.abs(x - x0))


def test_dual_graph_of_a_grid_and_of_a_non_manifold_edge():
    s = _grid(3, 3)
    pairs, edges, cons = dual_graph(s.faces)
    # interior edges of a 2x2-quad grid: 4 diagonals + 4 between quads = 8
    assert len(pairs) == 8 and cons.all()
    # three triangles around one edge: every pair is joined
    f = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    pairs, edges, cons = dual_graph(f)
    assert sorted(map(tuple, pairs)) == [(0, 1), (0, 2), (1, 2)]
    assert (edges == [0, 1]).all()


def test_concave_crease_is_cheap_and_convex_or_flat_expensive():
    cost_v, theta_v, concave_v = dihedral_edge_costs(_valley())
    cost_r, theta_r, concave_r = dihedral_edge_costs(_ridge())
    sharp_v = theta_v > 0.5
    sharp_r = theta_r > 0.5
    assert sharp_v.any() and concave_v[sharp_v].all() and not concave_r[sharp_r].any()
    flat = cost_v[theta_v < 1e-6]
    assert cost_v[sharp_v].max() < 1.5 < 3.0 < cost_r[sharp_r].min() < flat.min()


def test_speckled_labels_are_cleaned():
    s = _grid(31, 31)
    c = s.vertices[s.faces].mean(axis=1)
    truth = (c[:, 0] > 0.5).astype(int)
    rng = np.random.default_rng(0)
    noisy = truth.copy()
    flip = rng.random(len(truth)) < 0.15
    noisy[flip] = 1 - noisy[flip]
    out = smooth_labels(s, noisy, smoothing_lambda=0.5)
    assert (out != truth).mean() < 0.25 * (noisy != truth).mean()
    assert set(np.unique(out)) <= {0, 1}


def test_boundary_moves_to_the_concave_crease():
    s = _valley(x0=0.5)
    c = s.vertices[s.faces].mean(axis=1)
    shifted = (c[:, 0] > 0.56).astype(int)  # boundary 2 quad columns off the crease
    truth = (c[:, 0] > 0.5).astype(int)
    out = smooth_labels(s, shifted, smoothing_lambda=2.0, spread=6)
    assert (out != truth).mean() < 0.2 * (shifted != truth).mean()
    # on a flat sheet nothing pulls the boundary: it stays where it was
    flat = _grid(41, 11)
    out_flat = smooth_labels(flat, shifted, smoothing_lambda=2.0, spread=6)
    assert (out_flat != shifted).mean() < 0.05


def test_vertex_labels_and_vertex_order_invariance():
    s = _valley()
    c = s.vertices[s.faces].mean(axis=1)
    rng = np.random.default_rng(1)
    lab = (c[:, 0] > 0.55).astype(int) + 3
    lab[rng.random(len(lab)) < 0.1] = 7
    out = smooth_labels(s, lab, smoothing_lambda=0.8)
    assert set(np.unique(out)) <= {3, 7, 4}
    perm = rng.permutation(s.n_vertices)
    inv = np.argsort(perm)
    s2 = Shape(s.vertices[perm], inv[s.faces])
    np.testing.assert_array_equal(smooth_labels(s2, lab, smoothing_lambda=0.8), out)
    # face order too: labels follow their faces
    fp = rng.permutation(s.n_faces)
    s3 = Shape(s.vertices, s.faces[fp])
    np.testing.assert_array_equal(smooth_labels(s3, lab[fp], smoothing_lambda=0.8), out[fp])
    # vertex labels: converted by majority
    vl = (s.vertices[:, 0] > 0.5).astype(int)
    assert len(smooth_labels(s, vl, smoothing_lambda=0.5)) == s.n_faces


def test_alpha_expansion_lowers_the_energy_and_respects_the_unary_minimum():
    s = _grid(11, 11)
    pairs, _, _ = dual_graph(s.faces)
    rng = np.random.default_rng(2)
    unary = rng.random((s.n_faces, 3))
    w = np.full(len(pairs), 0.3)
    start = np.argmin(unary, axis=1)
    out = alpha_expansion(unary, pairs, w)
    assert potts_energy(unary, pairs, w, out) <= potts_energy(unary, pairs, w, start)
    np.testing.assert_array_equal(alpha_expansion(unary, pairs, np.zeros(len(pairs))), start)


def test_several_components_and_bad_input():
    a, b = _grid(6, 6), _grid(6, 6)
    s = Shape(np.vstack([a.vertices, b.vertices + [3, 0, 0]]), np.vstack([a.faces, b.faces + a.n_vertices]))
    lab = np.r_[np.zeros(a.n_faces, int), np.ones(b.n_faces, int)]
    np.testing.assert_array_equal(smooth_labels(s, lab, smoothing_lambda=5.0), lab)
    with pytest.raises(ParameterError):
        smooth_labels(s, lab[:-1])
    with pytest.raises(ParameterError):
        smooth_labels(s, lab, smoothing_lambda=-1)
    with pytest.raises(ParameterError):
        smooth_labels(s)


def test_concavity_weights_drop_across_a_concave_crease_only():
    # a step: concave crease at x = 0.3, convex crease of the same angle at x = 0.7, flat elsewhere
    step = _grid(41, 11, lambda x, y: 0.6 * np.abs(x - 0.3) - 0.6 * np.abs(x - 0.7))
    # sigma is relative to the mean angular distance, which is tiny on this piecewise-flat shape: a
    # larger concavity_scale keeps the convex crease above the floor
    pairs, w = concavity_weights(step, length_weighted=False, concavity_scale=20.0)
    _, theta, concave = dihedral_edge_costs(step)
    sharp = theta > 0.5
    flat = theta < 1e-6
    assert sharp.any() and flat.any() and concave[sharp].any() and not concave[sharp].all()
    cc, cx = sharp & concave, sharp & ~concave
    # 1 on flat parts, low across the concave crease, far higher across the convex one
    assert np.allclose(w[flat], 1.0)
    assert w[cc].max() < 0.05 and w[cx].min() > 10 * w[cc].max()
    # convex creases count like concave ones when convex_factor = 1
    _, w1 = concavity_weights(step, length_weighted=False, convex_factor=1.0, concavity_scale=20.0)
    assert np.allclose(w1[cx], w1[cc])
    # with the default scale both sharp creases of this shape are far above the mean: the floor
    _, w0 = concavity_weights(step, length_weighted=False)
    assert np.allclose(w0[sharp], 1e-3)
    # the floor bounds the contrast
    _, wf = concavity_weights(step, length_weighted=False, min_weight=0.05, concavity_scale=20.0)
    assert wf.min() >= 0.05 - 1e-12
    # edge lengths scale the affinities (relative to their mean)
    _, wl = concavity_weights(step, concavity_scale=20.0)
    assert not np.allclose(wl, w) and np.allclose(wl[flat].mean(), w[flat].mean(), rtol=0.3)


def test_concavity_weights_are_scale_invariant_and_validated():
    v = _valley()
    big = Shape(v.vertices * 250.0, v.faces)
    p1, w1 = concavity_weights(v)
    p2, w2 = concavity_weights(big)
    assert np.array_equal(p1, p2) and np.allclose(w1, w2)
    for bad in ({"concavity_scale": 0.0}, {"convex_factor": -0.1}, {"min_weight": 0.0}, {"min_weight": 2.0},
                {"concavity_scale": float("nan")}):
        with pytest.raises(ParameterError):
            concavity_weights(v, **bad)
    A = dual_adjacency(v.n_faces, p1, w1)
    assert A.shape == (v.n_faces, v.n_faces) and abs(A - A.T).max() == 0 and np.isclose(A.sum(), 2 * w1.sum())
