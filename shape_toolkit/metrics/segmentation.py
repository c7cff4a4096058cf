"""Segmentation scores: per-segment recall/precision (thesis 5.5) and the Princeton Segmentation
Benchmark metrics (Chen, Golovinskiy & Funkhouser 2009), all lower-is-better except recall and
precision.

Labels are per element (faces for PSB); ``weights`` are the element measures (face areas in PSB,
which weighs every metric by area), uniform when None. Each function compares one prediction with
one ground truth; :func:`segmentation_scores` averages over several human segmentations.

Cut discrepancy approximation: a cut is the set of mesh edges between two faces of different labels;
distances from one cut to the other are graph geodesics (multi-source Dijkstra over the mesh
edges, edge length = Euclidean length), measured at the cut edges' end vertices and averaged along
each cut weighted by edge length; the result is divided by the average Euclidean distance from a
surface point to the area centroid, as PSB does.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp
from scipy.optimize import linear_sum_assignment
from scipy.sparse.csgraph import dijkstra

from shape_toolkit.errors import ParameterError

if TYPE_CHECKING:  # pragma: no cover
    from shape_toolkit.core.shape import Shape

__all__ = [
    "contingency",
    "rand_index_error",
    "hamming_distance",
    "consistency_errors",
    "cut_discrepancy",
    "matched_recall_precision",
    "segmentation_scores",
    "SEGMENTATION_METRICS",
]

#: names of the scores returned by :func:`segmentation_scores`
SEGMENTATION_METRICS = (
    "rand_index_error", "cut_discrepancy", "hamming", "hamming_rm", "hamming_rf", "gce", "lce",
    "recall", "precision",
)


def _prep(
    a: np.ndarray, b: np.ndarray, weights: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    a = np.asarray(a).ravel()
    b = np.asarray(b).ravel()
    if a.shape != b.shape:
        raise ParameterError(f"segmentations differ in size: {a.size} and {b.size} labels")
    if a.size == 0:
        raise ParameterError("empty segmentations")
    w = np.ones(a.size) if weights is None else np.asarray(weights, dtype=np.float64).ravel()
    if w.shape != a.shape:
        raise ParameterError(f"{w.size} weights for {a.size} labels")
    if not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
        raise ParameterError("weights must be finite, non-negative, with a positive sum")
    return a, b, w


def contingency(a: np.ndarray, b: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Weighted contingency table ``(ka, kb)``: total weight of elements labelled ``(i, j)``."""
    a, b, w = _prep(a, b, weights)
    _, ia = np.unique(a, return_inverse=True)
    _, ib = np.unique(b, return_inverse=True)
    return sp.coo_matrix((w, (ia.ravel(), ib.ravel()))).toarray()


def rand_index_error(a: np.ndarray, b: np.ndarray, weights: np.ndarray | None = None) -> float:
    """``1 - RI``: the weighted fraction of element pairs ``i != j`` grouped together in one
    segmentation and apart in the other (pair weight ``w_i w_j``; classic Rand index when None)."""
    a, b, w = _prep(a, b, weights)
    _, ia = np.unique(a, return_inverse=True)
    _, ib = np.unique(b, return_inverse=True)
    ia, ib = ia.ravel(), ib.ravel()
    w2 = w * w
    n = sp.coo_matrix((w, (ia, ib))).toarray()
    s = sp.coo_matrix((w2, (ia, ib))).toarray()
    same_both = float((n**2 - s).sum())
    same_a = float((n.sum(1) ** 2 - s.sum(1)).sum())
    same_b = float((n.sum(0) ** 2 - s.sum(0)).sum())
    total = float(w.sum() ** 2 - w2.sum())
    if total <= 0:
        return 0.0
    return max(0.0, (same_a + same_b - 2.0 * same_both) / total)


