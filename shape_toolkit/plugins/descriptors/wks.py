"""Wave kernel signature (Aubry, Schlickewei and Cremers 2011), as offered by peer toolkits."""

from __future__ import annotations

import numpy as np

from shape_toolkit.api.interfaces import Descriptor
from shape_toolkit.api.params import Param
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.errors import ParameterError
from shape_toolkit.features.basis import spectral_basis
from shape_toolkit.plugins._params import LAPLACIAN, POSITIVE, POSITIVE_INT, WEIGHTING
from shape_toolkit.plugins.descriptors.heat_spectrum import K_PARAM, SignatureSpectrumMixin, own_spectrum

__all__ = ["WKSDescriptor", "wave_kernel_signature", "spectrum_wave_kernel_signature"]


def wave_kernel_signature(
    vals: np.ndarray, U: np.ndarray, n_energies: int = 100, variance: float = 7.0,
    log_range: tuple[float, float] | None = None,
) -> np.ndarray:
    """WKS ``(n, n_energies)`` of the non-null eigenpairs ``vals`` ``(K,)``, ``U`` ``(n, K)``
    (ascending, orthonormal in the spectrum's inner product): log-energies ``e`` evenly spaced in
    ``[log vals[0] + 2 sigma, log vals[-1] - 2 sigma]``, ``sigma = variance * (log vals[-1] -
    log vals[0]) / n_energies``, each column normalized by its sum of Gaussian weights (Aubry et
    al. 2011). ``log_range`` replaces ``(log vals[0], log vals[-1])`` there: two shapes given the same range
    (their eigenvalues in common units) get the same energies. The one place of the WKS formula: the
    ``wks`` plugin and ``fmap-zoomout`` call it."""
    vals = np.asarray(vals, dtype=np.float64)
    if vals.size < 2 or not vals[0] > 0:
        raise ParameterError("the WKS needs at least two positive eigenvalues")
    loge = np.log(vals)
    lo, hi = (loge[0], loge[-1]) if log_range is None else (float(log_range[0]), float(log_range[1]))
    with np.errstate(over="ignore", under="ignore"):
        sigma = variance * (hi - lo) / n_energies
        width2 = 2 * sigma**2
    if not variance > 0 or (sigma != 0 and not 0 < width2 < np.inf):  # the filters' squared width in float64
        raise ParameterError(f"the WKS variance {variance!r} gives filters float64 cannot hold (their squared width "
                             f"{'overflows' if variance > 1 else 'underflows'}): a few energy spacings, e.g. 7")
    e = np.linspace(lo + 2 * sigma, hi - 2 * sigma, int(n_energies))
    if sigma == 0:
        sigma = 1.0
    G = np.exp(-((e[None, :] - loge[:, None]) ** 2) / (2 * sigma**2))  # (K, E)
    norm = G.sum(axis=0)
    norm[norm == 0] = 1.0
    out = np.empty((U.shape[0], e.size))
    for s in range(0, U.shape[0], 16384):
        b = U[s : s + 16384]
        out[s : s + 16384] = (b * b) @ G
    return out / norm[None, :]


def spectrum_wave_kernel_signature(
    spectrum: Spectrum, n_energies: int = 100, variance: float = 7.0, band: float = 1.0,
) -> np.ndarray:
    """WKS ``(n, n_energies)`` on the first ``round(band * K)`` (at least 2) of the ``K`` non-null eigenpairs of
    ``spectrum`` (``band`` 1: every one): ``fmap-zoomout``'s default descriptor, on its own Laplace-Beltrami
    spectrum (with the mass matrix, which does not depend on the sampling as the ``wks`` plugin's graph
    spectrum does)."""
    vals, U = spectral_basis(spectrum)
    if band < 1.0:
        K = max(2, int(round(band * vals.size)))
        vals, U = vals[:K], U[:, :K]
    return wave_kernel_signature(vals, U, n_energies, variance)


class WKSDescriptor(SignatureSpectrumMixin, Descriptor):
    """WKS at ``n_energies`` log-energies ``e`` evenly spaced in
    ``[log lambda_2 + 2 sigma, log lambda_K - 2 sigma]`` with ``sigma = variance * (log lambda_K -
    log lambda_2) / n_energies``::

        WKS(i, e) = sum_k u_ik^2 exp(-(e - log lambda_k)^2 / 2 sigma^2) / sum_k exp(...)

    over the ``K`` first non-null eigenpairs (declared spectrum as for ``hks``: ``K + 1``
    eigenpairs, ``K = 100`` when None, Gaussian-weighted combinatorial Laplacian). Output
    ``(n, n_energies)``.
    """

    parameter_constraints = {
        "n_energies": Param(POSITIVE_INT, doc="number of log-energies"),
        "K": K_PARAM,
        "variance": Param(POSITIVE, doc="width of the energy filters, in energy spacings"),
        "weighting": WEIGHTING,
        "laplacian": LAPLACIAN,
    }

    def __init__(
        self,
        n_energies: int = 100,
        K: int | None = None,
        variance: float = 7.0,
        weighting: str = "gaussian",
        laplacian: str = "combinatorial",
    ):
        self.n_energies = n_energies
        self.K = K
        self.variance = variance
        self.weighting = weighting
        self.laplacian = laplacian

    def output_width(self, n_keypoints: int | None = None) -> int | None:
        """One column per energy."""
        return int(self.n_energies)

    def compute(
        self, shape: Shape, *, spectrum: Spectrum | None = None, keypoints: np.ndarray | None = None
    ) -> np.ndarray:
        """WKS ``(n, n_energies)`` float64 of ``shape``."""
        spectrum = own_spectrum(self, shape, spectrum)
        vals, U = spectral_basis(spectrum, self.K)
        return wave_kernel_signature(vals, U, int(self.n_energies), float(self.variance))
