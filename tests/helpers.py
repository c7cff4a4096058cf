"""What several test modules share that is not a fixture (fixtures live in conftest.py): test shapes,
running the CLI, loading a script of benchmarks/ or examples/, a plugin registered for one test, and for the
benchmark-runner tests a small synthetic config, writing it and running ``bench run``. Not a test module:
pytest collects ``test_*.py`` only."""

from __future__ import annotations

import importlib.util
import signal
import sys
import textwrap
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from shape_toolkit.api.registry import get_registry
from shape_toolkit.cli import main
from shape_toolkit.core.shape import Shape
from shape_toolkit.data.generate import icosphere
from shape_toolkit.data.synthetic import ArticulatedShape, articulated_shape
from shape_toolkit.io.mesh import save_shape

#: the repository root (benchmarks/, examples/)
REPO = Path(__file__).resolve().parents[1]

#: directions and heights of the protrusions of :func:`bumpy_sphere`
BUMP_DIRS = np.array([[0, 0, 1], [1, 0, 0], [0, -1, 0], [-0.6, 0.8, 0.0]], float)
BUMP_HEIGHTS = [1.2, 0.9, 0.7, 0.5]


# -- shapes ------------------------------------------------------------------------------------
def bumpy_sphere(
    subdivisions: int = 3, seed: int = 0, *, power: int = 12, noise: float = 0.002, name: str = "bumpy"
) -> tuple[Shape, list[int]]:
    """An icosphere with four protrusions of decreasing height (radius ``1 + sum h (v . d)_+^power``) and
    relative radial noise ``noise`` (seeded by ``seed``, so no symmetry); the shape and the tip vertex of each
    protrusion."""
    s = icosphere(subdivisions)
    v = s.vertices.copy()
    d = BUMP_DIRS / np.linalg.norm(BUMP_DIRS, axis=1, keepdims=True)
    r = np.ones(len(v))
    for di, h in zip(d, BUMP_HEIGHTS):
        r += h * np.clip(v @ di, 0, None) ** power
    r *= 1 + noise * np.random.default_rng(seed).standard_normal(len(v))
    return Shape(v * r[:, None], s.faces, name), [int(np.argmax(v @ di)) for di in d]


def articulated_pair_files(folder: Path) -> tuple[ArticulatedShape, ArticulatedShape]:
    """Two poses of the articulated synthetic shape (2 subdivisions, random states 1 and 2) written to
    ``folder / "a.off"`` and ``folder / "b.off"``; the two."""
    a = articulated_shape(subdivisions=2, random_state=1)
    b = articulated_shape(subdivisions=2, random_state=2)
    save_shape(a.shape, folder / "a.off")
    save_shape(b.shape, folder / "b.off")
    return a, b


# -- the CLI, scripts, plugins -----------------------------------------------------------------
def run_cli(capsys: Any, *args: object) -> tuple[int, str, str]:
    """``(exit code, stdout, stderr)`` of ``shape-toolkit ARGS...`` run in-process (``capsys``: pytest's)."""
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def load_script(name: str, path: Path) -> ModuleType:
    """The script at ``path`` imported as module ``name`` (also put in ``sys.modules``, which dataclasses
    and pickling need)."""
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


@contextmanager
def registered(family: str, name: str, cls: type) -> Iterator[None]:
    """``cls`` registered as plugin ``name`` of ``family`` for the ``with`` block."""
    reg = get_registry()
    reg.register(family, name, cls)
    try:
        yield
    finally:
        reg.unregister(family, name)


# -- benchmark runs ----------------------------------------------------------------------------
#: one spectral-clustering method (the unnormalized variant of von Luxburg's tutorial) with 3 segments
SPECTRAL_CLUSTERING = """
[[tasks.methods]]
plugin = "spectral-clustering"
preset = "luxburg-unnormalized"
params = { n_segments = 3 }
"""


def segmentation_config(
    name: str,
    *,
    limit: int,
    n_poses: int = 2,
    subdivisions: int = 2,
    metrics: str = '"n_segments", "segmentation"',
    methods: str = SPECTRAL_CLUSTERING,
) -> str:
    """TOML text of a run ``name``: ``limit`` synthetic shapes (``n_poses`` poses, ``subdivisions``), one
    segmentation task ``seg`` with ``metrics`` (TOML list items) and ``methods`` (``[[tasks.methods]]`` tables)."""
    return f"""
[run]
name = "{name}"
[[datasets]]
name = "synth"
kind = "synthetic"
limit = {limit}
params = {{ n_poses = {n_poses}, subdivisions = {subdivisions} }}
[[tasks]]
task = "segmentation"
name = "seg"
metrics = [{metrics}]
""" + methods.lstrip("\n")


