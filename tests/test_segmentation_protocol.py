"""The PSB segmentation protocol in the benchmark runner (issue 28): k per item from the humans' mode,
PSB clicks, the human-consistency row, rows' categories, and the tuning/reporting split by group."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from shape_toolkit.bench.config import ConfigError, parse_config, split_items
from shape_toolkit.data.datasets import ItemRef, item_group, psb_dataset, truth_segment_counts
from shape_toolkit.metrics.segmentation import (
    consensus_segment_count,
    human_consistency_scores,
    segmentation_scores,
)

REPO = Path(__file__).resolve().parent.parent


def _psb(shared_data: Path) -> Path:
    psb = shared_data / "psb"
    if not (psb / "off" / "1.off").is_file():
        pytest.skip("PSB meshes not in the shared data")
    return psb


# -- k per item -------------------------------------------------------------------------------
def test_consensus_count_is_the_mode_as_in_psb():
    """PSB's nSeg-ByModel.txt: the most frequent count; ties to the count closest to the median, then
    the larger (segment counts of shared meshes 7, 307, 381, 1 and their PSB values)."""
    assert consensus_segment_count([2, 6, 6, 6, 6, 8, 9, 9, 10, 12, 13, 15, 16, 17, 20]) == 6  # median: 9
    assert consensus_segment_count([2, 2, 3, 3, 6, 7, 8, 9]) == 3
    assert consensus_segment_count([3, 6, 9, 10, 11, 11, 14, 15, 15, 16, 17, 17, 26]) == 15
    assert consensus_segment_count([6, 6, 6, 8, 8, 13, 14, 15, 15, 15, 15, 16, 17, 21, 23, 60]) == 15
    assert consensus_segment_count([5, 6]) == 6  # a tie at equal distance from the median: the larger
    assert consensus_segment_count([1, 1]) == 2  # at least 2
    assert consensus_segment_count(np.array([4])) == 4


def test_k_mode_on_real_psb_segmentations(shared_data):
    """The counts read from the .seg files are the distinct labels of each human segmentation, and the
    rule gives PSB's values on the shared meshes (those the earlier script used: 1 -> 15, 7 -> 6, ...)."""
    refs = {r.name: r for r in psb_dataset(_psb(shared_data))}
    for name, k in (("1", 15), ("2", 12), ("7", 6), ("8", 16), ("27", 2), ("187", 7), ("328", 3)):
        ref = refs[name]
        direct = [len(np.unique(np.loadtxt(s, dtype=np.int64))) for s in ref.paths["segs"]]
        assert truth_segment_counts(ref) == direct
        assert consensus_segment_count(direct) == k


# -- human consistency ------------------------------------------------------------------------
def _sphere_truths(sphere):
    """Three face labellings of the sphere by coordinate, unlike each other."""
    c = sphere.vertices[sphere.faces].mean(axis=1)
    return [(c[:, 0] > 0).astype(np.int64), (c[:, 1] > 0.3).astype(np.int64) + 2 * (c[:, 2] > 0),
            np.digitize(c[:, 2], [-0.5, 0.0, 0.5]).astype(np.int64)]


def test_human_consistency_equals_the_direct_computation(sphere):
    truths = _sphere_truths(sphere)
    got = human_consistency_scores(truths, mesh=sphere)
    per = [segmentation_scores(t, [u for j, u in enumerate(truths) if j != i], mesh=sphere)
           for i, t in enumerate(truths)]
    for name in ("rand_index_error", "cut_discrepancy", "gce", "recall"):
        assert got[name] == pytest.approx(np.mean([p[name] for p in per]))
    assert got["rand_index_error"] > 0.05 and got["n_truths"] == 3
    same = human_consistency_scores([truths[0], truths[0].copy()], mesh=sphere)
    assert same["rand_index_error"] == 0.0 and same["cut_discrepancy"] == 0.0


def test_human_row_of_the_task_is_each_human_against_the_others(sphere):
    """The runner's human row (task adapter, uniform face weights) equals the direct loop, including the
    area-weighted Rand index beside it; a method scored after clicks skips the clicking human."""
    from shape_toolkit.bench.tasks import TASKS, HumanSegmentations, Prepared
    from shape_toolkit.metrics.segmentation import rand_index_error

    truths = _sphere_truths(sphere)
    n = sphere.n_vertices
    prep = Prepared("s", sphere, sphere, None, None, [], [np.zeros(n, np.int64)] * 3, np.arange(n),
                    target_face_labels=truths)
    task = TASKS["segmentation"]
    opts = task.check_options({"face_weights": "uniform", "human_consistency": True})
    out = task.run(HumanSegmentations(), prep, {}, opts, 0)
    got = task.evaluate(["n_segments", "segmentation"], prep, out, opts)
    ones = np.ones(sphere.n_faces)
    direct = np.mean([np.mean([rand_index_error(t, u, ones) for j, u in enumerate(truths) if j != i])
                      for i, t in enumerate(truths)])
    area = np.mean([np.mean([rand_index_error(t, u, sphere.face_areas) for j, u in enumerate(truths) if j != i])
                    for i, t in enumerate(truths)])
    assert got["rand_index_error"] == pytest.approx(direct)
    assert got["rand_index_error_area"] == pytest.approx(area)
    assert got["n_segments"] == pytest.approx(np.mean([len(np.unique(t)) for t in truths]))
    clicked = task.evaluate(["segmentation"], prep, {"labels": np.zeros(n, np.int64), "face_labels": truths[0],
                                                     "clicked_truth": 0}, opts)
    assert clicked["rand_index_error"] == pytest.approx(
        np.mean([rand_index_error(truths[0], u, ones) for u in truths[1:]]))


