"""The package's shape: no import cycle (function-local and type-checking-only imports count), layers only
import downwards, no plugin name in the core, one top-level import name, lazy plugin discovery, and the
scikit-learn contract of every plugin."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tomllib

REPO = Path(__file__).resolve().parent.parent
PKG = REPO / "shape_toolkit"

#: lowest layer first; a module may import its own layer and the layers before it
LAYERS = [
    ("base", ["shape_toolkit.errors", "shape_toolkit.validation", "shape_toolkit.api"]),
    ("core", ["shape_toolkit.core"]),
    ("features", ["shape_toolkit.features"]),
    ("results", ["shape_toolkit.results"]),
    ("io", ["shape_toolkit.io"]),
    ("viz", ["shape_toolkit.viz"]),
    ("data", ["shape_toolkit.data"]),
    ("spectra", ["shape_toolkit.spectra"]),
    ("plugins", ["shape_toolkit.plugins"]),
    ("pipeline", ["shape_toolkit.pipeline"]),
    ("metrics", ["shape_toolkit.metrics"]),
    ("bench", ["shape_toolkit.bench"]),
    ("cli", ["shape_toolkit.cli", "shape_toolkit.__main__"]),
]


def _module_name(path: Path) -> str:
    rel = path.relative_to(REPO).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports(path: Path, text: str | None = None) -> set[str]:
    """Every shape_toolkit module imported anywhere in ``path``: function-local imports and those under
    ``if TYPE_CHECKING:`` included (a type-only cycle is a cycle of the design, only hidden from the
    interpreter)."""
    tree = ast.parse(path.read_text() if text is None else text)
    me = _module_name(path)
    pkg = me if path.name == "__init__.py" else me.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.startswith("shape_toolkit"))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")[: len(pkg.split(".")) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            if mod.startswith("shape_toolkit"):
                out.add(mod)
                # `from shape_toolkit.x import y` may import the submodule y
                for a in node.names:
                    cand = f"{mod}.{a.name}"
                    if (PKG.parent / Path(*cand.split("."))).with_suffix(".py").exists() or (
                        PKG.parent / Path(*cand.split(".")) / "__init__.py"
                    ).exists():
                        out.add(cand)
    out.discard(me)
    return out


def _graph() -> dict[str, set[str]]:
    mods = {_module_name(p): p for p in PKG.rglob("*.py")}
    return {m: {i for i in _imports(p) if i in mods} for m, p in mods.items()}


def _layer(mod: str) -> int:
    best, idx = "", -1
    for i, (_, prefixes) in enumerate(LAYERS):
        for pre in prefixes:
            if (mod == pre or mod.startswith(pre + ".")) and len(pre) > len(best):
                best, idx = pre, i
    return idx


def test_the_import_scan_counts_type_checking_blocks():
    code = "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from shape_toolkit.core.shape import Shape\n"
    assert "shape_toolkit.core.shape" in _imports(PKG / "api" / "interfaces.py", code)
    assert not any(d.startswith("shape_toolkit.") and _layer(d) > 0 for d in _graph()["shape_toolkit.api.interfaces"])


def test_no_plugin_name_in_the_core():
    """The core takes weighting objects; names are resolved above it (``shape_toolkit.spectra``)."""
    import re

    cfg = tomllib.loads((REPO / "pyproject.toml").read_text())
    names = {name for table in cfg["project"]["entry-points"].values() for name in table}
    assert {"cotangent", "gaussian", "intrinsic-delaunay"} <= names
    bad = []
    for path in sorted((PKG / "core").glob("*.py")):
        text = path.read_text()
        for name in sorted(names):
            constants = [n for n in ast.walk(ast.parse(text)) if isinstance(n, ast.Constant) and n.value == name]
            quoted = re.findall(rf"""['"]{re.escape(name)}['"]""", text)
            if constants or quoted:
                bad.append(f"{path.relative_to(REPO)}: {name!r}")
    assert not bad, "plugin names in core/:\n" + "\n".join(bad)


def test_no_import_cycle_counting_function_local_imports():
    graph = _graph()
    # package __init__ files that only re-export are edges too; a cycle through them is a real cycle
    state: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                cycles.append(stack[stack.index(n):] + [n])
            elif n not in state:
                visit(n)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    # importing a package runs its __init__; an __init__ that imports its own submodules is no cycle
    real = [c for c in cycles if not all(b.startswith(a + ".") or a.startswith(b + ".") for a, b in zip(c, c[1:]))]
    assert not real, "import cycles:\n" + "\n".join(" -> ".join(c) for c in real)


def test_no_plugin_module_exceeds_450_lines():
    """Issue 26: a plugin module holds one plugin and what only it uses; shared concepts live in modules named
    after them (features.basis holds the functional-map energy, for example)."""
    long = {str(p.relative_to(PKG)): n for p in (PKG / "plugins").rglob("*.py")
            if (n := len(p.read_text().splitlines())) > 450}
    assert not long, long


def test_layers_only_import_downwards():
    graph = _graph()
    bad = []
    for mod, deps in graph.items():
        if mod == "shape_toolkit":  # the top-level facade re-exports from every layer
            continue
        lm = _layer(mod)
        assert lm >= 0, f"{mod} belongs to no layer: add it to LAYERS and docs/architecture.md"
        for d in deps:
            if d == "shape_toolkit":
                if _layer(mod) != len(LAYERS) - 1:  # only the CLI, on top, may use the facade
                    bad.append(f"{mod} imports the top-level facade")
            elif _layer(d) > lm:
                bad.append(f"{mod} ({LAYERS[lm][0]}) imports {d} ({LAYERS[_layer(d)][0]})")
    assert not bad, "\n".join(sorted(bad))