def spectrum_config(plugin: str) -> str:
    """TOML text of the smallest spectrum run: 2 synthetic poses, one spectrum task (``k = 8``) with the
    weighting ``plugin``."""
    return f"""
[[datasets]]
name = "synth"
kind = "synthetic"
params = {{ n_poses = 2, subdivisions = 2 }}
[[tasks]]
task = "spectrum"
spectrum = {{ k = 8 }}
[[tasks.methods]]
plugin = "{plugin}"
"""


#: the smallest valid benchmark config as a table (one generated pose pair, a 5-eigenpair spectrum): the base of
#: :func:`raw_config`
SMALL_CONFIG: dict[str, Any] = {
    "run": {"name": "small", "random_state": 0},
    "datasets": [{"name": "syn", "kind": "synthetic", "limit": 1, "params": {"n_poses": 2, "subdivisions": 1}}],
    "tasks": [{"task": "spectrum", "spectrum": {"k": 5}, "methods": [{"plugin": "cotangent"}]}],
}


def raw_config(**changes: Any) -> dict[str, Any]:
    """A copy of :data:`SMALL_CONFIG` with ``changes`` set, each a dotted path (list indices as numbers), e.g.
    ``raw_config(**{"datasets.0.params.n_poses": 10})``: the table ``parse_config`` reads."""
    import copy

    raw = copy.deepcopy(SMALL_CONFIG)
    for path, value in changes.items():
        node = raw
        keys = path.split(".")
        for k in keys[:-1]:
            node = node[int(k)] if k.isdigit() else node[k]
        node[keys[-1]] = value
    return raw


def write_config(folder: Path, text: str, name: str = "bench.toml") -> Path:
    """``text`` (dedented) written to ``folder / name``; the path."""
    p = folder / name
    p.write_text(textwrap.dedent(text))
    return p


def run_config(text: str, folder: Path) -> Path:
    """The benchmark of config ``text`` (paths relative to ``folder``) run without progress into
    ``folder / "run"``, every row a success; that run folder."""
    from shape_toolkit.bench.config import parse_config
    from shape_toolkit.bench.runner import run_benchmark

    run = folder / "run"
    assert run_benchmark(parse_config(text, base=folder), run, progress=False).failed == 0
    return run


def bench_run(config: Path, run: Path, *extra: str) -> int:
    """Exit code of ``shape-toolkit bench run CONFIG -o RUN --no-progress EXTRA...``."""
    return main(["bench", "run", str(config), "-o", str(run), "--no-progress", *extra])



def read_render(png: str | Path) -> tuple[np.ndarray, list | None]:
    """A render's PNG as RGB floats in [0, 1] ``(h, w, 3)`` and the panel boxes it recorded
    (:data:`shape_toolkit.viz.PANELS_KEY`: left, top, width, height in pixels), or None."""
    import json

    from PIL import Image

    from shape_toolkit.viz import PANELS_KEY

    with Image.open(png) as im:
        boxes = json.loads(im.text[PANELS_KEY]) if PANELS_KEY in im.text else None
        return np.asarray(im.convert("RGB"), dtype=np.float64) / 255.0, boxes


def empty_fraction(img: np.ndarray, box: tuple[int, int, int, int] | list[int] | None = None) -> float:
    """Share of a panel (``box``: left, top, width, height in pixels; default the whole image) outside the bounding
    box of its drawn (non-white) pixels; 1.0 when blank."""
    if box is not None:
        x, y, w, h = box
        img = img[y:y + h, x:x + w]
    ink = (img[..., :3] < 0.97).any(axis=2)
    rows, cols = np.flatnonzero(ink.any(axis=1)), np.flatnonzero(ink.any(axis=0))
    if not rows.size:
        return 1.0
    return 1.0 - (rows[-1] - rows[0] + 1) * (cols[-1] - cols[0] + 1) / ink.size


def panel_empty_fractions(png: str | Path) -> list[float]:
    """:func:`empty_fraction` of each panel a figure of :func:`shape_toolkit.viz.render_shapes` (or
    ``render_trajectories``) recorded in its PNG."""
    img, boxes = read_render(png)
    return [empty_fraction(img, b) for b in boxes]


@contextmanager
def time_budget(seconds: int = 60) -> Iterator[None]:
    """Fail (TimeoutError) instead of hanging when the block runs longer than ``seconds`` (a test of a parameter that
    once hung; SIGALRM, main thread only)."""

    def _expired(signum: int, frame: object) -> None:
        raise TimeoutError(f"still running after {seconds} s")

    previous = signal.signal(signal.SIGALRM, _expired)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
