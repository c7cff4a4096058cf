"""Keypoint matching by photometric consistency (thesis 7.2.2): for shapes of one sequence, the
surface colours move with the surface, so a keypoint's colour neighbourhood identifies it even
where the topology changed (merged hands), unlike spectral distances.

The thesis adapts the SIFT-based matching of Ahmed et al. 2008 on textured meshes. Here each
keypoint gets an intrinsic, rotation-invariant colour descriptor -- the mean and the standard
deviation of the vertex colours on ``n_rings`` concentric geodesic rings (k-ring shells of the
mesh graph, radius ``ring_width`` rings each) -- and matches are mutual nearest neighbours that
pass Lowe's ratio test. The colours are the shapes' own (``Shape.colors``, read from PLY, COFF,
OBJ vertex colours or an OBJ texture by :func:`shape_toolkit.io.mesh.load_shape`), or per-vertex
``(n, channels)`` arrays (any colour space) passed to :meth:`PhotometricMatcher.match`, which take
precedence. A pipeline uses it as its seed stage with ``[sparse] plugin = "photometric"`` (preset
``topo-robust-photometric``).
"""

from __future__ import annotations

import numpy as np

from shape_toolkit.api.interfaces import SparseMatcher
from shape_toolkit.api.params import Interval, Param
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.features.geodesics import k_rings
from shape_toolkit.plugins._params import POSITIVE_INT
from shape_toolkit.plugins.matching.validation import check_keypoints

__all__ = ["PhotometricMatcher", "ring_color_descriptors", "geometric_texture"]

