"""Run a plan: in process (``workers == 1``), on a local Dask cluster (``workers > 1``: processes,
one thread each, loopback) or on an existing Dask scheduler (``scheduler="tcp://..."``; the run
folder must then be on a filesystem the workers share).

One ``bench run`` writes a run folder at a time (an OS-level lock); rows already in
``results.jsonl`` are skipped (ok or failed; ``retry_failed`` re-runs failed ones). Prepare jobs
run first; with Dask, row jobs depend on their prepare job, so shared work is done once per run
even across workers. Only the runner process writes the files.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import CancelledError
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from shape_toolkit.bench.config import BenchConfig
from shape_toolkit.bench.plan import Job, PrepareJob, plan
from shape_toolkit.bench.progress import Progress
from shape_toolkit.bench.store import (
    PREPARED,
    RESULTS,
    SPLIT,
    WRITE_ERRNOS,
    Appender,
    RunFolderError,
    RunStoppedError,
    claim_run_folder,
    clean_results,
    read_rows,
    run_lock,
    set_aside_rows,
    write_planned,
)
from shape_toolkit.bench.worker import execute_job, lost_row, prepare_job
from shape_toolkit.errors import ParameterError, ShapeFileError
from shape_toolkit.validation import atomic_output, dumps_json, shown_value

__all__ = ["RunSummary", "run_benchmark", "run_local", "run_dask", "dask_client"]


@dataclass
class RunSummary:
    """What a run did: rows written now, failed among all rows of the folder, reused (already
    done), planned, wall seconds, the run folder."""

    rows: int
    failed: int
    reused: int
    planned: int
    seconds: float
    run_dir: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary."""
        return asdict(self)


_WRITE_ERRORS = WRITE_ERRNOS
#: what losing the scheduler raises (CommClosedError is an OSError; futures cancelled on a lost
#: connection raise CancelledError)
_LOST = (OSError, TimeoutError, CancelledError)
#: seconds a Dask run waits with no worker before it stops (``bench run --worker-timeout``)
WORKER_TIMEOUT = 60.0


def _open_run_dir(run_dir: str | os.PathLike) -> Path:
    run = Path(run_dir).resolve()
    try:
        run.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RunFolderError(f"cannot create run folder {run}: {exc.strerror or exc}") from None
    if not os.access(run, os.W_OK | os.X_OK):
        raise RunFolderError(f"run folder {run} is not writable")
    return run


def max_local_workers() -> int:
    """The most local Dask workers ``bench run --workers`` starts: 4 per core, at least 8 (each is a process with
    its own memory; thousands would exhaust the machine before the first row)."""
    return max(8, 4 * (os.cpu_count() or 1))


def run_benchmark(
    config: BenchConfig,
    run_dir: str | os.PathLike,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    limit: int | None = None,
    progress: bool = True,
    retry_failed: bool = False,
    worker_timeout: float = WORKER_TIMEOUT,
    rerun: Sequence[str] = (),
) -> RunSummary:
    """Run every planned row not already in ``RUN_DIR/results.jsonl``; see the module docstring. ``rerun``: method
    labels whose planned rows are computed again (after a change of code the config cannot see); their former rows
    move to ``results.jsonl.replaced``; a label the config does not plan is a :class:`ParameterError`.
    :class:`~shape_toolkit.bench.store.RunFolderError` when the folder is locked by another run
    or not writable; :class:`~shape_toolkit.bench.store.RunStoppedError` when a transient fault
    (an unwritable folder, a lost worker or scheduler, ``worker_timeout`` seconds without a Dask
    worker) stopped it: the rows it did not finish are not recorded."""
    most = max_local_workers()
    if isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= most:
        raise ParameterError(f"workers must be an integer in [1, {most}] (local worker processes: up to 4 per core, "
                             f"this machine has {os.cpu_count() or 1}; 8 always allowed), got {shown_value(workers)}")
    if limit is not None and limit < 1:
        raise ParameterError(f"limit must be >= 1, got {limit}")
    if not worker_timeout > 0:
        raise ParameterError(f"worker_timeout must be > 0 seconds, got {worker_timeout}")
    t0 = time.perf_counter()
    run = _open_run_dir(run_dir)
    with run_lock(run):
        try:
            return _run_locked(config, run, t0, workers, scheduler, limit, progress, retry_failed, worker_timeout,
                               tuple(rerun))
        except OSError as exc:
            if exc.errno not in _WRITE_ERRORS:
                raise
            raise RunFolderError(f"cannot write to run folder {run}: {exc.strerror or exc}") from None


