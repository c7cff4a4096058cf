"""Run folders are data, one writer at a time, and rows record the spectra methods received."""

from __future__ import annotations

import json
import os
import pickle
from pathlib import Path

import numpy as np
import pytest
from helpers import bench_run, registered, segmentation_config, write_config

from shape_toolkit.api.interfaces import Segmenter
from shape_toolkit.bench import load_config, read_rows, run_benchmark, write_report
from shape_toolkit.bench.store import LOCK, BenchWarning
from shape_toolkit.cli import main
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.errors import ParameterError
from shape_toolkit.results.segmentation import Segmentation
from shape_toolkit.spectra import SpectrumSpec

CONFIG = segmentation_config("safety", limit=1)
N_ROWS = 1


def _write(tmp_path: Path, text: str = CONFIG) -> Path:
    return write_config(tmp_path, text)


# -- a run folder is data, never code ---------------------------------------------------------
class _Evil:
    """Unpickling this creates ``path`` (a stand-in for arbitrary code)."""

    def __init__(self, path: Path):
        self.path = str(path)

    def __reduce__(self):
        return (open, (self.path, "w"))


def test_planted_pickles_are_never_loaded(tmp_path, capsys):
    control = tmp_path / "control"
    pickle.loads(pickle.dumps(_Evil(control))).close()
    assert control.exists()  # the payload is live: loading it runs code

    marker = tmp_path / "PWNED"
    payload = pickle.dumps(_Evil(marker))
    config = _write(tmp_path)
    run = tmp_path / "run"
    assert bench_run(config, run) == 0
    rows = read_rows(run)
    assert len(rows) == N_ROWS and rows[0]["output"]
    # every place the old runner and report unpickled (cache/prepared/KEY.pkl), and every file
    # they read now (prepared items, cached spectra, outputs), holds a malicious pickle
    planted = []
    for r in rows:
        old = run / "cache" / "prepared" / f"{r['prepare_key']}.pkl"
        old.write_bytes(payload)
        planted.append(old)
    for folder in ("cache/prepared", "cache/spectra", "outputs"):
        for f in (run / folder).glob("*.npz"):
            f.write_bytes(payload)
            planted.append(f)
    assert len(planted) >= 4
    assert main(["bench", "report", str(run)]) == 0  # renders are skipped, the report is written
    assert (run / "report" / "index.html").exists()
    assert not marker.exists()
    (run / "results.jsonl").unlink()  # every row again: prepared items and spectra are read back
    capsys.readouterr()
    assert bench_run(config, run, "--json") == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["rows"] == N_ROWS and summary["failed"] == 0
    assert not marker.exists()
    assert all(r["status"] == "ok" for r in read_rows(run))
    assert main(["bench", "report", str(run)]) == 0
    assert not marker.exists()
    with np.load(next((run / "cache" / "prepared").glob("*.npz")), allow_pickle=False) as z:
        assert "header" in z.files  # rebuilt as a plain archive


# -- one writer per run folder ----------------------------------------------------------------
def test_second_run_on_a_locked_folder_exits_2(tmp_path, capsys):
    from filelock import FileLock

    config = _write(tmp_path)
    run = tmp_path / "run"
    run.mkdir()
    with FileLock(str(run / LOCK), timeout=0):
        assert bench_run(config, run) == 2
        err = capsys.readouterr().err.strip()
        assert "in use by another 'bench run'" in err and len(err.splitlines()) == 1
        assert not (run / "results.jsonl").exists()
    assert bench_run(config, run) == 0
    assert len(read_rows(run)) == N_ROWS


