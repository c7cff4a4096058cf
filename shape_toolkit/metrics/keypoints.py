"""Keypoint repeatability on a pair of shapes with ground-truth correspondences."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.features.geodesics import geodesic_distance_to_set

__all__ = [
    "DEFAULT_REPEATABILITY_RADII",
    "ground_truth_map",
    "keypoint_repeatability",
    "keypoint_coverage",
    "repeatability_report",
]

#: Radii (fractions of ``sqrt(area)``) at which repeatability is reported by default.
DEFAULT_REPEATABILITY_RADII = (0.025, 0.05, 0.1)


def _ids(a: object, n: int, what: str) -> np.ndarray:
    x = np.atleast_1d(np.asarray(a))
    if x.size == 0:
        return np.zeros(0, dtype=np.int64)
    if x.ndim != 1 or not np.issubdtype(x.dtype, np.integer):
        raise ParameterError(f"{what} must be a 1-D array of integer vertex ids")
    if x.min() < 0 or x.max() >= n:
        raise ParameterError(f"{what} must be vertex ids in [0, {n - 1}], found [{x.min()}, {x.max()}]")
    return x.astype(np.int64)


def ground_truth_map(shape_a: Shape, truth_a: np.ndarray, truth_b: np.ndarray, n_b: int) -> np.ndarray:
    """Image on B of every vertex of A, int64 ``(n_a,)``, from paired ground-truth ids
    (``truth_a[i]`` corresponds to ``truth_b[i]``, e.g. two ``.vts`` files read 0-based).
    A vertex listed several times takes its first pair; an unlisted vertex takes the pair of the
    Euclidean-nearest listed vertex of A (an approximation, exact on listed vertices)."""
    ta = _ids(truth_a, shape_a.n_vertices, "truth_a")
    tb = _ids(truth_b, n_b, "truth_b")
    if ta.size != tb.size or ta.size == 0:
        raise ParameterError(
            f"truth_a and truth_b must pair the same non-zero number of vertices ({ta.size} vs {tb.size})"
        )
    uniq, first = np.unique(ta, return_index=True)
    image_of_listed = tb[first]
    tree = cKDTree(shape_a.vertices[uniq])
    _, nearest = tree.query(shape_a.vertices)
    return image_of_listed[np.asarray(nearest, dtype=np.int64)]


def _radii(radii: float | Sequence[float]) -> np.ndarray:
    r = np.atleast_1d(np.asarray(radii, dtype=np.float64))
    if r.size == 0 or not np.all(np.isfinite(r)) or np.any(r < 0):
        raise ParameterError(f"radii must be non-negative finite numbers, got {radii!r}")
    return r


def keypoint_repeatability(
    shape_b: Shape,
    keypoints_a: np.ndarray,
    keypoints_b: np.ndarray,
    map_a_to_b: np.ndarray,
    radii: float | Sequence[float] = DEFAULT_REPEATABILITY_RADII,
    *,
    method: str = "fmm",
) -> np.ndarray:
    """Fraction of A's keypoints whose true image (``map_a_to_b``, ``(n_a,)`` ids on B) lies
    within geodesic distance ``r * sqrt(area_B)`` of some keypoint of B, for each radius ``r``:
    float64 ``(len(radii),)``; NaN when A has no keypoint, 0 when B has none."""
    r = _radii(radii)
    m = np.asarray(map_a_to_b)
    ka = _ids(keypoints_a, m.size, "keypoints_a")
    kb = _ids(keypoints_b, shape_b.n_vertices, "keypoints_b")
    m = _ids(m, shape_b.n_vertices, "map_a_to_b")
    if ka.size == 0:
        return np.full(r.size, np.nan)
    if kb.size == 0:
        return np.zeros(r.size)
    d = geodesic_distance_to_set(shape_b, kb, method=method)[m[ka]] / np.sqrt(shape_b.area)
    return (d[None, :] <= r[:, None]).mean(axis=1)


def keypoint_coverage(
    shape: Shape, keypoints: np.ndarray, radii: float | Sequence[float] = DEFAULT_REPEATABILITY_RADII,
    *, method: str = "fmm",
) -> np.ndarray:
    """Area fraction of ``shape`` within geodesic distance ``r * sqrt(area)`` of a keypoint,
    ``(len(radii),)``: the repeatability a detector would reach by chance (random points)."""
    r = _radii(radii)
    k = _ids(keypoints, shape.n_vertices, "keypoints")
    if k.size == 0:
        return np.zeros(r.size)
    d = geodesic_distance_to_set(shape, k, method=method) / np.sqrt(shape.area)
    w = shape.vertex_areas / shape.vertex_areas.sum()
    return np.array([float(w[d <= x].sum()) for x in r])


def repeatability_report(
    shape_a: Shape,
    shape_b: Shape,
    keypoints_a: np.ndarray,
    keypoints_b: np.ndarray,
    map_a_to_b: np.ndarray,
    map_b_to_a: np.ndarray,
    radii: float | Sequence[float] = DEFAULT_REPEATABILITY_RADII,
    *,
    method: str = "fmm",
) -> dict[str, Any]:
    """Both directions of :func:`keypoint_repeatability`, their mean, the chance levels
    (:func:`keypoint_coverage`) and keypoint counts, as a JSON-ready dict keyed by radius."""
    r = _radii(radii)
    ab = keypoint_repeatability(shape_b, keypoints_a, keypoints_b, map_a_to_b, r, method=method)
    ba = keypoint_repeatability(shape_a, keypoints_b, keypoints_a, map_b_to_a, r, method=method)
    cb = keypoint_coverage(shape_b, keypoints_b, r, method=method)
    ca = keypoint_coverage(shape_a, keypoints_a, r, method=method)
    return {
        "radii": r.tolist(),
        "n_keypoints_a": int(np.size(keypoints_a)),
        "n_keypoints_b": int(np.size(keypoints_b)),
        "a_to_b": ab.tolist(),
        "b_to_a": ba.tolist(),
        "mean": (0.5 * (ab + ba)).tolist(),
        "chance": (0.5 * (ca + cb)).tolist(),
    }
