"""Shape graphs (thesis 3.2): connectivity from mesh edges or neighbourhoods, weights from a weighting object.

The weighting comes in as an object (any object with ``weigh(shape, edges)``, e.g. a weighting plugin); this
layer resolves no names: :func:`shape_toolkit.spectra.build_graph` turns a plugin name into the object."""

from __future__ import annotations

import copy
import hashlib
import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import InvalidShapeError, ParameterError
from shape_toolkit.validation import machine_memory, shown_value

__all__ = ["ShapeGraph", "build_graph", "knn_edges", "cloud_knn_edges", "epsilon_edges", "weights_from_edges",
           "edge_length_graph", "GRAPH_EDGE_BYTES", "graph_edge_count", "check_graph_memory"]


@dataclass(frozen=True, eq=False, repr=False)
class ShapeGraph:
    """An undirected weighted graph on the vertices of a shape.

    ``W`` is the symmetric ``(n, n)`` CSR weight matrix (zero diagonal), ``mass`` an optional
    ``(n,)`` lumped mass (vertex areas) for schemes that discretise the Laplace-Beltrami operator.
    """

    shape: Shape
    W: sp.csr_matrix
    mass: np.ndarray | None = None
    weighting: str = ""
    params: dict[str, Any] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)
    #: what to do when the Laplacian turns out numerically disconnected (the weighting's ``disconnection_hint``)
    hint: str = ""

    def __repr__(self) -> str:
        return (
            f"ShapeGraph({self.n_vertices} vertices, {self.n_edges} edges, "
            f"weighting={self.weighting!r}, mass={'yes' if self.mass is not None else 'no'})"
        )

    @property
    def n_vertices(self) -> int:
        """Number of vertices ``n``."""
        return int(self.W.shape[0])

    @property
    def n_edges(self) -> int:
        """Number of undirected edges with a non-zero weight."""
        return int((self.W.nnz - np.count_nonzero(self.W.diagonal())) // 2)

    @cached_property
    def degrees(self) -> np.ndarray:
        """Weighted degree ``d_i = sum_j w_ij``, float64 ``(n,)``."""
        return np.asarray(self.W.sum(axis=1)).ravel()

    @cached_property
    def components(self) -> tuple[int, np.ndarray]:
        """``(count, labels (n,))`` of the connected components of the graph."""
        n, labels = connected_components(self.W, directed=False)
        return int(n), labels.astype(np.int64)

    @cached_property
    def content_hash(self) -> str:
        """SHA-1 of the weights and mass: the key of cached spectra."""
        W = self.W
        h = hashlib.sha1()
        for a in (W.indptr, W.indices, W.data):
            h.update(np.ascontiguousarray(a).tobytes())
        if self.mass is not None:
            h.update(b"M")
            h.update(np.ascontiguousarray(self.mass).tobytes())
        return h.hexdigest()


def edge_length_graph(shape: Shape, n_neighbors: int = 8, *, memory_limit: float | None = None) -> sp.csr_matrix:
    """Symmetric ``(n, n)`` CSR matrix of Euclidean edge lengths (shape length units) over the mesh
    edges, or the ``n_neighbors``-nearest-neighbour graph of a point cloud (at most ``n - 1`` neighbours);
    coincident vertices keep their edge (length 1e-300, not 0). A point cloud's graph that would need more than
    ``memory_limit`` bytes (None: this machine's memory; infinite: no check) is refused before its neighbours are
    queried (:func:`check_graph_memory`, as :func:`build_graph`'s)."""
    n = shape.n_vertices
    if shape.is_mesh:
        e = np.asarray(shape.edges, dtype=np.int64)
    else:
        _check_n_neighbors(n_neighbors)
        _check_memory_limit(memory_limit)
        k = min(int(n_neighbors), n - 1)
        check_graph_memory(shape, connectivity="knn", n_neighbors=k, memory_limit=memory_limit)
        e = cloud_knn_edges(shape, k)
    w = np.maximum(np.linalg.norm(shape.vertices[e[:, 0]] - shape.vertices[e[:, 1]], axis=1), 1e-300)
    ij = (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])
    return sp.csr_matrix((np.r_[w, w], ij), shape=(n, n))


