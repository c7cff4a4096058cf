"""Compatibility module: the runner now lives in :mod:`~shape_toolkit.bench.plan` (jobs),
:mod:`~shape_toolkit.bench.worker` (prepare and row execution), :mod:`~shape_toolkit.bench.store`
(the run folder) and :mod:`~shape_toolkit.bench.executors` (local and Dask execution).
This module only re-exports their public names."""

from shape_toolkit.bench.executors import RunSummary, run_benchmark
from shape_toolkit.bench.plan import Job, PrepareJob, plan, row_key
from shape_toolkit.bench.store import PREPARED, RESULTS, Row, read_rows
from shape_toolkit.bench.worker import execute_job, prepare_job

__all__ = [
    "RunSummary",
    "run_benchmark",
    "Job",
    "PrepareJob",
    "Row",
    "plan",
    "row_key",
    "read_rows",
    "prepare_job",
    "execute_job",
    "RESULTS",
    "PREPARED",
]
