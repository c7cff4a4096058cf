"""The runner's ``geodesics`` task (issue 28: the geodesic table of the former bench_heat.py as a config): each
method's distances from evenly spaced sources, scored against the reference method."""

from __future__ import annotations

import pytest
import tomllib

from shape_toolkit.bench.config import ConfigError, parse_config
from shape_toolkit.bench.runner import read_rows, run_benchmark

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
