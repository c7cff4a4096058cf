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

if TYPE_CHECKING:  # pragma: no cover
    from shape_toolkit.core.shape import Shape

__all__ = [
    "DENSE_MAX_N",
    "NORMALIZATIONS",
    "check_times",
    "spectral_basis",
    "default_times",
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
    "scree_alpha",
    "min_time_for_dimension",
    "dimension_for_time",
    "pair_scale",
    "pair_times",
    "descriptor_matching_score",
    "shape_spectrum",
    "multiscale_times",
    "keypoint_descriptor_inputs",
]

#: Largest ``n`` for which ``heat_kernel(..., dense_ok=True)`` builds the full ``n x n`` matrix.
DENSE_MAX_N = 5000

#: Distances of :func:`heat_distance`: plain (eq. 6.30), unit hyper-sphere (eq. 6.43), trace-scaled
#: (eq. 6.52) and the time-invariant commute-time distance (eq. 6.59, ``t`` ignored).
NORMALIZATIONS = ("none", "unit-sphere", "trace", "time-invariant")

_CHUNK = 16384  # rows processed at a time: keeps temporary memory O(chunk * K), not O(n * K)


# -- validation ------------------------------------------------------------------------------------
def check_times(times: float | Sequence[float] | np.ndarray) -> np.ndarray:
    """Validate diffusion times: a float64 ``(T,)`` array of positive finite values."""
    t = np.atleast_1d(np.asarray(times, dtype=np.float64)).ravel()
    if t.size == 0:
        raise ParameterError("at least one diffusion time is needed")
    if not np.all(np.isfinite(t)) or np.any(t <= 0):
        bad = t[~(np.isfinite(t) & (t > 0))][0]
        raise ParameterError(f"diffusion times must be positive and finite, got {float(bad)!r}")
    return t


def _check_ids(ids: object, n: int, what: str) -> np.ndarray:
    a = np.atleast_1d(np.asarray(ids))
    if a.size == 0:
        return np.zeros(0, dtype=np.int64)
    if a.ndim != 1 or not (np.issubdtype(a.dtype, np.integer) or np.all(np.mod(a, 1) == 0)):
        raise ParameterError(f"{what} must be a 1-D array of integer vertex ids")
    a = a.astype(np.int64)
    if a.min() < 0 or a.max() >= n:
        raise ParameterError(
            f"{what} must be vertex ids in [0, {n - 1}], found range [{a.min()}, {a.max()}]"
        )
    return a


def _null_count(vals: np.ndarray, rtol: float = 1e-8) -> int:
    scale = max(float(np.abs(vals).max()), 1e-300)
    return int(np.sum(vals <= rtol * scale))


