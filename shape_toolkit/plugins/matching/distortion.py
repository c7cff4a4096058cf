"""How far a point map is from an isometry, without ground truth: the geodesic distortion of :func:`map_distortion`,
which ranks candidate maps (``eigvec-alignment``'s candidate alignments and their rotations).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from shape_toolkit.core.geometry import farthest_point_sampling
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.validation import check_random_state

__all__ = ["DISTORTION_ANCHORS", "DISTORTION_PROBES", "map_distortion"]

#: source anchors and probe vertices of :func:`map_distortion`
DISTORTION_ANCHORS, DISTORTION_PROBES = 24, 400


def map_distortion(
    source: Shape, target: Shape, target_of: np.ndarray, *, n_anchors: int = DISTORTION_ANCHORS,
    n_probes: int = DISTORTION_PROBES, random_state: Any = 0, source_distances: np.ndarray | None = None,
    statistic: str = "mean",
) -> tuple[float, np.ndarray]:
    """How far a map ``target_of`` ``(n_source,)`` (every entry a target vertex) is from an isometry: the mean
    (``statistic``: or the median), over ``n_anchors`` farthest-point source anchors and ``n_probes`` random source
    probes (``random_state``), of ``|d_S(a, p) - d_T(t(a), t(p))|``, graph geodesics along the edges in units of
    ``sqrt(area)`` of each shape (pairs a shortcut or a hole disconnects do not count). A mirror image distorts as
    little as the map. The mean counts a map wrong on one part (two limbs swapped: a minority of the pairs), which
    the median does not see. Returns the value and the source distances ``(n_anchors, n_probes)`` to pass back as
    ``source_distances``."""
    from shape_toolkit.features.geodesics import geodesic_distances

    if statistic not in ("mean", "median"):
        raise ParameterError(f"statistic must be 'mean' or 'median', got {statistic!r}")
    t = np.asarray(target_of, dtype=np.int64)
    if t.shape != (source.n_vertices,) or t.min() < 0:
        raise ParameterError("map_distortion needs a complete map: one target vertex per source vertex")
    anchors = farthest_point_sampling(np.asarray(source.vertices), min(int(n_anchors), source.n_vertices))
    probes = np.sort(check_random_state(random_state).choice(
        source.n_vertices, min(int(n_probes), source.n_vertices), replace=False))
    if source_distances is None:
        source_distances = geodesic_distances(source, anchors, probes, method="dijkstra", cache=False)
        source_distances = source_distances / np.sqrt(source.area)
    dt = geodesic_distances(target, t[anchors], t[probes], method="dijkstra", cache=False) / np.sqrt(target.area)
    ok = np.isfinite(dt) & np.isfinite(source_distances)
    if not ok.any():
        return float("inf"), source_distances
    err = np.abs(dt - source_distances)[ok]
    return float(err.mean() if statistic == "mean" else np.median(err)), source_distances
