"""Benchmark configuration: read a TOML file, validate everything before any work starts.

Layout (every key is checked; an error names the key, e.g. ``tasks[0].methods[1].params.k``)::

    [run]
    name = "my-run"            # optional
    random_state = 0           # seeds corruptions and every plugin with a random_state
    split = { by = "category", half = "report" }   # optional: run one half of a tuning/reporting split

Split (``[run] split``): per dataset, the items' groups (``by = "category"``: a PSB mesh's category,
a TOSCA pair's animal, a FAUST pair's subject, :func:`shape_toolkit.data.datasets.item_group`) are
ordered by the SHA-1 of ``salt + group``; the first ``floor(tune_fraction * groups)`` form the
*tune* half, the others the *report* half, and the run keeps the items of ``half`` only (a pair
whose shapes fall in both halves is in neither). A group is never split. An unknown key, a dataset
without groups or a half left empty is refused before any work, naming the key.

    [[datasets]]
    name = "psb"               # unique
    kind = "psb"               # tosca | psb | folder | synthetic | sequence
    path = "psb"               # absolute, or relative to $TOOLKIT_DATA (else to the config's folder)
    limit = 4                  # optional: first N items
    items = ["cat0-cat1"]      # optional: these items only, in this order (before limit); a pair is
                               # "SOURCE-TARGET" (synthetic: any "poseI-poseJ", e.g. "pose0-pose2")
    params = {}                # kind-specific (synthetic: n_poses, subdivisions, max_angle; sequence:
                               # seeds, frames, subdivisions, remesh, merge_frames, max_angle, permute)

    [[corruptions]]
    name = "noise"
    kind = "gaussian-noise"    # see shape_toolkit.data.corruptions.CORRUPTIONS
    params = { strength = [0.1, 0.3] }   # lists are grids (a literal list: wrap it, [[1, 2]])
    seed = 0                   # optional: every item's copy drawn with this random_state (default: a
                               # seed per item, hashed from run.random_state, dataset, item and name)

    [[corruptions]]            # corruptions in sequence: glue, then colour noise on the glued shape
    name = "glued-noisy"       # optional, default the kinds joined by "+" ("glue+color-noise")
    steps = [{ kind = "glue", params = { strength = 6 } },
             { kind = "color-noise", params = { strength = [0.05, 0.1] } }]

    [[tasks]]
    task = "segmentation"      # the task kind: spectrum | keypoints | descriptors | segmentation | matching | sequence
                               # | geodesics
    name = "seg"               # optional task name, default = the task kind
    datasets = ["psb"]         # default: every dataset
    corruptions = ["none", "noise"]      # default: ["none"]
    metrics = ["rand_index"]   # default: the task's default metrics
    options = {}               # task options (shape_toolkit.bench.tasks); every task: repeats, blas_threads
    published = ["table-5.1"]  # optional: the thesis's printed numbers shown beside the measured rows
                               # (shape_toolkit.bench.published; never measured, never best)
    [[tasks.methods]]
    plugin = "spectral-clustering"
    preset = "..."             # optional
    label = "..."              # optional display name
    params = { n_segments = [4, 6] }

Size: the rows a config plans (items x corruption settings x method settings, per task) are
counted from the grid sizes before anything is expanded; with ``max_rows`` (the CLI's
``--max-rows``, default :data:`MAX_ROWS`) a config planning more is refused naming the count.

Composed corruptions (``steps``, instead of ``kind`` and ``params``): each step is applied to the
previous one's result, with its own random state drawn from the item's corruption seed
(:func:`shape_toolkit.data.corruptions.step_seeds`), and the vertex maps are composed, so
``score_on = "clean"`` scores on the clean shape exactly. Every step's grid is an axis of the
entry's grid; a row's corruption reads ``glued-noisy[glue:6+color-noise:0.1]`` (every step's kind
and strength; without a ``name``, ``glue:6+color-noise:0.1``), its ``corruption_kind``
``glue+color-noise`` and its ``strength`` that of the swept step (else of the last one).

A matching method may instead be ``pipeline = "zoomout"`` (a preset, TOML file or inline table of
:mod:`shape_toolkit.pipeline`), ``peer = "pyfm"`` (a peer's published pipeline,
:mod:`shape_toolkit.bench.peers`) or ``peer = "maps"`` with ``path = "maps/BCICP"`` (published maps
``A_B.map`` in that folder of a pair dataset, uncorrupted only), each with an optional ``label``.

Geodesics: the ``geodesics`` task takes ``method = "heat"`` methods (``exact``, ``fmm``, ``heat``,
``dijkstra``: :func:`shape_toolkit.features.geodesics.geodesic_distances`) on single-shape datasets;
each row computes the distances from ``sources`` evenly spaced vertices, and its error is taken against
the ``reference`` method on the first ``reference_sources`` of them (``GeodesicsTask``).

Sequences (thesis 7.5.3): the ``sequence`` task takes ``pipeline = ...`` methods on ``sequence``
datasets (generated pose sequences, one item per seed); it matches frame t -> t+1 and chains the
maps (option ``mode = "chain"``) or matches frame 0 -> t (``"direct"``), and reports the drift per
frame (:mod:`shape_toolkit.bench.tasks`, ``SequenceTask``). Merged frames are a dataset parameter
(``merge_frames``); corruptions other than ``none`` are refused.

Spectra: methods receive the spectra they declare (``spectrum_spec()`` of a plugin and of its
keypoint detector, ``spectrum_specs()`` of a pipeline), so a ``spectrum`` table belongs to the
``spectrum`` task only, where the spectrum is the subject (``{ k = 40, laplacian = ..., use_mass
= ..., params = {...} }``; the weighting is each method's plugin). Elsewhere it is an error.
In Python, :class:`TaskSpec` has ``task_kind`` (the ``task`` key) and ``task_name`` (``name``);
:class:`MethodSpec` has ``plugin`` (registry name) and ``method_label`` (``label``).
"""

from __future__ import annotations

import inspect
import itertools
import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from shape_toolkit.core.cleanup import MAX_REMESH_VERTICES
from shape_toolkit.data.generate import MAX_SUBDIVISIONS
from shape_toolkit.data.synthetic import MAX_FRAMES, MAX_POSE_ANGLE, MAX_POSES, MAX_SEQUENCE_ANGLE
from shape_toolkit.errors import ParameterError, ToolkitError
from shape_toolkit.validation import finite_number, shown_value

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = [
    "ConfigError",
    "DatasetSpec",
    "CorruptionSpec",
    "MethodSpec",
    "TaskSpec",
    "BenchConfig",
    "load_config",
    "parse_config",
    "expand_grid",
    "resolve_data_path",
    "grid_size",
    "MAX_ROWS",
    "split_items",
    "split_line",
]

#: the rows ``bench run`` plans at most unless ``--max-rows`` raises it
MAX_ROWS = 1000


class ConfigError(ParameterError):
    """A benchmark config is invalid; ``key`` names the offending entry."""

    def __init__(self, key: str, problem: str):
        self.key = key
        self.problem = problem
        super().__init__(f"config key {key}: {problem}")


@dataclass(frozen=True)
class DatasetSpec:
    """A dataset of the config: its item refs are listed at validation time."""

    name: str
    kind: str
    path: str | None
    limit: int | None
    params: dict[str, Any]
    refs: tuple = ()


@dataclass(frozen=True)
class CorruptionSpec:
    """One corruption instance (a grid point): name (unique per instance), kind and params; ``seed``
    the ``random_state`` of every item's copy when the config fixes it (None: a seed per item, hashed
    from ``run.random_state``, the dataset, the item and the corruption's name)."""

    name: str
    kind: str
    params: dict[str, Any]
    group: str = ""
    seed: int | None = None
    step_strength: float | None = None

    @property
    def strength(self) -> float | None:
        """The ``strength`` parameter (0 for no corruption), for plots; of a composed corruption
        (``params = {"steps": [...]}``) ``step_strength``: the strength of its one step whose strength
        the config sweeps, else of its last step that has one."""
        if self.kind == "none":
            return 0.0
        if "steps" in self.params:
            return self.step_strength
        s = self.params.get("strength")
        return float(s) if isinstance(s, (int, float)) else None