#: most rings of the colour descriptor (``n_rings``'s doc)
MAX_RINGS = 100


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
                f"the photometric matcher needs per-vertex colours of the {what} shape: "
                f"{shape!r} has none (load a coloured PLY/COFF/OBJ, use Shape.with_colors, "
                f"or pass {what}_colors=(n, 3))"
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
    (shell 0 includes the vertex itself; an empty shell, on a small mesh, takes the vertex's own
    colour and zero deviation)."""
    v = np.asarray(vertices, dtype=np.int64).ravel()
    c = np.asarray(colors, dtype=np.float64)
    if v.size == 0:
        return np.zeros((0, 2 * int(n_rings) * c.shape[1]))
    radii = [(r + 1) * int(ring_width) for r in range(int(n_rings))]
    balls = [b.astype(np.float64) for b in k_rings(shape, radii, v)]
    feats, inner = [], None
    for ball in balls:
        shell = ball if inner is None else ball - inner
        shell.eliminate_zeros()
        inner = ball
        cnt = np.asarray(shell.sum(axis=1)).ravel()
        empty = cnt == 0
        safe = np.where(empty, 1.0, cnt)[:, None]
        mean = (shell @ c) / safe
        var = np.maximum((shell @ (c * c)) / safe - mean * mean, 0.0)
        mean[empty], var[empty] = c[v[empty]], 0.0
        feats += [mean, np.sqrt(var)]
    return np.concatenate(feats, axis=1)


class PhotometricMatcher(SparseMatcher):
    """Mutual nearest neighbours of ring colour descriptors (:func:`ring_color_descriptors`)
    with Lowe's ratio test ``ratio``, on ``source_colors`` and ``target_colors`` when given, else
    on ``source.colors`` and ``target.colors``. When only one shape is coloured it raises (a
    colour lost on the way, e.g. by a corruption, must not pass unnoticed). When neither is,
    ``require_colors=True`` raises; ``False`` (default, so the matcher runs wherever a sparse
    matcher does) falls back to :func:`geometric_texture` on both shapes. Uses no spectrum
    (``spectrum_spec()`` is None).

    ``refine_rings``: keypoint detectors are not exactly repeatable (least of all where the
    topology changed, which moves heat-diffusion maxima), colours are; so each matched target
    keypoint moves to the vertex within ``refine_rings`` rings of it whose descriptor is nearest
    the source keypoint's, when that distance beats the keypoint's own by the ratio-test margin
    (``< ratio *`` it; so colour noise alone does not move a well-placed keypoint). None: the
    descriptor's own radius ``n_rings * ring_width``; 0: keep the keypoints. Matches stay
    one-to-one (a target vertex reached twice keeps the closer descriptor)."""

    parameter_constraints = {
        "n_rings": Param(Interval(int, 1, MAX_RINGS), doc="rings of the colour descriptor (at most 100: each adds "
                         "2 x channels columns to the (source keypoints, target keypoints, columns) distance array, "
                         "100 rings of RGB at 200 keypoints a side take 190 MB; rings past the mesh's extent are "
                         "empty and only repeat the keypoint's own colour)"),
        "ring_width": Param(POSITIVE_INT, doc="mesh edges per ring (any: the growth of the rings stops, exactly, "
                            "once they cover the mesh)"),
        "ratio": Param(Interval(float, 0, 1, closed="right"), doc="Lowe's ratio test"),
        "require_colors": Param(bool, doc="raise when neither shape has colours (else geometric texture)"),
        "refine_rings": Param(None, Interval(int, 0), doc="rings searched to move a matched target keypoint"),
    }

    def __init__(self, n_rings: int = 4, ring_width: int = 2, ratio: float = 0.8, require_colors: bool = False,
                 refine_rings: int | None = None):
        self.n_rings = n_rings
        self.ring_width = ring_width
        self.ratio = ratio
        self.require_colors = require_colors
        self.refine_rings = refine_rings

    def match(self, source, target, source_keypoints, target_keypoints, *,
              source_spectrum=None, target_spectrum=None, source_colors=None, target_colors=None) -> np.ndarray:
        """Matched ``[source_vertex, target_vertex]`` pairs, int64 ``(q, 2)``."""
        refine = int(self.n_rings) * int(self.ring_width) if self.refine_rings is None else self.refine_rings
        source.require_faces("photometric matching")
        target.require_faces("photometric matching")
        if (source_colors is None) != (target_colors is None):
            raise ParameterError("give colours for both shapes or for neither")
        if source_colors is None:
            source_colors, target_colors = source.colors, target.colors
            if (source_colors is None) != (target_colors is None):
                have, lack = (source, target) if target_colors is None else (target, source)
                raise ParameterError(
                    f"photometric matching: {have!r} carries colours but {lack!r} has none; "
                    "colour both shapes (Shape.with_colors) or pass source_colors and target_colors"
                )
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
            pairs.append((a, b))
        if not pairs:
            return np.zeros((0, 2), dtype=np.int64)
        ia, ib = np.asarray(pairs, dtype=np.int64).T
        src, tgt, cost = kp_s[ia], kp_t[ib], D[ia, ib]
        if refine > 0:
            moved, moved_cost = self._refine(target, ct, ds[ia], tgt, int(refine))
            better = moved_cost < self.ratio * cost  # a move must win by the ratio test's margin
            tgt, cost = np.where(better, moved, tgt), np.where(better, moved_cost, cost)
        order = np.lexsort((src, cost))  # one-to-one: the closest descriptor keeps a shared target
        _, first = np.unique(tgt[order], return_index=True)
        keep = np.sort(order[first])
        return np.column_stack([src[keep], tgt[keep]]).astype(np.int64)

    def _refine(self, target: Shape, colors: np.ndarray, desc: np.ndarray, tgt: np.ndarray,
                rings: int) -> tuple[np.ndarray, np.ndarray]:
        """Move each target vertex to the vertex of its ``rings``-ring whose descriptor is nearest
        the matching row of ``desc``; the new vertices and their descriptor distances."""
        ball = k_rings(target, [rings], tgt)[0]
        cand = np.unique(ball.indices)
        dc = ring_color_descriptors(target, colors, cand, int(self.n_rings), int(self.ring_width))
        where = np.searchsorted(cand, ball.indices)
        rows = np.repeat(np.arange(len(tgt)), np.diff(ball.indptr))
        d = np.sqrt(((dc[where] - desc[rows]) ** 2).sum(axis=1))
        new, cost = tgt.copy(), np.empty(len(tgt))
        for i in range(len(tgt)):
            lo, hi = ball.indptr[i], ball.indptr[i + 1]
            j = lo + int(np.argmin(d[lo:hi]))
            new[i], cost[i] = ball.indices[j], d[j]
        return new, cost
