"""Execute a benchmark config: plan rows, skip finished ones, run the rest, append rows safely.

Rows are keyed by a stable hash of (dataset, item, task, method, preset, params, corruption,
spectrum settings, random state). ``RUN_DIR/results.jsonl`` holds one JSON object per line; the
runner process is the only writer and appends each finished row as one whole line followed by
``flush`` + ``fsync``, so a crash loses no finished row and at worst a torn last line, which is
dropped on the next start. A second ``bench run`` on the same folder skips every key already
present (ok or failed; ``retry_failed`` re-runs failed ones).

Work happens in two stages: one *prepare* job per (item, corruption) loads the item, applies the
corruption, carries the ground truth, computes the spectra every method will ask for (into the
on-disk cache ``RUN_DIR/cache/spectra``) and geodesic rows for the evaluation; then one job per
row runs a method on the prepared item. With Dask, row jobs depend on their prepare job, so
shared work is done once per run even across workers.

Execution: in-process when ``workers == 1``; a Dask ``LocalCluster`` (processes, one thread
each, loopback) for ``workers > 1``; an existing Dask scheduler with ``scheduler="tcp://..."``
(the run folder must then be on a filesystem the workers share).
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import platform
import resource
import sys
import threading
import time
import traceback
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from shape_toolkit.bench.config import BenchConfig
from shape_toolkit.bench.progress import Progress
from shape_toolkit.errors import ParameterError

__all__ = ["RunSummary", "plan", "run_benchmark", "read_rows", "prepare_job", "execute_job", "row_key"]

RESULTS = "results.jsonl"
PREPARED = "prepare.jsonl"


def _jsonable(o: Any) -> Any:
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return _jsonable(o.tolist())
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating, float)):
        f = float(o)
        return f if np.isfinite(f) else (None if np.isnan(f) else ("inf" if f > 0 else "-inf"))
    if isinstance(o, (np.bool_,)):
        return bool(o)
    return o


def _hash(obj: Any) -> str:
    return hashlib.sha1(json.dumps(_jsonable(obj), sort_keys=True).encode()).hexdigest()[:16]


def row_key(fields: dict[str, Any]) -> str:
    """Stable hash of the identity of a row (not of its results)."""
    return _hash(fields)


def _seed(*parts: Any) -> int:
    return int(hashlib.sha1(repr(parts).encode()).hexdigest()[:8], 16) % (2**31 - 1)


# --------------------------------------------------------------------------------------------
# planning
# --------------------------------------------------------------------------------------------
def plan(config: BenchConfig, run_dir: str | os.PathLike, *, limit: int | None = None) -> tuple[list, dict]:
    """Expand the config into row jobs (dicts, picklable) and prepare jobs ``{pkey: job}``."""
    from shape_toolkit.bench.tasks import TASKS

    run_dir = str(Path(run_dir).resolve())
    jobs, preps, seen = [], {}, set()
    for task in config.tasks:
        adapter = TASKS[task.task]
        for dname in task.datasets:
            ds = config.datasets[dname]
            refs = list(ds.refs)
            n = min(x for x in (ds.limit, limit, len(refs)) if x is not None)
            for ref in refs[:n]:
                for corr in task.corruptions:
                    seed = _seed(config.random_state, dname, ref.name, corr.name)
                    geo = task.task == "matching"
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
                    pkey = row_key(pident)
                    prep = preps.setdefault(pkey, {"key": pkey, "run_dir": run_dir, **pident, "spectra": []})
                    for m in task.methods:
                        spec = dict(m.spectrum or task.spectrum)
                        wparams: dict = {}
                        if task.task == "spectrum":
                            spec["weighting"], wparams = m.plugin, dict(m.params)
                        sides = ["target"] + (["source"] if adapter.pairwise else [])
                        for side in sides if task.task != "spectrum" else []:
                            entry = {"side": side, "settings": spec, "weighting_params": wparams}
                            if entry not in prep["spectra"]:
                                prep["spectra"].append(entry)
                        ident = {
                            "dataset": dname,
                            "item": ref.name,
                            "task": task.name,
                            "method": m.plugin,
                            "preset": m.preset,
                            "params": m.params,
                            "corruption": corr.name,
                            "corruption_params": corr.params,
                            "spectrum": spec,
                            "keypoints": m.keypoints,
                            "random_state": config.random_state,
                            "metrics": list(task.metrics),
                            "options": task.options,
                        }
                        key = row_key(ident)
                        if key in seen:
                            continue
                        seen.add(key)
                        jobs.append(
                            {
                                "key": key,
                                "pkey": pkey,
                                "run_dir": run_dir,
                                "run": config.name,
                                "task_kind": task.task,
                                **ident,
                                "family": m.family,
                                "label": m.label,
                                "corruption_kind": corr.kind,
                                "corruption_group": corr.group,
                                "strength": corr.strength,
                                "weighting_params": wparams,
                                "seed": seed,
                            }
                        )
    return jobs, preps


# --------------------------------------------------------------------------------------------
# worker side
# --------------------------------------------------------------------------------------------
@lru_cache(maxsize=1)
def package_versions() -> dict[str, str]:
    """Versions of the toolkit and the main numerical packages in this process."""
    import importlib.metadata as md

    out = {"python": platform.python_version()}
    for name in (
        "shape-toolkit",
        "numpy",
        "scipy",
        "scikit-learn",
        "libigl",
        "potpourri3d",
        "dask",
        "distributed",
    ):
        try:
            out[name] = md.version(name)
        except md.PackageNotFoundError:
            pass
    return out


def _rss_mb() -> float:
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError):  # pragma: no cover - non-Linux
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


class MemoryMonitor:
    """Peak resident memory (MB) above the RSS at entry: exact when the block raises the
    process's high-water mark (``ru_maxrss``), otherwise the maximum of RSS samples every 5 ms."""

    def __enter__(self) -> MemoryMonitor:
        self.start = _rss_mb()
        self.max_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        self.peak = self.start
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._sample, daemon=True)
        self._t.start()
        return self

    def _sample(self) -> None:
        while not self._stop.wait(0.005):
            self.peak = max(self.peak, _rss_mb())

    def __exit__(self, *exc: Any) -> None:
        self._stop.set()
        self._t.join()
        self.peak = max(self.peak, _rss_mb())
        max_after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        if max_after > self.max_before + 0.5:
            self.peak = max(self.peak, max_after)
        self.peak_mb = max(0.0, self.peak - self.start)


