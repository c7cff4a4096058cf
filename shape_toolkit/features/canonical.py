"""Canonical forms (Elad and Kimmel 2003): a shape embedded in 3-D so that Euclidean distances approximate its
geodesic distances. Bending (a change of pose that keeps lengths) leaves the geodesic distances, hence the
canonical form, unchanged up to a rigid motion: a person lying and the same person standing have nearly the
same canonical form. An extrinsic matcher that needs two shapes in one pose and one frame (``shell-alignment``)
can then run on the canonical forms, once a rotation between them is known.

The embedding is landmark MDS (de Silva and Tenenbaum 2004): classical MDS of the Dijkstra distances between
``landmarks`` farthest points, every vertex then placed from its distances to the landmarks (a linear
triangulation), so the cost is ``landmarks`` Dijkstra runs, ``O(L n log n)``, and the memory ``L n``. MDS
cannot tell a shape from its mirror image; the mirror that keeps the input's orientation (the sign of the
enclosed signed volume) is returned, so a map between canonical forms keeps the handedness of the shapes.
"""

from __future__ import annotations

import numpy as np

from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import InvalidShapeError, ParameterError
from shape_toolkit.features.geodesics import geodesic_farthest_points

__all__ = ["CANONICAL_LANDMARKS", "canonical_form"]

#: landmarks of the MDS: far more than the few degrees of freedom of a pose, few enough to cost ~0.2 s at 5k
CANONICAL_LANDMARKS = 150


def _signed_volume(X: np.ndarray, faces: np.ndarray) -> float:
    """The volume enclosed by the faces (oriented), about the centroid of ``X`` ``(n, 3)``."""
    P = X - X.mean(axis=0)
    return float(np.einsum("ij,ij->i", P[faces[:, 0]], np.cross(P[faces[:, 1]], P[faces[:, 2]])).sum() / 6.0)


def canonical_form(shape: Shape, landmarks: int = CANONICAL_LANDMARKS) -> np.ndarray:
    """The canonical form of a connected triangle mesh: float64 ``(n, 3)`` coordinates (length units of the
    shape) whose Euclidean distances approximate the Dijkstra geodesic distances along its edges; axes in
    decreasing variance, centred on the landmarks' mean, oriented like the input (module docstring).
    Deterministic and independent of the vertex order and of rigid motions of the input, up to a rigid
    motion of the output. :class:`InvalidShapeError` for a point cloud or a disconnected mesh."""
    faces = shape.require_faces("a canonical form (its orientation is the mesh's)")
    if isinstance(landmarks, bool) or not isinstance(landmarks, (int, np.integer)) or landmarks < 4:
        raise ParameterError(f"landmarks must be an integer >= 4, got {landmarks!r}")
    X = np.asarray(shape.vertices, dtype=np.float64)
    L = int(min(landmarks, shape.n_vertices))
    # the first landmark depends on the geometry only: the vertex farthest from the centroid
    start = int(np.argmax(((X - X.mean(axis=0)) ** 2).sum(axis=1)))
    ids, D = geodesic_farthest_points(shape, L, start=start, return_distances=True)
    if not np.all(np.isfinite(D)):
        raise InvalidShapeError(f"{shape!r} is not connected: a canonical form needs one component")
    D2 = D**2  # (L, n)
    Dll = D2[:, ids]
    J = np.eye(L) - 1.0 / L
    evals, V = np.linalg.eigh(-0.5 * J @ Dll @ J)
    evals, V = evals[::-1][:3], V[:, ::-1][:, :3]
    keep = evals > 1e-12 * max(float(evals[0]), 1e-300)  # a flat shape has fewer than 3 axes
    pinv = np.zeros((L, 3))
    pinv[:, keep] = V[:, keep] / np.sqrt(evals[keep])
    Y = -0.5 * (D2 - Dll.mean(axis=1, keepdims=True)).T @ pinv
    if _signed_volume(Y, faces) * _signed_volume(X, faces) < 0:  # MDS returned the mirror image
        Y[:, 2] = -Y[:, 2]
    return Y
