"""Correspondence metrics: normalized geodesic error and its cumulative curve (Kim et al. 2011),
r-smoothness (eq. 7.4-7.5), target coverage, recall/precision of transferred labels (Table 7.3).

Geodesic error protocol: for ground-truth pairs ``(s_i, t_i)`` (source vertex ``s_i`` truly
corresponds to target vertex ``t_i``) and a map ``Phi``, the error of pair ``i`` is the geodesic
distance on the target between ``Phi(s_i)`` and ``t_i`` divided by ``sqrt(area(target))``.
Symmetry-aware: the smaller of the errors to ``t_i`` and to its symmetric twin. A source vertex
left unmatched (``-1``) gets an infinite error: it never counts as correct in the curve and it is
left out of the mean (``matched_fraction`` reports how many were matched).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.results.correspondence import Correspondence

__all__ = [
    "DEFAULT_THRESHOLDS",
    "paired_geodesic_distances",
    "geodesic_errors",
    "error_curve",
    "correspondence_report",
    "check_truth",
    "r_smoothness",
    "r_smoothness_table",
    "target_coverage",
    "label_transfer_scores",
]

#: thresholds of the cumulative error curve: 0, 0.01, ..., 0.25 (units of sqrt(area))
DEFAULT_THRESHOLDS = np.round(np.linspace(0.0, 0.25, 26), 6)


def paired_geodesic_distances(
    shape: Shape, a: np.ndarray, b: np.ndarray, *, method: str = "exact", chunk: int = 128
) -> np.ndarray:
    """Geodesic distances ``d(a_i, b_i)`` on ``shape`` for vertex ids ``a`` ``(p,)`` and ``b``
    ``(p,)`` or ``(p, r)`` (``r`` partners per ``a_i``, e.g. the images of several maps), same
    shape as ``b``, in length units. One distance row per distinct ``a``, computed in chunks
    (memory ``chunk * n``)."""
    from shape_toolkit.features.geodesics import geodesic_distances

    a = np.asarray(a, dtype=np.int64).ravel()
    b = np.asarray(b, dtype=np.int64)
    b2 = b.reshape(b.shape[0], -1) if b.ndim else b.reshape(1, 1)
    if b2.shape[0] != a.size:
        raise ParameterError(f"paired ids must have equal lengths, got {a.size} and {b2.shape[0]}")
    n = shape.n_vertices
    for name, ids in (("a", a), ("b", b2)):
        if ids.size and (ids.min() < 0 or ids.max() >= n):
            raise ParameterError(f"vertex ids {name} must lie in [0, {n - 1}]")
    out = np.empty(b2.shape)
    uniq, inv = np.unique(a, return_inverse=True)
    order = np.argsort(inv, kind="stable")
    bounds = np.searchsorted(inv[order], np.arange(uniq.size + 1))
    for s in range(0, uniq.size, chunk):
        rows = np.asarray(geodesic_distances(shape, uniq[s : s + chunk], method=method, cache=False))
        for r in range(rows.shape[0]):
            sel = order[bounds[s + r] : bounds[s + r + 1]]
            out[sel] = rows[r][b2[sel]]
    return out.reshape(b.shape)


def check_truth(
    truth_src: np.ndarray, truth_dst: np.ndarray, n_source: int, n_target: int,
    truth_dst_sym: np.ndarray | None = None,
) -> None:
    """Raise :class:`ParameterError` unless the ground-truth id lists have equal lengths and lie
    inside their shapes (0-based)."""
    ts, td = np.asarray(truth_src), np.asarray(truth_dst)
    if ts.ndim != 1 or ts.shape != td.shape or ts.size == 0:
        raise ParameterError(
            f"ground-truth lists must be non-empty and of equal length, got {ts.size} and {td.size}"
        )
    if truth_dst_sym is not None and np.asarray(truth_dst_sym).shape != td.shape:
        raise ParameterError("the symmetric ground truth must have the length of the ground truth")
    for name, ids, n in (("source", ts, n_source), ("target", td, n_target)):
        if ids.min() < 0 or ids.max() >= n:
            raise ParameterError(
                f"{name} ground-truth ids must lie in [0, {n - 1}] (0-based), found "
                f"[{int(ids.min())}, {int(ids.max())}]"
            )


def geodesic_errors(
    target: Shape,
    target_of: np.ndarray | Correspondence,
    truth_src: np.ndarray,
    truth_dst: np.ndarray,
    *,
    truth_dst_sym: np.ndarray | None = None,
    method: str = "exact",
    normalize: bool = True,
) -> np.ndarray:
    """Error ``(p,)`` of each ground-truth pair: geodesic distance on ``target`` between the
    image of ``truth_src[i]`` and ``truth_dst[i]`` (divided by ``sqrt(target.area)`` when
    ``normalize``); with ``truth_dst_sym`` the smaller of the errors to the true and symmetric
    vertex; ``inf`` when the source vertex is unmatched."""
    t = target_of.target_of if isinstance(target_of, Correspondence) else np.asarray(target_of)
    t = np.asarray(t, dtype=np.int64)
    ts = np.asarray(truth_src, dtype=np.int64)
    td = np.asarray(truth_dst, dtype=np.int64)
    check_truth(ts, td, t.size, target.n_vertices, truth_dst_sym)
    if t.size and t.max() >= target.n_vertices:
        raise ParameterError(f"the map points past the target's {target.n_vertices} vertices")
    pred = t[ts]
    ok = pred >= 0
    err = np.full(ts.size, np.inf)
    if ok.any():
        # rows from the predicted vertices serve both the true and the symmetric partner
        partners = td[ok] if truth_dst_sym is None else np.column_stack(
            [td[ok], np.asarray(truth_dst_sym, dtype=np.int64)[ok]]
        )
        d = paired_geodesic_distances(target, pred[ok], partners, method=method)
        err[ok] = d if d.ndim == 1 else d.min(axis=1)
    if normalize:
        err = err / np.sqrt(target.area)
    return err


def error_curve(
    errors: np.ndarray, thresholds: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Cumulative curve: for each threshold the fraction of errors ``<=`` it (``inf`` never is);
    returns ``(thresholds, fractions)``."""
    th = DEFAULT_THRESHOLDS if thresholds is None else np.asarray(thresholds, dtype=np.float64)
    e = np.asarray(errors, dtype=np.float64).ravel()
    if e.size == 0:
        raise ParameterError("no errors to summarize")
    s = np.sort(e)
    frac = np.searchsorted(s, th + 1e-12, side="right") / e.size
    return th, frac