def _set_cache(run_dir: str) -> None:
    from shape_toolkit.core import spectrum as spm

    spm.set_cache_dir(Path(run_dir) / "cache" / "spectra")


def prepare_job(pjob: dict) -> dict:
    """Worker: prepare one (item, corruption): corrupt, carry ground truth, fill the spectrum
    cache and geodesic rows; writes ``cache/prepared/KEY.pkl``. Never raises: errors are
    returned in ``info['error']``."""
    from shape_toolkit.bench.tasks import TASKS, get_spectrum, prepare  # noqa: F401
    from shape_toolkit.data.datasets import ItemRef, load_item

    info: dict[str, Any] = {
        "key": pjob["key"],
        "dataset": pjob["dataset"],
        "item": pjob["item"],
        "corruption": pjob["corruption"],
        "corruption_params": pjob["corruption_params"],
        "error": None,
        "pid": os.getpid(),
    }
    path = Path(pjob["run_dir"]) / "cache" / "prepared" / f"{pjob['key']}.pkl"
    info["path"] = str(path)
    t0 = time.perf_counter()
    try:
        _set_cache(pjob["run_dir"])
        if path.exists():
            with open(path, "rb") as fh:
                prep = pickle.load(fh)
            info["reused"] = True
        else:
            t1 = time.perf_counter()
            item = load_item(ItemRef(**pjob["ref"]))
            info["load_seconds"] = time.perf_counter() - t1
            prep = prepare(
                item,
                pjob["corruption"],
                pjob["corruption_params"],
                pairwise=pjob["pairwise"],
                random_state=pjob["seed"],
                truth_sample=pjob["truth_sample"],
                geodesic_method=pjob["geodesic_method"],
            )
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
            with open(tmp, "wb") as fh:
                pickle.dump(prep, fh, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(tmp, path)
            info["reused"] = False
        info["corruption_seconds"] = prep.corruption_seconds
        info["geodesic_seconds"] = prep.geodesic_seconds
        info["n_vertices"] = prep.target.n_vertices
        spectra = []
        for entry in pjob["spectra"]:
            shape = prep.target if entry["side"] == "target" else prep.source
            try:
                _, secs, hit = get_spectrum(
                    shape, entry["settings"], weighting_params=entry["weighting_params"]
                )
                spectra.append(
                    {
                        "side": entry["side"],
                        "weighting": entry["settings"]["weighting"],
                        "k": entry["settings"]["k"],
                        "seconds": secs,
                        "cache_hit": hit,
                    }
                )
            except Exception as exc:  # the rows needing it will fail with the message
                spectra.append(
                    {
                        "side": entry["side"],
                        "weighting": entry["settings"]["weighting"],
                        "error": f"{type(exc).__name__}: {exc}",
                    }
                )
        info["spectra"] = spectra
    except Exception as exc:
        info["error"] = f"{type(exc).__name__}: {exc}"
    info["seconds"] = time.perf_counter() - t0
    return info


def _load_prepared(pinfo: dict | None, job: dict):
    if pinfo is not None and pinfo.get("error"):
        raise RuntimeError(f"preparing {job['item']} ({job['corruption']}) failed: {pinfo['error']}")
    path = Path(job["run_dir"]) / "cache" / "prepared" / f"{job['pkey']}.pkl"
    if not path.exists():
        raise RuntimeError(f"prepared item missing: {path}")
    with open(path, "rb") as fh:
        return pickle.load(fh)


def _save_output(job: dict, output: dict) -> str | None:
    arrays = {k: np.asarray(v) for k, v in output.items() if isinstance(v, (np.ndarray, list))}
    if not arrays:
        return None
    d = Path(job["run_dir"]) / "outputs"
    d.mkdir(parents=True, exist_ok=True)
    path = d / f"{job['key']}.npz"
    tmp = d / f".{job['key']}.{os.getpid()}.tmp.npz"
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)
    return str(path.relative_to(job["run_dir"]))


