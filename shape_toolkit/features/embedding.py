"""Spectral embeddings of shape graphs and the choice of their dimension (thesis 2.6.4-2.6.6)."""

from __future__ import annotations

import numpy as np

from shape_toolkit.core.spectrum import Spectrum, null_count
from shape_toolkit.errors import ParameterError
from shape_toolkit.features.basis import spectral_basis
from shape_toolkit.validation import check_vertex_ids

__all__ = [
    "laplacian_eigenmap",
    "commute_time_embedding",
    "commute_time_distance",
    "scree_theta",
    "theta_min",
    "choose_dimension",
]


def _non_null(spectrum: Spectrum, dim: int | None) -> tuple[np.ndarray, np.ndarray]:
    skip = max(null_count(spectrum.eigenvalues), 1)
    avail = spectrum.k - skip
    if dim is None:
        dim = avail
    if not 1 <= dim <= avail:
        raise ParameterError(
            f"dim must be in [1, {avail}]: the spectrum has {spectrum.k} eigenpairs, "
            f"{skip} of them null; compute a larger spectrum"
        )
    return spectrum.eigenvalues[skip : skip + dim], spectrum.eigenvectors[:, skip : skip + dim]


def laplacian_eigenmap(spectrum: Spectrum, dim: int | None = None) -> np.ndarray:
    """Laplacian eigenmap (Algorithm 3): the first ``dim`` non-null eigenvectors, ``(n, dim)``."""
    return np.array(_non_null(spectrum, dim)[1])


def commute_time_embedding(spectrum: Spectrum, dim: int | None = None) -> np.ndarray:
    """Commute-time embedding ``X = Lambda_K^-1/2 U_K^T`` (eq. 2.92; the time-invariant embedding of
    eq. 6.57), returned as ``(n, K)`` rows: the first ``dim`` non-null eigenpairs (None: all), in the
    basis of :func:`~shape_toolkit.features.basis.spectral_basis`. The one implementation: the heat
    module, the descriptors and the segmenters call it."""
    vals, vecs = spectral_basis(spectrum, dim)
    if np.any(vals <= 0):
        raise ParameterError("the commute-time embedding needs positive non-null eigenvalues")
    return vecs / np.sqrt(vals)[None, :]


def commute_time_distance(
    spectrum: Spectrum,
    sources: np.ndarray | int,
    targets: np.ndarray | int | None = None,
    dim: int | None = None,
) -> np.ndarray:
    """Commute-time distance ``CTD = sqrt(Vol(G)) ||x_i - x_j||`` (eq. 2.90) truncated to ``dim``
    eigenpairs, as an ``(len(sources), len(targets))`` array (all vertices when ``targets`` is None)."""
    X = commute_time_embedding(spectrum, dim)
    src = check_vertex_ids(sources, len(X), "sources")
    tgt = np.arange(len(X)) if targets is None else check_vertex_ids(targets, len(X), "targets")
    a, b = X[src], X[tgt]
    d2 = (a**2).sum(1)[:, None] + (b**2).sum(1)[None, :] - 2.0 * a @ b.T
    return np.sqrt(spectrum.volume * np.maximum(d2, 0.0))


def scree_theta(eigenvalues: np.ndarray, K: int) -> float:
    """Scree ratio ``theta(K)`` (eq. 2.97) from a *complete* spectrum (null eigenvalue first)."""
    inv = 1.0 / np.asarray(eigenvalues, dtype=np.float64)[1:]
    if not 1 <= K <= inv.size:
        raise ParameterError(f"K must be in [1, {inv.size}], got {K}")
    return float(inv[:K].sum() / inv.sum())


def theta_min(eigenvalues: np.ndarray, K: int, n: int) -> float:
    """Lower bound ``theta_min`` (eq. 2.99) of the scree ratio from the ``K + 1`` smallest
    eigenvalues (null first) of the combinatorial Laplacian of an ``n``-vertex graph."""
    lam = np.asarray(eigenvalues, dtype=np.float64)
    if not 1 <= K < n or lam.size < K + 1:
        raise ParameterError(f"theta_min needs K in [1, {n - 1}] and K + 1 eigenvalues")
    inv = 1.0 / lam[1 : K + 1]
    if not np.all(np.isfinite(inv)) or np.any(inv <= 0):
        raise ParameterError("theta_min needs positive non-null eigenvalues (connected graph)")
    return float(inv.sum() / (inv[:-1].sum() + (n - K) * inv[-1]))


def choose_dimension(spectrum: Spectrum, threshold: float = 0.95) -> int:
    """Smallest ``K`` whose ``theta_min`` (eq. 2.99) reaches ``threshold``; raises when the
    spectrum is too short to reach it."""
    if not 0 < threshold < 1:
        raise ParameterError(f"threshold must be in (0, 1), got {threshold}")
    n = spectrum.n_vertices
    for K in range(1, spectrum.k):
        if theta_min(spectrum.eigenvalues, K, n) >= threshold:
            return K
    raise ParameterError(
        f"theta_min stays below {threshold} with {spectrum.k} eigenpairs: compute more"
    )