NO_CORRUPTION = CorruptionSpec("none", "none", {}, "none")


@dataclass(frozen=True)
class MethodSpec:
    """One method instance (a grid point): plugin name, family, preset, params, display label
    (``method_label``); ``spectrum`` overrides the task's spectrum (spectrum task only)."""

    plugin: str
    family: str
    preset: str | None
    params: dict[str, Any]
    method_label: str
    spectrum: dict[str, Any] | None = None
    keypoints: dict[str, Any] | None = None
    solver: str | None = None  # a spectrum task's eigensolver peer (``peer = "scipy-eigsh"``); None: the toolkit's


@dataclass(frozen=True)
class TaskSpec:
    """A task of the config with its expanded methods and corruption instances: ``task_kind`` is
    the adapter (the config's ``task`` key), ``task_name`` the config's ``name``; ``spectrum`` is
    the subject of a ``spectrum`` task and None for every other kind."""

    task_name: str
    task_kind: str
    datasets: tuple[str, ...]
    corruptions: tuple[CorruptionSpec, ...]
    methods: tuple[MethodSpec, ...]
    spectrum: dict[str, Any] | None
    metrics: tuple[str, ...]
    options: dict[str, Any]


@dataclass(frozen=True)
class BenchConfig:
    """A validated benchmark configuration; ``planned_rows`` is the number of rows it plans (with
    the ``limit`` given to :func:`parse_config`), counted before expanding anything."""

    name: str
    random_state: int
    datasets: dict[str, DatasetSpec]
    tasks: tuple[TaskSpec, ...]
    source: str = ""
    raw: dict[str, Any] = field(default_factory=dict)
    planned_rows: int = 0
    split: dict[str, Any] | None = None


_NOT_A_SUBJECT = (
    "a spectrum table is allowed for the spectrum task only: {kind} methods receive the spectra "
    "they declare (spectrum_spec() of a plugin, spectrum_specs() of a pipeline); remove this table "
    "and choose the method's parameters or preset instead"
)
_SPECTRUM_KEYS = {"weighting", "k", "laplacian", "params", "use_mass", "connectivity", "n_neighbors"}
DEFAULT_SPECTRUM = {"weighting": "cotangent", "k": 30, "laplacian": "combinatorial"}


def _check_keys(d: Any, allowed: set[str], where: str, required: tuple[str, ...] = ()) -> dict:
    if not isinstance(d, dict):
        raise ConfigError(where, f"must be a table, got {type(d).__name__}")
    for k in d:
        if k not in allowed:
            raise ConfigError(
                f"{where}.{k}" if where else k, f"unknown key; allowed: {', '.join(sorted(allowed))}"
            )
    for k in required:
        if k not in d:
            raise ConfigError(f"{where}.{k}" if where else k, "is required")
    return d


def expand_grid(params: dict[str, Any]) -> list[dict[str, Any]]:
    """All combinations of a parameter grid: list values are axes (``[[a, b]]`` is the literal
    list ``[a, b]``), scalars are fixed; the order is deterministic (keys sorted)."""
    keys = sorted(params)
    axes = []
    for k in keys:
        v = params[k]
        if isinstance(v, list):
            axes.append(v if v else [v])
        else:
            axes.append([v])
    return [dict(zip(keys, combo)) for combo in itertools.product(*axes)]


def grid_size(params: dict[str, Any]) -> int:
    """The number of combinations :func:`expand_grid` would make, without making them."""
    return math.prod(len(v) if isinstance(v, list) and v else 1 for v in params.values())


def _axis(v: Any) -> list[Any]:
    """The values a grid parameter takes (``[[a, b]]`` is the one value ``[a, b]``)."""
    return v if isinstance(v, list) and v else [v]


def _str(v: Any, where: str) -> str:
    """``v`` when it is a non-empty string, else a :class:`ConfigError` naming ``where``."""
    if not isinstance(v, str) or not v:
        raise ConfigError(where, f"must be a non-empty string, got {v!r}")
    return v


def _names(v: Any, where: str, what: str) -> list[str]:
    """A non-empty list of strings (dataset, corruption or metric names)."""
    if not isinstance(v, list) or not v:
        raise ConfigError(where, f"must be a non-empty list of {what}")
    return [_str(x, f"{where}[{j}]") for j, x in enumerate(v)]


def _check_kinds(params: dict[str, Any], func: Any, where: str, grid: bool = True) -> None:
    """Each value (with ``grid``, each grid value of a list) of a parameter whose default is a
    number must be a number, of one whose default is a boolean a boolean: ``n_segments = "x"`` is
    refused here, naming the key, instead of failing every row at run time."""
    try:
        sig = inspect.signature(func)
    except (TypeError, ValueError):  # pragma: no cover - builtins
        return
    for k, v in params.items():
        par = sig.parameters.get(k)
        if par is None:
            continue
        d, ann = par.default, str(par.annotation)
        if any(w in ann for w in ("str", "Any", "dict", "list", "Sequence", "tuple")):
            continue  # the parameter takes other kinds too
        for x in _axis(v) if grid else [v]:
            if isinstance(d, bool) and not isinstance(x, bool):
                raise ConfigError(f"{where}.{k}", f"expects true or false, got {x!r}")
            if isinstance(d, (int, float)) and not isinstance(d, bool) and (
                isinstance(x, bool) or not isinstance(x, (int, float)) or (math.isfinite(d) and not finite_number(x))
            ):
                raise ConfigError(f"{where}.{k}", f"expects a finite number (default {d!r}), got {shown_value(x)}")


def resolve_data_path(path: str, base: Path | None = None) -> Path:
    """An absolute path as is; a relative one under ``$TOOLKIT_DATA`` when set, else under
    ``base`` (the config file's folder)."""
    p = Path(os.path.expanduser(path))
    if p.is_absolute():
        return p
    env = os.environ.get("TOOLKIT_DATA")
    if env:
        return Path(env) / p
    return (base or Path.cwd()) / p


def _int(v: Any, where: str, lo: int = 0) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < lo:
        raise ConfigError(where, f"must be an integer >= {lo}, got {v!r}")
    return v


def _validate_spectrum(spec: Any, where: str) -> dict[str, Any]:
    from shape_toolkit.api.registry import get_registry
    from shape_toolkit.core.spectrum import LAPLACIANS

    d = dict(DEFAULT_SPECTRUM)
    d.update(_check_keys(spec or {}, _SPECTRUM_KEYS, where))
    try:
        cls = get_registry().get("weightings", d["weighting"])
    except ToolkitError as exc:
        raise ConfigError(f"{where}.weighting", str(exc)) from None
    _int(d["k"], f"{where}.k", 2)
    if d["laplacian"] not in LAPLACIANS:
        raise ConfigError(f"{where}.laplacian", f"must be one of {', '.join(LAPLACIANS)}")
    prm = d.get("params", {}) or {}
    if not isinstance(prm, dict):
        raise ConfigError(f"{where}.params", "must be a table")
    names = set(cls._param_names()) if hasattr(cls, "_param_names") else set(prm)
    for k in prm:
        if k not in names:
            raise ConfigError(f"{where}.params.{k}", f"weighting {d['weighting']!r} has no such parameter")
    return d


