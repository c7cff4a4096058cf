"""Worker side: prepare one (item, corruption), run one row; both never raise.

Spectra flow down: a row asks its method (the plugin, its keypoint detector, or the pipeline)
for the spectra it declares, takes each from the cache the prepare stage filled (the merged,
larger spectrum of the same kind, truncated to exactly what was declared), times that as
``spectrum_seconds`` and passes them in; ``row.spectra`` records what the method received.
"""

from __future__ import annotations

import hashlib
import os
import platform
import resource
import subprocess
import threading
import time
import traceback
import warnings
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path
from typing import Any

from shape_toolkit.bench.plan import Job, PrepareJob, create_detector, create_method
from shape_toolkit.bench.store import (
    BenchWarning,
    Row,
    load_prepared,
    prepared_path,
    save_output,
    save_prepared,
    transient_problem,
)

__all__ = [
    "package_versions", "cpu_model", "machine_info", "blas_threads", "code_revision", "revision_label", "MemoryMonitor",
    "prepare_job", "execute_job", "lost_row", "input_digest",
]


@lru_cache(maxsize=1)
def package_versions() -> dict[str, str]:
    """Versions of the toolkit and the main numerical packages in this process."""
    import importlib.metadata as md

    out = {"python": platform.python_version()}
    for name in ("shape-toolkit", "numpy", "scipy", "scikit-learn", "libigl", "potpourri3d", "dask", "distributed"):
        try:
            out[name] = md.version(name)
        except md.PackageNotFoundError:
            pass
    return out