# -- groups and the split ----------------------------------------------------------------------
def _psb_refs(ids):
    return [ItemRef("psb", str(i), {"shape": f"/x/off/{i}.off", "segs": []}) for i in ids]


def test_item_groups():
    assert [item_group(r) for r in _psb_refs([1, 20, 21, 287, 387])] == ["human", "human", "cup", "armadillo",
                                                                         "fourleg"]
    tosca = ItemRef("tosca", "cat0-cat1", {"source": "/d/cat0.off", "target": "/d/cat1.off"})
    faust = ItemRef("tosca", "a-b", {"source": "/d/tr_reg_003.off", "target": "/d/tr_reg_027.off"})
    assert item_group(tosca) == "cat" and item_group(faust) == "subject-0+subject-2"
    assert item_group(ItemRef("synthetic", "pose0")) is None


def test_split_is_deterministic_by_group_and_never_splits_a_group():
    ids = [20 * c + m for c in range(19) for m in (1, 2, 7, 8)]
    refs = _psb_refs(ids)
    halves = split_items(refs)
    again = split_items(list(reversed(refs)))
    assert {h: sorted(r.name for r in v) for h, v in halves.items()} == \
        {h: sorted(r.name for r in v) for h, v in again.items()}  # order independent
    groups = {h: {item_group(r) for r in v} for h, v in halves.items()}
    assert not groups["tune"] & groups["report"] and not halves["neither"]
    assert len(groups["tune"]) == 9 and len(groups["report"]) == 10  # floor(19 / 2) tune
    assert sum(map(len, halves.values())) == len(refs)
    other = split_items(refs, salt="x")
    assert {item_group(r) for r in other["tune"]} != groups["tune"]  # the salt changes the draw
    # pairs across two subjects in different halves are in neither half
    people = [ItemRef("tosca", f"{a}-{b}", {"source": f"/d/tr_reg_{a:03d}.off", "target": f"/d/tr_reg_{b:03d}.off"})
              for a in range(0, 50, 5) for b in range(0, 50, 7) if a != b]
    ph = split_items(people)
    subj = {h: {g for r in v for g in item_group(r).split("+")} for h, v in ph.items() if h != "neither"}
    assert not subj["tune"] & subj["report"] and ph["neither"]


def _config(shared_data, run=None, options=None, methods=None):
    _psb(shared_data)
    raw = {"run": run or {}, "datasets": [{"name": "psb", "kind": "psb", "path": str(shared_data / "psb")}],
           "tasks": [{"task": "segmentation", "metrics": ["n_segments", "segmentation"],
                      "options": options or {}, "methods": methods or [{"plugin": "spectral-clustering"}]}]}
    return raw


@pytest.mark.parametrize("split, key", [
    ({"half": "report", "by": "animal"}, "run.split.by"),
    ({"half": "both"}, "run.split.half"),
    ({"half": "report", "rule": "x"}, "run.split.rule"),
    ({"by": "category"}, "run.split.half"),
    ({"half": "tune", "tune_fraction": 0.01}, "run.split.tune_fraction"),  # floor(0.19) = 0 groups tune
    ({"half": "report", "tune_fraction": 1.5}, "run.split.tune_fraction"),
])
def test_bad_split_is_refused_naming_the_key(shared_data, split, key):
    with pytest.raises(ConfigError) as err:
        parse_config(_config(shared_data, run={"split": split}))
    assert err.value.key == key


def test_split_keeps_one_half(shared_data):
    cfg = parse_config(_config(shared_data, run={"split": {"half": "report"}}))
    tune = parse_config(_config(shared_data, run={"split": {"half": "tune"}}))
    rep = {r.name for r in cfg.datasets["psb"].refs}
    tun = {r.name for r in tune.datasets["psb"].refs}
    assert rep and tun and not rep & tun and len(rep | tun) == 50
    assert not {item_group(r) for r in cfg.datasets["psb"].refs} & {item_group(r) for r in tune.datasets["psb"].refs}
    assert cfg.split["datasets"]["psb"]["report"]["items"] == len(rep)