def _family_for(task: str, plugin: str, where: str) -> str:
    from shape_toolkit.api.registry import get_registry
    from shape_toolkit.bench.tasks import TASKS

    reg = get_registry()
    fams = TASKS[task].families
    for fam in fams:
        if reg.has(fam, plugin):
            return fam
    avail = sorted({n for f in fams for n in reg.names(f)})
    raise ConfigError(
        f"{where}.plugin",
        f"unknown {'/'.join(fams)} plugin {plugin!r}; available: {', '.join(avail) or 'none'}",
    )


def _check_plugin_names(family: str, plugin: str, preset: Any, params: dict, where: str) -> type:
    """The plugin class, its preset and parameter names checked, and each parameter value's kind
    (:func:`_check_kinds`, every grid value): cheap checks made before any grid is expanded."""
    from shape_toolkit.api.registry import get_registry

    reg = get_registry()
    cls = reg.get(family, plugin)
    if preset is not None and (not isinstance(preset, str) or preset not in (getattr(cls, "presets", {}) or {})):
        raise ConfigError(
            f"{where}.preset",
            f"{family} plugin {plugin!r} has no preset {preset!r}; presets: "
            f"{', '.join(sorted(getattr(cls, 'presets', {}) or {})) or 'none'}",
        )
    if hasattr(cls, "_param_names"):
        valid = set(cls._param_names())
        for k in params:
            if k not in valid:
                raise ConfigError(
                    f"{where}.params.{k}",
                    f"{family} plugin {plugin!r} has no parameter {k!r}; valid: {', '.join(sorted(valid))}",
                )
    _check_kinds(params, cls.__init__, f"{where}.params")
    return cls


def _param_key(params: dict, value: Any, message: str, where: str) -> str:
    """The key of ``params`` a problem is about: the one holding ``value``, or named first in
    ``message``; else the table."""
    for k, v in params.items():
        if value is not None and v is value:
            return f"{where}.params.{k}"
    for k in sorted(params, key=len, reverse=True):
        if message.startswith(k) or f" {k} " in f" {message} " or f"{k!r}" in message:
            return f"{where}.params.{k}"
    return f"{where}.params"


def _check_declared(obj: Any, params: dict, where: str) -> None:
    """The spectra a created plugin declares are computable: ``spectrum_specs()`` runs (it reads
    the parameters) and names a registered weighting with known parameters and a known Laplacian.
    A bad nested value (``weighting = { a = 1 }``) is refused here, naming the key, instead of
    failing every row at run time."""
    from shape_toolkit.api.registry import get_registry
    from shape_toolkit.core.spectrum import LAPLACIANS

    if not hasattr(obj, "spectrum_specs"):
        return
    try:
        specs = list(obj.spectrum_specs())
    except Exception as exc:  # noqa: BLE001 - a plugin reading a bad parameter: any error
        msg = str(exc) or type(exc).__name__
        raise ConfigError(_param_key(params, None, msg, where), msg) from None
    reg = get_registry()
    for spec in specs:
        weighting = getattr(spec, "weighting", None)
        if not isinstance(weighting, str) or not reg.has("weightings", weighting):
            raise ConfigError(
                _param_key(params, weighting, "", where),
                f"declares a spectrum of weighting {weighting!r}, which is not a weighting plugin; "
                f"available: {', '.join(reg.names('weightings'))}",
            )
        if getattr(spec, "laplacian", None) not in LAPLACIANS:
            raise ConfigError(_param_key(params, spec.laplacian, "", where),
                              f"unknown Laplacian {spec.laplacian!r}; choose one of {', '.join(LAPLACIANS)}")
        cls = reg.get("weightings", weighting)
        names = set(cls._param_names()) if hasattr(cls, "_param_names") else None
        for k, _v in getattr(spec, "weighting_params", ()) or ():
            if names is not None and k not in names:
                raise ConfigError(_param_key(params, None, repr(k), where),
                                  f"weighting {weighting!r} has no parameter {k!r}; valid: {', '.join(sorted(names))}")


def _validate_plugin_params(family: str, plugin: str, preset: str | None, params: dict, where: str) -> None:
    from shape_toolkit.api.registry import get_registry

    _check_plugin_names(family, plugin, preset, params, where)
    try:  # constructing checks types where plugins validate in __init__ (cheap by contract)
        obj = get_registry().create(family, plugin, preset, **params)
    except ToolkitError as exc:
        raise ConfigError(_param_key(params, None, str(exc), where), str(exc)) from None
    _check_declared(obj, params, where)


@dataclass(frozen=True)
class _Corruption:
    """A validated, not yet expanded ``[[corruptions]]`` entry (``size`` grid points); ``steps`` the
    ``(kind, params)`` of each step of a composed one (``kind`` is then their kinds joined by ``+``,
    ``params`` empty) and ``named`` whether the config gave its name."""

    name: str
    kind: str
    params: dict[str, Any]
    size: int
    seed: int | None = None
    steps: tuple[tuple[str, dict[str, Any]], ...] = ()
    named: bool = True

    def expand(self) -> list[CorruptionSpec]:
        """Its grid points, named ``NAME[key=value,...]`` by the parameters that vary; a composed
        one's ``NAME[glue:6+color-noise:0.1]`` by every step's kind and strength (and ``(key=value)``
        of its other parameters that vary), or without a configured name just ``glue:6+color-noise:0.1``."""
        if self.steps:
            return self._expand_steps()
        insts = []
        for g in expand_grid(self.params):
            suffix = ",".join(f"{k}={g[k]}" for k in sorted(g) if isinstance(self.params[k], list))
            insts.append(CorruptionSpec(f"{self.name}[{suffix}]" if suffix else self.name, self.kind, g, self.name,
                                        self.seed))
        return insts

    def _expand_steps(self) -> list[CorruptionSpec]:
        from shape_toolkit.data.corruptions import CORRUPTIONS

        flat = {f"{j}.{k}": v for j, (_, prm) in enumerate(self.steps) for k, v in prm.items()}
        swept = [j for j, (_, prm) in enumerate(self.steps) if isinstance(prm.get("strength"), list)]
        defaults = [inspect.signature(CORRUPTIONS[kind]).parameters.get("strength") for kind, _ in self.steps]
        with_strength = [j for j, d in enumerate(defaults) if d is not None]
        # the step whose strength the rows plot: the one swept, else the last step that has a strength
        plotted = swept[0] if len(swept) == 1 else (with_strength[-1] if with_strength else None)
        insts = []
        for g in expand_grid(flat):
            steps = [{k: g[f"{j}.{k}"] for k in prm} for j, (_, prm) in enumerate(self.steps)]
            strengths = [st.get("strength", d.default if d is not None else None) for st, d in zip(steps, defaults)]
            labels = []
            for j, ((kind, prm), st) in enumerate(zip(self.steps, steps)):
                other = ",".join(f"{k}={st[k]}" for k in sorted(st) if k != "strength" and isinstance(prm[k], list))
                labels.append(kind + (f":{strengths[j]}" if strengths[j] is not None else "")
                              + (f"({other})" if other else ""))
            label = "+".join(labels)
            s = strengths[plotted] if plotted is not None else None
            insts.append(CorruptionSpec(f"{self.name}[{label}]" if self.named else label, self.kind, {"steps": steps},
                                        self.name, self.seed, float(s) if isinstance(s, (int, float)) else None))
        return insts


