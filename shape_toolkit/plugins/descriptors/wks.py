"""Wave kernel signature (Aubry, Schlickewei and Cremers 2011), as offered by peer toolkits."""

from __future__ import annotations

import numpy as np

from shape_toolkit.api.hookspecs import hookimpl
from shape_toolkit.api.interfaces import Descriptor
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.errors import ParameterError
from shape_toolkit.features.heat import shape_spectrum, spectral_basis


class WKSDescriptor(Descriptor):
    """WKS at ``n_energies`` log-energies ``e`` evenly spaced in
    ``[log lambda_2 + 2 sigma, log lambda_K - 2 sigma]`` with ``sigma = variance * (log lambda_K -
    log lambda_2) / n_energies``::

        WKS(i, e) = sum_k u_ik^2 exp(-(e - log lambda_k)^2 / 2 sigma^2) / sum_k exp(...)

    over the ``K`` first non-null eigenpairs (spectrum defaults as for ``hks``: ``K = 100``,
    Gaussian-weighted combinatorial Laplacian). Output ``(n, n_energies)``.
    """

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

    def compute(
        self, shape: Shape, *, spectrum: Spectrum | None = None, keypoints: np.ndarray | None = None
    ) -> np.ndarray:
        """WKS ``(n, n_energies)`` float64 of ``shape``."""
        if not isinstance(self.n_energies, (int, np.integer)) or self.n_energies < 1:
            raise ParameterError(f"n_energies must be a positive integer, got {self.n_energies!r}")
        if not self.variance > 0:
            raise ParameterError(f"variance must be positive, got {self.variance!r}")
        K = self.K
        if spectrum is None:
            kk = 100 if K is None else K
            spectrum = shape_spectrum(
                shape, min(kk + 1, shape.n_vertices), weighting=self.weighting,
                laplacian=self.laplacian,
            )
        if spectrum.n_vertices != shape.n_vertices:
            raise ParameterError(
                f"the spectrum has {spectrum.n_vertices} vertices, the shape {shape.n_vertices}"
            )
        vals, U = spectral_basis(spectrum, K)
        if vals.size < 2 or not vals[0] > 0:
            raise ParameterError("the WKS needs at least two positive eigenvalues")
        loge = np.log(vals)
        sigma = self.variance * (loge[-1] - loge[0]) / self.n_energies
        e = np.linspace(loge[0] + 2 * sigma, loge[-1] - 2 * sigma, int(self.n_energies))
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


@hookimpl
def toolkit_descriptors() -> dict[str, type]:
    return {"wks": WKSDescriptor}