def correspondence_report(
    errors: np.ndarray, thresholds: np.ndarray | None = None
) -> dict[str, Any]:
    """Summary of per-pair errors: ``mean_geodesic_error`` (matched pairs), ``curve`` as
    ``[[threshold, fraction], ...]``, ``matched_fraction``, median and fraction within 0.05."""
    e = np.asarray(errors, dtype=np.float64)
    th, frac = error_curve(e, thresholds)
    fin = e[np.isfinite(e)]
    return {
        "mean_geodesic_error": float(fin.mean()) if fin.size else float("nan"),
        "median_geodesic_error": float(np.median(fin)) if fin.size else float("nan"),
        "within_0.05": float(np.mean(e <= 0.05)),
        "matched_fraction": float(fin.size / e.size),
        "n_truth": int(e.size),
        "curve": [[float(a), float(b)] for a, b in zip(th, frac)],
    }


def r_smoothness(
    source: Shape,
    target: Shape,
    target_of: np.ndarray | Correspondence,
    r: float = 0.5,
    theta: float = 0.9,
    *,
    sample: int | None = None,
    method: str = "dijkstra",
    random_state: int = 0,
) -> float:
    """r-smoothness (eq. 7.4-7.5): the fraction of source vertices ``i`` for which at least
    ``theta`` of the matched vertices of the relative geodesic neighbourhood ``Nei_r(i)`` (the
    ``r`` percent of vertices geodesically closest to ``i``) map into ``Nei_r(Phi(i))``; unmatched
    vertices count as not smooth. ``sample`` evaluates a random subset of source vertices."""
    from shape_toolkit.features.geodesics import relative_geodesic_neighbourhood

    t = target_of.target_of if isinstance(target_of, Correspondence) else np.asarray(target_of)
    t = np.asarray(t, dtype=np.int64)
    if t.size != source.n_vertices:
        raise ParameterError(f"the map has {t.size} entries, the source {source.n_vertices} vertices")
    if not 0 < r <= 100 or not 0 < theta <= 1:
        raise ParameterError("need 0 < r <= 100 (percent of vertices) and 0 < theta <= 1")
    ids = np.arange(source.n_vertices)
    if sample is not None and sample < ids.size:
        ids = np.sort(np.random.default_rng(random_state).choice(ids, sample, replace=False))
    matched = ids[t[ids] >= 0]
    if matched.size == 0:
        return 0.0
    smooth = 0
    for i in matched:
        a = relative_geodesic_neighbourhood(source, int(i), r, method=method)
        b = relative_geodesic_neighbourhood(target, int(t[i]), r, method=method)
        img = t[a]
        img = img[img >= 0]
        if img.size == 0:
            continue
        smooth += np.isin(img, b).mean() >= theta - 1e-12
    return float(smooth / ids.size)