def _check_corruption_params(kind: Any, prm: Any, w: str) -> tuple[str, dict[str, Any]]:
    """One corruption's ``kind`` (at ``w.kind``) and ``params`` (at ``w.params``) checked: a known
    kind, parameters it has, each (grid) value of the right kind and within the corruption's own declared bounds
    (:func:`~shape_toolkit.data.corruptions.check_corruption_params`), so a bad value is refused here, not by every
    row at run time."""
    from shape_toolkit.data.corruptions import CORRUPTIONS, check_corruption_params

    kind = _str(kind, f"{w}.kind")
    if kind not in CORRUPTIONS:
        raise ConfigError(f"{w}.kind", f"unknown corruption {kind!r}; known: {', '.join(CORRUPTIONS)}")
    prm = prm or {}
    if not isinstance(prm, dict):
        raise ConfigError(f"{w}.params", "must be a table")
    valid = [p for p in inspect.signature(CORRUPTIONS[kind]).parameters if p not in ("shape", "random_state")]
    for k in prm:
        if k not in valid:
            raise ConfigError(
                f"{w}.params.{k}", f"corruption {kind!r} has no such parameter; valid: {', '.join(valid)}"
            )
    _check_kinds(prm, CORRUPTIONS[kind], f"{w}.params")
    for k, v in prm.items():
        for x in _axis(v):
            try:
                check_corruption_params(kind, {k: x})
            except ParameterError as exc:
                raise ConfigError(f"{w}.params.{k}", str(exc)) from None
    return kind, dict(prm)


def _validate_corruptions(raw: Any) -> dict[str, _Corruption]:
    """Every corruption checked (kind, parameter names, the kind of each value; each step of a
    composed one, ``steps = [{ kind = ..., params = ... }, ...]``), none expanded."""
    from shape_toolkit.data.corruptions import CHAIN

    out: dict[str, _Corruption] = {"none": _Corruption("none", "none", {}, 1)}
    if raw is None:
        return out
    if not isinstance(raw, list):
        raise ConfigError("corruptions", "must be an array of tables ([[corruptions]])")
    for i, c in enumerate(raw):
        w = f"corruptions[{i}]"
        _check_keys(c, {"name", "kind", "params", "seed", "steps"}, w)
        steps: list[tuple[str, dict[str, Any]]] = []
        if "steps" in c:
            if "kind" in c or "params" in c:
                key = "kind" if "kind" in c else "params"
                raise ConfigError(f"{w}.{key}", "a composed corruption (steps = [...]) takes its kinds and "
                                  "parameters in its steps: steps = [{ kind = ..., params = {...} }, ...]")
            if not isinstance(c["steps"], list) or not c["steps"]:
                raise ConfigError(f"{w}.steps", "must be a non-empty array of tables "
                                  "[{ kind = ..., params = {...} }, ...], applied in order")
            for j, st in enumerate(c["steps"]):
                _check_keys(st, {"kind", "params"}, f"{w}.steps[{j}]", ("kind",))
                steps.append(_check_corruption_params(st["kind"], st.get("params"), f"{w}.steps[{j}]"))
        elif "kind" not in c:
            raise ConfigError(f"{w}.kind", "is required (or steps = [...] for corruptions applied in sequence)")
        else:
            steps.append(_check_corruption_params(c["kind"], c.get("params"), w))
        kind = CHAIN.join(k for k, _ in steps)
        name = _str(c.get("name", kind), f"{w}.name")
        if name in out:
            raise ConfigError(f"{w}.name", f"duplicate corruption name {name!r}")
        seed = _int(c["seed"], f"{w}.seed") if "seed" in c else None
        if seed is not None and seed > 2**31 - 2:  # the range of the per-item seeds
            raise ConfigError(f"{w}.seed", f"must be at most 2**31 - 2, got {seed}")
        if len(steps) == 1:  # one corruption (a single step is the same)
            prm = steps[0][1]
            out[name] = _Corruption(name, kind, prm, grid_size(prm), seed)
        else:
            size = math.prod(grid_size(prm) for _, prm in steps)
            out[name] = _Corruption(name, kind, {}, size, seed, tuple(steps), "name" in c)
    return out


def _pipeline_method(task: str, m: dict, where: str) -> MethodSpec:
    """A matching method given as a pipeline (preset name, TOML path or inline table) of
    :mod:`shape_toolkit.pipeline`; its spec becomes the method's ``pipeline`` parameter."""
    from shape_toolkit.pipeline import load_pipeline

    if task not in ("matching", "sequence"):
        raise ConfigError(f"{where}.pipeline", 'pipelines are matching methods (task = "matching" or "sequence")')
    extra = sorted(set(m) - {"pipeline", "label"})
    if extra:
        raise ConfigError(f"{where}.{extra[0]}", "not allowed with pipeline (put it in the pipeline spec)")
    try:
        pipe = load_pipeline(m["pipeline"])
    except ToolkitError as exc:
        raise ConfigError(f"{where}.pipeline", str(exc)) from None
    spec = {"name": pipe.name, **pipe.stages}
    label = _str(m["label"], f"{where}.label") if "label" in m else f"pipeline:{pipe.name}"
    return MethodSpec(pipe.name, "pipelines", None, {"pipeline": spec}, label)


def _spectrum_peer_method(m: dict, where: str, spectrum: dict) -> MethodSpec:
    """A spectrum task's method computed by an eigensolver peer (``peer = "scipy-eigsh"``,
    :data:`shape_toolkit.bench.peers.SPECTRUM_PEERS`): the same Laplacian and mass as the toolkit's row
    of that weighting (``plugin``, default cotangent), solved by the peer instead of the toolkit."""
    from shape_toolkit.bench.peers import create_spectrum_peer

    extra = sorted(set(m) - {"peer", "label", "plugin", "spectrum"})
    if extra:
        raise ConfigError(f"{where}.{extra[0]}", "not allowed with an eigensolver peer (keys: peer, label, plugin, "
                                                 "spectrum)")  # fmt: skip
    name = _peer_name(m, where, create_spectrum_peer)
    plugin = _str(m.get("plugin", "cotangent"), f"{where}.plugin")
    fam = _family_for("spectrum", plugin, where)
    if "spectrum" in m and not isinstance(m["spectrum"], dict):
        raise ConfigError(f"{where}.spectrum", "must be a table")
    if isinstance(m.get("spectrum"), dict) and "weighting" in m["spectrum"]:
        raise ConfigError(f"{where}.spectrum.weighting", "the weighting of a spectrum task's method is its plugin")
    mspec = _validate_spectrum({**spectrum, **m["spectrum"]}, f"{where}.spectrum") if "spectrum" in m else None
    label = _str(m["label"], f"{where}.label") if "label" in m else f"peer:{name}"
    return MethodSpec(plugin, fam, None, {}, label, mspec, None, name)


def _peer_method(task: str, m: dict, where: str) -> MethodSpec:
    """A matching method run by a peer implementation (:mod:`shape_toolkit.bench.peers`, e.g.
    ``peer = "pyfm"``, or published maps read from files, ``peer = "maps"``), side by side with the
    toolkit's methods."""
    from shape_toolkit.bench.peers import create_peer

    if task != "matching":
        raise ConfigError(f"{where}.peer", 'peers are matching methods (task = "matching") or eigensolvers '
                                           '(task = "spectrum")')  # fmt: skip
    name = m["peer"]
    if not isinstance(name, str):
        raise ConfigError(f"{where}.peer", f"must be a peer name, got {name!r}")
    extra = sorted(set(m) - {"peer", "label", *(("path",) if name == "maps" else ())})
    if extra:
        raise ConfigError(f"{where}.{extra[0]}", "not allowed with peer (a peer runs its own published pipeline)")
    if name == "maps" and "path" not in m:
        raise ConfigError(f"{where}.path", 'peer "maps" needs path = "FOLDER" (its A_B.map files, relative to the '
                          "dataset's folder)")
    params = {"path": m["path"]} if name == "maps" else {}
    try:
        create_peer(name, **params)
    except ToolkitError as exc:
        raise ConfigError(f"{where}.path" if params else f"{where}.peer", str(exc)) from None
    default = f"maps:{Path(params['path']).name}" if params else f"peer:{name}"
    label = _str(m["label"], f"{where}.label") if "label" in m else default
    return MethodSpec(name, "peers", None, params, label)


