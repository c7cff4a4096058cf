"""Multi-scale heat diffusion descriptor (thesis 6.6.3.1, eqs. 6.61-6.63)."""

from __future__ import annotations

import numpy as np

from shape_toolkit.api.interfaces import Descriptor
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.features.heat import heat_kernel, heat_kernel_signature
from shape_toolkit.plugins.descriptors.heat_spectrum import KeypointHeatMixin


class HeatDiffusionDescriptor(KeypointHeatMixin, Descriptor):
    """Heat from each of the ``M`` keypoints ``h(v_i, p_m; t_1..t_tau)`` plus self-diffusion
    ``h(i, i; t_1..t_tau)``: ``tau x (M + 1)`` values per vertex, returned ``(n, (M + 1) * tau)``
    keypoint-major (columns ``m * tau .. (m + 1) * tau - 1`` belong to keypoint ``m``; the last
    ``tau`` columns are the self-diffusion).

    ``times`` None: ``n_times`` scales from the scree rule (``alpha(K, t_1) = alpha``,
    ``t_i = t_1 time_ratio^(i-1)``, section 7.3.1). Declared spectrum (:meth:`spectrum_spec`):
    ``2K + 1`` eigenpairs of the Gaussian-weighted combinatorial Laplacian, ``K = 25`` when None.
    Needs ``keypoints``. To compare two shapes, give both the same ``times``: from
    :meth:`descriptor_times` on one of them, or :func:`shape_toolkit.features.scales.pair_times`.

    Preset ``thesis`` (section 7.5: "tau = 5 and {t_1, ..., t_5} = {0, 20, 40, 80, 100}", ``K = 25`` of 7.3.1):
    absolute times on the Gaussian graph's ``D - W`` without mass, ``t = 0`` (the identity kernel) included.
    Absolute times mean another scale on every mesh (see ``adf-maxima``); the default times are scale-free.
    """

    presets = {"thesis": {"times": [0.0, 20.0, 40.0, 80.0, 100.0], "K": 25, "weighting": "gaussian",
                          "laplacian": "combinatorial"}}

    _who = "heat-diffusion"

    def __init__(
        self,
        times: list[float] | None = None,
        n_times: int = 5,
        K: int | None = None,
        alpha: float = 0.95,
        time_ratio: float = 2.0,
        weighting: str = "gaussian",
        laplacian: str = "combinatorial",
    ):
        self.times = times
        self.n_times = n_times
        self.K = K
        self.alpha = alpha
        self.time_ratio = time_ratio
        self.weighting = weighting
        self.laplacian = laplacian

    def output_width(self, n_keypoints: int | None = None) -> int | None:
        """``(M + 1) tau`` for ``M`` keypoints (None when none are given: the descriptor then refuses to run)."""
        return None if n_keypoints is None else (int(n_keypoints) + 1) * self.n_times_out()

    def compute(
        self, shape: Shape, *, spectrum: Spectrum | None = None, keypoints: np.ndarray | None = None
    ) -> np.ndarray:
        """Descriptor ``(n, (M + 1) * tau)`` float64."""
        spectrum, K, t, kp = self.inputs(shape, spectrum, keypoints)
        H = heat_kernel(spectrum, t, rows=None, cols=kp, K=K)  # (tau, n, M)
        self_diff = heat_kernel_signature(spectrum, t, K=K)  # (n, tau)
        out = np.concatenate([H.transpose(1, 2, 0), self_diff[:, None, :]], axis=1)
        return out.reshape(shape.n_vertices, -1)
