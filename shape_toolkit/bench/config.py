"""Benchmark configuration: read a TOML file, validate everything before any work starts.

Layout (every key is checked; an error names the key, e.g. ``tasks[0].methods[1].params.k``)::

    [run]
    name = "my-run"            # optional
    random_state = 0           # seeds corruptions and every plugin with a random_state

    [[datasets]]
    name = "psb"               # unique
    kind = "psb"               # tosca | psb | folder | synthetic
    path = "psb"               # absolute, or relative to $TOOLKIT_DATA (else to the config's folder)
    limit = 4                  # optional: first N items
    params = {}                # kind-specific (synthetic: n_poses, subdivisions, max_angle)

    [[corruptions]]
    name = "noise"
    kind = "gaussian-noise"    # see shape_toolkit.data.corruptions.CORRUPTIONS
    params = { strength = [0.1, 0.3] }   # lists are grids (a literal list: wrap it, [[1, 2]])

    [[tasks]]
    task = "segmentation"      # the task kind: spectrum | keypoints | segmentation | matching
    name = "seg"               # optional task name, default = the task kind
    datasets = ["psb"]         # default: every dataset
    corruptions = ["none", "noise"]      # default: ["none"]
    metrics = ["rand_index"]   # default: the task's default metrics
    options = {}               # task options (see shape_toolkit.bench.tasks)
    [[tasks.methods]]
    plugin = "spectral-clustering"
    preset = "..."             # optional
    label = "..."              # optional display name
    params = { n_segments = [4, 6] }

A matching method may instead be ``pipeline = "zoomout"`` (a preset, TOML file or inline table of
:mod:`shape_toolkit.pipeline`) or ``peer = "pyfm"`` (a peer's published pipeline,
:mod:`shape_toolkit.bench.peers`), each with an optional ``label``.

Spectra: methods receive the spectra they declare (``spectrum_spec()`` of a plugin and of its
keypoint detector, ``spectrum_specs()`` of a pipeline), so a ``spectrum`` table belongs to the
``spectrum`` task only, where the spectrum is the subject (``{ k = 40, laplacian = ..., use_mass
= ..., params = {...} }``; the weighting is each method's plugin). Elsewhere it is an error.
In Python, :class:`TaskSpec` has ``task_kind`` (the ``task`` key) and ``task_name`` (``name``);
:class:`MethodSpec` has ``plugin`` (registry name) and ``method_label`` (``label``).
"""

from __future__ import annotations

import itertools
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from shape_toolkit.errors import ParameterError, ToolkitError

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
]


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
    """One corruption instance (a grid point): name (unique per instance), kind and params."""

    name: str
    kind: str
    params: dict[str, Any]
    group: str = ""

    @property
    def strength(self) -> float | None:
        """The ``strength`` parameter (0 for no corruption), for plots."""
        if self.kind == "none":
            return 0.0
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
    """A validated benchmark configuration."""

    name: str
    random_state: int
    datasets: dict[str, DatasetSpec]
    tasks: tuple[TaskSpec, ...]
    source: str = ""
    raw: dict[str, Any] = field(default_factory=dict)


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


def _validate_plugin_params(family: str, plugin: str, preset: str | None, params: dict, where: str) -> None:
    from shape_toolkit.api.registry import get_registry

    reg = get_registry()
    cls = reg.get(family, plugin)
    if preset is not None and preset not in (getattr(cls, "presets", {}) or {}):
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
    try:  # constructing checks types where plugins validate in __init__ (cheap by contract)
        reg.create(family, plugin, preset, **params)
    except ToolkitError as exc:
        raise ConfigError(f"{where}.params", str(exc)) from None


def _validate_corruptions(raw: Any) -> dict[str, list[CorruptionSpec]]:
    import inspect

    from shape_toolkit.data.corruptions import CORRUPTIONS

    out: dict[str, list[CorruptionSpec]] = {"none": [NO_CORRUPTION]}
    if raw is None:
        return out
    if not isinstance(raw, list):
        raise ConfigError("corruptions", "must be an array of tables ([[corruptions]])")
    for i, c in enumerate(raw):
        w = f"corruptions[{i}]"
        _check_keys(c, {"name", "kind", "params"}, w, ("kind",))
        kind = c["kind"]
        if kind not in CORRUPTIONS:
            raise ConfigError(f"{w}.kind", f"unknown corruption {kind!r}; known: {', '.join(CORRUPTIONS)}")
        name = c.get("name", kind)
        if name in out:
            raise ConfigError(f"{w}.name", f"duplicate corruption name {name!r}")
        prm = c.get("params", {}) or {}
        if not isinstance(prm, dict):
            raise ConfigError(f"{w}.params", "must be a table")
        valid = [
            p for p in inspect.signature(CORRUPTIONS[kind]).parameters if p not in ("shape", "random_state")
        ]
        for k in prm:
            if k not in valid:
                raise ConfigError(
                    f"{w}.params.{k}", f"corruption {kind!r} has no such parameter; valid: {', '.join(valid)}"
                )
        grid = expand_grid(prm)
        insts = []
        for g in grid:
            suffix = ",".join(f"{k}={g[k]}" for k in sorted(g) if isinstance(prm[k], list))
            insts.append(CorruptionSpec(f"{name}[{suffix}]" if suffix else name, kind, g, name))
        out[name] = insts
    return out


