"""Functional maps (Ovsjanikov et al. 2012) fitted on descriptors with Laplacian commutativity,
descriptor commutativity and the orientation term of Ren et al. 2018, refined by ZoomOut (Melzi et al. 2019).

Left and right: intrinsic descriptors cannot tell a map from its mirror image; the orientation term
``sum_f ||C O_t(f) - O_s(f) C||^2`` (``O(f) g = <n x grad f, grad g>``, outward normals) changes sign under
a reflection, so it favours orientation-preserving maps.

The energy and its exact solver (:func:`~shape_toolkit.features.basis.fit_functional_map`, with the
multiplication and orientation operators and the descriptor compression) live with the other functional-map
operations in :mod:`shape_toolkit.features.basis`; this module chooses descriptors, hypotheses and ZoomOut.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np

from shape_toolkit.api.interfaces import DenseMatcher
from shape_toolkit.api.params import InstanceOf, Interval, ListOf, Param
from shape_toolkit.core.geometry import sample_weights
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.errors import ParameterError
from shape_toolkit.features.basis import (
    SharedPairWork,
    compress_descriptors,
    fit_functional_map,
    multiplication_operators,
    orientation_operators,
    part_support,
    point_map_within,
    slanted_size,
    zoomout,
    zoomout_select,
)
from shape_toolkit.plugins._params import (
    DESCRIPTOR,
    DESCRIPTOR_PARAMS,
    NON_NEGATIVE,
    ORIENTATION,
    POSITIVE,
    POSITIVE_INT,
)
from shape_toolkit.plugins.descriptors.wks import spectrum_wave_kernel_signature
from shape_toolkit.plugins.matching.dense.partial_search import part_wave_kernel_signatures
from shape_toolkit.plugins.matching.descriptors import UsesDescriptor, normalize_columns, shared_spectra
from shape_toolkit.plugins.matching.validation import check_descriptors, check_seeds
from shape_toolkit.results.correspondence import Correspondence
from shape_toolkit.spectra import SpectrumSpec, default_spec, merge_specs

__all__ = ["FmapZoomOutMatcher", "part_wave_kernel_signatures"]

#: target functions low-passing the part's image into its support on the whole (:func:`part_support`), where the
#: final point map of ``partial`` looks; chosen a priori (about the fitted map's size), kept on the tuning half
#: (benchmarks/results/partial_matching_notes.md)
SUPPORT_SMOOTHING = 30

#: a part whose area exceeds the whole's by more than this factor is refused (the units differ): two poses of
#: one body differ in area by a few percent, two people by some 10 to 20 percent
MAX_PART_AREA_RATIO = 1.5

#: the keys a hypothesis of :class:`FmapZoomOutMatcher` may override
HYPOTHESIS_KEYS = frozenset({"k", "band", "w_descr", "w_lap", "w_dcomm", "w_orient"})

#: the default hypotheses: pyFM's README fit (k = 30, weights 1 / 0.1 / 1 / 1, WKS on every eigenpair), the
#: same on the coarser half of the eigenpairs, and a coarser fit (two thirds of ``k``) whose orientation term
#: outweighs the rest, on both bands (chosen on the field benchmark's tuning half only)
DEFAULT_HYPOTHESES: tuple[dict, ...] = (
    {}, {"band": 0.5}, {"k": 20, "w_orient": 10.0}, {"k": 20, "w_orient": 10.0, "band": 0.5},
)


class FmapZoomOutMatcher(UsesDescriptor, DenseMatcher):
    """Dense map from a functional map fitted on descriptors and refined by ZoomOut.

    ``descriptor``/``descriptor_params``: descriptor plugin computed on both shapes (unless the
    caller passes ``source_descriptors``/``target_descriptors``); a name, a ``{plugin, preset,
    params}`` table or an instance; None (default) is the WKS on this matcher's own Laplace-Beltrami eigenpairs
    (:func:`~shape_toolkit.plugins.descriptors.wks.spectrum_wave_kernel_signature`; ``descriptor_params`` may set
    ``n_energies`` and ``variance``); ``n_descriptors`` evenly spaced columns are kept. ``k``: size of the
    fitted map; ZoomOut then grows it by ``zoomout_step`` for ``zoomout_iters`` iterations (0: none).
    ``orientation``: ``"preserving"`` (default), ``"reversing"`` or ``"none"`` (weight ``w_orient``).
    ``zoomout_samples``: farthest-point target vertices matched to inside ZoomOut (None: all); ``source_samples``:
    source vertices (farthest points, each weighted by its Voronoi cell) the final ZoomOut's iterations query before
    one on every vertex (0 or None, the default: every vertex throughout; two whole shapes only; 5 % less CPU in
    ``auto``, 5 % worse on FAUST across people: not its default, benchmarks/results/auto_speed_notes.md). Seeds add
    one heat-kernel descriptor per seed pair; the map keeps each pair (``trust_seeds``; a [refine] stage's are not).

    ``hypotheses``: several fits, each a mapping overriding some of ``k``, the four weights and ``band``
    (the default WKS on the first ``round(band * K)`` of the ``K`` non-null eigenpairs). The one ZoomOut
    refines best on ``selection_samples`` source vertices (:func:`~shape_toolkit.features.basis.zoomout_select`)
    is refined on every vertex; ``info["hypotheses"]`` records the residuals and the choice. None:
    :data:`DEFAULT_HYPOTHESES`; ``[{}]``: a single fit. Why: a swapped part depends on the fit's basis size,
    orientation weight and band; the refined map's residual tells it (``band``: the default WKS only).

    ``partial``: the source is a part of the target (a scan seeing one side, a region cut away). The functional maps are
    then rectangular: the target basis spans the frequencies of the source's
    (:func:`~shape_toolkit.features.basis.slanted_size`; Rodola et al. 2017's slanted diagonal, ZoomOut's partial
    variant), the WKS of both shapes share their energies (:func:`part_wave_kernel_signatures`) and the Laplacian term
    compares eigenvalues in common units. The part's share of the whole's area is ``area_ratio``, or the ratio of the
    shapes' areas (same units; above :data:`MAX_PART_AREA_RATIO` refused, above 1 taken as 1). The declared spectrum is
    twice as large, so a part down to half the target's area is covered; a smaller part is matched on a target basis
    truncated there (``info["target_basis_truncated"]``). A part in several pieces is refused
    (``DisconnectedGraphError``). The final point map looks only inside the part's support on the whole, recovered from
    the refined map (:func:`~shape_toolkit.features.basis.part_support`, ``info["partial"]["support"]``).
    ``area_ratios``: candidate ratios (with the areas' one), the map of least geodesic distortion kept and refined on
    its support (:func:`~shape_toolkit.plugins.matching.dense.partial_search.match_over_area_ratios`; shapes in any
    units). ``part_shells``: the search's map also places the part's smooth shells on the whole, and they compete on the
    same distortion (:func:`~shape_toolkit.plugins.matching.dense.partial_search.with_part_shells`).
    """

    presets = {
        # fast: the same final basis (110) in half the steps; no target sampling (both: measured notes in
        # benchmarks/results/fmap_zoomout_notes.md)
        "fast": {"zoomout_iters": 8, "zoomout_step": 10, "zoomout_samples": None},
        "accurate": {"zoomout_iters": 16, "zoomout_step": 5, "zoomout_samples": None},
    }

    parameter_constraints = {
        "k": Param(Interval(int, 2, 100), doc="size of the fitted functional map (its fit holds k^4 doubles)"),
        "descriptor": Param(None, *DESCRIPTOR.constraints, doc="descriptor plugin (None: WKS on the own basis)"),
        "descriptor_params": DESCRIPTOR_PARAMS,
        "n_descriptors": Param(POSITIVE_INT, doc="evenly spaced descriptor columns kept"),
        "w_descr": Param(NON_NEGATIVE, doc="weight of the descriptor term"),
        "w_lap": Param(NON_NEGATIVE, doc="weight of the Laplacian commutativity term"),
        "w_dcomm": Param(NON_NEGATIVE, doc="weight of the descriptor commutativity term"),
        "w_orient": Param(NON_NEGATIVE, doc="weight of the orientation term"),
        "orientation": ORIENTATION,
        "zoomout_iters": Param(Interval(int, 0), doc="ZoomOut iterations (0: off)"),
        "zoomout_step": Param(POSITIVE_INT, doc="eigenfunctions added per ZoomOut iteration"),
        "zoomout_samples": Param(None, POSITIVE_INT, doc="target samples inside ZoomOut (None: all)"),
        "source_samples": Param(None, Interval(int, 0), doc="source samples of the final ZoomOut iterations (0: all)"),
        "seed_time": Param(POSITIVE, doc="time of the heat-kernel descriptor of each seed pair"),
        "hypotheses": Param(None, ListOf(InstanceOf(dict, name="mapping")), doc="fits tried (None: the default set)"),
        "selection_samples": Param(Interval(int, 10), doc="samples of the residual choosing a hypothesis"),
        "partial": Param(bool, doc="the source is a part of the target, in the same units (rectangular maps)"),
        "area_ratio": Param(None, Interval(float, 0, 1, closed="right"),
                            doc="area of the part over the whole's (None: from the shapes' areas; partial only)"),
        "area_ratios": Param(None, ListOf(Interval(float, 0, 1, closed="right")),
                             doc="candidate area ratios, the map of least geodesic distortion kept (partial only)"),
        "part_shells": Param(bool, doc="also the part's smooth shells placed from the search's map (area_ratios)"),
        "trust_seeds": Param(bool, doc="the seeds are right (a user's): the map keeps each seed pair; False: they only "
                             "enter the fit (a pipeline's [refine] stage, whose seeds are the dense stage's map)"),
    }

    def __init__(
        self, k: int = 30, descriptor: str | dict | None = None, descriptor_params: dict | None = None,
        n_descriptors: int = 50, w_descr: float = 1.0, w_lap: float = 0.1, w_dcomm: float = 1.0, w_orient: float = 1.0,
        orientation: str = "preserving", zoomout_iters: int = 16, zoomout_step: int = 5,
        zoomout_samples: int | None = None, source_samples: int | None = None, seed_time: float = 0.01,
        hypotheses: tuple[dict, ...] | list[dict] | None = None, selection_samples: int = 500, partial: bool = False,
        area_ratio: float | None = None, area_ratios: list[float] | None = None, part_shells: bool = False,
        trust_seeds: bool = True,
    ):
        self.k = k
        self.descriptor = descriptor
        self.descriptor_params = descriptor_params
        self.n_descriptors = n_descriptors
        self.w_descr = w_descr
        self.w_lap = w_lap
        self.w_dcomm = w_dcomm
        self.w_orient = w_orient
        self.orientation = orientation
        self.zoomout_iters = zoomout_iters
        self.zoomout_step = zoomout_step
        self.zoomout_samples = zoomout_samples
        self.source_samples = source_samples
        self.seed_time = seed_time
        self.hypotheses = hypotheses
        self.selection_samples = selection_samples
        self.partial = partial
        self.area_ratio = area_ratio
        self.area_ratios = area_ratios
        self.part_shells = part_shells
        self.trust_seeds = trust_seeds

    def _check(self) -> None:
        self._validate_params()
        for h in self._hypotheses():
            if not isinstance(h, dict) or set(h) - HYPOTHESIS_KEYS:
                raise ParameterError(
                    f"each hypothesis is a mapping with keys among {sorted(HYPOTHESIS_KEYS)}, got {h!r}")
            band, k = h.get("band", 1.0), h.get("k", self.k)
            if isinstance(band, bool) or not isinstance(band, (int, float)) or not 0 < band <= 1:
                raise ParameterError(f"a hypothesis band must be a fraction in (0, 1], got {band!r}")
            if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 2:
                raise ParameterError(f"a hypothesis k must be an integer >= 2, got {k!r}")
            for name in ("w_descr", "w_lap", "w_dcomm", "w_orient"):
                w = h.get(name, 0.0)
                if isinstance(w, bool) or not isinstance(w, (int, float)) or not w >= 0:
                    raise ParameterError(f"a hypothesis {name} must be a number >= 0, got {w!r}")
        dp = self.descriptor_params
        if self.descriptor is None and dp and set(dp) - {"n_energies", "variance"}:
            raise ParameterError(
                f"descriptor_params of the built-in WKS take n_energies and variance, got {sorted(dp)}"
            )

        for name in ("area_ratio", "area_ratios"):
            if getattr(self, name) is not None and not self.partial:
                raise ParameterError(f"{name}: the part's share of the whole's area, needs partial = True")
        if self.part_shells and (self.area_ratios is None or self.area_ratio is not None):
            raise ParameterError("part_shells needs partial = True and area_ratios (no fixed area_ratio)")

    def _area_scale(self, spec_s: Spectrum, spec_t: Spectrum) -> float:
        """``area_t / area_s``: the whole's area over the part's (at least 1), from ``area_ratio`` or from the
        two spectra's total mass (the shapes' areas, in their common units)."""
        if self.area_ratio is not None:
            return 1.0 / float(self.area_ratio)
        if spec_s.mass is None or spec_t.mass is None:
            raise ParameterError("partial matching estimates the part's share of the area from the spectra's "
                                 "mass; these have none: pass area_ratio")
        ratio = float(np.sum(spec_s.mass)) / float(np.sum(spec_t.mass))
        if not np.isfinite(ratio) or ratio <= 0:
            raise ParameterError(f"partial: the part's area over the whole's is {ratio!r}")
        if ratio > MAX_PART_AREA_RATIO:
            raise ParameterError(
                f"partial: the part's area is {ratio:.2f}x the whole's; the shapes are not in the same units (or "
                f"the source is not a part of the target): pass area_ratio (the part's share of the whole's area)")
        if ratio >= 1.0:  # in range, but no part: a whole given as the source, or shapes in other units
            warnings.warn(f"partial: the source is not smaller than the target (area ratio {ratio:.2f}): matched as "
                          "a part covering the whole target; the part must be the source (pass area_ratio if the "
                          "shapes are in different units)", UserWarning, stacklevel=3)
        return 1.0 / min(ratio, 1.0)

    def _hypotheses(self) -> list[dict]:
        if self.hypotheses is None:  # the coarser fits at two thirds of this matcher's k (20 for 30)
            coarse = max(2, int(round(2 * self.k / 3))) if isinstance(self.k, (int, np.integer)) else self.k
            return [{**h, "k": coarse} if "k" in h else dict(h) for h in DEFAULT_HYPOTHESES]
        if not isinstance(self.hypotheses, (tuple, list)) or not self.hypotheses:
            raise ParameterError(f"hypotheses must be a non-empty list of mappings, got {self.hypotheses!r}")
        return list(self.hypotheses)

    def final_basis_size(self) -> int:
        """Size of the source basis ZoomOut ends at, ``k + zoomout_iters * zoomout_step`` (the final
        functional map's rows, before any cap at the shapes' vertex counts)."""
        return int(self.k + self.zoomout_iters * self.zoomout_step)

    def spectrum_spec(self) -> SpectrumSpec:
        """The Laplace-Beltrami spectrum with ``k + zoomout_iters * zoomout_step + 1`` eigenpairs (twice
        as many when ``partial``; with ``part_shells``, at least as many as the part's shells need)."""
        own = default_spec((2 if self.partial else 1) * self.final_basis_size() + 1)
        if not self.part_shells:
            return own
        from shape_toolkit.plugins.matching.dense.shell_alignment import ShellAlignmentMatcher  # (imports this module)

        return merge_specs([own, ShellAlignmentMatcher(partial=True).spectrum_spec()])[0]

    def _descriptor_plugin(self):
        if self.descriptor is None:  # the WKS on this matcher's own spectrum
            return None
        return super()._descriptor_plugin()

    def _nested_plugins(self) -> list:
        return [] if self.descriptor is None else super()._nested_plugins()

    def _select(self, d: np.ndarray) -> np.ndarray:
        if self.n_descriptors and d.shape[1] > self.n_descriptors:
            cols = np.unique(np.linspace(0, d.shape[1] - 1, self.n_descriptors).round().astype(int))
            d = d[:, cols]
        return d

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
        """Dense map source -> target (every source vertex matched); ``info['C']`` holds the
        final functional map ``(k, k)`` pulling target functions back to the source.
        ``progress`` (optional) receives one message per stage and per ZoomOut iteration."""
        self._check()
        seeds = check_seeds(seeds, source.n_vertices, target.n_vertices)
        spec_s = self._spectrum(source, source_spectrum)
        spec_t = self._spectrum(target, target_spectrum)
        if self.partial and self.area_ratios is not None and self.area_ratio is None:
            from shape_toolkit.plugins.matching.dense.partial_search import match_over_area_ratios

            return match_over_area_ratios(self, source, target, spec_s, spec_t, progress, seeds=seeds,
                                          source_descriptors=source_descriptors, target_descriptors=target_descriptors)
        scale = self._area_scale(spec_s, spec_t) if self.partial else None
        return self._match_at_scale(source, target, spec_s, spec_t, scale, seeds, source_descriptors,
                                    target_descriptors, progress, None, (source_spectrum, target_spectrum))

    def match_at_area_ratio(
        self, source: Shape, target: Shape, area_ratio: float, *, source_spectrum: Spectrum | None = None,
        target_spectrum: Spectrum | None = None, seeds: np.ndarray | None = None,
        source_descriptors: np.ndarray | None = None, target_descriptors: np.ndarray | None = None,
        progress: Callable[[str], None] | None = None, shared: SharedPairWork | None = None,
    ) -> Correspondence:
        """The partial map of the part ``source`` into the whole ``target`` with the part's share of the whole's
        area set to ``area_ratio`` (in (0, 1]) whatever this (``partial``) matcher's ``area_ratio`` and
        ``area_ratios``: what :meth:`match` returns with that ``area_ratio``, bit for bit. One candidate of an
        area-ratio search (:func:`~shape_toolkit.plugins.matching.dense.partial_search.match_over_area_ratios`):
        ``shared`` (a :class:`SharedPairWork` used with this pair and these spectra only) keeps the work that
        does not depend on the ratio for the next candidate."""
        self._check()
        if not self.partial:
            raise ParameterError("match_at_area_ratio: the part's share of the whole's area needs partial = True")
        r = float(area_ratio)
        if not 0 < r <= 1:
            raise ParameterError(f"area_ratio: the part's share of the whole's area must be in (0, 1], got {r!r}")
        seeds = check_seeds(seeds, source.n_vertices, target.n_vertices)
        spec_s = self._spectrum(source, source_spectrum)
        spec_t = self._spectrum(target, target_spectrum)
        return self._match_at_scale(source, target, spec_s, spec_t, 1.0 / r, seeds, source_descriptors,
                                    target_descriptors, progress, shared, (source_spectrum, target_spectrum))

    def _match_at_scale(
        self, source: Shape, target: Shape, spec_s: Spectrum, spec_t: Spectrum, scale: float | None,
        seeds: np.ndarray | None, source_descriptors: np.ndarray | None, target_descriptors: np.ndarray | None,
        progress: Callable[[str], None] | None, shared: SharedPairWork | None, given: tuple,
    ) -> Correspondence:
        """The map with the target basis slanted by ``scale`` (``area_t / area_s``; None: two whole shapes);
        ``given``: the spectra the caller passed (a descriptor plugin picks its own among them)."""
        shared = SharedPairWork() if shared is None else shared
        # point clouds: the spectrum is the point-cloud Laplacian (SpectrumSpec.for_shape), and the
        # orientation term is formed on the cloud's local surface (core.surface.cloud_surface)
        meshes = source.is_mesh and target.is_mesh
        k_final = int(min(self.final_basis_size(), source.n_vertices - 1, target.n_vertices - 1))
        # a self-map (a shape's symmetry) on one spectrum: every per-shape array is computed once
        same = scale is None and source is target and spec_s is spec_t and source_descriptors is target_descriptors
        bs = shared.basis(spec_s, k_final)
        bt = bs if same else shared.basis(spec_t, None if scale is not None else k_final)
        hyps = self._hypotheses()
        descs: dict[float | None, tuple[np.ndarray, np.ndarray]] = {}  # band -> descriptors of both shapes
        if (source_descriptors is None or target_descriptors is None) and self.descriptor is None:
            params = {"n_energies": 100, "variance": 7.0, **(self.descriptor_params or {})}
            for h in hyps:
                band = float(h.get("band", 1.0))
                if band not in descs and scale is not None:
                    descs[band] = part_wave_kernel_signatures(spec_s, spec_t, scale, **params, band=band)
                elif band not in descs:
                    ws = spectrum_wave_kernel_signature(spec_s, **params, band=band)
                    descs[band] = (ws, ws if same else spectrum_wave_kernel_signature(spec_t, **params, band=band))
        elif source_descriptors is None or target_descriptors is None:
            desc = self._descriptor_plugin()
            # the descriptor picks its own declared spectrum among what the caller gave
            descs[None] = (desc.compute(source, spectrum=shared_spectra(given[0])),
                           desc.compute(target, spectrum=shared_spectra(given[1])))
        else:
            descs[None] = (source_descriptors, target_descriptors)
        seed_cols = None
        if seeds is not None and len(seeds):
            # one heat-kernel map per seed (Ovsjanikov et al. 2010) at a time in unit-area units
            from shape_toolkit.features.heat import heat_kernel

            def seed_maps(spec: Spectrum, ids: np.ndarray) -> np.ndarray:
                area = float(np.sum(spec.mass)) if spec.mass is not None else 1.0
                return np.asarray(heat_kernel(spec, self.seed_time * area, ids))[0].T  # (n, q)

            seed_cols = (seed_maps(spec_s, seeds[:, 0]), seed_maps(spec_t, seeds[:, 1]))

        prepared: dict = {}  # band -> compressed descriptors and orientation operators, shared by its fits

        def prepare(band: float | None) -> tuple:
            if band not in prepared:
                ds = check_descriptors(descs[band][0], source.n_vertices, "source")
                dt = check_descriptors(descs[band][1], target.n_vertices, "target")
                if ds.shape[1] != dt.shape[1]:
                    raise ParameterError(f"descriptor widths differ: {ds.shape[1]} and {dt.shape[1]}")
                ds, dt = self._select(ds), self._select(dt)
                if seed_cols is not None:
                    ds, dt = np.hstack([ds, seed_cols[0]]), np.hstack([dt, seed_cols[1]])
                ds = normalize_columns(ds, bs.mass)
                dt = ds if same else normalize_columns(dt, bt.mass)
                ds, dt = compress_descriptors(ds, dt, bs.mass, bt.mass)
                Os = Ot = Xs = Xt = None
                # the operators of the largest k of the band: fit_functional_map uses their leading blocks
                k_max = max(int(min(h.get("k", self.k), k_final)) for h in hyps)
                if any(float(h.get("w_dcomm", self.w_dcomm)) > 0 for h in hyps):
                    Xs = multiplication_operators(bs, k_max, ds)
                    Xt = Xs if same else multiplication_operators(bt, slanted_size(bs, bt, k_max, scale), dt)
                if self.orientation != "none" and any(float(h.get("w_orient", self.w_orient)) > 0 for h in hyps):
                    surf_s = shared.surface(source)
                    Os = orientation_operators(surf_s, bs, k_max, ds, frame=shared.frame(surf_s, bs, k_max))
                    # compress_descriptors mixes equal inputs into equal outputs
                    kt_max = slanted_size(bs, bt, k_max, scale)
                    surf_t = shared.surface(target)
                    Ot = Os if same else orientation_operators(surf_t, bt, kt_max, dt,
                                                               frame=shared.frame(surf_t, bt, kt_max))
                    if self.orientation == "reversing":
                        Ot = -Ot
                prepared[band] = (ds, dt, Os, Ot, Xs, Xt)
            return prepared[band]

        def fit(h: dict) -> np.ndarray:
            ds, dt, Os, Ot, Xs, Xt = prepare(None if None in descs else float(h.get("band", 1.0)))
            k0 = int(min(h.get("k", self.k), k_final))
            w = {name: float(h.get(name, getattr(self, name))) for name in ("w_descr", "w_lap", "w_dcomm", "w_orient")}
            if self.orientation == "none":
                w["w_orient"] = 0.0
            if progress is not None:
                progress(f"fmap-zoomout: functional map fit (k = {k0}, {ds.shape[1]} descriptor directions)")
            return fit_functional_map(bs, bt, ds, dt, k0, **w, orient_src=Os, orient_tgt=Ot, mult_src=Xs, mult_tgt=Xt,
                                      k_target=slanted_size(bs, bt, k0, scale), eval_scale=scale or 1.0)

        # every source vertex queries, so each functional map is the exact projection of the point map;
        # the default samples no target either, as pyFM's README pipeline (notes: fmap_zoomout_notes.md)
        cols = None
        if self.zoomout_samples and self.zoomout_samples < target.n_vertices:
            cols = shared.samples(target, int(self.zoomout_samples))
        fits = [fit(h) for h in hyps]
        info: dict = {"k_final": k_final}
        if scale is not None:
            kt_final = slanted_size(bs, bt, k_final, scale)
            info["partial"] = {"area_ratio": 1.0 / scale, "k_target_final": kt_final}
            if kt_final == bt.k and bt.k < k_final * scale:
                info["target_basis_truncated"] = (
                    f"the target's {bt.k} eigenpairs span fewer frequencies than the source's {k_final}")
        if not meshes:
            info["orientation_term"] = "on the local surface of the point cloud(s) (core.surface.cloud_surface)"
        chosen = 0
        if len(fits) > 1:  # each refined on farthest-point source samples in steps twice as large
            rows = shared.samples(source, min(int(self.selection_samples), source.n_vertices))
            chosen, residuals, start = zoomout_select(fits, bs, bt, k_final, 2 * self.zoomout_step, rows, cols,
                                                      scale=scale)
            fits[chosen] = start
            info["hypotheses"] = {"tried": [dict(h) for h in hyps], "residuals": residuals, "chosen": chosen}
            if progress is not None:
                progress(f"fmap-zoomout: hypothesis {chosen} {hyps[chosen]} chosen (residuals "
                         + ", ".join(f"{r:.3g}" for r in residuals) + ")")
        rows = weights = None  # the final refinement's iterations on Voronoi-weighted source samples (whole shapes)
        if scale is None and self.source_samples and self.source_samples < source.n_vertices:
            rows = shared.samples(source, int(self.source_samples))
            weights = sample_weights(source.vertices, rows, bs.mass)
        C, T = zoomout(fits[chosen], bs, bt, k_final, self.zoomout_step, rows, cols, progress=progress, scale=scale,
                       weights=weights)
        if scale is not None:  # each part vertex to its nearest within the part's support on the whole
            support = part_support(T, bs, bt, 1.0 / scale, SUPPORT_SMOOTHING)
            T = point_map_within(C, bs, bt, support)
            info["partial"]["support"] = support
        if self.trust_seeds and seeds is not None and len(seeds):  # the user's pairs, as in the other matchers' maps
            T[seeds[:, 0]] = seeds[:, 1]
        info["C"] = C
        return Correspondence(T, target.n_vertices, info=info)