@lru_cache(maxsize=1)
def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``; else what :mod:`platform` knows), for benchmark reports."""
    model = platform.processor() or platform.machine() or "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return model


def machine_info() -> dict[str, Any]:
    """This machine for benchmark reports: ``{"cpu": model, "cores": n, "python": version, "blas":
    ["openblas 2 threads", ...]}`` (this process's BLAS libraries, identical entries once: numpy and
    scipy may each bundle the same OpenBLAS; ``["unknown"]`` without threadpoolctl)."""
    try:
        from threadpoolctl import threadpool_info

        blas = list(dict.fromkeys(f"{i.get('internal_api')} {i.get('num_threads')} threads"
                                  for i in threadpool_info() if i.get("user_api") == "blas"))
    except Exception:  # pragma: no cover - informational only
        blas = []
    return {"cpu": cpu_model(), "cores": os.cpu_count(), "python": platform.python_version(),
            "blas": blas or ["unknown"]}


#: the file an exported tree (``git archive COMMIT shape_toolkit``) carries beside ``shape_toolkit/``,
#: holding the commit it was exported from
EXPORTED_COMMIT = "EXPORTED_COMMIT"
#: seconds any one git call may take before :func:`code_revision` gives up on it
GIT_TIMEOUT = 20.0


def _git(root: Path, *args: str) -> str | None:
    """``git -C root ARGS``'s stdout, or None when git is missing, fails or times out. Optional
    locks are off: reading the state must not hold ``index.lock`` while others commit."""
    env = dict(os.environ, GIT_OPTIONAL_LOCKS="0", LC_ALL="C")
    try:
        res = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True,
                             timeout=GIT_TIMEOUT, check=False, env=env, stdin=subprocess.DEVNULL)
    except (OSError, subprocess.SubprocessError, ValueError):
        return None
    return res.stdout if res.returncode == 0 else None


def code_revision(repo: Path | None = None, paths: Sequence[str] | None = None) -> dict[str, Any]:
    """Which code produced a result, for benchmark reports; never raises.

    ``repo``: a directory inside the git work tree (default: the tree this ``shape_toolkit`` is
    imported from). Returns ``{"commit": HEAD's hash, 12 hex characters, "dirty": bool,
    "dirty_files": [paths relative to the top level]}``; dirty means *tracked* files differ from HEAD
    (staged or not; untracked files do not count), only under ``paths`` (relative to the top level,
    e.g. ``["shape_toolkit"]``) when given. A tree exported with ``git archive`` and the commit written
    to ``EXPORTED_COMMIT`` beside ``shape_toolkit/`` (put first on ``PYTHONPATH``) gives that commit,
    clean, plus ``"exported_to"`` (also when ``repo`` holds that file). ``"commit": "unknown"`` (not
    dirty) when git is missing, times out (:data:`GIT_TIMEOUT` per call) or the directory is not in a
    repository; dirty with ``["(git status failed)"]`` when only the comparison with HEAD fails.
    """
    root = Path(repo) if repo is not None else Path(__file__).resolve().parents[2]
    try:
        exported = (root / EXPORTED_COMMIT).read_text(encoding="utf-8").split()
    except (OSError, UnicodeDecodeError):
        exported = []
    if exported:
        return {"commit": exported[0][:12], "dirty": False, "dirty_files": [], "exported_to": str(root)}
    head = (_git(root, "rev-parse", "--verify", "HEAD") or "").strip()
    if len(head) < 12 or any(c not in "0123456789abcdef" for c in head):
        return {"commit": "unknown", "dirty": False, "dirty_files": []}
    spec = [f":(top){p}" for p in paths] if paths else [":(top)"]
    status = _git(root, "status", "--porcelain", "-z", "--untracked-files=no", "--", *spec)
    if status is None:  # HEAD is known, its comparison with the tree is not: say so, do not claim clean
        return {"commit": head[:12], "dirty": True, "dirty_files": ["(git status failed)"]}
    files: set[str] = set()
    entries = iter(status.split("\0"))
    for entry in entries:  # "XY path"; a rename or copy is followed by its source path
        if len(entry) > 3:
            files.add(entry[3:])
            if entry[0] in "RC":
                next(entries, None)
    return {"commit": head[:12], "dirty": bool(files), "dirty_files": sorted(files)}


def revision_label(rev: dict[str, Any] | None) -> str:
    """``"abc123def456"``, ``"... + uncommitted edits in a.py, b.py"``, or ``"not recorded"``, from a
    :func:`code_revision` dict or an older record (``dirty`` as the list of files, no ``dirty_files``)."""
    if not rev or not rev.get("commit"):
        return "not recorded"
    dirty = rev.get("dirty")
    files = rev.get("dirty_files") or (dirty if isinstance(dirty, list) else [])
    if files:
        return f"{rev['commit']} + uncommitted edits in {', '.join(map(str, files))}"
    return f"{rev['commit']} + uncommitted edits" if dirty else str(rev["commit"])


def _rss_mb() -> float:
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError):  # pragma: no cover - non-Linux
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


class MemoryMonitor:
    """Peak memory (MB) of a block. ``traced=False``: resident memory above the RSS at entry, exact
    when the block raises the process's high-water mark (``ru_maxrss``), otherwise the maximum of RSS
    samples every 5 ms (memory freed earlier and reused is not counted). ``traced=True``: the peak of
    the allocations ``tracemalloc`` traces during the block (Python objects and NumPy arrays, native
    libraries' own buffers not), whatever was freed before."""

    def __init__(self, traced: bool = False):
        self.traced = traced

    def __enter__(self) -> MemoryMonitor:
        self.peak_mb = 0.0
        if self.traced:
            import tracemalloc

            self._was_tracing = tracemalloc.is_tracing()
            if not self._was_tracing:
                tracemalloc.start()
            tracemalloc.reset_peak()
            self._base = tracemalloc.get_traced_memory()[0]
            return self
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
        if self.traced:
            import tracemalloc

            peak = tracemalloc.get_traced_memory()[1]
            if not self._was_tracing:
                tracemalloc.stop()
            self.peak_mb = max(0.0, (peak - self._base) / 2**20)
            return
        self._stop.set()
        self._t.join()
        self.peak = max(self.peak, _rss_mb())
        max_after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        if max_after > self.max_before + 0.5:
            self.peak = max(self.peak, max_after)
        self.peak_mb = max(0.0, self.peak - self.start)


def blas_threads() -> int | None:
    """The threads of this process's BLAS libraries (the largest, when there are several; threadpoolctl),
    or None when unknown: recorded per row, since one or two BLAS threads change a solver's timings."""
    try:
        from threadpoolctl import threadpool_info

        n = [int(i["num_threads"]) for i in threadpool_info() if i.get("user_api") == "blas"]
    except Exception:  # pragma: no cover - informational only
        return None
    return max(n) if n else None


def _set_cache(run_dir: str) -> None:
    from shape_toolkit.core import spectrum as spm

    spm.set_cache_dir(Path(run_dir) / "cache" / "spectra")


def _error(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"


def input_digest(ref: dict[str, Any]) -> str:
    """SHA-1 over the contents of every file an item reference names (``ref['paths']``, nested
    lists and tables included), in a fixed order: a prepared item is valid for these bytes only."""
    h = hashlib.sha1()

    def walk(v: Any) -> None:
        if isinstance(v, dict):
            for k in sorted(v):
                h.update(str(k).encode())
                walk(v[k])
        elif isinstance(v, (list, tuple)):
            for x in v:
                walk(x)
        elif isinstance(v, (str, os.PathLike)) and os.path.isfile(v):
            with open(v, "rb") as f:
                for block in iter(lambda: f.read(1 << 20), b""):
                    h.update(block)
        else:
            h.update(repr(v).encode())

    walk(ref.get("paths") or {})
    return h.hexdigest()


def _prepare_item(pjob: PrepareJob, info: dict[str, Any]):
    """The prepared item from the cache when it is there and holds this job's key and inputs,
    else prepared and cached (a damaged or foreign file is reported once on stderr)."""
    from shape_toolkit.bench.tasks import prepare
    from shape_toolkit.data.datasets import ItemRef, load_item

    path = prepared_path(pjob.run_dir, pjob.key)
    info["path"] = str(path)
    inputs = input_digest(pjob.ref)
    if path.exists():
        try:
            prep = load_prepared(path, key=pjob.key, inputs=inputs)
            info["reused"] = True
            return prep
        except ValueError as exc:  # unreadable or tampered with: prepare it again
            info["cache_problem"] = str(exc)
            warnings.warn(f"prepared item {path} ignored ({exc}); preparing it again", BenchWarning, stacklevel=2)
    t1 = time.perf_counter()
    item = load_item(ItemRef(**pjob.ref))
    info["load_seconds"] = time.perf_counter() - t1
    prep = prepare(
        item,
        pjob.corruption_kind,
        pjob.corruption_params,
        pairwise=pjob.pairwise,
        random_state=pjob.seed,
        truth_sample=pjob.truth_sample,
        geodesic_method=pjob.geodesic_method,
        score_on=pjob.score_on,
        target=pjob.target,
        truth_points=pjob.truth_points,
        corrupt=pjob.corrupt,
    )
    save_prepared(path, prep, key=pjob.key, inputs=inputs)
    info["reused"] = False
    return prep


def prepare_job(pjob: PrepareJob) -> dict[str, Any]:
    """Prepare one (item, corruption): corrupt, carry ground truth, geodesic rows, and compute
    the declared spectra into the cache; writes ``cache/prepared/KEY.npz``. Never raises:
    errors are returned in ``info['error']``."""
    from shape_toolkit.bench.tasks import compute_spectrum_cached

    info: dict[str, Any] = {
        "key": pjob.key,
        "dataset": pjob.dataset,
        "item": pjob.item,
        "corruption": pjob.corruption_kind,
        "corruption_params": pjob.corruption_params,
        "error": None,
        "pid": os.getpid(),
    }
    t0 = time.perf_counter()
    try:
        _set_cache(pjob.run_dir)
        prep = _prepare_item(pjob, info)
        info["corruption_seconds"] = prep.corruption_seconds
        info["geodesic_seconds"] = prep.geodesic_seconds
        info["n_vertices"] = prep.target.n_vertices
        spectra = []
        for spec in pjob.specs:
            for side in pjob.sides:
                shape = getattr(prep, side)
                entry: dict[str, Any] = {"side": side, "spectrum": spec.for_shape(shape).to_dict()}
                t1 = time.perf_counter()
                try:
                    _, entry["cache_hit"] = compute_spectrum_cached(spec, shape)
                    entry["seconds"] = time.perf_counter() - t1
                except Exception as exc:  # the rows needing it fail with the message
                    entry["error"] = _error(exc)
                spectra.append(entry)
        info["spectra"] = spectra
    except Exception as exc:
        info["error"] = _error(exc)
        if (why := transient_problem(exc, pjob.run_dir)) is not None:
            info["transient"] = why
    info["seconds"] = time.perf_counter() - t0
    return info


def _load_prepared(job: Job, pinfo: dict | None):
    if pinfo is not None and pinfo.get("error"):
        raise RuntimeError(f"preparing {job.item} ({job.corruption}) failed: {pinfo['error']}")
    path = prepared_path(job.run_dir, job.prepare_key)
    if not path.exists():
        raise RuntimeError(f"prepared item missing: {path}")
    try:
        return load_prepared(path, key=job.prepare_key)
    except ValueError as exc:
        raise RuntimeError(str(exc)) from None


def _new_row(job: Job) -> Row:
    return Row(**job.identity(), category=job.category, item_params=dict(job.item_params))


def lost_row(job: Job, exc: BaseException) -> dict[str, Any]:
    """The row of a job whose worker died: transient, never recorded (the run stops, and
    running it again retries the row)."""
    return {"key": job.key, "transient": f"a worker running {job.item} ({job.method_label or job.plugin}) "
            f"was lost ({type(exc).__name__}), e.g. killed for memory; try fewer --workers"}


class _Received:
    """Spectra handed to a method, and what the row records about them."""

    def __init__(self, job: Job, prep: Any, sides: tuple[str, ...]):
        self.job, self.prep, self.sides = job, prep, sides
        self.seconds = 0.0
        self.hits: list[bool] = []
        self.records: list[dict[str, Any]] = []

    def _one(self, spec, side: str):
        from shape_toolkit.bench.tasks import received_spec, spectrum_for

        shape = getattr(self.prep, side)
        t0 = time.perf_counter()
        spectrum, hit = spectrum_for(spec, shape, self.job.item_specs)
        self.seconds += time.perf_counter() - t0
        self.hits.append(hit)
        rec = received_spec(spec, shape)
        if rec not in self.records:
            self.records.append(rec)
        return spectrum

    def single(self, spec) -> dict[str, Any]:
        """``{side: Spectrum or None}`` for a plugin declaring ``spec`` (None: no spectrum)."""
        return {side: (self._one(spec, side) if spec is not None else None) for side in self.sides}

    def several(self, specs) -> dict[str, list]:
        """``{side: [Spectrum, ...]}`` for a pipeline declaring ``specs``."""
        return {side: [self._one(s, side) for s in specs] for side in self.sides}


def execute_job(job: Job, pinfo: dict | None = None) -> dict[str, Any]:
    """Run one method on one prepared item and score it; returns the row as a dict (never raises:
    a failure becomes ``status='failed'`` with the error message)."""
    from shape_toolkit.bench.tasks import TASKS, compute_spectrum_cached, method_specs, received_spec

    if pinfo is not None and pinfo.get("transient"):
        return {"key": job.key, "transient": pinfo["transient"]}
    row = _new_row(job)
    row.versions = package_versions()
    row.worker = f"{platform.node()}:{os.getpid()}"
    t_start = time.perf_counter()
    try:
        _set_cache(job.run_dir)
        adapter = TASKS[job.task_kind]
        prep = _load_prepared(job, pinfo)
        row.n_vertices = prep.target.n_vertices
        sides = ("target", "source") if adapter.pairwise else ("target",)
        detector = method = None
        spectra: dict[str, Any] = {}
        detector_spectra = None
        if job.subject_spectrum is None:
            params = {**job.params, **job.item_params}
            method = create_method(job.family, job.plugin, job.preset, params, job.random_state)
            detector = create_detector(job.keypoints)
            own, det_spec = method_specs(method, detector) if adapter.uses_spectra else ([], None)
            got = _Received(job, prep, sides)
            if job.family == "pipelines" or len(own) > 1:  # several kinds: each part picks its own
                spectra = got.several(own)
            else:
                spectra = got.single(own[0] if own else None)
            if detector is not None:
                detector_spectra = got.single(det_spec)
            row.spectra = got.records
            row.spectrum_seconds = got.seconds
            row.spectrum_cache_hit = all(got.hits) if got.hits else None
        from threadpoolctl import threadpool_limits

        row.repeats = int(job.options.get("repeats", 1))
        best = peak = None
        limit = job.options.get("blas_threads")  # None: as the runner set it (one thread)
        traced = job.options.get("memory") == "traced"
        for _ in range(row.repeats):  # best of N: the fastest run's times, the largest peak
            with threadpool_limits(limits=limit, user_api="blas"), MemoryMonitor(traced) as mon:
                row.blas_threads = blas_threads()
                t0, c0 = time.perf_counter(), time.process_time()
                if job.subject_spectrum is not None:  # the spectrum *is* the result: timed as the method
                    spec = job.subject_spectrum
                    solver = None
                    if job.solver is not None:  # an eigensolver peer computes the same spectrum
                        from shape_toolkit.bench.peers import create_spectrum_peer

                        solver = create_spectrum_peer(job.solver)
                    # solved afresh: a cached spectrum would time a lookup, not the solver
                    spectra["target"], row.spectrum_cache_hit = compute_spectrum_cached(spec, prep.target, solver,
                                                                                        cache=False)
                    row.spectra = [received_spec(spec, prep.target)]
                    solved = time.perf_counter() - t0
                output = adapter.run(
                    method, prep, spectra, job.options, job.random_state,
                    detector=detector, detector_spectra=detector_spectra,
                )
                seconds = time.perf_counter() - t0
                cpu = time.process_time() - c0  # the process's CPU (all its threads)
            peak = mon.peak_mb if peak is None else max(peak, mon.peak_mb)
            if best is None or seconds < best:
                best, row.seconds, row.cpu_seconds = seconds, seconds, cpu
                if job.subject_spectrum is not None:
                    row.spectrum_seconds = solved
        row.peak_memory_mb = peak
        if output.pop("published", False):  # a map no method computed here (a file, the ground truth): no cost
            row.seconds = row.cpu_seconds = row.peak_memory_mb = None
        t0 = time.perf_counter()
        if job.options.get("metric_costs"):  # the metrics are the subject: their peak memory too
            c0 = time.process_time()
            with MemoryMonitor(traced) as mon:
                row.metrics = adapter.evaluate(job.metrics, prep, output, job.options)
            row.metric_peak_memory_mb, row.metric_cpu_seconds = mon.peak_mb, time.process_time() - c0
        else:
            row.metrics = adapter.evaluate(job.metrics, prep, output, job.options)
        row.metric_seconds = time.perf_counter() - t0
        row.output = save_output(job.run_dir, job.key, output)
    except Exception as exc:
        if (why := transient_problem(exc, job.run_dir)) is not None:
            return {"key": job.key, "transient": why}
        if row.seconds is None:
            row.seconds = time.perf_counter() - t_start
        row.status = "failed"
        row.error = _error(exc)
        if os.environ.get("TOOLKIT_DEBUG"):
            row.traceback = traceback.format_exc()
    row.total_seconds = time.perf_counter() - t_start
    return row.to_dict()
