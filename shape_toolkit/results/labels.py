"""Segmentation labels: vertex <-> face conversion, relabelling, and pairwise constraints.

Benchmark ground truth such as the Princeton Segmentation Benchmark (PSB) is per face, while the
spectral segmenters label vertices; the conversions here are deterministic (ties go to the smallest
label). Must-link / cannot-link constraints (thesis 5.3) are read from JSON files
``{"must_link": [[i, j], ...], "cannot_link": [[i, j], ...]}`` with 0-based vertex ids, or drawn
reproducibly from a ground-truth segmentation.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp

from shape_toolkit.core.geometry import edge_components
from shape_toolkit.errors import ParameterError, ShapeFileError

if TYPE_CHECKING:  # pragma: no cover
    from shape_toolkit.core.shape import Shape

__all__ = [
    "read_vertex_ids",
    "vertex_ids_within",
    "read_int_file",
    "Constraints",
    "ConstraintError",
    "load_constraints",
    "save_constraints",
    "coerce_constraints",
    "draw_constraints",
    "clicks_from_segmentation",
    "vertex_to_face_labels",
    "face_to_vertex_labels",
    "face_segments_to_vertices",
    "relabel_consecutive",
    "segment_adjacency",
    "constraint_report",
]


class ConstraintError(ParameterError):
    """Pairwise constraints are malformed: out-of-range ids, self-pairs, or contradictory pairs."""


_INT_TOKEN = re.compile(r"[+-]?[0-9]+\Z")
#: Integers in label / id / map files must fit int64 with room to spare.
_MAX_ABS_INT = 2**62


def _read_small_text(p: Path, what: str) -> str:
    """The text of a small ascii/UTF-8 file, every problem a :class:`ShapeFileError`."""
    if not p.exists():
        raise ShapeFileError(p, "no such file")
    if p.is_dir():
        raise ShapeFileError(p, f"is a directory, expected a {what} file")
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise ShapeFileError(p, f"cannot read {what}: {exc.strerror or exc}") from None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ShapeFileError(p, f"not a text {what} file (invalid UTF-8 at byte {exc.start})") from None


def read_int_file(path: str | os.PathLike, what: str = "labels") -> np.ndarray:
    """Whitespace-separated integers of a text file (label files, PSB ``.seg``, ``.vts`` vertex ids,
    map files) as int64 ``(n,)``. Every problem (missing, directory, not text, empty, a token that
    is not a plain ASCII integer, a value beyond +-2**62) raises :class:`ShapeFileError` naming the
    file and the first bad token."""
    p = Path(path)
    tokens = _read_small_text(p, what).split()
    if not tokens:
        raise ShapeFileError(p, f"empty {what} file")
    try:
        values = np.array(tokens, dtype=np.int64)  # C parser; also accepts a few odd forms
        if all(_INT_TOKEN.match(t) for t in tokens) and (np.abs(values) <= _MAX_ABS_INT).all():
            return values
    except (ValueError, OverflowError):
        pass
    for k, t in enumerate(tokens):
        if not _INT_TOKEN.match(t):
            raise ShapeFileError(p, f"{what} must be integers, found {t[:40]!r} (value {k + 1})")
        if abs(int(t)) > _MAX_ABS_INT:
            raise ShapeFileError(p, f"value {k + 1} ({t[:40]}) is out of range for {what}")
    raise ShapeFileError(p, f"malformed {what} file")  # pragma: no cover - the loop names the token


def read_vertex_ids(
    path: str | os.PathLike, *, one_based: bool, n_vertices: int | None = None
) -> np.ndarray:
    """One vertex index per line (``.vts`` files count from 1) as 0-based int64 ``(p,)``; ``one_based``
    says how the file counts. With ``n_vertices``, indices outside the shape raise :class:`ShapeFileError`."""
    ids = read_int_file(path, "vertex indices")
    if one_based:
        if ids.min() < 1:
            raise ShapeFileError(path, f"1-based indices expected, found {int(ids.min())}")
        ids = ids - 1
    elif ids.min() < 0:
        raise ShapeFileError(path, f"negative vertex index {int(ids.min())}")
    return ids if n_vertices is None else vertex_ids_within(ids, path, n_vertices, one_based=one_based)


def vertex_ids_within(ids: np.ndarray, path: str | os.PathLike, n_vertices: int, *, one_based: bool) -> np.ndarray:
    """``ids`` (0-based, as :func:`read_vertex_ids` returns them from ``path``) checked against a shape of
    ``n_vertices`` vertices: :class:`ShapeFileError` naming the file's own (``one_based``) index when one is out of
    range. For ids read before the shape (a command's memory estimate counts them first)."""
    if ids.size and ids.max() >= n_vertices:
        raise ShapeFileError(
            path, f"vertex index {int(ids.max()) + one_based} is out of range for {n_vertices} vertices"
        )
    return ids


def _as_pairs(value: Any, what: str) -> np.ndarray:
    if value is None:
        return np.zeros((0, 2), dtype=np.int64)
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):
        raise ConstraintError(f"{what} must be a list of [i, j] vertex pairs") from None
    if arr.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ConstraintError(f"{what} must be a list of [i, j] vertex pairs, got shape {arr.shape}")
    if arr.dtype.kind == "f":
        if not np.all(np.isfinite(arr)) or not np.all(arr == np.round(arr)):
            raise ConstraintError(f"{what} must contain integer vertex ids")
    elif arr.dtype.kind not in "iu":
        raise ConstraintError(f"{what} must contain integer vertex ids, got {arr.dtype}")
    if np.abs(arr.astype(np.float64)).max() > _MAX_ABS_INT:
        raise ConstraintError(f"{what} contains vertex ids out of range")
    return arr.astype(np.int64)


