"""Heat kernels of shape graphs (thesis ch. 6): kernel entries, signatures, distances, embeddings.

Everything is computed from a (truncated) :class:`~shape_toolkit.core.spectrum.Spectrum` ``(lambda_k, u_k)``:

``h(i, j; t) = sum_k exp(-t lambda_k) u_ik u_jk``  (eq. 6.26 / 6.27)

without ever forming an ``n x n`` matrix (unless explicitly asked for on a small shape).

Conventions
-----------
* ``deflate=True`` (the default, eqs. 6.18-6.21) drops the null eigenpair(s) ``lambda = 0``, as
  the thesis does; ``deflate=False`` keeps them and gives ``exp(-t L)`` itself (rows sum to one).
* ``K`` is the number of *non-null* eigenpairs used (``k = 2 .. K + 1`` in the thesis); None uses
  every non-null eigenpair of the spectrum. ``K`` larger than what the spectrum holds raises
  :class:`~shape_toolkit.errors.ParameterError`.
* Any Laplacian works: combinatorial ``L = D - W`` (eq. 6.12), normalized (eq. 6.13, the
  eigenvectors ``w_k`` of ``D^-1/2 L D^-1/2``), and random-walk, whose ``D``-orthonormal vectors are
  turned into the normalized ones ``D^1/2 v`` (same eigenvalues, symmetric kernel). A generalized
  (mass) combinatorial spectrum gives the kernel *density* w.r.t. the vertex areas: ``sum_j h_ij m_j
  = 1`` for the undeflated full kernel.
* Times are in the units of ``1 / eigenvalue`` and must be positive and finite.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.errors import ParameterError
from shape_toolkit.features.basis import shifted_weights, spectral_basis
from shape_toolkit.features.embedding import commute_time_embedding
from shape_toolkit.features.scales import check_times, scalar_time
from shape_toolkit.validation import check_vertex_ids

if TYPE_CHECKING:  # pragma: no cover
    pass

__all__ = [
    "DENSE_MAX_N",
    "NORMALIZATIONS",
    "spectral_basis",
    "heat_kernel",
    "heat_kernel_signature",
    "heat_trace",
    "heat_log_determinant",
    "heat_distance",
    "heat_distances",
    "heat_embedding",
    "unit_sphere_embedding",
    "trace_scaled_embedding",
    "time_invariant_embedding",
    "time_invariant_distance",
    "heat_covariance",
]

#: Largest ``n`` for which ``heat_kernel(..., dense_ok=True)`` builds the full ``n x n`` matrix.
DENSE_MAX_N = 5000

#: Distances of :func:`heat_distance`: plain (eq. 6.30), unit hyper-sphere (eq. 6.43), trace-scaled
#: (eq. 6.52) and the time-invariant commute-time distance (eq. 6.59, ``t`` ignored).
NORMALIZATIONS = ("none", "unit-sphere", "trace", "time-invariant")

_CHUNK = 16384  # rows processed at a time: keeps temporary memory O(chunk * K), not O(n * K)


# -- heat kernel entries ---------------------------------------------------------------------------
def heat_kernel(
    spectrum: Spectrum,
    times: float | Sequence[float] | np.ndarray,
    rows: np.ndarray | Sequence[int] | None = None,
    cols: np.ndarray | Sequence[int] | None = None,
    *,
    K: int | None = None,
    deflate: bool = True,
    dense_ok: bool = False,
) -> np.ndarray:
    """Heat-kernel entries ``h(i, j; t)`` (eq. 6.26), float64 ``(T, len(rows), len(cols))``.

    ``rows``/``cols`` None means all vertices; both None (the ``n x n`` matrix) is refused unless
    ``dense_ok`` and ``n <= DENSE_MAX_N``.
    """
    t = check_times(times)
    vals, U = spectral_basis(spectrum, K, deflate=deflate)
    n = U.shape[0]
    if rows is None and cols is None:
        if not dense_ok:
            raise ParameterError(
                "heat_kernel with rows=None and cols=None would build the n x n matrix: pass the "
                "rows/cols you need, or dense_ok=True on a small shape"
            )
        if n > DENSE_MAX_N:
            raise ParameterError(
                f"refusing to build a dense {n} x {n} heat kernel (limit n <= {DENSE_MAX_N})"
            )
    r = np.arange(n) if rows is None else check_vertex_ids(rows, n, "rows")
    c = np.arange(n) if cols is None else check_vertex_ids(cols, n, "cols")
    Ur, Uc = U[r], U[c]
    phi = np.exp(-np.outer(t, vals))  # (T, k)
    return np.einsum("ak,tk,bk->tab", Ur, phi, Uc, optimize=True)


def heat_kernel_signature(
    spectrum: Spectrum,
    times: float | Sequence[float] | np.ndarray,
    *,
    K: int | None = None,
    deflate: bool = True,
    vertices: np.ndarray | Sequence[int] | None = None,
    scale: str = "none",
) -> np.ndarray:
    """Auto-diffusion function / heat kernel signature ``h(i, i; t)`` (eq. 6.32), float64
    ``(n, T)`` (or ``(len(vertices), T)``): ``(U**2) @ exp(-t lambda)``, linear in ``n``.

    ``scale='trace'`` divides each column by the heat trace ``sum_k exp(-t lambda_k)`` (the
    scaled HKS of Sun et al. 2009, and the trace-scaled norm of eq. 6.49-6.50).
    """
    t = check_times(times)
    if scale not in ("none", "trace"):
        raise ParameterError(f"scale must be 'none' or 'trace', got {scale!r}")
    vals, U = spectral_basis(spectrum, K, deflate=deflate)
    phi = np.exp(-np.outer(vals, t))  # (k, T)
    ids = None if vertices is None else check_vertex_ids(vertices, U.shape[0], "vertices")
    m = U.shape[0] if ids is None else ids.size
    out = np.empty((m, t.size))
    for s in range(0, m, _CHUNK):
        block = U[s : s + _CHUNK] if ids is None else U[ids[s : s + _CHUNK]]
        out[s : s + _CHUNK] = (block * block) @ phi
    if scale == "trace":
        out /= phi.sum(axis=0)[None, :]
    return out


def heat_trace(
    spectrum: Spectrum, times: float | Sequence[float] | np.ndarray, *, K: int | None = None,
    deflate: bool = True,
) -> np.ndarray:
    """``tr H(t) = sum_k exp(-t lambda_k)`` (eq. 6.34), float64 ``(T,)``."""
    t = check_times(times)
    vals, _ = spectral_basis(spectrum, K, deflate=deflate)
    return np.exp(-np.outer(t, vals)).sum(axis=1)


def heat_log_determinant(
    spectrum: Spectrum, times: float | Sequence[float] | np.ndarray, *, K: int | None = None
) -> np.ndarray:
    """``log det H(t) = -t sum_k lambda_k`` over the non-null eigenpairs (eq. 6.35), ``(T,)``;
    equals ``-t tr(L)`` when the spectrum is complete."""
    t = check_times(times)
    vals, _ = spectral_basis(spectrum, K, deflate=True)
    return -t * vals.sum()


# -- embeddings (6.3, 6.5) -------------------------------------------------------------------------
def heat_embedding(spectrum: Spectrum, t: float, K: int | None = None) -> np.ndarray:
    """Heat-kernel embedding ``x_i = exp(-t Lambda / 2) u_i`` (eq. 6.28), rows ``(n, K)``."""
    t = scalar_time(t)
    vals, U = spectral_basis(spectrum, K)
    return U * np.exp(-0.5 * t * vals)[None, :]


def unit_sphere_embedding(spectrum: Spectrum, t: float, K: int | None = None) -> np.ndarray:
    """Unit hyper-sphere embedding ``x_i / ||x_i||`` (eqs. 6.40-6.41), rows ``(n, K)``, stable
    for large ``t`` (tends to eq. 6.47)."""
    t = scalar_time(t)
    vals, U = spectral_basis(spectrum, K)
    X = U * np.sqrt(shifted_weights(vals, t))[None, :]
    norm = np.linalg.norm(X, axis=1)
    norm[norm == 0] = 1.0
    return X / norm[:, None]


def trace_scaled_embedding(spectrum: Spectrum, t: float, K: int | None = None) -> np.ndarray:
    """Trace-scaled embedding (eq. 6.51): ``exp(-t lambda_k / 2) u_ik / (sum_l exp(-t lambda_l))^1/2``,
    rows ``(n, K)``; ``K^-1/2 u_i`` at ``t -> 0`` (6.53), ``m^-1/2 (u_i2..u_i,m+1, 0..)`` at
    ``t -> inf`` (6.55)."""
    t = scalar_time(t)
    vals, U = spectral_basis(spectrum, K)
    w = shifted_weights(vals, t)
    return U * np.sqrt(w / w.sum())[None, :]


def time_invariant_embedding(spectrum: Spectrum, K: int | None = None) -> np.ndarray:
    """Time-invariant (commute-time) embedding ``lambda_k^-1/2 u_ik`` (eq. 6.57), rows ``(n, K)``:
    :func:`shape_toolkit.features.embedding.commute_time_embedding`."""
    return commute_time_embedding(spectrum, K)


def time_invariant_distance(
    spectrum: Spectrum, sources: np.ndarray | Sequence[int] | int,
    targets: np.ndarray | Sequence[int] | None = None, K: int | None = None,
) -> np.ndarray:
    """Time-invariant distance ``sqrt(sum_k (u_ik - u_jk)^2 / lambda_k)`` (eq. 6.59),
    ``(len(sources), n_targets)``."""
    X = time_invariant_embedding(spectrum, K)
    return _pairwise(X, sources, targets, "euclidean")


def heat_covariance(spectrum: Spectrum, t: float, K: int | None = None) -> np.ndarray:
    """Covariance ``Sigma_X = exp(-t Lambda) / n`` of the heat embedding (eq. 6.36), ``(K, K)``."""
    t = scalar_time(t)
    vals, U = spectral_basis(spectrum, K)
    return np.diag(np.exp(-t * vals)) / U.shape[0]


# -- distances ---------------------------------------------------------------------------------
def _pairwise(
    X: np.ndarray, sources: object, targets: object, kind: str
) -> np.ndarray:
    n = X.shape[0]
    src = check_vertex_ids(sources, n, "sources")
    tgt = None if targets is None else check_vertex_ids(targets, n, "targets")
    a = X[src]
    an = np.einsum("ij,ij->i", a, a)
    m = n if tgt is None else tgt.size
    out = np.empty((src.size, m))
    for s in range(0, m, _CHUNK):
        b = X[s : s + _CHUNK] if tgt is None else X[tgt[s : s + _CHUNK]]
        dot = a @ b.T
        if kind == "euclidean":
            bn = np.einsum("ij,ij->i", b, b)
            out[:, s : s + _CHUNK] = np.sqrt(np.maximum(an[:, None] + bn[None, :] - 2.0 * dot, 0.0))
        else:  # geodesic on the unit sphere
            out[:, s : s + _CHUNK] = np.arccos(np.clip(dot, -1.0, 1.0))
    return out


def heat_distances(
    spectrum: Spectrum,
    times: float | Sequence[float] | np.ndarray,
    sources: np.ndarray | Sequence[int] | int,
    targets: np.ndarray | Sequence[int] | None = None,
    *,
    normalization: str = "none",
    K: int | None = None,
) -> np.ndarray:
    """Multi-scale heat distances, float64 ``(T, len(sources), n_targets)`` (all vertices when
    ``targets`` is None); ``normalization`` is one of :data:`NORMALIZATIONS`:

    ``none``: ``||x_i - x_j||`` (eq. 6.30); ``unit-sphere``: ``arccos`` of the normalized kernel
    (eq. 6.43, radians); ``trace``: ``d_T`` (eq. 6.52); ``time-invariant``: eq. 6.59 (same for all t).
    Memory is ``O((len(sources) + chunk) * K)`` besides the output.
    """
    t = check_times(times)
    if normalization not in NORMALIZATIONS:
        raise ParameterError(
            f"unknown normalization {normalization!r}; choose one of {', '.join(NORMALIZATIONS)}"
        )
    vals, U = spectral_basis(spectrum, K)
    n = U.shape[0]
    src = check_vertex_ids(sources, n, "sources")
    tgt = None if targets is None else check_vertex_ids(targets, n, "targets")
    m = n if tgt is None else tgt.size
    out = np.empty((t.size, src.size, m))
    for ti, tt in enumerate(t):
        if normalization == "none":
            X = U * np.exp(-0.5 * tt * vals)[None, :]
            kind = "euclidean"
        elif normalization == "trace":
            w = shifted_weights(vals, tt)
            X = U * np.sqrt(w / w.sum())[None, :]
            kind = "euclidean"
        elif normalization == "time-invariant":
            X = commute_time_embedding(spectrum, K)
            kind = "euclidean"
        else:
            X = U * np.sqrt(shifted_weights(vals, tt))[None, :]
            norm = np.linalg.norm(X, axis=1)
            norm[norm == 0] = 1.0
            X = X / norm[:, None]
            kind = "sphere"
        out[ti] = _pairwise(X, src, tgt, kind)
    return out


def heat_distance(
    spectrum: Spectrum,
    t: float,
    sources: np.ndarray | Sequence[int] | int,
    targets: np.ndarray | Sequence[int] | None = None,
    normalization: str = "none",
    *,
    K: int | None = None,
) -> np.ndarray:
    """Heat distance at one time ``t`` (eq. 6.30, or eq. 6.43 / 6.52 / 6.59 by
    ``normalization``), float64 ``(len(sources), n_targets)``."""
    return heat_distances(
        spectrum, scalar_time(t), sources, targets, normalization=normalization, K=K
    )[0]
