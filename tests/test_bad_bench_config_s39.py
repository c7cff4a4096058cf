"""Extreme and malformed values in a benchmark config and in ``bench run / report`` options: each is refused
before any work, naming the key and the reason (a typed error in Python; one line and exit 2 from the CLI)."""

from __future__ import annotations

import math

import pytest
from helpers import raw_config, time_budget

from shape_toolkit.bench import executors
from shape_toolkit.bench.config import ConfigError, parse_config
from shape_toolkit.bench.report import write_report
from shape_toolkit.cli import main
from shape_toolkit.errors import ParameterError

BIG = int("9" * 400)  # TOML integers have any number of digits

_cfg = raw_config


def _refused(raw, key, *words, max_rows=1000):
    with pytest.raises(ConfigError) as exc:
        parse_config(raw, max_rows=max_rows)
    assert exc.value.key == key, str(exc.value)
    for w in words:
        assert w in str(exc.value)
    assert "\n" not in str(exc.value) and len(str(exc.value)) < 400
    return exc.value


@pytest.mark.parametrize("key", ["datasets.0.params.max_angle", "datasets.0.params.subdivisions"])
def test_a_400_digit_integer_is_a_config_error_not_an_overflow(key):
    _refused(_cfg(**{key: BIG}), key.replace(".0.", "[0]."), "finite number", "400 digits")


def test_a_400_digit_corruption_strength_is_a_config_error():
    raw = _cfg()
    raw["corruptions"] = [{"name": "n", "kind": "gaussian-noise", "params": {"strength": [0.1, BIG]}}]
    raw["tasks"][0]["corruptions"] = ["n"]
    _refused(raw, "corruptions[0].params.strength", "400 digits")


@pytest.mark.parametrize("value", [-1, 8, 1e308, 2.5])
def test_generated_subdivisions_out_of_the_icospheres_range(value):
    _refused(_cfg(**{"datasets.0.params.subdivisions": value}), "datasets[0].params.subdivisions", "[0, 7]")


@pytest.mark.parametrize("kind,value", [("synthetic", -1), ("synthetic", 1e308), ("sequence", 2.0)])
def test_generated_max_angle_out_of_range(kind, value):
    raw = _cfg()
    raw["datasets"][0] = {"name": "syn", "kind": kind, "params": {"max_angle": value}}
    if kind == "sequence":
        raw["tasks"] = [{"task": "sequence", "methods": [{"pipeline": "zoomout"}]}]
    _refused(raw, "datasets[0].params.max_angle", "rad")


def test_sequence_frames_past_the_row_cap():
    raw = _cfg()
    raw["datasets"][0] = {"name": "seq", "kind": "sequence", "params": {"frames": 10**9}}
    raw["tasks"] = [{"task": "sequence", "methods": [{"pipeline": "zoomout"}]}]
    _refused(raw, "datasets[0].params.frames", "1,000,000,000 frames", "--max-rows")


@pytest.mark.parametrize("option,value", [("repeats", 10**9), ("repeats", BIG), ("blas_threads", BIG),
                                          ("blas_threads", 10**6)])
def test_repeats_and_blas_threads_have_an_upper_bound(option, value):
    _refused(_cfg(**{"tasks.0.options": {option: value}}), f"tasks[0].options.{option}", "must be an integer in [1, ")


@pytest.mark.parametrize("option,value", [
    ("scree_fractions", [math.nan]), ("scree_fractions", [-1.0]), ("scree_fractions", [2]), ("scree_fractions", []),
    ("scree_fractions", "x"), ("scree_fractions", [BIG]), ("scree_times", [math.inf]), ("scree_times", [-1.0]),
    ("scree_times", ["x"]), ("scree_times", [1e308]), ("scree_times_for_K", [math.nan]), ("scree_times_for_K", [True]),
])
def test_spectrum_scree_options_are_checked(option, value):
    _refused(_cfg(**{"tasks.0.options": {option: value}}), f"tasks[0].options.{option}", "non-empty list")


def test_spectrum_scree_defaults_and_good_values_pass():
    cfg = parse_config(_cfg(**{"tasks.0.options": {"scree_fractions": [0.5, 1], "scree_times": [0, 10]}}))
    assert cfg.tasks[0].options["scree_fractions"] == [0.5, 1]
    assert parse_config(_cfg()).planned_rows == 1


def test_two_methods_with_one_label_are_refused():
    raw = _cfg(**{"tasks.0.methods": [{"plugin": "cotangent", "label": "A"}, {"plugin": "binary", "label": "A"}]})
    _refused(raw, "tasks[0].methods[1].label", "'A'", "distinct label")


