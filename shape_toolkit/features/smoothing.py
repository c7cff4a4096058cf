"""Label smoothing on a mesh's dual graph: alpha-expansion graph cuts with a concavity-aware boundary cost.

The faces are the nodes; two faces are neighbours when they share an edge (every pair of faces around a
non-manifold edge is joined, so meshes with several components or non-manifold edges need nothing
special: components simply share no dual edge). The energy of a face labelling ``l`` is

    E(l) = sum_f a_f D_f(l_f) + lambda * sum_{(f,g) dual edges, l_f != l_g} c_fg,

the Potts model of Shapira, Shamir and Cohen-Or (2008) and of CGAL's ``segmentation_from_sdf_values``:

- ``c_fg = -log(max(theta_fg / pi * s, eps))`` with ``theta_fg`` the angle between the two face normals
  (0 on flat parts), ``s = 1`` for a concave edge and ``s = convex_factor`` (0.08 as in CGAL) for a
  convex one: cutting along a sharp concave crease is almost free, across flat or convex parts it is
  expensive. With ``geometric`` weights (default) ``c_fg`` is multiplied by the shared edge length over
  the mean dual-edge length, and ``D_f`` by the face area over the mean face area, so the balance does
  not depend on the triangulation density.
- ``D_f(l)``: given unary costs (e.g. ``-log`` of GMM probabilities), or, from hard labels, ``-log`` of
  the label frequencies after ``spread`` steps of area-weighted averaging over the dual graph (a soft
  version of "keep your label" that lets a boundary slide a few rings toward a crease).

The minimisation is alpha-expansion (Boykov, Veksler and Zabih 2001) with the max-flow of PyMaxflow
(Kolmogorov's Boykov-Kolmogorov implementation). The dual graph, the costs and the expansion order
depend on the faces and the label values only, so renumbering the vertices changes nothing.

The same dual graph also carries *affinities* (:func:`concavity_weights`, :func:`dual_adjacency`) for
the segmenters that cut it (``ncut``) or diffuse labels over it (``seeded-walk``): Katz and Tal's angular
distance ``d_fg = eta (1 - cos theta_fg)`` (``eta = 1`` concave, ``convex_factor`` convex) turned into
``w_fg = l_fg max(exp(-d_fg / sigma), min_weight)`` with ``sigma = concavity_scale * mean(d)`` (Lai,
Hu, Martin and Rosin 2008 use ``concavity_scale = 1``) and ``l_fg`` the shared edge length over its
mean. Every factor is dimensionless, so the weights do not change with the shape's scale.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from shape_toolkit.core.geometry import dual_graph
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError

__all__ = [
    "dihedral_edge_costs",
    "concavity_weights",
    "relative_affinities",
    "dual_adjacency",
    "alpha_expansion",
    "potts_energy",
    "label_unary",
    "smooth_labels",
]

#: smallest probability / normalised angle before taking the log (CGAL's value)
EPS = 5e-6


def _opposite(faces: np.ndarray, fids: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """The vertex of each face ``fids[i]`` that is not on ``edges[i]``."""
    tri = faces[fids]
    on = (tri == edges[:, :1]) | (tri == edges[:, 1:])
    return tri[np.arange(len(tri)), np.argmin(on, axis=1)]


def dihedral_edge_costs(
    shape: Shape,
    pairs: np.ndarray | None = None,
    edges: np.ndarray | None = None,
    consistent: np.ndarray | None = None,
    *,
    convex_factor: float = 0.08,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Concavity-aware cut cost of every dual edge: ``-log(max(theta / pi * s, EPS))`` with ``theta``
    the angle between the face normals and ``s`` 1 (concave) or ``convex_factor`` (convex), as in CGAL.

    Returns ``(cost, theta, concave)``, each ``(p,)``. Inconsistently oriented neighbours have the
    second normal flipped first; an edge of a degenerate (zero-area) face counts as flat."""
    faces = shape.require_faces("dual-graph edge costs")
    if pairs is None or edges is None or consistent is None:
        pairs, edges, consistent = dual_graph(faces)
    n = np.asarray(shape.face_normals)
    n1 = n[pairs[:, 0]]
    n2 = n[pairs[:, 1]] * np.where(consistent, 1.0, -1.0)[:, None]
    v = shape.vertices / shape.scale
    c1 = v[_opposite(faces, pairs[:, 0], edges)]
    c2 = v[_opposite(faces, pairs[:, 1], edges)]
    theta = np.arccos(np.clip(np.einsum("ij,ij->i", n1, n2), -1.0, 1.0))
    degenerate = (np.abs(n1).sum(1) == 0) | (np.abs(n2).sum(1) == 0)
    theta[degenerate] = 0.0
    concave = np.einsum("ij,ij->i", c2 - c1, n1 - n2) > 0
    s = np.where(concave, 1.0, float(convex_factor))
    cost = -np.log(np.maximum(theta / np.pi * s, EPS))
    return cost, theta, concave


