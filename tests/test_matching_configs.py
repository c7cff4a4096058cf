"""The benchmark configs that replaced the matching scripts (issue 28) stay valid: every plugin, preset,
pipeline, peer and option they name exists, and they plan the rows their results files were made with."""

from __future__ import annotations

from pathlib import Path

import pytest

from shape_toolkit.bench.config import load_config

CONFIGS = Path(__file__).resolve().parent.parent / "benchmarks" / "configs"


def test_photometric_seeds_config_plans_its_rows():
    """Generated data only, 5 seeds x 2 pairs (pose 1 -> 2, pose 0 -> 2): (clean + 3 glue strengths + 3 colour
    noises + 3 glue strengths then colour noise) x 3 sparse matchers, (clean + 3 glue strengths) x 4 dense methods,
    (3 colour noises + 3 glued noisy) x the colour-seeded chain, 3 glued noisy x 2 geometric peers (`topo-robust`,
    pyFM: the same targets as the colour chain's)."""
    cfg = load_config(CONFIGS / "photometric_seeds.toml")
    assert cfg.planned_rows == 5 * 2 * (10 * 3 + 4 * 4 + 6 + 3 * 2)
    assert all([r.name for r in d.refs] == ["pose1", "pose0-pose2"] for d in cfg.datasets.values())
    assert all([r.params.get("target_index") for r in d.refs] == [None, 2] for d in cfg.datasets.values())
    seeds, dense, colours, peers = cfg.tasks
    assert all(t.options["score_on"] == "clean" for t in cfg.tasks)
    assert {m.method_label.split("(")[0] for m in seeds.methods} == {"photometric", "photometric-norefine",
                                                                     "replicator"}
    assert all(m.keypoints is not None for m in seeds.methods)
    assert {m.method_label for m in dense.methods} == {"pipeline:topo-robust-photometric", "pipeline:topo-robust",
                                                       "pipeline:zoomout", "peer:pyfm"}
    assert {c.kind for c in colours.corruptions} == {"color-noise", "glue+color-noise"}
    # the peers see the very targets the colour chain sees: the same corruption entries, hence the same seeds
    assert [c.name for c in peers.corruptions] == [c.name for c in colours.corruptions if c.kind != "color-noise"]
    assert {m.method_label for m in peers.methods} == {"pipeline:topo-robust", "peer:pyfm"}
    glued_noisy = [c for c in seeds.corruptions if c.kind == "glue+color-noise"]
    assert [c.name for c in glued_noisy] == [f"glued-noisy[glue:{s}+color-noise:0.05]" for s in (1, 3, 6)]
    assert [c.strength for c in glued_noisy] == [1, 3, 6]  # plotted against the contacts


@pytest.mark.parametrize(("name", "rows"), [("tosca_matching", 24 * 8), ("repeatability", 24 * 6),
                                            ("matching_field", 235),
                                            ("heat", 6),  # hks + spectrum at 2 sizes, heat-distance + spectrum at 1
                                            ("segmentation_metrics", 4)])
def test_shared_data_configs_plan_their_rows(name, rows, shared_data, monkeypatch):
    monkeypatch.setenv("TOOLKIT_DATA", str(shared_data))
    assert load_config(CONFIGS / f"{name}.toml").planned_rows == rows


def test_tosca_matching_scores_every_truth_point_with_dijkstra(shared_data, monkeypatch):
    """The former script's protocol: all 5,000 ground-truth points, Dijkstra geodesics."""
    monkeypatch.setenv("TOOLKIT_DATA", str(shared_data))
    (task,) = load_config(CONFIGS / "tosca_matching.toml").tasks
    assert task.options["geodesic_method"] == "dijkstra" and task.options["truth_sample"] >= 5000


def test_cloud_matching_config_matches_two_clouds_on_report_pairs(shared_data, monkeypatch):
    """Both shapes become clouds and are scored on the clean mesh; only report-half pairs (no dog, FAUST
    people 2-4); 7 pairs x (3 mesh rows + 4 cloud settings, with and without the meshes' normals, x 2 pipelines)
    = 133 rows."""
    monkeypatch.setenv("TOOLKIT_DATA", str(shared_data))
    cfg = load_config(CONFIGS / "cloud_matching.toml")
    assert cfg.planned_rows == 133
    clouds = next(t for t in cfg.tasks if t.task_name == "clouds")
    assert clouds.options["corrupt"] == "both" and clouds.options["score_on"] == "clean"
    assert sorted(str(c.params.get("normals")) for c in clouds.corruptions) == ["None"] * 4 + ["True"] * 4
    items = [r.name for d in cfg.datasets.values() for r in d.refs]
    assert len(items) == 7 and not any("dog" in i for i in items)
    people = [int(s[-3:]) // 10 for i in items if i.startswith("tr_reg") for s in i.split("-")]
    assert people and min(people) >= 2


def test_plt_alignment_config_is_the_former_scripts_protocol_on_the_report_shapes(shared_data, monkeypatch):
    """The former plt_alignment.py: 13 report shapes (wolves, cats, FAUST subjects 1-4; no dog, no subject 0)
    x holes 2/4 and shortcuts 1/3 drawn with random_state 0 x 3 variants, each to a copy of itself, 8 cells."""
    from shape_toolkit.bench.plan import plan

    monkeypatch.setenv("TOOLKIT_DATA", str(shared_data))
    cfg = load_config(CONFIGS / "plt_alignment.toml")
    assert cfg.planned_rows == 13 * 4 * 3
    (task,) = cfg.tasks
    assert task.options["target"] == "self" and task.options["label_segments"] == 8
    assert set(task.metrics) == {"soft_label_transfer", "label_transfer"}
    assert [(m.preset, m.params) for m in task.methods] == [
        (None, {}), ("thesis", {}), (None, {"alignment": "histogram", "holes": "keep", "side": "none"})]
    items = [r.name for d in cfg.datasets.values() for r in d.refs]
    assert len(items) == 13 and not any(i.startswith("dog") or i.startswith("tr_reg_00") for i in items)
    jobs, preps = plan(cfg, "unused-run-folder", limit=1)
    assert {p.seed for p in preps.values()} == {0} and {j.corruption_seed for j in jobs} == {0}


def test_partial_matching_config_crops_the_source_of_report_pairs(shared_data, monkeypatch):
    """Issue 29's partial benchmark: the source cropped at 10/30/50% (and whole), matched to the whole target and
    scored on it; only report-half pairs (cats and wolves, FAUST people 2-4: `partial` was developed on dogs and
    people 0-1); 15 pairs x 4 settings x (partial, zoomout, pyFM) = 180 rows."""
    monkeypatch.setenv("TOOLKIT_DATA", str(shared_data))
    cfg = load_config(CONFIGS / "partial_matching.toml")
    assert cfg.planned_rows == 180
    (task,) = cfg.tasks
    assert task.options["corrupt"] == "source" and task.options["score_on"] == "clean"
    assert {m.method_label for m in task.methods} == {"pipeline:partial", "pipeline:zoomout", "peer:pyfm"}
    items = [r.name for d in cfg.datasets.values() for r in d.refs]
    assert len(items) == 15 and not any("dog" in i for i in items)
    people = [int(s[-3:]) // 10 for i in items if i.startswith("tr_reg") for s in i.split("-")]
    assert people and min(people) >= 2