#: neighbours of a kNN graph when none are given (``build_graph``'s ``connectivity='knn'``)
KNN_NEIGHBORS = 10


def knn_edges(points: np.ndarray, n_neighbors: int) -> np.ndarray:
    """Symmetrised k-nearest-neighbour edges of ``(n, 3)`` points as ``(e, 2)`` int64, ``i < j``."""
    n = len(points)
    if not 1 <= n_neighbors < n:
        raise ParameterError(f"n_neighbors must be in [1, {n - 1}], got {n_neighbors}")
    _, idx = cKDTree(points).query(points, k=n_neighbors + 1)
    rows = np.repeat(np.arange(n), n_neighbors)
    e = np.stack([rows, idx[:, 1:].ravel()], axis=1)
    e = np.sort(e, axis=1)
    e = e[e[:, 0] != e[:, 1]]
    return np.unique(e, axis=0).astype(np.int64)


def cloud_knn_edges(shape: Shape, n_neighbors: int) -> np.ndarray:
    """The kNN edges ``(e, 2)`` int64 (``i < j``) of a point cloud's points, and where they fall apart, the edges of
    the cloud's own surface that join the pieces.

    A kNN graph of samples of one connected surface falls apart where the sampling is uneven: the vertices of an
    anisotropic remeshing (TOSCA's cat0 has rings of 20 vertices 1 unit apart on its tail, the rings 14 units
    apart: every vertex's 10 nearest lie on its own ring) are a cloud whose kNN graph has 4 pieces, although the
    points sample one surface. Raising ``k`` for every point would change the graph everywhere. Instead, only when
    the kNN graph has several pieces, the edges of the cloud's local Delaunay triangulations
    (:func:`shape_toolkit.core.surface.local_delaunay_triangles`, the point-cloud Laplacian's triangles: 30
    neighbours, each point's own sheet, with the cloud's outward normals) that run between two pieces are added:
    the surface's own links, no distance threshold. Pieces that the triangulations do not join either (two
    objects in one scan, each of more than 30 points) stay apart, and the graph is disconnected as before. A
    connected kNN graph is returned unchanged."""
    from shape_toolkit.core.geometry import edge_components

    P = np.asarray(shape.vertices, dtype=np.float64)
    e = knn_edges(P, n_neighbors)
    if shape.is_mesh:  # a mesh's vertices taken as points: its own edges say what is joined
        return e
    count, labels = edge_components(len(P), e)
    if count == 1:
        return e
    from shape_toolkit.core.surface import cloud_normals, local_delaunay_triangles

    F = local_delaunay_triangles(P, cloud_normals(shape))
    t = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    across = t[labels[t[:, 0]] != labels[t[:, 1]]]
    if not len(across):
        return e
    return np.unique(np.concatenate([e, across]), axis=0).astype(np.int64)


def epsilon_edges(points: np.ndarray, radius: float) -> np.ndarray:
    """All pairs of ``(n, 3)`` points closer than ``radius`` as ``(e, 2)`` int64, ``i < j``."""
    if not radius > 0:
        raise ParameterError(f"radius must be positive, got {radius}")
    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")
    return np.unique(np.sort(pairs, axis=1), axis=0).astype(np.int64).reshape(-1, 2)


def weights_from_edges(n: int, edges: np.ndarray, w: np.ndarray) -> sp.csr_matrix:
    """Symmetric ``(n, n)`` CSR matrix with ``w[k]`` at ``edges[k]`` and its transpose."""
    i, j = edges[:, 0], edges[:, 1]
    W = sp.coo_matrix(
        (np.concatenate([w, w]), (np.concatenate([i, j]), np.concatenate([j, i]))), shape=(n, n)
    ).tocsr()
    W.sum_duplicates()
    W.sort_indices()
    return W


