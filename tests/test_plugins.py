"""The plugin system: discovery through entry points, lookup, errors, a third-party plugin."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from shape_toolkit import ParameterError, PluginError, build_graph
from shape_toolkit.api.interfaces import FAMILY_INTERFACES, BasePlugin, Weighting, Weights
from shape_toolkit.api.params import RANDOM_STATE, Interval, ListOf, Options, Param, validate_params
from shape_toolkit.api.registry import FAMILY_GROUPS, Registry, available_plugins, get_plugin
from shape_toolkit.data.generate import icosphere

REPO = Path(__file__).resolve().parent.parent


def test_every_family_is_listed_and_builtins_come_through_entry_points():
    fams = available_plugins()
    assert set(fams) == set(FAMILY_GROUPS) == set(FAMILY_INTERFACES)
    assert {"binary", "gaussian", "cotangent", "intrinsic-delaunay"} <= set(fams["weightings"])
    # built-ins register exactly as a third-party plugin: through the per-family entry points
    reg = Registry()
    for name in ("binary", "gaussian", "cotangent", "intrinsic-delaunay"):
        assert reg.entry_point("weightings", name).startswith("shape_toolkit.plugins.weightings.")
    # one entry-point line per plugin, naming its class
    for family, names in fams.items():
        for name in names:
            module, _, attr = reg.entry_point(family, name).partition(":")
            assert attr and get_plugin(family, name).__qualname__ == attr, (family, name)
    assert not reg.broken


def test_every_registered_plugin_follows_its_family_interface():
    for family, names in available_plugins().items():
        base, method = FAMILY_INTERFACES[family]
        for name in names:
            cls = get_plugin(family, name)
            assert callable(getattr(cls, method)), (family, name)
            if issubclass(cls, BasePlugin):
                obj = cls()
                assert set(obj.get_params()) == set(cls._param_names())
                assert repr(obj).startswith(cls.__name__ + "(")
                for preset, params in cls.presets.items():
                    assert set(params) <= set(obj.get_params()), (family, name, preset)


def test_unknown_names_list_the_available_ones():
    with pytest.raises(PluginError, match=r"unknown weightings plugin 'nope'; available: binary"):
        get_plugin("weightings", "nope")
    with pytest.raises(PluginError, match="unknown plugin family"):
        get_plugin("colours", "red")
    reg = Registry()
    with pytest.raises(ParameterError, match="no preset"):
        reg.create("weightings", "gaussian", preset="fast")
    with pytest.raises(ParameterError, match="no parameter 'sigma'"):
        reg.create("weightings", "gaussian", sigma=1.0)


class _Doubled(Weighting):
    def __init__(self, factor: float = 2.0):
        self.factor = factor

    def weigh(self, shape, edges):
        from shape_toolkit.core.graph import weights_from_edges

        return Weights(weights_from_edges(shape.n_vertices, edges, np.full(len(edges), self.factor)))


def test_register_in_process_and_conflicts():
    reg = Registry()
    reg.register("weightings", "doubled", _Doubled)
    obj = reg.create("weightings", "doubled", factor=3.0)
    assert obj.get_params() == {"factor": 3.0}
    obj.set_params(factor=4.0)
    assert obj.factor == 4.0
    with pytest.raises(ParameterError):
        obj.set_params(bogus=1)
    with pytest.raises(PluginError, match="two plugins register weightings 'gaussian'"):
        reg.register("weightings", "gaussian", _Doubled)  # refused at once, though 'gaussian' is not imported yet
    with pytest.raises(PluginError, match="without a segment"):
        Registry().register("segmenters", "broken", object)
    reg.unregister("weightings", "doubled")
    assert not reg.has("weightings", "doubled")


THIRD_PARTY = '''
"""A throwaway third-party weighting plugin: w_ij = 1 / edge length ** power."""
import numpy as np
from shape_toolkit.api.interfaces import Weighting, Weights
from shape_toolkit.api.params import Interval, Param
from shape_toolkit.core.graph import weights_from_edges


class InverseLength(Weighting):
    """Inverse edge lengths."""

    parameter_constraints = {"power": Param(Interval(float, 0, None, closed="neither"), doc="exponent of the length")}

    def __init__(self, power: float = 1.0):
        self.power = power

    def weigh(self, shape, edges):
        d = np.linalg.norm(shape.vertices[edges[:, 0]] - shape.vertices[edges[:, 1]], axis=1)
        return Weights(weights_from_edges(shape.n_vertices, edges, d ** -self.power),
                       info={"third_party": True})
'''


def _distribution(site: Path, entry_points: str, name: str = "tp_weights") -> None:
    """A module and the dist-info pip would write when installing a wheel that declares ``entry_points``."""
    site.mkdir(exist_ok=True)
    (site / f"{name}.py").write_text(THIRD_PARTY)
    dist = site / f"{name}-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name.replace('_', '-')}\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(entry_points)


def test_third_party_plugin_is_one_class_and_one_entry_point_line(tmp_path):
    site = tmp_path / "site"
    _distribution(site, "[shape_toolkit.weightings]\ninverse-length = tp_weights:InverseLength\n")
    mesh = tmp_path / "sphere.off"
    from shape_toolkit.io.mesh import save_shape

    save_shape(icosphere(2), mesh)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(REPO)])}

    def cli(*args):
        return subprocess.run(
            [sys.executable, "-m", "shape_toolkit", *args], env=env, capture_output=True, text=True, timeout=120
        )

    listed = cli("plugins", "list", "--json")
    assert listed.returncode == 0, listed.stderr
    assert "inverse-length" in json.loads(listed.stdout)["weightings"]
    shown = cli("plugins", "show", "inverse-length")
    assert shown.returncode == 0, shown.stderr
    assert "power = 1.0  [float] a positive float: exponent of the length" in shown.stdout
    used = cli(
        "spectrum", str(mesh), "-k", "5", "--weighting", "inverse-length", "--param", "power=2", "--json"
    )
    assert used.returncode == 0, used.stderr
    out = json.loads(used.stdout)
    assert out["weighting"] == "inverse-length" and out["graph"]["third_party"] is True
    assert len(out["eigenvalues"]) == 5 and out["eigenvalues"][0] == pytest.approx(0, abs=1e-8)
    ref = build_graph(icosphere(2), "binary")  # 1/length^2 weights differ from binary ones
    assert out["graph"]["edges"] == ref.n_edges
    refused = cli("spectrum", str(mesh), "-k", "5", "--weighting", "inverse-length", "--param", "power=-1")
    assert refused.returncode != 0
    assert "InverseLength: power must be a positive float, got -1" in refused.stderr
    # in-process: importlib.metadata finds the dist-info on sys.path; listing imports nothing
    sys.path.insert(0, str(site))
    try:
        reg = Registry()
        assert "inverse-length" in reg.names("weightings") and "tp_weights" not in sys.modules
        cls = reg.get("weightings", "inverse-length")
        assert cls.__module__ == "tp_weights" and cls.__name__ == "InverseLength"
        w = reg.create("weightings", "inverse-length", power=2.0).weigh(icosphere(1), icosphere(1).edges)
        assert w.info == {"third_party": True}
    finally:
        sys.path.remove(str(site))
        sys.modules.pop("tp_weights", None)


def test_an_entry_point_naming_a_module_is_refused_and_the_legacy_group_is_not_read(tmp_path):
    site = tmp_path / "site"
    _distribution(site, "[shape_toolkit.weightings]\nold-style = tp_weights\n[toolkit]\nlegacy = tp_weights\n")
    sys.path.insert(0, str(site))
    try:
        reg = Registry()
        assert "old-style" in reg.names("weightings")
        assert all("legacy" not in names for names in reg.families().values())
        with pytest.raises(PluginError, match="names 'tp_weights', not a class: write 'package.module:Class'"):
            reg.get("weightings", "old-style")
    finally:
        sys.path.remove(str(site))
        sys.modules.pop("tp_weights", None)


def test_every_builtin_plugin_declares_each_parameter_and_its_defaults_pass():
    for family, names in available_plugins().items():
        for name in names:
            cls = get_plugin(family, name)
            declared = cls.parameter_constraints
            assert set(declared) == set(cls._param_names()), (family, name, set(declared) ^ set(cls._param_names()))
            for pname, par in declared.items():
                assert isinstance(par, Param) and par.doc and "\n" not in par.doc, (name, pname)
                assert par.describe() and par.type_name, (name, pname)
            obj = cls()
            obj._validate_params()  # the defaults are allowed values
            for preset in cls.presets.values():
                obj.set_params(**preset)._validate_params()


def test_parameter_constraints_accept_describe_and_refuse_in_one_line():
    pos_int = Interval(int, 1)
    assert pos_int.accepts(3) and pos_int.accepts(np.int64(3))
    assert not any(pos_int.accepts(v) for v in (0, True, 2.0, "3", None))
    unit = Interval(float, 0, 1, closed="left")
    assert unit.accepts(0) and unit.accepts(0.5) and not unit.accepts(1.0) and not unit.accepts(float("nan"))
    assert unit.describe() == "a float in [0, 1)" and Interval(float, 0, None, closed="neither").describe() == (
        "a positive float")
    assert not Interval(float).accepts(float("inf")) and Interval(float).describe() == "a finite float"
    times = ListOf(Interval(float, 0, None, closed="neither"))
    assert times.accepts([1.0, 2]) and times.accepts(np.array([0.5])) and not times.accepts([]) and not times.accepts(
        [1.0, -1.0])
    bw = Param(None, Options("auto", "mean"), Interval(float, 0, None, closed="neither"), doc="bandwidth")
    assert bw.type_name == "str | float | None" and bw.describe() == "None, one of 'auto', 'mean' or a positive float"
    assert bw.accepts(None) and bw.accepts("auto") and bw.accepts(0.3) and not bw.accepts("local")
    assert RANDOM_STATE.accepts(0) and RANDOM_STATE.accepts(np.random.default_rng(0)) and not RANDOM_STATE.accepts(-1)
    with pytest.raises(ParameterError) as err:
        validate_params("GaussianWeighting", {"bandwidth": bw}, {"bandwidth": -1})
    assert str(err.value) == (
        "GaussianWeighting: bandwidth must be None, one of 'auto', 'mean' or a positive float, got -1")
    # at use, not in __init__ (scikit-learn's clone contract): construction stores anything
    from sklearn.base import clone

    g = get_plugin("weightings", "gaussian")(bandwidth="wide")
    assert clone(g).bandwidth == "wide"
    with pytest.raises(ParameterError, match=r"^GaussianWeighting: bandwidth must be .*, got 'wide'$"):
        g.weigh(icosphere(1), icosphere(1).edges)
    with pytest.raises(ParameterError, match=r"^ADFMaxima: K must be a positive int, got 0$"):
        get_plugin("keypoints", "adf-maxima")(K=0).spectrum_spec()  # spectrum_spec checks too


def test_plugins_show_prints_type_range_and_description(capsys):
    from shape_toolkit.cli import main

    assert main(["plugins", "show", "gaussian"]) == 0
    out = capsys.readouterr().out
    assert ("bandwidth = None  [str | float | None] None, one of 'auto', 'local', 'mean' or a positive float: sigma in "
            "length units") in out
    assert "bandwidth_scale = 1.0  [float] a positive float: factor on the automatic bandwidths" in out
    assert main(["plugins", "show", "csc", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    rs = {p["name"]: p for p in info["parameters"]}["random_state"]
    assert rs["type"] == "int | Generator | RandomState | None" and rs["doc"].startswith("seed")


def test_random_state_reaches_only_the_plugins_that_take_it(tmp_path, capsys):
    """`segment --random-state 0` works with every segmenter (ncut has no randomness and broke); every dense
    matcher is built the same way (create_seeded)."""
    from shape_toolkit.api.registry import create_seeded
    from shape_toolkit.cli import main
    from shape_toolkit.data.synthetic import articulated_shape
    from shape_toolkit.io.mesh import save_shape

    body = articulated_shape(subdivisions=2, random_state=1)
    mesh = tmp_path / "body.off"
    save_shape(body.shape, mesh)
    clicks = tmp_path / "clicks.json"
    from shape_toolkit.results.labels import draw_constraints, save_constraints

    save_constraints(clicks, draw_constraints(body.labels, body.shape.edges, random_state=0))
    for name in available_plugins()["segmenters"]:
        cls = get_plugin("segmenters", name)
        extra = ["--constraints", str(clicks)] if cls.takes_constraints else []
        k = [] if name == "seeded-walk" else ["-k", "3"]
        code = main(["segment", str(mesh), "--method", name, *k, "--random-state", "0", *extra,
                     "-o", str(tmp_path / f"{name}.txt"), "--json"])
        captured = capsys.readouterr()
        assert code == 0, (name, captured.err)
    for name in available_plugins()["dense_matchers"]:
        obj = create_seeded("dense_matchers", name, None, 0)
        takes = "random_state" in type(obj)._param_names()
        assert (obj.get_params(deep=False).get("random_state") == 0) is takes, name
    assert create_seeded("segmenters", "csc", None, 0, random_state=5).random_state == 5  # a given one wins
