"""Progress on long work (issue 15): shown on a terminal (or when forced with
SHAPE_TOOLKIT_PROGRESS=1), absent under --json and --quiet, and never printed by library code."""

from __future__ import annotations

import os
import pty
import subprocess
import sys
import threading

import numpy as np
import pytest
from helpers import articulated_pair_files, run_cli, spectrum_config


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    d = tmp_path_factory.mktemp("progress")
    a, b = articulated_pair_files(d)
    n = a.shape.n_vertices
    t = np.arange(n)
    t[::7] = np.random.default_rng(0).integers(0, n, t[::7].size)
    np.savetxt(d / "m.txt", t, fmt="%d")
    np.savetxt(d / "t.vts", np.arange(1, n + 1, 3), fmt="%d")
    return d, a, b


def _evaluate_args(d):
    return ["evaluate-map", d / "a.off", d / "b.off", d / "m.txt", "--truth-src", d / "t.vts", "--truth-dst",
            d / "t.vts", "--geodesics", "dijkstra", "--r-smoothness", "1", "--r-sample", "50"]


def test_forced_progress_appears_and_json_or_quiet_silence_it(pair, capsys, monkeypatch):
    d, _, _ = pair
    monkeypatch.setenv("SHAPE_TOOLKIT_PROGRESS", "1")
    code, out, err = run_cli(capsys, *_evaluate_args(d))
    assert code == 0, err
    assert "evaluate-map: dijkstra geodesics" in err and "evaluate-map: r-smoothness" in err
    for flag in ("--json", "--quiet"):
        code, out, err = run_cli(capsys, *_evaluate_args(d), flag)
        assert code == 0 and err == "", err
    monkeypatch.setenv("SHAPE_TOOLKIT_PROGRESS", "0")  # off, even where it would be drawn
    code, out, err = run_cli(capsys, *_evaluate_args(d))
    assert code == 0 and err == ""


def test_status_counts_show_fraction_and_eta(monkeypatch, capsys):
    import argparse

    from shape_toolkit.cli.commands._common import status

    monkeypatch.setenv("SHAPE_TOOLKIT_PROGRESS", "1")
    with status(argparse.Namespace(), "work") as st:
        st.update("work: step")
        st.count(5, 20)
        st._bar.refresh()
    err = capsys.readouterr().err
    assert "work: step: 5/20 (25%, ETA" in err
    with status(argparse.Namespace(json=True), "work") as st:  # disabled: every call is a no-op
        st.update("x")
        st.count(1, 2)
    assert capsys.readouterr().err == ""


def _on_pty(args: list[str], cols: int = 0) -> tuple[int, str]:
    """Run the CLI with stderr on a pseudo-terminal (``cols`` 0: one that reports no width, as some
    do); returns the exit code and what the terminal received."""
    master, slave = pty.openpty()
    if cols:
        import fcntl
        import struct
        import termios

        fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, cols, 0, 0))
    chunks: list[bytes] = []

    def read() -> None:
        while True:
            try:
                data = os.read(master, 4096)
            except OSError:
                return
            if not data:
                return
            chunks.append(data)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    env = {k: v for k, v in os.environ.items() if k not in ("SHAPE_TOOLKIT_PROGRESS", "COLUMNS")}
    proc = subprocess.run([sys.executable, "-m", "shape_toolkit", *map(str, args)], stdin=subprocess.DEVNULL,
                          stdout=subprocess.PIPE, stderr=slave, env=env, timeout=300)
    os.close(slave)
    reader.join(timeout=10)
    os.close(master)
    return proc.returncode, b"".join(chunks).decode(errors="replace")


@pytest.mark.parametrize("cols", [0, 100])
def test_progress_is_drawn_on_a_pseudo_terminal(pair, cols):
    d, _, _ = pair
    code, seen = _on_pty(_evaluate_args(d), cols)
    assert code == 0, seen
    assert "evaluate-map: dijkstra geodesics" in seen
    code, seen = _on_pty([*_evaluate_args(d), "--quiet"], cols)
    assert code == 0 and seen == ""