def _pipeline_method(task: str, m: dict, where: str) -> MethodSpec:
    """A matching method given as a pipeline (preset name, TOML path or inline table) of
    :mod:`shape_toolkit.pipeline`; its spec becomes the method's ``pipeline`` parameter."""
    from shape_toolkit.pipeline import load_pipeline

    if task != "matching":
        raise ConfigError(f"{where}.pipeline", 'pipelines are matching methods (task = "matching")')
    extra = sorted(set(m) - {"pipeline", "label"})
    if extra:
        raise ConfigError(f"{where}.{extra[0]}", "not allowed with pipeline (put it in the pipeline spec)")
    try:
        pipe = load_pipeline(m["pipeline"])
    except ToolkitError as exc:
        raise ConfigError(f"{where}.pipeline", str(exc)) from None
    spec = {"name": pipe.name, **pipe.stages}
    return MethodSpec(
        pipe.name, "pipelines", None, {"pipeline": spec}, m.get("label", f"pipeline:{pipe.name}")
    )


def _peer_method(task: str, m: dict, where: str) -> MethodSpec:
    """A matching method run by a peer implementation (:mod:`shape_toolkit.bench.peers`, e.g.
    ``peer = "pyfm"``), side by side with the toolkit's methods."""
    from shape_toolkit.bench.peers import create_peer

    if task != "matching":
        raise ConfigError(f"{where}.peer", 'peers are matching methods (task = "matching")')
    extra = sorted(set(m) - {"peer", "label"})
    if extra:
        raise ConfigError(f"{where}.{extra[0]}", "not allowed with peer (a peer runs its own published pipeline)")
    name = m["peer"]
    if not isinstance(name, str):
        raise ConfigError(f"{where}.peer", f"must be a peer name, got {name!r}")
    try:
        create_peer(name)
    except ToolkitError as exc:
        raise ConfigError(f"{where}.peer", str(exc)) from None
    return MethodSpec(name, "peers", None, {}, m.get("label", f"peer:{name}"))