def _geodesic_method(task: str, m: dict, where: str) -> MethodSpec:
    """A ``geodesics`` task's method: ``method = "heat"`` (one of
    :data:`~shape_toolkit.features.geodesics.GEODESIC_METHODS`), with an optional ``label``."""
    from shape_toolkit.features.geodesics import GEODESIC_METHODS

    if task != "geodesics":
        raise ConfigError(f"{where}.method", 'a geodesic method belongs to a geodesics task (task = "geodesics")')
    if "method" not in m:
        raise ConfigError(f"{where}.method", f"a geodesics task's methods are method = one of "
                          f"{', '.join(map(repr, GEODESIC_METHODS))}")
    extra = sorted(set(m) - {"method", "label"})
    if extra:
        raise ConfigError(f"{where}.{extra[0]}", "not allowed with a geodesic method (keys: method, label)")
    name = m["method"]
    if name not in GEODESIC_METHODS:
        raise ConfigError(f"{where}.method", f"must be one of {', '.join(map(repr, GEODESIC_METHODS))}, got {name!r}")
    label = _str(m["label"], f"{where}.label") if "label" in m else name
    return MethodSpec(name, "geodesics", None, {}, label)


def _peer_name(m: dict, where: str, create: Any) -> str:
    """The ``peer`` name of a method entry, checked by making the peer (``create(name)``)."""
    name = m["peer"]
    if not isinstance(name, str):
        raise ConfigError(f"{where}.peer", f"must be a peer name, got {name!r}")
    try:
        create(name)
    except ToolkitError as exc:
        raise ConfigError(f"{where}.peer", str(exc)) from None
    return name



def _check_map_files(m: dict, where: str, datasets: dict[str, DatasetSpec], dsel: list[str],
                     csel: list[str], limit: int | None) -> None:
    """A ``peer = "maps"`` method: on uncorrupted pair datasets only, and a map file for every item
    it will read (missing: the file is named; its contents are checked when the row reads it)."""
    from shape_toolkit.bench.peers import map_file

    if any(c != "none" for c in csel):
        raise ConfigError(f"{where}.peer", 'published maps are maps of the clean pairs: a task with peer = "maps" '
                          'takes corruptions = ["none"] only')
    for dn in dict.fromkeys(dsel):
        ds = datasets[dn]
        if ds.kind != "tosca":
            raise ConfigError(f"{where}.peer", f'published maps need a pair dataset (kind = "tosca"); dataset {dn!r} '
                              f"is {ds.kind!r}")
        for ref in ds.refs[: _dataset_size(ds, limit)]:
            a, b = (Path(ref.paths[k]).stem for k in ("source", "target"))
            f = map_file(ds.path, m["path"], a, b)
            if not f.is_file():
                raise ConfigError(f"{where}.path", f"published map file not found: {f} (for the pair {a}, {b})")


def method_id(row: dict) -> str:
    """Display name of a row's method: its ``method_label`` plus its (short) parameters."""
    p = row.get("params") if isinstance(row.get("params"), dict) else {}
    label = str(row.get("method_label"))
    shown = {k: v for k, v in sorted(p.items()) if not isinstance(v, dict) and len(repr(v)) <= 24}
    if row.get("family") in ("pipelines", "peers") or not shown:
        return label
    return f"{label}({', '.join(f'{k}={v}' for k, v in shown.items())})"


def _distinct_methods(w: str, entries: list[list[MethodSpec]], n_listed: int) -> list[MethodSpec]:
    """The methods of task ``w`` (each entry's grid points; the entries past ``n_listed`` are the rows its options
    add: human, ground truth), refused when two entries are one method (plugin, preset, parameters, spectrum,
    keypoints, solver: a row's identity, so its rows would be computed once and shown under one label only) or
    when two methods would show under one name in the report and be pooled there (:func:`report.method_id`: the
    label and its short parameters)."""
    import json

    def where(j: int) -> str:
        return f"{w}.methods[{j}]" if j < n_listed else f"{w}.options"

    seen: dict[str, int] = {}
    shown: dict[str, tuple[int, str]] = {}
    out = []
    for j, specs in enumerate(entries):
        for ms in specs:
            ident = json.dumps([ms.plugin, ms.preset, ms.params, ms.spectrum, ms.keypoints, ms.solver],
                               sort_keys=True, default=repr)
            if ident in seen and seen[ident] != j:
                raise ConfigError(where(j), f"the same method as {where(seen[ident])} ({ms.plugin!r}, same preset and "
                                  "parameters): its rows would be computed once and shown under one label only; "
                                  "list it once")
            seen.setdefault(ident, j)
            name = method_id({"method_label": ms.method_label, "params": ms.params, "family": ms.family})
            if name in shown and shown[name][1] != ident:
                other = shown[name][0]
                raise ConfigError(f"{where(j)}.label" if j < n_listed else where(j),
                                  f"shows as {name!r} in the report, as {where(other)} does"
                                  + (" (a parameter that differs is not shown)" if other == j else "")
                                  + ": the report would pool the two methods' rows; give each a distinct label")
            shown.setdefault(name, (j, ident))
            out.append(ms)
    return out


def _dataset_size(spec: DatasetSpec, limit: int | None) -> int:
    return min(x for x in (spec.limit, limit, len(spec.refs)) if x is not None)