def spectral_basis(
    spectrum: Spectrum, K: int | None = None, *, deflate: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """The eigenvalues ``(k,)`` and orthonormal eigenvectors ``(n, k)`` the kernel is built from:
    the null eigenpairs dropped when ``deflate``, then the first ``K`` non-null ones."""
    vals = np.asarray(spectrum.eigenvalues, dtype=np.float64)
    vecs = np.asarray(spectrum.eigenvectors, dtype=np.float64)
    if spectrum.laplacian == "random-walk":
        vecs = vecs * np.sqrt(np.asarray(spectrum.degrees, dtype=np.float64))[:, None]
    null = _null_count(vals)
    avail = vals.size - null
    if K is None:
        K = avail
    if isinstance(K, bool) or not isinstance(K, (int, np.integer)):
        raise ParameterError(f"K must be an integer, got {K!r}")
    if not 1 <= K <= avail:
        raise ParameterError(
            f"K must be in [1, {avail}]: the spectrum holds {vals.size} eigenpairs, {null} of them "
            f"null; compute a larger spectrum (K = {K} asked)"
        )
    start = null if deflate else 0
    stop = null + int(K)
    return vals[start:stop], vecs[:, start:stop]


def default_times(spectrum: Spectrum, n_times: int = 16, K: int | None = None) -> np.ndarray:
    """``n_times`` log-spaced times ``(T,)`` from ``4 ln10 / lambda_max`` to ``4 ln10 / lambda_2``
    (Sun et al. 2009), with ``lambda`` the non-null eigenvalues actually used (``K``)."""
    if isinstance(n_times, bool) or not isinstance(n_times, (int, np.integer)) or n_times < 1:
        raise ParameterError(f"n_times must be a positive integer, got {n_times!r}")
    vals, _ = spectral_basis(spectrum, K)
    lo, hi = float(vals[0]), float(vals[-1])
    if not lo > 0:
        raise ParameterError("the spectrum has no positive eigenvalue to derive times from")
    tmin, tmax = 4.0 * np.log(10.0) / hi, 4.0 * np.log(10.0) / lo
    if n_times == 1:
        return np.array([np.sqrt(tmin * tmax)])
    return np.geomspace(tmin, tmax, int(n_times))


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
    r = np.arange(n) if rows is None else _check_ids(rows, n, "rows")
    c = np.arange(n) if cols is None else _check_ids(cols, n, "cols")
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
    ids = None if vertices is None else _check_ids(vertices, U.shape[0], "vertices")
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
def _scalar_time(t: float) -> float:
    tt = check_times(t)
    if tt.size != 1:
        raise ParameterError("a single diffusion time is expected here")
    return float(tt[0])


def heat_embedding(spectrum: Spectrum, t: float, K: int | None = None) -> np.ndarray:
    """Heat-kernel embedding ``x_i = exp(-t Lambda / 2) u_i`` (eq. 6.28), rows ``(n, K)``."""
    t = _scalar_time(t)
    vals, U = spectral_basis(spectrum, K)
    return U * np.exp(-0.5 * t * vals)[None, :]


def _shifted_weights(vals: np.ndarray, t: float) -> np.ndarray:
    """``exp(-t (lambda_k - lambda_min))``: the heat weights up to a common factor, which the
    normalized embeddings cancel; never underflows to all zeros at large ``t``."""
    return np.exp(-t * (vals - vals.min()))


def unit_sphere_embedding(spectrum: Spectrum, t: float, K: int | None = None) -> np.ndarray:
    """Unit hyper-sphere embedding ``x_i / ||x_i||`` (eqs. 6.40-6.41), rows ``(n, K)``, stable
    for large ``t`` (tends to eq. 6.47)."""
    t = _scalar_time(t)
    vals, U = spectral_basis(spectrum, K)
    X = U * np.sqrt(_shifted_weights(vals, t))[None, :]
    norm = np.linalg.norm(X, axis=1)
    norm[norm == 0] = 1.0
    return X / norm[:, None]


def trace_scaled_embedding(spectrum: Spectrum, t: float, K: int | None = None) -> np.ndarray:
    """Trace-scaled embedding (eq. 6.51): ``exp(-t lambda_k / 2) u_ik / (sum_l exp(-t lambda_l))^1/2``,
    rows ``(n, K)``; ``K^-1/2 u_i`` at ``t -> 0`` (6.53), ``m^-1/2 (u_i2..u_i,m+1, 0..)`` at
    ``t -> inf`` (6.55)."""
    t = _scalar_time(t)
    vals, U = spectral_basis(spectrum, K)
    w = _shifted_weights(vals, t)
    return U * np.sqrt(w / w.sum())[None, :]


def time_invariant_embedding(spectrum: Spectrum, K: int | None = None) -> np.ndarray:
    """Time-invariant (commute-time) embedding ``lambda_k^-1/2 u_ik`` (eq. 6.57), rows ``(n, K)``."""
    vals, U = spectral_basis(spectrum, K)
    if np.any(vals <= 0):
        raise ParameterError("the time-invariant embedding needs positive eigenvalues")
    return U / np.sqrt(vals)[None, :]


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
    t = _scalar_time(t)
    vals, U = spectral_basis(spectrum, K)
    return np.diag(np.exp(-t * vals)) / U.shape[0]


# -- distances ---------------------------------------------------------------------------------
def _pairwise(
    X: np.ndarray, sources: object, targets: object, kind: str
) -> np.ndarray:
    n = X.shape[0]
    src = _check_ids(sources, n, "sources")
    tgt = None if targets is None else _check_ids(targets, n, "targets")
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
    src = _check_ids(sources, n, "sources")
    tgt = None if targets is None else _check_ids(targets, n, "targets")
    m = n if tgt is None else tgt.size
    out = np.empty((t.size, src.size, m))
    for ti, tt in enumerate(t):
        if normalization == "none":
            X = U * np.exp(-0.5 * tt * vals)[None, :]
            kind = "euclidean"
        elif normalization == "trace":
            w = _shifted_weights(vals, tt)
            X = U * np.sqrt(w / w.sum())[None, :]
            kind = "euclidean"
        elif normalization == "time-invariant":
            if np.any(vals <= 0):
                raise ParameterError("the time-invariant distance needs positive eigenvalues")
            X = U / np.sqrt(vals)[None, :]
            kind = "euclidean"
        else:
            X = U * np.sqrt(_shifted_weights(vals, tt))[None, :]
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
        spectrum, _scalar_time(t), sources, targets, normalization=normalization, K=K
    )[0]


