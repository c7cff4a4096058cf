"""Helpers shared by the segmenter plugins (not a plugin itself: no entry point).

Default shape graph of the segmenters (thesis 3.3.3, 4.1.2, 5.2): mesh connectivity (kNN for point
clouds) with Gaussian weights ``exp(-d^2 / 2 sigma^2)``, sigma = mean edge length, so that
``0 < w_ij <= 1``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp
from sklearn.cluster import KMeans
from threadpoolctl import threadpool_limits

from shape_toolkit.core.graph import ShapeGraph, build_graph
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum, compute_spectrum
from shape_toolkit.errors import ParameterError
from shape_toolkit.results.labels import relabel_consecutive


def check_n_segments(k: Any, n: int, *, allow_none: bool) -> int | None:
    """Validate the number of segments: an int in ``[2, n]`` (or None when the method can choose)."""
    if k is None:
        if allow_none:
            return None
        raise ParameterError("n_segments is required for this method (an integer >= 2)")
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)):
        raise ParameterError(f"n_segments must be an integer >= 2, got {k!r}")
    if k < 2:
        raise ParameterError(f"n_segments must be >= 2, got {k}")
    if k > n:
        raise ParameterError(f"n_segments = {k} exceeds the number of vertices ({n})")
    return int(k)


def check_random_state(random_state: Any) -> int:
    """The integer seed (None means 0, for determinism)."""
    if random_state is None:
        return 0
    if isinstance(random_state, bool) or not isinstance(random_state, (int, np.integer)):
        raise ParameterError(f"random_state must be an integer, got {random_state!r}")
    return int(random_state)


def shape_graph(shape: Shape, weighting: str) -> ShapeGraph:
    """The segmenters' default shape graph with the named weighting."""
    return build_graph(shape, weighting)


def graph_spectrum(
    shape: Shape, k: int, *, weighting: str, laplacian: str, graph: ShapeGraph | None = None
) -> Spectrum:
    """``k`` smallest eigenpairs of the chosen Laplacian of the default graph (no mass matrix),
    cached by content; ``k`` is capped at the vertex count."""
    graph = graph if graph is not None else shape_graph(shape, weighting)
    return compute_spectrum(graph, min(int(k), graph.n_vertices), laplacian=laplacian, use_mass=False)


def check_spectrum(spectrum: Spectrum, shape: Shape, needed: int) -> None:
    """Refuse a spectrum of another shape or with fewer than ``needed`` eigenpairs."""
    if spectrum.n_vertices != shape.n_vertices:
        raise ParameterError(
            f"the spectrum has {spectrum.n_vertices} vertices but the shape has {shape.n_vertices}"
        )
    if spectrum.k < needed:
        raise ParameterError(
            f"the spectrum has {spectrum.k} eigenpairs; this segmenter needs {needed} "
            "(pass spectrum=None to compute it)"
        )


def n_null(eigenvalues: np.ndarray, rtol: float = 1e-8) -> int:
    """Number of (numerically) null eigenvalues at the start, at least 1."""
    scale = max(float(np.abs(eigenvalues).max()), 1e-300)
    return max(int(np.sum(eigenvalues <= rtol * scale)), 1)


def kmeans_labels(X: np.ndarray, k: int, random_state: int, n_init: int = 10) -> np.ndarray:
    """K-means labels of the rows of ``X`` ``(n, d)``, renumbered by first appearance."""
    km = KMeans(n_clusters=k, n_init=n_init, random_state=random_state)
    with single_thread():
        return relabel_consecutive(km.fit_predict(np.ascontiguousarray(X, dtype=np.float64)))


def single_thread() -> threadpool_limits:
    """Context limiting OpenMP/BLAS pools to one thread: k-means and GMM fits on a few thousand
    low-dimensional points are much faster without thread start-up and contention."""
    return threadpool_limits(limits=1)


def row_normalize(X: np.ndarray) -> np.ndarray:
    """Rows of ``X`` scaled to unit Euclidean length (zero rows left at zero)."""
    norms = np.linalg.norm(X, axis=1, keepdims=True)
    return X / np.where(norms > 0, norms, 1.0)


def laplacian_embedding_of(W: sp.csr_matrix, k: int) -> tuple[np.ndarray, np.ndarray]:
    """``(eigenvalues (k,), eigenvectors (n, k))``: the ``k`` first non-null eigenpairs of
    ``D - W`` for a connected graph ``W``."""
    from shape_toolkit.core.eigen import smallest_eigenpairs

    d = np.asarray(W.sum(axis=1)).ravel()
    L = sp.csr_matrix(sp.diags(d) - W)
    vals, vecs = smallest_eigenpairs(L, min(k + 1, W.shape[0]))
    return vals[1:], vecs[:, 1:]
