"""Scores of vertex descriptors across two shapes (thesis 6.6.4)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from shape_toolkit.errors import ParameterError
from shape_toolkit.validation import check_vertex_ids

__all__ = ["descriptor_matching_score"]


def descriptor_matching_score(
    desc_src: np.ndarray | Sequence[np.ndarray],
    desc_dst: np.ndarray | Sequence[np.ndarray],
    src_vertices: np.ndarray | Sequence[int] | None = None,
    dst_vertices: np.ndarray | Sequence[int] | None = None,
    *,
    n_times: int | None = None,
    pairwise: bool = False,
) -> np.ndarray:
    """Matching score of eq. 6.66: ``sum_m ||d_m(v_i) - d_m(v'_j)||_inf`` over the ``M`` matched
    keypoints (max over the ``tau`` scales), lower is better.

    Descriptors are ``(n, M * tau)`` arrays laid out keypoint-major (``[d_1(t_1..t_tau), d_2...]``,
    the layout of the ``heat-distance`` and ``heat-diffusion`` plugins) with ``n_times = tau``
    given, or ``(n, M, tau)`` arrays, or lists of ``M`` ``(n, tau)`` arrays; the keypoint order of
    the two shapes must follow the keypoint matching. Rows ``src_vertices[q]`` and
    ``dst_vertices[q]`` are compared pairwise (``(q,)`` scores), or every source row with every
    destination row (``(q_src, q_dst)``) when ``pairwise``.
    """
    a, b = _as_cube(desc_src, n_times, "desc_src"), _as_cube(desc_dst, n_times, "desc_dst")
    if a.shape[1:] != b.shape[1:]:
        raise ParameterError(
            f"descriptors disagree: (M, tau) = {a.shape[1:]} on the source, {b.shape[1:]} on the target"
        )
    na, nb = a.shape[0], b.shape[0]
    ia = np.arange(na) if src_vertices is None else check_vertex_ids(src_vertices, na, "src_vertices")
    ib = np.arange(nb) if dst_vertices is None else check_vertex_ids(dst_vertices, nb, "dst_vertices")
    if pairwise:
        out = np.empty((ia.size, ib.size))
        step = max(1, 2_000_000 // max(1, ib.size * a.shape[1] * a.shape[2]))
        B = b[ib]
        for s in range(0, ia.size, step):
            A = a[ia[s : s + step]]
            out[s : s + step] = np.abs(A[:, None] - B[None, :]).max(axis=3).sum(axis=2)
        return out
    if ia.size != ib.size:
        raise ParameterError(
            f"src_vertices and dst_vertices must have the same length ({ia.size} != {ib.size}) "
            "unless pairwise=True"
        )
    return np.abs(a[ia] - b[ib]).max(axis=2).sum(axis=1)


def _as_cube(desc: object, n_times: int | None, what: str) -> np.ndarray:
    if isinstance(desc, (list, tuple)):
        arrs = [np.asarray(d, dtype=np.float64) for d in desc]
        if not arrs:
            raise ParameterError(f"{what} is an empty list")
        arrs = [d[:, None] if d.ndim == 1 else d for d in arrs]
        return np.stack(arrs, axis=1)
    d = np.asarray(desc, dtype=np.float64)
    if d.ndim == 3:
        return d
    if d.ndim == 2:
        if n_times is None:
            raise ParameterError(f"{what} is 2-D: pass n_times (tau) to split it into keypoints")
        if n_times < 1 or d.shape[1] % n_times:
            raise ParameterError(f"{what} has {d.shape[1]} columns, not a multiple of n_times={n_times}")
        return d.reshape(d.shape[0], d.shape[1] // n_times, n_times)
    raise ParameterError(f"{what} must be (n, M*tau), (n, M, tau) or a list of (n, tau) arrays")