@dataclass(frozen=True)
class Constraints:
    """Must-link and cannot-link vertex pairs, int64 ``(p, 2)`` and ``(q, 2)``, 0-based."""

    must_link: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))
    cannot_link: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))

    def __post_init__(self) -> None:
        object.__setattr__(self, "must_link", _as_pairs(self.must_link, "must_link"))
        object.__setattr__(self, "cannot_link", _as_pairs(self.cannot_link, "cannot_link"))

    @property
    def n_must(self) -> int:
        """Number of must-link pairs."""
        return int(len(self.must_link))

    @property
    def n_cannot(self) -> int:
        """Number of cannot-link pairs."""
        return int(len(self.cannot_link))

    def __len__(self) -> int:
        return self.n_must + self.n_cannot

    def validate(self, n_vertices: int) -> Constraints:
        """Check ids against ``n_vertices``, reject self-pairs and pairs in both lists; returns self."""
        for name, pairs in (("must_link", self.must_link), ("cannot_link", self.cannot_link)):
            if len(pairs) == 0:
                continue
            bad = np.flatnonzero((pairs < 0).any(axis=1) | (pairs >= n_vertices).any(axis=1))
            if bad.size:
                i = int(bad[0])
                raise ConstraintError(
                    f"{name}[{i}] = {pairs[i].tolist()} is out of range: vertex ids must be in "
                    f"[0, {n_vertices - 1}] (0-based)"
                )
            same = np.flatnonzero(pairs[:, 0] == pairs[:, 1])
            if same.size:
                i = int(same[0])
                raise ConstraintError(f"{name}[{i}] = {pairs[i].tolist()} links a vertex to itself")
        if self.n_must and self.n_cannot:
            must = {tuple(p) for p in np.sort(self.must_link, axis=1).tolist()}
            for i, p in enumerate(np.sort(self.cannot_link, axis=1).tolist()):
                if tuple(p) in must:
                    raise ConstraintError(
                        f"pair {self.cannot_link[i].tolist()} is both a must-link and a cannot-link"
                    )
            # must-links are transitive: a cannot-link inside one must-linked group is contradictory
            n = int(max(self.must_link.max(), self.cannot_link.max())) + 1
            _, comp = edge_components(n, self.must_link)
            clash = np.flatnonzero(comp[self.cannot_link[:, 0]] == comp[self.cannot_link[:, 1]])
            if clash.size:
                i = int(clash[0])
                raise ConstraintError(
                    f"cannot_link[{i}] = {self.cannot_link[i].tolist()} joins two vertices that the "
                    "must-links (transitively) put in the same segment"
                )
        return self

    def to_dict(self) -> dict[str, list[list[int]]]:
        """The JSON-ready form ``{"must_link": [[i, j], ...], "cannot_link": [...]}``."""
        return {"must_link": self.must_link.tolist(), "cannot_link": self.cannot_link.tolist()}