def test_one_method_listed_twice_is_refused():
    raw = _cfg(**{"tasks.0.methods": [{"plugin": "cotangent", "label": "x"}, {"plugin": "cotangent", "label": "y"}]})
    _refused(raw, "tasks[0].methods[1]", "the same method as tasks[0].methods[0]")


def test_a_grid_and_distinct_parameters_keep_one_label():
    one = parse_config(_cfg(**{"tasks.0.methods": [{"plugin": "cotangent",
                                                     "params": {"clamp_negative": [True, False]}}]}))
    assert len(one.tasks[0].methods) == 2
    two = parse_config(_cfg(**{"tasks.0.methods": [{"plugin": "cotangent", "params": {"clamp_negative": True}},
                                                     {"plugin": "cotangent"}]}))
    assert len(two.tasks[0].methods) == 2


@pytest.mark.parametrize("workers", [10**9, BIG, True])
def test_workers_are_bounded_before_a_cluster_starts(tmp_path, monkeypatch, workers):
    def no_cluster(*a, **k):  # the former code got here with a billion workers
        raise AssertionError("a Dask cluster was started")

    monkeypatch.setattr(executors, "dask_client", no_cluster)
    cfg = parse_config(_cfg())
    with time_budget(60), pytest.raises(ParameterError, match=r"workers must be an integer in \[1, "):
        executors.run_benchmark(cfg, tmp_path / "run", workers=workers, progress=False)
    assert not (tmp_path / "run" / "results.jsonl").exists()


def test_report_renders_must_not_be_negative(tmp_path):
    with pytest.raises(ParameterError, match="renders must be an integer >= 0"):
        write_report(tmp_path / "missing-run", renders=-1)


def test_cli_a_400_digit_integer_is_one_line_exit_2(tmp_path, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text('[[datasets]]\nname = "syn"\nkind = "synthetic"\nlimit = 1\n'
                   f"params = {{ n_poses = 2, subdivisions = 1, max_angle = {BIG} }}\n"
                   '[[tasks]]\ntask = "spectrum"\nspectrum = { k = 5 }\n[[tasks.methods]]\nplugin = "cotangent"\n')
    assert main(["bench", "run", str(cfg), "-o", str(tmp_path / "run"), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "datasets[0].params.max_angle" in err[0] and "400 digits" in err[0], err
    assert not (tmp_path / "run" / "results.jsonl").exists()


@pytest.mark.parametrize("params,key,words", [
    ({"seeds": [0, 2**32]}, "datasets[0].params.seeds[1]", "2**32 - 1"),
    ({"seeds": BIG}, "datasets[0].params.seeds", "400 digits"),
    ({"remesh": 10**9, "subdivisions": 1}, "datasets[0].params.remesh", "at most 840"),
    ({"remesh": BIG}, "datasets[0].params.remesh", "400 digits"),
])
def test_sequence_seeds_and_remesh_are_bounded(params, key, words):
    raw = _cfg()
    raw["datasets"][0] = {"name": "seq", "kind": "sequence", "params": params}
    raw["tasks"] = [{"task": "sequence", "methods": [{"pipeline": "zoomout"}]}]
    _refused(raw, key, words)


def test_corruption_attempts_and_heat_times_are_bounded():
    """A centre-drawing corruption with an absurd ``attempts`` and a heat descriptor with an absurd ``n_times`` are
    refused up front (before: crop with attempts 1e9 on a shape no centre fits ran for hours, and hks with n_times
    1e9 asked for gigabytes)."""
    from shape_toolkit.api.registry import create_plugin
    from shape_toolkit.data.corruptions import MAX_ATTEMPTS, crop, holes
    from shape_toolkit.data.generate import icosphere
    from shape_toolkit.errors import ParameterError
    from shape_toolkit.plugins.descriptors.heat_spectrum import MAX_TIMES

    s = icosphere(2)
    for f in (crop, holes):
        with pytest.raises(ParameterError, match="attempts"):
            f(s, strength=0.3 if f is crop else 1, attempts=MAX_ATTEMPTS + 1)
    crop(s, strength=0.3, attempts=MAX_ATTEMPTS)  # the bound itself is accepted (the first centre fits)
    for name in ("hks", "heat-diffusion", "heat-distance"):  # parameters are checked when the plugin computes
        with pytest.raises(ParameterError, match="n_times"):
            create_plugin("descriptors", name, n_times=MAX_TIMES + 1).compute(s)
    assert create_plugin("descriptors", "hks", n_times=MAX_TIMES).compute(s).shape == (s.n_vertices, MAX_TIMES)