# -- scale and dimension (6.4) -----------------------------------------------------------------
def _eigen_array(spectrum_or_values: Spectrum | np.ndarray) -> tuple[np.ndarray, int]:
    if isinstance(spectrum_or_values, Spectrum):
        vals, _ = spectral_basis(spectrum_or_values)
        return vals, spectrum_or_values.n_vertices
    lam = np.sort(np.asarray(spectrum_or_values, dtype=np.float64).ravel())
    null = _null_count(lam) if lam.size else 0
    lam = lam[null:]
    return lam, lam.size + 1


def scree_alpha(
    spectrum: Spectrum | np.ndarray, K: int, t: float, *, n: int | None = None
) -> float:
    """Scree ratio ``alpha(K, t)`` (eq. 6.39): the heat-trace fraction of the ``K`` first non-null
    eigenpairs.

    Exact when the spectrum is complete (``k == n``); otherwise the unknown tail
    ``k > k_computed`` is bounded by ``(n - k) exp(-t lambda_max computed)``, which gives a *lower
    bound* of ``alpha`` (conservative, like ``theta_min`` of eq. 2.99). ``spectrum`` may also be an
    array of eigenvalues (null first) with ``n`` the vertex count.
    """
    t = _scalar_time(t)
    vals, n_spec = _eigen_array(spectrum)
    n = n_spec if n is None else int(n)
    avail = vals.size
    if isinstance(K, bool) or not isinstance(K, (int, np.integer)) or not 1 <= K <= avail:
        raise ParameterError(f"K must be an integer in [1, {avail}] (non-null eigenpairs), got {K}")
    w = _shifted_weights(vals, t)
    head = w[:K].sum()
    tail = w[K:].sum()
    missing = max(n - 1 - avail, 0)
    if missing:
        tail += missing * w[-1]
    return float(head / (head + tail))


def min_time_for_dimension(
    spectrum: Spectrum | np.ndarray, K: int, alpha: float = 0.95, *, n: int | None = None
) -> float:
    """Smallest time ``t`` with ``alpha(K, t) >= alpha`` (eq. 6.39; alpha grows with t), by
    bisection in ``log t``; raises when even very large t cannot reach it."""
    if not 0 < alpha < 1:
        raise ParameterError(f"alpha must be in (0, 1), got {alpha}")
    vals, _ = _eigen_array(spectrum)
    if not vals.size or not vals[0] > 0:
        raise ParameterError("the spectrum needs positive non-null eigenvalues")
    tiny = 1e-12 / float(vals[-1])
    if scree_alpha(spectrum, K, tiny, n=n) >= alpha:
        return tiny
    lo, hi = np.log(1e-12 / vals[-1]), np.log(1.0 / vals[0])
    while scree_alpha(spectrum, K, float(np.exp(hi)), n=n) < alpha:
        hi += np.log(10.0)
        if hi > np.log(1e12 / vals[0]):
            raise ParameterError(
                f"alpha({K}, t) never reaches {alpha}: K = {K} is smaller than the multiplicity "
                "gap allows, or the spectrum is too short; use a larger K"
            )
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if scree_alpha(spectrum, K, float(np.exp(mid)), n=n) >= alpha:
            hi = mid
        else:
            lo = mid
    return float(np.exp(hi))


def dimension_for_time(
    spectrum: Spectrum | np.ndarray, t: float, alpha: float = 0.95, *, n: int | None = None
) -> int:
    """Smallest ``K`` with ``alpha(K, t) >= alpha`` (eq. 6.39); raises when the spectrum is too
    short to reach it."""
    if not 0 < alpha < 1:
        raise ParameterError(f"alpha must be in (0, 1), got {alpha}")
    vals, n_spec = _eigen_array(spectrum)
    nn = n_spec if n is None else int(n)
    tt = _scalar_time(t)
    w = _shifted_weights(vals, tt)
    missing = max(nn - 1 - vals.size, 0)
    total = w.sum() + missing * w[-1]
    K = int(np.searchsorted(np.cumsum(w) / total, alpha) + 1)
    if K > vals.size:
        raise ParameterError(
            f"alpha(K, t={tt:g}) stays below {alpha} with the {vals.size} non-null eigenpairs "
            "available: compute a larger spectrum or use a larger t"
        )
    while K > 1 and scree_alpha(spectrum, K - 1, tt, n=n) >= alpha:  # guard rounding
        K -= 1
    return K


