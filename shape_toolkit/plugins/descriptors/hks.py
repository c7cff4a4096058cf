"""Multi-scale heat kernel signature ``h(i, i; t)`` (thesis eq. 6.32; Sun et al. 2009)."""

from __future__ import annotations

import numpy as np

from shape_toolkit.api.interfaces import Descriptor
from shape_toolkit.api.params import Interval, Options, Param
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.features.heat import heat_kernel_signature
from shape_toolkit.features.scales import check_heat_times, default_times
from shape_toolkit.plugins._params import LAPLACIAN, TIMES, WEIGHTING
from shape_toolkit.plugins.descriptors.heat_spectrum import K_PARAM, MAX_TIMES, SignatureSpectrumMixin, own_spectrum


class HKSDescriptor(SignatureSpectrumMixin, Descriptor):
    """Heat kernel signature at ``n_times`` log-spaced scales (or the given ``times``).

    Declared spectrum (:meth:`spectrum_spec`): ``K + 1`` eigenpairs (``K`` = 100 when None, capped
    at the vertex count) of the combinatorial Laplacian of the Gaussian-weighted graph; a longer
    spectrum given by the caller is truncated to it. ``times=None`` spans
    ``[4 ln10 / lambda_K, 4 ln10 / lambda_2]`` (:func:`shape_toolkit.features.scales.default_times`).
    ``times`` may also be one number (one time). A time so large that ``exp(-t lambda)`` falls below the
    smallest normal double for every eigenpair used (``t lambda_min > 708``) is refused: the column would be
    zero (NaN once divided by the vanished heat trace). ``scale='trace'`` divides by the heat trace
    (scale-normalised HKS); ``log`` takes the log. Output ``(n, n_times)``; ``keypoints`` are ignored.
    """

    parameter_constraints = {
        "n_times": Param(Interval(int, 1, MAX_TIMES), doc="number of log-spaced times when times is None (at most "
                         "1000: the HKS is a combination of the K eigenpairs' exp(-lambda t) phi^2, so past K times "
                         "its columns repeat information, and each takes 8 bytes a vertex)"),
        "times": Param(None, *TIMES, doc="diffusion times, one or a list (None: n_times spanning the spectrum)"),
        "K": K_PARAM,
        "scale": Param(Options("none", "trace"), doc="'trace': divide by the heat trace (scale-normalised HKS)"),
        "log": Param(bool, doc="take the logarithm"),
        "weighting": WEIGHTING,
        "laplacian": LAPLACIAN,
    }

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

    def output_width(self, n_keypoints: int | None = None) -> int | None:
        """One column per time (a single number is one time)."""
        if self.times is None:
            return int(self.n_times)
        return int(np.size(self.times))

    def compute(
        self, shape: Shape, *, spectrum: Spectrum | None = None, keypoints: np.ndarray | None = None
    ) -> np.ndarray:
        """HKS ``(n, T)`` float64 of ``shape``."""
        spectrum = own_spectrum(self, shape, spectrum)
        K = self.K  # None: every non-null eigenpair of the declared spectrum (K capped at n - 1)
        times = (default_times(spectrum, self.n_times, K) if self.times is None
                 else check_heat_times(self.times, spectrum, K, type(self).__name__))
        out = heat_kernel_signature(spectrum, times, K=K, scale=self.scale)
        if self.log:
            out = np.log(np.maximum(out, np.finfo(float).tiny))
        return out
