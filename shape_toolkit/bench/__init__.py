"""Benchmark runs: TOML configs -> one result row per (item, method, parameters) -> reports.

``load_config`` validates a config before any work (errors name the bad key), ``run_benchmark``
executes it locally, on a local Dask cluster (``workers > 1``) or on an existing Dask scheduler,
appending rows to ``RUN_DIR/results.jsonl`` as they finish, and ``write_report`` turns a run
folder into an HTML page with PNG figures.

Modules: ``config`` (TOML -> validated specs), ``plan`` (jobs), ``tasks`` (adapters and metrics),
``worker`` (prepare and row execution), ``store`` (the run folder: rows, cache, lock),
``executors`` (local and Dask), ``report``.
"""

from shape_toolkit.bench.config import BenchConfig, ConfigError, load_config
from shape_toolkit.bench.executors import RunSummary, run_benchmark
from shape_toolkit.bench.store import read_rows

__all__ = [
    "BenchConfig",
    "ConfigError",
    "load_config",
    "RunSummary",
    "read_rows",
    "run_benchmark",
    "write_report",
]


def write_report(run_dir, **kwargs):  # noqa: ANN001, ANN201 - thin lazy wrapper
    """Write ``RUN_DIR/report/index.html`` and PNG figures (see :func:`shape_toolkit.bench.report.write_report`)."""
    from shape_toolkit.bench.report import write_report as _w

    return _w(run_dir, **kwargs)