def parse_config(
    raw: dict[str, Any],
    *,
    base: Path | None = None,
    source: str = "",
    max_rows: int | None = None,
    limit: int | None = None,
) -> BenchConfig:
    """Validate a config dict (as read from TOML) and list the dataset items; raises
    :class:`ConfigError` naming the first bad key. With ``max_rows``, a config planning more rows
    (with ``limit`` items per dataset at most, as ``run_benchmark(limit=...)``) is refused before
    any grid is expanded."""
    from shape_toolkit.bench.tasks import TASKS

    if max_rows is not None and (isinstance(max_rows, bool) or not isinstance(max_rows, int) or max_rows < 1):
        raise ParameterError(f"max_rows must be a positive integer, got {max_rows!r}")
    _check_keys(raw, {"run", "datasets", "corruptions", "tasks"}, "", ("datasets", "tasks"))
    run = _check_keys(raw.get("run", {}), {"name", "random_state", "description", "split"}, "run")
    random_state = _int(run.get("random_state", 0), "run.random_state")
    if random_state > 2**32 - 1:  # every plugin's seed
        raise ConfigError("run.random_state", f"must be at most 2**32 - 1, got {random_state}")
    name = _str(run["name"], "run.name") if "name" in run else (Path(source).stem if source else "run")
    if "description" in run and not isinstance(run["description"], str):
        raise ConfigError("run.description", f"must be a string, got {run['description']!r}")

    datasets = _validate_datasets(raw["datasets"], base, max_rows)
    split = None
    if "split" in run:
        datasets, split = _apply_split(run["split"], datasets)
    corruptions = _validate_corruptions(raw.get("corruptions"))

    if not isinstance(raw["tasks"], list) or not raw["tasks"]:
        raise ConfigError("tasks", "must be a non-empty array of tables ([[tasks]])")
    pending = []  # (task fields, methods to expand) of each task, checked but not expanded
    names: set[str] = set()
    sizes: list[tuple[int, str, str]] = []  # (rows, key, how) per task
    for i, t in enumerate(raw["tasks"]):
        w = f"tasks[{i}]"
        _check_keys(
            t,
            {"task", "name", "datasets", "corruptions", "spectrum", "metrics", "methods", "options", "published"},
            w,
            ("task", "methods"),
        )
        kind = _str(t["task"], f"{w}.task")
        if kind not in TASKS:
            raise ConfigError(f"{w}.task", f"unknown task {kind!r}; known: {', '.join(TASKS)}")
        if "published" in t:  # the thesis's numbers shown beside the measured rows (bench.published)
            from shape_toolkit.bench.published import PublishedKeyError, check_published

            try:
                check_published(t["published"])
            except PublishedKeyError as exc:
                at = "" if exc.index is None else f"[{exc.index}]"
                raise ConfigError(f"{w}.published{at}", exc.problem) from None
        adapter = TASKS[kind]
        tname = _str(t.get("name", kind), f"{w}.name")
        if tname in names:
            raise ConfigError(f"{w}.name", f"duplicate task name {tname!r}")
        names.add(tname)
        dsel = _names(t.get("datasets", list(datasets)), f"{w}.datasets", "dataset names")
        for j, dn in enumerate(dsel):
            if dn not in datasets:
                raise ConfigError(
                    f"{w}.datasets[{j}]", f"unknown dataset {dn!r}; defined: {', '.join(datasets)}"
                )
        csel = _names(t.get("corruptions", ["none"]), f"{w}.corruptions", "corruption names")
        for j, cn in enumerate(csel):
            if cn not in corruptions:
                raise ConfigError(
                    f"{w}.corruptions[{j}]", f"unknown corruption {cn!r}; defined: {', '.join(corruptions)}"
                )
        if kind == "sequence":  # merged frames are the dataset's; each item is a whole sequence
            for j, cn in enumerate(csel):
                if cn != "none":
                    raise ConfigError(f"{w}.corruptions[{j}]", "a sequence task takes corruptions = [\"none\"] only "
                                      "(merged frames are the sequence dataset's merge_frames)")
            for j, dn in enumerate(dsel):
                if datasets[dn].kind != "sequence":
                    raise ConfigError(f"{w}.datasets[{j}]", f"dataset {dn!r} is not a sequence dataset "
                                      '(kind = "sequence")')
        elif any(datasets[dn].kind == "sequence" for dn in dsel):
            raise ConfigError(f"{w}.datasets", 'sequence datasets belong to the sequence task (task = "sequence")')
        if kind == "spectrum":
            if isinstance(t.get("spectrum"), dict) and "weighting" in t["spectrum"]:
                raise ConfigError(
                    f"{w}.spectrum.weighting", "the weightings of a spectrum task are its methods' plugins"
                )
            spectrum = _validate_spectrum(t.get("spectrum"), f"{w}.spectrum")
        elif "spectrum" in t:
            raise ConfigError(f"{w}.spectrum", _NOT_A_SUBJECT.format(kind=kind))
        else:
            spectrum = None
        options = _validate_options(adapter, t.get("options", {}) or {}, f"{w}.options")
        metrics = _names(t.get("metrics", list(adapter.default_metrics)), f"{w}.metrics", "metric names")
        for j, m in enumerate(metrics):
            problem = adapter.check_metric(m)
            if problem:
                raise ConfigError(f"{w}.metrics[{j}]", problem)
        if not isinstance(t["methods"], list) or not t["methods"]:
            raise ConfigError(f"{w}.methods", "must be a non-empty array of tables ([[tasks.methods]])")
        methods = [_check_method(kind, adapter, spectrum, m, f"{w}.methods[{j}]") for j, m in enumerate(t["methods"])]
        for j, m in enumerate(t["methods"]):
            _check_task_method(adapter, options, m, f"{w}.methods[{j}]")
            if m.get("peer") == "maps":
                _check_map_files(m, f"{w}.methods[{j}]", datasets, dsel, csel, limit)
        if options.get("human_consistency"):
            human = MethodSpec("human", "humans", None, {}, "human")
            methods.append(((lambda human=human: [human]), 1))
        if options.get("truth_reference"):
            truth = MethodSpec("ground truth", "references", None, {}, "ground truth")
            methods.append(((lambda truth=truth: [truth]), 1))
        n_items = sum(_dataset_size(datasets[dn], limit) for dn in dict.fromkeys(dsel))
        n_corr = sum(corruptions[cn].size for cn in dict.fromkeys(csel))
        n_meth = sum(size for _, size in methods)
        sizes.append((n_items * n_corr * n_meth, w,
                      f"task {tname!r}: {n_items} items x {n_corr} corruption settings x {n_meth} method settings"))
        pending.append((w, len(t["methods"]), tname, kind, dsel, csel, spectrum, metrics, options, methods))

    total = sum(n for n, _, _ in sizes)
    if max_rows is not None and total > max_rows:
        n, key, how = max(sizes)
        raise ConfigError(
            key,
            f"the config plans {total:,} rows ({how}), more than the cap of {max_rows:,}; use smaller grids "
            "or dataset limits, or raise the cap with --max-rows N",
        )

    tasks = []  # now the grids are known to be small enough: expand and check each point
    expanded = {name: c.expand() for name, c in corruptions.items() if any(name in p[5] for p in pending)}
    for w, n_listed, tname, kind, dsel, csel, spectrum, metrics, options, methods in pending:
        cinst = [inst for cn in csel for inst in expanded[cn]]
        mspecs = _distinct_methods(w, [make() for make, _ in methods], n_listed)
        tasks.append(
            TaskSpec(tname, kind, tuple(dsel), tuple(cinst), tuple(mspecs), spectrum, tuple(metrics), options)
        )
    return BenchConfig(name, random_state, datasets, tuple(tasks), source, raw, total, split)


SPLIT_HALVES = ("tune", "report")


def _split_halves(groups: list[str], salt: str, tune_fraction: float) -> dict[str, str]:
    """``{group: "tune" | "report"}``: groups ordered by SHA-1 of ``salt + group``, the first
    ``floor(tune_fraction * len(groups))`` tune."""
    import hashlib

    order = sorted(set(groups), key=lambda g: (hashlib.sha1(f"{salt}{g}".encode()).hexdigest(), g))
    n_tune = int(math.floor(tune_fraction * len(order) + 1e-9))
    return {g: ("tune" if i < n_tune else "report") for i, g in enumerate(order)}


def split_items(refs: Any, *, salt: str = "", tune_fraction: float = 0.5) -> dict[str, list]:
    """The items of one dataset by half: ``{"tune": [...], "report": [...], "neither": [...]}`` (a pair
    whose two shapes' groups fall in both halves is in neither); deterministic, by group
    (:func:`shape_toolkit.data.datasets.item_group`), never splitting a group. :class:`ParameterError`
    when an item has no group."""
    from shape_toolkit.data.datasets import item_group

    groups = {}
    for r in refs:
        g = item_group(r)
        if g is None:
            raise ParameterError(f"item {r.name!r} ({r.kind}) has no group to split by")
        groups[r.name] = g.split("+")
    half_of = _split_halves([g for gs in groups.values() for g in gs], salt, tune_fraction)
    out: dict[str, list] = {"tune": [], "report": [], "neither": []}
    for r in refs:
        halves = {half_of[g] for g in groups[r.name]}
        out[halves.pop() if len(halves) == 1 else "neither"].append(r)
    return out