def test_garbage_lines_are_skipped_with_a_warning_and_recomputed(tmp_path, capsys):
    config = _write(tmp_path)
    run = tmp_path / "run"
    assert bench_run(config, run) == 0
    good = (run / "results.jsonl").read_text().splitlines()
    garbage = ["42", '{"broken"', "[1, 2, 3]", '{"key": 7, "status": "ok"}']
    (run / "results.jsonl").write_text("\n".join(garbage + ["[" + good[0] + "]"]) + "\n")
    with pytest.warns(BenchWarning, match="skipped 5 invalid line"):
        assert read_rows(run) == []
    with pytest.warns(BenchWarning, match="invalid line"), pytest.raises(ParameterError, match="no valid row"):
        write_report(run, renders=0)  # nothing valid to report: refused, not an empty page
    capsys.readouterr()
    assert main(["bench", "report", str(run)]) == 2
    err = capsys.readouterr().err
    assert "warning:" in err and "skipped 5 invalid line" in err and "Traceback" not in err
    assert "holds no valid row" in err
    assert bench_run(config, run, "--json") == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["rows"] == N_ROWS  # the row hidden in garbage is recomputed
    assert "skipped 5 invalid line" in captured.err
    rows = read_rows(run)  # the garbage moved aside: no warning any more
    assert len(rows) == N_ROWS and rows[0]["status"] == "ok"
    assert (run / "results.jsonl.invalid").read_text().splitlines() == garbage + ["[" + good[0] + "]"]
    assert bench_run(config, run, "--json") == 0
    assert json.loads(capsys.readouterr().out)["reused"] == N_ROWS


def test_unwritable_run_folder_is_one_line(tmp_path, capsys):
    config = _write(tmp_path)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert bench_run(config, blocker / "run") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "cannot create run folder" in err and "Traceback" not in err


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root ignores permissions")
def test_read_only_run_folder_is_one_line(tmp_path, capsys):
    config = _write(tmp_path)
    run = tmp_path / "run"
    run.mkdir()
    run.chmod(0o555)
    try:
        assert bench_run(config, run) == 2
    finally:
        run.chmod(0o755)
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not writable" in err


def test_task_name_with_slash_does_not_break_the_report(tmp_path):
    config = _write(tmp_path, CONFIG.replace('name = "seg"', 'name = "../seg/a b"'))
    run = tmp_path / "run"
    assert bench_run(config, run) == 0
    res = write_report(run, renders=1)
    figures = run / "report" / "figures"
    assert res["figures"] and all(Path(f).parent == figures for f in res["figures"])
    assert "../seg/a b" in res["html"].read_text()


def test_text_read_from_the_rows_is_escaped_in_the_report(tmp_path):
    """A task kind read back from results.jsonl is data, never markup (issue 27: stored HTML injection)."""
    config = _write(tmp_path, CONFIG)
    run = tmp_path / "run"
    assert bench_run(config, run) == 0
    rows_file = next(run.glob("results*.jsonl"))
    rows = [json.loads(x) for x in rows_file.read_text().splitlines() if x.strip()]
    for r in rows:
        r["task_kind"] = "<script>alert(1)</script>"
    rows_file.write_text("".join(json.dumps(r) + "\n" for r in rows))
    text = write_report(run, renders=0)["html"].read_text()
    assert "<script>alert(1)" not in text and "&lt;script&gt;alert(1)" in text


# -- rows record the spectra methods received -------------------------------------------------
RECEIVED: list[tuple[str, Spectrum | None]] = []


class _Recorder(Segmenter):
    """Declares a spectrum (``k``, normalized Laplacian of Gaussian weights, or none with k=0)
    and records the one it is given."""

    def __init__(self, k: int = 5):
        self.k = k

    def spectrum_spec(self):
        if self.k == 0:
            return None
        return SpectrumSpec(self.k, "gaussian", "normalized", False)

    def segment(self, shape, *, spectrum=None, constraints=None):
        RECEIVED.append((f"k={self.k}", spectrum))
        return Segmentation(np.zeros(shape.n_vertices, dtype=np.int64))


@pytest.fixture
def recorder():
    RECEIVED.clear()
    with registered("segmenters", "spectrum-recorder-test", _Recorder):
        yield


