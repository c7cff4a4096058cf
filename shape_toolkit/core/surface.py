"""The local surface of a point cloud: consistently oriented normals and a tufted triangle fan
around every point, for the operators that need faces (gradients, orientation, normals).

A cloud has no faces, so a functional map's orientation term (``n x grad f``) and the test of a
map's orientation cannot be formed on it. Around each point, its nearest neighbours projected to
the tangent plane and sorted by angle give a fan of triangles (its approximate one-ring), wound
counter-clockwise about the point's normal; the normals are oriented consistently over the cloud
(Open3D's minimum-spanning-tree propagation) and then outwards (positive signed volume). Each
surface triangle appears in up to three fans: a uniform weight, which area-normalised operators do
not see. This is the idea of the tufted cover of local Delaunay triangulations (Sharp and Crane
2020) with a plain angular fan instead of the Delaunay one.
"""

from __future__ import annotations

import numpy as np

from shape_toolkit.core.geometry import signed_volume
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import InvalidShapeError

__all__ = ["cloud_surface", "FAN_NEIGHBORS"]

#: neighbours of each point in its fan (a one-ring has about 6)
FAN_NEIGHBORS = 8


def _oriented_normals(points: np.ndarray, k: int) -> np.ndarray:
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.array(points, dtype=np.float64)))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=max(k, 10)))
    pc.orient_normals_consistent_tangent_plane(max(k, 10))
    n = np.asarray(pc.normals, dtype=np.float64)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def cloud_surface(shape: Shape, n_neighbors: int = FAN_NEIGHBORS) -> Shape:
    """``shape`` itself when it is a mesh; for a point cloud of ``n`` points, the same points with
    the triangles ``(m, 3)`` of every point's fan (module docstring), oriented outwards.
    :class:`InvalidShapeError` for a cloud too small or too flat to have a surface."""
    if shape.is_mesh:
        return shape
    from scipy.spatial import cKDTree

    P = np.asarray(shape.vertices, dtype=np.float64)
    n = len(P)
    k = int(min(n_neighbors, n - 1))
    if k < 3:
        raise InvalidShapeError(f"{shape!r}: a local surface needs at least 4 points")
    normals = _oriented_normals(P, k)
    _, nb = cKDTree(P).query(P, k + 1)
    nb = nb[:, 1:]  # (n, k), self excluded
    # tangent basis per point, neighbours' angles about the normal
    a = np.where(np.abs(normals[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    e1 = np.cross(normals, a)
    e1 /= np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-300)
    e2 = np.cross(normals, e1)
    d = P[nb] - P[:, None, :]  # (n, k, 3)
    ang = np.arctan2(np.einsum("nkc,nc->nk", d, e2), np.einsum("nkc,nc->nk", d, e1))
    order = np.argsort(ang, axis=1)
    nb, ang = np.take_along_axis(nb, order, 1), np.take_along_axis(ang, order, 1)
    nxt = np.roll(np.arange(k), -1)
    gap = (ang[:, nxt] - ang) % (2 * np.pi)
    gap[:, -1] = np.where(gap[:, -1] == 0, 2 * np.pi, gap[:, -1])
    keep = gap < np.pi  # a wedge wider than a half turn is a boundary, not a triangle
    centre = np.repeat(np.arange(n)[:, None], k, axis=1)
    F = np.stack([centre[keep], nb[keep], nb[:, nxt][keep]], axis=1)
    # counter-clockwise about the centre's normal by construction (increasing angle); drop slivers
    cr = np.cross(P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]])
    area2 = np.linalg.norm(cr, axis=1)
    F = F[area2 > 1e-12 * max(float(np.median(area2)), 1e-300)]
    if len(F) == 0:
        raise InvalidShapeError(f"{shape!r}: the points span no surface (all collinear?)")
    if signed_volume(P, F) < 0:
        F = F[:, [0, 2, 1]]
    return Shape(P, F, name=shape.name)