#: peak bytes per edge of an epsilon or kNN graph (the pairs, their weights, the sparse Laplacian and its eigensolve)
#: above the spectrum's own memory (``core.spectrum.spectrum_memory``): measured 115 and 117 B on the complete epsilon
#: graphs of 2,562 and 5,000 points (0.46 and 1.56 GB), 126 B on the complete kNN graph of 2,562 points (0.49 GB)
GRAPH_EDGE_BYTES = 125.0

#: how :func:`check_graph_memory` names the arguments by default (the Python keywords)
_API_NAMES = {"radius": "radius", "n_neighbors": "n_neighbors", "memory_limit": "memory_limit"}


def _check_radius(radius: Any) -> None:
    if isinstance(radius, (bool, np.bool_)) or not isinstance(radius, (int, float, np.integer, np.floating)) or (
        not radius > 0
    ):
        raise ParameterError(f"radius must be a positive number (in the shape's length units), got "
                             f"{shown_value(radius)}")


def _check_n_neighbors(n_neighbors: Any) -> None:
    if isinstance(n_neighbors, (bool, np.bool_)) or not isinstance(n_neighbors, (int, np.integer)):
        raise ParameterError(f"n_neighbors must be an integer, got {n_neighbors!r}")


def _check_memory_limit(memory_limit: Any) -> None:
    number = (int, float, np.integer, np.floating)
    if memory_limit is not None and (
        isinstance(memory_limit, (bool, np.bool_)) or not isinstance(memory_limit, number) or not memory_limit > 0
    ):
        raise ParameterError(f"memory_limit must be a number of bytes > 0 (or None: this machine's memory), got "
                             f"{shown_value(memory_limit)}")


def graph_edge_count(
    shape: Shape, *, connectivity: str = "auto", n_neighbors: int | None = None, radius: float | None = None
) -> int | None:
    """About how many edges the kNN or epsilon graph of ``shape`` would have, without building it: an epsilon
    graph's pairs within ``radius`` counted by a k-d tree (its memory is the tree's), a kNN graph's ``n k / 2`` (its
    query holds all ``n k`` neighbours); None for mesh edges, or for a ``radius`` or ``n_neighbors`` that
    :func:`build_graph` refuses anyway."""
    n = shape.n_vertices
    if connectivity == "auto":
        connectivity = "mesh" if shape.is_mesh else "knn"
    if connectivity == "epsilon" and radius is not None:
        _check_radius(radius)
        tree = cKDTree(shape.vertices)
        return (int(tree.count_neighbors(tree, float(radius))) - n) // 2
    if connectivity == "knn":
        k = KNN_NEIGHBORS if n_neighbors is None else n_neighbors
        if isinstance(k, (bool, np.bool_)) or not isinstance(k, (int, np.integer)) or not 1 <= k < n:
            return None  # knn_edges says what is wrong
        return n * int(k) // 2
    return None


