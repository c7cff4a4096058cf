"""Multi-scale heat distance descriptor (thesis 6.6.3.2, eqs. 6.64-6.65)."""

from __future__ import annotations

import numpy as np

from shape_toolkit.api.interfaces import Descriptor
from shape_toolkit.api.params import Options, Param
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.features.heat import NORMALIZATIONS, heat_distances
from shape_toolkit.plugins.descriptors.heat_spectrum import KeypointHeatMixin


class HeatDistanceDescriptor(KeypointHeatMixin, Descriptor):
    """Heat distances ``d_h(v_i, p_m; t_1..t_tau)`` from every vertex to each of the ``M``
    keypoints, ``tau x M`` values per vertex, returned ``(n, M * tau)`` keypoint-major (columns
    ``m * tau .. (m + 1) * tau - 1`` belong to keypoint ``m``), ready for
    :func:`shape_toolkit.features.descriptor_score.descriptor_matching_score` (eq. 6.66) with ``n_times = tau``.

    ``normalization`` picks the metric (:data:`shape_toolkit.features.heat.NORMALIZATIONS`); the thesis uses the
    unit hyper-sphere distance of eq. 6.43 (the default). Times and declared spectrum as for
    ``heat-diffusion`` (scree rule with ``K = 25``, section 7.3.1). Needs ``keypoints``.
    To compare two shapes, give both the same ``times``: from :meth:`descriptor_times` on one of
    them, or :func:`shape_toolkit.features.scales.pair_times`.

    Preset ``thesis`` (7.3.1): the defaults spelled out, which are the text's: ``K = 25``, ``tau = 5``, ``t_1``
    by the scree rule and logarithmically increasing times, unit hyper-sphere distance (eq. 6.43), Gaussian
    graph ``D - W`` without mass.
    """

    _who = "heat-distance"
    presets = {"thesis": {"K": 25, "n_times": 5, "times": None, "normalization": "unit-sphere",
                          "weighting": "gaussian", "laplacian": "combinatorial"}}
    parameter_constraints = {
        **KeypointHeatMixin.parameter_constraints,
        "normalization": Param(Options(*NORMALIZATIONS), doc="metric of the heat distances (eq. 6.43: unit-sphere)"),
    }

    def __init__(
        self,
        times: list[float] | None = None,
        n_times: int = 5,
        K: int | None = None,
        normalization: str = "unit-sphere",
        alpha: float = 0.95,
        time_ratio: float = 2.0,
        weighting: str = "gaussian",
        laplacian: str = "combinatorial",
    ):
        self.times = times
        self.n_times = n_times
        self.K = K
        self.normalization = normalization
        self.alpha = alpha
        self.time_ratio = time_ratio
        self.weighting = weighting
        self.laplacian = laplacian

    def output_width(self, n_keypoints: int | None = None) -> int | None:
        """``M tau`` for ``M`` keypoints (None when none are given: the descriptor then refuses to run)."""
        return None if n_keypoints is None else int(n_keypoints) * self.n_times_out()

    def compute(
        self, shape: Shape, *, spectrum: Spectrum | None = None, keypoints: np.ndarray | None = None
    ) -> np.ndarray:
        """Descriptor ``(n, M * tau)`` float64."""
        spectrum, K, t, kp = self.inputs(shape, spectrum, keypoints)
        D = heat_distances(spectrum, t, kp, None, normalization=self.normalization, K=K)
        return np.ascontiguousarray(D.transpose(2, 1, 0)).reshape(shape.n_vertices, -1)
