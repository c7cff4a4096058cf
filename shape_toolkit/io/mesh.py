"""Read and write shapes: triangle meshes (OFF, PLY, OBJ, STL) and point clouds (PLY, XYZ, PCD, OFF, OBJ).

Validation comes first: the file size against the header's counts and the counts against
:data:`MAX_VERTICES`, before anything large is allocated or a library sees the file; every problem is
a :class:`ShapeFileError` naming the file (and the line, where there is one). libigl reads STL (the
soup welded here, first-occurrence order) and Open3D LZF-compressed PCD. Polygons are fan-triangulated;
indices are 0-based except in OBJ. Colours (``Shape.colors``, RGB in [0, 1]) are read from PLY, COFF,
OBJ (``v x y z r g b``, or a texture sampled bilinearly with Pillow, a vertex's samples averaged), XYZ
and PCD: integer types are 8-bit (``ushort`` 16-bit), float types in [0, 1], and in text files values
that are all integers with one above 1 are 8-bit. Writers round-trip float64 (STL: float32) and keep
colours (PLY and PCD: 8-bit).

The other readers are numpy parsers, because each library tried mishandles a malformed file silently,
refuses a valid one, or cannot say what is wrong (libigl 2.6.3, Open3D 0.19.0, plyfile 1.1.5, trimesh
5.2.0, meshio 5.3.5, pypcd4 1.5.1):

- OFF: libigl reads index 4294967298 as 2 (32-bit wrap) and divides float COFF colours by 255; Open3D
  returns uninitialised coordinates for a vertex ``1 abc 0`` and an empty mesh for ``OFF 3 1 0`` on one
  line; trimesh drops a face ``2 0 1`` and reads ``4 0 1 2`` as a triangle; meshio prints and raises
  SystemExit on COFF, polygons and a one-line header.
- OBJ: libigl wraps indices too and reads index 0 as -1; Open3D returns an empty mesh for ``f 1/1 2/2
  3/3 4/4``; trimesh reads ``f 0 1 2`` as (0, 0, 1) and drops the vertex of ``f 1/1 2/1 3/1 -1/1``;
  meshio keeps index 0 as -1; none averages the texture samples of a vertex with several UVs.
- PLY: libigl reads float index 1.5 as 1, leaves polygons untriangulated and returns uninitialised
  coordinates for a truncated binary file; Open3D divides every colour by 255 (float 1.0 gives 0.0039)
  and both keep indices out of range. plyfile refuses these, but refuses the whole file for one bad
  colour (uchar 2.5: the geometry cannot be read alone), names neither a list count of -2 nor -1 (it
  says "malformed input", "early end-of-file"), and reads variable-length lists row by row (two million
  empty faces: 9 s before anything can refuse them; an ascii mesh of 200k vertices: 4.7 s against
  0.7 s here; writing it: 8.8 s against 1.6 s).
- XYZ, PCD: Open3D drops a malformed XYZ line and returns uninitialised points for a truncated ascii
  PCD; pypcd4 ignores POINTS (reads 2 rows of 3 declared points as 2 points) and refuses the whole file
  for a colour of 300 in a ``U 1`` field.
- writers: libigl's keep 15 digits and Open3D's 6.
"""

from __future__ import annotations

import os
import re
import sys
import threading
import warnings
from collections.abc import Callable
from contextlib import contextmanager
from itertools import chain
from pathlib import Path

import numpy as np

from shape_toolkit.core.shape import NormalsWarning, Shape, check_no_duplicate_faces, duplicate_face_pairs
from shape_toolkit.errors import InvalidShapeError, ParameterError, ShapeFileError
from shape_toolkit.validation import atomic_output

__all__ = [
    "MAX_FILE_BYTES",
    "MAX_VERTICES",
    "MESH_FORMATS",
    "NormalsWarning",
    "POINT_FORMATS",
    "declared_vertices",
    "load_shape",
    "save_shape",
]

#: Files larger than this are refused with a clear error instead of exhausting memory.
MAX_FILE_BYTES = 2 * 1024**3
#: Files declaring more vertices (or faces, or STL triangles) than this are refused.
MAX_VERTICES = 50_000_000
#: Face indices beyond this magnitude cannot be vertex ids of any loadable file.
_MAX_INDEX = 2**62
#: The least bytes an element (vertex, face, point) takes in a text file: one digit and a separator.
MIN_TEXT_BYTES_PER_ELEMENT = 2

#: Extensions that may hold triangle meshes / point clouds.
MESH_FORMATS = (".off", ".ply", ".obj", ".stl")
POINT_FORMATS = (".ply", ".xyz", ".pcd", ".off", ".obj")

#: Texture images with more pixels than this are refused (they are sampled, never decoded to floats).
MAX_TEXTURE_PIXELS = 2**27

_Parsed = tuple[np.ndarray, "np.ndarray | None"]
#: vertices, faces, colours (float64 ``(n, 3)`` in [0, 1], or integer 8-bit / uint16 values)
_ParsedColors = tuple[np.ndarray, "np.ndarray | None", "np.ndarray | None"]
#: the same and a point cloud's normals as the file gives them (``(n, 3)``, or None)
_ParsedNormals = tuple[np.ndarray, "np.ndarray | None", "np.ndarray | None", "np.ndarray | None"]


class _Err(Exception):
    """Internal: a parse problem, turned into ShapeFileError with the path by load_shape."""


class DuplicateFacesWarning(UserWarning):
    """Exactly duplicated faces were dropped on load (``duplicate_faces="drop"``)."""


class ColorWarning(UserWarning):
    """Colours were read in part or not at all: some vertices of a texture-mapped OBJ received no
    colour sample (they are given mid grey), or a nine-column XYZ file has no unit-normal columns
    to tell its colour columns by."""


