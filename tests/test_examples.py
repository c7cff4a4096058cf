"""Every example config validates as shipped and runs on a small subset.

The shipped file is loaded exactly (plugins, metrics, corruptions and dataset paths relative to
$TOOLKIT_DATA are all checked), then run on one item with the first method of each task, at
most two corruption instances and spectra capped at 20 eigenpairs, to keep the suite short.
Examples reading the shared data are skipped when it is absent.
"""

from __future__ import annotations

import copy
import sys
from pathlib import Path

import pytest

from shape_toolkit.bench.config import load_config, parse_config
from shape_toolkit.bench.runner import read_rows, run_benchmark

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
CONFIGS = sorted(EXAMPLES.glob("*/config.toml"))


def _needs_data(raw: dict) -> bool:
    return any(d.get("kind") != "synthetic" for d in raw["datasets"])


def _small(raw: dict) -> dict:
    raw = copy.deepcopy(raw)
    for d in raw["datasets"]:
        d["limit"] = 1
        if d.get("kind") == "synthetic":
            d.setdefault("params", {})["n_poses"] = 2
    for t in raw["tasks"]:
        t["methods"] = t["methods"][:1]
        if "corruptions" in t:
            t["corruptions"] = t["corruptions"][:2]
        for spec in [t.get("spectrum")] + [m.get("spectrum") for m in t["methods"]]:
            if spec and "k" in spec:
                spec["k"] = min(spec["k"], 20)
        opts = t.get("options", {})
        if "truth_sample" in opts:
            opts["truth_sample"] = min(opts["truth_sample"], 100)
    for c in raw.get("corruptions", []):
        for k, v in c.get("params", {}).items():
            if isinstance(v, list):
                c["params"][k] = v[:1]
    return raw


def test_every_example_has_a_config_and_a_command():
    assert len(CONFIGS) >= 5
    readme = (EXAMPLES / "README.md").read_text()
    for c in CONFIGS:
        assert f"examples/{c.parent.name}/config.toml" in readme
        assert "shape-toolkit bench run" in c.read_text()  # the one command, in the file header


@pytest.mark.slow
@pytest.mark.parametrize("config", CONFIGS, ids=[c.parent.name for c in CONFIGS])
def test_example_runs_on_a_subset(config, tmp_path, request, monkeypatch):
    raw = tomllib.loads(config.read_text())
    if _needs_data(raw):
        data = request.getfixturevalue("shared_data")  # skips when absent
        monkeypatch.setenv("TOOLKIT_DATA", str(data))
    full = load_config(config)  # the shipped config validates as is
    assert full.tasks
    cfg = parse_config(_small(raw), base=config.parent, source=str(config))
    summary = run_benchmark(cfg, tmp_path / "run", progress=False)
    rows = read_rows(tmp_path / "run")
    assert summary.rows == len(rows) > 0
    errors = [r["error"] for r in rows if r["status"] != "ok"]
    assert not errors, errors
    for r in rows:
        assert r["metrics"], r