def test_row_records_the_spectrum_the_method_received(tmp_path, recorder):
    text = CONFIG.replace(
        'plugin = "spectral-clustering"\npreset = "luxburg-unnormalized"\nparams = { n_segments = 3 }',
        'plugin = "spectrum-recorder-test"\nparams = { k = [5, 9, 0] }',
    )
    cfg = load_config(_write(tmp_path, text))
    run = tmp_path / "run"
    s = run_benchmark(cfg, run, progress=False)
    rows = {f"k={r['params']['k']}": r for r in read_rows(run)}
    assert s.failed == 0 and len(rows) == 3, [r["error"] for r in rows.values()]
    given = dict(RECEIVED)
    for name in ("k=5", "k=9"):  # one eigen-solve (k=9) serves both; each gets exactly its own k
        spectrum, row = given[name], rows[name]
        assert isinstance(spectrum, Spectrum)
        received = {
            "weighting": spectrum.weighting,
            "laplacian": spectrum.laplacian,
            "k": spectrum.k,
            "use_mass": spectrum.generalized,
        }
        assert row["spectra"] == [received]
        assert received["k"] == row["params"]["k"]
        assert row["spectrum_seconds"] >= 0 and row["spectrum_cache_hit"] is True
    assert given["k=0"] is None and rows["k=0"]["spectra"] == []  # declared none, given none
    preps = [json.loads(x) for x in (run / "prepare.jsonl").read_text().splitlines()]
    assert [e["spectrum"]["k"] for p in preps for e in p["spectra"]] == [9]


class _TwoKinds(_Recorder):
    """Needs two spectra of different kinds (as a matcher with a nested descriptor does)."""

    def spectrum_specs(self):
        return [SpectrumSpec(self.k, "gaussian", "normalized", False),
                SpectrumSpec(4, "binary", "combinatorial", False)]

    def segment(self, shape, *, spectrum=None, constraints=None):
        RECEIVED.append(("two", spectrum))
        for spec in self.spectrum_specs():  # each part finds its own among what it was given
            spec.pick(spectrum, shape)
        return Segmentation(np.zeros(shape.n_vertices, dtype=np.int64))


def test_a_method_declaring_two_kinds_receives_both(tmp_path):
    RECEIVED.clear()
    with registered("segmenters", "two-kinds-test", _TwoKinds):
        text = CONFIG.replace(
            'plugin = "spectral-clustering"\npreset = "luxburg-unnormalized"\nparams = { n_segments = 3 }',
            'plugin = "two-kinds-test"\nparams = { k = 5 }',
        )
        run = tmp_path / "run"
        s = run_benchmark(load_config(_write(tmp_path, text)), run, progress=False)
        rows = read_rows(run)
        assert s.failed == 0, [r["error"] for r in rows]
        (name, given), = RECEIVED
        assert isinstance(given, list) and {g.weighting for g in given} == {"gaussian", "binary"}
        assert sorted(r["weighting"] for r in rows[0]["spectra"]) == ["binary", "gaussian"]


@pytest.mark.parametrize("address", ["notaurl", "tcp://127.0.0.1:abc", "tcp://127.0.0.1:99999", "http://x:1",
                                     "tcp://:8786"])
def test_a_bad_scheduler_address_is_one_line_and_exit_2(tmp_path, capsys, address):
    """Issue 27: these reached distributed's parser and came out as internal errors (exit 1)."""
    config = _write(tmp_path, CONFIG)
    code = main(["bench", "run", str(config), "-o", str(tmp_path / "run"), "--scheduler", address])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "scheduler address" in err, err
    assert not (tmp_path / "run").exists()  # nothing was run or written
    code = main(["track", str(config), str(config), "--dask", address])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "scheduler address" in err, err


def test_good_scheduler_addresses_pass_the_check():
    from shape_toolkit.cli.commands._common import dask_target, scheduler_address

    for a in ("tcp://127.0.0.1:8786", "tls://scheduler.example:8786", "ws://h:1"):
        assert scheduler_address(a) == a
    assert dask_target("local") == "local"
