"""Shape graphs (thesis 3.2): connectivity from mesh edges or neighbourhoods, weights from shape_toolkit.plugins."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import InvalidShapeError, ParameterError

__all__ = ["ShapeGraph", "build_graph", "knn_edges", "epsilon_edges", "weights_from_edges"]


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


def build_graph(
    shape: Shape,
    weighting: str = "gaussian",
    *,
    connectivity: str = "auto",
    n_neighbors: int = 10,
    radius: float | None = None,
    **params: Any,
) -> ShapeGraph:
    """Build the shape graph of ``shape`` with a weighting plugin (by name) and its parameters.

    ``connectivity``: ``"mesh"`` (mesh edges), ``"knn"`` (``n_neighbors``), ``"epsilon"``
    (``radius``, in the shape's length units) or ``"auto"`` (mesh edges for meshes, kNN otherwise).
    """
    from shape_toolkit.api.registry import create_plugin

    scheme = create_plugin("weightings", weighting, **params)
    if connectivity == "auto":
        connectivity = "mesh" if shape.is_mesh else "knn"
    if getattr(scheme, "needs_faces", False):
        shape.require_faces(f"the {weighting!r} weighting")
    if connectivity == "mesh":
        shape.require_faces("connectivity='mesh'")
        edges = shape.edges
    elif connectivity == "knn":
        edges = knn_edges(shape.vertices, n_neighbors)
    elif connectivity == "epsilon":
        if radius is None:
            raise ParameterError("connectivity='epsilon' needs a radius")
        edges = epsilon_edges(shape.vertices, radius)
    else:
        raise ParameterError(
            f"unknown connectivity {connectivity!r}; choose auto, mesh, knn or epsilon"
        )
    if len(edges) == 0 and not getattr(scheme, "needs_faces", False):
        raise InvalidShapeError(f"{shape!r} has no edges to weigh")
    result = scheme.weigh(shape, edges)
    W = sp.csr_matrix(result.W, dtype=np.float64)
    if W.shape != (shape.n_vertices, shape.n_vertices):
        raise InvalidShapeError(f"weighting {weighting!r} returned a matrix of shape {W.shape}")
    if not np.isfinite(W.data).all():
        raise InvalidShapeError(
            f"weighting {weighting!r} produced non-finite weights on {shape!r} (degenerate "
            "triangles or coincident vertices?): clean the shape or use 'intrinsic-delaunay'"
        )
    mass = result.mass
    if mass is not None:
        mass = np.asarray(mass, dtype=np.float64).ravel()
        if mass.shape != (shape.n_vertices,) or not np.isfinite(mass).all():
            raise InvalidShapeError(f"weighting {weighting!r} returned an invalid mass vector")
    info = {"connectivity": connectivity, **result.info}
    return ShapeGraph(shape, W, mass, weighting, scheme.get_params(), info)