def _run_locked(config, run, t0, workers, scheduler, limit, progress, retry_failed, worker_timeout,
                rerun=()) -> RunSummary:
    claim_run_folder(run)
    results = run / RESULTS
    try:
        with atomic_output(run / "config.json", "run config") as tmp:
            tmp.write_text(dumps_json(config.raw, indent=2))
        if config.split is not None:  # which half of which split the rows are (the report says so)
            with atomic_output(run / SPLIT, "run split") as tmp:
                tmp.write_text(dumps_json(config.split, indent=2))
        elif (run / SPLIT).exists():
            (run / SPLIT).unlink()
        clean_results(results, keep_failed=not retry_failed)
        clean_results_log(run / PREPARED)
    except ShapeFileError as exc:  # atomic_output's typed write failure, as the OSError below
        raise RunFolderError(f"cannot write to run folder {run}: {exc.problem}") from None
    jobs, preps = plan(config, run, limit=limit)
    if rerun:
        labels = sorted({j.method_label for j in jobs})
        unknown = [r for r in rerun if r not in labels]
        if unknown:
            raise ParameterError(f"--rerun {unknown[0]!r}: not a method label of this config; its labels: "
                                 + ", ".join(repr(x) for x in labels))
        set_aside_rows(results, {j.key for j in jobs if j.method_label in rerun})
    done = {r["key"] for r in read_rows(run)}
    try:  # what this config plans: a report shows these rows, not those an earlier config left in the folder
        write_planned(run, [j.key for j in jobs])
    except ShapeFileError as exc:
        raise RunFolderError(f"cannot write to run folder {run}: {exc.problem}") from None
    todo = [j for j in jobs if j.key not in done]
    reused = len(jobs) - len(todo)
    needed = {j.prepare_key for j in todo}
    preps = {k: v for k, v in preps.items() if k in needed}
    bar = Progress(len(jobs), initial=reused, enabled=progress)
    out = Appender(results)
    plog = Appender(run / PREPARED)
    n_rows = 0

    def stop(why: str) -> None:
        raise RunStoppedError(
            f"run stopped, {why}; {n_rows} rows written this time are kept, run the same command again to resume"
        )

    def finish(row: dict) -> None:
        nonlocal n_rows
        if row.get("transient"):  # the environment failed, not the method: never a result
            stop(row["transient"])
        out.write(row)
        n_rows += 1
        bar.update(failed=row["status"] != "ok")

    def log(info: dict) -> None:
        if info.get("transient"):
            stop(info["transient"])
        plog.write(info)

    try:
        if scheduler is None and workers == 1:
            run_local(todo, preps, finish, log)
        else:
            run_dask(todo, preps, workers, scheduler, finish, log, worker_timeout)
    finally:
        bar.close()
        out.close()
        plog.close()
    n_failed_total = sum(r["status"] != "ok" for r in read_rows(run, planned_only=True))
    return RunSummary(n_rows, n_failed_total, reused, len(jobs), time.perf_counter() - t0, str(run))


def clean_results_log(path: Path) -> None:
    """Drop a torn last line of the prepare log so appends start on a fresh line."""
    if not path.exists() or path.stat().st_size == 0:
        return
    data = path.read_bytes()
    if data.endswith(b"\n"):
        return
    cut = data.rfind(b"\n") + 1
    with atomic_output(path, "prepare log") as tmp:
        tmp.write_bytes(data[:cut])


def run_local(
    todo: list[Job], preps: dict[str, PrepareJob], finish: Callable[[dict], None], log: Callable[[dict], None]
) -> None:
    """In process: each prepare job, then its rows; with one BLAS thread, as in a Dask worker, so
    that results (near-degenerate eigenvectors are sensitive to it) and timings do not depend on
    how a run is executed."""
    from threadpoolctl import threadpool_limits

    from shape_toolkit.core import spectrum as spm

    by_prep: dict[str, list[Job]] = {}
    for j in todo:
        by_prep.setdefault(j.prepare_key, []).append(j)
    before = spm._CACHE_DIR  # the jobs point the spectrum cache at the run folder: restored after
    try:
        with threadpool_limits(limits=1):
            for pkey, js in by_prep.items():
                info = prepare_job(preps[pkey])
                log(info)
                for j in js:
                    finish(execute_job(j, info))
    finally:
        spm._CACHE_DIR = before


