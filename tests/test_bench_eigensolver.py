"""Issue 28 "Spectra": the eigensolver against SciPy's eigsh as a peer of the spectrum task, over a grid of
sizes (the ``subdivide`` corruption) and k, each row with CPU time, peak memory and eigenvalue_error."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np
import pytest

from shape_toolkit.bench.config import ConfigError, load_config
from shape_toolkit.cli import main
from shape_toolkit.data.corruptions import apply_corruption, split_triangles
from shape_toolkit.data.generate import icosphere
from shape_toolkit.errors import ParameterError

CONFIG = """
[run]
name = "eig"
[[datasets]]
name = "synth"
kind = "synthetic"
limit = 1
params = { n_poses = 1, subdivisions = 2 }
[[corruptions]]
name = "split"
kind = "subdivide"
params = { splits = [1, 2] }
[[tasks]]
task = "spectrum"
corruptions = ["split"]
spectrum = { k = 12, use_mass = true }
metrics = ["eigenvalue_error", "lambda2"]
[[tasks.methods]]
plugin = "cotangent"
label = "toolkit"
[[tasks.methods]]
peer = "scipy-eigsh"
"""


def _write(folder: Path, text: str = CONFIG) -> Path:
    p = folder / "eig.toml"
    p.write_text(textwrap.dedent(text))
    return p


@pytest.mark.parametrize("s", [1, 2, 3, 5])
def test_split_triangles_counts_and_keeps_the_original_vertices(s):
    """n' = n + (s - 1) E + (s - 1)(s - 2) F / 2 (Euler), s^2 F triangles, the originals first and exact,
    the area unchanged (a flat split) and every edge shared by two triangles (closed surface)."""
    sh = icosphere(2)
    V, F = np.asarray(sh.vertices), np.asarray(sh.faces)
    n_edges = len(sh.edges)
    v, f = split_triangles(V, F, s)
    assert len(v) == len(V) + (s - 1) * n_edges + (s - 1) * (s - 2) * len(F) // 2
    assert len(f) == s * s * len(F)
    np.testing.assert_array_equal(v[: len(V)], V)

    def area(v, f):
        return 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum()

    assert area(v, f) == pytest.approx(area(V, F), rel=1e-12)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    assert np.all(counts == 2)
    # orientation kept: each split triangle's normal points like its parent's (outwards on the sphere)
    nrm = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all(np.einsum("ij,ij->i", nrm, v[f].mean(axis=1)) > 0)


def test_subdivide_corruption_maps_every_vertex_to_a_nearest_original():
    sh = icosphere(1)
    out, vmap = apply_corruption(sh, "subdivide", splits=3)
    assert out.n_vertices > sh.n_vertices and vmap.shape == (out.n_vertices,)
    np.testing.assert_array_equal(vmap[: sh.n_vertices], np.arange(sh.n_vertices))
    d = np.linalg.norm(out.vertices[:, None] - sh.vertices[None], axis=2)
    np.testing.assert_allclose(np.linalg.norm(out.vertices - sh.vertices[vmap], axis=1), d.min(axis=1))
    for bad in (0, 1.5, True, 65):
        with pytest.raises(ParameterError, match="splits"):
            apply_corruption(sh, "subdivide", splits=bad)


def test_scipy_eigsh_peer_is_a_spectrum_method_and_bad_keys_are_named(tmp_path):
    cfg = load_config(_write(tmp_path))
    (task,) = cfg.tasks
    toolkit, peer = task.methods
    assert (toolkit.solver, peer.solver, peer.plugin, peer.method_label) == (None, "scipy-eigsh", "cotangent",
                                                                              "peer:scipy-eigsh")  # fmt: skip
    for old, new, key in [
        ('peer = "scipy-eigsh"', 'peer = "arpack-nope"', "tasks[0].methods[1].peer"),
        ('peer = "scipy-eigsh"', 'peer = "scipy-eigsh"\nparams = { a = 1 }', "tasks[0].methods[1].params"),
        ('peer = "scipy-eigsh"', 'peer = "scipy-eigsh"\nplugin = "nope"', "tasks[0].methods[1].plugin"),
        ("splits = [1, 2]", "splits = [\"x\"]", "corruptions[0].params.splits"),
    ]:
        with pytest.raises(ConfigError) as ei:
            load_config(_write(tmp_path, CONFIG.replace(old, new)))
        assert ei.value.key == key, (ei.value.key, str(ei.value))


def test_runner_compares_the_solver_with_scipy_eigsh_per_size(tmp_path):
    """Both solvers' rows, per size: the same eigenvalues to 1e-10 of the reference, CPU time and peak
    memory recorded, and the report's mean table carries cpu_seconds and eigenvalue_error."""
    from shape_toolkit.bench import read_rows
    from shape_toolkit.bench.report import summarize

    run = tmp_path / "run"
    assert main(["bench", "run", str(_write(tmp_path)), "-o", str(run), "-q"]) == 0
    rows = [json.loads(line) for line in (run / "results.jsonl").read_text().splitlines()]
    assert len(rows) == 4 and all(r["status"] == "ok" for r in rows)
    assert {r["method_label"] for r in rows} == {"toolkit", "peer:scipy-eigsh"}
    assert len({r["key"] for r in rows}) == 4
    sizes = sorted({r["n_vertices"] for r in rows})
    assert len(sizes) == 2 and sizes[1] > sizes[0]
    for r in rows:
        assert r["metrics"]["eigenvalue_error"] < 1e-10
        assert r["cpu_seconds"] > 0 and r["peak_memory_mb"] is not None
        assert r["spectrum_cache_hit"] is False  # each solver computes its own spectrum inside the row
    by = {(r["method_label"], r["n_vertices"]): r["metrics"]["lambda2"] for r in rows}
    for n in sizes:
        assert by["toolkit", n] == pytest.approx(by["peer:scipy-eigsh", n], rel=1e-9)
    cells = summarize(read_rows(run))["spectrum"]  # what the report's mean table shows
    assert len(cells) == 4
    assert all({"cpu_seconds", "eigenvalue_error", "peak_memory_mb"} <= set(c) for c in cells.values())


