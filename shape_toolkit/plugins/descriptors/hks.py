"""Multi-scale heat kernel signature ``h(i, i; t)`` (thesis eq. 6.32; Sun et al. 2009)."""

from __future__ import annotations

import numpy as np

from shape_toolkit.api.hookspecs import hookimpl
from shape_toolkit.api.interfaces import Descriptor
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.errors import ParameterError
from shape_toolkit.features.heat import check_times, default_times, heat_kernel_signature, shape_spectrum


class HKSDescriptor(Descriptor):
    """Heat kernel signature at ``n_times`` log-spaced scales (or the given ``times``).

    Without a spectrum, ``K + 1`` eigenpairs (``K`` defaults to 100) of the combinatorial
    Laplacian of the Gaussian-weighted graph are computed (:func:`shape_toolkit.features.heat.shape_spectrum`);
    with one, ``K=None`` uses all its non-null eigenpairs. ``times=None`` spans
    ``[4 ln10 / lambda_K, 4 ln10 / lambda_2]`` (:func:`shape_toolkit.features.heat.default_times`).
    ``scale='trace'`` divides by the heat trace (scale-normalised HKS); ``log`` takes the log.
    Output ``(n, n_times)``; ``keypoints`` are ignored.
    """

    def __init__(
        self,
        n_times: int = 16,
        times: list[float] | None = None,
        K: int | None = None,
        scale: str = "none",
        log: bool = False,
        weighting: str = "gaussian",
        laplacian: str = "combinatorial",
    ):
        self.n_times = n_times
        self.times = times
        self.K = K
        self.scale = scale
        self.log = log
        self.weighting = weighting
        self.laplacian = laplacian

    def compute(
        self, shape: Shape, *, spectrum: Spectrum | None = None, keypoints: np.ndarray | None = None
    ) -> np.ndarray:
        """HKS ``(n, T)`` float64 of ``shape``."""
        if self.times is not None:
            check_times(self.times)
        if spectrum is None:
            K = 100 if self.K is None else self.K
            spectrum = shape_spectrum(
                shape, min(K + 1, shape.n_vertices), weighting=self.weighting,
                laplacian=self.laplacian,
            )
            K = min(K, spectrum.k - 1) if self.K is None else K
        else:
            K = self.K
        if spectrum.n_vertices != shape.n_vertices:
            raise ParameterError(
                f"the spectrum has {spectrum.n_vertices} vertices, the shape {shape.n_vertices}"
            )
        times = default_times(spectrum, self.n_times, K) if self.times is None else self.times
        out = heat_kernel_signature(spectrum, times, K=K, scale=self.scale)
        if self.log:
            out = np.log(np.maximum(out, np.finfo(float).tiny))
        return out


@hookimpl
def toolkit_descriptors() -> dict[str, type]:
    return {"hks": HKSDescriptor}