def parse_config(raw: dict[str, Any], *, base: Path | None = None, source: str = "") -> BenchConfig:
    """Validate a config dict (as read from TOML) and list the dataset items; raises
    :class:`ConfigError` naming the first bad key."""
    from shape_toolkit.bench.tasks import TASKS
    from shape_toolkit.data.datasets import DATASET_KINDS, open_dataset

    _check_keys(raw, {"run", "datasets", "corruptions", "tasks"}, "", ("datasets", "tasks"))
    run = _check_keys(raw.get("run", {}), {"name", "random_state", "description"}, "run")
    random_state = _int(run.get("random_state", 0), "run.random_state")
    name = str(run.get("name", Path(source).stem if source else "run"))

    if not isinstance(raw["datasets"], list) or not raw["datasets"]:
        raise ConfigError("datasets", "must be a non-empty array of tables ([[datasets]])")
    datasets: dict[str, DatasetSpec] = {}
    for i, d in enumerate(raw["datasets"]):
        w = f"datasets[{i}]"
        _check_keys(d, {"name", "kind", "path", "limit", "params"}, w, ("kind",))
        kind = d["kind"]
        if kind not in DATASET_KINDS:
            raise ConfigError(
                f"{w}.kind", f"unknown dataset kind {kind!r}; known: {', '.join(DATASET_KINDS)}"
            )
        dname = d.get("name", kind)
        if dname in datasets:
            raise ConfigError(f"{w}.name", f"duplicate dataset name {dname!r}")
        limit = _int(d["limit"], f"{w}.limit", 1) if "limit" in d else None
        params = d.get("params", {}) or {}
        path = None
        if kind != "synthetic":
            if "path" not in d:
                raise ConfigError(f"{w}.path", f"a {kind} dataset needs a path")
            p = resolve_data_path(str(d["path"]), base)
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
        try:
            refs = open_dataset(kind, path, **params)
        except ToolkitError as exc:
            raise ConfigError(f"{w}.params" if params else f"{w}.path", str(exc)) from None
        if not refs:
            raise ConfigError(f"{w}.path", f"no items found in {path}")
        datasets[dname] = DatasetSpec(dname, kind, path, limit, dict(params), tuple(refs))

    corruptions = _validate_corruptions(raw.get("corruptions"))

    if not isinstance(raw["tasks"], list) or not raw["tasks"]:
        raise ConfigError("tasks", "must be a non-empty array of tables ([[tasks]])")
    tasks = []
    names = set()
    for i, t in enumerate(raw["tasks"]):
        w = f"tasks[{i}]"
        _check_keys(
            t,
            {"task", "name", "datasets", "corruptions", "spectrum", "metrics", "methods", "options"},
            w,
            ("task", "methods"),
        )
        kind = t["task"]
        if kind not in TASKS:
            raise ConfigError(f"{w}.task", f"unknown task {kind!r}; known: {', '.join(TASKS)}")
        adapter = TASKS[kind]
        tname = t.get("name", kind)
        if tname in names:
            raise ConfigError(f"{w}.name", f"duplicate task name {tname!r}")
        names.add(tname)
        dsel = t.get("datasets", list(datasets))
        if not isinstance(dsel, list):
            raise ConfigError(f"{w}.datasets", "must be a list of dataset names")
        for j, dn in enumerate(dsel):
            if dn not in datasets:
                raise ConfigError(
                    f"{w}.datasets[{j}]", f"unknown dataset {dn!r}; defined: {', '.join(datasets)}"
                )
        csel = t.get("corruptions", ["none"])
        if not isinstance(csel, list):
            raise ConfigError(f"{w}.corruptions", "must be a list of corruption names")
        cinst: list[CorruptionSpec] = []
        for j, cn in enumerate(csel):
            if cn not in corruptions:
                raise ConfigError(
                    f"{w}.corruptions[{j}]", f"unknown corruption {cn!r}; defined: {', '.join(corruptions)}"
                )
            cinst += corruptions[cn]
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
        options = t.get("options", {}) or {}
        try:
            options = adapter.check_options(options)
        except ToolkitError as exc:
            raise ConfigError(f"{w}.options", str(exc)) from None
        metrics = t.get("metrics", list(adapter.default_metrics))
        if not isinstance(metrics, list) or not metrics:
            raise ConfigError(f"{w}.metrics", "must be a non-empty list of metric names")
        for j, m in enumerate(metrics):
            problem = adapter.check_metric(m)
            if problem:
                raise ConfigError(f"{w}.metrics[{j}]", problem)
        if not isinstance(t["methods"], list) or not t["methods"]:
            raise ConfigError(f"{w}.methods", "must be a non-empty array of tables ([[tasks.methods]])")
        methods = []
        for j, m in enumerate(t["methods"]):
            mw = f"{w}.methods[{j}]"
            _check_keys(m, {"plugin", "pipeline", "peer", "preset", "label", "params", "spectrum", "keypoints"}, mw)
            if "pipeline" in m:
                methods.append(_pipeline_method(kind, m, mw))
                continue
            if "peer" in m:
                methods.append(_peer_method(kind, m, mw))
                continue
            if "plugin" not in m:
                raise ConfigError(
                    f"{mw}.plugin", "is required (or pipeline = ... / peer = ... for a matching method)"
                )
            fam = _family_for(kind, m["plugin"], mw)
            prm = m.get("params", {}) or {}
            if not isinstance(prm, dict):
                raise ConfigError(f"{mw}.params", "must be a table")
            if "spectrum" in m and spectrum is None:
                raise ConfigError(f"{mw}.spectrum", _NOT_A_SUBJECT.format(kind=kind))
            if isinstance(m.get("spectrum"), dict) and "weighting" in m["spectrum"]:
                raise ConfigError(f"{mw}.spectrum.weighting", "the weighting of a spectrum task's method is its plugin")
            mspec = (
                _validate_spectrum({**spectrum, **m["spectrum"]}, f"{mw}.spectrum")
                if "spectrum" in m
                else None
            )
            kp = m.get("keypoints")
            if kp is not None:
                _check_keys(kp, {"plugin", "preset", "params"}, f"{mw}.keypoints", ("plugin",))
                _validate_plugin_params(
                    "keypoints", kp["plugin"], kp.get("preset"), kp.get("params", {}) or {}, f"{mw}.keypoints"
                )
            elif fam in adapter.needs_keypoints:
                raise ConfigError(f"{mw}.keypoints", f"a {fam} method needs keypoints = {{ plugin = ... }}")
            for g in expand_grid(prm):
                _validate_plugin_params(fam, m["plugin"], m.get("preset"), g, mw)
                label = m.get("label", m["plugin"] + (f":{m['preset']}" if m.get("preset") else ""))
                methods.append(MethodSpec(m["plugin"], fam, m.get("preset"), g, label, mspec, kp))
        tasks.append(
            TaskSpec(
                tname, kind, tuple(dsel), tuple(cinst), tuple(methods), spectrum, tuple(metrics), options
            )
        )
    return BenchConfig(name, random_state, datasets, tuple(tasks), source, raw)


def load_config(path: str | os.PathLike) -> BenchConfig:
    """Read and validate a TOML benchmark config (see the module docstring for the layout)."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError("(file)", f"config file not found: {p}")
    try:
        raw = tomllib.loads(p.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError("(file)", f"{p}: invalid TOML: {exc}") from None
    return parse_config(raw, base=p.resolve().parent, source=str(p))