def run_dask(
    todo: list[Job],
    preps: dict[str, PrepareJob],
    workers: int,
    scheduler: str | None,
    finish: Callable[[dict], None],
    log: Callable[[dict], None],
    worker_timeout: float = WORKER_TIMEOUT,
) -> None:
    """On a local Dask cluster of ``workers`` processes, or on the scheduler at ``scheduler``.
    :class:`RunStoppedError` when the scheduler has had no worker for ``worker_timeout`` seconds
    or is lost; a row whose worker died is not recorded (``finish`` stops the run on it)."""
    from distributed import wait

    where = f"the Dask scheduler at {scheduler}" if scheduler else "the local Dask cluster"
    with dask_client(workers, scheduler, worker_timeout) as client:
        try:
            pfuts = {k: client.submit(prepare_job, p, key=f"prepare-{k}", pure=False) for k, p in preps.items()}
            by_key = {f"row-{j.key}": j for j in todo}
            pending = {
                client.submit(execute_job, j, pfuts[j.prepare_key], key=f"row-{j.key}", pure=False) for j in todo
            }
            logged: set[str] = set()
            while pending:
                try:
                    done, pending = wait(pending, timeout=worker_timeout, return_when="FIRST_COMPLETED")
                except TimeoutError:  # nothing finished for a while: fine, unless no worker is left
                    if not client.scheduler_info().get("workers"):
                        raise RunStoppedError(
                            f"{where} has had no worker for {worker_timeout:g} s; the rows finished so far are "
                            "kept: start workers and run the same command again"
                        ) from None
                    continue
                for fut in done:
                    try:
                        row = fut.result()
                    except _LOST:
                        raise
                    except Exception as exc:  # the worker died (KilledWorker): transient, not a result
                        row = lost_row(by_key[fut.key], exc)
                    finish(row)
                for k, pf in pfuts.items():
                    if k not in logged and pf.done():
                        logged.add(k)
                        try:
                            log(pf.result())
                        except RunStoppedError:
                            raise
                        except Exception as exc:  # the worker died while preparing: its rows say so
                            log({"key": k, "error": f"worker lost: {type(exc).__name__}: {exc}", "spectra": []})
        except _LOST as exc:
            raise RunStoppedError(
                f"lost {where} ({type(exc).__name__}); the rows finished so far are kept: run the same command "
                "again to resume"
            ) from None


@contextmanager
def dask_client(
    workers: int = 2, scheduler: str | None = None, worker_timeout: float = WORKER_TIMEOUT
) -> Iterator[Any]:
    """A ``distributed.Client``: on a local cluster of ``workers`` processes (one thread each,
    loopback, no dashboard) or on the scheduler at ``scheduler`` (``tcp://host:port``), which must
    have a worker within ``worker_timeout`` seconds (else :class:`RunStoppedError`); workers get
    this process's ``sys.path`` so they import the same toolkit. Closed (and the local cluster
    shut down) on exit."""
    import logging

    from distributed import Client, LocalCluster

    cluster = None
    for name in ("distributed", "distributed.worker", "distributed.scheduler", "distributed.nanny",
                 "distributed.client", "distributed.core", "distributed.comm"):
        logging.getLogger(name).setLevel(logging.CRITICAL)
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
        try:
            client = Client(scheduler, timeout="30s")
        except (OSError, TimeoutError) as exc:
            raise RunStoppedError(f"cannot reach the Dask scheduler at {scheduler}: {type(exc).__name__}") from None
    try:
        if scheduler is not None:
            try:
                client.wait_for_workers(1, timeout=worker_timeout)
            except TimeoutError:
                raise RunStoppedError(
                    f"the Dask scheduler at {scheduler} has no worker after {worker_timeout:g} s; start workers "
                    "(dask worker ADDRESS) or raise --worker-timeout"
                ) from None
        client.run(_extend_path, [p for p in sys.path if p])
        yield client
    finally:
        with contextlib.suppress(Exception):  # a lost scheduler: closing must not mask the reason
            client.close(timeout=5)
        if cluster is not None:
            with contextlib.suppress(Exception):
                cluster.close(timeout=10)


def _extend_path(paths: list[str]) -> None:
    for p in reversed(paths):
        if p not in sys.path:
            sys.path.insert(0, p)

