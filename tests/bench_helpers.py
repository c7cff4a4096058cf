"""What the benchmark-runner tests share: a small synthetic segmentation config, writing a config file
and running ``shape-toolkit bench run`` on it (not a test module: pytest collects ``test_*.py`` only)."""

from __future__ import annotations

import textwrap
from pathlib import Path

from shape_toolkit.cli import main

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


def write_config(folder: Path, text: str, name: str = "bench.toml") -> Path:
    """``text`` (dedented) written to ``folder / name``; the path."""
    p = folder / name
    p.write_text(textwrap.dedent(text))
    return p


def bench_run(config: Path, run: Path, *extra: str) -> int:
    """Exit code of ``shape-toolkit bench run CONFIG -o RUN --no-progress EXTRA...``."""
    return main(["bench", "run", str(config), "-o", str(run), "--no-progress", *extra])