def test_the_report_says_which_half_it_shows(shared_data, tmp_path):
    """The one split line of a report (HTML and Markdown): the half shown, the rule, its groups and item count,
    how many items of the other half are left out, and how many items have rows."""
    import json

    from shape_toolkit.bench.report import _split_note
    from shape_toolkit.bench.store import SPLIT

    cfg = parse_config(_config(shared_data, run={"split": {"half": "report"}}))
    tune = parse_config(_config(shared_data, run={"split": {"half": "tune"}}))
    (tmp_path / SPLIT).write_text(json.dumps(cfg.split))
    rows = [{"dataset": "psb", "item": r.name} for r in cfg.datasets["psb"].refs[:3]]
    line = _split_note(tmp_path, rows)
    rep_groups = sorted({item_group(r) for r in cfg.datasets["psb"].refs})
    tune_groups = {item_group(r) for r in tune.datasets["psb"].refs}
    assert line.startswith("Split: only the report half is shown.") and "SHA-1(group name)" in line
    assert f"psb: {len(cfg.datasets['psb'].refs)} items in {len(rep_groups)} groups ({', '.join(rep_groups)})" in line
    assert f"{len(tune.datasets['psb'].refs)} tune items left out" in line
    assert not any(f"{g}," in line or f"{g})" in line for g in tune_groups)
    assert line.endswith("Items with rows in this run: 3.")
    assert _split_note(tmp_path / "nothing", rows) is None  # a run without a split says nothing


@pytest.mark.parametrize("options, methods, key", [
    ({"n_segments": "human-mode"}, [{"plugin": "seeded-walk"}], "tasks[0].methods[0].plugin"),
    ({"clicks": {}}, [{"plugin": "csc"}, {"plugin": "ncut"}], "tasks[0].methods[1].plugin"),
    ({"n_segments": "mode"}, None, "tasks[0].options.n_segments"),
    ({"n_segments": 1}, None, "tasks[0].options.n_segments"),
    ({"face_weights": "volume"}, None, "tasks[0].options.face_weights"),
    ({"clicks": {"n_must": 1}}, None, "tasks[0].options.clicks"),
    ({"clicks": {"n_must_per_segment": 0}}, None, "tasks[0].options.clicks"),
    ({"human_consistency": 1}, None, "tasks[0].options.human_consistency"),
    ({"click": {}}, None, "tasks[0].options.click"),
])
def test_bad_segmentation_option_is_refused_naming_the_key(shared_data, options, methods, key):
    with pytest.raises(ConfigError) as err:
        parse_config(_config(shared_data, options=options, methods=methods))
    assert err.value.key == key


def test_cli_refuses_a_bad_split_in_one_line(shared_data, tmp_path):
    _psb(shared_data)
    cfg = tmp_path / "c.toml"
    cfg.write_text('[run]\nsplit = { half = "report", colour = "red" }\n[[datasets]]\nkind = "psb"\npath = "psb"\n'
                   '[[tasks]]\ntask = "segmentation"\n[[tasks.methods]]\nplugin = "ncut"\n')
    env = {**os.environ, "PYTHONPATH": str(REPO), "TOOLKIT_DATA": str(shared_data)}
    res = subprocess.run([sys.executable, "-m", "shape_toolkit", "bench", "run", str(cfg), "-o", str(tmp_path / "r")],
                         capture_output=True, text=True, env=env, timeout=120)
    assert res.returncode == 2
    assert len(res.stderr.strip().splitlines()) == 1 and "run.split.colour" in res.stderr
    assert not (tmp_path / "r").exists()  # refused before any work


# -- per-item k reaches the plugin -------------------------------------------------------------
def test_per_item_k_reaches_the_plugin(shared_data, tmp_path):
    from shape_toolkit.bench.plan import plan
    from shape_toolkit.bench.worker import execute_job, prepare_job

    raw = _config(shared_data, run={"split": {"half": "report"}},
                  options={"n_segments": "human-mode", "human_consistency": True, "clicks": {"n_must_per_segment": 1}},
                  methods=[{"plugin": "csc", "label": "csc-vertex", "params": {"graph": "vertex"}},
                           {"plugin": "csc", "params": {"n_segments": 3}}])
    cfg = parse_config(raw)
    jobs, preps = plan(cfg, tmp_path / "run", limit=2)
    names = [r.name for r in cfg.datasets["psb"].refs[:2]]
    want = {r.name: consensus_segment_count(truth_segment_counts(r)) for r in cfg.datasets["psb"].refs[:2]}
    assert {j.item for j in jobs} == set(names)
    for j in jobs:
        assert j.category == item_group(next(r for r in cfg.datasets["psb"].refs if r.name == j.item))
        if j.method_label == "csc-vertex":
            assert j.item_params == {"n_segments": want[j.item]}
            assert any(s.k >= want[j.item] for s in j.item_specs)  # the spectrum the per-item k needs
        else:  # a method's own n_segments wins; the human row has none
            assert j.item_params == {}
    assert {j.method_label for j in jobs} == {"csc-vertex", "csc", "human"}
    first = [j for j in jobs if j.item == names[0]]
    pinfo = prepare_job(preps[first[0].prepare_key])
    assert pinfo["error"] is None
    for j in first:
        if j.method_label == "csc":
            continue
        row = execute_job(j, pinfo)
        assert row["status"] == "ok", row.get("error")
        assert row["category"] == j.category
        if j.method_label == "csc-vertex":
            assert row["item_params"] == {"n_segments": want[j.item]}
            assert row["metrics"]["n_segments_given"] == row["metrics"]["n_segments"] == want[j.item]
        else:
            assert 0 < row["metrics"]["rand_index_error"] < 0.3