def concavity_weights(
    shape: Shape,
    *,
    concavity_scale: float = 1.0,
    convex_factor: float = 0.2,
    min_weight: float = 1e-3,
    length_weighted: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Concavity-aware affinities of the dual graph (see the module docstring).

    Returns ``pairs`` int64 ``(p, 2)`` (as :func:`dual_graph`) and ``weights`` float64 ``(p,)`` in
    ``(0, max edge length / mean edge length]``: about 1 across flat or smooth parts, down to
    ``min_weight`` (times the relative edge length) across sharp concave creases. ``min_weight > 0``
    bounds the contrast, so noise creases cannot cut a few faces off the graph numerically."""
    faces = shape.require_faces("dual-graph affinities")
    scale, cf, floor = float(concavity_scale), float(convex_factor), float(min_weight)
    if not np.isfinite(scale) or scale <= 0:
        raise ParameterError(f"concavity_scale must be finite and > 0, got {concavity_scale!r}")
    if not np.isfinite(cf) or cf < 0:
        raise ParameterError(f"convex_factor must be finite and >= 0, got {convex_factor!r}")
    if not np.isfinite(floor) or not 0 < floor <= 1:
        raise ParameterError(f"min_weight must be in (0, 1], got {min_weight!r}")
    pairs, edges, cons = dual_graph(faces)
    if len(pairs) == 0:
        return pairs, np.zeros(0)
    _, theta, concave = dihedral_edge_costs(shape, pairs, edges, cons)
    w = relative_affinities(np.where(concave, 1.0, cf) * (1.0 - np.cos(theta)), scale, floor)
    if length_weighted:
        v = shape.vertices / shape.scale
        ln = np.linalg.norm(v[edges[:, 0]] - v[edges[:, 1]], axis=1)
        if ln.mean() > 0:
            w = w * np.maximum(ln / ln.mean(), 1e-12)
    return pairs, w


def relative_affinities(d: np.ndarray, scale: float, floor: float) -> np.ndarray:
    """Affinities ``(p,)`` in ``[floor, 1]`` of edges with dissimilarities ``d`` ``(p,)`` (>= 0) relative to the
    shape's own: ``exp(-d / (scale * mean(d)))``, floored; all 1 where ``d`` is 0 everywhere. The construction of
    :func:`concavity_weights` and of ``ncut``'s thickness term."""
    sigma = float(scale) * float(d.mean()) if len(d) else 0.0
    w = np.exp(-d / sigma) if np.isfinite(sigma) and sigma > 0 else np.ones(len(d))
    return np.maximum(w, float(floor))


def dual_adjacency(n_faces: int, pairs: np.ndarray, weights: np.ndarray) -> sp.csr_matrix:
    """Symmetric ``(n_faces, n_faces)`` CSR adjacency of the dual graph with ``weights`` per pair."""
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    w = np.asarray(weights, dtype=np.float64).ravel()
    i, j = pairs[:, 0], pairs[:, 1]
    return sp.coo_matrix((np.r_[w, w], (np.r_[i, j], np.r_[j, i])), shape=(n_faces, n_faces)).tocsr()


def potts_energy(unary: np.ndarray, pairs: np.ndarray, weights: np.ndarray, labels: np.ndarray) -> float:
    """``sum_f unary[f, l_f] + sum_{(f,g): l_f != l_g} weights``."""
    labels = np.asarray(labels, dtype=np.int64)
    data = float(unary[np.arange(len(labels)), labels].sum())
    cut = labels[pairs[:, 0]] != labels[pairs[:, 1]]
    return data + float(weights[cut].sum())


def _expand(unary, pairs, weights, labels, alpha, maxflow):
    m = len(labels)
    g = maxflow.Graph[float](m, max(len(pairs), 1))
    nodes = g.add_nodes(m)
    u0 = unary[np.arange(m), labels].astype(np.float64)
    u1 = unary[:, alpha].astype(np.float64).copy()
    pi, pj = pairs[:, 0], pairs[:, 1]
    li, lj = labels[pi], labels[pj]
    A = weights * (li != lj)
    B = weights * (li != alpha)
    C = weights * (lj != alpha)
    # E(x_i, x_j) = A + (C - A) x_i - C x_j + (B + C - A) (1 - x_i) x_j, x = 1: switch to alpha
    np.add.at(u1, pi, C - A)
    np.add.at(u1, pj, -C)
    base = np.minimum(u0, u1)
    g.add_grid_tedges(nodes, u1 - base, u0 - base)  # source capacity = cost of ending on the sink side
    cap = np.maximum(B + C - A, 0.0)
    use = cap > 0
    if use.any():
        g.add_edges(pi[use].astype(np.int32), pj[use].astype(np.int32), cap[use], np.zeros(int(use.sum())))
    g.maxflow()
    switch = np.asarray(g.get_grid_segments(nodes), dtype=bool)
    return np.where(switch, alpha, labels)


def alpha_expansion(
    unary: np.ndarray,
    pairs: np.ndarray,
    weights: np.ndarray,
    labels: np.ndarray | None = None,
    *,
    max_sweeps: int = 10,
) -> np.ndarray:
    """Minimise the Potts energy :func:`potts_energy` by alpha-expansion (labels ``0..k-1`` =
    columns of ``unary`` ``(m, k)``; ``weights >= 0`` per dual edge). Starts from ``labels`` (default:
    the unary minimum); expands ``alpha = 0, 1, ..`` in turn and sweeps until no move lowers the energy.
    Each move is one max-flow (PyMaxflow); the result is within a factor 2 of the optimum."""
    try:
        import maxflow
    except ModuleNotFoundError:  # pragma: no cover - declared dependency
        raise ModuleNotFoundError("label smoothing needs PyMaxflow: pip install PyMaxflow") from None
    unary = np.asarray(unary, dtype=np.float64)
    if unary.ndim != 2:
        raise ParameterError(f"unary costs must be an (m, k) array, got shape {unary.shape}")
    if not np.isfinite(unary).all():
        raise ParameterError("unary costs must be finite")
    m, k = unary.shape
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    weights = np.asarray(weights, dtype=np.float64).ravel()
    if len(weights) != len(pairs) or (weights < 0).any() or not np.isfinite(weights).all():
        raise ParameterError("weights must be finite, >= 0 and one per pair")
    cur = np.argmin(unary, axis=1) if labels is None else np.asarray(labels, dtype=np.int64).copy()
    if len(cur) != m or (m and (cur.min() < 0 or cur.max() >= k)):
        raise ParameterError(f"initial labels must be {m} values in [0, {k - 1}]")
    if k < 2 or m == 0:
        return cur
    energy = potts_energy(unary, pairs, weights, cur)
    for _ in range(int(max_sweeps)):
        improved = False
        for alpha in range(k):
            new = _expand(unary, pairs, weights, cur, alpha, maxflow)
            e = potts_energy(unary, pairs, weights, new)
            if e < energy - 1e-10 * max(1.0, abs(energy)):
                cur, energy, improved = new, e, True
        if not improved:
            break
    return cur


def _as_face_labels(shape: Shape, labels: Any, on: str) -> np.ndarray:
    """Face labels from face labels, or from vertex labels by majority (ties: smallest label)."""
    lab = np.asarray(labels).ravel()
    if lab.size and not np.issubdtype(lab.dtype, np.integer):
        if not np.all(np.mod(lab, 1) == 0):
            raise ParameterError("labels must be integers")
    lab = lab.astype(np.int64)
    m, n = shape.n_faces, shape.n_vertices
    if on == "auto":
        if len(lab) == m:
            on = "faces"
        elif len(lab) == n:
            on = "vertices"
        else:
            raise ParameterError(f"{len(lab)} labels: expected one per face ({m}) or per vertex ({n})")
    if on == "faces":
        if len(lab) != m:
            raise ParameterError(f"{len(lab)} labels for {m} faces")
        return lab
    if on != "vertices":
        raise ParameterError(f"on must be 'auto', 'faces' or 'vertices', got {on!r}")
    if len(lab) != n:
        raise ParameterError(f"{len(lab)} labels for {n} vertices")
    f = shape.faces
    a, b, c = lab[f[:, 0]], lab[f[:, 1]], lab[f[:, 2]]
    out = np.minimum(np.minimum(a, b), c)
    out = np.where(b == c, b, out)
    out = np.where(a == c, a, out)
    return np.where(a == b, a, out)


def label_unary(
    shape: Shape, face_labels: np.ndarray, k: int, pairs: np.ndarray, *, spread: int = 3
) -> np.ndarray:
    """``-log`` of the label frequencies (``(m, k)``) around each face after ``spread`` steps of
    area-weighted averaging of the one-hot labels over the face and its dual neighbours."""
    m = shape.n_faces
    P = np.zeros((m, k))
    P[np.arange(m), face_labels] = 1.0
    if spread > 0 and len(pairs):
        S = sp.coo_matrix((np.ones(2 * len(pairs)), (np.r_[pairs[:, 0], pairs[:, 1]], np.r_[pairs[:, 1], pairs[:, 0]])),
                          shape=(m, m)).tocsr() + sp.identity(m, format="csr")
        a = np.asarray(shape.face_areas, dtype=np.float64)
        a = a + 1e-12 * max(float(a.mean()), 1e-300)
        SA = (S @ sp.diags(a)).tocsr()
        norm = np.asarray(SA.sum(axis=1)).ravel()
        T = sp.diags(1.0 / norm) @ SA
        for _ in range(int(spread)):
            P = T @ P
    return -np.log(np.maximum(P, EPS))


def smooth_labels(
    shape: Shape,
    labels: Any = None,
    unary: np.ndarray | None = None,
    smoothing_lambda: float = 0.5,
    *,
    on: str = "auto",
    spread: int = 3,
    convex_factor: float = 0.08,
    geometric: bool = True,
    max_sweeps: int = 10,
) -> np.ndarray:
    """Face labels ``(m,)`` int64 after an alpha-expansion graph cut on the dual graph.

    ``labels``: one per face, or one per vertex (converted to faces by majority; ``on`` says which
    when ``n_faces == n_vertices``); their values are kept (a label may disappear, none is invented).
    ``unary``: optional ``(m, k)`` costs of giving face ``f`` the ``j``-th label (the ``j``-th of the
    sorted distinct ``labels``, or ``j`` itself when ``labels`` is None); default: :func:`label_unary`
    with ``spread``. ``smoothing_lambda`` weighs the boundary cost against the unary one (0: no
    smoothing); ``convex_factor`` and ``geometric``: see the module docstring.
    """
    faces = shape.require_faces("label smoothing")
    lam = float(smoothing_lambda)
    if not np.isfinite(lam) or lam < 0:
        raise ParameterError(f"smoothing_lambda must be finite and >= 0, got {smoothing_lambda!r}")
    if labels is None and unary is None:
        raise ParameterError("smooth_labels needs labels, unary costs, or both")
    m = shape.n_faces
    if labels is not None:
        fl = _as_face_labels(shape, labels, on)
        values, init = np.unique(fl, return_inverse=True)
        init = init.ravel().astype(np.int64)
    else:
        values, init = None, None
    pairs, edges, cons = dual_graph(faces)
    if unary is None:
        unary = label_unary(shape, init, len(values), pairs, spread=spread)
    else:
        unary = np.asarray(unary, dtype=np.float64)
        if unary.ndim != 2 or unary.shape[0] != m:
            raise ParameterError(f"unary must be an ({m}, k) array, got shape {unary.shape}")
        if values is None:
            values = np.arange(unary.shape[1])
        elif unary.shape[1] != len(values):
            raise ParameterError(f"unary has {unary.shape[1]} columns for {len(values)} distinct labels")
    cost, _, _ = dihedral_edge_costs(shape, pairs, edges, cons, convex_factor=convex_factor)
    if geometric:
        a = np.asarray(shape.face_areas, dtype=np.float64)
        if a.mean() > 0:
            unary = unary * (a / a.mean())[:, None]
        if len(edges):
            v = shape.vertices / shape.scale
            ln = np.linalg.norm(v[edges[:, 0]] - v[edges[:, 1]], axis=1)
            if ln.mean() > 0:
                cost = cost * (ln / ln.mean())
    out = alpha_expansion(unary, pairs, lam * cost, init, max_sweeps=max_sweeps)
    return np.asarray(values, dtype=np.int64)[out]