def _apply_split(raw: Any, datasets: dict[str, DatasetSpec]) -> tuple[dict[str, DatasetSpec], dict[str, Any]]:
    """The datasets restricted to the split's half, and the split's summary (for the report)."""
    from dataclasses import replace

    w = "run.split"
    sp = _check_keys(raw, {"by", "half", "salt", "tune_fraction"}, w, ("half",))
    by = sp.get("by", "category")
    if by != "category":
        raise ConfigError(f"{w}.by", f"must be 'category' (the item's group: PSB category, animal, subject), "
                                     f"got {by!r}")
    half = sp["half"]
    if half not in SPLIT_HALVES:
        raise ConfigError(f"{w}.half", f"must be 'tune' or 'report', got {half!r}")
    salt = sp.get("salt", "")
    if not isinstance(salt, str):
        raise ConfigError(f"{w}.salt", f"must be a string, got {salt!r}")
    frac = sp.get("tune_fraction", 0.5)
    if isinstance(frac, bool) or not isinstance(frac, (int, float)) or not 0 < frac < 1:
        raise ConfigError(f"{w}.tune_fraction", f"must be a number in (0, 1), got {frac!r}")
    out: dict[str, DatasetSpec] = {}
    summary: dict[str, Any] = {"by": by, "half": half, "salt": salt, "tune_fraction": float(frac), "datasets": {}}
    for dname, spec in datasets.items():
        try:
            halves = split_items(spec.refs, salt=salt, tune_fraction=float(frac))
        except ParameterError as exc:
            raise ConfigError(f"{w}.by", f"dataset {dname!r}: {exc}; only psb and tosca datasets have groups") from None
        for h in SPLIT_HALVES:
            if not halves[h]:
                raise ConfigError(f"{w}.tune_fraction" if "tune_fraction" in sp else w,
                                  f"leaves the {h} half of dataset {dname!r} empty ({len(spec.refs)} items); "
                                  "use another tune_fraction or salt, or no split")
        from shape_toolkit.data.datasets import item_group

        summary["datasets"][dname] = {
            h: {"items": len(v), "groups": sorted({item_group(r) for r in v})} for h, v in halves.items()
        }
        out[dname] = replace(spec, refs=tuple(halves[half]))
    return out, summary


def split_line(split: dict[str, Any] | None) -> str | None:
    """One line saying which half of which split a run shows, and how many items; None without a split."""
    if not split:
        return None
    parts = []
    for dname, d in split["datasets"].items():
        h = d[split["half"]]
        other = "tune" if split["half"] == "report" else "report"
        parts.append(f"{dname}: {h['items']} items in {len(h['groups'])} groups ({', '.join(h['groups'])}); "
                     f"{d[other]['items']} {other} items left out" + (
                         f", {d['neither']['items']} pairs across halves in neither" if d["neither"]["items"] else ""))
    salt = "salt + " if split["salt"] else ""
    return (f"Split: only the {split['half']} half is shown. Rule: per dataset, the groups ({split['by']}) "
            f"ordered by SHA-1({salt}group name), the first {100 * split['tune_fraction']:g}% of them (rounded down) "
            "tune, the others report; " + "; ".join(parts) + ".")


def _validate_datasets(raw: Any, base: Path | None, max_rows: int | None) -> dict[str, DatasetSpec]:
    """Every ``[[datasets]]`` entry checked and its items listed."""
    from shape_toolkit.data.datasets import DATASET_KINDS, GENERATED_KINDS, find_item, open_dataset

    if not isinstance(raw, list) or not raw:
        raise ConfigError("datasets", "must be a non-empty array of tables ([[datasets]])")
    datasets: dict[str, DatasetSpec] = {}
    for i, d in enumerate(raw):
        w = f"datasets[{i}]"
        _check_keys(d, {"name", "kind", "path", "limit", "params", "items"}, w, ("kind",))
        kind = _str(d["kind"], f"{w}.kind")
        if kind not in DATASET_KINDS:
            raise ConfigError(
                f"{w}.kind", f"unknown dataset kind {kind!r}; known: {', '.join(DATASET_KINDS)}"
            )
        dname = _str(d.get("name", kind), f"{w}.name")
        if dname in datasets:
            raise ConfigError(f"{w}.name", f"duplicate dataset name {dname!r}")
        limit = _int(d["limit"], f"{w}.limit", 1) if "limit" in d else None
        params = d.get("params", {}) or {}
        if not isinstance(params, dict):
            raise ConfigError(f"{w}.params", "must be a table")
        n_poses = params.get("n_poses")
        if kind == "synthetic" and max_rows is not None and isinstance(n_poses, int) and n_poses > max_rows:
            raise ConfigError(f"{w}.params.n_poses", f"{n_poses:,} items are more than the cap of {max_rows:,} "
                              "rows; use fewer, or raise the cap with --max-rows N")
        path = None
        if kind not in GENERATED_KINDS:
            if "path" not in d:
                raise ConfigError(f"{w}.path", f"a {kind} dataset needs a path")
            p = resolve_data_path(_str(d["path"], f"{w}.path"), base)
            if not p.is_dir():
                env = os.environ.get("TOOLKIT_DATA")
                how = (
                    f"relative paths are resolved under $TOOLKIT_DATA={env}"
                    if env
                    else "relative paths are resolved under $TOOLKIT_DATA when set (it is not), "
                    "else under the config's folder"
                )
                raise ConfigError(f"{w}.path", f"dataset folder not found: {p} ({how})")
            path = str(p)
        _check_kinds(params, DATASET_KINDS[kind], f"{w}.params", grid=False)
        _check_generated(kind, params, f"{w}.params", max_rows)
        try:
            refs = open_dataset(kind, path, **params)
        except (ToolkitError, ValueError, TypeError) as exc:
            raise ConfigError(f"{w}.params" if params else f"{w}.path", str(exc)) from None
        if not refs:
            raise ConfigError(f"{w}.path", f"no items found in {path}")
        if "items" in d:  # a declared selection of items, in the given order
            chosen = _names(d["items"], f"{w}.items", "item names")
            picked = []
            for j, it in enumerate(chosen):
                try:
                    picked.append(find_item(kind, refs, it))
                except ParameterError as exc:
                    raise ConfigError(f"{w}.items[{j}]", str(exc)) from None
            if len(set(chosen)) != len(chosen):
                raise ConfigError(f"{w}.items", "lists an item twice")
            refs = picked
        datasets[dname] = DatasetSpec(dname, kind, path, limit, dict(params), tuple(refs))
    return datasets


#: the bounds the generators of generated datasets check when an item is made (``subdivisions``:
#: :func:`shape_toolkit.data.generate.icosphere`; ``max_angle``, ``n_poses`` and ``frames``:
#: :func:`shape_toolkit.data.synthetic.synthetic_dataset` and :func:`~shape_toolkit.data.synthetic.pose_sequence`):
#: checked here too, so that a value out of range is refused before any work (with or without ``max_rows``: a
#: billion poses are never listed) instead of failing every row
GENERATED_RANGES: dict[str, dict[str, tuple[float, float, bool]]] = {
    "synthetic": {"subdivisions": (0, MAX_SUBDIVISIONS, True), "max_angle": (0.0, MAX_POSE_ANGLE, False),
                  "n_poses": (1, MAX_POSES, True)},
    "sequence": {"subdivisions": (0, MAX_SUBDIVISIONS, True), "max_angle": (0.0, MAX_SEQUENCE_ANGLE, False),
                 "frames": (2, MAX_FRAMES, True)},
}
#: why each bound of :data:`GENERATED_RANGES` is there (named by the refusal)
_RANGE_REASONS = {
    "subdivisions": "the icosphere's subdivisions: 10 * 4**s + 2 vertices per sphere",
    "n_poses": "each item makes every pose of the dataset",
    "frames": "each item makes and keeps every frame of its sequence",
}


