"""A transient failure is not a result (issue 27): a refused write or a scheduler without
workers stops the run with one line and exit 3; nothing is recorded for the rows it did not
finish, and running the same command again resumes."""

from __future__ import annotations

import errno
from pathlib import Path

import numpy as np
import pytest
from helpers import bench_run, registered, segmentation_config, write_config

from shape_toolkit.bench import read_rows
from shape_toolkit.results.segmentation import Segmentation

CONFIG = segmentation_config("transient", limit=2, subdivisions=1, metrics='"n_segments"',
                             methods='[[tasks.methods]]\nplugin = "{plugin}"\n')

FAULT = {"on": False, "path": ""}


class _Flaky:
    """Segments everything as one part, or meets a refused write while FAULT is on."""

    def get_params(self, deep=True):
        return {}

    def set_params(self, **params):
        return self

    def segment(self, shape, *, spectrum=None, constraints=None):
        if FAULT["on"]:
            raise PermissionError(errno.EACCES, "Permission denied", FAULT["path"])
        return Segmentation(np.zeros(shape.n_vertices, dtype=np.int64))


@pytest.fixture
def flaky():
    with registered("segmenters", "flaky-write-test", _Flaky):
        yield
    FAULT["on"] = False


def _run(tmp_path: Path, run: Path, plugin: str, *extra: str) -> int:
    return bench_run(write_config(tmp_path, CONFIG.replace("{plugin}", plugin)), run, *extra)


def test_a_refused_write_stops_the_run_and_records_nothing(tmp_path, capsys, flaky):
    run = tmp_path / "run"
    FAULT.update(on=True, path=str(run / "outputs" / "x.npz"))
    assert _run(tmp_path, run, "flaky-write-test") == 3
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "run stopped" in err and "Permission denied" in err
    assert read_rows(run) == []  # not a failed row: nothing to retry by hand
    FAULT["on"] = False
    assert _run(tmp_path, run, "flaky-write-test") == 0  # the same command resumes
    rows = read_rows(run)
    assert len(rows) == 2 and all(r["status"] == "ok" for r in rows)


def test_a_scheduler_without_workers_times_out_with_one_line(tmp_path, capsys):
    from distributed import LocalCluster

    no_workers = {"n_workers": 0, "processes": False, "protocol": "tcp", "host": "127.0.0.1"}
    with LocalCluster(**no_workers, dashboard_address=None) as cluster:
        code = _run(tmp_path, tmp_path / "run", "spectral-clustering", "--scheduler", cluster.scheduler_address,
                    "--worker-timeout", "2")
    assert code == 3
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no worker" in err, err
    assert read_rows(tmp_path / "run") == []


@pytest.mark.parametrize("bad", ["0", "-1", "nan", "soon"])
def test_a_bad_worker_timeout_is_one_line_and_exit_2(tmp_path, capsys, bad):
    assert _run(tmp_path, tmp_path / "run", "spectral-clustering", "--worker-timeout", bad) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