def test_match_shows_pipeline_stages(pair, capsys, monkeypatch, tmp_path):
    d, _, _ = pair
    spec = tmp_path / "small.toml"
    spec.write_text('[dense]\nplugin = "fmap-zoomout"\n[dense.params]\nk = 10\nzoomout_iters = 2\n')
    monkeypatch.setenv("SHAPE_TOOLKIT_PROGRESS", "1")
    code, out, err = run_cli(capsys, "match", d / "a.off", d / "b.off", "--pipeline", spec, "-o", tmp_path / "m.txt")
    assert code == 0, err
    assert "small: spectra" in err and "small: dense (fmap-zoomout)" in err
    code, out, err = run_cli(capsys, "match", d / "a.off", d / "b.off", "--pipeline", spec, "-o", tmp_path / "m.txt",
                          "--json")
    assert code == 0 and err == ""


def test_spectrum_shows_a_status(pair, capsys, monkeypatch):
    d, _, _ = pair
    monkeypatch.setenv("SHAPE_TOOLKIT_PROGRESS", "1")
    code, out, err = run_cli(capsys, "spectrum", d / "a.off", "-k", "8")
    assert code == 0 and "spectrum: 8 eigenpairs" in err
    code, out, err = run_cli(capsys, "spectrum", d / "a.off", "-k", "8", "--json")
    assert code == 0 and err == ""


SPECTRUM_RUN = spectrum_config("cotangent")


def test_bench_report_says_each_figure(tmp_path, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text(SPECTRUM_RUN)
    code, out, err = run_cli(capsys, "bench", "run", cfg, "-o", tmp_path / "run", "--quiet")
    assert code == 0, err
    code, out, err = run_cli(capsys, "bench", "report", tmp_path / "run", "--renders", "0")
    assert code == 0, err
    lines = err.splitlines()
    assert lines[0].startswith("report: read ") and any(x.startswith("report: figure 1: ") for x in lines)
    for flag in ("--quiet", "--json"):
        code, out, err = run_cli(capsys, "bench", "report", tmp_path / "run", "--renders", "0", flag)
        assert code == 0 and err == ""


def test_library_code_is_silent(pair, capsys):
    from shape_toolkit.features.geodesics import geodesic_distances
    from shape_toolkit.metrics import geodesic_errors, r_smoothness_table
    from shape_toolkit.pipeline import Pipeline

    d, a, b = pair
    n = a.shape.n_vertices
    t = np.loadtxt(d / "m.txt", dtype=int)
    geodesic_distances(a.shape, [0, 1], method="heat", cache=False)
    geodesic_errors(b.shape, t, np.arange(0, n, 9), np.arange(0, n, 9), method="dijkstra")
    r_smoothness_table(a.shape, b.shape, t, (1.0,), sample=20)
    Pipeline({"dense": {"plugin": "fmap-zoomout", "params": {"k": 10, "zoomout_iters": 1}}}).run(a.shape, b.shape)
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""


def test_pipeline_passes_iteration_progress_to_stages_that_take_it(pair, monkeypatch):
    from shape_toolkit.api.registry import get_plugin
    from shape_toolkit.pipeline import Pipeline

    d, a, b = pair
    cls = get_plugin("dense_matchers", "fmap-zoomout")
    plain = cls.match

    def counting(self, source, target, progress=None, **kw):  # a matcher that reports its iterations
        for i in range(3):
            if progress is not None:
                progress(i + 1, 3)
        return plain(self, source, target, **kw)

    monkeypatch.setattr(cls, "match", counting)
    pipe = Pipeline({"name": "p", "dense": {"plugin": "fmap-zoomout", "params": {"k": 10, "zoomout_iters": 1}}})
    heard: list[str] = []
    pipe.run(a.shape, b.shape, progress=heard.append)
    assert [m for m in heard if "/" in m] == [f"p: dense (fmap-zoomout) {i}/3" for i in (1, 2, 3)]
    pipe.run(a.shape, b.shape)  # no progress asked: the stage is not given a callback either
