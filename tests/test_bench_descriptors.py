"""The runner's ``descriptors`` and ``geodesics`` tasks and the common options ``memory`` and ``metric_costs``
(issue 28: the former bench_heat.py and bench_segmentation_metrics.py as configs)."""

from __future__ import annotations

import numpy as np
import pytest
import tomllib

from shape_toolkit.bench.config import ConfigError, parse_config
from shape_toolkit.bench.report import write_report
from shape_toolkit.bench.runner import read_rows, run_benchmark
from shape_toolkit.bench.worker import MemoryMonitor

_BASE = """
[run]
name = "t"
[[datasets]]
name = "body"
kind = "synthetic"
params = { n_poses = 1, subdivisions = 2 }
"""


def _cfg(tasks: str) -> dict:
    return tomllib.loads(_BASE + tasks)


def test_descriptor_rows_have_the_descriptor_shape_and_traced_memory(tmp_path):
    cfg = _cfg("""
[[tasks]]
task = "descriptors"
options = { memory = "traced" }
[[tasks.methods]]
plugin = "hks"
params = { n_times = 7, K = 20 }
[[tasks]]
task = "descriptors"
name = "hd"
options = { keypoints = 4 }
[[tasks.methods]]
plugin = "heat-distance"
params = { K = 10, n_times = 3 }
""")
    run = tmp_path / "run"
    run_benchmark(parse_config(cfg), run, progress=False)
    rows = {r["task_name"]: r for r in read_rows(run)}
    assert all(r["status"] == "ok" for r in rows.values()), [r.get("error") for r in rows.values()]
    hks, hd = rows["descriptors"], rows["hd"]
    assert hks["metrics"] == {"dimensions": 7, "finite": True}
    assert hd["metrics"]["dimensions"] == 4 * 3  # keypoint-major: 4 keypoints x 3 times
    # traced: at least the (n, 7) float64 output itself
    assert hks["peak_memory_mb"] >= hks["n_vertices"] * 7 * 8 / 2**20
    assert hks["spectrum_seconds"] is not None  # the spectrum came from the cache, timed apart
    assert "metric_peak_memory_mb" not in hks  # metric costs only where a task asks for them


@pytest.mark.parametrize("bad, key", [
    ('options = { keypoints = 0 }', "keypoints"),
    ('options = { memory = "vms" }', "memory"),
    ('options = { metric_costs = "yes" }', "metric_costs"),
])
def test_bad_descriptor_and_memory_options_are_refused_naming_the_key(bad, key):
    cfg = _cfg(f"""
[[tasks]]
task = "descriptors"
{bad}
[[tasks.methods]]
plugin = "hks"
""")
    with pytest.raises(ConfigError, match=key):
        parse_config(cfg)


def test_traced_monitor_sees_memory_reused_after_a_free():
    """The RSS rise misses an allocation into memory freed just before; the traced peak does not."""
    big = np.ones(4_000_000)  # 30.5 MB
    del big
    with MemoryMonitor(traced=True) as mon:
        a = np.ones(2_000_000)  # 15.3 MB
        a[0] = 2.0
    assert 15.0 <= mon.peak_mb < 17.0
    with MemoryMonitor(traced=True) as mon:
        pass
    assert mon.peak_mb < 1.0


def test_metric_costs_are_recorded_and_reported(tmp_path):
    cfg = _cfg("""
[[tasks]]
task = "segmentation"
metrics = ["segmentation"]
options = { n_segments = 3, metric_costs = true, memory = "traced" }
[[tasks.methods]]
plugin = "spectral-clustering"
""")
    run = tmp_path / "run"
    run_benchmark(parse_config(cfg), run, progress=False)
    (row,) = read_rows(run)
    assert row["status"] == "ok", row.get("error")
    assert row["metric_peak_memory_mb"] > 0 and row["metric_cpu_seconds"] >= 0
    md = tmp_path / "r.md"
    write_report(run, markdown=md)
    text = md.read_text()
    assert "metric_peak_memory_mb (MB)" in text and "metric_seconds (s)" in text


def test_geodesic_rows_are_scored_against_the_exact_distances(tmp_path):
    """The reference scores itself 0; Dijkstra along the edges is a path on the surface, so never shorter than the
    exact geodesic: a positive error, bounded; the heat method is closer to the exact distances than Dijkstra's
    zigzag on this mesh; every row counts its sources."""
    cfg = _cfg("""
[[tasks]]
task = "geodesics"
options = { sources = 5, reference_sources = 2 }
[[tasks.methods]]
method = "exact"
[[tasks.methods]]
method = "dijkstra"
label = "edges"
[[tasks.methods]]
method = "heat"
""")
    run = tmp_path / "run"
    run_benchmark(parse_config(cfg), run, progress=False)
    rows = {r["method_label"]: r for r in read_rows(run)}
    assert all(r["status"] == "ok" for r in rows.values()), [r.get("error") for r in rows.values()]
    assert set(rows) == {"exact", "edges", "heat"}
    assert rows["exact"]["metrics"]["mean_relative_error"] == 0.0
    edges = rows["edges"]["metrics"]
    assert 0.0 < edges["mean_relative_error"] < 0.3 and edges["mean_relative_error"] <= edges["max_relative_error"]
    assert rows["heat"]["metrics"]["mean_relative_error"] < edges["mean_relative_error"]
    assert all(r["metrics"]["n_sources"] == 5 for r in rows.values())
    assert all(r["metrics"]["unreached_fraction"] == 0.0 for r in rows.values())


def test_vertices_a_method_leaves_unreached_are_counted_not_averaged():
    """A method's infinite distance where the reference is finite is counted in ``unreached_fraction`` and kept
    out of the relative error (no inf or NaN in a row)."""
    import numpy as np

    from shape_toolkit.bench.tasks import _m_relative_error
    from shape_toolkit.data.generate import icosphere
    from shape_toolkit.features.geodesics import geodesic_distances

    class P:
        target = icosphere(2)
        clean_target = None

    ids = np.array([0])
    rows = geodesic_distances(P.target, ids, method="exact").copy()
    far = np.flatnonzero(rows[0] > 0.01 * rows.max())
    rows[0, far[:10]] = np.inf
    m = _m_relative_error(P, {"sources": ids, "reference_rows": rows}, {"reference": "exact"})
    assert m["unreached_fraction"] == pytest.approx(10 / len(far))
    assert m["mean_relative_error"] == 0.0 and m["max_relative_error"] == 0.0


@pytest.mark.parametrize("bad, key", [
    ('options = { sources = 0 }\n[[tasks.methods]]\nmethod = "heat"', "sources"),
    ('options = { reference = "geodesic" }\n[[tasks.methods]]\nmethod = "heat"', "reference"),
    ('options = { sources = 2, reference_sources = 3 }\n[[tasks.methods]]\nmethod = "heat"', "reference_sources"),
    ('[[tasks.methods]]\nmethod = "bogus"', "method"),
    ('[[tasks.methods]]\nplugin = "hks"', "method"),
    ('[[tasks.methods]]\nmethod = "heat"\nparams = { t = 1 }', "params"),
])
def test_bad_geodesic_options_and_methods_are_refused_naming_the_key(bad, key):
    with pytest.raises(ConfigError, match=key):
        parse_config(_cfg(f'[[tasks]]\ntask = "geodesics"\n{bad}\n'))


def test_a_geodesic_method_belongs_to_a_geodesics_task():
    cfg = _cfg('[[tasks]]\ntask = "descriptors"\n[[tasks.methods]]\nmethod = "heat"\n')
    with pytest.raises(ConfigError, match="geodesics task"):
        parse_config(cfg)