# --------------------------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------------------------
def load_shape(
    path: str | Path, *, kind: str = "auto", duplicate_faces: str = "error", colors: bool = True,
    normals: bool = True,
) -> Shape:
    """Read a mesh or point cloud file into a :class:`Shape` (vertices in file units).

    ``kind``: "auto" (faces if the file has any), "mesh" (faces required), "points" (faces
    dropped). ``duplicate_faces`` (faces with the same three vertices, which silently change every
    spectrum): "error" (default: refuse, naming ``shape-toolkit clean``), "drop" (keep the first of
    each, with a :class:`DuplicateFacesWarning`) or "keep" (for inspection and repair: ``info``,
    ``clean``). ``colors``: read per-vertex colours (and sample OBJ textures) into
    ``Shape.colors`` when the file has them; False reads the geometry alone. ``normals``: a point
    cloud keeps the per-point normals of its file (PLY ``nx ny nz``, PCD ``normal_x normal_y normal_z``, NOFF, XYZ
    normal columns, OBJ ``vn`` lines one per point) in ``Shape.normals``, where the cloud's Laplacian and
    orientation tests take them as the outward normals instead of estimating them
    (:func:`~shape_toolkit.core.surface.cloud_normals`); False, or a mesh, ignores them, and a file with a zero or
    non-finite normal has them all estimated instead (a :class:`NormalsWarning` says so). Raises
    :class:`ShapeFileError` naming the file (or the texture / material file) for any problem.
    """
    if kind not in ("auto", "mesh", "points"):
        raise ParameterError(f"kind must be 'auto', 'mesh' or 'points', got {kind!r}")
    if duplicate_faces not in ("error", "drop", "keep"):
        raise ParameterError(f"duplicate_faces must be 'error', 'drop' or 'keep', got {duplicate_faces!r}")
    p = Path(path)
    ext = p.suffix.lower()
    if not p.exists():
        raise ShapeFileError(p, "no such file")
    if p.is_dir():
        raise ShapeFileError(p, "is a directory, not a shape file")
    reader = _READERS.get(ext)
    if reader is None:
        known = ", ".join(sorted(_READERS))
        raise ShapeFileError(p, f"unknown shape format {ext or '(no extension)'!r}; known: {known}")
    try:
        size = p.stat().st_size
    except OSError as e:
        raise ShapeFileError(p, f"cannot read: {e.strerror or e}") from None
    if size == 0:
        raise ShapeFileError(p, "file is empty")
    if size > MAX_FILE_BYTES:
        raise ShapeFileError(
            p,
            f"file is {size / 1024**3:.1f} GiB, above the limit of "
            f"{MAX_FILE_BYTES / 1024**3:.1f} GiB (shape_toolkit.io.mesh.MAX_FILE_BYTES)",
        )
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")  # numpy's loadtxt warnings are dropped; problems are raised below
            parsed = reader(p, bool(colors))
            vertices, faces, vcolors = parsed[:3]
            vnormals = parsed[3] if len(parsed) > 3 else None
    except _Err as e:
        raise ShapeFileError(p, str(e)) from None
    except OSError as e:
        raise ShapeFileError(p, f"cannot read: {e.strerror or e}") from None
    except MemoryError:
        raise ShapeFileError(p, "not enough memory to load this file") from None
    except (ValueError, OverflowError, IndexError, KeyError, TypeError, UnicodeError, RecursionError) as e:
        # a malformation the parsers above do not name precisely: still the file's fault
        raise ShapeFileError(p, f"malformed {ext[1:].upper()} file ({type(e).__name__}: {e})") from None

    for w in caught:  # ours are passed on (naming the file), the parsers' are not
        if issubclass(w.category, ColorWarning):
            warnings.warn(f"{p}: {w.message}", ColorWarning, stacklevel=2)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or vertices.shape[0] == 0:
        raise ShapeFileError(p, "the file contains no vertices")
    if faces is not None and faces.shape[0] == 0:
        faces = None
    if kind == "points":
        faces = None
    elif kind == "mesh" and faces is None:
        raise ShapeFileError(p, "contains no faces (a point cloud); load it with kind='points'")
    if not np.isfinite(vertices).all():
        bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
        raise ShapeFileError(
            p, f"{bad.size} vertices have NaN or infinite coordinates (first: vertex {bad[0]})"
        )
    if faces is not None:
        lo, hi = int(faces.min()), int(faces.max())
        if lo < 0 or hi >= vertices.shape[0]:
            bad = lo if lo < 0 else hi
            raise ShapeFileError(
                p,
                f"face index {bad} out of range: the file has {vertices.shape[0]} vertices "
                f"(valid 0-based indices 0..{vertices.shape[0] - 1})",
            )
        if duplicate_faces == "error":
            try:
                check_no_duplicate_faces(faces)
            except InvalidShapeError as e:
                raise ShapeFileError(p, str(e)) from None
        elif duplicate_faces == "drop":
            pairs = duplicate_face_pairs(faces)
            if len(pairs):
                keep = np.ones(len(faces), dtype=bool)
                keep[pairs[:, 1]] = False
                faces = faces[keep]
                warnings.warn(
                    f"{p}: dropped {len(pairs)} duplicate faces (same three vertices as an earlier face)",
                    DuplicateFacesWarning,
                    stacklevel=2,
                )
    if vnormals is not None and (faces is not None or not normals):
        vnormals = None  # a mesh's normals come from its faces
    if vnormals is not None:
        vn = np.asarray(vnormals, dtype=np.float64)
        bad = ~np.isfinite(vn).all(axis=1) | ~(vn != 0).any(axis=1)  # non-finite, or a zero vector (no length taken)
        if bad.any():
            warnings.warn(f"{p}: {int(bad.sum())} points have a zero or non-finite normal (first: point "
                          f"{int(np.flatnonzero(bad)[0])}), so the file's normals are not used: every normal is "
                          "estimated from the points", NormalsWarning, stacklevel=2)
            vnormals = None
    try:
        return Shape(vertices, faces, name=p.stem, colors=vcolors, normals=vnormals)
    except InvalidShapeError as e:
        raise ShapeFileError(p, str(e)) from None


def save_shape(shape: Shape, path: str | Path, *, binary: bool = False) -> None:
    """Write a shape as OFF, PLY, OBJ, STL (meshes) or XYZ, PCD (vertices only), atomically (a
    temporary file next to ``path``, then renamed).

    ``binary`` selects binary PLY/STL (little endian); other formats are always text. Coordinates
    are written with full float64 precision (except STL, which stores float32). Colours are written
    to PLY (``uchar red green blue``, rounded to 8 bits), OFF (as COFF, RGBA floats, exact), OBJ
    (``v x y z r g b``, exact), XYZ (``x y z r g b``, exact) and PCD (packed ``rgb``, 8 bits); STL
    stores geometry only. A point cloud's normals (``Shape.normals``) are written exactly to PLY (``double nx ny
    nz``), OFF (as NOFF or CNOFF), XYZ (``x y z nx ny nz [r g b]``) and PCD (``normal_x normal_y normal_z``), and left
    out of OBJ.
    """
    p = Path(path)
    ext = p.suffix.lower()
    writer = _WRITERS.get(ext)
    if writer is None:
        known = ", ".join(sorted(_WRITERS))
        raise ShapeFileError(p, f"cannot write format {ext or '(no extension)'!r}; known: {known}")
    if ext == ".stl" and not shape.is_mesh:
        raise ShapeFileError(p, "STL stores triangles only; this shape is a point cloud")
    with atomic_output(p, f"{ext[1:].upper()} file") as tmp, open(tmp, "wb") as fh:
        writer(fh, shape, binary)


def declared_vertices(path: str | Path) -> int | None:
    """How many vertices (or points) the file declares, so that a caller can refuse a shape too large for its memory
    before anything is parsed: OFF, PLY and PCD the count in their header (its first 64 KiB); a binary STL half its
    triangles (a closed mesh's vertices once welded); OBJ its ``v`` lines and XYZ its lines, counted in 16 MiB blocks
    (no array of the file's size). None for an ascii STL, or where the header cannot be read (:func:`load_shape`
    then says what is wrong)."""
    p = Path(path)
    ext = p.suffix.lower()
    try:
        size = p.stat().st_size
        with open(p, "rb") as fh:
            head = fh.read(65536)
    except OSError:
        return None
    text = head.decode("latin-1")
    try:
        if ext == ".off":
            toks = " ".join(line.split("#")[0] for line in text.splitlines()[:3]).split()
            return int(toks[1]) if toks and toks[0] in ("OFF", "COFF", "NOFF", "CNOFF") and len(toks) > 2 else None
        if ext == ".ply":
            m = re.search(r"^element\s+vertex\s+(\d+)\s*$", text, flags=re.MULTILINE)
            return int(m.group(1)) if text.startswith("ply") and m else None
        if ext == ".pcd":
            m = re.search(r"^POINTS\s+(\d+)\s*$", text, flags=re.MULTILINE | re.IGNORECASE)
            return int(m.group(1)) if m else None
        if ext == ".stl" and len(head) >= 84:
            n = int(np.frombuffer(head, dtype="<u4", count=1, offset=80)[0])
            return n // 2 if size == 84 + 50 * n else None
        if ext in (".obj", ".xyz"):
            return _count_lines(p, b"v " if ext == ".obj" else None)
    except (ValueError, IndexError, OSError):
        return None
    return None


def _count_lines(p: Path, prefix: bytes | None, block_bytes: int = 1 << 24) -> int:
    """Lines of ``p`` starting with ``prefix`` (None: every line), read in blocks of ``block_bytes``."""
    pattern = b"\n" + (prefix or b"")
    count, tail, end = 0, b"\n", b""  # the first line starts after an implied newline
    with open(p, "rb") as fh:
        while block := fh.read(block_bytes):
            text = tail + block
            count += text.count(pattern)
            tail = text[-(len(pattern) - 1):] if len(pattern) > 1 else b""  # too short to hold a whole match
            end = block[-1:]
    return count - (prefix is None and end == b"\n")  # a final newline starts no line


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------
def _check_count(n: int, what: str) -> None:
    if n < 0:
        raise _Err(f"negative {what} count {n} in the header")
    if n > MAX_VERTICES:
        raise _Err(f"declares {n} {what}, above the limit of {MAX_VERTICES} (shape_toolkit.io.mesh.MAX_VERTICES)")


def _check_text_size(n_elements: int, n_bytes: int, what: str) -> None:
    """Refuse a text body that cannot hold ``n_elements`` declared elements (before allocating)."""
    if n_elements * MIN_TEXT_BYTES_PER_ELEMENT > n_bytes:
        raise _Err(
            f"truncated: the header declares {n_elements} {what}, which need at least "
            f"{n_elements * MIN_TEXT_BYTES_PER_ELEMENT} bytes, but the data has {n_bytes}"
        )


