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

from collections.abc import Callable
from typing import Any

import numpy as np

from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import InvalidShapeError, ParameterError
from shape_toolkit.features.geodesics import paired_geodesic_distances  # re-exported: its old home
from shape_toolkit.results.correspondence import Correspondence

__all__ = [
    "DEFAULT_THRESHOLDS",
    "paired_geodesic_distances",
    "geodesic_errors",
    "error_normalization",
    "error_curve",
    "is_flipped",
    "correspondence_report",
    "check_truth",
    "R_SMOOTH_RS",
    "r_smoothness",
    "r_smoothness_table",
    "target_coverage",
    "label_transfer_scores",
    "map_label_scores",
    "truth_segments",
]

#: thresholds of the cumulative error curve: 0, 0.01, ..., 0.25 (units of sqrt(area))
DEFAULT_THRESHOLDS = np.round(np.linspace(0.0, 0.25, 26), 6)


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


def error_normalization(target: Shape) -> float:
    """``sqrt(target.area)``, the unit of the normalized geodesic error (a point cloud: the area of the surface its
    heat geodesics run on, :func:`~shape_toolkit.core.surface.cloud_area`), or :class:`InvalidShapeError` when it
    is not a positive number: a mesh whose every face is degenerate (zero area to rounding: collinear or coincident
    vertices, repeated indices), where the error would be a division by zero (NaN or infinite errors, reported as
    null)."""
    from shape_toolkit.core.inspect import degenerate_face_mask

    if not target.is_mesh:
        from shape_toolkit.core.surface import cloud_area

        area = cloud_area(target)
        if not area > 0 or not np.isfinite(area):
            raise InvalidShapeError(f"the target {target!r} has no surface area (its points' neighbourhoods span no "
                                    "triangle), so the geodesic error normalized by sqrt(area) is undefined")
        return float(np.sqrt(area))
    faces = target.faces
    area = float(target.area)
    if not area > 0 or not np.isfinite(area) or degenerate_face_mask(target.vertices, faces).all():
        raise InvalidShapeError(
            f"the target {target!r} has zero surface area (every face is degenerate: collinear or coincident "
            "vertices), so the geodesic error normalized by sqrt(area) is undefined"
        )
    return float(np.sqrt(area))


def geodesic_errors(
    target: Shape,
    target_of: np.ndarray | Correspondence,
    truth_src: np.ndarray,
    truth_dst: np.ndarray,
    *,
    truth_dst_sym: np.ndarray | None = None,
    method: str = "exact",
    normalize: bool = True,
    time_limit: float | None = None,
    progress: Callable[[int, int | None], None] | None = None,
) -> np.ndarray:
    """Error ``(p,)`` of each ground-truth pair: geodesic distance on ``target`` between the
    image of ``truth_src[i]`` and ``truth_dst[i]`` (divided by ``sqrt(target.area)`` when
    ``normalize``); with ``truth_dst_sym`` the smaller of the errors to the true and symmetric
    vertex; ``inf`` when the source vertex is unmatched. ``time_limit`` and ``progress`` as in
    :func:`paired_geodesic_distances`. A target of zero area cannot normalize:
    :class:`InvalidShapeError` (:func:`error_normalization`), before any geodesic is computed."""
    t = target_of.target_of if isinstance(target_of, Correspondence) else np.asarray(target_of)
    t = np.asarray(t, dtype=np.int64)
    ts = np.asarray(truth_src, dtype=np.int64)
    td = np.asarray(truth_dst, dtype=np.int64)
    check_truth(ts, td, t.size, target.n_vertices, truth_dst_sym)
    if t.size and t.max() >= target.n_vertices:
        raise ParameterError(f"the map points past the target's {target.n_vertices} vertices")
    unit = error_normalization(target) if normalize else 1.0
    pred = t[ts]
    ok = pred >= 0
    err = np.full(ts.size, np.inf)
    if ok.any():
        # rows from the predicted vertices serve both the true and the symmetric partner
        partners = td[ok] if truth_dst_sym is None else np.column_stack(
            [td[ok], np.asarray(truth_dst_sym, dtype=np.int64)[ok]]
        )
        d = paired_geodesic_distances(
            target, pred[ok], partners, method=method, time_limit=time_limit, progress=progress
        )
        err[ok] = d if d.ndim == 1 else d.min(axis=1)
    return err / unit


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


