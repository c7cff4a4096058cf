"""Diffusion times and scales of the heat-kernel methods (thesis 6.4, 7.3.1).

Validation of times, the default log-spaced times (Sun et al. 2009), the scree ratio
``alpha(K, t)`` (eq. 6.39) and what follows from it: the minimum time for a dimension, the
dimension for a time, the pair rule of section 7.3.1 and the multi-scale descriptor times.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from shape_toolkit.core.spectrum import Spectrum, null_count
from shape_toolkit.errors import ParameterError
from shape_toolkit.features.basis import shifted_weights, spectral_basis

__all__ = [
    "check_times",
    "check_heat_times",
    "scalar_time",
    "default_times",
    "scree_alpha",
    "min_time_for_dimension",
    "dimension_for_time",
    "pair_scale",
    "pair_times",
    "multiscale_times",
    "descriptor_times",
]


def check_times(times: float | Sequence[float] | np.ndarray) -> np.ndarray:
    """Validate diffusion times: a float64 ``(T,)`` array of finite values ``>= 0``. ``t = 0`` is allowed (the
    thesis's descriptor times ``{0, 20, 40, 80, 100}``, section 7.5): ``exp(-0 L)`` is the identity, so the
    (deflated, truncated) kernel at ``t = 0`` is the projection ``sum_k u_ik u_jk`` onto the eigenvectors used;
    nothing here divides by ``t``."""
    if isinstance(times, (str, bytes, dict)):
        raise ParameterError(f"diffusion times must be a number or a list of numbers, got {times!r}")
    try:
        t = np.atleast_1d(np.asarray(times, dtype=np.float64)).ravel()
    except (TypeError, ValueError):
        raise ParameterError(f"diffusion times must be a number or a list of numbers, got {times!r}") from None
    if t.size == 0:
        raise ParameterError("at least one diffusion time is needed")
    if not np.all(np.isfinite(t)) or np.any(t < 0):
        bad = t[~(np.isfinite(t) & (t >= 0))][0]
        raise ParameterError(f"diffusion times must be non-negative and finite, got {float(bad)!r}")
    return t



def check_heat_times(times: float | Sequence[float] | np.ndarray, spectrum: Spectrum, K: int | None,
                     who: str) -> np.ndarray:
    """:func:`check_times`, and no time at which the heat ``exp(-t lambda)`` of every eigenpair a kernel uses (the
    first ``K`` non-null ones of ``spectrum``; None: all) underflows below the smallest normal double
    (``t lambda_min > -ln tiny``, about 708): its column would be zero, or NaN once divided by the vanished heat
    trace. ``who`` names the descriptor in the :class:`ParameterError`."""
    t = check_times(times)
    vals, _ = spectral_basis(spectrum, K, deflate=True)
    lam = float(vals.min()) if vals.size else 0.0
    if lam > 0:
        limit = -np.log(np.finfo(float).tiny) / lam
        if np.any(t > limit):
            raise ParameterError(
                f"{who}: times must be at most {limit:.6g} on this shape (beyond it the heat exp(-t lambda) of "
                f"every eigenpair underflows), got {float(t[t > limit][0]):g}")
    return t

def scalar_time(t: float) -> float:
    """One diffusion time, validated by :func:`check_times`."""
    tt = check_times(t)
    if tt.size != 1:
        raise ParameterError("a single diffusion time is expected here")
    return float(tt[0])


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


# -- scale and dimension (6.4) -----------------------------------------------------------------
def _eigen_array(spectrum_or_values: Spectrum | np.ndarray) -> tuple[np.ndarray, int]:
    if isinstance(spectrum_or_values, Spectrum):
        vals, _ = spectral_basis(spectrum_or_values)
        return vals, spectrum_or_values.n_vertices
    lam = np.sort(np.asarray(spectrum_or_values, dtype=np.float64).ravel())
    null = null_count(lam)
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
    t = scalar_time(t)
    vals, n_spec = _eigen_array(spectrum)
    n = n_spec if n is None else int(n)
    avail = vals.size
    if isinstance(K, bool) or not isinstance(K, (int, np.integer)) or not 1 <= K <= avail:
        raise ParameterError(f"K must be an integer in [1, {avail}] (non-null eigenpairs), got {K}")
    w = shifted_weights(vals, t)
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
    tt = scalar_time(t)
    w = shifted_weights(vals, tt)
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
    if np.log(t1) + (int(n_times) - 1) * np.log(float(ratio)) > np.log(np.finfo(np.float64).max):
        raise ParameterError(f"the times t_1 ratio^(n_times - 1) overflow float64 (t_1 = {t1:.3g}, ratio {ratio:g}, "
                             f"n_times {n_times}): fewer times or a smaller ratio")
    return t1 * float(ratio) ** np.arange(int(n_times))




def descriptor_times(
    spectrum: Spectrum,
    K: int | None,
    times: float | Sequence[float] | np.ndarray | None,
    *,
    n_times: int = 5,
    alpha: float = 0.95,
    ratio: float = 2.0,
) -> tuple[int, np.ndarray]:
    """``(K, times (tau,))`` of a multi-scale keypoint descriptor (eqs. 6.61-6.65, section 7.3.1):
    ``K`` the non-null eigenpairs used (None: all those of ``spectrum``), ``times`` validated, or
    :func:`multiscale_times` when None."""
    if times is not None:
        t = check_times(times)
    vals, _ = spectral_basis(spectrum, K)
    K = int(vals.size)
    if times is None:
        t = multiscale_times(spectrum, n_times, K, alpha=alpha, ratio=ratio)
    return K, t