def test_the_wheel_installs_one_top_level_name():
    cfg = tomllib.loads((REPO / "pyproject.toml").read_text())
    assert cfg["tool"]["setuptools"]["packages"]["find"]["include"] == ["shape_toolkit*"]
    assert not (REPO / "toolkit").exists() and not (REPO / "plugins").exists()
    eps = cfg["project"]["entry-points"]
    names = {}
    for group, table in eps.items():
        assert group.startswith("shape_toolkit."), group
        for name, target in table.items():
            assert target.startswith("shape_toolkit.plugins."), target
            assert name not in names, f"{name} is registered twice"
            names[name] = group
    assert cfg["project"]["scripts"]["shape-toolkit"] == "shape_toolkit.cli:main"


def test_listing_plugins_imports_no_plugin_module_and_using_one_imports_only_it():
    code = (
        "import sys, json, shape_toolkit as st\n"
        "fams = st.available_plugins()\n"
        "before = sorted(m for m in sys.modules if m.startswith('shape_toolkit.plugins.'))\n"
        "st.create_plugin('weightings', 'gaussian')\n"
        "after = sorted(m for m in sys.modules if m.startswith('shape_toolkit.plugins.'))\n"
        "print(json.dumps({'n': sum(map(len, fams.values())), 'before': before, 'after': after}))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    assert got["n"] >= 20
    assert [m for m in got["before"] if m.count(".") > 2] == []  # only (empty) family packages at most
    loaded = [m for m in got["after"] if not m.endswith("__init__")]
    assert "shape_toolkit.plugins.weightings.gaussian" in loaded
    assert not any(m.startswith(("shape_toolkit.plugins.segmenters.", "shape_toolkit.plugins.matching."))
                   for m in loaded), loaded


def _small_pair():
    from shape_toolkit.data.synthetic import articulated_shape

    a = articulated_shape(subdivisions=2).shape
    b = articulated_shape(subdivisions=2, random_state=3).shape
    return a, b


def _all_plugins():
    import shape_toolkit as st

    return [(fam, name) for fam, names in st.available_plugins().items() for name in names]


@pytest.mark.parametrize(("family", "name"), _all_plugins())
def test_every_plugin_clones_with_sklearn_and_the_clone_gives_the_same_output(family, name):
    sklearn_base = pytest.importorskip("sklearn.base")
    import shape_toolkit as st

    plugin = st.create_plugin(family, name)
    if plugin.get_params(deep=False).get("n_segments", 0) is None:
        plugin.set_params(n_segments=4)
    clone = sklearn_base.clone(plugin)
    assert type(clone) is type(plugin) and clone is not plugin
    assert repr(clone) == repr(plugin)
    deep = plugin.get_params(deep=True)
    assert set(plugin.get_params(deep=False)) <= set(deep)
    clone.set_params(**plugin.get_params(deep=False))
    a, b = _small_pair()
    out1, out2 = _run(family, plugin, a, b), _run(family, clone, a, b)
    if isinstance(out1, np.ndarray):
        np.testing.assert_allclose(out1, out2)
    else:
        np.testing.assert_array_equal(out1.target_of, out2.target_of)


def _run(family, plugin, a, b):
    if family == "weightings":
        return plugin.weigh(a, a.edges).W.toarray()
    if family == "keypoints":
        return plugin.detect(a)
    if family == "descriptors":
        return plugin.compute(a, keypoints=np.arange(0, a.n_vertices, max(1, a.n_vertices // 8)))
    if family == "segmenters":  # the clicks a person would give, to those that take them (seeded-walk needs them)
        from shape_toolkit.data.synthetic import articulated_shape
        from shape_toolkit.results.labels import Constraints

        parts = articulated_shape(subdivisions=2).labels
        must = np.array([np.flatnonzero(parts == p)[[0, -1]] for p in np.unique(parts)])
        cons = Constraints(must, must[:2, 0][None]) if plugin.accepts_constraints() else None
        return plugin.segment(a, constraints=cons).labels
    seeds = np.column_stack([np.arange(0, a.n_vertices, max(1, a.n_vertices // 12))] * 2)
    if family == "sparse_matchers":
        return plugin.match(a, a, seeds[:, 0], seeds[:, 1])
    kwargs = {} if type(plugin).__name__ in ("FmapZoomOutMatcher", "EigvecAlignmentMatcher") else {"seeds": seeds}
    return plugin.match(a, b, **kwargs)


@pytest.mark.parametrize(("family", "name"), _all_plugins())
def test_random_state_only_where_there_is_randomness_with_sklearn_semantics(family, name):
    import inspect

    import shape_toolkit as st

    cls = st.get_plugin(family, name)
    if "random_state" not in cls._param_names():
        return
    source = inspect.getsource(inspect.getmodule(cls))
    reads = source.count("self.random_state") - source.count("self.random_state = random_state")
    assert reads > 0, f"{name} takes a random_state that it never reads"
    for value in (None, 0, np.random.RandomState(1), np.random.default_rng(2)):
        st.create_plugin(family, name, random_state=value)  # accepted at construction