def _check_generated(kind: str, params: dict[str, Any], where: str, max_rows: int | None) -> None:
    """A generated dataset's parameters within the generator's bounds (:data:`GENERATED_RANGES`, named with the
    reason); a sequence's ``frames`` (each frame is matched, as a row is) at most ``max_rows`` (checked first: the
    cap named, as the rows past it are)."""
    frames = params.get("frames")
    if kind == "sequence" and max_rows is not None and isinstance(frames, int) and frames > max_rows:
        raise ConfigError(f"{where}.frames", f"{frames:,} frames (each matched to the next) are more than the cap "
                          f"of {max_rows:,} rows; use fewer, or raise the cap with --max-rows N")
    for key, (lo, hi, integral) in GENERATED_RANGES.get(kind, {}).items():
        v = params.get(key)
        if v is None:
            continue
        if integral and (isinstance(v, float) and not v.is_integer() or not lo <= v <= hi):
            raise ConfigError(f"{where}.{key}", f"must be an integer in [{lo}, {hi}] ({_RANGE_REASONS[key]}), got "
                                                f"{shown_value(v)}")
        if not integral and not lo <= v <= hi:
            raise ConfigError(f"{where}.{key}", f"must be in [{lo:g}, {hi:g}] rad (the {kind} generator's joint "
                                                f"angles), got {shown_value(v)}")
    if kind != "sequence":
        return
    seeds = params.get("seeds")
    for j, sd in enumerate(seeds if isinstance(seeds, list) else [seeds]):
        if isinstance(sd, int) and not isinstance(sd, bool) and sd > 2**32 - 1:
            at = f"[{j}]" if isinstance(seeds, list) else ""
            raise ConfigError(f"{where}.seeds{at}", f"must be at most 2**32 - 1 (each seed is the random_state of "
                                                    f"its sequence), got {shown_value(sd)}")
    remesh, sub = params.get("remesh"), params.get("subdivisions", 3)
    if isinstance(remesh, int) and not isinstance(remesh, bool) and isinstance(sub, (int, float)):
        most = 20 * (10 * 4 ** int(sub) + 2)  # as the remesh corruption: at most 20 times the clean frame's vertices
        why = f"20 times the {10 * 4 ** int(sub) + 2:,} vertices of a clean frame at subdivisions = {int(sub)}"
        if most > MAX_REMESH_VERTICES:  # and within the remeshing budget (the remesh corruption's n_vertices)
            most, why = MAX_REMESH_VERTICES, "the remeshing budget shape_toolkit.core.cleanup.MAX_REMESH_VERTICES"
        if remesh > most:
            raise ConfigError(f"{where}.remesh", f"must be a vertex count of at most {most:,} ({why}), got "
                                                 f"{shown_value(remesh)}")


def _validate_options(adapter: Any, options: Any, where: str) -> dict[str, Any]:
    """A task's options merged over its defaults; an unknown or bad option names its key."""
    if not isinstance(options, dict):
        raise ConfigError(where, "must be a table")
    from shape_toolkit.bench.tasks import COMMON_OPTIONS

    # COMMON_OPTIONS: every task's; protocol_options: how the task's items are prepared
    known = sorted({*adapter.option_defaults, *COMMON_OPTIONS, *adapter.protocol_options})
    for k in options:
        if k not in known:
            raise ConfigError(f"{where}.{k}", f"unknown {adapter.name} option {k!r}; known: {', '.join(known)}")
    try:
        return adapter.check_options(options)
    except ToolkitError as exc:
        msg = str(exc)
        key = next((k for k in sorted(options, key=len, reverse=True) if msg.startswith(k)), None)
        raise ConfigError(f"{where}.{key}" if key else where, msg) from None


def _check_task_method(adapter: Any, options: dict[str, Any], m: Any, mw: str) -> None:
    """A plugin method fits the task's options (:meth:`TaskAdapter.check_method`)."""
    from shape_toolkit.api.registry import get_registry

    if "plugin" not in m:
        if options.get("truth_seeds") is not None:
            raise ConfigError(mw, "the task option truth_seeds gives ground-truth seeds to dense matcher plugins; "
                                  "pipelines and peers find their own: put them in a task without that option")
        return
    fam = _family_for(adapter.name, m["plugin"], mw)
    problem = adapter.check_method(options, get_registry().get(fam, m["plugin"]), m.get("params") or {})
    if problem:
        raise ConfigError(f"{mw}.plugin", problem)


def _check_method(kind: str, adapter: Any, spectrum: dict | None, m: Any, mw: str) -> tuple[Any, int]:
    """One ``[[tasks.methods]]`` entry checked without expanding its grid: ``(make, size)``, where
    ``make()`` expands and checks each grid point into :class:`MethodSpec` instances."""
    _check_keys(m, {"plugin", "pipeline", "peer", "path", "preset", "label", "params", "spectrum", "keypoints",
                    "method"}, mw)
    if kind == "geodesics" or "method" in m:
        spec = _geodesic_method(kind, m, mw)
        return (lambda: [spec]), 1
    if "pipeline" in m:
        spec = _pipeline_method(kind, m, mw)
        return (lambda: [spec]), 1
    if kind == "sequence":
        raise ConfigError(f"{mw}.pipeline", "a sequence task's methods are matching pipelines: pipeline = "
                          "a preset name, TOML file or inline table")
    if "peer" in m and kind == "spectrum" and spectrum is not None:
        spec = _spectrum_peer_method(m, mw, spectrum)
        return (lambda: [spec]), 1
    if "peer" in m:
        spec = _peer_method(kind, m, mw)
        return (lambda: [spec]), 1
    if "path" in m:
        raise ConfigError(f"{mw}.path", 'only a published-maps peer (peer = "maps") takes a path')
    if "plugin" not in m:
        raise ConfigError(f"{mw}.plugin", "is required (or pipeline = ... / peer = ... for a matching method)")
    plugin = _str(m["plugin"], f"{mw}.plugin")
    fam = _family_for(kind, plugin, mw)
    preset = _str(m["preset"], f"{mw}.preset") if "preset" in m else None
    label = _str(m["label"], f"{mw}.label") if "label" in m else plugin + (f":{preset}" if preset else "")
    prm = m.get("params", {}) or {}
    if not isinstance(prm, dict):
        raise ConfigError(f"{mw}.params", "must be a table")
    if "spectrum" in m and spectrum is None:
        raise ConfigError(f"{mw}.spectrum", _NOT_A_SUBJECT.format(kind=kind))
    if isinstance(m.get("spectrum"), dict) and "weighting" in m["spectrum"]:
        raise ConfigError(f"{mw}.spectrum.weighting", "the weighting of a spectrum task's method is its plugin")
    if "spectrum" in m and not isinstance(m["spectrum"], dict):
        raise ConfigError(f"{mw}.spectrum", "must be a table")
    mspec = _validate_spectrum({**spectrum, **m["spectrum"]}, f"{mw}.spectrum") if "spectrum" in m else None
    kp = m.get("keypoints")
    if kp is not None:
        _check_keys(kp, {"plugin", "preset", "params"}, f"{mw}.keypoints", ("plugin",))
        kp_params = kp.get("params", {}) or {}
        if not isinstance(kp_params, dict):
            raise ConfigError(f"{mw}.keypoints.params", "must be a table")
        kp_preset = _str(kp["preset"], f"{mw}.keypoints.preset") if "preset" in kp else None
        _validate_plugin_params(
            "keypoints", _str(kp["plugin"], f"{mw}.keypoints.plugin"), kp_preset, kp_params, f"{mw}.keypoints"
        )
    elif fam in adapter.needs_keypoints:
        raise ConfigError(f"{mw}.keypoints", f"a {fam} method needs keypoints = {{ plugin = ... }}")
    _check_plugin_names(fam, plugin, preset, prm, mw)

    def make() -> list[MethodSpec]:
        out = []
        for g in expand_grid(prm):
            _validate_plugin_params(fam, plugin, preset, g, mw)
            out.append(MethodSpec(plugin, fam, preset, g, label, mspec, kp))
        return out

    return make, grid_size(prm)


def load_config(
    path: str | os.PathLike, *, max_rows: int | None = None, limit: int | None = None
) -> BenchConfig:
    """Read and validate a TOML benchmark config (see the module docstring for the layout;
    ``max_rows`` and ``limit`` as in :func:`parse_config`)."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError("(file)", f"config file not found: {p}")
    try:
        raw = tomllib.loads(p.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError("(file)", f"{p}: invalid TOML: {exc}") from None
    return parse_config(raw, base=p.resolve().parent, source=str(p), max_rows=max_rows, limit=limit)