def check_graph_memory(
    shape: Shape,
    *,
    connectivity: str = "auto",
    n_neighbors: int | None = None,
    radius: float | None = None,
    memory_limit: float | None = None,
    reserve: float = 0.0,
    names: dict[str, str] | None = None,
) -> None:
    """Refuse a ``radius`` or ``n_neighbors`` whose graph (:func:`graph_edge_count` edges, :data:`GRAPH_EDGE_BYTES`
    each) and ``reserve`` bytes (what the caller needs besides, e.g. the spectrum's) would need more than
    ``memory_limit`` bytes (None: :func:`~shape_toolkit.validation.machine_memory`; infinite: no check): a radius
    near the shape's size, or neighbours near its vertex count, link every pair of points (n^2 / 2 edges: 25 GB at
    20,000 points). One-line :class:`ParameterError` naming the value, the sizes and the way out; ``names`` maps
    ``radius``, ``n_neighbors`` and ``memory_limit`` to how the caller calls them (the CLI: ``--radius``...)."""
    given = memory_limit is not None
    limit = memory_limit if given else machine_memory()
    if limit is None or limit == math.inf:
        return
    if connectivity == "epsilon" and radius is None:
        return  # build_graph asks for one
    edges = graph_edge_count(shape, connectivity=connectivity, n_neighbors=n_neighbors, radius=radius)
    if edges is None:
        return
    need = float(reserve) + GRAPH_EDGE_BYTES * edges
    if need <= limit:
        return
    label = {**_API_NAMES, **(names or {})}
    key = "radius" if connectivity == "epsilon" else "n_neighbors"
    value = radius if key == "radius" else (KNN_NEIGHBORS if n_neighbors is None else n_neighbors)
    shown = f"{float(value):g}" if key == "radius" else str(int(value))
    what = f"{label[key]} {shown}" if label[key].startswith("-") else f"{label[key]}={shown}"
    mem = label["memory_limit"]
    default = "" if given else ", this machine's memory"
    raise ParameterError(
        f"{what} links about {edges:,} pairs of the {shape.n_vertices:,} points, a graph that would need about "
        f"{need / 1e9:.3g} GB, above the memory limit of {limit / 1e9:.3g} GB ({mem}{default}); give a smaller "
        f"{'radius' if key == 'radius' else 'number of neighbours'} or raise {mem}")


def build_graph(
    shape: Shape,
    weighting: Any,
    *,
    name: str | None = None,
    connectivity: str = "auto",
    n_neighbors: int | None = None,
    radius: float | None = None,
    memory_limit: float | None = None,
) -> ShapeGraph:
    """Build the shape graph of ``shape`` with a weighting object (``weigh(shape, edges)``, e.g. a
    weighting plugin); ``name`` labels the graph (its ``weighting``, part of the spectrum cache key;
    default the object's class name). Names of plugins are resolved above: :func:`shape_toolkit.spectra.build_graph`.

    ``connectivity``: ``"mesh"`` (mesh edges), ``"knn"`` (``n_neighbors``, default 10), ``"epsilon"``
    (``radius``, in the shape's length units) or ``"auto"`` (mesh edges for meshes, kNN otherwise).

    Weightings that build their own connectivity instead of weighing the graph's edges
    (``uses_edges = False``, the default of those with ``needs_faces``): one that needs the mesh
    triangles (cotangent) refuses any connectivity but ``"auto"``/``"mesh"`` with a :class:`ParameterError`;
    one that triangulates points itself (intrinsic Delaunay) honours ``"knn"`` on a mesh by treating its
    vertices as a point cloud (local Delaunay triangulations of ``n_neighbors`` neighbours, default the
    weighting's own ``n_neighbors``) and refuses ``"epsilon"``.

    A kNN or epsilon graph that would need more than ``memory_limit`` bytes (None: this machine's memory; an
    infinite limit: no check) is refused before it is built (:func:`check_graph_memory`, which counts its pairs).
    """
    if not callable(getattr(weighting, "weigh", None)) or isinstance(weighting, type):
        shown = repr(weighting) if len(repr(weighting)) <= 60 else repr(weighting)[:57] + "..."
        raise ParameterError(
            f"weighting must be a weighting object (with a weigh() method), got {type(weighting).__name__} {shown}"
        )
    if not isinstance(connectivity, str) or connectivity not in ("auto", "mesh", "knn", "epsilon"):
        raise ParameterError(
            f"unknown connectivity {connectivity!r}; choose auto, mesh, knn or epsilon"
        )
    if n_neighbors is not None:
        _check_n_neighbors(n_neighbors)
    if radius is not None:
        _check_radius(radius)
    _check_memory_limit(memory_limit)
    scheme = weighting
    weighting = type(scheme).__name__ if name is None else str(name)
    requested = connectivity
    if connectivity == "auto":
        connectivity = "mesh" if shape.is_mesh else "knn"
    needs_faces = bool(getattr(scheme, "needs_faces", False))
    if needs_faces:
        shape.require_faces(f"the {weighting!r} weighting")
    if not getattr(scheme, "uses_edges", not needs_faces):
        return _build_own_connectivity(shape, scheme, weighting, requested, connectivity, n_neighbors)
    if n_neighbors is None:
        n_neighbors = KNN_NEIGHBORS
    check_graph_memory(shape, connectivity=connectivity, n_neighbors=n_neighbors, radius=radius,
                       memory_limit=memory_limit)
    if connectivity == "mesh":
        shape.require_faces("connectivity='mesh'")
        edges = shape.edges
    elif connectivity == "knn":
        edges = knn_edges(shape.vertices, n_neighbors) if shape.is_mesh else cloud_knn_edges(shape, n_neighbors)
    elif connectivity == "epsilon":
        if radius is None:
            raise ParameterError("connectivity='epsilon' needs a radius")
        edges = epsilon_edges(shape.vertices, radius)
    if len(edges) == 0:
        raise InvalidShapeError(f"{shape!r} has no edges to weigh")
    return _finish(shape, scheme, weighting, scheme.weigh(shape, edges), connectivity)


