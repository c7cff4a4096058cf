"""Geodesic distances on shapes behind one function, k-rings and relative geodesic neighbourhoods.

Methods of :func:`geodesic_distances`:

* ``"exact"``: libigl's exact polyhedral geodesics (MMP, ``igl.exact_geodesic``); the target
  vertices are always passed explicitly (libigl returns an empty array without them).
* ``"fmm"``: fast marching (potpourri3d's ``MeshFastMarchingDistanceSolver``, geometry-central);
  first-order accurate, the method of thesis section 7.5.2.
* ``"heat"``: the heat method (Crane et al. 2013) through potpourri3d's
  ``MeshHeatMethodDistanceSolver`` (intrinsic-Delaunay "robust" Laplacian, factored once per shape).
* ``"dijkstra"``: shortest paths along mesh edges (scipy); an upper bound of the exact distance.
  Point clouds use a symmetrised 8-nearest-neighbour graph instead, its pieces joined where the cloud's
  surface joins them (:func:`~shape_toolkit.core.graph.cloud_knn_edges`).

Point clouds take ``"heat"`` and ``"dijkstra"``. The heat method runs there on the surface the point-cloud
Laplacian is built on (:func:`~shape_toolkit.core.surface.sheet_triangulation`: every point's local Delaunay
triangulation of its 30 nearest neighbours on its own sheet, so parts touching in space are not linked) with the
points projected onto their local quadric fits (``"jet"``: the distance is measured along the surface, not along
the noise across it). Against libigl's exact geodesics on the meshes the clouds came from (TOSCA cat0, dog0, FAUST
tr_reg_000 and tr_reg_007, vertex clouds, 3 sources; 2026-12-07): mean relative error 2.1-6.5 % (Dijkstra on the
cloud 5.0-6.8 %), with 0.5 % noise 4.3-9.3 % (Dijkstra 8.8-12.6 %; the points as given, without the projection,
10.4-14.0 %).

Distances are in the shape's length units. Rows (one per source vertex) are cached by shape
content and method (:data:`GEODESIC_ROWS_CACHE`), so a benchmark that asks twice computes once.

The native solvers cannot take every mesh a :class:`Shape` may hold, and fail badly where they cannot (measured with
libigl and potpourri3d on small meshes, every source vertex tried): libigl's exact geodesics crash (SIGSEGV) on a
face with a repeated vertex or an edge on more than two faces, and can loop forever on a face of zero or near-zero
area (a sliver) or one too small for the coordinates to resolve; fast marching raises an untyped error on a repeated
vertex, a non-manifold edge or a non-manifold vertex (pieces touching at a vertex). The heat method ("robust"
Laplacian) copes with all of these, as Dijkstra does. So the solver of a shape is prepared only after
:func:`solver_defects` found none of the defects its method fails on (:data:`METHOD_DEFECTS`); otherwise
:class:`~shape_toolkit.errors.InvalidShapeError` names them, the repair (``shape-toolkit clean``) and the methods that
work. The check runs once per shape and method, with the prepared solver it guards (:data:`GEODESIC_SOLVERS_CACHE`).

Long solves (exact geodesics take about a second per source on a 5,000-vertex mesh) take a
:class:`GeodesicBudget`: a time limit, checked after every source, that raises
:class:`~shape_toolkit.errors.TimeLimitError` when it is passed or when the projected total is
clearly over it, and a ``progress(done, total)`` callback (the library itself never prints).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.sparse.csgraph import dijkstra as _csgraph_dijkstra

from shape_toolkit.core.cache import LRUCache
from shape_toolkit.core.graph import edge_length_graph
from shape_toolkit.core.inspect import (
    degenerate_face_mask,
    degenerate_index_faces,
    edge_face_counts,
    non_manifold_vertices,
)
from shape_toolkit.core.shape import Shape, coordinate_scale
from shape_toolkit.errors import InvalidShapeError, ParameterError, SolverError, TimeLimitError
from shape_toolkit.validation import check_vertex_ids

__all__ = [
    "GEODESIC_METHODS",
    "METHOD_DEFECTS",
    "GeodesicBudget",
    "solver_defects",
    "check_solver_input",
    "fill_from_nearest",
    "geodesic_distances",
    "paired_geodesic_distances",
    "geodesic_distance_to_set",
    "adjacency",
    "k_ring",
    "k_ring_all",
    "k_rings",
    "ring_maxima",
    "relative_geodesic_neighbourhood",
    "relative_neighbourhood_size",
    "geodesic_nearest",
    "nearest_source",
    "geodesic_farthest_points",
    "order_by_distance",
    "clear_geodesic_cache",
]

GEODESIC_METHODS = ("exact", "fmm", "heat", "dijkstra")
#: the methods that take a point cloud, and the neighbours of the local triangulations the heat method runs on there
CLOUD_METHODS, CLOUD_NEIGHBORS = ("heat", "dijkstra"), 30

#: distance rows (read-only, keyed by shape content, method and source), bounded by float64 entries (400 MB)
GEODESIC_ROWS_CACHE = LRUCache(None, max_cost=50_000_000, cost=lambda row: row.size, name="geodesic rows")
#: prepared solvers, edge graphs' components and adjacencies of the last shapes, keyed by content and kind
GEODESIC_SOLVERS_CACHE = LRUCache(8, name="geodesic solvers")
_KNN_NEIGHBORS = 8


#: peak bytes of ``shape-toolkit geodesics`` per method, a fixed part and a part per vertex (mesh, solver), from its
#: measured peaks with one source (``benchmarks/results/memory_models.md``, 2026-12-06: 80k to 500k vertices; exact
#: 20k to 80k)
GEODESIC_MEMORY = {"dijkstra": (85e6, 380.0), "fmm": (60e6, 1260.0), "heat": (0.0, 4500.0), "exact": (5e6, 6400.0)}
#: the same for the heat method on a point cloud (its normals, local triangulations of 30 neighbours, each triangle in
#: up to three of them, the jet fits and the solver): 847 MB at 79,970 points and 2,944 MB at 244,904 (TOSCA cat0
#: split 4 x 4 and 7 x 7, its vertices without faces, one source, ``/usr/bin/time``, 2026-12-07), about 2.6x a mesh's
GEODESIC_CLOUD_MEMORY = {"heat": (0.0, 12_000.0)}
#: bytes per vertex and source: the distance rows, the solved rows, their read-only copy in the rows cache and the
#: command's nearest-source distances (float64 each; the cache is capped, so an estimate from above)
GEODESIC_ROW_BYTES = 32.0
#: sources solved in one call of scipy's Dijkstra between two budget checks
_DIJKSTRA_BLOCK = 256

#: the mesh defects each method's native solver cannot take (crash, endless loop or untyped error), checked by
#: :func:`check_solver_input` before the solver is prepared: ``"repeated"`` faces with a repeated vertex index,
#: ``"non_manifold_edges"`` edges on more than two faces (a duplicated face makes them too), ``"non_manifold_vertices"``
#: vertices where pieces of surface touch (bow-ties), ``"thin_faces"`` and ``"tiny_faces"`` faces exact geodesics cannot
#: resolve (:data:`EXACT_MIN_ALTITUDE`, :data:`EXACT_MIN_EDGE`). Exact geodesics take non-manifold vertices, fast
#: marching zero-area faces, the heat method all of them.
METHOD_DEFECTS: dict[str, tuple[str, ...]] = {
    "exact": ("repeated", "non_manifold_edges", "thin_faces", "tiny_faces"),
    "fmm": ("repeated", "non_manifold_edges", "non_manifold_vertices"),
    "heat": (),
    "dijkstra": (),
}
#: libigl's exact geodesics (Kirsanov's MMP code) drop every window shorter than this fraction of its edge
#: (``SMALLEST_INTERVAL_RATIO``): the relative resolution of the solver
EXACT_RESOLUTION = 1e-6
#: a face is too thin for exact geodesics when its smallest altitude (2 area / longest edge) is below this fraction
#: of its longest edge (zero area included): ten times the solver's resolution, as slivers made it loop forever
#: from some sources up to 2.3e-6 (never seen at 4e-6 or more)
EXACT_MIN_ALTITUDE = 10 * EXACT_RESOLUTION
#: ... or too small when its longest edge is below this fraction of the coordinate scale (a power of two near the
#: largest coordinate, :attr:`Shape.scale`): float64 then holds its edge vectors to less than the solver's resolution
#: (machine epsilon / EXACT_RESOLUTION, about 2.2e-10; well-shaped faces 1.5e-11 of it, next to large ones, made the
#: solver loop forever)
EXACT_MIN_EDGE = float(np.finfo(np.float64).eps) / EXACT_RESOLUTION
#: (singular, plural) words of each defect of :data:`METHOD_DEFECTS`
_DEFECT_WORDS = {
    "repeated": ("face with a repeated vertex", "faces with a repeated vertex"),
    "non_manifold_edges": ("non-manifold edge", "non-manifold edges"),
    "non_manifold_vertices": ("non-manifold vertex", "non-manifold vertices"),
    "thin_faces": (
        f"face of zero or near-zero area (altitude under {EXACT_MIN_ALTITUDE:g} of its longest edge)",
        f"faces of zero or near-zero area (altitude under {EXACT_MIN_ALTITUDE:g} of their longest edge)",
    ),
    "tiny_faces": (
        f"face too small for its coordinates (longest edge under {EXACT_MIN_EDGE:.2g} of the largest coordinate)",
        f"faces too small for their coordinates (longest edge under {EXACT_MIN_EDGE:.2g} of the largest coordinate)",
    ),
}


class GeodesicBudget:
    """Time limit and progress shared by the geodesic solves of one job (possibly several
    :func:`geodesic_distances` calls): ``time_limit`` in seconds (None: no limit), ``total`` the
    number of sources the job will solve (for the projection and the progress fraction; None when
    unknown), ``progress(done, total)`` called after each solved source or block of sources.

    :meth:`tick` raises :class:`TimeLimitError` once the elapsed time passes ``time_limit``, or
    earlier, after at least 3 sources, when the projected total (elapsed / done * total) is more
    than twice the limit: a run that would take far too long fails within seconds, not minutes.
    """

    #: sources solved before the projection may stop a run
    MIN_SOURCES_FOR_PROJECTION = 3
    #: the projection stops a run when it exceeds the limit by this factor
    PROJECTION_FACTOR = 2.0

    def __init__(
        self,
        time_limit: float | None = None,
        total: int | None = None,
        progress: Callable[[int, int | None], None] | None = None,
        what: str = "geodesics",
        remedy: str = "use a faster geodesic method (heat, fmm, dijkstra) or a larger time limit",
    ):
        if time_limit is not None:
            if isinstance(time_limit, bool) or not isinstance(time_limit, (int, float)) or not (
                math.isfinite(time_limit) and time_limit > 0
            ):
                raise ParameterError(f"time_limit must be a positive number of seconds, got {time_limit!r}")
        self.time_limit = None if time_limit is None else float(time_limit)
        self.total = None if total is None else int(total)
        self.progress = progress
        self.what = what
        self.remedy = remedy
        self.done = 0
        self.t0 = time.perf_counter()

    @property
    def elapsed(self) -> float:
        """Seconds since the budget was created."""
        return time.perf_counter() - self.t0

    def tick(self, n: int = 1) -> None:
        """Count ``n`` solved sources, report progress, and enforce the time limit."""
        self.done += int(n)
        if self.progress is not None:
            self.progress(self.done, self.total)
        self.check()

    def check(self) -> None:
        """Raise :class:`TimeLimitError` when the limit is passed or clearly will be."""
        if self.time_limit is None:
            return
        el = self.elapsed
        of = f" of {self.total}" if self.total else ""
        if el > self.time_limit:
            raise TimeLimitError(
                f"{self.what}: time limit of {self.time_limit:g} s exceeded after {self.done}{of} sources "
                f"({el:.1f} s); {self.remedy}"
            )
        if self.total and self.done >= self.MIN_SOURCES_FOR_PROJECTION and self.done < self.total:
            projected = el / self.done * self.total
            if projected > self.PROJECTION_FACTOR * self.time_limit:
                raise TimeLimitError(
                    f"{self.what}: {self.done}{of} sources took {el:.1f} s, about {projected:.0f} s for all, "
                    f"over the time limit of {self.time_limit:g} s; {self.remedy}"
                )


def clear_geodesic_cache() -> None:
    """Forget every cached distance row and prepared solver (:data:`GEODESIC_ROWS_CACHE`,
    :data:`GEODESIC_SOLVERS_CACHE`)."""
    GEODESIC_ROWS_CACHE.clear()
    GEODESIC_SOLVERS_CACHE.clear()


def _solver(shape: Shape, method: str) -> Any:
    """The prepared solver of ``method`` on ``shape`` (cached)."""
    return GEODESIC_SOLVERS_CACHE.get_or_compute((shape.content_hash, method), lambda: _make_solver(shape, method))


def _dijkstra(G: sp.csr_matrix, **kwargs: Any) -> Any:
    """SciPy's Dijkstra on the symmetric edge graph ``G`` of :func:`_edge_graph`, as a directed graph: the same
    distances as ``directed=False``, without the transpose SciPy forms on every undirected call (28 % of a
    single-source run at 5k vertices)."""
    return _csgraph_dijkstra(G, directed=True, **kwargs)


def _face_resolution(shape: Shape) -> tuple[np.ndarray, np.ndarray]:
    """``(altitude, size)`` of every face, float64 ``(m,)`` each: its smallest altitude (2 area / longest edge) over
    its longest edge (0 for zero area, a repeated vertex or a face collapsed to a point), and its longest edge over
    the coordinate scale :attr:`Shape.scale`. Both scale-free, computed on coordinates rescaled by that power of two
    (exact), so 1e-100 and 1e100 coordinates give the same answer as 1.0."""
    v = shape.vertices / shape.scale
    f = shape.faces
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)  # twice the area
    longest2 = np.maximum.reduce([((b - a) ** 2).sum(1), ((c - b) ** 2).sum(1), ((a - c) ** 2).sum(1)])
    altitude = np.divide(area2, longest2, out=np.zeros_like(area2), where=longest2 > 0)
    return altitude, np.sqrt(longest2)


def solver_defects(shape: Shape, kinds: Sequence[str] | None = None) -> dict[str, tuple[int, str]]:
    """The defects of the mesh ``shape`` that geodesic solvers fail on, among ``kinds`` (those named in
    :data:`METHOD_DEFECTS`; default all): ``{kind: (count, first example)}`` for each kind found, empty for a clean
    mesh. A face counts once: a face with a repeated vertex is not thin too, a thin face not tiny too. Vectorized
    numpy, O(m log m) in the number of faces."""
    f = shape.require_faces("geodesic solver checks")
    kinds = tuple(_DEFECT_WORDS) if kinds is None else tuple(kinds)
    found: dict[str, tuple[int, str]] = {}
    rep = degenerate_index_faces(f)
    if "repeated" in kinds and rep.any():
        i = int(np.flatnonzero(rep)[0])
        found["repeated"] = (int(rep.sum()), f"face {i}: {f[i].tolist()}")
    if "non_manifold_edges" in kinds:
        edges, counts = edge_face_counts(f)
        nm = np.flatnonzero(counts > 2)
        if nm.size:
            found["non_manifold_edges"] = (
                int(nm.size), f"edge {edges[nm[0]].tolist()} on {int(counts[nm[0]])} faces"
            )
    if "non_manifold_vertices" in kinds:
        nmv = non_manifold_vertices(f)
        if len(nmv):
            found["non_manifold_vertices"] = (len(nmv), f"vertex {int(nmv[0])}, where pieces of surface touch")
    if "thin_faces" in kinds or "tiny_faces" in kinds:
        altitude, size = _face_resolution(shape)
        thin = (altitude <= EXACT_MIN_ALTITUDE) & ~rep
        tiny = (size <= EXACT_MIN_EDGE) & ~thin & ~rep
        for kind, mask, what, value in (("thin_faces", thin, "altitude", altitude), ("tiny_faces", tiny, "edge", size)):
            if kind in kinds and mask.any():
                i = int(np.flatnonzero(mask)[0])
                found[kind] = (int(mask.sum()), f"face {i}, {what} {value[i]:.2g}")
    return found


def check_solver_input(shape: Shape, method: str) -> None:
    """Raise :class:`~shape_toolkit.errors.InvalidShapeError` when the mesh ``shape`` has a defect that the solver
    of ``method`` crashes on, loops forever on or refuses (:data:`METHOD_DEFECTS`, :func:`solver_defects`); the one-line
    message counts them, names the repair and the methods that take the mesh as it is. Nothing for a clean mesh, the
    heat method and Dijkstra."""
    kinds = METHOD_DEFECTS[method]
    if not kinds or not shape.is_mesh:
        return
    found = solver_defects(shape, kinds)
    if not found:
        return
    listed = "; ".join(f"{n} {_DEFECT_WORDS[k][n != 1]} (first: {ex})" for k, (n, ex) in found.items())
    works = [m for m in GEODESIC_METHODS if m != method and not set(found) & set(METHOD_DEFECTS[m])]
    others = ", ".join(works[:-1]) + (" or " if len(works) > 1 else "") + works[-1]
    if method == "fmm":
        effect = "fast marching (geometry-central) refuses them"
    else:
        does = [w for w, on in (("crash", {"repeated", "non_manifold_edges"}), ("can loop forever", {"thin_faces",
                "tiny_faces"})) if on & set(found)]
        effect = f"libigl's exact geodesics {' or '.join(does)} on them"
    fix = "repair it with `shape-toolkit clean` (shape_toolkit.core.cleanup.clean_shape)"
    if "thin_faces" in found or "tiny_faces" in found:
        # clean drops zero-area faces only (degenerate_face_mask); slivers and tiny faces need a remesh
        altitude, size = _face_resolution(shape)
        bad = ((altitude <= EXACT_MIN_ALTITUDE) | (size <= EXACT_MIN_EDGE)) & ~degenerate_index_faces(shape.faces)
        n_bad = int(bad.sum())
        removed = int(degenerate_face_mask(shape.vertices, shape.faces[bad]).sum())
        if removed < n_bad:
            fix = (f"remesh it with `shape-toolkit clean --remesh EDGE_LEN` (plain clean drops only the {removed} of "
                   "zero area)" + (" or move it to the origin" if "tiny_faces" in found else ""))
    raise InvalidShapeError(
        f"{method} geodesics need a clean manifold mesh, but {shape!r} has {listed}: {effect}; {fix}, "
        f"or use the {others} method"
    )


def _make_solver(shape: Shape, method: str) -> Any:
    if method in ("heat", "fmm"):  # their operators multiply areas (the heat method's Laplacian and mass)
        shape.check_computable()
    check_solver_input(shape, method)  # before any native call: once per shape, cached with the solver
    V = np.ascontiguousarray(shape.vertices, dtype=np.float64)
    if method == "dijkstra":
        solver = _edge_graph(shape)
    else:
        if shape.is_mesh:
            F = np.ascontiguousarray(shape.faces, dtype=np.int64)
        else:  # a cloud (heat only): the point-cloud Laplacian's own surface, denoised (module docstring)
            from shape_toolkit.core.surface import sheet_triangulation

            V, F = sheet_triangulation(shape, CLOUD_NEIGHBORS, "jet")
            V, F = np.ascontiguousarray(V), np.ascontiguousarray(F, dtype=np.int64)
        import potpourri3d as pp3d

        try:
            if method == "fmm":
                solver = pp3d.MeshFastMarchingDistanceSolver(V, F)
            elif method == "heat":
                solver = pp3d.MeshHeatMethodDistanceSolver(V, F, use_robust=True)
            else:  # libigl's MMP compares lengths with absolute tolerances (it looped at 1e-30 coordinates): it gets
                # them divided by a power of two near the largest (exact), and its distances are multiplied back
                scale = coordinate_scale(V)
                solver = (V / scale, F, scale)
        except (RuntimeError, ValueError) as exc:
            raise SolverError(f"{method} geodesic solver failed on {shape!r}: {exc}") from None
    return solver


def _solve_failed(shape: Shape, method: str, exc: Exception) -> SolverError:
    """The one-line :class:`SolverError` for a native solve of ``method`` that raised ``exc``."""
    return SolverError(
        f"{method} geodesics failed on {shape!r}: {' '.join(str(exc).split())}; try `shape-toolkit clean` on the mesh "
        "or use the dijkstra method"
    )


def _edge_graph(shape: Shape) -> sp.csr_matrix:
    """The edge-length graph Dijkstra runs on (mesh edges; a cloud's kNN graph), built once per shape (cached: a
    cloud's may take its local triangulations) and shared by the Dijkstra solver, the components and the adjacency."""
    return GEODESIC_SOLVERS_CACHE.get_or_compute(
        (shape.content_hash, "edge graph"), lambda: edge_length_graph(shape, _KNN_NEIGHBORS)
    )


def _components(shape: Shape) -> np.ndarray:
    """Connected-component label ``(n,)`` of every vertex (mesh edges / kNN graph), cached."""
    return GEODESIC_SOLVERS_CACHE.get_or_compute(
        (shape.content_hash, "components"), lambda: connected_components(_edge_graph(shape), directed=False)[1]
    )


def _compute_rows(
    shape: Shape, sources: np.ndarray, method: str, budget: GeodesicBudget | None = None
) -> np.ndarray:
    n = shape.n_vertices
    solver = _solver(shape, method)
    out = np.empty((sources.size, n))
    if method == "dijkstra":
        block = sources.size if budget is None else _DIJKSTRA_BLOCK
        for b in range(0, sources.size, block):
            idx = sources[b : b + block]
            out[b : b + idx.size] = _dijkstra(solver, indices=idx)
            if budget is not None:
                budget.tick(idx.size)
        return out
    labels = _components(shape)
    for r, s in enumerate(sources):
        try:
            if method == "exact":
                V, F, scale = solver
                d = scale * np.asarray(
                    __import__("igl").exact_geodesic(
                        V, F, VS=np.array([s], dtype=np.int64), VT=np.arange(n, dtype=np.int64)
                    ),
                    dtype=np.float64,
                ).ravel()
            elif method == "fmm":
                d = np.asarray(solver.compute_distance([[(int(s), [])]]), dtype=np.float64).ravel()
            else:
                d = np.asarray(solver.compute_distance(int(s)), dtype=np.float64).ravel()
        except RuntimeError as exc:  # a failure check_solver_input did not foresee: typed, one line
            raise _solve_failed(shape, method, exc) from None
        if d.shape != (n,):
            raise SolverError(f"{method} geodesics returned {d.shape[0]} values for {n} vertices")
        d[labels != labels[s]] = np.inf  # libigl says 0 and the heat method guesses there
        out[r] = d
        if budget is not None:
            budget.tick()
    return out


#: distance rows solved at once by :func:`paired_geodesic_distances` and :func:`geodesic_nearest`
PAIRED_CHUNK, NEAREST_CHUNK = 128, 64


def geodesic_memory(n: int, n_sources: int, method: str, *, cloud: bool = False) -> float:
    """Estimated peak bytes of ``shape-toolkit geodesics`` on a shape of ``n`` vertices from ``n_sources`` sources by
    ``method`` (:data:`GEODESIC_MEMORY`, :data:`GEODESIC_ROW_BYTES`; ``cloud``: a point cloud's,
    :data:`GEODESIC_CLOUD_MEMORY` where it differs). An estimate for refusing a shape before its work
    (``--memory-limit``), not a bound."""
    a, b = (GEODESIC_CLOUD_MEMORY if cloud and method in GEODESIC_CLOUD_MEMORY else GEODESIC_MEMORY)[method]
    return a + n * (b + GEODESIC_ROW_BYTES * max(int(n_sources), 1))


def _check_method(shape: Shape, method: str) -> None:
    if method not in GEODESIC_METHODS:
        raise ParameterError(
            f"unknown geodesic method {method!r}; choose one of {', '.join(GEODESIC_METHODS)}"
        )
    if method not in CLOUD_METHODS and not shape.is_mesh:
        raise InvalidShapeError(
            f"{method!r} geodesics need a triangle mesh but {shape!r} is a point cloud; use the 'heat' method (on "
            "the cloud's local triangulations) or 'dijkstra' (its kNN graph), or reconstruct a mesh"
        )


def geodesic_distances(
    shape: Shape,
    sources: int | Sequence[int] | np.ndarray,
    targets: Sequence[int] | np.ndarray | None = None,
    *,
    method: str = "exact",
    cache: bool = True,
    time_limit: float | None = None,
    progress: Callable[[int, int | None], None] | None = None,
    budget: GeodesicBudget | None = None,
) -> np.ndarray:
    """Geodesic distances from each source vertex, float64 ``(len(sources), n)`` or
    ``(len(sources), len(targets))``, in length units; ``method`` in :data:`GEODESIC_METHODS`.
    Unreachable vertices (other components) get ``inf``. ``time_limit`` (seconds) and
    ``progress(done, total)`` make a :class:`GeodesicBudget` for this call (``budget`` shares one
    across calls); past the limit :class:`~shape_toolkit.errors.TimeLimitError` is raised."""
    _check_method(shape, method)
    n = shape.n_vertices
    src = check_vertex_ids(sources, n, "sources")
    tgt = None if targets is None else check_vertex_ids(targets, n, "targets")
    rows = np.empty((src.size, n))
    key0 = shape.content_hash
    todo = []
    for r, s in enumerate(src):
        hit = GEODESIC_ROWS_CACHE.get((key0, method, int(s))) if cache else None
        if hit is not None:
            rows[r] = hit
        else:
            todo.append(r)
    if budget is None and (time_limit is not None or progress is not None):
        budget = GeodesicBudget(
            time_limit, int(np.unique(src[todo]).size) if todo else 0, progress, f"{method} geodesics"
        )
    if todo:
        uniq, inv = np.unique(src[todo], return_inverse=True)
        new = _compute_rows(shape, uniq, method, budget)
        rows[todo] = new[inv]
        if cache:  # a row larger than the budget on its own is not kept
            for s, row in zip(uniq, new):
                row = row.copy()
                row.setflags(write=False)
                GEODESIC_ROWS_CACHE.put((key0, method, int(s)), row)
    if method == "fmm" or method == "heat":
        rows[np.arange(src.size), src] = 0.0
    return rows if tgt is None else rows[:, tgt]


def paired_geodesic_distances(
    shape: Shape,
    a: np.ndarray,
    b: np.ndarray,
    *,
    method: str = "exact",
    chunk: int = PAIRED_CHUNK,
    time_limit: float | None = None,
    progress: Callable[[int, int | None], None] | None = None,
) -> np.ndarray:
    """Geodesic distances ``d(a_i, b_i)`` on ``shape`` for vertex ids ``a`` ``(p,)`` and ``b``
    ``(p,)`` or ``(p, r)`` (``r`` partners per ``a_i``, e.g. the images of several maps), same
    shape as ``b``, in length units. One distance row per distinct ``a``, computed in chunks
    (memory ``chunk * n``). ``progress(done, total)`` counts the rows; past ``time_limit``
    seconds (or when the projection is far over it) :class:`~shape_toolkit.errors.TimeLimitError`
    is raised."""
    a = np.asarray(a, dtype=np.int64).ravel()
    b = np.asarray(b, dtype=np.int64)
    b2 = b.reshape(b.shape[0], -1) if b.ndim else b.reshape(1, 1)
    if b2.shape[0] != a.size:
        raise ParameterError(f"paired ids must have equal lengths, got {a.size} and {b2.shape[0]}")
    n = shape.n_vertices
    for name, ids in (("a", a), ("b", b2)):
        if ids.size and (ids.min() < 0 or ids.max() >= n):
            raise ParameterError(f"vertex ids {name} must lie in [0, {n - 1}]")
    out = np.empty(b2.shape)
    uniq, inv = np.unique(a, return_inverse=True)
    order = np.argsort(inv, kind="stable")
    bounds = np.searchsorted(inv[order], np.arange(uniq.size + 1))
    budget = None
    if time_limit is not None or progress is not None:
        budget = GeodesicBudget(time_limit, uniq.size, progress, f"{method} geodesics")
    for s in range(0, uniq.size, chunk):
        rows = np.asarray(
            geodesic_distances(shape, uniq[s : s + chunk], method=method, cache=False, budget=budget)
        )
        for r in range(rows.shape[0]):
            sel = order[bounds[s + r] : bounds[s + r + 1]]
            out[sel] = rows[r][b2[sel]]
    return out.reshape(b.shape)


def geodesic_distance_to_set(
    shape: Shape, sources: Sequence[int] | np.ndarray, *, method: str = "fmm"
) -> np.ndarray:
    """Distance from every vertex to the nearest of ``sources`` (one multi-source solve),
    float64 ``(n,)`` in length units."""
    _check_method(shape, method)
    n = shape.n_vertices
    src = np.unique(check_vertex_ids(sources, n, "sources"))
    if src.size == 0:
        raise ParameterError("geodesic_distance_to_set needs at least one source vertex")
    solver = _solver(shape, method)
    if method == "dijkstra":
        d = np.asarray(_dijkstra(solver, indices=src, min_only=True))
        d[src] = 0.0
        return d
    labels = _components(shape)
    d = np.full(n, np.inf)
    for comp in np.unique(labels[src]):  # one solve per component that holds sources
        group = src[labels[src] == comp]
        try:
            if method == "fmm":
                part = solver.compute_distance([[(int(s), [])] for s in group])
            elif method == "heat":
                part = solver.compute_distance_multisource([int(s) for s in group])
            else:
                import igl

                V, F, scale = solver
                part = scale * np.asarray(igl.exact_geodesic(V, F, VS=group, VT=np.arange(n, dtype=np.int64)),
                                          dtype=np.float64)
        except RuntimeError as exc:
            raise _solve_failed(shape, method, exc) from None
        part = np.asarray(part, dtype=np.float64).ravel()
        inside = labels == comp
        d[inside] = np.minimum(d[inside], part[inside])
    d[src] = 0.0
    return d


# -- neighbourhoods ----------------------------------------------------------------------------
def adjacency(shape: Shape) -> sp.csr_matrix:
    """Boolean-valued ``(n, n)`` CSR adjacency of the mesh edges (kNN graph for point clouds),
    no self loops; cached per shape."""
    return GEODESIC_SOLVERS_CACHE.get_or_compute((shape.content_hash, "adjacency"), lambda: _adjacency(shape))


def _adjacency(shape: Shape) -> sp.csr_matrix:
    G = _edge_graph(shape)
    A = sp.csr_matrix((np.ones(G.nnz), G.indices, G.indptr), shape=G.shape)
    A.setdiag(0)
    A.eliminate_zeros()
    return A


def _ring_matrix(A: sp.csr_matrix) -> sp.csr_matrix:
    return sp.csr_matrix(A + sp.identity(A.shape[0], format="csr"))


def k_ring(shape: Shape, vertex: int, k: int) -> np.ndarray:
    """Sorted int64 ids of the vertices at most ``k`` edges away from ``vertex`` (itself
    included), by breadth-first search on :func:`adjacency`."""
    n = shape.n_vertices
    v = int(check_vertex_ids([vertex], n, "vertex")[0])
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 0:
        raise ParameterError(f"k must be a non-negative integer, got {k!r}")
    A = adjacency(shape)
    seen = np.zeros(n, dtype=bool)
    seen[v] = True
    front = np.array([v])
    for _ in range(int(k)):
        if front.size == 0:
            break
        nb = np.unique(np.concatenate([A.indices[A.indptr[i] : A.indptr[i + 1]] for i in front]))
        front = nb[~seen[nb]]
        seen[front] = True
    return np.flatnonzero(seen).astype(np.int64)


def k_ring_all(shape_or_adjacency: Shape | sp.spmatrix, k: int) -> sp.csr_matrix:
    """``(n, n)`` boolean CSR whose row ``i`` marks the ``k``-ring of ``i`` (itself included);
    memory grows with the ring sizes, keep ``k`` small. The rings stop growing once none adds a vertex (after at
    most the largest component's diameter in edges): any larger ``k`` gives that saturated matrix, at its cost."""
    return k_rings(shape_or_adjacency, [k])[0]


def k_rings(shape_or_adjacency: Shape | sp.spmatrix, radii: Sequence[int],
            rows: np.ndarray | None = None) -> list[sp.csr_matrix]:
    """For each ``k`` of the non-decreasing ``radii``, a boolean CSR ``(len(rows), n)`` whose row ``i`` marks the
    ``k``-ring of vertex ``rows[i]`` (itself included; ``rows`` None: every vertex, ``(n, n)``). The rings grow one
    edge at a time and stop once none adds a vertex (exact: rings only grow), so a ``k`` beyond the largest
    component's diameter costs no more than that diameter."""
    A = adjacency(shape_or_adjacency) if isinstance(shape_or_adjacency, Shape) else sp.csr_matrix(
        shape_or_adjacency
    )
    ks = list(radii)
    if any(isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 0 for k in ks) or ks != sorted(ks):
        raise ParameterError(f"radii must be non-negative integers in increasing order, got {radii!r}")
    n = A.shape[0]
    R = _ring_matrix(A)
    if rows is None:
        B = sp.identity(n, format="csr")
    else:
        ids = check_vertex_ids(rows, n, "rows")
        B = sp.csr_matrix((np.ones(len(ids)), (np.arange(len(ids)), ids)), shape=(len(ids), n))
    out, hops, full = [], 0, False
    for k in ks:
        for _ in range(int(k) - hops):
            if full:
                break
            grown = B @ R
            grown.data[:] = 1.0
            full = grown.nnz == B.nnz  # rings only grow: as many entries is the same pattern, and so it stays
            if not full:
                B = grown
        hops = max(hops, int(k))
        out.append(sp.csr_matrix(B, dtype=bool))
    return out


def ring_maxima(
    values: np.ndarray, shape_or_adjacency: Shape | sp.spmatrix, ring: int
) -> np.ndarray:
    """Vertices whose value is the strict maximum of their ``ring``-ring (ties broken by the
    smaller vertex id), ordered by decreasing value: int64 ``(p,)``. Uses ``ring`` max-dilations
    over the adjacency, so memory stays linear in ``n``; they stop once one changes nothing (a ring wider than
    every component), so a huge ``ring`` costs no more than that."""
    v = np.asarray(values, dtype=np.float64).ravel()
    A = adjacency(shape_or_adjacency) if isinstance(shape_or_adjacency, Shape) else sp.csr_matrix(
        shape_or_adjacency
    )
    if A.shape[0] != v.size:
        raise ParameterError(f"{v.size} values for a graph of {A.shape[0]} vertices")
    if isinstance(ring, bool) or not isinstance(ring, (int, np.integer)) or ring < 1:
        raise ParameterError(f"ring must be a positive integer, got {ring!r}")
    if not np.all(np.isfinite(v)):
        raise ParameterError("ring_maxima needs finite values")
    order = np.lexsort((-np.arange(v.size), v))  # ascending value, smaller id wins ties
    rank = np.empty(v.size, dtype=np.int64)
    rank[order] = np.arange(v.size)
    R = _ring_matrix(A)
    m = rank.copy()
    for _ in range(int(ring)):
        grown = np.maximum.reduceat(m[R.indices], R.indptr[:-1])
        if np.array_equal(grown, m):  # every vertex already sees the maximum of its component
            break
        m = grown
    peaks = np.flatnonzero(m == rank)
    return peaks[np.argsort(-rank[peaks], kind="stable")].astype(np.int64)


def relative_neighbourhood_size(r_percent: float, n: int) -> int:
    """Size ``ceil(r_percent / 100 * n)`` (at least 1) of the relative r-neighbourhood of thesis
    section 7.5.2 on a shape of ``n`` vertices; ``r_percent`` in (0, 100]."""
    r = float(r_percent)
    if not np.isfinite(r) or not 0 < r <= 100:
        raise ParameterError(f"r_percent must be in (0, 100], got {r_percent!r}")
    return max(1, int(np.ceil(r / 100.0 * n - 1e-9)))


def order_by_distance(distances: np.ndarray, vertex: int) -> np.ndarray:
    """Vertex ids ``(n,)`` int64 sorted by the distance row ``distances`` ``(n,)`` from
    ``vertex``: itself first (even with a zero-length edge), ties broken by the smaller id."""
    d = np.array(distances, dtype=np.float64, copy=True).ravel()
    d[int(vertex)] = -1.0
    return np.lexsort((np.arange(d.size), d)).astype(np.int64)


def geodesic_nearest(
    shape: Shape,
    sources: Sequence[int] | np.ndarray,
    count: int,
    *,
    method: str = "dijkstra",
    budget: GeodesicBudget | None = None,
    chunk: int = NEAREST_CHUNK,
) -> np.ndarray:
    """The ``count`` vertices geodesically closest to each source, int64 ``(len(sources), count)``,
    sorted as :func:`order_by_distance` (the source first, ties by id); ``-1`` pads a row whose
    component has fewer vertices. With ``"dijkstra"`` the search stops at a radius estimated from
    the area that ``count`` vertices cover (a row that did not reach ``count`` vertices strictly
    inside it is searched again without limit), so the answer is exact and the cost local."""
    n = shape.n_vertices
    src = check_vertex_ids(sources, n, "sources")
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or not 1 <= count <= n:
        raise ParameterError(f"count must be an integer in [1, {n}], got {count!r}")
    _check_method(shape, method)
    count = int(count)
    out = np.full((src.size, count), -1, dtype=np.int64)

    def fill(rows: np.ndarray, block: np.ndarray, at: int) -> None:
        for k in range(block.size):  # order_by_distance, on the reached vertices only
            cand = np.flatnonzero(np.isfinite(rows[k]))
            d = rows[k][cand]
            d[cand == block[k]] = -1.0
            order = cand[np.lexsort((cand, d))][:count]
            out[at + k, : order.size] = order

    if method != "dijkstra" or count >= n:
        for b in range(0, src.size, chunk):
            block = src[b : b + chunk]
            fill(geodesic_distances(shape, block, method=method, cache=False, budget=budget), block, b)
        return out
    G = _solver(shape, "dijkstra")
    area = shape.area if shape.is_mesh else 0.0
    step = float(np.median(G.data)) if G.nnz else 0.0
    # twice the radius of a geodesic disc holding count / n of the area, plus two typical edges
    radius = 2.0 * np.sqrt(count / n * area / np.pi) + 2.0 * step if area > 0 else np.inf
    for b in range(0, src.size, chunk):
        block = src[b : b + chunk]
        rows = np.asarray(_dijkstra(G, indices=block, limit=radius))
        for k in range(block.size):
            fin = np.flatnonzero(np.isfinite(rows[k]))
            if fin.size < count or np.partition(rows[k][fin], count - 1)[count - 1] >= radius:
                rows[k] = _dijkstra(G, indices=int(block[k]))
        fill(rows, block, b)
        if budget is not None:
            budget.tick(block.size)
    return out


def relative_geodesic_neighbourhood(
    shape: Shape, vertex: int, r_percent: float, *, method: str = "fmm"
) -> np.ndarray:
    """The ``ceil(r_percent / 100 * n)`` vertices geodesically closest to ``vertex`` (itself
    first), sorted by distance (ties by id): the relative r-neighbourhood of thesis section 7.5.2,
    int64."""
    n = shape.n_vertices
    v = int(check_vertex_ids([vertex], n, "vertex")[0])
    count = relative_neighbourhood_size(r_percent, n)
    row = geodesic_nearest(shape, [v], count, method=method)[0]
    return row[row >= 0]


def nearest_source(shape: Shape, sources: Sequence[int] | np.ndarray) -> np.ndarray:
    """For every vertex the nearest of ``sources`` along the mesh edges (kNN graph for point
    clouds): int64 ``(n,)`` vertex ids, ``-1`` where no source is reachable. These are the
    geodesic (edge-path) Voronoi cells of the sources; one multi-source Dijkstra."""
    n = shape.n_vertices
    src = np.unique(check_vertex_ids(sources, n, "sources"))
    if src.size == 0:
        raise ParameterError("nearest_source needs at least one source vertex")
    # undirected, not _dijkstra: the distances would be the same, but which source owns a vertex at equal distance
    # follows the order edges are relaxed in, and the Voronoi cells callers have seen are kept
    _, _, owner = _csgraph_dijkstra(
        _solver(shape, "dijkstra"), directed=False, indices=src, min_only=True, return_predecessors=True
    )
    owner = np.asarray(owner, dtype=np.int64)
    owner[owner < 0] = -1
    return owner


def fill_from_nearest(shape: Shape, values: np.ndarray) -> np.ndarray:
    """Per-vertex integer ``values`` ``(n,)`` with every ``-1`` replaced by the value of the nearest vertex that has
    one along the edges (:func:`nearest_source`); ``-1`` stays where no such vertex is reachable, or when none has
    one. Returns a new int64 array."""
    out = np.array(values, dtype=np.int64)
    have, miss = np.flatnonzero(out >= 0), np.flatnonzero(out < 0)
    if have.size and miss.size:
        owner = nearest_source(shape, have)[miss]
        ok = owner >= 0
        out[miss[ok]] = out[owner[ok]]
    return out


def geodesic_farthest_points(
    shape: Shape, n_points: int, start: int | None = None, *, return_distances: bool = False,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """``n_points`` vertex ids (int64) spread by farthest point sampling along the mesh edges
    (Dijkstra): the first is ``start`` (default the vertex farthest from vertex 0), each next one
    the vertex farthest from those chosen (a vertex of a component not reached yet comes first, so
    every component gets a point while points last). Deterministic. ``return_distances``: also the
    Dijkstra distances ``(n_points, n)`` from each chosen vertex (length units), computed on the way."""
    n = shape.n_vertices
    if isinstance(n_points, bool) or not isinstance(n_points, (int, np.integer)) or not 1 <= n_points <= n:
        raise ParameterError(f"n_points must be an integer in [1, {n}], got {n_points!r}")
    G = _solver(shape, "dijkstra")
    if start is None:
        d0 = _dijkstra(G, indices=0)
        start = int(np.argmax(np.where(np.isfinite(d0), d0, -1.0)))
    first = int(check_vertex_ids([start], n, "start")[0])
    chosen = [first]
    rows = [np.asarray(_dijkstra(G, indices=first), dtype=np.float64)]
    d = rows[0].copy()
    for _ in range(int(n_points) - 1):
        score = np.where(np.isfinite(d), d, np.finfo(np.float64).max)
        score[chosen] = -1.0
        nxt = int(np.argmax(score))
        chosen.append(nxt)
        row = np.asarray(_dijkstra(G, indices=nxt), dtype=np.float64)
        d = np.minimum(d, row)
        if return_distances:
            rows.append(row)
    ids = np.asarray(chosen, dtype=np.int64)
    return (ids, np.vstack(rows)) if return_distances else ids
