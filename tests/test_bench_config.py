"""Benchmark configs are validated before any work, and errors name the bad key."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest
from helpers import spectrum_config

from shape_toolkit.bench.config import ConfigError, expand_grid, load_config, parse_config
from shape_toolkit.cli import main

BASE = """
[run]
name = "t"
random_state = 3
[[datasets]]
name = "synth"
kind = "synthetic"
params = { n_poses = 2, subdivisions = 2 }
[[corruptions]]
name = "noise"
kind = "gaussian-noise"
params = { strength = [0.1, 0.2] }
[[tasks]]
task = "segmentation"
corruptions = ["none", "noise"]
metrics = ["n_segments"]
[[tasks.methods]]
plugin = "spectral-clustering"
preset = "luxburg-unnormalized"
params = { n_segments = [3, 6] }
"""


def _write(tmp_path, text, name="c.toml"):
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def test_valid_config_expands_grids(tmp_path):
    cfg = load_config(_write(tmp_path, BASE))
    assert cfg.name == "t" and cfg.random_state == 3
    (task,) = cfg.tasks
    assert [m.params["n_segments"] for m in task.methods] == [3, 6]
    assert [c.name for c in task.corruptions] == ["none", "noise[strength=0.1]", "noise[strength=0.2]"]
    assert [c.strength for c in task.corruptions] == [0.0, 0.1, 0.2]
    assert len(cfg.datasets["synth"].refs) == 2


def test_expand_grid_literal_lists():
    assert expand_grid({"a": [1, 2], "b": "x"}) == [{"a": 1, "b": "x"}, {"a": 2, "b": "x"}]
    assert expand_grid({"times": [[1, 2]]}) == [{"times": [1, 2]}]


@pytest.mark.parametrize(
    "old,new,key",
    [
        ('plugin = "spectral-clustering"', 'plugin = "no-such-method"', "tasks[0].methods[0].plugin"),
        (
            "params = { n_segments = [3, 6] }",
            "params = { n_segmentz = 3 }",
            "tasks[0].methods[0].params.n_segmentz",
        ),
        ('preset = "luxburg-unnormalized"', 'preset = "nope"', "tasks[0].methods[0].preset"),
        ('kind = "gaussian-noise"', 'kind = "melt"', "corruptions[0].kind"),
        ("params = { strength = [0.1, 0.2] }", "params = { sigma = 1 }", "corruptions[0].params.sigma"),
        ('corruptions = ["none", "noise"]', 'corruptions = ["none", "fog"]', "tasks[0].corruptions[1]"),
        ('metrics = ["n_segments"]', 'metrics = ["nope"]', "tasks[0].metrics[0]"),
        ('task = "segmentation"', 'task = "painting"', "tasks[0].task"),
        ('kind = "synthetic"', 'kind = "psb"\npath = "no/such/folder"', "datasets[0].path"),
        ("[run]", "[runn]", "runn"),
        ('name = "t"', 'name = "t"\nworkers = 2', "run.workers"),
    ],
)
def test_bad_config_names_the_key(tmp_path, old, new, key):
    assert old in BASE
    with pytest.raises(ConfigError) as ei:
        load_config(_write(tmp_path, BASE.replace(old, new, 1)))
    assert ei.value.key == key, str(ei.value)
    assert key in str(ei.value)


def test_relative_paths_use_toolkit_data(tmp_path, monkeypatch):
    data = tmp_path / "data"
    (data / "shapes").mkdir(parents=True)
    from shape_toolkit.data.generate import icosphere
    from shape_toolkit.io.mesh import save_shape

    save_shape(icosphere(1), data / "shapes" / "ball.off")
    raw = {
        "datasets": [{"name": "d", "kind": "folder", "path": "shapes"}],
        "tasks": [{"task": "spectrum", "methods": [{"plugin": "cotangent"}], "spectrum": {"k": 5}}],
    }
    monkeypatch.setenv("TOOLKIT_DATA", str(data))
    cfg = parse_config(raw)
    assert cfg.datasets["d"].path == str(data / "shapes")
    monkeypatch.delenv("TOOLKIT_DATA")
    cfg = parse_config(raw, base=data)  # else relative to the config's folder
    assert cfg.datasets["d"].path == str(data / "shapes")
    with pytest.raises(ConfigError, match=r"datasets\[0\]\.path"):
        parse_config(raw, base=tmp_path)


def test_cli_bad_config_fails_before_work(tmp_path, capsys):
    cfg = _write(tmp_path, BASE.replace('plugin = "spectral-clustering"', 'plugin = "nope"'))
    run = tmp_path / "run"
    assert main(["bench", "run", str(cfg), "-o", str(run)]) == 2
    err = capsys.readouterr().err
    assert "tasks[0].methods[0].plugin" in err and "nope" in err
    assert not run.exists()
    bad = _write(tmp_path, "[[datasets]\n", "bad.toml")
    assert main(["bench", "run", str(bad), "-o", str(run)]) == 2
    assert "invalid TOML" in capsys.readouterr().err


SPECTRUM_TASK = spectrum_config("gaussian")


def test_spectrum_table_is_the_subject_of_the_spectrum_task_only(tmp_path):
    cfg = load_config(_write(tmp_path, SPECTRUM_TASK))
    (task,) = cfg.tasks
    assert (task.task_kind, task.task_name, task.spectrum["k"]) == ("spectrum", "spectrum", 8)
    assert task.methods[0].plugin == "gaussian" and task.methods[0].method_label == "gaussian"
    with pytest.raises(ConfigError) as ei:
        load_config(_write(tmp_path, SPECTRUM_TASK.replace("{ k = 8 }", '{ k = 8, weighting = "nope" }')))
    assert ei.value.key == "tasks[0].spectrum.weighting"
    # elsewhere methods receive the spectra they declare: a spectrum table would mislead
    bad = BASE.replace('corruptions = ["none", "noise"]\n', 'corruptions = ["none", "noise"]\nspectrum = { k = 8 }\n')
    with pytest.raises(ConfigError) as ei:
        load_config(_write(tmp_path, bad))
    assert ei.value.key == "tasks[0].spectrum"
    assert "receive the spectra they declare" in str(ei.value)
    bad = BASE.replace('preset = "luxburg-unnormalized"', 'preset = "luxburg-unnormalized"\nspectrum = { k = 8 }')
    with pytest.raises(ConfigError) as ei:
        load_config(_write(tmp_path, bad))
    assert ei.value.key == "tasks[0].methods[0].spectrum"
    assert "receive the spectra they declare" in str(ei.value)


def test_missing_dataset_folder_mentions_toolkit_data(tmp_path, monkeypatch):
    bad = BASE.replace('kind = "synthetic"', 'kind = "psb"\npath = "no/such/folder"')
    monkeypatch.delenv("TOOLKIT_DATA", raising=False)
    with pytest.raises(ConfigError, match=r"\$TOOLKIT_DATA.*not\)"):
        load_config(_write(tmp_path, bad))
    monkeypatch.setenv("TOOLKIT_DATA", str(tmp_path / "data"))
    with pytest.raises(ConfigError) as ei:
        load_config(_write(tmp_path, bad))
    assert f"$TOOLKIT_DATA={tmp_path / 'data'}" in str(ei.value)
    assert str(tmp_path / "data" / "no" / "such" / "folder") in str(ei.value)


R_SMOOTH = """
[[datasets]]
name = "synth"
kind = "synthetic"
params = { n_poses = 2, subdivisions = 2 }
[[tasks]]
task = "matching"
metrics = ["geodesic_error", "r_smoothness", "label_transfer"]
[tasks.options]
geodesic_method = "dijkstra"
truth_sample = 50
r_smooth_rs = [1, 5]
r_smooth_sample = 60
label_segments = 5
[[tasks.methods]]
plugin = "eigvec-alignment"
"""


def test_matching_metrics_r_smoothness_and_derived_labels(tmp_path):
    from shape_toolkit.bench.report import write_report
    from shape_toolkit.bench.runner import read_rows, run_benchmark
    from shape_toolkit.bench.store import load_output, load_prepared, prepared_path
    from shape_toolkit.metrics import map_label_scores, r_smoothness_table, truth_segments

    cfg = load_config(_write(tmp_path, R_SMOOTH))
    run = tmp_path / "run"
    s = run_benchmark(cfg, run, limit=1, progress=False)
    (row,) = read_rows(run)
    assert s.failed == 0, row.get("error")
    m = row["metrics"]
    assert {"r_smooth@1", "r_smooth@5", "r_smoothness_curve", "label_recall", "label_precision"} <= set(m)
    # the columns are the metric functions called directly on the run's shapes and map
    prep = load_prepared(prepared_path(run, row["prepare_key"]))
    t = load_output(run, row["output"])["target_of"]
    table = r_smoothness_table(prep.source, prep.target, t, (1, 5), sample=60)
    assert m["r_smooth@1"] == table[1.0] and m["r_smooth@5"] == table[5.0]
    assert m["r_smoothness_curve"] == [[1.0, table[1.0]], [5.0, table[5.0]]]
    ls, lt = truth_segments(prep.source, prep.target, prep.truth[:, 0], prep.truth[:, 1], 5)
    sc = map_label_scores(t, ls, lt, prep.target)
    assert m["label_recall"] == sc["recall"] and m["label_precision"] == sc["precision"]
    html = write_report(run, renders=0)["html"].read_text()
    assert "r_<wbr>smooth@5 (%) &uarr;" in html and "label_<wbr>recall" in html  # headers may break after _


@pytest.mark.parametrize(
    "old,new,problem",
    [
        ('"r_smoothness", ', '"r_smoothnes", ', "unknown matching metric 'r_smoothnes'; known: coverage, "
         "geodesic_error, label_transfer, r_smoothness"),
        ("r_smooth_rs = [1, 5]", "r_smooth_rs = [0, 5]", "r_smooth_rs must be a non-empty list"),
        ("r_smooth_sample = 60", "r_smooth_sample = 0", "r_smooth_sample must be a positive integer"),
        ("label_segments = 5", "label_segments = true", "label_segments must be a positive integer"),
        ("truth_sample = 50", "r_smooth_theta = 2\ntruth_sample = 50", "r_smooth_theta must be in (0, 1]"),
        ("truth_sample = 50", "r_smooth_typo = 2\ntruth_sample = 50", "unknown matching option 'r_smooth_typo'"),
    ],
)
def test_matching_metric_and_option_errors_list_the_valid_ones(tmp_path, old, new, problem):
    with pytest.raises(ConfigError) as e:
        load_config(_write(tmp_path, R_SMOOTH.replace(old, new)))
    assert problem in str(e.value)
    assert e.value.key.startswith("tasks[0].metrics[1]" if "metric " in problem else "tasks[0].options")


def test_peer_methods_run_side_by_side(tmp_path, monkeypatch):
    import numpy as np

    from shape_toolkit.bench import peers
    from shape_toolkit.bench.runner import read_rows, run_benchmark

    calls = []

    def identity(source, target):  # a stand-in peer: the exact map of the generated poses
        calls.append(source.n_vertices)
        return np.arange(source.n_vertices)

    monkeypatch.setitem(peers.PEERS, "identity", (identity, "numpy", "numpy"))
    text = R_SMOOTH.replace('plugin = "eigvec-alignment"', 'peer = "identity"\nlabel = "exact"')
    cfg = load_config(_write(tmp_path, text))
    (m,) = cfg.tasks[0].methods
    assert (m.family, m.plugin, m.method_label) == ("peers", "identity", "exact")
    run_benchmark(cfg, tmp_path / "run", limit=1, progress=False)
    (row,) = read_rows(tmp_path / "run")
    assert row["status"] == "ok", row.get("error")
    assert calls and row["method_label"] == "exact"
    assert row["metrics"]["mean_geodesic_error"] == 0.0 and row["metrics"]["label_recall"] == 1.0
    assert row["metrics"]["r_smooth@5"] > 50  # the poses are near-isometric, not isometric


@pytest.mark.parametrize("method, key, problem", [
    ('peer = "nope"', "peer", "unknown peer 'nope'; known: maps, pyfm"),
    ('peer = "pyfm"\nparams = { k = 3 }', "params", "not allowed with peer"),
])
def test_peer_errors_name_the_key(tmp_path, method, key, problem):
    with pytest.raises(ConfigError) as e:
        load_config(_write(tmp_path, R_SMOOTH.replace('plugin = "eigvec-alignment"', method)))
    assert e.value.key == f"tasks[0].methods[0].{key}" and problem in str(e.value)
    seg = BASE.replace('plugin = "spectral-clustering"\npreset = "luxburg-unnormalized"\n'
                       'params = { n_segments = [3, 6] }', 'peer = "pyfm"')
    with pytest.raises(ConfigError, match="peers are matching methods"):
        load_config(_write(tmp_path, seg, "seg.toml"))


COMPOSED = BASE.replace('''[[tasks]]''', '''[[corruptions]]
name = "glued-noisy"
steps = [{ kind = "glue", params = { strength = 6 } },
         { kind = "color-noise", params = { strength = [0.05, 0.1], gain = 0.9 } }]
[[corruptions]]
steps = [{ kind = "gaussian-noise", params = { strength = [0.1, 0.2] } }, { kind = "glue" }]
[[tasks]]''').replace('corruptions = ["none", "noise"]',
                      'corruptions = ["none", "glued-noisy", "gaussian-noise+glue"]')


def test_composed_corruptions_expand_every_step_grid_and_name_their_steps(tmp_path):
    (task,) = load_config(_write(tmp_path, COMPOSED)).tasks
    assert [c.name for c in task.corruptions] == [
        "none", "glued-noisy[glue:6+color-noise:0.05]", "glued-noisy[glue:6+color-noise:0.1]",
        "gaussian-noise:0.1+glue:4", "gaussian-noise:0.2+glue:4"]  # unnamed: the steps; glue's default strength
    c = task.corruptions[2]
    assert c.kind == "glue+color-noise" and c.group == "glued-noisy"
    assert c.params == {"steps": [{"strength": 6}, {"strength": 0.1, "gain": 0.9}]}
    assert [x.strength for x in task.corruptions] == [0.0, 0.05, 0.1, 0.1, 0.2]  # the swept step's strength
    one = COMPOSED.replace('} }, { kind = "glue" }]', "} }]")
    one = one.replace('"gaussian-noise+glue"]', '"gaussian-noise"]')
    (task,) = load_config(_write(tmp_path, one)).tasks  # one step is the corruption itself, named as one
    assert [(c.name, c.kind, c.params) for c in task.corruptions[3:]] == [
        ("gaussian-noise[strength=0.1]", "gaussian-noise", {"strength": 0.1}),
        ("gaussian-noise[strength=0.2]", "gaussian-noise", {"strength": 0.2})]


@pytest.mark.parametrize(
    "steps,key,problem",
    [
        ('[{ kind = "glue" }, { kind = "melt" }]', "corruptions[2].steps[1].kind", "unknown corruption 'melt'"),
        ("[]", "corruptions[2].steps", "non-empty array"),
        ('"glue"', "corruptions[2].steps", "non-empty array"),
        ('["glue"]', "corruptions[2].steps[0]", "must be a table"),
        ('[{ kind = "glue", params = { sigma = 1 } }, { kind = "scale" }]', "corruptions[2].steps[0].params.sigma",
         "no such parameter"),
        ('[{ kind = "glue", params = { strength = "x" } }, { kind = "scale" }]',
         "corruptions[2].steps[0].params.strength", "finite number"),
        ('[{ kind = "glue", seed = 1 }, { kind = "scale" }]', "corruptions[2].steps[0].seed", "unknown key"),
        ('[{ params = {} }, { kind = "scale" }]', "corruptions[2].steps[0].kind", "is required"),
    ],
)
def test_bad_composed_corruptions_name_the_key(tmp_path, steps, key, problem):
    text = COMPOSED.replace('steps = [{ kind = "gaussian-noise", params = { strength = [0.1, 0.2] } }, '
                            '{ kind = "glue" }]', f"steps = {steps}")
    with pytest.raises(ConfigError) as ei:
        load_config(_write(tmp_path, text))
    assert ei.value.key == key and problem in str(ei.value), str(ei.value)
    with pytest.raises(ConfigError) as ei:  # kind and steps together
        both = COMPOSED.replace('name = "glued-noisy"\n', 'name = "glued-noisy"\nkind = "glue"\n')
        load_config(_write(tmp_path, both))
    assert ei.value.key == "corruptions[1].kind" and "steps" in str(ei.value)


def test_cli_refuses_a_bad_composed_corruption_in_one_line(tmp_path, capsys):
    cfg = _write(tmp_path, COMPOSED.replace('{ kind = "glue" }]', '{ kind = "melt" }]'))
    assert main(["bench", "run", str(cfg), "-o", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "corruptions[2].steps[1].kind" in err and "melt" in err
    assert not (tmp_path / "run").exists()


def test_a_synthetic_pair_item_names_any_two_poses(tmp_path):
    """``items = ["pose0-pose2"]`` pairs pose 0 with pose 2 (named as TOSCA's pairs); ``pose1`` is still
    pose 1 -> pose 2; a pose the dataset lacks is refused naming the item."""
    from shape_toolkit.data.datasets import load_item
    from shape_toolkit.data.synthetic import synthetic_dataset

    text = BASE.replace("n_poses = 2, subdivisions = 2", "n_poses = 3, subdivisions = 2, random_state = 5")
    text = text.replace('kind = "synthetic"', 'kind = "synthetic"\nitems = ["pose0-pose2", "pose1", "pose2-pose0"]')
    refs = load_config(_write(tmp_path, text)).datasets["synth"].refs
    assert [r.name for r in refs] == ["pose0-pose2", "pose1", "pose2-pose0"]
    poses = synthetic_dataset(n_poses=3, subdivisions=2, random_state=5)
    for ref, (i, j) in zip(refs, [(0, 2), (1, 2), (2, 0)]):
        item = load_item(ref)
        np.testing.assert_array_equal(item.shape.vertices, poses[i].shape.vertices)
        np.testing.assert_array_equal(item.target.vertices, poses[j].shape.vertices)
        np.testing.assert_array_equal(item.target.colors, poses[j].colors)
        np.testing.assert_array_equal(item.correspondence[:, 0], item.correspondence[:, 1])
    assert not np.array_equal(poses[1].shape.vertices, poses[2].shape.vertices)  # the poses differ
    for bad in ("pose0-pose3", "pose1-pose1", "pose0_pose2", "pose7"):
        with pytest.raises(ConfigError) as ei:
            load_config(_write(tmp_path, text.replace('"pose2-pose0"', f'"{bad}"')))
        assert ei.value.key == "datasets[0].items[2]" and "pose0-pose2" in str(ei.value), str(ei.value)