def hamming_distance(
    pred: np.ndarray, truth: np.ndarray, weights: np.ndarray | None = None
) -> tuple[float, float, float]:
    """``(HD, Rm, Rf)`` of Chen et al.: ``Rm = D_H(pred => truth) / |S|`` (missing rate),
    ``Rf = D_H(truth => pred) / |S|`` (false alarm), ``HD = (Rm + Rf) / 2``; ``D_H(S1 => S2)`` sums
    over the segments of ``S2`` the weight outside their best-overlapping segment of ``S1``."""
    n = contingency(pred, truth, weights)  # rows: pred segments, columns: truth segments
    total = n.sum()
    rm = float((n.sum(0) - n.max(0)).sum() / total)
    rf = float((n.sum(1) - n.max(1)).sum() / total)
    return 0.5 * (rm + rf), rm, rf


def consistency_errors(
    a: np.ndarray, b: np.ndarray, weights: np.ndarray | None = None
) -> tuple[float, float]:
    """``(GCE, LCE)`` (Martin et al. 2001) with weighted set sizes: per element
    ``E(S1, S2, p) = |R(S1, p) \\ R(S2, p)| / |R(S1, p)|``; GCE takes the better direction globally,
    LCE per element."""
    n = contingency(a, b, weights)
    ra, rb = n.sum(1, keepdims=True), n.sum(0, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        e12 = np.where(n > 0, (ra - n) / ra, 0.0)  # per cell: error of an element in that cell
        e21 = np.where(n > 0, (rb - n) / rb, 0.0)
    total = n.sum()
    gce = min(float((n * e12).sum()), float((n * e21).sum())) / total
    lce = float((n * np.minimum(e12, e21)).sum()) / total
    return gce, lce


def matched_recall_precision(
    pred: np.ndarray, truth: np.ndarray, weights: np.ndarray | None = None
) -> tuple[float, float]:
    """Thesis 5.5 ``(m_tpr, m_ppv)``: predicted segments matched one-to-one to true ones maximising
    the total overlap (Hungarian); recall is the mean over true segments of ``tp / (tp + fn)``,
    precision the mean over predicted segments of ``tp / (tp + fp)`` (unmatched segments count 0)."""
    n = contingency(pred, truth, weights)
    rows, cols = linear_sum_assignment(-n)
    tp = n[rows, cols]
    recall = float((tp / n.sum(0)[cols]).sum() / n.shape[1])
    precision = float((tp / n.sum(1)[rows]).sum() / n.shape[0])
    return recall, precision


def _cut_edges(faces: np.ndarray, face_labels: np.ndarray) -> np.ndarray:
    """Mesh edges ``(c, 2)`` shared by two faces of different labels."""
    f = np.asarray(faces, dtype=np.int64)
    he = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    owner = np.tile(np.arange(len(f)), 3)
    key = np.sort(he, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    key, owner = key[order], owner[order]
    same = np.all(key[1:] == key[:-1], axis=1)
    i = np.flatnonzero(same)
    lab = np.asarray(face_labels).ravel()
    diff = lab[owner[i]] != lab[owner[i + 1]]
    return np.unique(key[i[diff]], axis=0).reshape(-1, 2)


def _edge_graph(shape: Shape) -> sp.csr_matrix:
    e = shape.edges
    length = np.linalg.norm(shape.vertices[e[:, 0]] - shape.vertices[e[:, 1]], axis=1)
    length = np.maximum(length, 1e-300)
    n = shape.n_vertices
    ij = (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])
    return sp.csr_matrix((np.r_[length, length], ij), shape=(n, n))


def _average_radius(shape: Shape) -> float:
    """Area-weighted mean Euclidean distance from the face centroids to the surface centroid."""
    c = shape.vertices[shape.faces].mean(axis=1)
    a = shape.face_areas
    centroid = (c * a[:, None]).sum(0) / a.sum()
    return float((np.linalg.norm(c - centroid, axis=1) * a).sum() / a.sum())


def _directed_cd(G: sp.csr_matrix, verts: np.ndarray, cut_from: np.ndarray, cut_to: np.ndarray) -> float:
    sources = np.unique(cut_to.ravel())
    d = dijkstra(G, directed=False, indices=sources, min_only=True)
    length = np.linalg.norm(verts[cut_from[:, 0]] - verts[cut_from[:, 1]], axis=1)
    per_edge = 0.5 * (d[cut_from[:, 0]] + d[cut_from[:, 1]])
    finite = np.isfinite(per_edge)
    if not finite.any():
        return float("nan")
    return float((per_edge[finite] * length[finite]).sum() / max(length[finite].sum(), 1e-300))


def cut_discrepancy(
    pred_face_labels: np.ndarray, truth_face_labels: np.ndarray, mesh: Shape, *, _graph: Any = None
) -> float:
    """Chen et al. cut discrepancy: mean geodesic distance from the predicted cut to the true one
    plus the reverse, divided by the average radius of the mesh (see module doc). 0 when neither
    has a cut, NaN when only one has."""
    mesh.require_faces("cut discrepancy")
    a = np.asarray(pred_face_labels).ravel()
    b = np.asarray(truth_face_labels).ravel()
    if len(a) != mesh.n_faces or len(b) != mesh.n_faces:
        raise ParameterError(f"cut discrepancy needs one label per face ({mesh.n_faces})")
    ca, cb = _cut_edges(mesh.faces, a), _cut_edges(mesh.faces, b)
    if len(ca) == 0 and len(cb) == 0:
        return 0.0
    if len(ca) == 0 or len(cb) == 0:
        return float("nan")
    G = _graph if _graph is not None else _edge_graph(mesh)
    v = mesh.vertices
    return (_directed_cd(G, v, ca, cb) + _directed_cd(G, v, cb, ca)) / _average_radius(mesh)


def segmentation_scores(
    pred_face_labels: np.ndarray,
    truth_face_labels_list: list[np.ndarray] | np.ndarray,
    face_areas: np.ndarray | None = None,
    mesh: Shape | None = None,
) -> dict[str, Any]:
    """Every metric of :data:`SEGMENTATION_METRICS`, each averaged over the ground truths.

    ``face_areas`` default to ``mesh.face_areas`` (uniform without a mesh); ``cut_discrepancy`` needs
    ``mesh`` (NaN without one, and averaged over the truths where it is defined). Also returns
    ``n_truths`` and ``per_truth`` (a list of per-truth dicts).
    """
    pred = np.asarray(pred_face_labels).ravel()
    truths = [truth_face_labels_list] if isinstance(truth_face_labels_list, np.ndarray) and \
        truth_face_labels_list.ndim == 1 else list(truth_face_labels_list)
    if not truths:
        raise ParameterError("no ground-truth segmentation given")
    if mesh is not None:
        mesh.require_faces("segmentation scores")
        if len(pred) != mesh.n_faces:
            raise ParameterError(f"{len(pred)} predicted labels for {mesh.n_faces} faces")
        if face_areas is None:
            face_areas = mesh.face_areas
    G = _edge_graph(mesh) if mesh is not None else None
    per = []
    for t, truth in enumerate(truths):
        truth = np.asarray(truth).ravel()
        if truth.shape != pred.shape:
            raise ParameterError(
                f"ground truth #{t} has {truth.size} labels, the prediction {pred.size}"
            )
        hd, rm, rf = hamming_distance(pred, truth, face_areas)
        gce, lce = consistency_errors(pred, truth, face_areas)
        rec, prec = matched_recall_precision(pred, truth, face_areas)
        cd = cut_discrepancy(pred, truth, mesh, _graph=G) if mesh is not None else float("nan")
        per.append({
            "rand_index_error": rand_index_error(pred, truth, face_areas), "cut_discrepancy": cd,
            "hamming": hd, "hamming_rm": rm, "hamming_rf": rf, "gce": gce, "lce": lce,
            "recall": rec, "precision": prec,
        })
    out: dict[str, Any] = {}
    for name in SEGMENTATION_METRICS:
        vals = np.array([p[name] for p in per], dtype=np.float64)
        out[name] = float(np.nanmean(vals)) if np.isfinite(vals).any() else float("nan")
    out["n_truths"] = len(per)
    out["per_truth"] = per
    return out
