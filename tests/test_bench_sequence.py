"""The sequence protocol of the benchmark runner (thesis 7.5.3): generated pose sequences as a dataset
kind, each pipeline's frame-to-frame maps chained (or matched from frame 0), drift per frame."""

from __future__ import annotations

import math

import numpy as np
import pytest
import tomllib

from shape_toolkit.bench.config import ConfigError, parse_config
from shape_toolkit.bench.runner import read_rows, run_benchmark
from shape_toolkit.bench.tasks import TASKS, Prepared
from shape_toolkit.data.datasets import load_item, open_dataset
from shape_toolkit.data.synthetic import cached_pose_sequence

SMALL = {"frames": 3, "subdivisions": 2}


def _prepared(params: dict) -> tuple[Prepared, object]:
    ref = open_dataset("sequence", seeds=[3], **params)[0]
    item = load_item(ref)
    seq = cached_pose_sequence(item.meta["sequence"])
    p = Prepared(item.name, item.shape, item.shape, None, None, [], [], np.arange(item.shape.n_vertices),
                 meta=item.meta)
    return p, seq


def _evaluate(p: Prepared, ids: np.ndarray) -> dict:
    task = TASKS["sequence"]
    return task.evaluate(["drift", "wrong_part"], p, {"ids": ids}, task.check_options({"sample": None}))


@pytest.mark.parametrize("merge", [[], [1]])
def test_the_true_trajectories_drift_zero_and_a_known_permutation_is_followed(merge):
    # not remeshed: every vertex is a material point, so the truth is exact; the frames are shuffled
    # (permute), so following the truth means following a known permutation per frame
    p, seq = _prepared({**SMALL, "merge_frames": merge})
    assert p.target.n_vertices == seq.frames[0].n_vertices and not np.array_equal(seq.material[1], seq.material[0])
    m = _evaluate(p, seq.truth())
    assert m["drift@f1"] == 0.0 and m["drift@f2"] == 0.0 and m["drift_last"] == 0.0 and m["drift_mean"] == 0.0
    assert m["within_last"] == 1.0 and m["lost_last"] == 0.0 and m["wrong_part"] == 0.0
    assert m["drift_curve"] == [[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]


def test_a_wrong_frame_drifts_and_a_lost_trajectory_counts():
    p, seq = _prepared(SMALL)
    truth = seq.truth()
    ids = truth.copy()
    rng = np.random.default_rng(0)
    ids[:, 2] = rng.permutation(ids[:, 2])  # frame 2 scrambled: drift there, none at frame 1
    ids[0, 2] = -1
    m = _evaluate(p, ids)
    assert m["drift@f1"] == 0.0 and m["drift@f2"] > 0.1
    assert m["drift_mean"] == pytest.approx(m["drift@f2"] / 2)
    assert m["lost_last"] == pytest.approx(1 / ids.shape[0])
    assert 0 < m["wrong_part"] < 1


def test_a_pipeline_follows_the_sequence_chained_and_direct(tmp_path):
    cfg = tomllib.loads("""
[[datasets]]
name = "seq"
kind = "sequence"
params = { seeds = [1], frames = 3, subdivisions = 2 }
[[tasks]]
task = "sequence"
name = "chain"
options = { sample = 200 }
[[tasks.methods]]
pipeline = "zoomout"
label = "zoomout"
[[tasks]]
task = "sequence"
name = "direct"
options = { mode = "direct", sample = 200 }
[[tasks.methods]]
pipeline = "zoomout"
label = "zoomout"
""")
    run_benchmark(parse_config(cfg), tmp_path / "run", progress=False)
    rows = {r["task_name"]: r for r in read_rows(tmp_path / "run")}
    assert set(rows) == {"chain", "direct"}
    for r in rows.values():
        assert r["status"] == "ok", r.get("error")
        m = r["metrics"]
        # a shuffled, re-posed body is tracked: far below a random map's drift (~0.5 sqrt(area))
        assert m["drift_last"] < 0.05 and m["within_last"] > 0.8 and m["wrong_part"] < 0.05
        assert all(v is None or math.isfinite(v) for v in m.values() if not isinstance(v, list))
    # frame 1 is the same map in both modes
    assert rows["chain"]["metrics"]["drift@f1"] == pytest.approx(rows["direct"]["metrics"]["drift@f1"])


def _sequence_config() -> dict:
    return tomllib.loads("""
[[datasets]]
name = "seq"
kind = "sequence"
params = { seeds = [1], frames = 3, subdivisions = 2 }
[[corruptions]]
name = "noise"
kind = "gaussian-noise"
params = { strength = 0.1 }
[[tasks]]
task = "sequence"
[[tasks.methods]]
pipeline = "zoomout"
""")


def _set(path: str, value) -> callable:
    def change(cfg: dict) -> None:
        *head, last = path.split(".")
        d = cfg
        for k in head:
            d = d[k][0] if isinstance(d[k], list) else d[k]
        d[last] = value
    return change


@pytest.mark.parametrize("change, key", [
    (_set("tasks.corruptions", ["noise"]), "tasks[0].corruptions[0]"),
    (_set("tasks.options", {"mode": "backwards"}), "tasks[0].options"),
    (_set("tasks.task", "matching"), "tasks[0].datasets"),
    (_set("datasets.params.merge_frames", [5]), "datasets[0].params"),
    (_set("datasets.params.seeds", []), "datasets[0].params"),
])
def test_bad_sequence_configs_are_refused_naming_the_key(change, key):
    cfg = _sequence_config()
    change(cfg)
    with pytest.raises(ConfigError) as e:
        parse_config(cfg)
    assert e.value.key.startswith(key), e.value


def test_a_sequence_method_must_be_a_pipeline():
    cfg = _sequence_config()
    cfg["tasks"][0]["methods"] = [{"plugin": "zoomout"}]
    with pytest.raises(ConfigError) as e:
        parse_config(cfg)
    assert e.value.key == "tasks[0].methods[0].pipeline"


def test_the_shipped_trajectory_config_plans_its_rows():
    from pathlib import Path

    from shape_toolkit.bench.config import load_config

    cfg = load_config(Path(__file__).resolve().parent.parent / "benchmarks" / "configs" / "trajectory_drift.toml")
    assert cfg.planned_rows == 32  # 2 datasets x 2 seeds x 4 pipelines x (chain, direct)
    assert {t.options["mode"] for t in cfg.tasks} == {"chain", "direct"}
