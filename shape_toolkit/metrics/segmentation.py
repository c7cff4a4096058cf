"""Segmentation scores: per-segment recall/precision (thesis 5.5) and the Princeton Segmentation
Benchmark metrics (Chen, Golovinskiy & Funkhouser 2009), all lower-is-better except recall and
precision.

Memory is O(n): every score is computed from the non-zero cells of the contingency table (at most one
per element), never from an n x n or k_pred x k_truth dense array (a 27k-face mesh with a per-face
labelling would otherwise need gigabytes).

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
from scipy.sparse.csgraph import dijkstra, min_weight_full_bipartite_matching

from shape_toolkit.core.graph import edge_length_graph
from shape_toolkit.core.shape import coordinate_scale
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
    "human_consistency_scores",
    "consensus_segment_count",
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
    if not np.all(np.isfinite(w)) or np.any(w < 0) or not w.max(initial=0.0) > 0:
        raise ParameterError("weights must be finite, non-negative, with a positive sum")
    # every metric is a ratio of sums of weights or of their products: divided by a power of two near the largest
    # (exact), so face areas of 1e-200 or 1e200 neither underflow nor overflow when squared
    return a, b, w / coordinate_scale(w)


#: Tables with at most this many cells use the dense Hungarian solver (the historical reference);
#: larger ones a sparse bipartite matching over the non-zero cells (same optimum, O(n) memory).
DENSE_ASSIGNMENT_CELLS = 1_000_000


class _Table:
    """The non-zero cells of a weighted contingency table: ``row``, ``col`` (int64), ``n`` (weight
    of the elements in the cell), ``s`` (sum of their squared weights), and the row / column sums."""

    def __init__(self, a: np.ndarray, b: np.ndarray, w: np.ndarray):
        _, ia = np.unique(a, return_inverse=True)
        _, ib = np.unique(b, return_inverse=True)
        ia, ib = ia.ravel().astype(np.int64), ib.ravel().astype(np.int64)
        self.ka, self.kb = int(ia.max()) + 1, int(ib.max()) + 1
        cell, inv = np.unique(ia * self.kb + ib, return_inverse=True)
        inv = inv.ravel()
        self.row, self.col = cell // self.kb, cell % self.kb
        self.n = np.bincount(inv, weights=w, minlength=len(cell))
        self.s = np.bincount(inv, weights=w * w, minlength=len(cell))
        self.row_sum = np.bincount(self.row, weights=self.n, minlength=self.ka)
        self.col_sum = np.bincount(self.col, weights=self.n, minlength=self.kb)
        self.total = float(self.n.sum())

    def dense(self) -> np.ndarray:
        out = np.zeros((self.ka, self.kb))
        out[self.row, self.col] = self.n
        return out


def contingency(a: np.ndarray, b: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Weighted contingency table ``(ka, kb)``: total weight of elements labelled ``(i, j)``.

    Dense, for inspection of small segmentations; the scores below never build it."""
    return _Table(*_prep(a, b, weights)).dense()


def rand_index_error(a: np.ndarray, b: np.ndarray, weights: np.ndarray | None = None) -> float:
    """``1 - RI``: the weighted fraction of element pairs ``i != j`` grouped together in one
    segmentation and apart in the other (pair weight ``w_i w_j``; classic Rand index when None)."""
    a, b, w = _prep(a, b, weights)
    t = _Table(a, b, w)
    w2 = w * w
    same_both = float((t.n**2 - t.s).sum())
    same_a = float((t.row_sum**2).sum() - w2.sum())
    same_b = float((t.col_sum**2).sum() - w2.sum())
    total = float(w.sum() ** 2 - w2.sum())
    if total <= 0:
        return 0.0
    return max(0.0, (same_a + same_b - 2.0 * same_both) / total)


def _group_max(keys: np.ndarray, values: np.ndarray, k: int) -> np.ndarray:
    out = np.zeros(k)
    np.maximum.at(out, keys, values)
    return out


def hamming_distance(
    pred: np.ndarray, truth: np.ndarray, weights: np.ndarray | None = None
) -> tuple[float, float, float]:
    """``(HD, Rm, Rf)`` of Chen et al.: ``Rm = D_H(pred => truth) / |S|`` (missing rate),
    ``Rf = D_H(truth => pred) / |S|`` (false alarm), ``HD = (Rm + Rf) / 2``; ``D_H(S1 => S2)`` sums
    over the segments of ``S2`` the weight outside their best-overlapping segment of ``S1``."""
    t = _Table(*_prep(pred, truth, weights))  # rows: pred segments, columns: truth segments
    rm = float((t.col_sum - _group_max(t.col, t.n, t.kb)).sum() / t.total)
    rf = float((t.row_sum - _group_max(t.row, t.n, t.ka)).sum() / t.total)
    return 0.5 * (rm + rf), rm, rf