def _read_text(p: Path) -> str:
    data = p.read_bytes()
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")  # decodes any byte


def _content(text: str) -> list[tuple[int, str]]:
    """Lines that are neither blank nor whole-line comments, as (1-based line number, line).

    Inline ``#`` comments are left in place (the parsers below drop them).
    """
    lines = text.splitlines()
    return [(i + 1, ln) for i, ln in enumerate(lines) if (t := ln.lstrip()) and t[0] != "#"]


def _tokens(line: str) -> list[str]:
    return line.split("#", 1)[0].split()


def _floats(rows: list[tuple[int, str]], cols: int | list[int], what: str, *, exact: bool = False) -> np.ndarray:
    """Columns ``cols`` (or the first ``cols``) of text rows as float64 ``(len(rows), k)``;
    ``exact``: every row has exactly the first ``cols`` columns (a row with more is an error too).

    Fast path: numpy's C parser; on any problem a slow pass names the offending line.
    """
    cols = list(range(cols)) if isinstance(cols, int) else list(cols)
    if not rows:
        return np.zeros((0, len(cols)))
    need = max(cols) + 1
    exact = exact and cols == list(range(need))
    try:
        if not exact:
            return np.loadtxt([r for _, r in rows], usecols=cols, ndmin=2, comments="#")
        table = np.loadtxt([r for _, r in rows], ndmin=2, comments="#")  # refuses a changing column count
        if table.shape[1] == need:
            return table
    except ValueError:
        pass
    for ln, line in rows:
        toks = _tokens(line)
        if len(toks) < need or (exact and len(toks) != need):
            raise _Err(f"line {ln}: {what} needs {need} numbers, found {len(toks)}")
        for c in cols:
            try:
                float(toks[c])
            except ValueError:
                raise _Err(f"line {ln}: non-numeric {what} value {toks[c]!r}") from None
    raise _Err(f"malformed {what} data")  # pragma: no cover


def _text_colors(c: np.ndarray, what: str) -> np.ndarray:
    """Colour columns of a text format: 8-bit integers (int64) when every value is an integer and
    one is above 1, else floats for [0, 1] (range checks: :func:`~shape_toolkit.core.shape.check_colors`)."""
    if c.size and np.isfinite(c).all() and (c == np.round(c)).all() and c.max() > 1:
        if c.min() < 0 or c.max() > 255:
            bad = int(np.flatnonzero(((c < 0) | (c > 255)).any(axis=1))[0])
            raise _Err(f"{what} colour of vertex {bad} {c[bad].tolist()} outside the 8-bit range 0..255")
        return c.astype(np.int64)
    return c


def _int(tok: str, ln: int, what: str) -> int:
    try:
        v = int(tok)
    except ValueError:
        raise _Err(f"line {ln}: {what} {tok!r} is not an integer") from None
    if abs(v) > _MAX_INDEX:
        raise _Err(f"line {ln}: {what} {tok[:30]!r} is out of range")
    return v


def _fan(polys: list[list[int]], where: list[int] | None = None) -> np.ndarray:
    """Triangulate polygons (lists of indices) as fans around their first vertex -> (m, 3)."""
    tris: list[tuple[int, int, int]] = []
    for k, poly in enumerate(polys):
        if len(poly) < 3:
            loc = f"line {where[k]}: " if where else ""
            raise _Err(f"{loc}face with {len(poly)} vertices; a face needs at least 3")
        a = poly[0]
        for j in range(1, len(poly) - 1):
            tris.append((a, poly[j], poly[j + 1]))
    return np.array(tris, dtype=np.int64).reshape(-1, 3)


# --------------------------------------------------------------------------------------------
# OFF
# --------------------------------------------------------------------------------------------
def _read_off(p: Path, want_colors: bool = True) -> _ParsedNormals:
    lines = _content(_read_text(p))
    if not lines:
        raise _Err("file has no content")
    ln, first = lines[0]
    toks = _tokens(first)
    head = toks[0] if toks else ""
    if head not in ("OFF", "COFF", "NOFF", "CNOFF"):
        if head.endswith("OFF"):
            raise _Err(f"OFF variant {head!r} is not supported (only OFF, COFF, NOFF, CNOFF)")
        raise _Err(f"not an OFF file: first keyword is {head[:20]!r}, expected 'OFF'")
    rest = toks[1:]
    k = 1
    if not rest:
        if len(lines) < 2:
            raise _Err("truncated: missing the 'n_vertices n_faces n_edges' header line")
        ln, line = lines[1]
        rest = _tokens(line)
        k = 2
    if len(rest) < 2:
        got = " ".join(rest)
        raise _Err(f"line {ln}: header needs 'n_vertices n_faces [n_edges]', got {got!r}")
    nv = _int(rest[0], ln, "vertex count")
    nf = _int(rest[1], ln, "face count")
    _check_count(nv, "vertices")
    _check_count(nf, "faces")
    _check_text_size(nv + nf, p.stat().st_size, "vertices and faces")
    body = lines[k:]
    if len(body) < nv:
        raise _Err(f"truncated: header declares {nv} vertices but the file has {len(body)} lines")
    colors = normals = None
    if head.startswith("C") and want_colors:  # COFF: x y z r g b [a]; CNOFF: x y z nx ny nz r g b [a]
        s = 6 if head == "CNOFF" else 3
        table = _floats(body[:nv], [0, 1, 2, s, s + 1, s + 2], f"{head} vertex (coordinates and colour)")
        vertices, colors = table[:, :3], _text_colors(table[:, 3:], head)
    else:
        vertices = _floats(body[:nv], 3, "vertex")
    if "N" in head and nf == 0:  # a cloud's NOFF, CNOFF: the normal follows the coordinates (a mesh's are not read)
        normals = _floats(body[:nv], [3, 4, 5], f"{head} vertex normal")
    frows = body[nv:]
    if len(frows) < nf:
        raise _Err(
            f"truncated: header declares {nf} faces but only {len(frows)} face lines follow the {nv} vertices"
        )
    if len(frows) > nf:
        ln = frows[nf][0]
        raise _Err(f"line {ln}: unexpected content after the {nf} declared faces")
    if nf == 0:
        return vertices, None, colors, normals
    return vertices, _parse_counted_faces(frows), colors, normals


def _parse_counted_faces(rows: list[tuple[int, str]]) -> np.ndarray:
    """Faces given as 'k i1 .. ik [extra]' text rows (OFF, ascii PLY) -> fan-triangulated (m, 3)."""
    try:  # fast path: all triangles (extra columns such as colours are ignored)
        arr = np.loadtxt([r for _, r in rows], dtype=np.int64, ndmin=2, comments="#")
        if arr.shape[1] >= 4 and (arr[:, 0] == 3).all():
            return arr[:, 1:4].copy()
    except (ValueError, OverflowError):
        pass
    polys, where = [], []
    for ln, line in rows:
        r = _tokens(line)
        if not r:
            raise _Err(f"line {ln}: empty face line")
        n = _int(r[0], ln, "face vertex count")
        if n < 3:
            raise _Err(f"line {ln}: face with {n} vertices; a face needs at least 3")
        if len(r) < n + 1:
            raise _Err(f"line {ln}: face declares {n} vertices but lists {len(r) - 1}")
        polys.append([_int(t, ln, "face index") for t in r[1 : n + 1]])
        where.append(ln)
    return _fan(polys, where)