def execute_job(job: dict, pinfo: dict | None = None) -> dict:
    """Worker: run one method on one prepared item and score it; returns the row (never raises:
    a failure becomes ``status='failed'`` with the error message)."""
    from shape_toolkit.api.registry import create_plugin
    from shape_toolkit.bench.tasks import TASKS, _with_random_state, get_spectrum

    row: dict[str, Any] = {
        "key": job["key"],
        "run": job["run"],
        "task": job["task"],
        "task_kind": job["task_kind"],
        "dataset": job["dataset"],
        "item": job["item"],
        "method": job["label"],
        "plugin": job["method"],
        "family": job["family"],
        "preset": job["preset"],
        "params": job["params"],
        "corruption": job["corruption"],
        "corruption_kind": job["corruption_kind"],
        "corruption_group": job["corruption_group"],
        "corruption_params": job["corruption_params"],
        "strength": job["strength"],
        "spectrum": job["spectrum"],
        "random_state": job["random_state"],
        "corruption_seed": job["seed"],
        "status": "ok",
        "error": None,
        "seconds": None,
        "peak_memory_mb": None,
        "metrics": {},
        "versions": package_versions(),
        "worker": f"{platform.node()}:{os.getpid()}",
        "prepare_key": job["pkey"],
    }
    t_start = time.perf_counter()
    try:
        _set_cache(job["run_dir"])
        adapter = TASKS[job["task_kind"]]
        prep = _load_prepared(pinfo, job)
        row["n_vertices"] = prep.target.n_vertices
        sides = ["target"] + (["source"] if adapter.pairwise else [])

        def _spectra() -> tuple[dict, float, bool]:
            out, secs_all, hits = {}, 0.0, []
            for side in sides:
                shape = prep.target if side == "target" else prep.source
                spec, secs, hit = get_spectrum(
                    shape, job["spectrum"], weighting_params=job["weighting_params"]
                )
                out[side] = spec
                secs_all += secs
                hits.append(hit)
            return out, secs_all, all(hits)

        detector = None
        if job.get("keypoints"):
            kp = job["keypoints"]
            detector = create_plugin("keypoints", kp["plugin"], kp.get("preset"), **(kp.get("params") or {}))
        if job["task_kind"] == "spectrum":  # the spectrum *is* the method: time it inside the row
            method = None
        elif job["family"] == "pipelines":
            from shape_toolkit.pipeline import load_pipeline

            method = load_pipeline(job["params"]["pipeline"])
            spectra, row["spectrum_seconds"], row["spectrum_cache_hit"] = _spectra()
        else:
            method = _with_random_state(
                job["family"], job["method"], job["preset"], job["params"], job["random_state"]
            )
            spectra, row["spectrum_seconds"], row["spectrum_cache_hit"] = _spectra()
        with MemoryMonitor() as mon:
            t0 = time.perf_counter()
            if job["task_kind"] == "spectrum":
                spectra, row["spectrum_seconds"], row["spectrum_cache_hit"] = _spectra()
            output = adapter.run(
                method, prep, spectra, job["options"], job["random_state"], detector=detector
            )
            row["seconds"] = time.perf_counter() - t0
        row["peak_memory_mb"] = mon.peak_mb
        t0 = time.perf_counter()
        row["metrics"] = adapter.evaluate(job["metrics"], prep, output, job["options"])
        row["metric_seconds"] = time.perf_counter() - t0
        row["output"] = _save_output(job, output)
    except Exception as exc:
        if row["seconds"] is None:
            row["seconds"] = time.perf_counter() - t_start
        row["status"] = "failed"
        row["error"] = f"{type(exc).__name__}: {exc}"
        if os.environ.get("TOOLKIT_DEBUG"):
            row["traceback"] = traceback.format_exc()
    row["total_seconds"] = time.perf_counter() - t_start
    return _jsonable(row)