def pair_scale(
    first: Spectrum | np.ndarray, second: Spectrum | np.ndarray, K: int = 25,
    alpha: float = 0.95, *, n_first: int | None = None, n_second: int | None = None,
) -> tuple[float, int]:
    """The rule of section 7.3.1 for two shapes: the minimum time ``t`` reaching ``alpha`` with
    ``K`` eigenpairs on the first shape, then the second shape's ``K'`` for that ``t``;
    returns ``(t, K')``."""
    t = min_time_for_dimension(first, K, alpha, n=n_first)
    return t, dimension_for_time(second, t, alpha, n=n_second)


def pair_times(
    first: Spectrum, second: Spectrum, K: int = 25, n_times: int = 5, *, alpha: float = 0.95,
    ratio: float = 2.0,
) -> tuple[np.ndarray, int, int]:
    """Common descriptor times for matching two shapes (section 7.3.1): ``t_1`` from ``K`` on the
    first shape, ``t_i = t_1 ratio^(i-1)``, and the second shape's ``K'`` for ``t_1``; returns
    ``(times (n_times,), K, K')``. Pass ``times`` and ``K``/``K'`` to the ``heat-distance`` /
    ``heat-diffusion`` plugins of each shape so that both use the same scales."""
    times = multiscale_times(first, n_times, K, alpha=alpha, ratio=ratio)
    return times, int(K), dimension_for_time(second, float(times[0]), alpha)


