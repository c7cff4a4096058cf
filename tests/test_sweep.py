"""Defaults sweep (issue 11), now the runner's ``benchmarks/configs/sweep.toml``: it names every registered
plugin and pipeline preset (a plugin added later must join it), and a fast subset of it must not fail.

The subset is one shape per dataset, chosen for being hard for default parameters: TOSCA ``dog0`` has the most
irregular triangulation of tosca5k (longest edge 7x the mean: with the former Gaussian bandwidth, the mean edge
length, its weights went down to 5e-12), PSB ``188`` (a hand) has edges up to 20x the mean. The shared PSB copy
has no mesh with several components; that case is covered synthetically in ``tests/test_graph_spectrum.py``.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import tomllib

from shape_toolkit.api.registry import available_plugins
from shape_toolkit.bench.config import parse_config
from shape_toolkit.bench.runner import read_rows, run_benchmark
from shape_toolkit.pipeline import PRESETS

CONFIG = Path(__file__).resolve().parent.parent / "benchmarks" / "configs" / "sweep.toml"
#: segmenters that need user constraints: the sweep cannot run them with their defaults (named in the config)
NEEDS_INPUT = {"ccskl", "seeded-walk", "spectral-learning"}
#: families a sweep task runs directly (matchers run through the pipeline presets)
FAMILIES = {"weightings": "weightings", "keypoints": "keypoints", "descriptors": "descriptors",
            "segmenters": "segmenters"}
SUBSET = {"tosca5k": "dog0", "faust5k": "tr_reg_000", "psb": "188"}


def _raw() -> dict:
    return tomllib.loads(CONFIG.read_text())


def test_the_sweep_names_every_registered_plugin_and_preset():
    raw = _raw()
    named = {t["name"]: {m.get("plugin") or m.get("pipeline") for m in t["methods"]} for t in raw["tasks"]}
    registered = available_plugins()
    for task, family in FAMILIES.items():
        missing = set(registered.get(family, [])) - named[task] - NEEDS_INPUT
        assert not missing, f"registered {family} missing from {CONFIG.name}: {sorted(missing)}"
    assert set(PRESETS) <= named["pipelines"], sorted(set(PRESETS) - named["pipelines"])
    for name in NEEDS_INPUT:
        assert name in raw["run"]["description"]  # said, not silently left out


@pytest.mark.slow
def test_every_plugin_runs_with_its_defaults_on_hard_shapes(shared_data, tmp_path, monkeypatch):
    """A minute of real data: the weightings, keypoints, descriptors and segmenters of the sweep on three
    hard shapes, 0 failed rows; the Gaussian default spectrum has one null eigenvalue (lambda_2 well above 0)."""
    monkeypatch.setenv("TOOLKIT_DATA", str(shared_data))
    raw = _raw()
    raw["datasets"] = [dict(d, items=[SUBSET[d["name"]]]) for d in raw["datasets"] if d["name"] in SUBSET]
    raw["tasks"] = [t for t in raw["tasks"] if t["name"] != "pipelines"]
    run = tmp_path / "run"
    run_benchmark(parse_config(raw, base=CONFIG.parent), run, progress=False)
    rows = read_rows(run)
    failed = [f"{r['item']} {r['method_label']}: {r.get('error')}" for r in rows if r["status"] != "ok"]
    assert not failed, "\n".join(failed)
    assert len(rows) == 3 * sum(len(t["methods"]) for t in raw["tasks"])
    gauss = [r for r in rows if r["task_name"] == "weightings" and r["plugin"] == "gaussian"]
    assert len(gauss) == 3 and all(r["metrics"]["lambda2"] > 1e-6 for r in gauss)