# --------------------------------------------------------------------------------------------
# the results file
# --------------------------------------------------------------------------------------------
def _repair(path: Path) -> None:
    """Drop a torn last line (a crash mid-write) so appends start on a fresh line."""
    if not path.exists() or path.stat().st_size == 0:
        return
    data = path.read_bytes()
    if data.endswith(b"\n"):
        return
    cut = data.rfind(b"\n") + 1
    tmp = path.with_name(f".{path.name}.repair")
    tmp.write_bytes(data[:cut])
    os.replace(tmp, path)


def read_rows(run_dir: str | os.PathLike, name: str = RESULTS) -> list[dict]:
    """Every complete row of ``RUN_DIR/results.jsonl`` (torn or invalid lines skipped)."""
    path = Path(run_dir) / name
    rows = []
    if not path.exists():
        return rows
    for line in path.read_text().splitlines():
        line = line.strip()
        if not line:
            continue
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return rows


class _Appender:
    def __init__(self, path: Path):
        self.path = path
        _repair(path)
        self.fh = open(path, "a", encoding="utf-8")

    def write(self, row: dict) -> None:
        self.fh.write(json.dumps(row, sort_keys=False) + "\n")
        self.fh.flush()
        os.fsync(self.fh.fileno())

    def close(self) -> None:
        self.fh.close()