def is_flipped(mean_error: float, mean_error_symmetric: float) -> bool:
    """A left-right swapped map: its mean error against the ground truth alone is more than twice
    (+0.02) its error up to the dataset's symmetry (both in units of sqrt(area); the rule of the
    matching benchmarks' ``flipped pairs``)."""
    return bool(mean_error > 2.0 * mean_error_symmetric + 0.02)


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


#: neighbourhood sizes r of thesis Table 7.2, in percent of a shape's vertices
R_SMOOTH_RS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.8)
#: neighbourhood entries (vertex ids) held at once by :func:`r_smoothness_table`, 32 MB of int64 per shape
R_SMOOTH_BLOCK_VALUES = 2**22


def _map_array(target_of: np.ndarray | Correspondence, n_source: int, n_target: int) -> np.ndarray:
    t = target_of.target_of if isinstance(target_of, Correspondence) else np.asarray(target_of)
    t = np.asarray(t)
    if t.ndim != 1 or t.size != n_source:
        raise ParameterError(f"the map has {t.size} entries, the source {n_source} vertices")
    if t.size and not np.issubdtype(t.dtype, np.integer):
        raise ParameterError("the map must hold integer vertex ids")
    t = t.astype(np.int64)
    if t.size and (t.min() < -1 or t.max() >= n_target):
        raise ParameterError(f"the map must hold ids in [-1, {n_target - 1}]")
    return t


def _check_rs(rs: Any, theta: float) -> list[float]:
    vals = [rs] if np.isscalar(rs) else list(rs)
    if not vals:
        raise ParameterError("give at least one neighbourhood size r (percent of the vertices)")
    out = []
    for r in vals:
        if isinstance(r, bool) or not isinstance(r, (int, float, np.integer, np.floating)) or not (
            np.isfinite(r) and 0 < r <= 100
        ):
            raise ParameterError(f"r must be in (0, 100] (percent of the vertices), got {r!r}")
        out.append(float(r))
    if isinstance(theta, bool) or not isinstance(theta, (int, float, np.floating)) or not 0 < theta <= 1:
        raise ParameterError(f"theta must be in (0, 1] (fraction of the neighbours), got {theta!r}")
    return out


