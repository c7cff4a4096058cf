"""Planning: expand a validated config into row jobs and the prepare jobs they share.

A :class:`Job` is one row to compute (a method on one dataset item under one corruption); a
:class:`PrepareJob` is the work shared by every row of one (item, corruption): loading, the
corruption, ground truth carried through it, geodesic rows for the evaluation, and the spectra
the methods on that item declare (merged per kind: one eigen-solve with the largest ``k``).

Rows are keyed by a stable hash of their identity (dataset, item, task, plugin, preset,
parameters, corruption, the spectra the method declares, random state, metrics, options), so a
resumed run skips exactly the rows already done.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from shape_toolkit.bench.config import BenchConfig, MethodSpec, TaskSpec
from shape_toolkit.bench.store import RowIdentity
from shape_toolkit.data.datasets import item_group
from shape_toolkit.spectra import SpectrumSpec, merge_specs
from shape_toolkit.validation import dumps_json

__all__ = ["Job", "PrepareJob", "plan", "row_key", "subject_spec", "create_method", "declared_specs"]


def row_key(fields: dict[str, Any]) -> str:
    """Stable hash of the identity of a row (not of its results)."""
    return hashlib.sha1(dumps_json(fields, sort_keys=True).encode()).hexdigest()[:16]


def _seed(*parts: Any) -> int:
    return int(hashlib.sha1(repr(parts).encode()).hexdigest()[:8], 16) % (2**31 - 1)


@dataclass
class PrepareJob:
    """Shared work of one (item, corruption): see the module docstring. ``specs`` are the merged
    spectra every method on the item declared, computed on ``sides`` into the cache."""

    key: str
    run_dir: str
    dataset: str
    item: str
    ref: dict[str, Any]
    corruption_kind: str
    corruption_params: dict[str, Any]
    pairwise: bool
    seed: int
    geodesic_method: str | None
    truth_sample: int | None
    specs: list[SpectrumSpec] = field(default_factory=list)
    score_on: str = "target"
    target: str = "pair"
    truth_points: str = "random"
    corrupt: str = "target"

    @property
    def sides(self) -> tuple[str, ...]:
        """The shapes a method sees: the target, and the source of a pairwise task."""
        return ("target", "source") if self.pairwise else ("target",)


@dataclass
class Job(RowIdentity):
    """One row to compute: the identity its row will carry (:class:`RowIdentity`: ``plugin`` the
    registry name, a pipeline's name for pipelines, ``method_label`` the display name,
    ``task_kind`` the adapter and ``task_name`` the config's task) and what computing it needs:
    ``subject_spectrum`` is set for the spectrum task only (the spectrum *is* the result);
    ``item_specs`` are the merged spectra the prepare stage computed for the item; ``item_params``
    the parameters set per item (``n_segments = "human-mode"``: the humans' count), given to the method
    on top of ``params``; ``category`` the item's group (:func:`shape_toolkit.data.datasets.item_group`)."""

    run_dir: str
    keypoints: dict[str, Any] | None
    metrics: tuple[str, ...]
    options: dict[str, Any]
    subject_spectrum: SpectrumSpec | None = None
    item_specs: tuple[SpectrumSpec, ...] = ()
    item_params: dict[str, Any] = field(default_factory=dict)
    category: str | None = None
    solver: str | None = None


def subject_spec(task: TaskSpec, method: MethodSpec) -> SpectrumSpec:
    """The spectrum a ``spectrum`` task computes for a weighting method: the task's (or the
    method's) ``spectrum`` table with the method's plugin as weighting and its parameters."""
    s = dict(method.spectrum or task.spectrum)
    params = {**(s.get("params") or {}), **method.params}
    for key in ("connectivity", "n_neighbors"):
        if key in s:
            params[key] = s[key]
    return SpectrumSpec(int(s["k"]), method.plugin, s["laplacian"], s.get("use_mass"), params)


def create_method(family: str, plugin: str, preset: str | None, params: dict, random_state: int) -> Any:
    """The method object of a row: a pipeline, a peer, or a plugin seeded with the run's random state."""
    if family == "pipelines":
        from shape_toolkit.pipeline import load_pipeline

        return load_pipeline(params["pipeline"])
    if family == "peers":
        from shape_toolkit.bench.peers import create_peer

        return create_peer(plugin, **params)
    if family == "humans":
        from shape_toolkit.bench.tasks import HumanSegmentations

        return HumanSegmentations()
    if family == "references":
        from shape_toolkit.bench.tasks import GroundTruthMap

        return GroundTruthMap()
    if family == "geodesics":
        from shape_toolkit.bench.tasks import GeodesicMethod

        return GeodesicMethod(plugin)
    from shape_toolkit.bench.tasks import _with_random_state

    return _with_random_state(family, plugin, preset, params, random_state)


def create_detector(keypoints: dict[str, Any] | None) -> Any:
    """The keypoint detector of a sparse-matching method, or None."""
    if not keypoints:
        return None
    from shape_toolkit.api.registry import create_plugin

    return create_plugin("keypoints", keypoints["plugin"], keypoints.get("preset"), **(keypoints.get("params") or {}))


def declared_specs(
    task: TaskSpec, method: MethodSpec, random_state: int, item_params: dict[str, Any] | None = None
) -> list[SpectrumSpec]:
    """Every spectrum a method of a (non-spectrum) task declares (with the ``item_params`` of an item),
    its keypoint detector's included; empty when the method cannot be created (its row will fail
    with the reason)."""
    from shape_toolkit.bench.tasks import method_specs

    try:
        params = {**method.params, **(item_params or {})}
        obj = create_method(method.family, method.plugin, method.preset, params, random_state)
        own, det = method_specs(obj, create_detector(method.keypoints))
    except Exception:  # noqa: BLE001 - reported by the row itself
        return []
    return own + ([det] if det is not None else [])


def item_params_of(task: TaskSpec, method: MethodSpec, ref: Any, counts: dict[str, int]) -> dict[str, Any]:
    """The parameters a task's options set for one item: ``n_segments`` (an integer, or the humans'
    count with ``"human-mode"``, read once per item into ``counts``) unless the method sets its own."""
    from shape_toolkit.bench.tasks import HUMAN_MODE

    k = task.options.get("n_segments") if task.task_kind == "segmentation" else None
    if k is None or method.family != "segmenters" or "n_segments" in method.params:
        return {}
    if k == HUMAN_MODE:
        key = f"{ref.kind}:{ref.name}:{ref.paths.get('shape', '')}"
        if key not in counts:
            from shape_toolkit.data.datasets import truth_segment_counts
            from shape_toolkit.metrics.segmentation import consensus_segment_count

            counts[key] = consensus_segment_count(truth_segment_counts(ref))
        k = counts[key]
    return {"n_segments": int(k)}


def plan(
    config: BenchConfig, run_dir: str | os.PathLike, *, limit: int | None = None
) -> tuple[list[Job], dict[str, PrepareJob]]:
    """Expand the config into row jobs and prepare jobs ``{prepare key: job}``."""
    from shape_toolkit.bench.tasks import PROTOCOL_VALUES, TASKS

    run_dir = str(Path(run_dir).resolve())
    jobs: list[Job] = []
    preps: dict[str, PrepareJob] = {}
    seen: set[str] = set()
    declared: dict[tuple[str, int, str], list[SpectrumSpec]] = {}
    counts: dict[str, int] = {}
    for task in config.tasks:
        adapter = TASKS[task.task_kind]
        geo = task.task_kind == "matching"
        for dname in task.datasets:
            ds = config.datasets[dname]
            refs = list(ds.refs)
            n = min(x for x in (ds.limit, limit, len(refs)) if x is not None)
            for ref in refs[:n]:
                category = item_group(ref)
                extra = [item_params_of(task, m, ref, counts) for m in task.methods]
                for m_index, m in enumerate(task.methods):
                    dkey = (task.task_name, m_index, dumps_json(extra[m_index], sort_keys=True))
                    if task.task_kind != "spectrum" and dkey not in declared:
                        declared[dkey] = (declared_specs(task, m, config.random_state, extra[m_index])
                                          if adapter.uses_spectra else [])
                for corr in task.corruptions:
                    seed = corr.seed if corr.seed is not None else _seed(config.random_state, dname, ref.name,
                                                                        corr.name)
                    pident = {
                        "dataset": dname,
                        "item": ref.name,
                        "ref": asdict(ref),
                        "corruption": corr.kind,
                        "corruption_params": corr.params,
                        "pairwise": adapter.pairwise,
                        "seed": seed,
                        "geodesic_method": task.options.get("geodesic_method") if geo else None,
                        "truth_sample": task.options.get("truth_sample") if geo else None,
                    }
                    protocol = {k: task.options[k] for k, allowed in PROTOCOL_VALUES.items()  # default first
                                if (geo or k in adapter.protocol_options)
                                and task.options.get(k, allowed[0]) != allowed[0]}
                    pident.update(protocol)  # only when set: the keys of earlier runs stay valid
                    pkey = row_key(pident)
                    prep = preps.get(pkey)
                    if prep is None:
                        prep = preps[pkey] = PrepareJob(
                            pkey, run_dir, dname, ref.name, asdict(ref), corr.kind, dict(corr.params),
                            adapter.pairwise, seed, pident["geodesic_method"], pident["truth_sample"],
                            **protocol,
                        )
                    for m_index, m in enumerate(task.methods):
                        subject = subject_spec(task, m) if task.task_kind == "spectrum" else None
                        specs = [subject] if subject else declared[
                            (task.task_name, m_index, dumps_json(extra[m_index], sort_keys=True))]
                        if subject is None:
                            prep.specs = merge_specs(prep.specs + specs)
                        ident = {
                            "dataset": dname,
                            "item": ref.name,
                            "task_name": task.task_name,
                            "task_kind": task.task_kind,
                            "plugin": m.plugin,
                            "preset": m.preset,
                            "params": m.params,
                            **({"item_params": extra[m_index]} if extra[m_index] else {}),
                            "corruption": corr.name,
                            "corruption_params": corr.params,
                            "spectra": [s.to_dict() for s in specs],
                            "keypoints": m.keypoints,
                            "random_state": config.random_state,
                            "metrics": list(task.metrics),
                            "options": task.options,
                        }
                        if m.solver is not None:  # only then: the keys of earlier runs' rows hold
                            ident["solver"] = m.solver
                        if corr.seed is not None:  # likewise: a fixed corruption seed
                            ident["corruption_seed"] = corr.seed
                        key = row_key(ident)
                        if key in seen:
                            continue
                        seen.add(key)
                        jobs.append(
                            Job(
                                key=key,
                                prepare_key=pkey,
                                run_dir=run_dir,
                                run_name=config.name,
                                task_name=task.task_name,
                                task_kind=task.task_kind,
                                dataset=dname,
                                item=ref.name,
                                plugin=m.plugin,
                                family=m.family,
                                preset=m.preset,
                                params=m.params,
                                method_label=m.method_label,
                                keypoints=m.keypoints,
                                corruption=corr.name,
                                corruption_kind=corr.kind,
                                corruption_group=corr.group,
                                corruption_params=corr.params,
                                strength=corr.strength,
                                random_state=config.random_state,
                                corruption_seed=seed,
                                metrics=tuple(task.metrics),
                                options=task.options,
                                subject_spectrum=subject,
                                item_params=extra[m_index],
                                category=category,
                                solver=m.solver,
                            )
                        )
    jobs = [replace(j, item_specs=tuple(preps[j.prepare_key].specs)) for j in jobs]
    return jobs, preps