@dataclass
class RunSummary:
    """What a run did: rows written now, failed among all, reused (already done)."""

    rows: int
    failed: int
    reused: int
    planned: int
    seconds: float
    run_dir: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary."""
        return asdict(self)


def _drop_failed(path: Path) -> None:
    rows = read_rows(path.parent, path.name)
    keep = [r for r in rows if r.get("status") == "ok"]
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w") as fh:
        for r in keep:
            fh.write(json.dumps(r) + "\n")
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def run_benchmark(
    config: BenchConfig,
    run_dir: str | os.PathLike,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    limit: int | None = None,
    progress: bool = True,
    retry_failed: bool = False,
) -> RunSummary:
    """Run every planned row not already in ``RUN_DIR/results.jsonl``; see the module docstring."""
    if workers < 1:
        raise ParameterError(f"workers must be >= 1, got {workers}")
    if limit is not None and limit < 1:
        raise ParameterError(f"limit must be >= 1, got {limit}")
    t0 = time.perf_counter()
    run = Path(run_dir).resolve()
    run.mkdir(parents=True, exist_ok=True)
    (run / "config.json").write_text(json.dumps(_jsonable(config.raw), indent=2))
    results = run / RESULTS
    _repair(results)
    if retry_failed and results.exists():
        _drop_failed(results)
    done = {r.get("key") for r in read_rows(run)}
    jobs, preps = plan(config, run, limit=limit)
    todo = [j for j in jobs if j["key"] not in done]
    reused = len(jobs) - len(todo)
    needed = {j["pkey"] for j in todo}
    preps = {k: v for k, v in preps.items() if k in needed}
    bar = Progress(len(jobs), initial=reused, enabled=progress)
    out = _Appender(results)
    plog = _Appender(run / PREPARED)
    n_rows = n_failed = 0

    def _finish(row: dict) -> None:
        nonlocal n_rows, n_failed
        out.write(row)
        n_rows += 1
        n_failed += row["status"] != "ok"
        bar.update(failed=row["status"] != "ok")

    try:
        if scheduler is None and workers == 1:
            by_prep: dict[str, list] = {}
            for j in todo:
                by_prep.setdefault(j["pkey"], []).append(j)
            for pkey, js in by_prep.items():
                info = prepare_job(preps[pkey])
                plog.write(_jsonable(info))
                for j in js:
                    _finish(execute_job(j, info))
        else:
            _run_dask(todo, preps, workers, scheduler, _finish, plog)
    finally:
        bar.close()
        out.close()
        plog.close()
    n_failed_total = sum(r.get("status") != "ok" for r in read_rows(run))
    return RunSummary(n_rows, n_failed_total, reused, len(jobs), time.perf_counter() - t0, str(run))


def _run_dask(todo, preps, workers, scheduler, finish, plog) -> None:
    import logging

    from distributed import Client, LocalCluster, as_completed

    cluster = None
    for name in ("distributed", "distributed.worker", "distributed.scheduler", "distributed.nanny"):
        logging.getLogger(name).setLevel(logging.ERROR)
    if scheduler is None:
        cluster = LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=None,
            silence_logs=logging.ERROR,
        )
        client = Client(cluster)
    else:
        client = Client(scheduler, timeout="30s")
    try:
        # workers must import the same toolkit: forward sys.path entries of this process
        client.run(_extend_path, [p for p in sys.path if p])
        pfuts = {k: client.submit(prepare_job, p, key=f"prepare-{k}", pure=False) for k, p in preps.items()}
        rfuts = [
            client.submit(execute_job, j, pfuts[j["pkey"]], key=f"row-{j['key']}", pure=False) for j in todo
        ]
        logged: set[str] = set()
        for fut in as_completed(rfuts):
            try:
                row = fut.result()
            except Exception as exc:  # a worker died: record the row as failed, go on
                j = next(x for x in todo if f"row-{x['key']}" == fut.key)
                row = _jsonable(
                    {
                        "key": j["key"],
                        "run": j["run"],
                        "task": j["task"],
                        "dataset": j["dataset"],
                        "item": j["item"],
                        "method": j["label"],
                        "params": j["params"],
                        "corruption": j["corruption"],
                        "status": "failed",
                        "error": f"worker lost: {type(exc).__name__}: {exc}",
                        "seconds": None,
                        "peak_memory_mb": None,
                        "metrics": {},
                    }
                )
            finish(row)
            for k, pf in pfuts.items():
                if k not in logged and pf.done():
                    logged.add(k)
                    try:
                        plog.write(_jsonable(pf.result()))
                    except Exception:  # pragma: no cover
                        pass
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _extend_path(paths: list[str]) -> None:
    for p in reversed(paths):
        if p not in sys.path:
            sys.path.insert(0, p)
