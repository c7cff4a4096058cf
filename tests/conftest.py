"""Shared pytest fixtures: real-data location, a small icosphere, a scratch directory."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from shape_toolkit.core.shape import Shape
from shape_toolkit.data.generate import icosphere

_REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Directory of the shared reference data ($TOOLKIT_DATA, else <repo>/../shared/data)."""
    env = os.environ.get("TOOLKIT_DATA")
    path = Path(env) if env else _REPO.parent / "shared" / "data"
    if not path.is_dir():
        pytest.skip(f"shared reference data not found at {path}: set TOOLKIT_DATA")
    return path


@pytest.fixture(scope="session")
def sphere() -> Shape:
    """Unit icosphere with 3 subdivisions: 642 vertices, 1280 faces, closed, genus 0."""
    return icosphere(3)


@pytest.fixture
def tmp_mesh_dir(tmp_path: Path) -> Path:
    """An empty per-test directory for writing mesh files."""
    d = tmp_path / "meshes"
    d.mkdir()
    return d