def consistency_errors(
    a: np.ndarray, b: np.ndarray, weights: np.ndarray | None = None
) -> tuple[float, float]:
    """``(GCE, LCE)`` (Martin et al. 2001) with weighted set sizes: per element
    ``E(S1, S2, p) = |R(S1, p) \\ R(S2, p)| / |R(S1, p)|``; GCE takes the better direction globally,
    LCE per element."""
    t = _Table(*_prep(a, b, weights))
    n = t.n
    ra, rb = t.row_sum[t.row], t.col_sum[t.col]
    pos = n > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        e12 = np.where(pos, (ra - n) / np.where(pos, ra, 1.0), 0.0)  # error of an element in that cell
        e21 = np.where(pos, (rb - n) / np.where(pos, rb, 1.0), 0.0)
    gce = min(float((n * e12).sum()), float((n * e21).sum())) / t.total
    lce = float((n * np.minimum(e12, e21)).sum()) / t.total
    return gce, lce


def _max_overlap_matching(t: _Table) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices of a one-to-one matching of segments maximising the total overlap."""
    if t.ka * t.kb <= DENSE_ASSIGNMENT_CELLS:
        return linear_sum_assignment(-t.dense())
    # Sparse: a perfect matching of minimum cost on a graph where every row may also pair with
    # its own "unmatched" node (and every column likewise); costs c - overlap > 0 on the cells,
    # c elsewhere, so the minimum is the maximum total overlap. Nodes: left = rows + column
    # copies, right = columns + row copies.
    ka, kb, m = t.ka, t.kb, len(t.n)
    c = float(t.n.max()) + 1.0
    r_idx = np.r_[t.row, np.arange(ka), ka + np.arange(kb), ka + t.col]
    c_idx = np.r_[t.col, kb + np.arange(ka), np.arange(kb), kb + t.row]
    cost = np.r_[c - t.n, np.full(ka + kb + m, c)]
    g = sp.csr_matrix((cost, (r_idx, c_idx)), shape=(ka + kb, ka + kb))
    left, right = min_weight_full_bipartite_matching(g)
    real = (left < ka) & (right < kb)
    return left[real], right[real]


def matched_recall_precision(
    pred: np.ndarray, truth: np.ndarray, weights: np.ndarray | None = None
) -> tuple[float, float]:
    """Thesis 5.5 ``(m_tpr, m_ppv)``: predicted segments matched one-to-one to true ones maximising
    the total overlap (Hungarian); recall is the mean over true segments of ``tp / (tp + fn)``,
    precision the mean over predicted segments of ``tp / (tp + fp)`` (unmatched segments count 0)."""
    t = _Table(*_prep(pred, truth, weights))
    rows, cols = _max_overlap_matching(t)
    lookup = dict(zip((t.row * t.kb + t.col).tolist(), t.n.tolist()))
    tp = np.array([lookup.get(int(r) * t.kb + int(c), 0.0) for r, c in zip(rows, cols)], dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        recall = float((tp / t.col_sum[cols]).sum() / t.kb)
        precision = float((tp / t.row_sum[rows]).sum() / t.ka)
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
    G = _graph if _graph is not None else edge_length_graph(mesh)
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
    G = edge_length_graph(mesh) if mesh is not None else None
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


def human_consistency_scores(
    truth_face_labels_list: list[np.ndarray],
    face_areas: np.ndarray | None = None,
    mesh: Shape | None = None,
) -> dict[str, Any]:
    """PSB's "Human" row: each ground truth scored (:func:`segmentation_scores`) against the others,
    every metric of :data:`SEGMENTATION_METRICS` averaged over the truths (NaN where undefined);
    ``n_truths`` is their number. Needs at least two truths (:class:`ParameterError`)."""
    truths = [np.asarray(t).ravel() for t in truth_face_labels_list]
    if len(truths) < 2:
        raise ParameterError(f"human consistency needs at least 2 ground-truth segmentations, got {len(truths)}")
    per = [segmentation_scores(t, truths[:i] + truths[i + 1:], face_areas, mesh) for i, t in enumerate(truths)]
    out: dict[str, Any] = {}
    for name in SEGMENTATION_METRICS:
        vals = np.array([p[name] for p in per], dtype=np.float64)
        out[name] = float(np.nanmean(vals)) if np.isfinite(vals).any() else float("nan")
    out["n_truths"] = len(truths)
    return out


def consensus_segment_count(counts: list[int] | np.ndarray) -> int:
    """The number of segments the humans agree on (PSB's ``nSeg-ByModel`` rule): the most frequent of
    ``counts`` (segments per human segmentation); a tie goes to the count closest to their median, then
    to the larger; at least 2. :class:`ParameterError` for no count."""
    c = np.asarray(counts, dtype=np.int64).ravel()
    if c.size == 0:
        raise ParameterError("no ground-truth segmentation to take the number of segments from")
    values, freq = np.unique(c, return_counts=True)
    tied = values[freq == freq.max()]
    med = float(np.median(c))
    return max(2, int(min(tied, key=lambda v: (abs(float(v) - med), -int(v)))))
