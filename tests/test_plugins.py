"""The plugin system: discovery through entry points, lookup, errors, a third-party plugin."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from shape_toolkit import ParameterError, PluginError, build_graph, hookimpl
from shape_toolkit.api.hookspecs import FAMILY_HOOKS
from shape_toolkit.api.interfaces import FAMILY_INTERFACES, BasePlugin, Weighting, Weights
from shape_toolkit.api.registry import Registry, available_plugins, get_plugin
from shape_toolkit.data.generate import icosphere

REPO = Path(__file__).resolve().parent.parent


def test_every_family_is_listed_and_builtins_come_through_entry_points():
    fams = available_plugins()
    assert set(fams) == set(FAMILY_HOOKS) == set(FAMILY_INTERFACES)
    assert {"binary", "gaussian", "cotangent", "intrinsic-delaunay"} <= set(fams["weightings"])
    # built-ins register exactly as a third-party plugin: through the per-family entry points
    reg = Registry()
    for name in ("binary", "gaussian", "cotangent", "intrinsic-delaunay"):
        assert reg.entry_point("weightings", name).startswith("shape_toolkit.plugins.weightings.")
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


class _InProcessPlugin:
    @hookimpl
    def toolkit_weightings(self):
        return {"doubled": _Doubled}


def test_register_in_process_and_conflicts():
    reg = Registry()
    reg.register(_InProcessPlugin(), name="inproc")
    obj = reg.create("weightings", "doubled", factor=3.0)
    assert obj.get_params() == {"factor": 3.0}
    obj.set_params(factor=4.0)
    assert obj.factor == 4.0
    with pytest.raises(ParameterError):
        obj.set_params(bogus=1)

    class Clash:
        @hookimpl
        def toolkit_weightings(self):
            return {"gaussian": _Doubled}

    with pytest.raises(PluginError, match="two plugins register weightings 'gaussian'"):
        reg.register(Clash(), name="clash")  # refused at once, though 'gaussian' is not imported yet

    class NoMethod:
        @hookimpl
        def toolkit_segmenters(self):
            return {"broken": object}

    reg2 = Registry()
    with pytest.raises(PluginError, match="without a segment"):
        reg2.register(NoMethod(), name="nomethod")


THIRD_PARTY = '''
"""A throwaway third-party weighting plugin: w_ij = 1 / edge length."""
import numpy as np
from shape_toolkit.api.hookspecs import hookimpl
from shape_toolkit.api.interfaces import Weighting, Weights
from shape_toolkit.core.graph import weights_from_edges


class InverseLength(Weighting):
    def __init__(self, power: float = 1.0):
        self.power = power

    def weigh(self, shape, edges):
        d = np.linalg.norm(shape.vertices[edges[:, 0]] - shape.vertices[edges[:, 1]], axis=1)
        return Weights(weights_from_edges(shape.n_vertices, edges, d ** -self.power),
                       info={"third_party": True})


@hookimpl
def toolkit_weightings():
    return {"inverse-length": InverseLength}
'''


def test_third_party_plugin_installed_by_entry_point_is_listed_and_used(tmp_path):
    site = tmp_path / "site"
    site.mkdir()
    (site / "tp_weights.py").write_text(THIRD_PARTY)
    dist = site / "tp_weights-0.1.dist-info"  # what pip writes when it installs a wheel
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: tp-weights\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[toolkit]\ninverse-length = tp_weights\n")
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
    used = cli(
        "spectrum", str(mesh), "-k", "5", "--weighting", "inverse-length", "--param", "power=2", "--json"
    )
    assert used.returncode == 0, used.stderr
    out = json.loads(used.stdout)
    assert out["weighting"] == "inverse-length" and out["graph"]["third_party"] is True
    # the same numbers in-process, with the plugin's class registered by hand
    sys.path.insert(0, str(site))
    try:
        import tp_weights

        reg = Registry(load_entry_points=False)
        reg.register(tp_weights, name="tp")
        assert reg.families()["weightings"] == ["inverse-length"]
    finally:
        sys.path.remove(str(site))
    assert len(out["eigenvalues"]) == 5 and out["eigenvalues"][0] == pytest.approx(0, abs=1e-8)
    ref = build_graph(icosphere(2), "binary")  # 1/length^2 weights differ from binary ones
    assert out["graph"]["edges"] == ref.n_edges
