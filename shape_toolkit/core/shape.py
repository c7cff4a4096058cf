"""The immutable :class:`Shape`: vertices, optional triangle faces, optional per-vertex colours, optional
outward normals of a point cloud, cheap cached properties."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from shape_toolkit.errors import InvalidShapeError, MeshRequiredError

__all__ = [
    "Shape",
    "check_colors",
    "check_normals",
    "NormalsWarning",
    "check_extent",
    "coordinate_scale",
    "duplicate_face_pairs",
    "check_no_duplicate_faces",
]

#: Float colours may exceed [0, 1] by this much (rounding of computed colours) and are clipped;
#: anything further out is refused.
COLOR_TOLERANCE = 1e-6


def coordinate_scale(vertices: np.ndarray) -> float:
    """A power of two close to the largest absolute coordinate (1.0 for all-zero coordinates).

    Dividing coordinates by it is exact (only the exponent changes), so lengths and areas computed
    on ``vertices / scale`` and multiplied back are bit-identical to the direct computation when that
    does not overflow or underflow, and stay finite where the direct one would not (1e300 or 1e-300
    coordinates).
    """
    v = np.asarray(vertices)
    m = float(np.max(np.abs(v))) if v.size else 0.0
    if not np.isfinite(m) or m == 0.0:
        return 1.0
    return float(np.ldexp(1.0, int(np.frexp(m)[1])))


#: the largest finite float64
_FLOAT_MAX = float(np.finfo(np.float64).max)
#: the smallest positive normal float64: squared lengths below it lose their precision (subnormal) or vanish
_FLOAT_TINY = float(np.finfo(np.float64).tiny)


def check_extent(vertices: np.ndarray, n_items: int | None = None, where: str = "", *, power: int = 2) -> float:
    """The bounding-box diagonal of finite ``vertices`` ``(n, 3)``, or :class:`InvalidShapeError` when the
    shape's squared lengths do not fit float64 (``power=4``: when the products of two areas do not, the rule
    of the computations, :meth:`Shape.check_computable`).

    The rule: every area and squared length the toolkit computes (face and vertex areas, Laplacian
    weights and mass matrices, sums of squared distances over all vertices or faces) must be a
    normal float64 number. So, with ``d`` the bounding-box diagonal and ``n_items`` the number of
    vertices or faces, whichever is larger (default: the number of vertices), ``n_items * d**2`` must
    not overflow (coordinates near 1e154 and beyond: infinite areas) and a non-zero ``d**2`` must not
    underflow below the smallest normal number (coordinates near 1e-154 and below: areas of zero).
    A shape whose vertices all coincide (``d == 0``) passes; its degeneracy is judged where it
    matters. The message names the diagonal, the limit and the fix (rescale the coordinates).

    ``power=4`` is the rule of the computations (spectra, segmentations, matches): the Laplacian's weights and
    masses, norms of area vectors and area-weighted sums multiply two areas, about ``d**4 / n_items**2`` each. So
    ``n_items * d**4`` must not overflow (coordinates near 1e76 and beyond) and ``d**4 / n_items**2`` must not
    underflow (near 1e-75 and below); a shape read or cleaned may lie outside (``info`` works at 1e150).
    """
    if power not in (2, 4):  # pragma: no cover - programming error
        raise ValueError(f"power must be 2 or 4, got {power}")
    v = np.asarray(vertices, dtype=np.float64)
    if v.size == 0:
        return 0.0
    m = float(np.abs(v).max())
    if m == 0.0:
        return 0.0
    e = int(np.frexp(m)[1])
    w = np.ldexp(v, -e)  # exact rescaling into (-1, 1): no overflow for any finite coordinates
    d_scaled = float(np.linalg.norm(w.max(axis=0) - w.min(axis=0)))
    count = max(int(v.shape[0] if n_items is None else n_items), 1)
    p10 = int(np.floor(np.log10(m)))  # the decimal exponent of the coordinates, for the advice
    with np.errstate(over="ignore", under="ignore"):
        d = float(np.ldexp(d_scaled, e))
        if power == 4:
            hi, lo = (_FLOAT_MAX / count) ** 0.25, (_FLOAT_TINY * float(count) ** 2) ** 0.25
            if not np.isfinite(d) or d > hi or 0 < d < lo:
                big = not np.isfinite(d) or d > hi
                raise InvalidShapeError(
                    f"coordinates too {'large' if big else 'small'} for the toolkit's computations{where}: the "
                    f"bounding-box diagonal is {d:.3g}, so products of two areas (the Laplacian's weights and "
                    f"masses) {'overflow' if big else 'underflow'} float64 (for {count} vertices or faces the diagonal "
                    f"must lie in [{lo:.3g}, {hi:.3g}]); rescale the shape, e.g. "
                    + (f"divide its coordinates by 1e{p10}" if big else f"multiply its coordinates by 1e{-p10}"))
            return d
        limit = float(np.sqrt(_FLOAT_MAX / count))
        if not np.isfinite(d) or d > limit:
            shown = f"{d:.3g}" if np.isfinite(d) else f"beyond float64 ({_FLOAT_MAX:.3g})"
            raise InvalidShapeError(
                f"coordinates too large for float64{where}: the bounding-box diagonal is {shown}, so squared "
                f"lengths and areas overflow (for {count} vertices or faces the diagonal must stay below "
                f"{limit:.3g}); rescale the shape, e.g. divide its coordinates by 1e{p10}"
            )
        if d > 0 and d * d < _FLOAT_TINY:
            raise InvalidShapeError(
                f"coordinates too small for float64{where}: the bounding-box diagonal is {d:.3g}, so squared "
                f"lengths and areas underflow to zero (the diagonal must be at least {np.sqrt(_FLOAT_TINY):.3g}); "
                f"rescale the shape, e.g. multiply its coordinates by 1e{-p10}"
            )
    return d


def duplicate_face_pairs(faces: np.ndarray) -> np.ndarray:
    """``(d, 2)`` int64 pairs ``[earlier face, duplicate face]`` of faces with the same vertex set
    (any order or orientation), one row per duplicate, in order of the duplicate."""
    f = np.sort(np.asarray(faces, dtype=np.int64), axis=1)
    if len(f) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    order = np.lexsort(f.T[::-1])
    srt = f[order]
    same = (srt[1:] == srt[:-1]).all(axis=1)
    if not same.any():
        return np.zeros((0, 2), dtype=np.int64)
    start = np.flatnonzero(np.r_[True, ~same])  # group starts in sorted order
    group = np.cumsum(np.r_[True, ~same]) - 1
    first = order[start][group]  # lexsort is stable: the lowest face index leads its group
    dup = np.flatnonzero(order != first)
    pairs = np.stack([first[dup], order[dup]], axis=1)
    return pairs[np.argsort(pairs[:, 1], kind="stable")].astype(np.int64)


def check_no_duplicate_faces(faces: np.ndarray, where: str = "") -> None:
    """Raise :class:`InvalidShapeError` when two faces share the same three vertices.

    Duplicate faces double the weight of their edges and vertex areas, so they silently change
    every spectrum (an icosphere's lambda2 moves from 2.0 to 1.85); the rule of the toolkit is to
    refuse them, naming the fix (``shape-toolkit clean`` or :func:`shape_toolkit.core.cleanup.clean_shape`).
    """
    pairs = duplicate_face_pairs(faces)
    if len(pairs):
        a, b = (int(x) for x in pairs[0])
        tri = np.asarray(faces)[b].tolist()
        raise InvalidShapeError(
            f"{len(pairs)} duplicate faces{where} (first: face {b} repeats face {a}, vertices {tri}); "
            "they would silently change the spectrum: remove them with `shape-toolkit clean` "
            "(or shape_toolkit.core.cleanup.clean_shape)"
        )


def check_colors(colors: np.ndarray, n_vertices: int, where: str = "") -> np.ndarray:
    """Per-vertex RGB colours as float64 ``(n_vertices, 3)`` in [0, 1], or :class:`InvalidShapeError`.

    ``uint16`` values are divided by 65535, other integer types must lie in 0..255 and are divided
    by 255 (8-bit channels); floats must be finite and in [0, 1] (values off by at most
    :data:`COLOR_TOLERANCE` are clipped). Out-of-range values are refused, never clipped: float
    colours in 0..255, say, would otherwise all turn white.
    """
    c = np.asarray(colors)
    if c.ndim != 2 or c.shape != (n_vertices, 3):
        raise InvalidShapeError(f"colors must be an ({n_vertices}, 3) RGB array, got shape {c.shape}{where}")
    if c.dtype == np.bool_ or not np.issubdtype(c.dtype, np.number) or np.iscomplexobj(c):
        raise InvalidShapeError(f"colors must be real numbers, got {c.dtype}{where}")
    if np.issubdtype(c.dtype, np.integer):
        top = 65535 if c.dtype == np.uint16 else 255
        bad = (c < 0) | (c > top)
        if bad.any():
            i = int(np.flatnonzero(bad.any(axis=1))[0])
            raise InvalidShapeError(
                f"{int(bad.any(axis=1).sum())} vertex colours outside the integer range 0..{top} "
                f"(first: vertex {i}, {c[i].tolist()}){where}"
            )
        return c.astype(np.float64) / top
    c = c.astype(np.float64, copy=True)
    if not np.isfinite(c).all():
        i = int(np.flatnonzero(~np.isfinite(c).all(axis=1))[0])
        raise InvalidShapeError(f"vertex colours must be finite (first bad: vertex {i}, {c[i].tolist()}){where}")
    bad = (c < -COLOR_TOLERANCE) | (c > 1 + COLOR_TOLERANCE)
    if bad.any():
        i = int(np.flatnonzero(bad.any(axis=1))[0])
        raise InvalidShapeError(
            f"{int(bad.any(axis=1).sum())} vertex colours outside [0, 1] (first: vertex {i}, {c[i].tolist()}); "
            f"float colours are in [0, 1] -- 8-bit values go in a uint8 array{where}"
        )
    return np.clip(c, 0.0, 1.0, out=c)


class NormalsWarning(UserWarning):
    """A point cloud's own normals were not used as given: a file's with zero or non-finite ones (PCL writes NaN
    for a normal it did not compute) or normals without consistent signs are replaced by estimated ones, and
    normals pointing inwards are turned (:func:`~shape_toolkit.core.surface.cloud_normals`)."""


def check_normals(normals: np.ndarray, n_vertices: int, where: str = "") -> np.ndarray:
    """Per-point normals as unit float64 ``(n_vertices, 3)`` vectors (each divided by its length), or
    :class:`InvalidShapeError` for another shape, non-real or non-finite values, or a zero vector (a point whose
    normal the file does not know: read it without normals and they are estimated for every point)."""
    a = np.asarray(normals)
    if a.ndim != 2 or a.shape != (n_vertices, 3):
        raise InvalidShapeError(f"normals must be an ({n_vertices}, 3) array, got shape {a.shape}{where}")
    if a.dtype == np.bool_ or not np.issubdtype(a.dtype, np.number) or np.iscomplexobj(a):
        raise InvalidShapeError(f"normals must be real numbers, got {a.dtype}{where}")
    a = a.astype(np.float64, copy=True)
    if not np.isfinite(a).all():
        i = int(np.flatnonzero(~np.isfinite(a).all(axis=1))[0])
        raise InvalidShapeError(f"normals must be finite (first bad: point {i}, {a[i].tolist()}){where}")
    with np.errstate(over="ignore", under="ignore"):
        if np.all(np.abs(np.linalg.norm(a, axis=1) - 1.0) <= 1e-12):
            return a  # unit already (a shape's own normals passed on): kept bit for bit, so is the content hash
    scale = np.abs(a).max(axis=1, keepdims=True)  # no overflow or underflow in the lengths
    np.divide(a, scale, out=a, where=scale > 0)
    length = np.linalg.norm(a, axis=1, keepdims=True)
    if not (length > 0).all():
        i = int(np.flatnonzero(~(length[:, 0] > 0))[0])
        raise InvalidShapeError(
            f"{int((~(length > 0)).sum())} normals are zero vectors (first: point {i}): a normal must have a "
            f"direction; read the cloud without its normals to have them estimated{where}"
        )
    return a / length


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False, repr=False)
class Shape:
    """A triangle mesh (``faces`` given) or a point cloud (``faces`` is None).

    ``vertices`` is a float64 ``(n, 3)`` array, ``faces`` an int64 ``(m, 3)`` array of 0-based
    vertex indices. Both are validated and made read-only on construction: a Shape never holds
    NaN/inf coordinates or out-of-range face indices, so native code (libigl) is safe to call, nor
    coordinates whose squared lengths and areas overflow or underflow float64 (:func:`check_extent`:
    1e200 or 1e-300 coordinates are refused with the advice to rescale), nor two or more vertices all at one
    point (no geometry to analyse).
    ``colors`` (optional) are per-vertex RGB, stored as a read-only float64 ``(n, 3)`` array in
    [0, 1] (see :func:`check_colors`: uint8 input is divided by 255, out-of-range values refused).
    Colours are appearance, not geometry: :attr:`content_hash` ignores them, so spectra and other
    geometry caches are shared between a shape and its recoloured copies.
    ``normals`` (optional, point clouds only) are per-point outward normals, as a scanner or a mesh export writes
    them: a read-only float64 ``(n, 3)`` array of unit vectors (see :func:`check_normals`). A cloud's Laplacian and
    orientation tests use them instead of estimating normals from the points
    (:func:`~shape_toolkit.core.surface.cloud_normals`), so they are geometry: :attr:`content_hash` includes them.
    A mesh takes its normals from its faces and refuses given ones.
    """

    vertices: np.ndarray
    faces: np.ndarray | None = None
    name: str = field(default="")
    colors: np.ndarray | None = None
    normals: np.ndarray | None = None

    def __post_init__(self) -> None:
        v = np.asarray(self.vertices)
        where = f" ({self.name})" if self.name else ""
        if v.ndim != 2 or v.shape[1] != 3:
            raise InvalidShapeError(f"vertices must be an (n, 3) array, got shape {v.shape}{where}")
        if v.shape[0] == 0:
            raise InvalidShapeError(f"the shape has no vertices{where}")
        if not np.issubdtype(v.dtype, np.number):
            raise InvalidShapeError(f"vertices must be numeric, got {v.dtype}{where}")
        v = v.astype(np.float64, copy=True)
        if not np.isfinite(v).all():
            bad = int((~np.isfinite(v)).any(axis=1).sum())
            raise InvalidShapeError(f"{bad} vertices have NaN or infinite coordinates{where}")
        n_faces = 0 if self.faces is None else int(np.shape(self.faces)[0]) if np.ndim(self.faces) else 0
        if check_extent(v, max(v.shape[0], n_faces), where) == 0.0 and v.shape[0] > 1:
            raise InvalidShapeError(f"all {v.shape[0]} vertices are at one point{where}: the shape has no extent")
        object.__setattr__(self, "vertices", _readonly(v))
        if self.faces is not None:
            f = np.asarray(self.faces)
            if f.ndim != 2 or f.shape[1] != 3:
                raise InvalidShapeError(
                    f"faces must be an (m, 3) array of triangles, got shape {f.shape}{where}"
                )
            if f.size and not np.issubdtype(f.dtype, np.integer):
                if not np.all(np.equal(np.mod(f, 1), 0)):
                    raise InvalidShapeError(f"face indices must be integers{where}")
            f = f.astype(np.int64, copy=True)
            if f.shape[0] == 0:
                raise InvalidShapeError(
                    f"the mesh has no faces{where}; pass faces=None for a point cloud"
                )
            lo, hi = int(f.min()), int(f.max())
            if lo < 0 or hi >= v.shape[0]:
                raise InvalidShapeError(
                    f"face indices must lie in [0, {v.shape[0] - 1}], found range [{lo}, {hi}]{where}"
                )
            object.__setattr__(self, "faces", _readonly(f))
        if self.colors is not None:
            object.__setattr__(self, "colors", _readonly(check_colors(self.colors, v.shape[0], where)))
        if self.normals is not None:
            if self.faces is not None:
                raise InvalidShapeError(f"normals are given for point clouds only; a mesh's come from its faces{where}")
            object.__setattr__(self, "normals", _readonly(check_normals(self.normals, v.shape[0], where)))

    # -- basic facts -------------------------------------------------------------------------
    @property
    def n_vertices(self) -> int:
        """Number of vertices ``n``."""
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        """Number of triangles ``m`` (0 for a point cloud)."""
        return 0 if self.faces is None else int(self.faces.shape[0])

    @property
    def is_mesh(self) -> bool:
        """True for a triangle mesh, False for a point cloud."""
        return self.faces is not None

    @property
    def has_colors(self) -> bool:
        """True when the shape carries per-vertex colours."""
        return self.colors is not None

    def __repr__(self) -> str:
        kind = f"{self.n_faces} faces" if self.is_mesh else "point cloud"
        nm = f"{self.name!r}, " if self.name else ""
        col = ", coloured" if self.colors is not None else ""
        col += ", with normals" if self.normals is not None else ""
        return f"Shape({nm}{self.n_vertices} vertices, {kind}{col})"

    def require_faces(self, what: str) -> np.ndarray:
        """Return the faces or raise :class:`MeshRequiredError` (an :class:`InvalidShapeError`) naming ``what`` needs
        them."""
        if self.faces is None:
            raise MeshRequiredError(f"{what} needs a triangle mesh, but {self!r} has no faces")
        return self.faces

    # -- cached derived properties ----------------------------------------------------------
    @cached_property
    def edges(self) -> np.ndarray:
        """Unique undirected mesh edges as an int64 ``(e, 2)`` array with ``i < j``, sorted."""
        f = self.require_faces("edges")
        e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        e = np.sort(e, axis=1)
        e = e[e[:, 0] != e[:, 1]]
        return _readonly(np.unique(e, axis=0))

    @cached_property
    def scale(self) -> float:
        """:func:`coordinate_scale` of the vertices: a power of two near the largest coordinate."""
        return coordinate_scale(self.vertices)

    def _scaled_cross(self) -> np.ndarray:
        """Face cross products computed on ``vertices / scale`` (exact rescaling, no overflow)."""
        f = self.require_faces("face geometry")
        v = self.vertices / self.scale
        return np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])

    @cached_property
    def face_areas(self) -> np.ndarray:
        """Area of each triangle, float64 ``(m,)``, in squared length units.

        Computed on rescaled coordinates, so it neither overflows nor underflows unless the area
        itself is outside the float64 range."""
        self.require_faces("face areas")
        s = self.scale
        with np.errstate(over="ignore"):
            return _readonly(0.5 * np.linalg.norm(self._scaled_cross(), axis=1) * s * s)

    @cached_property
    def face_normals(self) -> np.ndarray:
        """Unit normal of each triangle, float64 ``(m, 3)`` (zero for degenerate faces)."""
        self.require_faces("face normals")
        cr = self._scaled_cross()
        nrm = np.linalg.norm(cr, axis=1, keepdims=True)
        return _readonly(np.divide(cr, nrm, out=np.zeros_like(cr), where=nrm > 0))

    @cached_property
    def vertex_areas(self) -> np.ndarray:
        """Barycentric vertex area (one third of the incident triangles), float64 ``(n,)``."""
        f = self.require_faces("vertex areas")
        a = np.zeros(self.n_vertices)
        np.add.at(a, f.ravel(), np.repeat(self.face_areas / 3.0, 3))
        return _readonly(a)

    @cached_property
    def area(self) -> float:
        """Total surface area (squared length units; inf when beyond the float64 range)."""
        with np.errstate(over="ignore"):
            return float(self.face_areas.sum())

    def check_computable(self) -> None:
        """Refuse (:class:`InvalidShapeError`, naming the fix) a shape whose coordinates are too large or too small
        for the products of two areas that spectra, segmentations and matches form: :func:`check_extent` with
        ``power=4`` (the diagonal within about [1e-75, 1e76]). A shape outside can still be read, inspected and
        cleaned; every plugin's work method (``weigh``, ``detect``, ``compute``, ``match``, ``segment``) checks
        the shapes it is given first."""
        if "_computable" not in self.__dict__:
            where = f" ({self.name})" if self.name else ""
            check_extent(self.vertices, max(self.n_vertices, self.n_faces), where, power=4)
            object.__setattr__(self, "_computable", True)

    @cached_property
    def bounding_box(self) -> np.ndarray:
        """Axis-aligned bounding box as a ``(2, 3)`` array ``[min, max]``."""
        return _readonly(np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)]))

    @cached_property
    def diagonal(self) -> float:
        """Length of the bounding-box diagonal."""
        b = self.bounding_box / self.scale
        with np.errstate(over="ignore"):
            return float(np.linalg.norm(b[1] - b[0]) * self.scale)

    @cached_property
    def edge_lengths(self) -> np.ndarray:
        """Length of each unique mesh edge, float64 ``(e,)``, aligned with :attr:`edges`."""
        e = self.edges
        v = self.vertices / self.scale
        with np.errstate(over="ignore"):
            return _readonly(np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1) * self.scale)

    @cached_property
    def mean_edge_length(self) -> float:
        """Mean length of the unique mesh edges."""
        return float(self.edge_lengths.mean()) if len(self.edges) else 0.0

    @cached_property
    def content_hash(self) -> str:
        """SHA-1 of the vertex and face bytes (and of a cloud's given normals): equal geometries share cached
        spectra.

        Colours are deliberately left out: nothing keyed by this hash (spectra, geodesics,
        adjacency, SDF) depends on them, so recolouring a shape keeps its caches. A cloud's normals are in: its
        Laplacian is built on them."""
        h = hashlib.sha1()
        h.update(self.vertices.tobytes())
        if self.faces is not None:
            h.update(b"F")
            h.update(self.faces.tobytes())
        if self.normals is not None:
            h.update(b"N")
            h.update(self.normals.tobytes())
        return h.hexdigest()

    # -- derived shapes ---------------------------------------------------------------------
    def normalized(self) -> tuple[Shape, np.ndarray, float]:
        """The shape centred on its bounding-box centre and divided by its bounding-box diagonal
        (so every length is well inside the float64 range), with the ``centre`` and ``diagonal``:
        ``original = normalized * diagonal + centre``. Scale-invariant measures (geodesic errors
        over sqrt(area), angles, relative tolerances) are computed safely on it."""
        s = self.scale
        b = self.bounding_box / s
        centre = 0.5 * (b[0] + b[1])
        v = self.vertices / s - centre
        d = float(np.linalg.norm(b[1] - b[0]))
        if d == 0.0:
            d = 1.0
        return Shape(v / d, self.faces, self.name, self.colors, self.normals), centre * s, d * s

    def with_vertices(self, vertices: np.ndarray) -> Shape:
        """Same connectivity and colours, new ``(n, 3)`` coordinates (a cloud's given normals are dropped: they
        belonged to the former positions)."""
        return Shape(vertices, self.faces, self.name, self.colors)

    def with_colors(self, colors: np.ndarray | None) -> Shape:
        """Same geometry, new per-vertex ``(n, 3)`` colours (None drops them); see :func:`check_colors`."""
        return Shape(self.vertices, self.faces, self.name, colors, self.normals)

    def with_normals(self, normals: np.ndarray | None) -> Shape:
        """The same point cloud with outward normals ``(n, 3)`` (None drops them); see :func:`check_normals`."""
        return Shape(self.vertices, self.faces, self.name, self.colors, normals)

    def submesh(self, vertex_ids: np.ndarray) -> tuple[Shape, np.ndarray]:
        """Keep the given vertices (and the faces entirely inside them).

        Returns the new shape and the int64 array of kept original vertex ids (new id -> old id).
        """
        keep = np.unique(np.asarray(vertex_ids, dtype=np.int64))
        if keep.size == 0:
            raise InvalidShapeError("submesh: no vertex kept")
        remap = -np.ones(self.n_vertices, dtype=np.int64)
        remap[keep] = np.arange(keep.size)
        faces = None
        if self.faces is not None:
            ff = remap[self.faces]
            ff = ff[(ff >= 0).all(axis=1)]
            faces = ff if len(ff) else None
        colors = None if self.colors is None else self.colors[keep]
        normals = None if self.normals is None else self.normals[keep]
        return Shape(self.vertices[keep], faces, self.name, colors, normals), keep