# --------------------------------------------------------------------------------------------
# OBJ
# --------------------------------------------------------------------------------------------
def _read_obj(p: Path, want_colors: bool = True) -> _ParsedNormals:
    """OBJ's vertices, faces, colours, and a point cloud's normals: its ``vn`` lines when the file has no faces and
    one ``vn`` per ``v``, in the same order (as MeshLab and CloudCompare write a cloud; in a mesh, normals belong to
    face corners and are not read)."""
    lines = [(ln, line.lstrip()) for ln, line in _content(_read_text(p))]
    vrows = [(ln, line[2:]) for ln, line in lines if line[:2] in ("v ", "v\t")]
    _check_count(len(vrows), "vertices")
    colors = None
    if want_colors and vrows and len(_tokens(vrows[0][1])) >= 6:  # v x y z r g b: then on every vertex
        table = _floats(vrows, 6, "vertex with colour (v x y z r g b)")
        vertices, colors = table[:, :3], _text_colors(table[:, 3:], "OBJ vertex")
    else:
        vertices = _floats(vrows, 3, "vertex")
    libs = [line[6:] for _, line in lines if line.startswith("mtllib") and line[6:7].isspace()]
    textured = want_colors and colors is None and bool(libs) and any(line[:3] in ("vt ", "vt\t") for _, line in lines)
    faces = _obj_triangles(lines)
    if faces is None or textured:
        polys, where, corners, uv_rows, names = _obj_walk(lines, textured)
        if faces is None and polys:
            faces = _fan(polys, where)
        if textured and faces is not None:
            colors = _obj_texture_colors(p, libs, corners, uv_rows, names, len(vertices))
    normals = None
    if faces is None or not len(faces):
        nrows = [(ln, line[3:]) for ln, line in lines if line[:3] in ("vn ", "vn\t")]
        if nrows and len(nrows) == len(vrows):
            normals = _floats(nrows, 3, "vertex normal (vn x y z)")
    return vertices, faces, colors, normals


def _obj_triangles(lines: list[tuple[int, str]]) -> np.ndarray | None:
    """0-based faces of an OBJ whose faces are all triangles with absolute indices (numpy's parser); else None."""
    frows = [line[2:] for _, line in lines if line[:2] in ("f ", "f\t")]
    if not frows or any("-" in line for line in frows):
        return None
    if any("/" in line for line in frows):
        slash = re.compile(r"/\S*")
        frows = [slash.sub("", line) for line in frows]
    try:
        arr = np.loadtxt(frows, dtype=np.int64, ndmin=2, comments="#")
    except (ValueError, OverflowError):
        return None
    return arr - 1 if arr.shape[1] == 3 and arr.min() > 0 else None


def _obj_walk(lines: list[tuple[int, str]], textures: bool) -> tuple:
    """The OBJ faces in one pass: lists of 0-based vertex ids (negative indices count back from the
    vertices read so far) and their line numbers; with ``textures`` also every corner as (vertex,
    ``vt`` index or -1, material or -1), the ``vt`` rows and the ``usemtl`` names in order of first use."""
    polys: list[list[int]] = []
    where: list[int] = []
    corners: list[tuple[int, int, int]] = []
    uv_rows: list[tuple[int, str]] = []
    names: dict[str, int] = {}
    nv, cur = 0, -1
    for ln, line in lines:
        if line[:2] in ("v ", "v\t"):
            nv += 1
        elif textures and line[:3] in ("vt ", "vt\t"):
            uv_rows.append((ln, line[3:]))
        elif textures and line.startswith("usemtl") and line[6:7].isspace():
            cur = names.setdefault(line[6:].split("#", 1)[0].strip(), len(names))
        elif line[:2] in ("f ", "f\t"):
            poly = []
            for tok in _tokens(line)[1:]:
                parts = tok.split("/")
                i = _int(parts[0], ln, "face index")
                if i == 0:
                    raise _Err(f"line {ln}: face index 0 is invalid in OBJ (indices are 1-based)")
                poly.append(i - 1 if i > 0 else nv + i)
                if not textures:
                    continue
                t, nt = -1, len(uv_rows)
                if len(parts) > 1 and parts[1]:
                    t = _int(parts[1], ln, "texture coordinate index")
                    if t == 0:
                        raise _Err(f"line {ln}: texture coordinate index 0 is invalid in OBJ (1-based)")
                    t = t - 1 if t > 0 else nt + t
                    if not 0 <= t < nt:
                        raise _Err(f"line {ln}: texture coordinate index {parts[1]} out of range "
                                   f"({nt} vt lines so far)")
                corners.append((poly[-1], t, cur))
            polys.append(poly)
            where.append(ln)
    return polys, where, np.array(corners, dtype=np.int64).reshape(-1, 3), uv_rows, list(names)


def _obj_refs(rest: str, base: Path) -> list[Path]:
    """File names on an ``mtllib`` / ``map_Kd`` line, relative to ``base``: the whole remainder when
    it names an existing file (names with spaces), else the whitespace-separated names."""
    rest = rest.strip().replace("\\", "/")
    whole = base / rest
    if rest and whole.is_file():
        return [whole]
    return [base / t for t in rest.split()]


#: map_Kd options and the number of arguments each takes (their effect is not modelled)
_MAP_OPTIONS = {"-blendu": 1, "-blendv": 1, "-bm": 1, "-boost": 1, "-cc": 1, "-clamp": 1, "-imfchan": 1,
                "-mm": 2, "-o": 3, "-s": 3, "-t": 3, "-texres": 1}


def _read_mtl(mtl: Path) -> dict[str, dict]:
    """Materials of an MTL file: ``{name: {"Kd": (3,) or None, "map": Path or None, "mtl": mtl}}``."""
    if not mtl.is_file():
        raise _Err(f"material library {str(mtl)!r} (mtllib) not found; put it next to the OBJ file, "
                   "or remove the mtllib line to load the geometry without colours")
    try:
        text = mtl.read_bytes().decode("utf-8", errors="replace")
    except OSError as e:
        raise _Err(f"material library {str(mtl)!r}: cannot read ({e.strerror or e})") from None
    mats: dict[str, dict] = {}
    cur: dict | None = None
    for ln, raw in enumerate(text.splitlines(), 1):
        t = raw.split("#", 1)[0].strip()
        if not t:
            continue
        key, _, rest = t.partition(" ")
        key = key.strip()
        if key == "newmtl":
            cur = mats.setdefault(rest.strip(), {"Kd": None, "map": None, "mtl": mtl})
        elif cur is None:
            continue
        elif key == "Kd":
            vals = rest.split()
            try:
                kd = np.array([float(x) for x in vals[:3]])
            except ValueError:
                raise _Err(f"material library {str(mtl)!r} line {ln}: non-numeric Kd {rest.strip()!r}") from None
            if kd.shape != (3,) or not np.isfinite(kd).all() or kd.min() < 0 or kd.max() > 1:
                raise _Err(f"material library {str(mtl)!r} line {ln}: Kd needs three values in [0, 1]")
            cur["Kd"] = kd
        elif key == "map_Kd":
            toks = rest.split()
            i = 0
            while i < len(toks) and toks[i] in _MAP_OPTIONS:
                i += 1 + _MAP_OPTIONS[toks[i]]
            names = " ".join(toks[i:])
            if not names:
                raise _Err(f"material library {str(mtl)!r} line {ln}: map_Kd names no image")
            cur["map"] = _obj_refs(names, mtl.parent)[0]
    return mats


def _load_texture(tex: Path, mtl: Path, material: str) -> np.ndarray:
    """The texture image as a ``(H, W, 3)`` uint8 or uint16 array (Pillow)."""
    where = f"texture image {str(tex)!r} (map_Kd of material {material!r} in {str(mtl)!r})"
    if not tex.is_file():
        raise _Err(f"{where} not found; put the image next to the material file, or remove the "
                   "map_Kd line to load the geometry without colours")
    try:
        from PIL import Image
    except ImportError:  # pragma: no cover - Pillow is a dependency
        raise _Err(f"{where}: reading textures needs Pillow (pip install Pillow)") from None
    try:
        with Image.open(tex) as im:
            w, h = im.size
            if w * h > MAX_TEXTURE_PIXELS or w < 1 or h < 1:
                raise _Err(f"{where} is {w} x {h} pixels, outside 1 .. {MAX_TEXTURE_PIXELS} pixels "
                           "(shape_toolkit.io.mesh.MAX_TEXTURE_PIXELS)")
            if im.mode.startswith("I;16"):
                a = np.asarray(im).astype(np.uint16)
                return np.repeat(a[:, :, None], 3, axis=2)
            a = np.asarray(im.convert("RGB"))
    except _Err:
        raise
    except Exception as e:  # Pillow's decoders raise many types (OSError, SyntaxError, DecompressionBombError, ...)
        raise _Err(f"{where}: not a readable image ({type(e).__name__}: {e})") from None
    if a.ndim != 3 or a.shape[2] != 3:
        raise _Err(f"{where}: unexpected image layout {a.shape}")
    return a


