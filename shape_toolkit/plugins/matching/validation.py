"""Checks of what a matcher is given: descriptors, seeds, keypoints (:class:`ParameterError` otherwise)."""

from __future__ import annotations

import numpy as np

from shape_toolkit.errors import ParameterError
from shape_toolkit.validation import check_seeds as _check_seeds

__all__ = ["check_descriptors", "check_seeds", "check_keypoints"]


def check_descriptors(desc: np.ndarray, n: int, what: str) -> np.ndarray:
    """``desc`` as float64 ``(n, d)``; raises :class:`ParameterError` on a bad shape or NaN."""
    d = np.asarray(desc, dtype=np.float64)
    if d.ndim == 1:
        d = d[:, None]
    if d.ndim != 2 or d.shape[0] != n:
        raise ParameterError(f"{what} descriptors must be ({n}, d), got shape {d.shape}")
    if not np.isfinite(d).all():
        raise ParameterError(f"{what} descriptors contain NaN or infinite values")
    return d


def check_seeds(seeds: np.ndarray | None, n_src: int, n_tgt: int) -> np.ndarray | None:
    """Seeds as int64 ``(q, 2)`` ``[source, target]`` inside both shapes, or None."""
    return None if seeds is None else _check_seeds(seeds, n_src, n_tgt)


def check_keypoints(kp: np.ndarray, n: int, what: str, minimum: int = 3) -> np.ndarray:
    """Keypoints as unique int64 ids inside the shape; fewer than ``minimum`` raise."""
    k = np.asarray(kp)
    if k.ndim != 1:
        raise ParameterError(f"{what} keypoints must be a 1-D array of vertex ids")
    if k.size and not np.issubdtype(k.dtype, np.integer):
        raise ParameterError(f"{what} keypoints must be integer vertex ids")
    k = k.astype(np.int64)
    if k.size and (k.min() < 0 or k.max() >= n):
        raise ParameterError(f"{what} keypoints must lie in [0, {n - 1}]")
    _, first = np.unique(k, return_index=True)
    k = k[np.sort(first)]
    if k.size < minimum:
        raise ParameterError(
            f"not enough {what} keypoints to match: {k.size} (need at least {minimum}); "
            "use a denser keypoint preset or give seeds"
        )
    return k