def load_constraints(path: str | os.PathLike, n_vertices: int | None = None) -> Constraints:
    """Read a constraints JSON file and validate it against ``n_vertices`` (when given)."""
    p = Path(path)
    if not p.exists():
        raise ShapeFileError(p, "no such constraints file")
    text = _read_small_text(p, "constraints JSON")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ShapeFileError(p, f"constraints are not valid JSON: {exc}") from None
    except (RecursionError, ValueError) as exc:  # absurdly nested, or an integer too long to parse
        raise ShapeFileError(p, f"constraints are not usable JSON: {type(exc).__name__}") from None
    if not isinstance(data, dict):
        raise ShapeFileError(
            p, 'constraints must be a JSON object {"must_link": [...], "cannot_link": [...]}'
        )
    unknown = sorted(set(data) - {"must_link", "cannot_link"})
    if unknown:
        raise ShapeFileError(p, f"unknown constraint keys {unknown}; expected must_link and cannot_link")
    try:
        c = Constraints(data.get("must_link"), data.get("cannot_link"))
        if n_vertices is not None:
            c.validate(n_vertices)
    except ConstraintError as exc:
        raise ConstraintError(f"{p}: {exc}") from None
    return c


def save_constraints(path: str | os.PathLike, constraints: Constraints) -> None:
    """Write ``constraints`` as JSON (0-based vertex ids)."""
    Path(path).write_text(json.dumps(constraints.to_dict()) + "\n")


def coerce_constraints(value: Any, n_vertices: int) -> Constraints | None:
    """A validated :class:`Constraints` from a Constraints, a dict, a JSON path, or None."""
    if value is None:
        return None
    if isinstance(value, Constraints):
        c = value
    elif isinstance(value, dict):
        unknown = sorted(set(value) - {"must_link", "cannot_link"})
        if unknown:
            raise ConstraintError(f"unknown constraint keys {unknown}; expected must_link and cannot_link")
        c = Constraints(value.get("must_link"), value.get("cannot_link"))
    elif isinstance(value, (str, os.PathLike)):
        return load_constraints(value, n_vertices)
    else:
        raise ConstraintError(
            f"constraints must be a Constraints, a dict or a path, got {type(value).__name__}"
        )
    return c.validate(n_vertices)


def constraint_report(labels: np.ndarray, constraints: Constraints) -> dict[str, Any]:
    """How many of ``constraints`` the vertex ``labels`` ``(n,)`` keep: counts of must-links (same
    segment) and cannot-links (different segments), the number of clicked parts (groups of vertices
    joined by must-links; cannot-link ends on their own are not parts) and of segments, and
    ``reason`` (None when every constraint is kept): why some could not be, when the labels show it
    (fewer segments than clicked parts that must be apart), else that the method does not enforce
    them."""
    labels = np.asarray(labels)
    ml, cl = constraints.must_link, constraints.cannot_link
    must_broken = int(np.sum(labels[ml[:, 0]] != labels[ml[:, 1]])) if len(ml) else 0
    cannot_broken = int(np.sum(labels[cl[:, 0]] == labels[cl[:, 1]])) if len(cl) else 0
    parts = 0  # clicked parts: the groups of vertices must-links join
    if len(ml):
        ids = np.unique(ml)
        pos = np.searchsorted(ids, ml)
        parts = edge_components(ids.size, pos)[0]
    n_segments = int(np.unique(labels).size)
    reason = None
    if must_broken or cannot_broken:
        if cannot_broken and n_segments < parts:
            reason = (f"{n_segments} segments for {parts} clicked parts: parts that must be apart share a "
                      f"segment; ask for {parts} segments")
        else:
            reason = "the method uses the constraints to shape its clustering but does not enforce them"
    return {
        "must_link": int(len(ml)), "must_link_broken": must_broken,
        "cannot_link": int(len(cl)), "cannot_link_broken": cannot_broken,
        "clicked_parts": parts, "n_segments": n_segments, "reason": reason,
    }