def _sample_bilinear(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples ``(k, 3)`` in [0, 1] of an ``(H, W, 3)`` image at OBJ texture coordinates
    ``uv`` ``(k, 2)`` (v = 0 at the bottom row; repeating outside [0, 1), pixel centres at half
    pixels)."""
    h, w = img.shape[:2]
    top = 65535.0 if img.dtype == np.uint16 else 255.0
    x = np.mod(uv[:, 0], 1.0) * w - 0.5
    y = (1.0 - np.mod(uv[:, 1], 1.0)) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    xa, ya = x0.astype(np.int64) % w, y0.astype(np.int64) % h
    xb, yb = (xa + 1) % w, (ya + 1) % h
    px = [img[yy, xx].astype(np.float64) for yy, xx in ((ya, xa), (ya, xb), (yb, xa), (yb, xb))]
    out = (1 - fy) * ((1 - fx) * px[0] + fx * px[1]) + fy * ((1 - fx) * px[2] + fx * px[3])
    return np.clip(out / top, 0.0, 1.0)


def _obj_texture_colors(p: Path, libs: list[str], corners: np.ndarray, uv_rows: list[tuple[int, str]],
                        names: list[str], n_vertices: int) -> np.ndarray | None:
    """Vertex colours of a texture-mapped OBJ (None when it is not one: no ``vt`` referenced by faces, or
    no ``map_Kd`` among the materials used). ``corners``, ``uv_rows``, ``names``: :func:`_obj_walk`'s.
    Each distinct (vertex, UV, material) corner contributes the bilinear texture sample (or, without a
    UV or an image, the material's ``Kd`` when it has one); a vertex gets the mean of its contributions."""
    mats: dict[str, dict] = {}
    for rest in libs:
        for mtl in _obj_refs(rest.split("#", 1)[0], p.parent):
            for name, m in _read_mtl(mtl).items():
                mats.setdefault(name, m)
    if not any(m["map"] is not None for m in mats.values()) or not (corners[:, 1] >= 0).any():
        return None  # no texture image, or no face with texture coordinates
    for nm in names:
        if nm not in mats:
            files = ", ".join(repr(str(f)) for f in dict.fromkeys(m["mtl"] for m in mats.values()))
            raise _Err(f"material {nm!r} (usemtl) is not defined in the material libraries {files}")
    if not any(mats[nm]["map"] is not None for nm in names):
        return None
    uv = _floats(uv_rows, 2, "texture coordinate (vt u v)")
    if not np.isfinite(uv).all():
        raise _Err("texture coordinates (vt) must be finite")
    corners = np.unique(corners, axis=0)  # distinct (vertex, uv, material)
    corners = corners[(corners[:, 0] >= 0) & (corners[:, 0] < n_vertices)]
    total = np.zeros((n_vertices, 3))
    count = np.zeros(n_vertices)
    for k, nm in enumerate(names):
        m = mats[nm]
        mine = corners[corners[:, 2] == k]
        with_uv = mine[mine[:, 1] >= 0] if m["map"] is not None else mine[:0]
        if len(with_uv):
            img = _load_texture(m["map"], m["mtl"], nm)
            np.add.at(total, with_uv[:, 0], _sample_bilinear(img, uv[with_uv[:, 1]]))
            np.add.at(count, with_uv[:, 0], 1.0)
        rest = mine[mine[:, 1] < 0] if m["map"] is not None else mine
        if len(rest) and m["Kd"] is not None:
            np.add.at(total, rest[:, 0], m["Kd"])
            np.add.at(count, rest[:, 0], 1.0)
    missing = count == 0
    if missing.any():
        warnings.warn(
            f"{int(missing.sum())} of {n_vertices} vertices have no texture sample or material colour "
            f"(first: vertex {int(np.flatnonzero(missing)[0])}); they are mid grey",
            ColorWarning,
            stacklevel=2,
        )
        total[missing], count[missing] = 0.5, 1.0
    return total / count[:, None]


# --------------------------------------------------------------------------------------------
# XYZ
# --------------------------------------------------------------------------------------------
def _read_xyz(p: Path, want_colors: bool = True) -> _ParsedNormals:
    """``x y z`` rows (spaces or commas). The first line's column count sets the layout of every row (a row
    with another count is an error): six columns are ``x y z r g b`` (8-bit or [0, 1], see
    :func:`_text_colors`), unless the last three columns are unit vectors with a negative entry: ``x
    y z nx ny nz`` normals. Nine columns are ``x y z nx ny nz r g b``
    (CloudCompare / Open3D exports) or ``x y z r g b nx ny nz``: the triple that is a unit vector on
    every row is the normals (the first layout when both are), the other the colour; when
    neither is, the points are read without colour or normals and a :class:`ColorWarning` says so."""
    text = _read_text(p)
    rows = _content(text.replace(",", " ") if "," in text else text)
    _check_count(len(rows), "points")
    ncols = len(_tokens(rows[0][1])) if want_colors and rows else 3
    if ncols == 6:
        table = _floats(rows, 6, "point with colour (x y z r g b)", exact=True)
        extra = table[:, 3:]
        if (extra < 0).any() and _unit_rows(extra):
            return table[:, :3], None, None, extra
        return table[:, :3], None, _text_colors(extra, "XYZ point"), None
    if ncols == 9:
        table = _floats(rows, 9, "point with normal and colour (x y z nx ny nz r g b)", exact=True)
        for normals, colors in ((table[:, 3:6], table[:, 6:]), (table[:, 6:], table[:, 3:6])):
            if _unit_rows(normals):
                return table[:, :3], None, _text_colors(colors, "XYZ point"), normals
        warnings.warn("nine columns, but neither columns 4-6 nor 7-9 are unit normals on every row, so "
                      "the colour columns are unknown: points read without colour", ColorWarning, stacklevel=2)
        return table[:, :3], None, None, None
    return _floats(rows, 3, "point"), None, None, None


def _unit_rows(a: np.ndarray) -> bool:
    """Every row of ``a`` a unit vector, to the precision of a text file (1e-3)."""
    return bool(len(a)) and bool(np.allclose(np.linalg.norm(a, axis=1), 1.0, atol=1e-3))


# --------------------------------------------------------------------------------------------
# PLY (ascii, binary little/big endian)
# --------------------------------------------------------------------------------------------
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip


#: PLY vertex colour property names, in order of preference
_PLY_COLOR_NAMES = (("red", "green", "blue"), ("r", "g", "b"), ("diffuse_red", "diffuse_green", "diffuse_blue"))


def _ply_colors(vert: dict, types: dict[str, str]) -> np.ndarray | None:
    """Vertex colours of a PLY file by declared type: ``ushort`` is 16-bit, other integer types 8-bit
    (0..255), float types in [0, 1]; None when the vertices have no colour properties."""
    names = next((nm for nm in _PLY_COLOR_NAMES if all(c in vert for c in nm)), None)
    if names is None:
        return None
    cols = []
    for nm in names:
        a = np.asarray(vert[nm])
        t = np.dtype(types[nm])
        if t.kind == "f":
            cols.append(a.astype(np.float64))
            continue
        top = 65535 if t.itemsize == 2 and t.kind == "u" else 255
        a = a.astype(np.float64)  # ascii bodies are parsed as floats
        bad = ~np.isfinite(a) | (a != np.round(a)) | (a < 0) | (a > top)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise _Err(f"vertex {i}: colour property {nm!r} ({t.name}) is {a[i]!r}, not an integer in 0..{top}")
        cols.append(a.astype(np.uint16 if top == 65535 else np.int64))
    if len({c.dtype.kind for c in cols}) > 1 or len({c.dtype for c in cols}) > 1:
        raise _Err(f"PLY colour properties {', '.join(names)} have different types")
    return np.stack(cols, axis=1)


def _read_ply(p: Path, want_colors: bool = True) -> _ParsedNormals:
    data = p.read_bytes()
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise _Err("not a PLY file (missing 'ply' magic or 'end_header')")
    nl = data.find(b"\n", end)
    body_start = len(data) if nl < 0 else nl + 1
    header = data[:end].decode("ascii", errors="replace").splitlines()
    fmt = None
    # elements: (name, count, [(prop, type) | (prop, count_type, item_type)])
    elements: list[tuple[str, int, list[tuple]]] = []
    for raw in header[1:]:
        t = raw.split()
        if not t or t[0] in ("comment", "obj_info"):
            continue
        if t[0] == "format":
            fmt = t[1] if len(t) > 1 else ""
        elif t[0] == "element" and len(t) == 3:
            try:
                count = int(t[2])
            except ValueError:
                raise _Err(f"bad element count in header line {raw!r}") from None
            _check_count(count, t[1])
            elements.append((t[1], count, []))
        elif t[0] == "property" and elements:
            if t[1] == "list" and len(t) == 5 and t[2] in _PLY_TYPES and t[3] in _PLY_TYPES:
                elements[-1][2].append((t[4], _PLY_TYPES[t[2]], _PLY_TYPES[t[3]]))
            elif len(t) == 3 and t[1] in _PLY_TYPES:
                elements[-1][2].append((t[2], _PLY_TYPES[t[1]]))
            else:
                raise _Err(f"unsupported PLY property line {raw!r}")
        else:
            raise _Err(f"unsupported PLY header line {raw!r}")
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise _Err(f"unknown PLY format {fmt!r}")
    body = memoryview(data)[body_start:]  # no copy of the body
    names = [e[0] for e in elements]
    if "vertex" not in names:
        raise _Err("PLY header has no 'vertex' element")
    _check_ply_size(elements, fmt, len(body))
    if fmt == "ascii":
        parsed = _ply_ascii(bytes(body).decode("latin-1"), elements)
    else:
        parsed = _ply_binary(body, elements, "<" if fmt == "binary_little_endian" else ">")
    vert = parsed["vertex"]
    for c in "xyz":
        if c not in vert:
            raise _Err(f"PLY vertex element has no '{c}' property")
    vertices = np.stack([np.asarray(vert[c], dtype=np.float64) for c in "xyz"], axis=1)
    normals = None
    if all(c in vert for c in ("nx", "ny", "nz")):
        normals = np.stack([np.asarray(vert[c], dtype=np.float64) for c in ("nx", "ny", "nz")], axis=1)
    colors = None
    if want_colors:
        vprops = next(props for name, _, props in elements if name == "vertex")
        colors = _ply_colors(vert, {pr[0]: pr[1] for pr in vprops if len(pr) == 2})
    faces = None
    face = parsed.get("face")
    if face is not None:
        key = "vertex_indices" if "vertex_indices" in face else "vertex_index"
        if key not in face:
            raise _Err("PLY face element has no 'vertex_indices' list")
        faces = face[key]
        if isinstance(faces, list):
            faces = _fan(faces)
    return vertices, faces, colors, normals


def _check_ply_size(elements: list, fmt: str, n_bytes: int) -> None:
    """Refuse declared element counts the body cannot hold, before allocating anything: binary
    elements need their exact record size (list properties at least their count field), ascii
    elements at least :data:`MIN_TEXT_BYTES_PER_ELEMENT` bytes each."""
    if fmt == "ascii":
        n = sum(count for _, count, props in elements if props)
        _check_text_size(n, n_bytes, "elements")
        return
    need = 0
    for name, count, props in elements:
        rec = sum(np.dtype(pr[1]).itemsize for pr in props)  # a list's count field (its minimum)
        if count and rec:
            need += count * rec
            if need > n_bytes:
                raise _Err(
                    f"truncated: the header declares {count} {name}, which need at least {need} bytes "
                    f"of binary data, but the body has {n_bytes}"
                )


def _list_indices(arr: np.ndarray, what: str) -> np.ndarray:
    """List-property items as int64 vertex indices: integer types, or floats only when integral."""
    if arr.dtype.kind == "f":
        ok = np.isfinite(arr) & (np.abs(arr) <= _MAX_INDEX)
        if not ok.all() or not (np.mod(arr, 1) == 0).all():
            raise _Err(f"{what} are stored as floats and are not all integers")
    return arr.astype(np.int64)


def _ply_ascii(text: str, elements: list) -> dict:
    lines = [(i, s) for i, s in enumerate(text.splitlines(), 1) if s.strip()]
    out, pos = {}, 0
    for name, count, props in elements:
        rows = lines[pos : pos + count]
        if len(rows) < count:
            raise _Err(f"truncated: header declares {count} {name} but the body has {len(rows)}")
        pos += count
        if not props:
            continue
        if all(len(pr) == 2 for pr in props):
            arr = _floats(rows, len(props), name)
            out[name] = {pr[0]: arr[:, j] for j, pr in enumerate(props)}
        elif len(props) == 1 and name == "face":  # the usual: one list property
            faces = _parse_counted_faces(rows)
            out[name] = {props[0][0]: faces}
        elif name in ("vertex", "face"):
            raise _Err(f"unsupported ascii PLY {name} layout (mixed list and scalar properties)")
    return out


def _ply_binary(body: memoryview, elements: list, order: str) -> dict:
    out, pos = {}, 0
    for name, count, props in elements:
        if all(len(pr) == 2 for pr in props):
            dt = np.dtype([(pr[0], order + pr[1]) for pr in props])
            nbytes = dt.itemsize * count
            if pos + nbytes > len(body):
                raise _Err(f"truncated: binary body too short for {count} {name}")
            arr = np.frombuffer(body, dtype=dt, count=count, offset=pos)
            pos += nbytes
            out[name] = {pr[0]: arr[pr[0]] for pr in props}
            continue
        if name != "face" or len(props) != 1:
            if name == "vertex":
                raise _Err("unsupported binary PLY vertex layout (list properties)")
            raise _Err(f"unsupported binary PLY element {name!r} with list properties")
        lname, ct, it = props[0]
        ct, it = np.dtype(order + ct), np.dtype(order + it)
        if count and ct.kind == "f":
            raise _Err(f"PLY face list count type is a float ({ct.name}); it must be an integer type")
        # fast path: every face has the size k of the first one -> fixed-size records
        if count and pos + ct.itemsize <= len(body):
            k = int(np.frombuffer(body, dtype=ct, count=1, offset=pos)[0])
            dt = np.dtype([("n", ct), ("i", it, (max(k, 1),))])
            nbytes = dt.itemsize * count
            if k >= 3 and pos + nbytes <= len(body):
                arr = np.frombuffer(body, dtype=dt, count=count, offset=pos)
                if (arr["n"] == k).all():
                    pos += nbytes
                    idx = _list_indices(arr["i"], "face indices")
                    tri = np.stack([idx[:, [0, j, j + 1]] for j in range(1, k - 1)], axis=1).reshape(-1, 3)
                    out[name] = {lname: tri}
                    continue
        polys = []
        for k in range(count):
            if pos + ct.itemsize > len(body):
                raise _Err(f"truncated: binary body ends inside face {k} of {count}")
            n = int(np.frombuffer(body, dtype=ct, count=1, offset=pos)[0])
            pos += ct.itemsize
            if n < 3:
                raise _Err(f"face {k} has {n} vertices; a face needs at least 3")
            if pos + n * it.itemsize > len(body):
                raise _Err(f"truncated: binary body ends inside face {k} of {count}")
            idx = np.frombuffer(body, dtype=it, count=n, offset=pos)
            polys.append(_list_indices(idx, "face indices").tolist())
            pos += n * it.itemsize
        out[name] = {lname: polys}
    return out


# --------------------------------------------------------------------------------------------
# STL (ascii and binary), welded
# --------------------------------------------------------------------------------------------
_STL_DT = np.dtype([("n", "<f4", (3,)), ("v", "<f4", (3, 3)), ("attr", "<u2")])


def _weld(corners: np.ndarray) -> _Parsed:
    """Merge exactly coincident triangle corners ((m, 3, 3) soup) -> vertices, faces.

    Vertices keep the order of their first occurrence, so the result is deterministic.
    """
    flat = corners.reshape(-1, 3).astype(np.float64)
    flat = flat + 0.0  # turn -0.0 into +0.0 so both weld together
    _, first, inv = np.unique(flat, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return flat[first[order]], rank[inv.ravel()].reshape(-1, 3).astype(np.int64)


def _read_stl(p: Path, want_colors: bool = True) -> _ParsedColors:
    """STL through libigl's ``readSTL`` (a triangle soup in file order), welded here. Checked first, so
    the count limit applies before libigl allocates and a refusal says what is wrong (libigl 2.6 says
    "Failed to open file" for an ascii STL without facets, and names no line)."""
    size = p.stat().st_size
    with open(p, "rb") as fh:
        head = fh.read(84)
    binary = len(head) >= 84 and size == 84 + 50 * int(np.frombuffer(head, dtype="<u4", count=1, offset=80)[0])
    if binary:
        n = (size - 84) // 50
        _check_count(n, "triangles")
        if n == 0:
            raise _Err("binary STL with 0 triangles")
    else:
        if not head.lstrip().lower().startswith(b"solid"):
            raise _Err(
                "neither a valid binary STL (size does not match the triangle count) nor ascii STL "
                "(no 'solid' keyword): the file is probably truncated"
            )
        text = _read_text(p)
        n_vertex = len(re.findall(r"^\s*vertex\s", text, flags=re.MULTILINE))
        if not n_vertex:
            raise _Err("ascii STL without any 'vertex' line")
        n = len(re.findall(r"^\s*endfacet", text, flags=re.MULTILINE))
        if n * 3 != n_vertex:
            raise _Err(f"ascii STL has {n_vertex} vertex lines for {n} facets (truncated?)")
        _check_count(n, "triangles")
    import igl

    try:
        with _quiet():
            v, f, _ = igl.readSTL(str(p))
    except RuntimeError as e:  # libigl's message names no line
        raise _Err(f"libigl cannot read this {'binary' if binary else 'ascii'} STL ({e})") from None
    if f.shape != (n, 3) or not np.array_equal(f.ravel(), np.arange(3 * n)):
        raise _Err(f"libigl read {f.shape[0]} triangles of the {n} in the file")
    return (*_weld(v.reshape(-1, 3, 3)), None)


_QUIET_LOCK = threading.Lock()  # two threads swapping the same file descriptors would lose the real ones


@contextmanager
def _quiet():
    """Silence C-level output (libigl prints its parse errors to stdout, which is the CLI's JSON)."""
    with _QUIET_LOCK:
        sys.stdout.flush()
        sys.stderr.flush()
        try:
            saved = [os.dup(1), os.dup(2)]
        except OSError:  # no standard streams (a daemon): nothing to silence
            yield
            return
        try:
            with open(os.devnull, "wb") as null:
                os.dup2(null.fileno(), 1)
                os.dup2(null.fileno(), 2)
                yield
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])


# --------------------------------------------------------------------------------------------
# PCD (Open3D)
# --------------------------------------------------------------------------------------------
#: PCD fields holding packed colour (PCL's ``rgb`` float / ``rgba`` uint32: bits 0x00RRGGBB)
_PCD_PACKED = ("rgb", "rgba")
#: PCD TYPE letters as numpy kinds
_PCD_KINDS = {"F": "f", "I": "i", "U": "u"}


def _unpack_rgb(bits: np.ndarray) -> np.ndarray:
    """8-bit ``(n, 3)`` int64 colours of packed uint32 values 0x??RRGGBB (alpha ignored)."""
    b = bits.astype(np.uint32).astype(np.int64)
    return np.stack([(b >> 16) & 255, (b >> 8) & 255, b & 255], axis=1)


#: PCD normal fields (PCL's ``PointNormal``)
_PCD_NORMALS = ("normal_x", "normal_y", "normal_z")


def _has_normals(names: list[str], counts: list[int]) -> bool:
    """Whether a PCD file has the three normal fields, one value each."""
    return all(c in names and counts[names.index(c)] == 1 for c in _PCD_NORMALS)


def _pcd_colors(names: list[str], sizes: list[int], types: list[str], counts: list[int],
                column: Callable[[str], np.ndarray]) -> np.ndarray | None:
    """Colours of a PCD file: a packed ``rgb``/``rgba`` field (4 bytes; float fields are
    reinterpreted bit for bit, as PCL writes them) or separate ``r g b`` / ``red green blue``
    fields (typed as in PLY: integer types 8-bit except 2-byte unsigned, floats in [0, 1]).
    ``column(name)`` returns a field's values (float32 for float fields, else integers); None
    without colour fields."""
    packed = next((nm for nm in _PCD_PACKED if nm in names), None)
    if packed is not None:
        i = names.index(packed)
        if sizes[i] != 4 or counts[i] != 1:
            raise _Err(f"PCD colour field {packed!r} must be one 4-byte value (SIZE 4, COUNT 1), "
                       f"got SIZE {sizes[i]} COUNT {counts[i]}")
        v = column(packed)
        bits = v.astype(np.float32).view(np.uint32) if types[i].upper() == "F" else v.astype(np.int64)
        return _unpack_rgb(bits)
    vert = {nm: column(nm) for nm in names if nm in {c for trio in _PLY_COLOR_NAMES for c in trio}}
    typ = {nm: _PCD_KINDS.get(types[names.index(nm)].upper(), "f") + str(sizes[names.index(nm)]) for nm in vert}
    return _ply_colors(vert, typ)


def _read_pcd(p: Path, want_colors: bool = True) -> _ParsedNormals:
    data = p.read_bytes()
    fields: dict[str, list[str]] = {}
    pos = 0
    while "DATA" not in fields:
        nl = data.find(b"\n", pos)
        if nl < 0:
            raise _Err("not a PCD file (header without a DATA line)")
        line = data[pos:nl].decode("latin-1").split("#")[0].split()
        pos = nl + 1
        if line:
            fields[line[0].upper()] = line[1:]
        if pos > 65536:
            raise _Err("not a PCD file (no DATA line in the first 64 KiB)")
    try:
        names = fields["FIELDS"]
        n = int(fields["POINTS"][0])
        sizes = [int(x) for x in fields.get("SIZE", ["4"] * len(names))]
        types = fields.get("TYPE", ["F"] * len(names))
        counts = [int(x) for x in fields.get("COUNT", ["1"] * len(names))]
        mode = fields["DATA"][0].lower()
    except (KeyError, IndexError, ValueError):
        raise _Err("malformed PCD header (FIELDS/POINTS/SIZE/TYPE/COUNT/DATA)") from None
    if not all(c in names for c in "xyz"):
        raise _Err(f"PCD has no x/y/z fields (fields: {' '.join(names)})")
    if not (len(sizes) == len(types) == len(counts) == len(names)):
        raise _Err("PCD header: FIELDS, SIZE, TYPE and COUNT have different lengths")
    bad = [f"{nm}={c}" for nm, c in zip(names, counts) if c < 1]
    if bad:
        raise _Err(f"PCD header: COUNT must be >= 1 for every field, got {' '.join(bad)}")
    bad = [f"{nm}={sz}" for nm, sz in zip(names, sizes) if sz not in (1, 2, 4, 8)]
    if bad:
        raise _Err(f"PCD header: SIZE must be 1, 2, 4 or 8 bytes, got {' '.join(bad)}")
    if len(set(names)) != len(names):
        raise _Err(f"PCD header: repeated field names in FIELDS {' '.join(names)}")
    _check_count(n, "points")
    if mode == "ascii":
        _check_text_size(n, len(data) - pos, "points")
        width = sum(counts)
        rows = [(ln, r) for ln, r in _content(data[pos:].decode("latin-1"))]
        if len(rows) < n:
            raise _Err(f"truncated: header declares {n} points but the file has {len(rows)}")
        if len(rows) > n:
            raise _Err(f"header declares {n} points but the file has {len(rows)} data lines")
        short = [ln for ln, r in rows if len(r.split()) < width]
        if short:
            raise _Err(f"data line {short[0]} has fewer than the {width} declared values")
        def at(name: str) -> int:
            return sum(counts[: names.index(name)])

        table = _floats(rows, [at(c) for c in "xyz"], "point")
        colors = None
        if want_colors:
            colors = _pcd_colors(names, sizes, types, counts, lambda nm: _floats(rows, [at(nm)], nm)[:, 0])
        normals = _floats(rows, [at(c) for c in _PCD_NORMALS], "normal") if _has_normals(names, counts) else None
        return table, None, colors, normals
    if mode == "binary":
        try:
            dt = np.dtype([(nm, f"<{_PCD_KINDS[t.upper()]}{sz}", (c,) if c > 1 else ())
                           for nm, sz, t, c in zip(names, sizes, types, counts)])
        except (KeyError, TypeError, ValueError):
            raise _Err("PCD header: unsupported TYPE/SIZE combination") from None
        if len(data) - pos < dt.itemsize * n:
            raise _Err(f"truncated: binary data too short for {n} points")
        arr = np.frombuffer(data, dtype=dt, count=n, offset=pos)
        colors = None
        if want_colors:
            colors = _pcd_colors(names, sizes, types, counts, lambda nm: np.ascontiguousarray(arr[nm]))
        normals = None
        if _has_normals(names, counts):
            normals = np.stack([arr[c].astype(np.float64) for c in _PCD_NORMALS], axis=1)
        return np.stack([arr[c].astype(np.float64) for c in "xyz"], axis=1), None, colors, normals
    if mode != "binary_compressed":
        raise _Err(f"unknown PCD DATA mode {mode!r}")
    del data
    import open3d as o3d  # imported lazily: slow import; only for LZF-compressed data

    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        pc = o3d.io.read_point_cloud(str(p), format="pcd", remove_nan_points=False, remove_infinite_points=False)
    pts = np.asarray(pc.points, dtype=np.float64)
    if pts.shape[0] != n:  # Open3D returns an empty cloud instead of raising
        raise _Err(f"header declares {n} points but Open3D could read {pts.shape[0]}")
    colors = np.asarray(pc.colors, dtype=np.float64) if want_colors and pc.has_colors() else None
    normals = np.asarray(pc.normals, dtype=np.float64) if pc.has_normals() else None
    return pts, None, colors, normals


# --------------------------------------------------------------------------------------------
# writers
# --------------------------------------------------------------------------------------------
def _fmt_rows(*blocks: np.ndarray, prefix: str = "") -> bytes:
    """Rows of the column blocks side by side as text, one row per line: floats in shortest round-trip
    repr (exact), integers as integers."""
    rows = zip(*(b.tolist() for b in blocks))
    return "".join(prefix + " ".join(map(repr, chain(*row))) + "\n" for row in rows).encode()


def _point_columns(shape: Shape) -> list[np.ndarray]:
    """The per-point geometry every writer puts first: coordinates ``(n, 3)``, then a cloud's normals ``(n, 3)``."""
    return [shape.vertices] + ([] if shape.normals is None else [shape.normals])


def _write_off(fh, shape: Shape, binary: bool) -> None:
    # [C][N]OFF: x y z [nx ny nz] [r g b a], colours as floats in [0, 1]
    head = "C" * (shape.colors is not None) + "N" * (shape.normals is not None) + "OFF"
    fh.write(f"{head}\n{shape.n_vertices} {shape.n_faces} 0\n".encode())
    blocks = _point_columns(shape)
    if shape.colors is not None:
        blocks += [shape.colors, np.ones((shape.n_vertices, 1))]
    fh.write(_fmt_rows(*blocks))
    if shape.faces is not None:
        fh.write(_fmt_rows(shape.faces, prefix="3 "))


def _write_obj(fh, shape: Shape, binary: bool) -> None:
    fh.write(_fmt_rows(shape.vertices, *([] if shape.colors is None else [shape.colors]), prefix="v "))
    if shape.normals is not None:  # a cloud's: one vn per v, in order (MeshLab's and CloudCompare's layout)
        fh.write(_fmt_rows(shape.normals, prefix="vn "))
    if shape.faces is not None:
        fh.write(_fmt_rows(shape.faces + 1, prefix="f "))


def _write_xyz(fh, shape: Shape, binary: bool) -> None:
    # x y z [nx ny nz] [r g b]: the layouts the reader tells apart (normals are unit rows)
    fh.write(_fmt_rows(*_point_columns(shape), *([] if shape.colors is None else [shape.colors])))


def _write_pcd(fh, shape: Shape, binary: bool) -> None:
    n, rgb = shape.n_vertices, shape.colors is not None  # colours: PCL's packed float rgb (bits 0x00RRGGBB)
    nrm = shape.normals is not None
    fh.write(
        (
            f"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
            f"FIELDS x y z{' normal_x normal_y normal_z' * nrm}{' rgb' * rgb}\n"
            f"SIZE 8 8 8{' 8 8 8' * nrm}{' 4' * rgb}\nTYPE F F F{' F F F' * nrm}{' F' * rgb}\n"
            f"COUNT 1 1 1{' 1 1 1' * nrm}{' 1' * rgb}\nWIDTH {n}\nHEIGHT 1\n"
            f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA ascii\n"
        ).encode()
    )
    geometry = _point_columns(shape)
    if not rgb:
        fh.write(_fmt_rows(*geometry))
        return
    c = np.round(shape.colors * 255.0).astype(np.uint32)
    packed = ((c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]).view(np.float32)
    # the float32 value as a double prints exactly, and reads back to the same 32 bits
    fh.write(_fmt_rows(*geometry, packed[:, None].astype(np.float64)))


def _write_ply(fh, shape: Shape, binary: bool) -> None:
    fmt = f"binary_{sys.byteorder}_endian" if binary else "ascii"
    head = f"ply\nformat {fmt} 1.0\nelement vertex {shape.n_vertices}\n"
    head += "property double x\nproperty double y\nproperty double z\n"
    if shape.normals is not None:
        head += "property double nx\nproperty double ny\nproperty double nz\n"
    rgb = None
    if shape.colors is not None:  # 8-bit, as viewers expect
        rgb = np.round(shape.colors * 255.0).astype(np.uint8)
        head += "property uchar red\nproperty uchar green\nproperty uchar blue\n"
    if shape.faces is not None:
        head += f"element face {shape.n_faces}\nproperty list uchar int vertex_indices\n"
    fh.write((head + "end_header\n").encode())
    geometry = _point_columns(shape)
    if not binary:
        fh.write(_fmt_rows(*geometry, *([] if rgb is None else [rgb])))
        if shape.faces is not None:
            fh.write(_fmt_rows(shape.faces, prefix="3 "))
        return
    rec = np.empty(shape.n_vertices, dtype=[("v", "=f8", (3 * len(geometry),))]
                   + ([] if rgb is None else [("c", "u1", (3,))]))
    rec["v"] = np.hstack(geometry)
    if rgb is not None:
        rec["c"] = rgb
    fh.write(rec.tobytes())
    if shape.faces is not None:
        rec = np.empty(shape.n_faces, dtype=[("n", "u1"), ("i", "=i4", (3,))])
        rec["n"], rec["i"] = 3, shape.faces
        fh.write(rec.tobytes())


def _write_stl(fh, shape: Shape, binary: bool) -> None:
    f = shape.require_faces("STL output")
    tri = shape.vertices[f]
    if binary:
        rec = np.zeros(shape.n_faces, dtype=_STL_DT)
        rec["n"] = shape.face_normals
        rec["v"] = tri
        fh.write(b"binary STL written by shape-toolkit".ljust(80, b" "))
        fh.write(np.uint32(shape.n_faces).tobytes())
        fh.write(rec.tobytes())
        return
    parts = ["solid toolkit\n"]
    for nrm, t in zip(shape.face_normals.tolist(), tri.astype(np.float32).tolist()):
        parts.append("facet normal {!r} {!r} {!r}\n outer loop\n".format(*nrm))
        parts.extend("  vertex {!r} {!r} {!r}\n".format(*c) for c in t)
        parts.append(" endloop\nendfacet\n")
    parts.append("endsolid toolkit\n")
    fh.write("".join(parts).encode())


_READERS: dict[str, Callable[[Path, bool], _ParsedColors | _ParsedNormals]] = {
    ".off": _read_off, ".obj": _read_obj, ".ply": _read_ply, ".stl": _read_stl, ".xyz": _read_xyz, ".pcd": _read_pcd
}
_WRITERS = {".off": _write_off, ".obj": _write_obj, ".ply": _write_ply, ".stl": _write_stl, ".xyz": _write_xyz,
            ".pcd": _write_pcd}
