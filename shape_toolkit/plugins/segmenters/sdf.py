"""Shape Diameter Function segmentation (Shapira, Shamir and Cohen-Or 2008; CGAL's
``segmentation_from_sdf_values``), and a ``smoothed`` wrapper that applies the same graph cut after any
segmenter.

``sdf``:

1. the SDF of every face: rays from the face centroid into the shape, in a cone of ``cone_angle``
   (120 degrees) around the inward normal, ``n_rays`` fixed directions (a golden-angle spiral, so the
   SDF itself has no randomness), cast with Open3D's ray-casting scene; only hits on the back side of a
   face count (the ray leaves the solid there); per face the rays farther than one standard deviation
   from their median are dropped and the rest averaged. When the normal is flipped (more valid hits
   along +N), the other side is used, so inconsistently oriented PSB meshes work;
2. a few steps of a bilateral filter over the dual graph, robust min-max normalisation to ``[0, 1]``
   and CGAL's log normalisation ``log(alpha x + 1) / log(alpha + 1)``;
3. a 1-D Gaussian mixture with ``k`` components (``random_state``: its initialisation), fitted on the
   sorted values (so the fit does not depend on the face order);
4. the alpha-expansion graph cut of :func:`shape_toolkit.features.smoothing.smooth_labels` with unary
   costs ``-log p`` and the concavity-aware dihedral boundary cost.

Labels are per face (``face_labels`` of the returned :class:`~shape_toolkit.results.segmentation.Segmentation`,
what PSB scores); its vertex labels are those of the largest incident area. Clusters are numbered by
increasing SDF. It needs no spectrum (``spectrum_spec()`` is None). A mesh of several pieces of the dual
graph is segmented piece by piece (the SDF of each piece on its own), ``n_segments`` shared by area
(:class:`~shape_toolkit.plugins.segmenters.per_component.PerComponent`).

``smoothed``: ``base`` (a registry name or a segmenter instance, sklearn-style nested plugin) segments,
its face labels (its own, or the vertex majority) are smoothed by
:func:`~shape_toolkit.features.smoothing.smooth_labels`.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import scipy.sparse as sp

from shape_toolkit.api.interfaces import BasePlugin, Segmenter
from shape_toolkit.api.params import RANDOM_STATE, Interval, Param, PluginRef
from shape_toolkit.core.cache import LRUCache
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.features.smoothing import EPS, dual_adjacency, dual_graph, relative_affinities, smooth_labels
from shape_toolkit.plugins._params import N_INIT, N_SEGMENTS, POSITIVE
from shape_toolkit.plugins.segmenters._bounds import GRAPH_CUT_CONVEX_FACTOR, smoothing_lambda
from shape_toolkit.plugins.segmenters.base import BaseSegmenter
from shape_toolkit.plugins.segmenters.kmeans import single_thread
from shape_toolkit.plugins.segmenters.merging import merge_to_segments
from shape_toolkit.results.segmentation import Segmentation
from shape_toolkit.validation import seed_of

_GOLDEN = np.pi * (3.0 - np.sqrt(5.0))
#: most rays per face (n_rays): sqrt(pi sr / 10,000) = 1 degree between rays over the default cone
MAX_RAYS = 10_000
#: most bilateral steps (filter_iterations)
MAX_FILTER_ITERATIONS = 1_000
#: most rings of label spreading (smoothed's spread)
MAX_SPREAD = 1_000


def _cone_directions(n_rays: int, cone_angle: float) -> tuple[np.ndarray, np.ndarray]:
    """``n_rays`` unit directions ``(n, 3)`` in the local frame (axis +z) evenly spread over the cap of
    half-angle ``cone_angle / 2`` (golden-angle spiral), and their angles to the axis."""
    i = np.arange(n_rays) + 0.5
    cos_half = np.cos(cone_angle / 2.0)
    c = 1.0 - i / n_rays * (1.0 - cos_half)
    s = np.sqrt(np.maximum(0.0, 1.0 - c * c))
    phi = i * _GOLDEN
    return np.column_stack([s * np.cos(phi), s * np.sin(phi), c]), np.arccos(np.clip(c, -1, 1))


def face_sdf(shape: Shape, n_rays: int = 25, cone_angle: float = 2.0 * np.pi / 3.0) -> np.ndarray:
    """Raw Shape Diameter Function per face, float64 ``(m,)`` in the shape's length units; NaN where no
    ray found the other side of the shape (open or degenerate parts)."""
    import open3d as o3d

    faces = shape.require_faces("the shape diameter function")
    norm, _, diag = shape.normalized()
    v = norm.vertices
    m = len(faces)
    N = np.asarray(shape.face_normals)
    P = v[faces].mean(axis=1)
    # a frame per face: t1 along the first edge projected on the face plane
    e = v[faces[:, 1]] - v[faces[:, 0]]
    t1 = e - np.einsum("ij,ij->i", e, N)[:, None] * N
    ln = np.linalg.norm(t1, axis=1, keepdims=True)
    t1 = np.divide(t1, ln, out=np.zeros_like(t1), where=ln > 0)
    t2 = np.cross(N, t1)
    local, _ = _cone_directions(int(n_rays), float(cone_angle))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(faces.astype(np.uint32)))
    eps = 1e-6
    best = np.full(m, np.nan)
    best_hits = np.full(m, -1)
    # faces a block at a time, 200,000 rays: with their temporaries (~300 bytes a ray) about 60 MB whatever m
    step = max(1, 200_000 // max(1, len(local)))
    for a in range(0, m, step):
        f = np.arange(a, min(m, a + step))
        for side in (-1.0, 1.0):  # inward first (ties keep it), then the flipped normal
            axis = side * N[f]
            d = (local[None, :, 0:1] * t1[f, None, :] + local[None, :, 1:2] * (side * t2[f])[:, None, :]
                 + local[None, :, 2:3] * axis[:, None, :])  # (block, r, 3)
            o = np.broadcast_to((P[f] + eps * axis)[:, None, :], d.shape)
            rays = np.concatenate([o, d], axis=2).reshape(-1, 6).astype(np.float32)
            hit = scene.cast_rays(o3d.core.Tensor(rays), nthreads=1)
            t = hit["t_hit"].numpy().astype(np.float64).reshape(len(f), -1)
            prim = hit["primitive_ids"].numpy().astype(np.int64).reshape(len(f), -1)
            valid = np.isfinite(t) & (prim != f[:, None]) & (prim < m)
            hn = N[np.where(valid, prim, 0)]
            # the back side of a face (leaving the solid); with flipped normals, the front side
            valid &= -side * np.einsum("mrk,mrk->mr", d, hn) > 0
            R = np.where(valid, t, np.nan)
            nh = valid.sum(axis=1)
            with np.errstate(invalid="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                med = np.nanmedian(R, axis=1)
                sd = np.nanstd(R, axis=1)
                keep = np.abs(R - med[:, None]) <= sd[:, None] + 1e-12
                val = np.nansum(np.where(keep, R, 0.0), axis=1) / np.maximum(keep.sum(axis=1), 1)
            val[nh == 0] = np.nan
            better = nh > best_hits[f]
            best[f[better]] = val[better]
            best_hits[f[better]] = nh[better]
    return best * diag


def _fill_and_filter(x: np.ndarray, A: sp.csr_matrix, areas: np.ndarray, iterations: int) -> np.ndarray:
    """NaNs filled from their neighbours (else the median), then ``iterations`` bilateral steps."""
    x = x.copy()
    for _ in range(50):
        bad = ~np.isfinite(x)
        if not bad.any():
            break
        good = np.where(bad, 0.0, x)
        s = A @ good
        c = A @ (~bad).astype(np.float64)
        fill = bad & (c > 0)
        if not fill.any():
            break
        x[fill] = s[fill] / c[fill]
    if not np.isfinite(x).all():
        x[~np.isfinite(x)] = np.nanmedian(x) if np.isfinite(x).any() else 1.0
    if iterations <= 0 or A.nnz == 0:
        return x
    coo = (A + sp.identity(A.shape[0], format="csr")).tocoo()
    r, c = coo.row, coo.col
    sigma = 0.5 * float(np.std(x)) + 1e-12
    for _ in range(int(iterations)):
        w = areas[c] * np.exp(-((x[r] - x[c]) ** 2) / (2.0 * sigma * sigma))
        num = np.bincount(r, weights=w * x[c], minlength=len(x))
        den = np.bincount(r, weights=w, minlength=len(x))
        new = np.where(den > 0, num / np.maximum(den, 1e-300), x)
        if np.array_equal(new, x):  # a fixed point: every further step returns it unchanged
            break
        x = new
    return x


#: normalised SDFs of the last 4 meshes and parameter sets (:func:`normalized_sdf`; sweeps reuse the rays)
SDF_CACHE = LRUCache(4, name="sdf")


def normalized_sdf(
    shape: Shape,
    n_rays: int = 25,
    cone_angle: float = 2.0 * np.pi / 3.0,
    filter_iterations: int = 3,
    log_alpha: float = 4.0,
) -> np.ndarray:
    """Per-face SDF, filled, bilateral-filtered, normalised to ``[0, 1]`` (1st-99th percentile range,
    clipped) and log-normalised as in CGAL: ``log(alpha x + 1) / log(alpha + 1)``."""
    faces = shape.require_faces("the shape diameter function")
    key = (shape.content_hash, int(n_rays), float(cone_angle), int(filter_iterations), float(log_alpha))
    hit = SDF_CACHE.get(key)
    if hit is not None:
        return hit.copy()
    raw = face_sdf(shape, n_rays, cone_angle)
    pairs, _, _ = dual_graph(faces)
    A = dual_adjacency(len(faces), pairs, np.ones(len(pairs)))
    areas = np.asarray(shape.face_areas, dtype=np.float64) + 1e-300
    x = _fill_and_filter(raw, A, areas, filter_iterations)
    lo, hi = np.percentile(x, [1.0, 99.0])
    x = np.clip((x - lo) / (hi - lo), 0.0, 1.0) if hi > lo else np.zeros_like(x)
    if log_alpha > 0:
        x = np.log1p(log_alpha * x) / np.log1p(log_alpha)
    SDF_CACHE.put(key, x)
    return x.copy()


def thickness_affinities(shape: Shape, pairs: np.ndarray, scale: float, floor: float = 1e-3) -> np.ndarray:
    """Affinities ``(p,)`` in ``[floor, 1]`` of the dual-graph ``pairs`` ``(p, 2)`` that drop where the shape's
    thickness changes (Shapira et al. 2008: a fin, a wing or a handle is thinner than the body it joins):
    ``exp(-|x_a - x_b| / (scale * mean |x_a - x_b|))`` with ``x`` the :func:`normalized_sdf` of the faces (scale-free,
    in ``[0, 1]``); the concavity term's construction (:func:`~shape_toolkit.features.smoothing.relative_affinities`),
    ``scale`` its ``concavity_scale``. All 1 where the SDF does not change."""
    x = normalized_sdf(shape)
    return relative_affinities(np.abs(x[pairs[:, 0]] - x[pairs[:, 1]]) if len(pairs) else np.zeros(0), scale, floor)


def _check_k(k: Any, m: int) -> int:
    if k > m:
        raise ParameterError(f"n_segments = {k} exceeds the number of faces ({m})")
    return int(k)


class SDFSegmenter(BaseSegmenter):
    """CGAL's SDF segmentation: per-face SDF, 1-D GMM with ``n_segments`` clusters, graph cut.

    Parameters: ``n_segments`` (``k``), ``n_rays`` / ``cone_angle`` (SDF rays), ``filter_iterations``
    (bilateral steps), ``log_alpha`` (log normalisation), ``smoothing_lambda`` (boundary cost weight of
    the graph cut; 0 = plain GMM labels), ``convex_factor``, ``geometric`` (area / edge-length weights),
    ``n_init`` (GMM restarts), ``random_state`` (GMM initialisation, sklearn semantics).

    After :meth:`segment` of a mesh of one piece: ``sdf_`` (normalised per-face SDF), ``gmm_labels_``
    (before the graph cut), ``n_segments_`` (labels left after the cut).
    """

    parameter_constraints = {
        "n_segments": N_SEGMENTS,
        "n_clusters": Param(None, Interval(int, 2), doc="GMM clusters of the SDF (None: n_segments)"),
        "n_rays": Param(Interval(int, 1, MAX_RAYS),
                        doc=f"rays per face of the SDF; <= {MAX_RAYS:,} (CGAL: 25): they are then about 1 degree "
                            "apart over the 120-degree cone, time and the ray blocks' memory grow linearly"),
        "cone_angle": Param(POSITIVE, doc="opening of the ray cone (radians)"),
        "filter_iterations": Param(Interval(int, 0, MAX_FILTER_ITERATIONS),
                                   doc=f"bilateral smoothing steps of the SDF; <= {MAX_FILTER_ITERATIONS:,}: each is "
                                       "a pass over the dual graph (CGAL: 1 to 3); they stop early, exactly, once a "
                                       "step changes nothing"),
        "log_alpha": Param(POSITIVE, doc="log normalisation of the SDF"),
        "smoothing_lambda": smoothing_lambda("boundary cost of the graph cut (0: plain GMM labels)"),
        "convex_factor": GRAPH_CUT_CONVEX_FACTOR,
        "geometric": Param(bool, doc="area and edge-length weights"),
        "n_init": N_INIT,
        "random_state": RANDOM_STATE,
    }

    def __init__(
        self,
        n_segments: int | None = 4,
        *,
        n_clusters: int | None = 5,
        n_rays: int = 25,
        cone_angle: float = 2.0 * np.pi / 3.0,
        filter_iterations: int = 3,
        log_alpha: float = 4.0,
        smoothing_lambda: float = 0.26,
        convex_factor: float = 0.08,
        geometric: bool = True,
        n_init: int = 3,
        random_state: Any = 0,
    ):
        self.n_segments = n_segments
        self.n_clusters = n_clusters
        self.n_rays = n_rays
        self.cone_angle = cone_angle
        self.filter_iterations = filter_iterations
        self.log_alpha = log_alpha
        self.smoothing_lambda = smoothing_lambda
        self.convex_factor = convex_factor
        self.geometric = geometric
        self.n_init = n_init
        self.random_state = random_state

    def component_graph(self, shape: Shape) -> str:
        """``"dual"``: the pieces of the dual graph are segmented one by one."""
        return "dual"

    def _check_params(self, shape: Shape) -> None:
        self._k_and_clusters(shape)

    def _k_and_clusters(self, shape: Shape) -> tuple[int | None, int]:
        """``(k, number of GMM clusters)``, checked."""
        faces = shape.require_faces("SDF segmentation")
        k = None if self.n_segments is None else _check_k(self.n_segments, len(faces))
        nc = self.n_clusters if self.n_clusters is not None else k
        if nc is None:
            raise ParameterError("sdf: n_segments and n_clusters cannot both be None")
        nc = _check_k(nc, len(faces))
        if k is not None:
            nc = min(nc, k)
        if int(self.n_rays) < 1:
            raise ParameterError(f"n_rays must be >= 1, got {self.n_rays!r}")
        return k, nc

    def _segment(self, shape: Shape, *, spectrum: Any, constraints: Any) -> Segmentation:
        """The face segmentation of a mesh of one piece (of the dual graph)."""
        from sklearn.mixture import GaussianMixture

        k, nc = self._k_and_clusters(shape)
        seed = seed_of(self.random_state)
        x = normalized_sdf(shape, int(self.n_rays), float(self.cone_angle), int(self.filter_iterations),
                           float(self.log_alpha))
        self.sdf_ = x
        k_fit = min(nc, max(1, len(np.unique(np.round(x, 12)))))
        xs = np.sort(x)[:, None]
        gm = GaussianMixture(k_fit, n_init=int(self.n_init), random_state=seed, reg_covar=1e-6)
        with single_thread():
            gm.fit(xs)
            proba = gm.predict_proba(x[:, None])
        order = np.argsort(gm.means_.ravel(), kind="stable")  # clusters numbered by increasing SDF
        proba = proba[:, order]
        unary = -np.log(np.maximum(proba, EPS))
        self.gmm_labels_ = np.argmin(unary, axis=1).astype(np.int64)
        if float(self.smoothing_lambda) > 0:
            fl = smooth_labels(shape, None, unary, float(self.smoothing_lambda), convex_factor=self.convex_factor,
                               geometric=bool(self.geometric))
        else:
            fl = self.gmm_labels_.copy()
        self.cluster_labels_ = np.asarray(fl, dtype=np.int64)
        pairs, _, _ = dual_graph(shape.faces)
        fl = merge_to_segments(self.cluster_labels_, pairs, np.asarray(shape.face_areas, dtype=np.float64), k)
        self.n_segments_ = int(fl.max() + 1)
        return Segmentation.of_faces(shape, fl)


class SmoothedSegmenter(BaseSegmenter):
    """Any segmenter followed by the dual-graph graph cut of
    :func:`~shape_toolkit.features.smoothing.smooth_labels`.

    Parameters: ``base`` (registry name or segmenter instance; a name is created with its defaults),
    ``n_segments`` (when not None, passed to the base), ``smoothing_lambda``, ``spread``,
    ``convex_factor``, ``geometric`` (see :func:`smooth_labels`). Spectra: those of the base (passed
    through). After :meth:`segment`: ``base_`` (the fitted base), ``base_face_labels_`` (the base's
    face labels, before smoothing), ``n_segments_``.
    """

    parameter_constraints = {
        "base": Param(PluginRef("segmenters"), doc="the segmenter whose labels are smoothed"),
        "n_segments": N_SEGMENTS,
        "smoothing_lambda": smoothing_lambda("boundary cost of the graph cut"),
        "spread": Param(Interval(int, 0, MAX_SPREAD),
                        doc=f"rings the boundaries may move; <= {MAX_SPREAD:,}: each ring is a pass of label "
                            "averaging over the dual graph, and a boundary that may slide 1,000 rings is no "
                            "longer smoothed locally but re-placed"),
        "convex_factor": GRAPH_CUT_CONVEX_FACTOR,
        "geometric": Param(bool, doc="area and edge-length weights"),
    }

    def __init__(
        self,
        base: Any = "eigvec-gmm",
        n_segments: int | None = None,
        *,
        smoothing_lambda: float = 0.5,
        spread: int = 3,
        convex_factor: float = 0.08,
        geometric: bool = True,
    ):
        self.base = base
        self.n_segments = n_segments
        self.smoothing_lambda = smoothing_lambda
        self.spread = spread
        self.convex_factor = convex_factor
        self.geometric = geometric

    def _make_base(self) -> Segmenter:
        if isinstance(self.base, str):
            from shape_toolkit.api.registry import create_plugin

            if self.base == "smoothed":
                raise ParameterError("smoothed: base must be another segmenter")
            b = create_plugin("segmenters", self.base)
        elif isinstance(self.base, BasePlugin) and callable(getattr(self.base, "segment", None)):
            b = type(self.base)(**self.base.get_params(deep=False))
        else:
            raise ParameterError(f"smoothed: base must be a segmenter name or instance, got {self.base!r}")
        if self.n_segments is not None:
            b.set_params(n_segments=self.n_segments)
        return b

    def accepts_constraints(self) -> bool:
        """Whether the base segmenter uses constraints (they are passed on to it)."""
        return self._make_base().accepts_constraints()

    def lacks_n_segments(self) -> bool:
        """Whether the base segmenter needs ``n_segments`` and has none (``n_segments`` is passed on to it)."""
        return self._make_base().lacks_n_segments()

    def spectrum_spec(self):
        return self._make_base().spectrum_spec()

    def spectrum_specs(self):
        return self._make_base().spectrum_specs()

    def component_graph(self, shape: Shape) -> None:
        """None: the base segments the pieces."""
        return None

    def _segment(self, shape: Shape, *, spectrum: Any, constraints: Any) -> Segmentation:
        """The base's face labels, smoothed."""
        shape.require_faces("label smoothing")
        b = self._make_base()
        fl0 = b.segment(shape, spectrum=spectrum, constraints=constraints).face_labels
        fl = smooth_labels(shape, fl0, None, float(self.smoothing_lambda), on="faces", spread=int(self.spread),
                           convex_factor=float(self.convex_factor), geometric=bool(self.geometric))
        self.base_ = b
        self.base_face_labels_ = np.asarray(fl0, dtype=np.int64)
        self.n_segments_ = int(len(np.unique(fl)))
        return Segmentation.of_faces(shape, fl)