# -- descriptor matching (6.6.4) ---------------------------------------------------------------
def descriptor_matching_score(
    desc_src: np.ndarray | Sequence[np.ndarray],
    desc_dst: np.ndarray | Sequence[np.ndarray],
    src_vertices: np.ndarray | Sequence[int] | None = None,
    dst_vertices: np.ndarray | Sequence[int] | None = None,
    *,
    n_times: int | None = None,
    pairwise: bool = False,
) -> np.ndarray:
    """Matching score of eq. 6.66: ``sum_m ||d_m(v_i) - d_m(v'_j)||_inf`` over the ``M`` matched
    keypoints (max over the ``tau`` scales), lower is better.

    Descriptors are ``(n, M * tau)`` arrays laid out keypoint-major (``[d_1(t_1..t_tau), d_2...]``,
    the layout of the ``heat-distance`` and ``heat-diffusion`` plugins) with ``n_times = tau``
    given, or ``(n, M, tau)`` arrays, or lists of ``M`` ``(n, tau)`` arrays; the keypoint order of
    the two shapes must follow the keypoint matching. Rows ``src_vertices[q]`` and
    ``dst_vertices[q]`` are compared pairwise (``(q,)`` scores), or every source row with every
    destination row (``(q_src, q_dst)``) when ``pairwise``.
    """
    a, b = _as_cube(desc_src, n_times, "desc_src"), _as_cube(desc_dst, n_times, "desc_dst")
    if a.shape[1:] != b.shape[1:]:
        raise ParameterError(
            f"descriptors disagree: (M, tau) = {a.shape[1:]} on the source, {b.shape[1:]} on the target"
        )
    na, nb = a.shape[0], b.shape[0]
    ia = np.arange(na) if src_vertices is None else _check_ids(src_vertices, na, "src_vertices")
    ib = np.arange(nb) if dst_vertices is None else _check_ids(dst_vertices, nb, "dst_vertices")
    if pairwise:
        out = np.empty((ia.size, ib.size))
        step = max(1, 2_000_000 // max(1, ib.size * a.shape[1] * a.shape[2]))
        B = b[ib]
        for s in range(0, ia.size, step):
            A = a[ia[s : s + step]]
            out[s : s + step] = np.abs(A[:, None] - B[None, :]).max(axis=3).sum(axis=2)
        return out
    if ia.size != ib.size:
        raise ParameterError(
            f"src_vertices and dst_vertices must have the same length ({ia.size} != {ib.size}) "
            "unless pairwise=True"
        )
    return np.abs(a[ia] - b[ib]).max(axis=2).sum(axis=1)


def _as_cube(desc: object, n_times: int | None, what: str) -> np.ndarray:
    if isinstance(desc, (list, tuple)):
        arrs = [np.asarray(d, dtype=np.float64) for d in desc]
        if not arrs:
            raise ParameterError(f"{what} is an empty list")
        arrs = [d[:, None] if d.ndim == 1 else d for d in arrs]
        return np.stack(arrs, axis=1)
    d = np.asarray(desc, dtype=np.float64)
    if d.ndim == 3:
        return d
    if d.ndim == 2:
        if n_times is None:
            raise ParameterError(f"{what} is 2-D: pass n_times (tau) to split it into keypoints")
        if n_times < 1 or d.shape[1] % n_times:
            raise ParameterError(f"{what} has {d.shape[1]} columns, not a multiple of n_times={n_times}")
        return d.reshape(d.shape[0], d.shape[1] // n_times, n_times)
    raise ParameterError(f"{what} must be (n, M*tau), (n, M, tau) or a list of (n, tau) arrays")


# -- defaults shared by the heat plugins -------------------------------------------------------
def shape_spectrum(
    shape: Shape, k: int, *, weighting: str = "gaussian", laplacian: str = "combinatorial",
    components: str = "raise",
) -> Spectrum:
    """The thesis's default spectrum for heat-kernel work (sections 6.4.1, 6.6.1): the ``k``
    smallest eigenpairs (``k`` capped at ``n``) of the combinatorial Laplacian of the
    Gaussian-weighted shape graph (mesh edges, kNN for point clouds), no mass matrix."""
    from shape_toolkit.core.graph import build_graph
    from shape_toolkit.core.spectrum import compute_spectrum

    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 2:
        raise ParameterError(f"the spectrum needs k >= 2 eigenpairs, got {k!r}")
    graph = build_graph(shape, weighting)
    return compute_spectrum(
        graph, int(min(k, shape.n_vertices)), laplacian=laplacian, use_mass=False,
        components=components,
    )


def multiscale_times(
    spectrum: Spectrum, n_times: int = 5, K: int | None = None, *, alpha: float = 0.95,
    ratio: float = 2.0,
) -> np.ndarray:
    """Descriptor time scales of section 7.3.1: ``t_1`` is the smallest time with
    ``alpha(K, t_1) >= alpha`` (eq. 6.39, from this spectrum), then ``t_i = t_1 ratio^(i-1)``
    (logarithmically increasing); float64 ``(n_times,)``."""
    if isinstance(n_times, bool) or not isinstance(n_times, (int, np.integer)) or n_times < 1:
        raise ParameterError(f"n_times must be a positive integer, got {n_times!r}")
    if not (np.isfinite(ratio) and ratio > 1):
        raise ParameterError(f"ratio must be > 1, got {ratio!r}")
    vals, _ = spectral_basis(spectrum)
    K = vals.size if K is None else K
    t1 = min_time_for_dimension(spectrum, K, alpha)
    return t1 * float(ratio) ** np.arange(int(n_times))


def keypoint_descriptor_inputs(
    shape: Shape,
    spectrum: Spectrum | None,
    keypoints: np.ndarray | Sequence[int] | None,
    *,
    K: int | None,
    times: Sequence[float] | None,
    n_times: int,
    alpha: float,
    time_ratio: float,
    weighting: str,
    laplacian: str,
    who: str,
) -> tuple[Spectrum, int, np.ndarray, np.ndarray]:
    """Shared preparation of the keypoint descriptors (eqs. 6.61-6.65): validated keypoints
    ``(M,)``, the spectrum (``2K + 1`` eigenpairs computed when None, K defaulting to 25 as in
    section 7.3.1), ``K`` and the times ``(tau,)`` (``multiscale_times`` when None)."""
    if keypoints is None:
        raise ParameterError(f"the {who!r} descriptor needs keypoints (0-based vertex ids)")
    kp = _check_ids(keypoints, shape.n_vertices, "keypoints")
    if kp.size == 0:
        raise ParameterError(f"the {who!r} descriptor needs at least one keypoint")
    if times is not None:
        check_times(times)
    if spectrum is None:
        kk = 25 if K is None else K
        if isinstance(kk, bool) or not isinstance(kk, (int, np.integer)) or kk < 1:
            raise ParameterError(f"K must be a positive integer, got {kk!r}")
        spectrum = shape_spectrum(
            shape, min(2 * kk + 1, shape.n_vertices), weighting=weighting, laplacian=laplacian
        )
        K = min(kk, spectrum.k - 1)
    if spectrum.n_vertices != shape.n_vertices:
        raise ParameterError(
            f"the spectrum has {spectrum.n_vertices} vertices, the shape {shape.n_vertices}"
        )
    vals, _ = spectral_basis(spectrum, K)
    K = vals.size
    t = (
        multiscale_times(spectrum, n_times, K, alpha=alpha, ratio=time_ratio)
        if times is None
        else check_times(times)
    )
    return spectrum, K, t, kp