def relabel_consecutive(labels: np.ndarray) -> np.ndarray:
    """Labels renumbered ``0..k-1`` in order of first appearance, int64 ``(n,)``."""
    labels = np.asarray(labels).ravel()
    if labels.size == 0:
        return labels.astype(np.int64)
    _, first, inv = np.unique(labels, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return rank[inv.ravel()].astype(np.int64)


def _check_faces(faces: np.ndarray, n_vertices: int | None = None) -> np.ndarray:
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ParameterError(f"faces must be an (m, 3) array, got shape {faces.shape}")
    faces = faces.astype(np.int64)
    if n_vertices is not None and faces.size and (faces.min() < 0 or faces.max() >= n_vertices):
        raise ParameterError(f"face vertex ids must be in [0, {n_vertices - 1}]")
    return faces


def vertex_to_face_labels(faces: np.ndarray, vertex_labels: np.ndarray) -> np.ndarray:
    """Face labels ``(m,)`` int64: the majority label of each face's three vertices; when all three
    differ the smallest label wins (deterministic)."""
    vl = np.asarray(vertex_labels).ravel().astype(np.int64)
    faces = _check_faces(faces, len(vl))
    a, b, c = vl[faces[:, 0]], vl[faces[:, 1]], vl[faces[:, 2]]
    out = np.minimum(np.minimum(a, b), c)
    out = np.where(b == c, b, out)
    out = np.where(a == c, a, out)
    out = np.where(a == b, a, out)
    return out


def face_to_vertex_labels(
    faces: np.ndarray,
    face_labels: np.ndarray,
    n_vertices: int,
    face_areas: np.ndarray | None = None,
) -> np.ndarray:
    """Vertex labels ``(n,)`` int64: the label of the largest total area (face count when
    ``face_areas`` is None) among each vertex's incident faces; ties go to the smallest label,
    vertices without faces get -1."""
    faces = _check_faces(faces, n_vertices)
    fl = np.asarray(face_labels).ravel().astype(np.int64)
    if len(fl) != len(faces):
        raise ParameterError(f"{len(fl)} face labels for {len(faces)} faces")
    w = np.ones(len(faces)) if face_areas is None else np.asarray(face_areas, dtype=np.float64).ravel()
    if len(w) != len(faces):
        raise ParameterError(f"{len(w)} face areas for {len(faces)} faces")
    uniq, lab = np.unique(fl, return_inverse=True)
    rows = faces.ravel()
    cols = np.repeat(lab.ravel(), 3)
    votes = sp.csr_matrix((np.repeat(w, 3), (rows, cols)), shape=(n_vertices, len(uniq)))
    votes.sum_duplicates()
    out = np.full(n_vertices, -1, dtype=np.int64)
    if votes.nnz == 0:
        return out
    # per row: largest vote, smallest column among ties (columns are sorted labels)
    coo = votes.tocoo()
    tol = 1e-12 * max(float(np.abs(coo.data).max()), 1.0)
    key = np.lexsort((coo.col, -np.round(coo.data / tol) * tol, coo.row))
    r = coo.row[key]
    first = np.ones(len(r), dtype=bool)
    first[1:] = r[1:] != r[:-1]
    out[r[first]] = uniq[coo.col[key][first]]
    return out


def face_segments_to_vertices(shape: Shape, face_labels: np.ndarray) -> np.ndarray:
    """Per-vertex labels int64 ``(n,)`` of the mesh ``shape`` from its face labels ``(m,)``: the label of
    the largest incident area (:func:`face_to_vertex_labels`); vertices in no face take their nearest
    vertex's. What a segmenter of faces returns as vertex labels."""
    vl = face_to_vertex_labels(shape.faces, face_labels, shape.n_vertices, shape.face_areas)
    lone = vl < 0
    if lone.any():
        from scipy.spatial import cKDTree

        ok = np.flatnonzero(~lone)
        _, j = cKDTree(shape.vertices[ok]).query(shape.vertices[lone])
        vl[lone] = vl[ok[j]]
    return vl


def segment_adjacency(labels: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Pairs of distinct labels ``(a, b)``, ``a < b``, joined by at least one of the ``(e, 2)``
    vertex edges; int64 ``(r, 2)`` sorted."""
    labels = np.asarray(labels).ravel()
    e = np.asarray(edges, dtype=np.int64)
    la, lb = labels[e[:, 0]], labels[e[:, 1]]
    diff = la != lb
    pairs = np.sort(np.stack([la[diff], lb[diff]], axis=1), axis=1)
    return np.unique(pairs, axis=0).astype(np.int64).reshape(-1, 2)


def _interior(labels: np.ndarray, edges: np.ndarray, rings: int) -> np.ndarray:
    """Boolean ``(n,)``: vertices at least ``rings`` edges away from another label."""
    n = len(labels)
    e = np.asarray(edges, dtype=np.int64)
    boundary = np.zeros(n, dtype=bool)
    cut = labels[e[:, 0]] != labels[e[:, 1]]
    boundary[e[cut].ravel()] = True
    A = sp.csr_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n))
    near = boundary.copy()
    for _ in range(max(rings - 1, 0)):
        near = near | (A @ near.astype(np.float64) > 0)
    return ~near


def _walk_inside(
    A: sp.csr_matrix, labels: np.ndarray, start: int, hops: int, rng: np.random.Generator
) -> int:
    """A random vertex of ``start``'s segment at ``hops`` edges from it (fewer if the segment ends)."""
    lab = labels[start]
    seen = {start}
    frontier = [start]
    for _ in range(hops):
        nxt = []
        for v in frontier:
            for w in A.indices[A.indptr[v] : A.indptr[v + 1]].tolist():
                if w not in seen and labels[w] == lab:
                    seen.add(w)
                    nxt.append(w)
        if not nxt:
            break
        frontier = nxt
    return int(rng.choice(np.sort(np.asarray(frontier))))


def draw_constraints(
    labels: np.ndarray,
    edges: np.ndarray,
    *,
    n_must_per_segment: int = 2,
    n_cannot_per_boundary: int = 1,
    boundary_rings: int = 3,
    cannot_offset: int = 3,
    min_segment_size: int = 1,
    random_state: int = 0,
) -> Constraints:
    """Constraints drawn from a ground-truth vertex segmentation ``labels`` ``(n,)`` on a graph with
    ``(e, 2)`` ``edges``, the way a user would place them (thesis 5.3, 5.5):

    - ``n_must_per_segment`` must-links chained between random vertices of each segment, avoiding
      the band of ``boundary_rings`` edges along its boundary when the segment has other vertices;
    - ``n_cannot_per_boundary`` cannot-links across every pair of neighbouring segments: a random
      cut edge ``(u, v)`` is picked and each end walks ``cannot_offset`` edges into its own segment,
      so the pair straddles the boundary closely (CSC propagates a cannot-link to the whole
      hypersphere between the two vertices, so far-apart pairs would damage whole segments).

    Segments smaller than ``min_segment_size`` get no constraint. Reproducible with ``random_state``.
    """
    labels = np.asarray(labels).ravel().astype(np.int64)
    if min(n_must_per_segment, n_cannot_per_boundary, boundary_rings, cannot_offset) < 0:
        raise ParameterError("numbers of constraints, rings and offsets must be >= 0")
    n = len(labels)
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    if e.size and (e.min() < 0 or e.max() >= n):
        raise ParameterError(f"edge vertex ids must be in [0, {n - 1}]")
    rng = np.random.default_rng(random_state)
    interior = _interior(labels, e, boundary_rings)
    values, sizes = np.unique(labels, return_counts=True)  # any label values (a bincount of 2**62 would not fit)
    big = {int(lab) for lab, size in zip(values, sizes) if size >= min_segment_size}
    must = []
    for lab in sorted(big):
        ids = np.flatnonzero(labels == lab)
        inner = ids[interior[ids]]
        pool = inner if len(inner) >= n_must_per_segment + 1 else ids
        if len(pool) < 2 or n_must_per_segment == 0:
            continue
        pick = rng.choice(pool, size=min(n_must_per_segment + 1, len(pool)), replace=False)
        must.extend([int(pick[t]), int(pick[t + 1])] for t in range(len(pick) - 1))
    cannot = []
    if n_cannot_per_boundary and len(e):
        A = sp.csr_matrix(
            (np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)
        )
        la, lb = labels[e[:, 0]], labels[e[:, 1]]
        cut = np.flatnonzero(la != lb)
        lo, hi = np.minimum(la[cut], lb[cut]), np.maximum(la[cut], lb[cut])
        for a, b in segment_adjacency(labels, e).tolist():
            if a not in big or b not in big:
                continue
            candidates = cut[(lo == a) & (hi == b)]
            for _ in range(n_cannot_per_boundary):
                u, v = e[int(rng.choice(candidates))]
                if labels[u] != a:
                    u, v = v, u
                cannot.append([_walk_inside(A, labels, int(u), cannot_offset, rng),
                               _walk_inside(A, labels, int(v), cannot_offset, rng)])
    return Constraints(must, cannot).validate(n)


def clicks_from_segmentation(
    shape: Any,
    labels: np.ndarray,
    *,
    n_must_per_segment: int = 1,
    n_cannot_per_boundary: int = 3,
    cannot_offset: int = 8,
    min_segment_fraction: float = 0.01,
    faces: bool | None = None,
    random_state: int = 0,
) -> Constraints:
    """The clicks a person would give for a known segmentation, with the PSB benchmark's protocol
    (``benchmarks/configs/psb_segmentation.toml``; its ``-1ml`` rows are the defaults here): ``labels`` has one
    label per face ``(m,)`` (PSB ``.seg``; a vertex takes its largest incident area) or per vertex
    ``(n,)`` of the mesh ``shape`` (``faces``: which; None: told by the count). Every segment with at
    least ``min_segment_fraction`` of the vertices gets ``n_must_per_segment`` must-links chained
    between ``n_must_per_segment + 1`` random vertices at least 3 rings inside it, and every pair of
    neighbouring such segments ``n_cannot_per_boundary`` cannot-links whose ends lie ``cannot_offset``
    edges either side of a random edge of their common boundary (:func:`draw_constraints`). A vertex
    without a labelled face (on no face, or only on faces labelled < 0) gets no click. Reproducible
    with ``random_state``; :class:`ParameterError` for a label count that does not fit (or fits both
    when ``faces`` is None), non-integer labels, negative vertex labels, or a fraction outside
    ``[0, 1]``."""
    tri = shape.require_faces("clicks from a segmentation")
    n, m = shape.n_vertices, len(tri)
    lab = np.asarray(labels).ravel()
    if lab.size and not np.issubdtype(lab.dtype, np.integer):
        raise ParameterError("segmentation labels must be integers")
    frac = float(min_segment_fraction)
    if not 0.0 <= frac <= 1.0:
        raise ParameterError(f"min_segment_fraction must be in [0, 1], got {min_segment_fraction!r}")
    if faces is None:
        if m == n and len(lab) == n:
            raise ParameterError(f"{n} labels fit both the faces and the vertices: say which (faces=)")
        faces = len(lab) == m
    if len(lab) != (m if faces else n):
        raise ParameterError(f"{len(lab)} labels for a mesh of {m} faces and {n} vertices: "
                             f"expected one per {'face' if faces else 'vertex'}")
    if faces:
        vt = face_to_vertex_labels(tri, lab, n, shape.face_areas)
    else:
        vt = lab.astype(np.int64)
        if (vt < 0).any():
            raise ParameterError("vertex labels must be >= 0")
    cons = draw_constraints(vt, shape.edges, n_must_per_segment=n_must_per_segment,
                            n_cannot_per_boundary=n_cannot_per_boundary, cannot_offset=cannot_offset,
                            min_segment_size=max(2, int(n * frac + 1e-9)), random_state=random_state)
    unlabelled = vt < 0  # no labelled face (face labels only): never clicked

    def keep(pairs: np.ndarray) -> np.ndarray:
        return pairs[~unlabelled[pairs].any(axis=1)] if len(pairs) else pairs

    return Constraints(keep(cons.must_link), keep(cons.cannot_link)).validate(n)