def r_smoothness_table(
    source: Shape,
    target: Shape,
    target_of: np.ndarray | Correspondence,
    rs: tuple[float, ...] = (0.1, 0.2, 0.3, 0.4, 0.5, 0.8),
    theta: float = 0.9,
    *,
    sample: int | None = 200,
    method: str = "dijkstra",
    random_state: int = 0,
) -> dict[float, float]:
    """Table 7.2: :func:`r_smoothness` in percent for each neighbourhood size ``r`` (percent of the
    vertices) at ``theta`` (90 % in the thesis), on the same ``sample`` of source vertices."""
    return {
        float(r): 100.0 * r_smoothness(source, target, target_of, r, theta, sample=sample, method=method,
                                       random_state=random_state)
        for r in rs
    }


def target_coverage(target_of: np.ndarray | Correspondence, n_target: int | None = None) -> float:
    """Fraction of target vertices that are the image of at least one source vertex."""
    if isinstance(target_of, Correspondence):
        n_target = target_of.n_target if n_target is None else n_target
        target_of = target_of.target_of
    if n_target is None:
        raise ParameterError("n_target is needed for a plain array map")
    t = np.asarray(target_of, dtype=np.int64)
    t = t[t >= 0]
    return float(np.unique(t).size / n_target)


def label_transfer_scores(predicted: np.ndarray, truth: np.ndarray) -> dict[str, Any]:
    """Mean recall ``m^tpr`` and precision ``m^ppv`` over the ground-truth labels (Section 5.5,
    Table 7.3) of transferred vertex labels ``(n,)``; negative labels are unlabelled."""
    p = np.asarray(predicted, dtype=np.int64).ravel()
    g = np.asarray(truth, dtype=np.int64).ravel()
    if p.shape != g.shape:
        raise ParameterError(f"label arrays differ in length: {p.size} and {g.size}")
    classes = np.unique(g[g >= 0])
    if classes.size == 0:
        raise ParameterError("the ground truth has no labels")
    recall, precision = [], []
    for c in classes:
        tp = np.sum((p == c) & (g == c))
        recall.append(tp / max(np.sum(g == c), 1))
        precision.append(tp / np.sum(p == c) if np.any(p == c) else 0.0)
    return {
        "recall": float(np.mean(recall)),
        "precision": float(np.mean(precision)),
        "per_label_recall": [float(x) for x in recall],
        "per_label_precision": [float(x) for x in precision],
        "labels": classes.tolist(),
    }