def test_eigenvalue_error_on_a_small_shape_uses_a_dense_reference(tmp_path):
    """Below the dense crossover (ARPACK cannot take k close to n) the reference is LAPACK: both rows score."""
    text = CONFIG.replace("subdivisions = 2", "subdivisions = 1").replace("splits = [1, 2]", "splits = [1]")
    run = tmp_path / "run"
    assert main(["bench", "run", str(_write(tmp_path, text)), "-o", str(run), "-q"]) == 0
    rows = [json.loads(line) for line in (run / "results.jsonl").read_text().splitlines()]
    assert len(rows) == 2 and all(r["n_vertices"] <= 400 for r in rows)
    assert all(r["metrics"]["eigenvalue_error"] < 1e-10 for r in rows)


def test_repeats_run_each_solver_n_times_and_rows_record_blas_threads(tmp_path, monkeypatch):
    """``options = { repeats = 3 }``: every row solves three times (the fastest run's times kept), says so,
    and records the BLAS threads it ran with; the Markdown report states both. ``repeats = 0`` is refused."""
    from threadpoolctl import threadpool_limits

    import shape_toolkit.bench.tasks as tasks
    from shape_toolkit.bench.report import write_report
    from shape_toolkit.bench.runner import run_benchmark

    solves = []
    real = tasks.compute_spectrum_cached

    def counted(*a, **k):
        if k.get("cache") is False:  # the row's own, timed solve (preparing an item caches, untimed)
            solves.append(1)
        return real(*a, **k)

    monkeypatch.setattr(tasks, "compute_spectrum_cached", counted)
    text = CONFIG.replace("splits = [1, 2]", "splits = [1]").replace(
        'metrics = ["eigenvalue_error", "lambda2"]', 'metrics = ["lambda2"]\noptions = { repeats = 3 }')
    run = tmp_path / "run"
    with threadpool_limits(limits=1, user_api="blas"):  # in process (the CLI may supervise a child)
        run_benchmark(load_config(_write(tmp_path, text)), run, progress=False)
    rows = [json.loads(line) for line in (run / "results.jsonl").read_text().splitlines()]
    assert len(rows) == 2 and len(solves) == 6
    assert all(r["repeats"] == 3 and r["blas_threads"] == 1 and r["cpu_seconds"] > 0 for r in rows)
    md = tmp_path / "r.md"
    write_report(run, renders=0, markdown=md)
    assert "BLAS threads while the methods ran: 1 in every row; timings are the fastest of 3 runs" in md.read_text()
    with pytest.raises(ConfigError) as ei:
        load_config(_write(tmp_path, text.replace("repeats = 3", "repeats = 0")))
    assert ei.value.key == "tasks[0].options.repeats"


def test_blas_threads_option_and_the_toolkit_solvers_as_peers(tmp_path):
    """``blas_threads = 2`` runs (and records) two BLAS threads where the runner's default is one; the
    toolkit's dense and Krylov solvers as peers (the crossover ``auto`` picks on) agree with ``auto``."""
    import os

    from shape_toolkit.bench.runner import run_benchmark

    text = CONFIG.replace("splits = [1, 2]", "splits = [1]").replace(
        'peer = "scipy-eigsh"', 'peer = "toolkit-dense"\n[[tasks.methods]]\npeer = "toolkit-krylov"')
    two = text.replace('metrics = ["eigenvalue_error", "lambda2"]',
                       'metrics = ["lambda2"]\noptions = { blas_threads = 2 }')
    for name, cfg in (("one", text), ("two", two)):
        run_benchmark(load_config(_write(tmp_path, cfg)), tmp_path / name, progress=False)
    one = {r["method_label"]: r for r in map(json.loads, (tmp_path / "one" / "results.jsonl").read_text().splitlines())}
    assert set(one) == {"toolkit", "peer:toolkit-dense", "peer:toolkit-krylov"}
    assert all(r["status"] == "ok" and r["blas_threads"] == 1 for r in one.values())
    lam = [r["metrics"]["lambda2"] for r in one.values()]
    assert max(lam) == pytest.approx(min(lam), rel=1e-8)
    assert all(r["metrics"]["eigenvalue_error"] < 1e-10 for r in one.values())
    rows = [json.loads(x) for x in (tmp_path / "two" / "results.jsonl").read_text().splitlines()]
    if (os.cpu_count() or 1) >= 2:
        assert {r["blas_threads"] for r in rows} == {2}
    with pytest.raises(ConfigError) as ei:
        load_config(_write(tmp_path, two.replace("blas_threads = 2", "blas_threads = 0")))
    assert ei.value.key == "tasks[0].options.blas_threads"