def r_smoothness_table(
    source: Shape,
    target: Shape,
    target_of: np.ndarray | Correspondence,
    rs: tuple[float, ...] | list[float] = R_SMOOTH_RS,
    theta: float = 0.9,
    *,
    sample: int | None = 200,
    method: str = "dijkstra",
    random_state: Any = 0,
    time_limit: float | None = None,
    progress: Callable[[int, int | None], None] | None = None,
) -> dict[float, float]:
    """Table 7.2: r-smoothness (eq. 7.4-7.5) in percent, ``{r: percent}``, for each neighbourhood
    size ``r`` in ``rs`` (percent of a shape's vertices).

    ``Nei_r(i)`` is the relative geodesic neighbourhood of thesis 7.5.2: the ``ceil(r/100 * n)``
    vertices geodesically closest to ``i`` on its own shape (itself first, ties by id). Source
    vertex ``i`` is r-smooth when at least ``theta`` of the matched vertices of ``Nei_r(i)`` map
    into ``Nei_r(Phi(i))`` on the target (eq. 7.4 relaxed to ``theta``; the thesis uses 90 %);
    eq. 7.5 averages over the vertices, an unmatched vertex counting as not smooth. ``sample``
    evaluates that many source vertices drawn with ``random_state`` (None: all of them, as in
    the thesis); every ``r`` uses the same vertices and distance rows (one row per evaluated
    vertex on each shape, ``method`` as in :func:`~shape_toolkit.features.geodesics.geodesic_distances`).
    ``progress(done, total)`` counts solved distance rows; ``time_limit`` (seconds) raises
    :class:`~shape_toolkit.errors.TimeLimitError` past it."""
    from shape_toolkit.features.geodesics import GeodesicBudget, geodesic_nearest, relative_neighbourhood_size
    from shape_toolkit.validation import check_random_state

    t = _map_array(target_of, source.n_vertices, target.n_vertices)
    rs = _check_rs(rs, theta)
    ids = np.arange(source.n_vertices)
    if sample is not None:
        if isinstance(sample, bool) or not isinstance(sample, (int, np.integer)) or sample < 1:
            raise ParameterError(f"sample must be a positive integer or None, got {sample!r}")
        if sample < ids.size:
            ids = np.sort(check_random_state(random_state).choice(ids, int(sample), replace=False))
    cs = [relative_neighbourhood_size(r, source.n_vertices) for r in rs]
    ct = [relative_neighbourhood_size(r, target.n_vertices) for r in rs]
    matched = ids[t[ids] >= 0]
    budget = GeodesicBudget(time_limit, 2 * matched.size, progress, f"r-smoothness ({method} geodesics)",
                            remedy="evaluate fewer source vertices (sample; --r-sample N on the command line) "
                            "or give a larger time limit")
    smooth = np.zeros(len(rs))
    # a block of evaluated vertices at a time: their neighbourhoods are (block, count) arrays of at most
    # R_SMOOTH_BLOCK_VALUES entries, so the memory stays flat when every vertex of a large mesh is evaluated
    # (all at once they were two (n, r n / 100) arrays: 2 x 16 GB at 500k vertices and r = 0.8)
    block = max(1, R_SMOOTH_BLOCK_VALUES // max(max(cs), max(ct)))
    for b in range(0, matched.size, block):
        here = matched[b : b + block]
        near_s = geodesic_nearest(source, here, max(cs), method=method, budget=budget)
        near_t = geodesic_nearest(target, t[here], max(ct), method=method, budget=budget)
        row = np.arange(here.size, dtype=np.int64)[:, None] * target.n_vertices
        for j, (c_s, c_t) in enumerate(zip(cs, ct)):
            nb = near_s[:, :c_s]
            img = np.where(nb >= 0, t[np.maximum(nb, 0)], -1)  # images of Nei_r(i), -1: unmatched or padding
            valid = img >= 0
            ball = near_t[:, :c_t]
            keys = (row + ball)[ball >= 0]  # (row, target vertex) pairs of Nei_r(Phi(i)), as one integer
            inside = np.isin(row + img, keys) & valid
            n_valid = valid.sum(axis=1)
            frac = inside.sum(axis=1) / np.maximum(n_valid, 1)
            smooth[j] += np.count_nonzero((n_valid > 0) & (frac >= theta - 1e-12))
    return {r: float(100.0 * smooth[j] / ids.size) for j, r in enumerate(rs)}


def r_smoothness(
    source: Shape,
    target: Shape,
    target_of: np.ndarray | Correspondence,
    r: float = 0.5,
    theta: float = 0.9,
    *,
    sample: int | None = None,
    method: str = "dijkstra",
    random_state: Any = 0,
) -> float:
    """r-smoothness (eq. 7.4-7.5) of one neighbourhood size ``r`` (percent of the vertices) as a
    fraction in [0, 1]: :func:`r_smoothness_table` for ``rs=(r,)`` divided by 100 (same
    definition, same sampling); ``sample=None`` evaluates every source vertex."""
    table = r_smoothness_table(
        source, target, target_of, (r,), theta, sample=sample, method=method, random_state=random_state
    )
    return table[float(r)] / 100.0


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



def map_label_scores(
    target_of: np.ndarray | Correspondence,
    source_labels: np.ndarray,
    target_labels: np.ndarray,
    target: Shape | None = None,
    *,
    soft: bool = False,
) -> dict[str, Any]:
    """Table 7.3: mean recall and precision (:func:`label_transfer_scores`) of a segmentation
    carried through a map. The source's labels ``(n_source,)`` go to the target as in the thesis
    (target vertex ``j`` takes the label of the source vertex mapped onto it; of several, the
    smallest id, or the most confident with a :class:`Correspondence` that has confidences); with
    ``target``, a target vertex that no source vertex reaches takes the label of the nearest
    reached one along the mesh edges (a hard map covers only part of the target, while the
    thesis's probabilistic transfer labels every vertex); without it, such a vertex stays
    unlabelled and counts against recall. ``soft``: Algorithm 5's probabilistic label transfer
    (eq. 5.9, :func:`~shape_toolkit.results.correspondence.transfer_labels` with ``soft=True``):
    target vertex ``j`` takes the label of largest posterior mass ``sum_i p_ij`` over the map's
    posteriors (a map without posteriors: its 0/1 matrix, a vote of the source vertices mapped onto
    ``j``). Label ids must mean the same segment on both shapes; negative labels are unlabelled.
    Adds ``filled``: the fraction of target vertices labelled by that nearest-vertex rule."""
    from shape_toolkit.results.correspondence import transfer_labels

    ls = np.asarray(source_labels)
    lt = np.asarray(target_labels)
    if lt.ndim != 1:
        raise ParameterError(f"target labels must be one per target vertex, got shape {lt.shape}")
    t = _map_array(target_of, ls.size if ls.ndim == 1 else -1, lt.size)
    corr = target_of if isinstance(target_of, Correspondence) else Correspondence(t, lt.size)
    if target is not None and target.n_vertices != lt.size:
        raise ParameterError(f"{lt.size} target labels for a target of {target.n_vertices} vertices")
    pred = transfer_labels(corr, ls, to="target", soft=bool(soft))
    filled = 0.0
    if target is not None:
        from shape_toolkit.features.geodesics import fill_from_nearest

        before = int((pred < 0).sum())
        pred = fill_from_nearest(target, pred)
        filled = float((before - int((pred < 0).sum())) / lt.size)
    out = label_transfer_scores(pred, lt)
    out["filled"] = filled
    return out


def truth_segments(
    source: Shape,
    target: Shape,
    truth_src: np.ndarray,
    truth_dst: np.ndarray,
    n_segments: int = 8,
) -> tuple[np.ndarray, np.ndarray]:
    """Segment labels for Table 7.3 on pairs without hand segmentations (TOSCA, FAUST): the
    source is cut into ``n_segments`` geodesic Voronoi cells (along mesh edges) of farthest
    points (:func:`~shape_toolkit.features.geodesics.geodesic_farthest_points`, deterministic);
    the target's labels are the source labels carried by the ground truth ``truth_src[i] <->
    truth_dst[i]``, target vertices without a ground-truth partner taking the label of the
    nearest one along the edges. Returns int64 ``(n_source,)`` and ``(n_target,)`` labels in
    ``0..n_segments-1`` (-1 only where a component holds no labelled vertex). The segments are
    patches, not body parts; they are consistent with the ground truth by construction, so a
    map's recall and precision measure how well it carries regions."""
    from shape_toolkit.features.geodesics import fill_from_nearest, geodesic_farthest_points, nearest_source

    ts = np.asarray(truth_src, dtype=np.int64)
    td = np.asarray(truth_dst, dtype=np.int64)
    check_truth(ts, td, source.n_vertices, target.n_vertices)
    if isinstance(n_segments, bool) or not isinstance(n_segments, (int, np.integer)) or not (
        1 <= n_segments <= source.n_vertices
    ):
        raise ParameterError(f"n_segments must be an integer in [1, {source.n_vertices}], got {n_segments!r}")
    centres = geodesic_farthest_points(source, int(n_segments))
    index = np.full(source.n_vertices, -1, dtype=np.int64)
    index[centres] = np.arange(centres.size)
    owner = nearest_source(source, centres)
    src = np.where(owner >= 0, index[np.maximum(owner, 0)], -1)
    tgt = np.full(target.n_vertices, -1, dtype=np.int64)
    tgt[td] = src[ts]
    if not np.any(tgt >= 0):
        raise ParameterError("no ground-truth pair reaches a labelled source vertex")
    return src, fill_from_nearest(target, tgt)
