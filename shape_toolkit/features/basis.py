"""The spectral basis the heat kernels, scales and embeddings are built from (thesis 2.6, 6.2).

One place that says which eigenpairs are "the non-null ones" of a (truncated)
:class:`~shape_toolkit.core.spectrum.Spectrum`, and in which normalisation.
"""

from __future__ import annotations

import numpy as np

from shape_toolkit.core.spectrum import Spectrum, null_count
from shape_toolkit.errors import ParameterError

__all__ = ["spectral_basis", "shifted_weights"]


def spectral_basis(
    spectrum: Spectrum, K: int | None = None, *, deflate: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """The eigenvalues ``(k,)`` and orthonormal eigenvectors ``(n, k)`` the kernel is built from:
    the null eigenpairs (:func:`~shape_toolkit.core.spectrum.null_count`) dropped when ``deflate``,
    then the first ``K`` non-null ones (None: all of them). Random-walk eigenvectors ``v`` are
    returned as the normalized ones ``D^1/2 v`` (same eigenvalues, symmetric kernel)."""
    vals = np.asarray(spectrum.eigenvalues, dtype=np.float64)
    vecs = np.asarray(spectrum.eigenvectors, dtype=np.float64)
    if spectrum.laplacian == "random-walk":
        vecs = vecs * np.sqrt(np.asarray(spectrum.degrees, dtype=np.float64))[:, None]
    null = null_count(vals)
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


def shifted_weights(vals: np.ndarray, t: float) -> np.ndarray:
    """``exp(-t (lambda_k - lambda_min))``: the heat weights up to a common factor, which the
    normalized embeddings and the scree ratios cancel; never underflows to all zeros at large ``t``."""
    return np.exp(-t * (vals - vals.min()))
