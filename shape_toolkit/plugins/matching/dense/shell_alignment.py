"""Dense matching of shapes that are not isometric (a gorilla and a person): coarse-to-fine alignment of
smooth shells, after the idea of Smooth Shells (Eisenberger et al., CVPR 2020); our own, simpler
formulation.

A *shell* of resolution ``K`` is the shape's coordinate functions low-pass filtered on its first ``K``
Laplace-Beltrami eigenfunctions: a blob at ``K = 6``, the limbs at ``K = 16``, the details at ``K = 64``.
Coordinates are centred (area-weighted) and divided by ``sqrt(area)``, so nothing depends on scale.
At each resolution of ``k_schedule`` the source shell is deformed towards the target's by a displacement
field in the same ``K`` eigenfunctions, ``P = X_K + Phi_K tau`` (``tau`` ``(K, 3)``), alternating:

- point maps both ways, nearest neighbours in the product space ``[P, alpha Phi_s, beta N(P)]`` against
  ``[X_K, alpha Phi_t C^T, beta N(X_K)]`` (extrinsic position, the spectral coordinates carried by the
  current functional map ``C``, and the shells' unit normals ``N``): the spectral part keeps a part from
  jumping to a nearby wrong part, the normals keep the front of a limb off its back;
- ``tau`` by least squares on both maps (bijectivity: every target point pulls too), each
  eigenfunction's displacement damped by ``mu lambda_k^2`` (smooth deformations are cheap);
- ``C`` from the source-to-target map.

The last map is taken between the full-resolution source deformed by ``tau`` and the target.

The alternation sees ``samples`` farthest points of each shape (2,000 by default; every vertex below that),
each weighted by the area of its Voronoi cell, so that the sums of the least squares and of ``C`` stay
integrals over the surface. The nearest-neighbour searches, most of the cost, shrink by ``(n / samples)^2``:
at 5k vertices 1.6-2.0 s -> 0.33-0.38 s CPU, with errors within +-0.008 of the every-vertex run on nine
tuning pairs (gorillas to men, a dog pair, two FAUST pairs); the samples resolve eigenfunctions far beyond
the 64 used.

Parts (``partial``, :meth:`ShellAlignmentMatcher.match_part`; issue 29, item 3). When the source is a part of
the target (a region cut away), the bijective least squares are wrong: every target point pulls, and most of the
whole has no counterpart on the part. So only the part's points pull (the source -> target term alone). The
part's shell is put in the whole's units and place without fitted constants, from a start map into the whole
(a partial functional map's) and the part's share ``r`` of the whole's area: its coordinates are centred on its
own centroid, scaled by ``sqrt(r area_t / area_s) / sqrt(area_t)`` (the whole's normalisation, in the part's
length units), and moved to the centroid of the start map's support on the whole
(:func:`~shape_toolkit.features.basis.part_support`). The whole's shell at resolution ``K`` is filtered on the
whole's eigenfunctions up to the part's ``K``-th frequency, and the spectral coordinates go through the
rectangular functional map (:func:`~shape_toolkit.features.basis.slanted_size`, Rodola et al. 2017) of the
alignment's own map, as for two whole shapes (the first step sees positions only). The start map places the part
and nothing else: taking the first functional map from it too carried its errors into the alignment (on the
tuning half's 30% crops, 6 dog pairs: 0.085 against 0.111 after the selection of
:func:`~shape_toolkit.plugins.matching.dense.partial_search.match_over_area_ratios`). ``info["residual"]`` is then
the part's term only.

Frames. Extrinsic alignment needs the two shapes in a common frame (upright the same way, as scans of
one capture set-up and the public datasets are): the method does not search rotations. A search scored
by the alignment's own residual picked wrong rotations on the tuning pairs (the deformation fits any
start), so it is not offered; rotate the shapes into one frame first. ``info["frame"]`` says ``given``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from shape_toolkit.api.interfaces import DenseMatcher
from shape_toolkit.api.params import InstanceOf, Interval, ListOf, Param
from shape_toolkit.core.geometry import farthest_point_sampling, nearest_neighbors, sample_weights, vertex_normals
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.errors import ParameterError
from shape_toolkit.features.basis import Basis, basis_of, part_support, slanted_size
from shape_toolkit.plugins._params import POSITIVE_INT
from shape_toolkit.plugins.matching.validation import check_seeds
from shape_toolkit.results.correspondence import Correspondence
from shape_toolkit.spectra import SpectrumSpec, default_spec

__all__ = ["ShellAlignmentMatcher", "shell_coordinates"]

#: largest alpha, beta (parameter docs), mu and iters
MAX_WEIGHT, MAX_DAMPING, MAX_ITERS = 1e3, 1e6, 1000


def _centred(shape: Shape, basis: Basis, area: float) -> np.ndarray:
    X = np.asarray(shape.vertices, dtype=np.float64)
    return (X - basis.mass @ X / basis.mass.sum()) / np.sqrt(area)


def shell_coordinates(shape: Shape, basis: Basis, k: int, area: float) -> np.ndarray:
    """The shell of resolution ``k``: vertex coordinates ``(n, 3)``, centred (mass-weighted) and divided
    by ``sqrt(area)``, low-pass filtered on the first ``k`` functions of ``basis``."""
    return basis.low_pass(_centred(shape, basis, area), k)


class ShellAlignmentMatcher(DenseMatcher):
    """Coarse-to-fine alignment of smooth shells for non-isometric pairs (module docstring).

    ``k_schedule``: increasing shell resolutions (eigenfunctions); ``alpha``: weight of the spectral
    coordinates against positions in the product space (both are unitless: positions over
    ``sqrt(area)``, eigenfunctions of a unit-area basis); ``beta``: weight of the shells' unit normals
    (they tell the front of a limb from its back; on the tuning pairs 0.05 to 0.3 all gave 0.213-0.219,
    none 0.246); ``mu``: damping of the displacement of
    eigenfunction ``k`` by ``mu lambda_k^2``; ``iters``: alignment steps per resolution; ``samples``:
    farthest points per shape the alignment sees (None: every vertex; module docstring). Seeds ``(q, 2)``,
    when given, are kept in the map and pull the deformation with the weight of the whole surface.
    """

    extrinsic = True
    presets = {"fast": {"k_schedule": (6, 12, 24, 48), "iters": 3}}
    parameter_constraints = {
        "k_schedule": Param(ListOf(Interval(int, 2)), doc="increasing shell resolutions (eigenfunctions)"),
        "alpha": Param(Interval(float, 0, MAX_WEIGHT), doc="weight of the spectral coordinates against positions "
                       "(both O(1); above 1e3 the positions fall below the float32 resolution of the search's "
                       "squared distances, 1.2e-7 of 4 alpha^2: spectral matching alone, as for any larger alpha, "
                       "until the products overflow)"),
        "beta": Param(Interval(float, 0, MAX_WEIGHT), doc="weight of the shells' unit normals (positions are O(1): "
                      "above 1e3 they fall below the float32 resolution of the search's squared distances, 1.2e-7 "
                      "of 4 beta^2: matching by normals alone, as for any larger beta, until float32 overflows)"),
        "mu": Param(Interval(float, 0, MAX_DAMPING), doc="damping of eigenfunction k's displacement by mu lambda_k^2 "
                    "(the data terms are at most the unit area and lambda_1 of a unit-area surface is O(10): at 1e6 "
                    "the shells stay undeformed to 1e-8, as for any larger mu, which would only overflow mu "
                    "lambda_k^2)"),
        "iters": Param(Interval(int, 1, MAX_ITERS), doc="alignment steps per resolution (a resolution stops early, "
                       "exactly, once both maps repeat; at most 1000: a step costs two nearest-neighbour searches "
                       "of the samples, and maps that still change after 1000 steps cycle)"),
        "samples": Param(None, POSITIVE_INT, doc="farthest-point samples per shape inside the alignment "
                         "(None: every vertex)"),
        "partial": Param(InstanceOf(bool), doc="the source is a part of the target: only the part pulls, its shell "
                         "in the whole's units (module docstring, Parts)"),
        "area_ratio": Param(None, Interval(float, 0, 1, closed="right"),
                            doc="area of the part over the whole's (None: from the shapes' areas; partial only)"),
    }

    def __init__(
        self,
        k_schedule: tuple[int, ...] | list[int] = (6, 10, 16, 24, 32, 48, 64),
        alpha: float = 1.0,
        beta: float = 0.15,
        mu: float = 1e-3,
        iters: int = 4,
        samples: int | None = 2000,
        partial: bool = False,
        area_ratio: float | None = None,
    ):
        self.k_schedule = k_schedule
        self.alpha = alpha
        self.beta = beta
        self.mu = mu
        self.iters = iters
        self.samples = samples
        self.partial = partial
        self.area_ratio = area_ratio

    def _check(self) -> tuple[int, ...]:
        ks = self.k_schedule
        if (not isinstance(ks, (tuple, list)) or not ks
                or not all(isinstance(k, (int, np.integer)) and not isinstance(k, bool) and k >= 2 for k in ks)
                or list(ks) != sorted(set(ks))):
            raise ParameterError(f"k_schedule must be increasing integers >= 2, got {ks!r}")
        if self.area_ratio is not None and not self.partial:
            raise ParameterError("area_ratio: the part's share of the whole's area, needs partial = True")
        return tuple(int(k) for k in ks)

    def _sampled(self, shape: Shape, keep: np.ndarray | None) -> np.ndarray:
        """Sorted vertex ids the alignment sees: ``samples`` farthest points and ``keep``, or every vertex."""
        n = shape.n_vertices
        if not self.samples or self.samples >= n:
            return np.arange(n)
        X = np.asarray(shape.vertices, dtype=np.float64)
        start = int(np.argmax(((X - X.mean(axis=0)) ** 2).sum(axis=1)))  # whatever the vertex order
        idx = farthest_point_sampling(X, int(self.samples), start=start)
        return np.unique(idx if keep is None else np.concatenate([idx, keep]))

    def spectrum_spec(self) -> SpectrumSpec:
        """The Laplace-Beltrami spectrum with ``max(k_schedule) + 1`` eigenpairs (``partial``: as many as the
        partial ``fmap-zoomout`` start needs, at least ``2 max(k_schedule) + 1``: the whole's basis spans the
        part's frequencies)."""
        if not self.partial:
            return default_spec(int(max(self._check())) + 1)
        from shape_toolkit.api.registry import create_plugin  # by name: fmap-zoomout's search imports this module

        start = create_plugin("dense_matchers", "fmap-zoomout", partial=True).spectrum_spec().k
        return default_spec(max(start, 2 * int(max(self._check())) + 1))

    def match(
        self,
        source: Shape,
        target: Shape,
        *,
        seeds: np.ndarray | None = None,
        source_spectrum: Spectrum | None = None,
        target_spectrum: Spectrum | None = None,
        source_descriptors: np.ndarray | None = None,
        target_descriptors: np.ndarray | None = None,
        n_times: int | None = None,
        progress: Callable[[str], None] | None = None,
    ) -> Correspondence:
        """Dense map source -> target (every source vertex matched); ``info["C"]`` holds the last
        functional map, ``info["residual"]`` the mean squared distance (units of area) between the deformed
        source and the target along both final maps (``partial``: the part's only), ``info["frame"]`` is
        ``"given"``. ``partial``: the start is the partial ``fmap-zoomout`` map at ``area_ratio``
        (:meth:`match_part`)."""
        self._check()
        if self.partial:
            from shape_toolkit.api.registry import create_plugin  # by name, as in spectrum_spec

            start = create_plugin("dense_matchers", "fmap-zoomout", partial=True, area_ratio=self.area_ratio).match(
                source, target, seeds=seeds, source_spectrum=source_spectrum, target_spectrum=target_spectrum)
            ratio = float(start.info["partial"]["area_ratio"])
            return self.match_part(source, target, np.asarray(start.target_of), ratio, seeds=seeds,
                                   source_spectrum=source_spectrum, target_spectrum=target_spectrum,
                                   progress=progress)
        return self._align(source, target, seeds, source_spectrum, target_spectrum, progress, None)

    def match_part(
        self,
        source: Shape,
        target: Shape,
        start: np.ndarray,
        area_ratio: float,
        *,
        seeds: np.ndarray | None = None,
        source_spectrum: Spectrum | None = None,
        target_spectrum: Spectrum | None = None,
        progress: Callable[[str], None] | None = None,
    ) -> Correspondence:
        """The part ``source`` aligned to the whole ``target`` (module docstring, "Parts") from a map ``start``
        ``(n_s,)`` of the part into the whole (every entry >= 0; e.g. a partial functional map's) and the part's
        share ``area_ratio`` (in (0, 1]) of the whole's area: dense map source -> target, ``info`` as
        :meth:`match`'s plus ``info["partial"]`` (the ratio, the length scale whole / part)."""
        r = float(area_ratio)
        if not 0.0 < r <= 1.0:
            raise ParameterError(f"area_ratio: the part's share of the whole's area must be in (0, 1], got {r!r}")
        start = np.asarray(start, dtype=np.int64)
        if start.shape != (source.n_vertices,) or start.min(initial=0) < 0 or start.max(initial=0) >= target.n_vertices:
            raise ParameterError(f"start must hold a target vertex for each of the {source.n_vertices} source "
                                 f"vertices, got shape {start.shape}")
        return self._align(source, target, seeds, source_spectrum, target_spectrum, progress, (start, r))

    def _align(
        self, source: Shape, target: Shape, seeds: np.ndarray | None, source_spectrum: Spectrum | None,
        target_spectrum: Spectrum | None, progress: Callable[[str], None] | None,
        part: tuple[np.ndarray, float] | None,
    ) -> Correspondence:
        """The alignment of :meth:`match` (``part`` None) or :meth:`match_part` (``(start, area_ratio)``)."""
        ks = self._check()
        seeds = check_seeds(seeds, source.n_vertices, target.n_vertices)
        spec_s, spec_t = self._spectrum(source, source_spectrum), self._spectrum(target, target_spectrum)
        k_max = int(min(ks[-1], spec_s.k - 1, spec_t.k - 1, source.n_vertices - 1, target.n_vertices - 1))
        ks = tuple(k for k in ks if k < k_max) + (k_max,)
        bs, bt = basis_of(spec_s, k_max), basis_of(spec_t, k_max if part is None else None)
        area_s, area_t = spec_s.area, spec_t.area
        ms, mt = bs.mass, bt.mass
        Xt0 = _centred(target, bt, area_t)
        if part is None:
            Xs0, slope = _centred(source, bs, area_s), None

            def kt(k: int) -> int:
                return k
        else:  # the part in the whole's units, its centroid on its support's (module docstring, "Parts")
            start, ratio = part
            slope = 1.0 / ratio
            support = part_support(start, bs, bt, ratio)
            support[start] = True
            centre = mt[support] @ Xt0[support] / mt[support].sum()
            Xs0 = _centred(source, bs, area_s) * np.sqrt(ratio) + centre

            def kt(k: int) -> int:
                return slanted_size(bs, bt, k, slope)
        # the alignment sees farthest-point samples weighted by their Voronoi cells (seeds always among them)
        rows = self._sampled(source, None if seeds is None else seeds[:, 0])
        cols = self._sampled(target, None if seeds is None else seeds[:, 1])
        wr = ms if len(rows) == source.n_vertices else sample_weights(source.vertices, rows, ms)
        wc = mt if len(cols) == target.n_vertices else sample_weights(target.vertices, cols, mt)
        seed_rows = None if seeds is None else np.searchsorted(rows, seeds[:, 0])
        tau = np.zeros((0, 3))
        C = None
        ws = 1.0 / len(seeds) if seeds is not None and len(seeds) else 0.0

        def nn(points: np.ndarray, queries: np.ndarray) -> np.ndarray:
            return nearest_neighbors(points, queries, dtype=np.float32)[1]

        for K in ks:
            Ps, Pt = bs.evecs[:, :K], bt.evecs[:, :kt(K)]
            Psr, Ptc = Ps[rows], Pt[cols]
            Xs, Xt = bs.low_pass(Xs0, K), bt.low_pass(Xt0, kt(K))
            Xsr, Xtc = Xs[rows], Xt[cols]
            grown = np.zeros((K, 3))
            grown[: len(tau)] = tau[:K]
            tau = grown
            damp = self.mu * np.diag(bs.evals[:K] ** 2)
            use_normals = self.beta > 0 and source.is_mesh and target.is_mesh  # the shells' normals (front, back)
            Nt = self.beta * vertex_normals(Xt, target.faces)[cols] if use_normals else None  # fixed at this K
            last = None  # the maps of the previous step: the same maps again give the same tau and C (a fixed point)
            for _ in range(int(self.iters)):
                if use_normals:  # the normals need the whole deformed shell
                    P = Xs + Ps @ tau
                    Ns, P = self.beta * vertex_normals(P, source.faces)[rows], P[rows]
                else:
                    P = Xsr + Psr @ tau
                if self.alpha > 0 and C is not None:
                    kc = min(K, C.shape[0])
                    qs = np.hstack([P, self.alpha * Psr[:, :kc]])
                    qt = np.hstack([Xtc, self.alpha * Ptc[:, :kt(kc)] @ C[:kc, :kt(kc)].T])
                else:
                    qs, qt = P, Xtc
                if use_normals:
                    qs, qt = np.hstack([qs, Ns]), np.hstack([qt, Nt])
                T = cols[nn(qt, qs)]  # target vertex of each row
                Tr = rows[nn(qs, qt)] if part is None else None  # source vertex of each col
                maps = (T.copy(), Tr)
                if last is not None and all(np.array_equal(a, b) for a, b in zip(last, maps)):
                    break
                last = maps
                # least squares on both maps: source x -> T(x), and T'(y) -> target y (a part: the first only)
                if part is None:
                    H = Psr.T @ (wr[:, None] * Psr) + Ps[Tr].T @ (wc[:, None] * Ps[Tr]) + damp
                    g = Psr.T @ (wr[:, None] * (Xt[T] - Xsr)) + Ps[Tr].T @ (wc[:, None] * (Xtc - Xs[Tr]))
                else:
                    H = Psr.T @ (wr[:, None] * Psr) + damp
                    g = Psr.T @ (wr[:, None] * (Xt[T] - Xsr))
                if ws:
                    a, b = seeds[:, 0], seeds[:, 1]
                    H += ws * Ps[a].T @ Ps[a]
                    g += ws * Ps[a].T @ (Xt[b] - Xs[a])
                H[np.diag_indices(K)] += 1e-12 * np.trace(H) / K  # mu = 0 with too few distinct matches
                tau = np.linalg.solve(H, g)
                if seeds is not None:
                    T[seed_rows] = seeds[:, 1]
                C = Psr.T @ (wr[:, None] * Pt[T])
            if progress is not None:
                progress(f"shell-alignment: resolution {K} of {ks[-1]}")
        # the last map: the full-resolution source deformed by tau against the full-resolution target
        Xs = Xs0 + bs.evecs[:, : len(tau)] @ tau
        T = nn(Xt0, Xs)
        if seeds is not None:
            T[seeds[:, 0]] = seeds[:, 1]
        residual = float(ms @ ((Xs - Xt0[T]) ** 2).sum(axis=1))
        info = {"C": C, "residual": residual, "frame": "given", "k_schedule": list(ks)}
        if part is None:
            Tr = nn(Xs, Xt0)
            info["residual"] = residual + float(mt @ ((Xt0 - Xs[Tr]) ** 2).sum(axis=1))
        else:
            info["partial"] = {"area_ratio": part[1], "length_scale": float(np.sqrt(part[1] * area_t / area_s))}
        return Correspondence(T, target.n_vertices, info=info)
