"""Ground-truth files and dataset layouts (TOSCA-style correspondences, PSB segmentations)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .errors import ShapeFileError

__all__ = ["read_vertex_ids", "read_vts", "read_face_labels", "read_labels", "write_labels"]


def _read_ints(path: str | os.PathLike, what: str) -> np.ndarray:
    p = Path(path)
    if not p.exists():
        raise ShapeFileError(p, "no such file")
    if p.is_dir():
        raise ShapeFileError(p, "is a directory, expected a file")
    try:
        text = p.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise ShapeFileError(p, f"cannot read {what}: {exc}") from None
    tokens = text.split()
    if not tokens:
        raise ShapeFileError(p, f"empty {what} file")
    try:
        values = np.array([int(t) for t in tokens], dtype=np.int64)
    except ValueError:
        bad = next(t for t in tokens if not t.lstrip("-").isdigit())
        raise ShapeFileError(p, f"{what} must be integers, found {bad!r}") from None
    return values


def read_vertex_ids(
    path: str | os.PathLike, *, one_based: bool, n_vertices: int | None = None
) -> np.ndarray:
    """Read one vertex index per line as 0-based int64 ``(p,)``; ``one_based`` says how the file
    counts. With ``n_vertices``, indices outside the shape raise :class:`ShapeFileError`."""
    ids = _read_ints(path, "vertex indices")
    if one_based:
        if ids.min() < 1:
            raise ShapeFileError(path, f"1-based indices expected, found {int(ids.min())}")
        ids = ids - 1
    elif ids.min() < 0:
        raise ShapeFileError(path, f"negative vertex index {int(ids.min())}")
    if n_vertices is not None and ids.max() >= n_vertices:
        raise ShapeFileError(
            path, f"vertex index {int(ids.max()) + one_based} is out of range for {n_vertices} vertices"
        )
    return ids


def read_vts(path: str | os.PathLike, n_vertices: int | None = None) -> np.ndarray:
    """Read a TOSCA ``.vts`` correspondence file (1-based) as 0-based int64 vertex ids."""
    return read_vertex_ids(path, one_based=True, n_vertices=n_vertices)


def read_labels(path: str | os.PathLike, n_expected: int | None = None) -> np.ndarray:
    """Read one integer label per line (vertex labels, or face labels of a PSB ``.seg`` file)
    as int64 ``(n,)``; a length other than ``n_expected`` raises :class:`ShapeFileError`."""
    labels = _read_ints(path, "labels")
    if n_expected is not None and len(labels) != n_expected:
        raise ShapeFileError(path, f"has {len(labels)} labels, expected {n_expected}")
    return labels


def read_face_labels(path: str | os.PathLike, n_faces: int | None = None) -> np.ndarray:
    """Read a PSB ``.seg`` file: one label per face, in face order, int64 ``(m,)``."""
    return read_labels(path, n_faces)


def write_labels(path: str | os.PathLike, labels: np.ndarray) -> None:
    """Write one integer per line (labels, or 0-based vertex ids with -1 for unmatched)."""
    p = Path(path)
    if p.parent and not p.parent.exists():
        raise ShapeFileError(p, "the output folder does not exist")
    tmp = p.with_name(f".{p.name}.tmp")
    np.savetxt(tmp, np.asarray(labels, dtype=np.int64), fmt="%d")
    os.replace(tmp, p)
