"""Where ``best-of`` runs its extrinsic matchers again: in the frame a map estimates, and on the two shapes'
canonical forms.

- :func:`estimated_frame`: the source turned by the rigid rotation that best carries it onto its images under a
  map judged to keep orientation (scans turned between captures).
- :func:`canonical_pair`: both shapes' canonical forms (pose removed), the source's turned onto the target's along a
  map.

Why and how each was decided: the module docstring of :mod:`~shape_toolkit.plugins.matching.dense.best_of`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from shape_toolkit.core.geometry import rigid_rotation
from shape_toolkit.core.inspect import connected_components
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.surface import cloud_surface, sheet_surface
from shape_toolkit.errors import InvalidShapeError
from shape_toolkit.features.canonical import canonical_form
from shape_toolkit.plugins.matching.orientation import orientation_verdict

__all__ = ["estimated_frame", "canonical_pair"]


def _degrees(R: np.ndarray) -> float:
    """The angle of the rotation ``R`` ``(3, 3)``, in degrees."""
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def estimated_frame(source: Shape, target: Shape, target_of: np.ndarray, mass: np.ndarray, name: str,
                    same: float = 0.0) -> tuple[Shape | None, dict[str, Any]]:
    """The source turned into the frame a map ``target_of`` ``(n_s,)`` estimates: the rigid rotation that best
    carries the source's vertices (weights ``mass`` ``(n_s,)``) onto their images, when the map is judged to keep
    orientation (:func:`~shape_toolkit.plugins.matching.orientation.orientation_verdict`), and what was decided
    (``name``: the map's origin, for ``info``). None instead of a shape when the map is not judged to keep
    orientation, or when the frame is turned by less than ``same`` degrees from the given one."""
    t = np.asarray(target_of)
    verdict = orientation_verdict(source, target, t)
    frame: dict[str, Any] = {"from": name, "verdict": verdict["verdict"], "z": verdict["z"]}
    ok = np.flatnonzero(t >= 0)
    if verdict["verdict"] != "preserving" or len(ok) < 3:
        return None, frame
    X = np.asarray(source.vertices, dtype=np.float64)
    R = rigid_rotation(X[ok], np.asarray(target.vertices, dtype=np.float64)[t[ok]], mass[ok])
    frame["rotation_degrees"] = _degrees(R)
    if frame["rotation_degrees"] < same:
        frame["same_as_given"] = True
        return None, frame
    return source.with_vertices(X @ R.T), frame


def canonical_pair(source: Shape, target: Shape, t: np.ndarray, mass: np.ndarray,
                   name: str) -> tuple[tuple[Shape, Shape], dict[str, Any]]:
    """The two shapes' canonical forms (:func:`~shape_toolkit.features.canonical.canonical_form`), the
    source's turned onto the target's by the rigid rotation that best carries it along the map ``t``
    ``(n_s,)`` (the best so far, from matcher ``name``), and what was decided."""
    ok = np.flatnonzero(t >= 0)
    if len(ok) < 3:
        raise InvalidShapeError("canonical forms: the best map so far matches fewer than 3 vertices")
    surfaces = [cloud_surface(source), cloud_surface(target)]
    if not all(connected_components(s)[0] == 1 for s in surfaces):  # the fans fell apart: the sheet triangles
        surfaces = [sheet_surface(source), sheet_surface(target)]
    Ys, Yt = canonical_form(surfaces[0]), canonical_form(surfaces[1])
    R = rigid_rotation(Ys[ok], Yt[t[ok]], mass[ok])
    return ((source.with_vertices(Ys @ R.T), target.with_vertices(Yt)),
            {"from": name, "rotation_degrees": _degrees(R)})
