"""Task adapters: how a benchmark calls each plugin family and scores its output.

A task adapter knows the plugin families whose methods it compares, how to call a method
through the family interface of :mod:`shape_toolkit.api.interfaces` (so any registered plugin works),
and its metrics by name. Metrics return ``{column: value}`` where a value is a number, or a
curve ``[[x, y], ...]`` that reports plot averaged per method. Metric functions of other
modules (``shape_toolkit.metrics.*``) are looked up by name when used, so a metric appears as soon
as its module exists.

Items are *prepared* once per (item, corruption) and shared by every method: the corrupted
shape, the ground truth carried through the corruption, and geodesic distance rows of the
evaluated ground-truth points (matching). Spectra are the ones each method declares
(``spectrum_spec()`` of a plugin and of its keypoint detector, ``spectrum_specs()`` of a pipeline);
they go through the content-addressed cache of :mod:`shape_toolkit.core.spectrum` (on disk in the
run folder), so each is computed once per item and run.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import scipy.sparse as sp

from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.data.corruptions import apply_corruption, carry_correspondence, carry_labels, resamples
from shape_toolkit.data.datasets import DatasetItem
from shape_toolkit.errors import ParameterError
from shape_toolkit.results.correspondence import Correspondence
from shape_toolkit.spectra import SpectrumSpec, merge_specs
from shape_toolkit.validation import finite_number, shown_value

__all__ = [
    "Prepared",
    "TaskAdapter",
    "COMMON_OPTIONS",
    "MEMORY_PROBES",
    "TASKS",
    "prepare",
    "compute_spectrum_cached",
    "spectrum_for",
    "received_spec",
    "method_specs",
    "lookup_metric",
    "GroundTruthMap",
    "HumanSegmentations",
    "HUMAN_MODE",
]


@dataclass
class Prepared:
    """An item ready for a task: ``source`` (clean) and ``target`` (corrupted; for single-shape
    tasks the analysed shape), ground-truth pairs ``truth`` ``(q, 2)`` source -> target (and
    ``truth_sym``), per-vertex ground-truth labels of both, the corruption's vertex map
    (target -> uncorrupted target) and ``geodesic_rows`` (q_eval, n_target) of the evaluated
    truth pairs ``truth_eval`` when a task needs them.

    Scored on the clean shape (``clean_target`` set: the matching option ``score_on = "clean"``),
    ``target`` is still the corrupted shape a method matches, but the ground truth (``truth``,
    ``truth_sym``, ``truth_eval``, ``target_labels``) and the geodesic rows refer to
    ``clean_target``, and a map is scored through ``vertex_map`` (:func:`score_on_clean`)."""

    name: str
    source: Shape
    target: Shape
    truth: np.ndarray | None
    truth_sym: np.ndarray | None
    source_labels: list[np.ndarray]
    target_labels: list[np.ndarray]
    vertex_map: np.ndarray
    corruption_seconds: float = 0.0
    truth_eval: np.ndarray | None = None
    truth_eval_sym: np.ndarray | None = None
    geodesic_rows: np.ndarray | None = None
    geodesic_rows_sym: np.ndarray | None = None
    geodesic_seconds: float = 0.0
    meta: dict[str, Any] = field(default_factory=dict)
    target_face_labels: list[np.ndarray] = field(default_factory=list)
    clean_target: Shape | None = None


def prepare(
    item: DatasetItem,
    corruption_kind: str,
    corruption_params: dict[str, Any],
    *,
    pairwise: bool,
    random_state: int,
    truth_sample: int | None = None,
    geodesic_method: str | None = None,
    score_on: str = "target",
    target: str = "pair",
    truth_points: str = "random",
    corrupt: str = "target",
) -> Prepared:
    """Corrupt the analysed shape of ``item`` and carry its ground truth: for ``pairwise`` tasks
    the target is ``item.target`` (or, without one or with ``target="self"``, a copy of the shape
    with the identity as truth: thesis Table 5.2's clean shape against its corrupted instances),
    else the shape itself. With ``geodesic_method``, distance rows from (a sample of
    ``truth_sample``) ground-truth target vertices are computed once here for every method to
    reuse (``truth_points="even"``: evenly spaced in the ground truth's order instead of a seeded
    random draw, ends included; ``"stride"``: every ``len(truth) // truth_sample``-th point from
    the first). ``score_on="clean"`` keeps the ground truth and the rows on the uncorrupted target
    (``Prepared.clean_target``) instead of carrying them onto the corrupted one. ``corrupt="both"``
    corrupts the source of a pair too (its own seed; the ground truth's source column and the source's
    labels carried onto it), e.g. both shapes of a pair subdivided for a size grid; ``corrupt="source"`` the
    source only (the same seed as with ``"both"``), e.g. a crop of the source matched to the whole target."""
    if score_on not in SCORE_ON:
        raise ParameterError(f"score_on must be one of {', '.join(SCORE_ON)}, got {score_on!r}")
    if target not in TARGETS:
        raise ParameterError(f"target must be one of {', '.join(TARGETS)}, got {target!r}")
    if truth_points not in TRUTH_POINTS:
        raise ParameterError(f"truth_points must be one of {', '.join(TRUTH_POINTS)}, got {truth_points!r}")
    if corrupt not in CORRUPT:
        raise ParameterError(f"corrupt must be one of {', '.join(CORRUPT)}, got {corrupt!r}")
    src = item.shape
    if pairwise and item.target is not None and target == "pair":
        tgt0, truth, sym = item.target, item.correspondence, item.symmetric_correspondence
        tlabels = item.target_labels
        if corrupt in ("both", "source") and corruption_kind != "none":
            src0, rs = src, resamples(corruption_kind)
            src, svmap = apply_corruption(src0, corruption_kind, random_state=random_state + 1, **corruption_params)
            truth = carry_correspondence(truth, svmap, src0, side=0, resampled=rs) if truth is not None else None
            sym = carry_correspondence(sym, svmap, src0, side=0, resampled=rs) if sym is not None else None
            item = replace(item, shape=src, labels=[carry_labels(lab, svmap) for lab in item.labels])
    else:
        tgt0, truth, sym, tlabels = src, None, None, item.labels
        ident = np.arange(src.n_vertices, dtype=np.int64)
        truth = np.stack([ident, ident], axis=1)
    t0 = time.perf_counter()
    if corrupt == "source" and tgt0 is not src:  # a part of the source against the clean target
        tgt, vmap = apply_corruption(tgt0, "none")
    else:
        tgt, vmap = apply_corruption(tgt0, corruption_kind, random_state=random_state, **corruption_params)
    secs = time.perf_counter() - t0
    clean = tgt0 if score_on == "clean" else None
    if corruption_kind != "none" and clean is None:
        rs = resamples(corruption_kind)
        truth = carry_correspondence(truth, vmap, tgt0, resampled=rs) if truth is not None else None
        sym = carry_correspondence(sym, vmap, tgt0, resampled=rs) if sym is not None else None
        tlabels = [carry_labels(lab, vmap) for lab in tlabels]
    p = Prepared(
        item.name, src, tgt, truth, sym, list(item.labels), list(tlabels), vmap, secs, meta=dict(item.meta),
        clean_target=clean,
    )
    if corruption_kind == "none" and tgt0 is src:
        p.target_face_labels = list(item.face_labels)
    scored = clean if clean is not None else tgt
    if geodesic_method and truth is not None and len(truth):
        from shape_toolkit.features.geodesics import geodesic_distances

        rng = np.random.default_rng(random_state)
        sel = np.arange(len(truth))
        if sym is not None and len(sym) != len(truth):  # rows dropped differently: no symmetric truth
            sym = None
        if truth_sample and len(truth) > truth_sample and truth_points == "even":
            sel = np.unique(np.linspace(0, len(truth) - 1, truth_sample).round().astype(np.int64))
        elif truth_sample and len(truth) > truth_sample and truth_points == "stride":
            sel = np.arange(0, len(truth), len(truth) // truth_sample)[:truth_sample]
        elif truth_sample and len(truth) > truth_sample:
            sel = np.sort(rng.choice(len(truth), truth_sample, replace=False))
        t0 = time.perf_counter()
        p.truth_eval = truth[sel]
        p.geodesic_rows = np.asarray(
            geodesic_distances(scored, truth[sel, 1], method=geodesic_method), np.float32
        )
        if sym is not None:
            p.truth_eval_sym = sym[sel]
            p.geodesic_rows_sym = np.asarray(
                geodesic_distances(scored, sym[sel, 1], method=geodesic_method), np.float32
            )
        p.geodesic_seconds = time.perf_counter() - t0
    return p


#: where a matching task scores a map: on the (corrupted) target it matched, or on the clean target
#: through the corruption's vertex back-map
SCORE_ON = ("target", "clean")
#: what a pairwise item is matched to: the dataset's pair, or a copy of the source itself
TARGETS = ("pair", "self")
#: which shapes of a pair a corruption changes: the target, both (a size grid of pairs), or the source only (a
#: part matched to a whole shape)
CORRUPT = ("target", "both", "source")
#: which ground-truth points ``truth_sample`` keeps: a seeded random draw, evenly spaced ones (ends included),
#: or every ``len(truth) // truth_sample``-th from the first (a fixed stride, e.g. every 5th of 5,000)
TRUTH_POINTS = ("random", "even", "stride")
#: the options of how an item is prepared (:func:`prepare`'s keywords) and their values, the default first
PROTOCOL_VALUES = {"score_on": SCORE_ON, "target": TARGETS, "truth_points": TRUTH_POINTS, "corrupt": CORRUPT}


def score_on_clean(prepared: Prepared, target_of: np.ndarray) -> tuple[Prepared, np.ndarray]:
    """The view of ``prepared`` a map is scored on, and the map there: unchanged without a clean
    target; else the clean target in place of the corrupted one and the map composed with the
    corruption's back-map (``vertex_map[target_of]``, -1 kept): int64 ``(n_source,)``."""
    t = np.asarray(target_of, dtype=np.int64)
    if prepared.clean_target is None:
        return prepared, t
    vmap = np.asarray(prepared.vertex_map, dtype=np.int64)
    if t.size and t.max() >= vmap.size:
        raise ParameterError(f"the map points past the corrupted target's {vmap.size} vertices")
    composed = np.where(t >= 0, vmap[np.maximum(t, 0)], -1)
    view = Prepared(**{**prepared.__dict__, "target": prepared.clean_target, "clean_target": None,
                       "vertex_map": np.arange(prepared.clean_target.n_vertices, dtype=np.int64),
                       "target_face_labels": []})
    return view, composed


def compute_spectrum_cached(
    spec: SpectrumSpec, shape: Shape, solver: Any = None, *, cache: bool = True,
) -> tuple[Spectrum, bool]:
    """``spec`` computed on ``shape`` through the content cache (largest connected component, as
    corruptions may split a shape; ``k`` capped by :func:`~shape_toolkit.spectra.spectrum_k`), by the
    eigensolver ``solver`` (None: the toolkit's); returns ``(Spectrum, cache_hit)``. ``cache=False``
    solves afresh (a spectrum task times the solver itself)."""
    hit = cache and spec.is_cached(shape, components="largest", solver=solver)
    return spec.compute(shape, components="largest", solver=solver, cache=cache), hit


def spectrum_for(spec: SpectrumSpec, shape: Shape, pool: Sequence[SpectrumSpec] = ()) -> tuple[Spectrum, bool]:
    """The spectrum ``spec`` asks for on ``shape``, exactly (``k`` eigenpairs, never more): taken
    from the larger spectrum of the same kind in ``pool`` (what the prepare stage computed into
    the cache) when there is one, and checked with :meth:`SpectrumSpec.check`."""
    source = next((p for p in pool if p.kind == spec.kind and p.k >= spec.k), spec)
    spectrum, hit = compute_spectrum_cached(source, shape)
    want = spec.for_shape(shape)
    k = min(want.k, spectrum.k)
    spectrum = spectrum.truncated(k) if spectrum.k > k else spectrum
    if k == want.k:
        spec.check(spectrum, shape)
    return spectrum, hit


def received_spec(spec: SpectrumSpec, shape: Shape) -> dict[str, Any]:
    """What a row records for a spectrum ``spec`` given on ``shape`` (its ``to_dict`` as applied to
    the shape: ``k`` capped at the vertex count, a mesh-only weighting swapped on point clouds)."""
    return spec.for_shape(shape).to_dict()


def method_specs(method: Any, detector: Any = None) -> tuple[list[SpectrumSpec], SpectrumSpec | None]:
    """The spectra a method declares: ``(specs of the method, spec of its keypoint detector)``; a
    pipeline (:meth:`~shape_toolkit.pipeline.Pipeline.spectrum_specs`) may declare several, a
    plugin one (:meth:`spectrum_spec`) or none."""
    if method is None:
        own: list[SpectrumSpec] = []
    elif hasattr(method, "spectrum_specs"):
        own = merge_specs(method.spectrum_specs() or [])
    else:
        getter = getattr(method, "spectrum_spec", None)
        own = [s for s in [getter() if getter else None] if s is not None]
    getter = getattr(detector, "spectrum_spec", None) if detector is not None else None
    det = getter() if getter else None
    for s in own + ([det] if det is not None else []):
        if not isinstance(s, SpectrumSpec):
            raise ParameterError(f"{type(method).__name__} declared {s!r}, not a SpectrumSpec")
    return own, det


def lookup_metric(name: str) -> Callable[..., Any] | None:
    """A function of :mod:`shape_toolkit.metrics` by name, or None when no such metric exists (yet)."""
    import importlib

    mod = importlib.import_module("shape_toolkit.metrics")
    return getattr(mod, name, None)


def _with_random_state(family: str, plugin: str, preset: str | None, params: dict, random_state: int):
    from shape_toolkit.api.registry import create_plugin, get_plugin

    cls = get_plugin(family, plugin)
    params = dict(params)
    names = cls._param_names() if hasattr(cls, "_param_names") else []
    if "random_state" in names and "random_state" not in params:
        params["random_state"] = random_state
    return create_plugin(family, plugin, preset, **params)


def _curve(x: np.ndarray, y: np.ndarray) -> list[list[float]]:
    return [[float(a), float(b)] for a, b in zip(x, y)]


# --------------------------------------------------------------------------------------------
#: options every task takes, with their defaults (None: the runner's one BLAS thread)
COMMON_OPTIONS: dict[str, Any] = {"repeats": 1, "blas_threads": None, "memory": "rss", "metric_costs": False}
#: what a row's ``peak_memory_mb`` measures (common option ``memory``): the rise of the worker's resident
#: memory, or the peak of the Python and NumPy allocations traced by ``tracemalloc``
MEMORY_PROBES = ("rss", "traced")


#: the most runs of one row (common option ``repeats``, best of N) and BLAS threads of one method call
#: (``blas_threads``): past these a config's row would run for ever, or BLAS refuses the count (a C int)
MAX_REPEATS = 100
MAX_BLAS_THREADS = 1024


def check_number_lists(options: dict[str, Any], keys: Sequence[str], lo: float, hi: float, *,
                       open_low: bool = False, what: str = "") -> None:
    """Each option of ``keys`` is a non-empty list of finite numbers in ``[lo, hi]`` (``open_low``: ``(lo, hi]``),
    else :class:`ParameterError` naming it (``what``: what the numbers are, in the message)."""
    for key in keys:
        v = options[key]
        ok = isinstance(v, list) and bool(v) and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and finite_number(x)
            and (lo < x if open_low else lo <= x) and x <= hi for x in v)
        if not ok:
            shown = v if not isinstance(v, list) else [shown_value(x) if isinstance(x, int) else x for x in v]
            raise ParameterError(f"{key} must be a non-empty list of {what}numbers in {'(' if open_low else '['}"
                                 f"{lo:g}, {hi:g}], got {shown!r}")