def _build_own_connectivity(
    shape: Shape, scheme: Any, weighting: str, requested: str, connectivity: str, n_neighbors: int | None
) -> ShapeGraph:
    """Weightings that make their own edges (cotangent, intrinsic Delaunay): honour or refuse the
    requested connectivity, never ignore it."""
    if requested == "epsilon" or (requested == "knn" and getattr(scheme, "needs_faces", False)):
        cloud = getattr(scheme, "point_cloud_weighting", None)
        alternatives = (
            "use connectivity='auto' or 'mesh', or a weighting of graph edges (gaussian, binary)"
            + ("" if requested == "epsilon" or not cloud else f", or {cloud!r} for a kNN point-cloud Laplacian")
        )
        raise ParameterError(
            f"the {weighting!r} weighting builds its own edges from "
            + ("the mesh triangles" if getattr(scheme, "needs_faces", False) else "Delaunay triangulations")
            + f" and cannot use connectivity={requested!r}: {alternatives}"
        )
    if requested == "mesh":
        shape.require_faces("connectivity='mesh'")
    target = shape
    if connectivity == "knn":
        if shape.is_mesh:
            target = Shape(shape.vertices)
        if n_neighbors is not None and "n_neighbors" in scheme.get_params():
            scheme = copy.deepcopy(scheme).set_params(n_neighbors=int(n_neighbors))  # the caller's object stays
    return _finish(shape, scheme, weighting, scheme.weigh(target, np.zeros((0, 2), np.int64)), connectivity)


def _finish(shape: Shape, scheme: Any, weighting: str, result: Any, connectivity: str) -> ShapeGraph:
    W = sp.csr_matrix(result.W, dtype=np.float64)
    if W.shape != (shape.n_vertices, shape.n_vertices):
        raise InvalidShapeError(f"weighting {weighting!r} returned a matrix of shape {W.shape}")
    if not np.isfinite(W.data).all():
        raise InvalidShapeError(
            f"weighting {weighting!r} produced non-finite weights on {shape!r} (degenerate "
            "triangles or coincident vertices?): clean the shape or use the intrinsic-delaunay weighting"
        )
    mass = result.mass
    if mass is not None:
        mass = np.asarray(mass, dtype=np.float64).ravel()
        if mass.shape != (shape.n_vertices,) or not np.isfinite(mass).all():
            raise InvalidShapeError(f"weighting {weighting!r} returned an invalid mass vector")
    info = {"connectivity": connectivity, **(result.info or {})}
    params = scheme.get_params() if hasattr(scheme, "get_params") else {}
    return ShapeGraph(shape, W, mass, weighting, params, info, str(getattr(scheme, "disconnection_hint", "")))
