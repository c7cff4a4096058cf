"""Keypoint matching by photometric consistency (thesis 7.2.2): for shapes of one sequence, the
surface colours move with the surface, so a keypoint's colour neighbourhood identifies it even
where the topology changed (merged hands), unlike spectral distances.

The thesis adapts the SIFT-based matching of Ahmed et al. 2008 on textured meshes. Here each
keypoint gets an intrinsic, rotation-invariant colour descriptor -- the mean and the standard
deviation of the vertex colours on ``n_rings`` concentric geodesic rings (k-ring shells of the
mesh graph, radius ``ring_width`` rings each) -- and matches are mutual nearest neighbours that
pass Lowe's ratio test. Colours are an argument of :meth:`PhotometricMatcher.match` (per-vertex
``(n, 3)`` arrays, any colour space), since :class:`~shape_toolkit.core.shape.Shape` has no
colour attribute yet.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from shape_toolkit.api.hookspecs import hookimpl
from shape_toolkit.api.interfaces import SparseMatcher
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.plugins.matching._common import check_keypoints

__all__ = ["PhotometricMatcher", "ring_color_descriptors", "geometric_texture"]


def geometric_texture(shape: Shape) -> np.ndarray:
    """One-channel stand-in for colours, ``(n, 1)``: the length of the umbrella Laplacian of the
    coordinates (vertex minus the mean of its neighbours) in mean edge lengths -- a curvature
    proxy that moves with the surface like a texture."""
    from shape_toolkit.features.geodesics import adjacency

    A = adjacency(shape).tocsr().astype(np.float64)
    deg = np.maximum(np.asarray(A.sum(axis=1)).ravel(), 1.0)
    v = np.asarray(shape.vertices, dtype=np.float64)
    lap = v - (A @ v) / deg[:, None]
    return (np.linalg.norm(lap, axis=1) / max(shape.mean_edge_length, 1e-300))[:, None]


def _check_colors(colors: np.ndarray | None, shape: Shape, what: str, required: bool) -> np.ndarray:
    n = shape.n_vertices
    if colors is None:
        if required:
            raise ParameterError(
                f"the photometric matcher needs per-vertex colours of the {what} shape "
                f"({what}_colors=(n, 3) array); Shape does not carry colours"
            )
        return geometric_texture(shape)
    c = np.asarray(colors, dtype=np.float64)
    if c.ndim == 1:
        c = c[:, None]
    if c.ndim != 2 or c.shape[0] != n or not np.isfinite(c).all():
        raise ParameterError(f"{what} colours must be a finite ({n}, channels) array, got shape {c.shape}")
    return c


def ring_color_descriptors(
    shape: Shape, colors: np.ndarray, vertices: np.ndarray, n_rings: int = 4, ring_width: int = 2
) -> np.ndarray:
    """Descriptor ``(len(vertices), 2 * n_rings * channels)``: mean and standard deviation of
    ``colors`` on the shells ``[r * ring_width, (r + 1) * ring_width)`` rings around each vertex
    (shell 0 includes the vertex itself)."""
    from shape_toolkit.features.geodesics import adjacency

    A = adjacency(shape).tocsr()
    A = ((A + sp.eye(A.shape[0], format="csr")) > 0).astype(np.float64)
    c = np.asarray(colors, dtype=np.float64)
    out = []
    for v in np.asarray(vertices, dtype=np.int64):
        reached = np.zeros(shape.n_vertices, dtype=bool)
        front = np.zeros(shape.n_vertices)
        front[v] = 1.0
        feats = []
        for _ in range(int(n_rings)):
            shell = np.zeros(shape.n_vertices, dtype=bool)
            for _ in range(int(ring_width)):
                front = (A @ front > 0).astype(np.float64)
                new = (front > 0) & ~reached
                shell |= new
                reached |= new
            vals = c[shell] if shell.any() else c[[v]]
            feats += [vals.mean(axis=0), vals.std(axis=0)]
        out.append(np.concatenate(feats))
    return np.asarray(out)


class PhotometricMatcher(SparseMatcher):
    """Mutual nearest neighbours of ring colour descriptors (:func:`ring_color_descriptors`)
    with Lowe's ratio test ``ratio``, on ``source_colors`` and ``target_colors``. Without
    colours, ``require_colors=True`` raises; ``False`` (default, so the matcher runs wherever a
    sparse matcher does) falls back to :func:`geometric_texture` on both shapes. Uses no
    spectrum (``spectrum_spec()`` is None)."""

    def __init__(self, n_rings: int = 4, ring_width: int = 2, ratio: float = 0.8, require_colors: bool = False):
        self.n_rings = n_rings
        self.ring_width = ring_width
        self.ratio = ratio
        self.require_colors = require_colors

    def match(self, source, target, source_keypoints, target_keypoints, *,
              source_spectrum=None, target_spectrum=None, source_colors=None, target_colors=None) -> np.ndarray:
        """Matched ``[source_vertex, target_vertex]`` pairs, int64 ``(q, 2)``."""
        if int(self.n_rings) < 1 or int(self.ring_width) < 1 or not 0 < self.ratio <= 1:
            raise ParameterError("need n_rings >= 1, ring_width >= 1 and 0 < ratio <= 1")
        source.require_faces("photometric matching")
        target.require_faces("photometric matching")
        if (source_colors is None) != (target_colors is None):
            raise ParameterError("give colours for both shapes or for neither")
        cs = _check_colors(source_colors, source, "source", bool(self.require_colors))
        ct = _check_colors(target_colors, target, "target", bool(self.require_colors))
        if cs.shape[1] != ct.shape[1]:
            raise ParameterError(f"colour channels differ: {cs.shape[1]} and {ct.shape[1]}")
        kp_s = check_keypoints(source_keypoints, source.n_vertices, "source", minimum=1)
        kp_t = check_keypoints(target_keypoints, target.n_vertices, "target", minimum=1)
        ds = ring_color_descriptors(source, cs, kp_s, int(self.n_rings), int(self.ring_width))
        dt = ring_color_descriptors(target, ct, kp_t, int(self.n_rings), int(self.ring_width))
        D = np.sqrt(((ds[:, None, :] - dt[None, :, :]) ** 2).sum(axis=2))
        best_t = D.argmin(axis=1)
        best_s = D.argmin(axis=0)
        pairs = []
        for a, b in enumerate(best_t):
            if best_s[b] != a:
                continue
            if D.shape[1] > 1:
                second = np.partition(D[a], 1)[1]
                if D[a, b] > self.ratio * second:
                    continue
            pairs.append((kp_s[a], kp_t[b]))
        return np.asarray(pairs, dtype=np.int64).reshape(-1, 2)


@hookimpl
def toolkit_sparse_matchers() -> dict[str, type]:
    return {"photometric": PhotometricMatcher}