def check_positive_ints(options: dict[str, Any], keys: Sequence[str], *, optional: bool = False,
                        note: str = "") -> None:
    """Each option of ``keys`` is an integer >= 1 (``optional``: or None), else :class:`ParameterError` naming it
    (``note``: what the number counts, appended to the message)."""
    for key in keys:
        v = options[key]
        if optional and v is None:
            continue
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise ParameterError(f"{key} must be a positive integer{note}, got {v!r}")


def check_geodesic_methods(options: dict[str, Any], keys: Sequence[str]) -> None:
    """Each option of ``keys`` names one of :data:`~shape_toolkit.features.geodesics.GEODESIC_METHODS`."""
    from shape_toolkit.features.geodesics import GEODESIC_METHODS

    for key in keys:
        if options[key] not in GEODESIC_METHODS:
            raise ParameterError(f"{key} must be one of {', '.join(GEODESIC_METHODS)}, got {options[key]!r}")


def evenly_spaced_vertices(n: int, count: int) -> np.ndarray:
    """``min(count, n)`` vertex ids evenly spaced from 0 to ``n - 1`` (distinct: the spacing is at least 1)."""
    return np.linspace(0, n - 1, min(int(count), n)).astype(np.int64)


class TaskAdapter:
    """Base adapter: ``families`` of the compared plugins, metric table, option defaults."""

    name = ""
    families: tuple[str, ...] = ()
    pairwise = False
    needs_keypoints: tuple[str, ...] = ()
    option_defaults: dict[str, Any] = {}
    #: whether the worker hands the method the spectra it declares (a sequence task's pipelines solve their own)
    uses_spectra = True
    default_metrics: tuple[str, ...] = ()
    #: metric name -> (function(prepared, output, options) -> {column: value}, required shape_toolkit.metrics names)
    metrics: dict[str, tuple[Callable[..., dict[str, Any]], tuple[str, ...]]] = {}
    #: options of how an item is prepared (:data:`PROTOCOL_VALUES`) this task takes beside a matching task, which
    #: takes them all; each kept in the options (a row's key) only when not its default
    protocol_options: tuple[str, ...] = ()

    def _pop_protocol(self, options: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
        """``options`` without the :attr:`protocol_options`, and those checked, the defaults left out."""
        if not isinstance(options, dict):
            raise ParameterError("options must be a table")
        rest, proto = dict(options), {}
        for key in self.protocol_options:
            if key in rest:
                value, allowed = rest.pop(key), PROTOCOL_VALUES[key]
                if value not in allowed:
                    raise ParameterError(f"{key} must be one of {', '.join(map(repr, allowed))}, got {value!r}")
                if value != allowed[0]:
                    proto[key] = value
        return rest, proto

    def check_options(self, options: dict[str, Any]) -> dict[str, Any]:
        """Options merged over the defaults; unknown keys raise :class:`ParameterError`. Every task
        also takes the :data:`COMMON_OPTIONS`: ``repeats`` (an integer >= 1): each row runs its method
        that often, one run after the other, and keeps the timings of the fastest (best of N, for timing
        benchmarks); ``blas_threads`` (an integer >= 1): the BLAS threads the method runs with (the runner's
        default is one); ``memory`` (:data:`MEMORY_PROBES`): ``"rss"`` (default) measures a row's peak memory as
        the rise of the worker's resident memory, which under-counts what a long-lived process allocates into
        memory freed earlier, ``"traced"`` as the peak of the allocations ``tracemalloc`` traces during the
        call (NumPy's arrays included; slower); ``metric_costs`` (bool): also time the row's metrics and
        measure their peak memory the same way (``metric_seconds``, ``metric_peak_memory_mb``, shown in the
        report), for benchmarks of the metrics themselves. Kept in the options only when set, so rows
        planned without them keep their keys."""
        if not isinstance(options, dict):
            raise ParameterError("options must be a table")
        known = {**self.option_defaults, **COMMON_OPTIONS}
        bad = sorted(set(options) - set(known))
        if bad:
            raise ParameterError(
                f"unknown {self.name} option {bad[0]!r}; known: {', '.join(sorted(known))}"
            )
        o = {**self.option_defaults, **options}
        common = {k: o.pop(k, default) for k, default in COMMON_OPTIONS.items()}
        r, b = common["repeats"], common["blas_threads"]
        if isinstance(r, bool) or not isinstance(r, int) or not 1 <= r <= MAX_REPEATS:
            raise ParameterError(f"repeats must be an integer in [1, {MAX_REPEATS}] (each row runs its method that "
                                 f"often, one run after the other), got {shown_value(r)}")
        if b is not None and (isinstance(b, bool) or not isinstance(b, int) or not 1 <= b <= MAX_BLAS_THREADS):
            raise ParameterError(f"blas_threads must be an integer in [1, {MAX_BLAS_THREADS}] (threads of one "
                                 f"method call), got {shown_value(b)}")
        if common["memory"] not in MEMORY_PROBES:
            known_probes = ", ".join(map(repr, MEMORY_PROBES))
            raise ParameterError(f"memory must be one of {known_probes}, got {common['memory']!r}")
        if not isinstance(common["metric_costs"], bool):
            raise ParameterError(f"metric_costs must be true or false, got {common['metric_costs']!r}")
        return {**o, **{k: v for k, v in common.items() if v != COMMON_OPTIONS[k]}}

    def check_method(self, options: dict[str, Any], cls: type, params: dict[str, Any]) -> str | None:
        """None when a method (its plugin class and parameters) fits the task's ``options``, else the
        problem (default: every method fits)."""
        return None

    def check_metric(self, name: str) -> str | None:
        """None when ``name`` is usable, else the problem."""
        if name not in self.metrics:
            return f"unknown {self.name} metric {name!r}; known: {', '.join(sorted(self.metrics))}"
        missing = [m for m in self.metrics[name][1] if lookup_metric(m) is None]
        if missing:
            return f"metric {name!r} needs shape_toolkit.metrics.{missing[0]}, which is not available"
        return None

    def run(
        self,
        method,
        prepared: Prepared,
        spectra: dict[str, Any],
        options: dict[str, Any],
        random_state: int,
        detector: Any = None,
        detector_spectra: dict[str, Any] | None = None,
    ):
        """Call the method with the spectra it declared: ``spectra`` ``{"source": ..., "target": ...}``
        (a :class:`Spectrum` or None per side for a plugin, a list of spectra for a pipeline);
        ``detector`` is the keypoint detector of a sparse matcher, given ``detector_spectra``.
        Returns a dict of output arrays (saved for reports)."""
        raise NotImplementedError

    def evaluate(self, names, prepared: Prepared, output: dict, options: dict) -> dict[str, Any]:
        """Every requested metric as ``{column: value}`` (a failing metric raises)."""
        out: dict[str, Any] = {}
        for n in names:
            out.update(self.metrics[n][0](prepared, output, options))
        return out


# -- spectrum ---------------------------------------------------------------------------------
def _m_eigenvalues(p, o, opt):
    lam = np.asarray(o["eigenvalues"])
    return {"eigenvalues": _curve(np.arange(1, lam.size + 1), lam), "mean_eigenvalue": float(lam.mean())}


def _m_fiedler(p, o, opt):
    lam = np.asarray(o["eigenvalues"])
    return {"lambda2": float(lam[1]) if lam.size > 1 else float("nan")}


def _m_mean_degree(p, o, opt):
    """Thesis eq. 3.8: the mean weighted degree, tr(L)/n of the combinatorial Laplacian (Figs. 3.13-3.14)."""
    return {"mean_degree": float(o["mean_degree"])}


def _m_scree(p, o, opt):
    from shape_toolkit.features.scales import scree_alpha

    lam = np.asarray(o["eigenvalues"])
    n = int(o["n_vertices"])
    avail = max(lam.size - 1, 1)
    res: dict[str, Any] = {}
    ts = np.asarray(opt["scree_times"], dtype=float)
    for frac in opt["scree_fractions"]:  # alpha vs t for K = frac of the computed eigenpairs (Fig. 6.3)
        K = max(1, min(avail, int(round(frac * avail))))
        res[f"alpha_vs_t_K{int(round(frac * 100))}pct"] = _curve(
            ts, [scree_alpha(lam, K, t, n=n) for t in ts]
        )
    Ks = np.arange(1, avail + 1)
    for t in opt["scree_times_for_K"]:  # alpha vs K (percent of computed eigenpairs) at fixed t (Fig. 6.4)
        res[f"alpha_vs_K_t{t:g}"] = _curve(100.0 * Ks / avail, [scree_alpha(lam, int(K), t, n=n) for K in Ks])
    return res


def _m_eigenvalue_error(p, o, opt):
    """Max relative eigenvalue error against a reference spectrum of the same Laplacian and mass: ARPACK
    shift-invert on a CHOLMOD factor at full precision (``tol=0``; dense LAPACK for small or nearly full
    problems), through the run's cache (so computed once per item); ``max_i |l_i - ref_i| / max(|ref_i|,
    ref_2)``: the null eigenvalue is judged against the first non-zero one."""
    from shape_toolkit.core.eigen import DENSE_MAX_N, EigenSolver

    spectrum = o["spectrum"]
    lam = np.asarray(spectrum.eigenvalues)
    spec = SpectrumSpec(int(lam.size), spectrum.weighting, spectrum.laplacian, spectrum.mass is not None,
                        dict(spectrum.meta.get("weighting_params") or {}))  # fmt: skip
    n = p.target.n_vertices  # ARPACK needs k < n - 1: small problems get dense LAPACK instead
    method = "dense" if n <= DENSE_MAX_N or 3 * lam.size >= n else "arpack"
    ref = np.asarray(spec.compute(p.target, components="largest", solver=EigenSolver(method, tol=0.0)).eigenvalues)
    if ref.size != lam.size:
        raise ParameterError(f"reference spectrum has {ref.size} eigenvalues, the row {lam.size}")
    den = np.maximum(np.abs(ref), abs(ref[1]) if ref.size > 1 else max(abs(ref[0]), 1e-300))
    return {"eigenvalue_error": float(np.max(np.abs(np.sort(lam) - ref) / den))}


class SpectrumTask(TaskAdapter):
    """Laplacian spectra of each shape under each weighting plugin (the compared methods)."""

    name = "spectrum"
    families = ("weightings",)
    option_defaults = {
        "scree_fractions": [0.05, 0.1, 0.2, 0.5],
        "scree_times": [0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0],
        "scree_times_for_K": [1.0, 10.0],
    }
    default_metrics = ("eigenvalues", "lambda2")

    def check_options(self, options: dict[str, Any]) -> dict[str, Any]:
        """``scree_fractions``: fractions in (0, 1] of the computed eigenpairs; ``scree_times`` and
        ``scree_times_for_K``: diffusion times, finite and >= 0 (:func:`shape_toolkit.features.scales.scree_alpha`)."""
        o = super().check_options(options)
        check_number_lists(o, ("scree_fractions",), 0.0, 1.0, open_low=True, what="fractions of the eigenpairs: ")
        check_number_lists(o, ("scree_times", "scree_times_for_K"), 0.0, 1e12, what="diffusion times: ")
        return o
    metrics = {
        "eigenvalues": (_m_eigenvalues, ()),
        "lambda2": (_m_fiedler, ()),
        "scree_alpha": (_m_scree, ()),
        "eigenvalue_error": (_m_eigenvalue_error, ()),
        "mean_degree": (_m_mean_degree, ()),
    }

    def run(self, method, prepared, spectra, options, random_state, detector=None, detector_spectra=None):
        spec = spectra["target"]  # the subject: computed inside the row, timed as the method
        return {"eigenvalues": spec.eigenvalues, "n_vertices": prepared.target.n_vertices, "spectrum": spec,
                "mean_degree": float(np.mean(spec.degrees))}


# -- keypoints --------------------------------------------------------------------------------
def _m_n_keypoints(p, o, opt):
    return {"n_keypoints": int(len(o["keypoints"])), "n_keypoints_source": int(len(o["source_keypoints"]))}


def _m_repeatability(p, o, opt):
    """Keypoint repeatability in both directions through the ground-truth map
    (:func:`shape_toolkit.metrics.repeatability_report`); columns per radius and a curve. Scored on the clean
    target (``score_on = "clean"``), the target's keypoints are taken there through the corruption's back-map
    (a point cloud's point: its vertex, or the nearest vertex of the mesh it was sampled from)."""
    report, gt_map = lookup_metric("repeatability_report"), lookup_metric("ground_truth_map")
    if p.clean_target is not None:
        p, kp = score_on_clean(p, o["keypoints"])
        o = {**o, "keypoints": np.unique(kp[kp >= 0])}
    if p.truth is None or not len(p.truth):
        raise ParameterError(f"item {p.name!r} has no ground-truth map for repeatability")
    a_to_b = gt_map(p.source, p.truth[:, 0], p.truth[:, 1], p.target.n_vertices)
    b_to_a = gt_map(p.target, p.truth[:, 1], p.truth[:, 0], p.source.n_vertices)
    kw = {} if opt.get("radii") is None else {"radii": opt["radii"]}
    res = report(
        p.source,
        p.target,
        o["source_keypoints"],
        o["keypoints"],
        a_to_b,
        b_to_a,
        method=opt["geodesic_method"],
        **kw,
    )
    out: dict[str, Any] = {
        "repeatability_curve": _curve(res["radii"], res["mean"]),
        "chance_curve": _curve(res["radii"], res["chance"]),
    }
    for r, m, c in zip(res["radii"], res["mean"], res["chance"]):
        out[f"repeatability@{r:g}"] = m
        out[f"chance@{r:g}"] = c
    return out


class KeypointsTask(TaskAdapter):
    """Keypoints on the clean source and the (corrupted / other pose) target; repeatability
    through the ground-truth map."""

    name = "keypoints"
    families = ("keypoints",)
    pairwise = True
    option_defaults = {"radii": None, "geodesic_method": "fmm"}
    default_metrics = ("n_keypoints",)
    metrics = {
        "n_keypoints": (_m_n_keypoints, ()),
        "repeatability": (_m_repeatability, ("repeatability_report", "ground_truth_map")),
    }
    #: ``score_on = "clean"``: repeatability on the clean target (keypoints of a point cloud scored on its mesh);
    #: ``target = "self"``: the source against a corrupted copy of itself (the identity as ground truth)
    protocol_options = ("score_on", "target")

    def check_options(self, options):
        rest, proto = self._pop_protocol(options)
        return {**super().check_options(rest), **proto}

    def run(self, method, prepared, spectra, options, random_state, detector=None, detector_spectra=None):
        return {
            "source_keypoints": np.asarray(
                method.detect(prepared.source, spectrum=spectra.get("source")), np.int64
            ),
            "keypoints": np.asarray(method.detect(prepared.target, spectrum=spectra.get("target")), np.int64),
        }


# -- descriptors ------------------------------------------------------------------------------
def _m_dimensions(p, o, opt):
    return {"dimensions": int(o["shape"][1]), "finite": bool(o["finite"])}


class DescriptorsTask(TaskAdapter):
    """Per-vertex descriptors of each shape (the compared methods: ``descriptors`` plugins, with the
    spectrum they declare from the run's cache, timed apart as ``spectrum_seconds``): the row's time and
    peak memory are the descriptor's alone, against the spectrum it needs. A keypoint descriptor
    (``heat-distance``, ``heat-diffusion``) gets the keypoints of the method's ``keypoints = { plugin =
    ... }`` detector (detected inside the row), or with the option ``keypoints = N`` the ``N`` vertex ids
    evenly spaced from 0 to ``n - 1`` (no detector: the descriptor timed alone). Output: the descriptor's
    shape ``(n, d)`` and whether every value is finite (the matrix is not kept); metric ``dimensions``."""

    name = "descriptors"
    families = ("descriptors",)
    option_defaults = {"keypoints": None}
    default_metrics = ("dimensions",)
    metrics = {"dimensions": (_m_dimensions, ())}

    def check_options(self, options):
        o = super().check_options(options)
        check_positive_ints(o, ("keypoints",), optional=True, note=" (evenly spaced vertices)")
        return o

    def run(self, method, prepared, spectra, options, random_state, detector=None, detector_spectra=None):
        shape = prepared.target
        kp = None
        if options["keypoints"] is not None:
            kp = evenly_spaced_vertices(shape.n_vertices, options["keypoints"])
        elif detector is not None:
            kp = np.asarray(detector.detect(shape, spectrum=(detector_spectra or {}).get("target")), np.int64)
        d = np.asarray(method.compute(shape, spectrum=spectra.get("target"), keypoints=kp))
        # the (n, d) matrix itself is not kept: at 10^5 vertices it would fill the run folder
        return {"shape": np.array(d.shape, dtype=np.int64), "finite": np.array(bool(np.isfinite(d).all()))}


# -- segmentation -----------------------------------------------------------------------------
class HumanSegmentations:
    """The method of the human-consistency row (``human_consistency = true``): the dataset's own
    segmentations, each scored against the others (PSB's "Human" row); it declares no spectrum."""

    def spectrum_spec(self) -> None:
        """No spectrum."""
        return None


#: the n_segments option's value that takes each item's k from its ground truth
HUMAN_MODE = "human-mode"
#: the keys of the ``clicks`` option (:func:`shape_toolkit.results.labels.clicks_from_segmentation`)
_CLICK_KEYS = ("n_must_per_segment", "n_cannot_per_boundary", "cannot_offset", "min_segment_fraction")


def _truth_faces(p: Prepared) -> list[np.ndarray]:
    """The item's ground truths per face: the dataset's own face labels when the mesh is unchanged,
    else face labels derived from the (carried) vertex labels."""
    from shape_toolkit.results.labels import vertex_to_face_labels

    if not p.target_labels and not p.target_face_labels:
        raise ParameterError(f"item {p.name!r} has no ground-truth segmentation")
    faces = p.target.require_faces("segmentation scores")
    return list(p.target_face_labels) or [vertex_to_face_labels(faces, g) for g in p.target_labels]


def _m_n_segments(p, o, opt):
    if o.get("human"):  # the humans' own segment counts, averaged
        return {"n_segments": float(np.mean([np.unique(t).size for t in _truth_faces(p)]))}
    lab = np.asarray(o["labels"])
    out: dict[str, Any] = {"n_segments": int(np.unique(lab[lab >= 0]).size)}
    if "n_segments_given" in o:
        out["n_segments_given"] = int(np.asarray(o["n_segments_given"]))
    return out


def _m_segmentation(p, o, opt):
    """PSB scores (:func:`shape_toolkit.metrics.segmentation_scores`) of the predicted face labels (the
    segmenter's own where it segments faces, else its vertex labels by majority) against every human
    segmentation, averaged; against the others when the first one gave the clicks. The human row
    (:func:`shape_toolkit.metrics.human_consistency_scores`) scores each human against the others.
    Faces weigh their area (``face_weights = "area"``) or count once (``"uniform"``, PSB's
    definition; then ``rand_index_error_area`` is added for comparison)."""
    from shape_toolkit.results.labels import vertex_to_face_labels

    truths = _truth_faces(p)
    faces = p.target.require_faces("segmentation scores")
    weights = p.target.face_areas if opt.get("face_weights", "area") == "area" else np.ones(len(faces))
    if o.get("human"):
        res = lookup_metric("human_consistency_scores")(truths, weights, mesh=p.target)
        pred = None
    else:
        fl = o.get("face_labels")
        pred = np.asarray(fl) if fl is not None and len(fl) == len(faces) else vertex_to_face_labels(
            faces, np.asarray(o["labels"]))
        skip = int(np.asarray(o.get("clicked_truth", -1)))
        if 0 <= skip < len(truths) and len(truths) > 1:
            truths = truths[:skip] + truths[skip + 1:]
        res = lookup_metric("segmentation_scores")(pred, truths, weights, mesh=p.target)
    out = {k: float(v) for k, v in res.items()
           if isinstance(v, (int, float, np.floating)) and k != "n_truths"}
    if opt.get("face_weights") == "uniform":
        ri = lookup_metric("rand_index_error")
        if pred is None:  # each human against the others, area-weighted
            area = [float(np.mean([ri(t, u, p.target.face_areas) for j, u in enumerate(truths) if j != i]))
                    for i, t in enumerate(truths)]
        else:
            area = [ri(pred, t, p.target.face_areas) for t in truths]
        out["rand_index_error_area"] = float(np.mean(area))
    return out


class SegmentationTask(TaskAdapter):
    """Segmenters on each (corrupted) shape, scored against its ground-truth segmentations.

    Options: ``constraints`` draws must/cannot-links from the first ground truth's vertex labels
    (:func:`shape_toolkit.results.labels.draw_constraints`); ``clicks`` draws them with the PSB
    protocol from the first human's face labels (:func:`shape_toolkit.results.labels.clicks_from_segmentation`,
    keys ``n_must_per_segment``, ``n_cannot_per_boundary``, ``cannot_offset``, ``min_segment_fraction``;
    the run's ``random_state``), and the method is then scored against the other humans.
    ``n_segments``: every method's number of segments (an integer, or ``"human-mode"``: per item, the
    most frequent count among its human segmentations, PSB's nSeg-ByModel; a method's own
    ``params.n_segments`` wins). ``face_weights``: ``"area"`` or ``"uniform"`` (every face counts once,
    as PSB). ``human_consistency``: add a ``human`` row, each human against the others."""

    name = "segmentation"
    families = ("segmenters",)
    option_defaults = {
        "constraints": None, "clicks": None, "n_segments": None, "face_weights": "area", "human_consistency": False,
    }
    default_metrics = ("n_segments",)
    metrics = {
        "n_segments": (_m_n_segments, ()),
        "segmentation": (_m_segmentation, ("segmentation_scores", "human_consistency_scores", "rand_index_error")),
    }

    def check_options(self, options):
        o = super().check_options(options)
        k = o["n_segments"]
        if k is not None and k != HUMAN_MODE and (isinstance(k, bool) or not isinstance(k, int) or k < 2):
            raise ParameterError(f"n_segments must be an integer >= 2 or {HUMAN_MODE!r}, got {k!r}")
        if o["face_weights"] not in ("area", "uniform"):
            raise ParameterError(f"face_weights must be 'area' or 'uniform', got {o['face_weights']!r}")
        if not isinstance(o["human_consistency"], bool):
            raise ParameterError(f"human_consistency must be true or false, got {o['human_consistency']!r}")
        for key in ("constraints", "clicks"):
            if o[key] is not None and not isinstance(o[key], dict):
                raise ParameterError(f"{key} must be a table, got {o[key]!r}")
        if o["constraints"] is not None and o["clicks"] is not None:
            raise ParameterError("clicks and constraints draw the same links two ways: give one of them")
        c = o["clicks"]
        if c is not None:
            bad = sorted(set(c) - set(_CLICK_KEYS))
            if bad:
                raise ParameterError(f"clicks has no key {bad[0]!r}; known: {', '.join(_CLICK_KEYS)}")
            for key, v in c.items():
                lo = 0.0 if key == "min_segment_fraction" else 1
                if isinstance(v, bool) or not isinstance(v, (int, float)) or v < lo or (
                        key != "min_segment_fraction" and not isinstance(v, int)):
                    raise ParameterError(f"clicks {key} must be {'a number >= 0' if lo == 0.0 else 'an integer >= 1'}"
                                         f", got {v!r}")
        return o

    def check_method(self, options: dict[str, Any], cls: type, params: dict[str, Any]) -> str | None:
        """None when a method fits the options, else the problem: ``n_segments`` needs methods that
        take ``n_segments`` (unless they set it themselves), ``clicks`` and ``constraints`` methods that
        take constraints."""
        from shape_toolkit.api.interfaces import Segmenter

        names = cls._param_names() if hasattr(cls, "_param_names") else []
        drawn = next((k for k in ("clicks", "constraints") if options.get(k) is not None), None)
        decides = getattr(cls, "accepts_constraints", None) is not getattr(Segmenter, "accepts_constraints", None)
        if drawn and not getattr(cls, "takes_constraints", False) and not decides:
            return (f"the task option {drawn} gives every method constraints, but {getattr(cls, '__name__', cls)} "
                    "takes none (it is unsupervised): put it in a task without that option")
        if options.get("n_segments") is not None and "n_segments" not in names and "n_segments" not in params:
            return (f"the task option n_segments = {options['n_segments']!r} sets each method's n_segments, "
                    f"but {getattr(cls, '__name__', cls)} takes none: put it in a task without that option")
        return None

    def run(self, method, prepared, spectra, options, random_state, detector=None, detector_spectra=None):
        if isinstance(method, HumanSegmentations):
            if len(_truth_faces(prepared)) < 2:
                raise ParameterError(f"item {prepared.name!r} has fewer than 2 human segmentations")
            first = prepared.target_labels[0] if prepared.target_labels else np.zeros(0, np.int64)
            return {"human": True, "labels": np.asarray(first)}
        constraints = None
        clicked = -1
        if options.get("constraints") is not None:
            from shape_toolkit.results.labels import draw_constraints

            if not prepared.target_labels:
                raise ParameterError("constraints need a ground-truth segmentation")
            c = dict(options["constraints"])
            constraints = draw_constraints(
                prepared.target_labels[0], prepared.target.edges, random_state=random_state, **c
            )
        elif options.get("clicks") is not None:
            from shape_toolkit.results.labels import clicks_from_segmentation

            constraints = clicks_from_segmentation(prepared.target, _truth_faces(prepared)[0], faces=True,
                                                   random_state=random_state, **options["clicks"])
            clicked = 0
        from shape_toolkit.plugins.segmenters.sdf import SDF_CACHE

        SDF_CACHE.clear()  # each row its own SDF (ncut and sdf share it): a row's time is not the rows' order
        result = method.segment(prepared.target, spectrum=spectra.get("target"), constraints=constraints)
        out: dict[str, Any] = {"labels": result.labels, "clicked_truth": clicked}
        if result.face_labels is not None:
            out["face_labels"] = result.face_labels
        k = getattr(method, "n_segments", None)
        if options.get("n_segments") is not None and isinstance(k, (int, np.integer)):
            out["n_segments_given"] = int(k)
        return out


# -- matching ---------------------------------------------------------------------------------
def _errors(p: Prepared, target_of: np.ndarray, *, symmetric: bool = False) -> np.ndarray:
    """Normalised geodesic errors of the evaluated truth pairs from the prepared rows (the
    protocol of :func:`shape_toolkit.metrics.geodesic_errors`, reusing rows computed once per item):
    against the ground truth alone, or with ``symmetric`` the smaller of the errors to the true and
    to the symmetric vertex (the item must have symmetric rows); ``inf`` where unmatched."""
    if p.geodesic_rows is None:
        raise ParameterError(f"item {p.name!r} has no correspondence ground truth")
    ts = p.truth_eval[:, 0]
    pred = np.asarray(target_of, dtype=np.int64)[ts]
    ok = pred >= 0
    err = np.full(len(ts), np.inf)
    r = np.flatnonzero(ok)
    err[r] = p.geodesic_rows[r, pred[r]]
    if symmetric:
        err[r] = np.minimum(err[r], p.geodesic_rows_sym[r, pred[r]])
    return err / np.sqrt(p.target.area)


def _m_geodesic(p, o, opt):
    """The normalised geodesic error against the ground truth alone (mean, median, within 0.05,
    matched fraction, curve; for a sparse method, on its seeds at truth points, and ``n_scored``, how
    many those are); where the dataset has a symmetric ground truth also the
    symmetry-aware error (``mean_geodesic_error_sym``, its curve) and ``flipped`` (1 when the map
    swaps left and right: :func:`shape_toolkit.metrics.is_flipped`, else 0); without one those are
    null (n/a in reports, never 0)."""
    report, flipped = lookup_metric("correspondence_report"), lookup_metric("is_flipped")
    ts = p.truth_eval[:, 0]
    t = np.asarray(o["target_of"])
    sym = p.geodesic_rows_sym is not None
    if o.get("sparse"):  # evaluate the matched truth points only
        keep = t[ts] >= 0
        if not keep.any():
            return {"mean_geodesic_error": float("nan"), "matched_fraction": 0.0, "n_scored": 0,
                    **({"mean_geodesic_error_sym": float("nan"), "flipped": None} if sym else {})}
        sub = Prepared(**{**p.__dict__})
        sub.truth_eval = p.truth_eval[keep]
        sub.geodesic_rows = p.geodesic_rows[keep]
        sub.geodesic_rows_sym = p.geodesic_rows_sym[keep] if sym else None
        p = sub
    res = report(_errors(p, t))
    out = {
        "mean_geodesic_error": res["mean_geodesic_error"],
        "median_geodesic_error": res["median_geodesic_error"],
        "within_0.05": res["within_0.05"],
        "matched_fraction": res["matched_fraction"],
        "geodesic_error_curve": res["curve"],
        "mean_geodesic_error_sym": None,
        "flipped": None,
    }
    if sym:
        rs = report(_errors(p, t, symmetric=True))
        out["mean_geodesic_error_sym"] = rs["mean_geodesic_error"]
        out["geodesic_error_sym_curve"] = rs["curve"]
        both = np.isfinite([res["mean_geodesic_error"], rs["mean_geodesic_error"]]).all()
        out["flipped"] = int(flipped(res["mean_geodesic_error"], rs["mean_geodesic_error"])) if both else None
    if o.get("sparse"):  # how many seeds were scored: the weight of this row when seeds are pooled over items
        out["n_scored"] = len(p.truth_eval)
    return out


def _m_coverage(p, o, opt):
    fn = lookup_metric("target_coverage")
    return {"target_coverage": fn(np.asarray(o["target_of"]), p.target.n_vertices)}


def _labels_for(p: Prepared, opt: dict) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth segmentations of source and target: the dataset's (first) labels, or with the
    ``label_segments`` option, that many geodesic Voronoi segments of the source carried to the
    target by the ground-truth map (:func:`shape_toolkit.metrics.truth_segments`; TOSCA, FAUST)."""
    k = opt.get("label_segments")
    if k:
        if p.truth is None or not len(p.truth):
            raise ParameterError(f"item {p.name!r} has no ground-truth map to carry segments with")
        return lookup_metric("truth_segments")(p.source, p.target, p.truth[:, 0], p.truth[:, 1], int(k))
    if not p.source_labels or not p.target_labels:
        raise ParameterError(
            f"item {p.name!r} has no ground-truth labels on both shapes "
            "(set the matching option label_segments = K to derive K segments from the ground-truth map)"
        )
    return np.asarray(p.source_labels[0]), np.asarray(p.target_labels[0])


def _m_label_transfer(p, o, opt):
    """Table 7.3: mean recall and precision of the source's segmentation carried through the map
    (:func:`shape_toolkit.metrics.map_label_scores`; target vertices that no source vertex reaches
    take the label of the nearest reached one along the edges)."""
    src, tgt = _labels_for(p, opt)
    res = lookup_metric("map_label_scores")(np.asarray(o["target_of"]), src, tgt, p.target)
    return {"label_recall": res["recall"], "label_precision": res["precision"]}


def _m_soft_label_transfer(p, o, opt):
    """Table 5.2 (Algorithm 5): mean recall and precision of the source's segmentation carried by the
    probabilistic label transfer of eq. 5.9 (:func:`shape_toolkit.metrics.map_label_scores` with
    ``soft=True``): each target vertex takes the label of largest posterior mass of the method's
    :class:`~shape_toolkit.results.correspondence.Correspondence` (EM's posteriors; a map without
    posteriors, or a sparse or published one: its 0/1 matrix); a target vertex without mass stays
    unlabelled (no nearest-vertex filling, unlike ``label_transfer``) and counts against recall."""
    src, tgt = _labels_for(p, opt)
    corr = o.get("correspondence")
    if corr is None:
        corr = Correspondence(np.asarray(o["target_of"], dtype=np.int64), p.target.n_vertices)
    res = lookup_metric("map_label_scores")(corr, src, tgt, soft=True)
    return {"soft_label_recall": res["recall"], "soft_label_precision": res["precision"]}


def _on_clean(prepared: Prepared, corr: Any, target_of: np.ndarray) -> Any:
    """A method's :class:`~shape_toolkit.results.correspondence.Correspondence` onto the corrupted target, read
    on the clean target of ``prepared`` (:func:`score_on_clean`): the map ``target_of`` (already composed) and
    the posteriors summed through the corruption's vertex map ``(n_source, n_clean)``; None stays None."""
    if corr is None or prepared.clean_target is None:
        return corr
    n = prepared.clean_target.n_vertices
    post = None
    if corr.posteriors is not None:
        vmap = np.asarray(prepared.vertex_map, dtype=np.int64)
        ok = np.flatnonzero(vmap >= 0)
        back = sp.csr_matrix((np.ones(ok.size), (ok, vmap[ok])), shape=(vmap.size, n))
        post = (corr.posteriors @ back).tocsr()
    return Correspondence(target_of, n, corr.confidence, post, corr.info)


def _m_r_smoothness(p, o, opt):
    """Table 7.2: percent of r-smooth source vertices (eq. 7.4-7.5) per neighbourhood size r
    (:func:`shape_toolkit.metrics.r_smoothness_table`): a column ``r_smooth@R`` per r and the curve."""
    table = lookup_metric("r_smoothness_table")(
        p.source, p.target, np.asarray(o["target_of"]), tuple(opt["r_smooth_rs"]), opt["r_smooth_theta"],
        sample=opt["r_smooth_sample"], method=opt["r_smooth_geodesics"],
        random_state=opt["r_smooth_random_state"],
    )
    out: dict[str, Any] = {f"r_smooth@{r:g}": v for r, v in table.items()}
    out["r_smoothness_curve"] = _curve(list(table), list(table.values()))
    return out


def truth_seeds(prepared: Prepared, n: int) -> np.ndarray:
    """``n`` ground-truth pairs ``(n, 2)`` [source vertex, target vertex] spread over the source: farthest-point
    samples (from the first) of the source positions of the item's truth pairs, each source vertex's first pair.
    The seeds name vertices of the shapes the method matches: scored on the clean target (``score_on = "clean"``),
    the truth's target column is carried onto the corrupted target through the corruption's vertex map, and pairs
    whose target vertex did not survive the corruption are not drawn."""
    from shape_toolkit.core.geometry import farthest_point_sampling
    from shape_toolkit.data.corruptions import invert_vertex_map

    truth = None if prepared.truth is None else np.asarray(prepared.truth, np.int64)
    if truth is not None and len(truth) and prepared.clean_target is not None:
        onto = invert_vertex_map(prepared.vertex_map, prepared.clean_target)[truth[:, 1]]
        truth = np.column_stack([truth[:, 0], onto])[onto >= 0]
    if truth is None or not len(truth):
        raise ParameterError(f"item {prepared.name!r} has no ground truth to draw seeds from")
    _, first = np.unique(truth[:, 0], return_index=True)
    first = np.sort(first)
    pts = np.asarray(prepared.source.vertices)[truth[first, 0]]
    rows = first[np.asarray(farthest_point_sampling(pts, min(n, len(first))), np.int64)]
    return truth[rows]


def _kept(corr: Any) -> dict[str, Any]:
    """``{"correspondence": corr}`` when a method returned a
    :class:`~shape_toolkit.results.correspondence.Correspondence` (its posteriors score
    ``soft_label_transfer``; an object, so never saved with the row's arrays), else ``{}``."""
    return {"correspondence": corr} if isinstance(corr, Correspondence) else {}


class GroundTruthMap:
    """The method of the ground-truth reference row (``truth_reference = true``): each pair's own
    ground truth scored by the same metrics, so that a table shows what the metric gives a perfect
    map (between independently remeshed shapes even the true map is not r-smooth everywhere). The
    ground truth pairs some source vertices (template points); every other source vertex takes the
    image of the nearest paired one along the edges, so that the map is total. No spectrum."""

    def spectrum_spec(self) -> None:
        """No spectrum."""
        return None

    @staticmethod
    def target_of(prepared: Prepared) -> np.ndarray:
        """int64 ``(n_source,)`` target vertex of each source vertex (-1 where no paired vertex is reachable)."""
        from shape_toolkit.features.geodesics import fill_from_nearest

        truth = prepared.truth
        if truth is None or not len(truth):
            raise ParameterError(f"item {prepared.name!r} has no ground-truth correspondence for truth_reference")
        t = np.full(prepared.source.n_vertices, -1, dtype=np.int64)
        t[truth[:, 0]] = truth[:, 1]
        return fill_from_nearest(prepared.source, t)


class MatchingTask(TaskAdapter):
    """Dense matchers (and sparse matchers on detected keypoints) from the clean source to the
    (corrupted) target, scored by the normalised geodesic error on ground-truth pairs.

    Options of the protocol: ``score_on = "clean"`` scores every metric on the uncorrupted target,
    the map composed with the corruption's vertex back-map (a corrupted shape is matched, the
    error is measured where the ground truth was given); ``target = "self"`` matches each shape to
    a (corrupted) copy of itself, thesis Table 5.2's label transfer from a clean shape to its
    corrupted instances (``label_transfer`` scores the hard map, ``soft_label_transfer`` Algorithm 5's soft
    transfer of eq. 5.9 from the method's posteriors; ``label_segments = K``: K geodesic Voronoi cells as the
    truth where the dataset has no segmentations). A peer reading published maps (``peer = "maps"``) is given
    the item.
    ``corrupt = "both"`` corrupts the source too (a size grid of pairs with ``subdivide``), ``corrupt =
    "source"`` the source only (a crop of the source against the whole target: partial matching);
    ``truth_seeds = N`` gives dense matcher plugins N ground-truth seeds (:func:`truth_seeds`);
    ``truth_reference = true`` adds a ``ground truth`` row, the pair's own ground-truth map
    (:class:`GroundTruthMap`), shown beside the methods and never ranked."""

    name = "matching"
    families = ("dense_matchers", "sparse_matchers")
    pairwise = True
    needs_keypoints = ("sparse_matchers",)
    option_defaults = {
        "truth_sample": 500,
        # "even": evenly spaced in the ground truth's order; "stride": every (n // truth_sample)-th
        "truth_points": "random",
        "geodesic_method": "heat",
        # r_smoothness (Table 7.2): neighbourhood sizes in percent of the vertices, theta, evaluated
        # source vertices (None: all, as the thesis) drawn with r_smooth_random_state, geodesics
        "r_smooth_rs": [0.1, 0.2, 0.3, 0.4, 0.5, 0.8],
        "r_smooth_theta": 0.9,
        "r_smooth_sample": None,
        "r_smooth_random_state": 0,
        "r_smooth_geodesics": "dijkstra",
        # label_transfer (Table 7.3): None uses the dataset's segmentations; K derives K segments
        "label_segments": None,
        # "target": scored on the corrupted target; "clean": on the clean one, through the back-map
        "score_on": "target",
        # "pair": the dataset's target; "self": a (corrupted) copy of the source (Table 5.2)
        "target": "pair",
        # "target": the corruption changes the target; "both": the source too (e.g. subdivided pairs); "source":
        # the source only (a part against a whole shape)
        "corrupt": "target",
        # N: dense matchers get N ground-truth seeds (farthest-point samples on the source; those using seeds)
        "truth_seeds": None,
        # true: a "ground truth" reference row, the ground-truth map scored by the same metrics
        "truth_reference": False,
    }
    default_metrics = ("geodesic_error",)
    metrics = {
        "geodesic_error": (_m_geodesic, ("correspondence_report", "is_flipped")),
        "coverage": (_m_coverage, ("target_coverage",)),
        "label_transfer": (_m_label_transfer, ("map_label_scores", "truth_segments")),
        "soft_label_transfer": (_m_soft_label_transfer, ("map_label_scores", "truth_segments")),
        "r_smoothness": (_m_r_smoothness, ("r_smoothness_table",)),
    }

    def check_options(self, options):
        o = super().check_options(options)
        check_geodesic_methods(o, ("geodesic_method", "r_smooth_geodesics"))
        check_positive_ints(o, ("truth_sample", "r_smooth_sample", "label_segments", "truth_seeds"), optional=True)
        rs = o["r_smooth_rs"]
        if not isinstance(rs, list) or not rs or not all(
            isinstance(r, (int, float)) and not isinstance(r, bool) and 0 < r <= 100 for r in rs
        ):
            raise ParameterError(f"r_smooth_rs must be a non-empty list of percents in (0, 100], got {rs!r}")
        th = o["r_smooth_theta"]
        if isinstance(th, bool) or not isinstance(th, (int, float)) or not 0 < th <= 1:
            raise ParameterError(f"r_smooth_theta must be in (0, 1], got {th!r}")
        for key, allowed in PROTOCOL_VALUES.items():
            if o[key] not in allowed:
                raise ParameterError(f"{key} must be one of {', '.join(map(repr, allowed))}, got {o[key]!r}")
        if o["corrupt"] in ("both", "source") and o["target"] == "self":
            raise ParameterError(f'corrupt = "{o["corrupt"]}" needs a pair: with target = "self" the source is the '
                                 'clean shape')
        if not isinstance(o["truth_reference"], bool):
            raise ParameterError(f"truth_reference must be true or false, got {o['truth_reference']!r}")
        if o["truth_reference"] and o["score_on"] == "clean":
            raise ParameterError('truth_reference scores the ground truth of the matched target: it does not go '
                                 'with score_on = "clean"')
        if not o["truth_reference"]:  # kept only when true: the options are part of a row's key, which must hold
            del o["truth_reference"]  # for the rows of runs made before the option existed
        rsd = o["r_smooth_random_state"]
        if isinstance(rsd, bool) or not isinstance(rsd, int) or rsd < 0:
            raise ParameterError(f"r_smooth_random_state must be a non-negative integer, got {rsd!r}")
        return o

    def check_method(self, options: dict[str, Any], cls: type, params: dict[str, Any]) -> str | None:
        """None when a method fits the options, else the problem: ``truth_seeds`` needs matchers whose
        ``match`` takes ``seeds`` (every dense matcher; not the sparse ones)."""
        import inspect

        if options.get("truth_seeds") is None:
            return None
        match = getattr(cls, "match", None)
        if match is None or "seeds" not in inspect.signature(match).parameters:
            return (f"the task option truth_seeds gives every method ground-truth seeds, but "
                    f"{getattr(cls, '__name__', cls)} takes none: put it in a task without that option")
        return None

    def evaluate(self, names, prepared: Prepared, output: dict, options: dict) -> dict[str, Any]:
        """Every requested metric, on the clean target through the back-map when the item was
        prepared with ``score_on = "clean"`` (:func:`score_on_clean`)."""
        view, t = score_on_clean(prepared, output["target_of"])
        corr = _on_clean(prepared, output.get("correspondence"), t)
        return super().evaluate(names, view, {**output, "target_of": t, "correspondence": corr}, options)

    def run(self, method, prepared, spectra, options, random_state, detector=None, detector_spectra=None):
        src, tgt = prepared.source, prepared.target
        if isinstance(method, GroundTruthMap):  # the reference row: no method ran, no cost
            return {"target_of": method.target_of(prepared), "sparse": False, "published": True}
        if hasattr(method, "match_item"):  # published maps: read for the item, onto its clean target
            corr = method.match_item(prepared)
            return {"target_of": np.asarray(corr.target_of, dtype=np.int64), "sparse": False, "published": True}
        if detector is not None:
            ds = detector_spectra or {}
            skp = np.asarray(detector.detect(src, spectrum=ds.get("source")), np.int64)
            tkp = np.asarray(detector.detect(tgt, spectrum=ds.get("target")), np.int64)
            pairs = np.asarray(
                method.match(
                    src,
                    tgt,
                    skp,
                    tkp,
                    source_spectrum=spectra.get("source"),
                    target_spectrum=spectra.get("target"),
                ),
                dtype=np.int64,
            ).reshape(-1, 2)
            t = np.full(src.n_vertices, -1, dtype=np.int64)
            t[pairs[:, 0]] = pairs[:, 1]
            return {"target_of": t, "pairs": pairs, "sparse": True}
        if type(method).__name__ == "Pipeline":  # shape_toolkit.pipeline: its stages pick their spectra
            given = {side: list(spectra.get(side) or []) for side in ("source", "target")}
            corr = method.run(src, tgt, spectra=given) if any(given.values()) else method.run(src, tgt)
            t = np.asarray(corr.target_of, dtype=np.int64)
            return {"target_of": t, "sparse": False, **_kept(corr)}
        seeds = {} if options.get("truth_seeds") is None else {"seeds": truth_seeds(prepared, options["truth_seeds"])}
        corr = method.match(
            src, tgt, source_spectrum=spectra.get("source"), target_spectrum=spectra.get("target"), **seeds
        )
        t = corr.target_of if hasattr(corr, "target_of") else np.asarray(corr, dtype=np.int64)
        return {"target_of": np.asarray(t, dtype=np.int64), "sparse": False, **_kept(corr)}


# -- sequences --------------------------------------------------------------------------------
SEQUENCE_MODES = ("chain", "direct")


def _none_if_nan(v: Any) -> float | None:
    return None if v is None or not np.isfinite(v) else float(v)


def _m_drift(p, o, opt):
    """Thesis 7.5.3: the drift per frame of the tracked trajectories (``PoseSequence.drift``: Dijkstra
    geodesic on the clean frame between tracked and true material point / sqrt(area), over
    ``sample`` trajectories evenly spaced; points welded away in a merged frame left out): a column
    ``drift@fT`` per frame T >= 1, ``drift_mean`` (mean over frames 1..T-1), ``drift_last``,
    ``within_last`` (fraction within ``radius``), ``lost_last`` and the curves per frame."""
    from shape_toolkit.data.synthetic import cached_pose_sequence

    seq = cached_pose_sequence(p.meta["sequence"])
    d = seq.drift(np.asarray(o["ids"]), radius=float(opt["radius"]), sample=opt["sample"])
    mean = [_none_if_nan(m) for m in d["mean"]]
    out: dict[str, Any] = {f"drift@f{t}": mean[t] for t in range(1, len(mean))}
    later = [m for m in mean[1:] if m is not None]
    out["drift_mean"] = float(np.mean(later)) if later else None
    out["drift_last"] = mean[-1]
    out["within_last"] = _none_if_nan(d["within"][-1])
    out["lost_last"] = _none_if_nan(d["lost"][-1])
    out["drift_curve"] = [[float(t), m] for t, m in enumerate(mean) if m is not None]
    out["within_curve"] = [[float(t), float(w)] for t, w in enumerate(d["within"]) if w is not None]
    return out


def _m_wrong_part(p, o, opt):
    """The fraction of the trajectories (alive, with a truth) on another body part (body, each limb)
    than their true material point, averaged over frames 1..T-1 (limb swaps, whole-body turns)."""
    from shape_toolkit.data.synthetic import cached_pose_sequence

    seq = cached_pose_sequence(p.meta["sequence"])
    ids = np.asarray(o["ids"])
    true_part = seq.labels[seq.material[0]]
    per = []
    for t in range(1, seq.n_frames):
        gone = seq.welded[t] if seq.welded else np.zeros(0, dtype=np.int64)
        ok = (ids[:, t] >= 0) & ~np.isin(seq.material[0], gone)
        if ok.any():
            per.append(float(np.mean(seq.labels[seq.material[t][ids[ok, t]]] != true_part[ok])))
    return {"wrong_part": float(np.mean(per)) if per else None}


class SequenceTask(TaskAdapter):
    """Trajectory drift on generated pose sequences (thesis 7.5.3; ``sequence`` datasets): each
    method, a matching pipeline, maps frame t -> t+1 and the maps are chained
    (``results.trajectories.chain_maps``, what ``shape-toolkit track`` does; option ``mode =
    "chain"``), or maps frame 0 -> t directly (``"direct"``: no accumulation, but larger
    deformations). Pairs run one after the other, each with a fresh pipeline and one BLAS thread (as
    ``shape-toolkit track`` runs them); the row's time is the whole sequence's. Output: the
    trajectories ``ids`` ``(n_0, T)``; metrics ``drift`` and ``wrong_part``."""

    name = "sequence"
    families = ()
    option_defaults = {"mode": "chain", "sample": 500, "radius": 0.05}
    default_metrics = ("drift", "wrong_part")
    metrics = {"drift": (_m_drift, ()), "wrong_part": (_m_wrong_part, ())}
    uses_spectra = False

    def check_options(self, options):
        o = super().check_options(options)
        if o["mode"] not in SEQUENCE_MODES:
            raise ParameterError(f"mode must be one of {', '.join(map(repr, SEQUENCE_MODES))}, got {o['mode']!r}")
        check_positive_ints(o, ("sample",), optional=True)
        r = o["radius"]
        if isinstance(r, bool) or not isinstance(r, (int, float)) or not 0 < r < 1:
            raise ParameterError(f"radius must be in (0, 1) (units of sqrt(area)), got {r!r}")
        return o

    def run(self, method, prepared, spectra, options, random_state, detector=None, detector_spectra=None):
        from shape_toolkit.data.synthetic import cached_pose_sequence
        from shape_toolkit.pipeline import run_pair_timed
        from shape_toolkit.results.trajectories import Trajectories, chain_maps

        if "sequence" not in prepared.meta:
            raise ParameterError(f"item {prepared.name!r} is not a pose sequence (dataset kind \"sequence\")")
        seq = cached_pose_sequence(prepared.meta["sequence"])
        T = seq.n_frames
        sizes = [f.n_vertices for f in seq.frames]
        pairs = [(t, t + 1) for t in range(T - 1)] if options["mode"] == "chain" else [(0, t) for t in range(1, T)]
        spec = method.to_dict()
        res = [run_pair_timed(spec, seq.frames[i], seq.frames[j]) for i, j in pairs]  # as `shape-toolkit track`
        maps = [c for c, _ in res]
        if options["mode"] == "chain":
            ids = chain_maps(maps, n_vertices=sizes).ids
        else:
            direct = np.empty((sizes[0], T), dtype=np.int64)
            direct[:, 0] = np.arange(sizes[0])
            for t, m in enumerate(maps, start=1):
                direct[:, t] = m.target_of
            ids = Trajectories(direct, tuple(sizes)).ids  # validates
        return {"ids": ids, "pair_cpu": np.array([t["cpu"] for _, t in res]),
                "pair_wall": np.array([t["wall"] for _, t in res])}


# -- geodesics -------------------------------------------------------------------------------
class GeodesicMethod:
    """A ``geodesics`` task's method: one of :data:`~shape_toolkit.features.geodesics.GEODESIC_METHODS`."""

    def __init__(self, name: str):
        self.name = name

    def distances(self, shape: Shape, sources: np.ndarray) -> np.ndarray:
        """Distances ``(len(sources), n)`` from each source vertex, mesh length units (nothing cached)."""
        from shape_toolkit.features.geodesics import geodesic_distances

        return geodesic_distances(shape, sources, method=self.name, cache=False)


def _m_relative_error(p, o, opt):
    from shape_toolkit.features.geodesics import geodesic_distances

    rows = np.asarray(o["reference_rows"])
    ids = np.asarray(o["sources"])[: len(rows)]
    # the reference rows are cached in the worker (content hash, method, source): every method compares to one copy
    if p.clean_target is None:
        ref = geodesic_distances(p.target, ids, method=opt["reference"])
    else:  # on the clean shape, read at each point's vertex there (score_on = "clean")
        vmap = np.asarray(p.vertex_map, dtype=np.int64)
        ref = geodesic_distances(p.clean_target, vmap[ids], method=opt["reference"])[:, vmap]
    far = np.isfinite(ref) & (ref > 0.01 * np.max(ref[np.isfinite(ref)], initial=0.0))
    # a vertex the reference reaches and the method does not (inf, NaN) is counted apart, never averaged in
    reached = far & np.isfinite(rows)
    out = {"unreached_fraction": float(1.0 - reached.sum() / far.sum()) if far.any() else None}
    if not reached.any():
        return {"mean_relative_error": None, "max_relative_error": None, **out}
    rel = np.abs(rows[reached] - ref[reached]) / ref[reached]
    return {"mean_relative_error": float(rel.mean()), "max_relative_error": float(rel.max()), **out}


def _m_sources(p, o, opt):
    return {"n_sources": int(len(o["sources"]))}


class GeodesicsTask(TaskAdapter):
    """Geodesic distances on single shapes (the compared methods: ``method = "exact" | "fmm" | "heat" |
    "dijkstra"``, :func:`~shape_toolkit.features.geodesics.geodesic_distances`): each row computes the
    distances from ``sources`` vertex ids evenly spaced from 0 to ``n - 1`` (the row's time is theirs; divide by
    ``n_sources`` for a source's). Metric ``relative_error``: against the ``reference`` method (default
    ``exact``, libigl's exact polyhedral geodesics) on the first ``reference_sources`` sources, the mean and the
    largest ``|d - d_ref| / d_ref`` over the vertices farther than 1 % of the largest reference distance, and the
    ``unreached_fraction`` of those the method leaves at infinity (the reference is computed in the metric,
    outside the row's time, once per worker and shape); ``sources``:
    ``n_sources``. Output: the source ids and the first ``reference_sources`` distance rows."""

    name = "geodesics"
    families = ()
    option_defaults = {"sources": 20, "reference": "exact", "reference_sources": 2}
    default_metrics = ("relative_error", "sources")
    metrics = {"relative_error": (_m_relative_error, ()), "sources": (_m_sources, ())}
    uses_spectra = False
    #: ``score_on = "clean"``: the reference on the uncorrupted shape, read at each point's vertex there (a point
    #: cloud's distances against its mesh's)
    protocol_options = ("score_on",)

    def check_options(self, options):
        rest, proto = self._pop_protocol(options)
        o = {**super().check_options(rest), **proto}
        check_positive_ints(o, ("sources", "reference_sources"))
        if o["reference_sources"] > o["sources"]:
            raise ParameterError(f"reference_sources ({o['reference_sources']}) must be at most sources "
                                 f"({o['sources']})")
        check_geodesic_methods(o, ("reference",))
        return o

    def run(self, method, prepared, spectra, options, random_state, detector=None, detector_spectra=None):
        shape = prepared.target
        ids = evenly_spaced_vertices(shape.n_vertices, options["sources"])
        D = method.distances(shape, ids)
        # every row of the (sources, n) matrix is not kept: at 10^5 vertices it would fill the run folder
        return {"sources": ids, "reference_rows": D[: options["reference_sources"]]}


#: task name -> adapter
TASKS: dict[str, TaskAdapter] = {
    t.name: t
    for t in (SpectrumTask(), KeypointsTask(), DescriptorsTask(), SegmentationTask(), MatchingTask(), SequenceTask(),
              GeodesicsTask())
}
