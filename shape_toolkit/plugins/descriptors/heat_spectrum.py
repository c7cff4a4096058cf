"""What the spectral descriptors share (not a plugin itself: no entry point): the spectrum they
declare and how they resolve ``K``; for the keypoint heat descriptors also the times and the keypoints
(thesis 6.6.3, 7.3.1)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from shape_toolkit.api.params import Interval, Param
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum, null_count
from shape_toolkit.errors import ParameterError
from shape_toolkit.features.scales import check_heat_times, check_times, descriptor_times
from shape_toolkit.plugins._params import LAPLACIAN, POSITIVE_INT, TIMES, WEIGHTING
from shape_toolkit.spectra import SpectrumSpec, default_spec
from shape_toolkit.validation import check_vertex_ids

#: ``K`` (non-null eigenpairs) of the keypoint descriptors when not given (section 7.3.1)
DEFAULT_K = 25

#: ``K`` of the per-vertex signatures (``hks``, ``wks``) when not given
SIGNATURE_K = 100


#: ``K`` of a spectral descriptor: None (the plugin's default) or a count of non-null eigenpairs
K_PARAM = Param(None, POSITIVE_INT, doc="non-null eigenpairs used (None: the plugin's default)")
#: most diffusion times a heat descriptor takes from its ``n_times`` (hks, heat-diffusion, heat-distance)
MAX_TIMES = 1000


def check_K(K: object, default: int) -> int:
    """``K`` as an int (``default`` when None; the value is declared and checked as :data:`K_PARAM`)."""
    return int(default if K is None else K)  # type: ignore[call-overload]


def own_spectrum(plugin: object, shape: Shape, spectrum: Spectrum | None) -> Spectrum:
    """The plugin's declared spectrum (given one checked, or computed), truncated to the declared
    ``k``: the output does not depend on how many extra eigenpairs a caller passed."""
    spec: SpectrumSpec = plugin.spectrum_spec()  # type: ignore[attr-defined]
    spectrum = plugin._spectrum(shape, spectrum)  # type: ignore[attr-defined]
    return spectrum.truncated(min(spectrum.k, spec.for_shape(shape).k))


def keypoint_heat_spec(K: int | None, weighting: str, laplacian: str) -> SpectrumSpec:
    """``2K + 1`` eigenpairs (``K`` = 25 when None) of the ``laplacian`` of the ``weighting`` graph,
    no mass matrix: the default of the thesis for heat descriptors (sections 6.4.1, 6.6.1); the
    eigenpairs beyond ``K`` feed the scree rule of the default times."""
    return default_spec(2 * check_K(K, DEFAULT_K) + 1, "graph", weighting=weighting, laplacian=laplacian)


class SignatureSpectrumMixin:
    """Spectrum declaration of the per-vertex signatures ``hks`` and ``wks`` (parameters ``K``,
    ``weighting``, ``laplacian``)."""

    def spectrum_spec(self) -> SpectrumSpec:
        """``K + 1`` eigenpairs (``K`` = :data:`SIGNATURE_K` when None) of the ``laplacian`` of the
        ``weighting`` graph, no mass matrix."""
        return default_spec(check_K(self.K, SIGNATURE_K) + 1, "graph",  # type: ignore[attr-defined]
                            weighting=self.weighting, laplacian=self.laplacian)  # type: ignore[attr-defined]


def keypoint_heat_inputs(
    shape: Shape,
    spectrum: Spectrum,
    keypoints: np.ndarray | Sequence[int] | None,
    *,
    K: int | None,
    times: Sequence[float] | None,
    n_times: int,
    alpha: float,
    time_ratio: float,
    who: str,
) -> tuple[int, np.ndarray, np.ndarray]:
    """``(K, times (tau,), keypoints (M,))`` of a keypoint heat descriptor on its (declared)
    ``spectrum``: ``K`` capped at the non-null eigenpairs, times by the scree rule when None."""
    if keypoints is None:
        raise ParameterError(f"the {who!r} descriptor needs keypoints (0-based vertex ids)")
    kp = check_vertex_ids(keypoints, shape.n_vertices, "keypoints")
    if kp.size == 0:
        raise ParameterError(f"the {who!r} descriptor needs at least one keypoint")
    avail = spectrum.k - null_count(spectrum.eigenvalues)
    kk = min(check_K(K, DEFAULT_K), avail)
    if times is not None:
        check_heat_times(times, spectrum, kk, who)
    K_used, t = descriptor_times(spectrum, kk, times, n_times=n_times, alpha=alpha, ratio=time_ratio)
    return K_used, t, kp


class KeypointHeatMixin:
    """Spectrum declaration and input resolution of the ``heat-diffusion`` / ``heat-distance``
    descriptors (parameters ``times``, ``n_times``, ``K``, ``alpha``, ``time_ratio``, ``weighting``,
    ``laplacian``)."""

    uses_keypoints = True  # each column is the heat from one keypoint

    _who = "heat descriptor"
    parameter_constraints = {
        "times": Param(None, *TIMES, doc="diffusion times (None: n_times scales from the scree rule)"),
        "n_times": Param(Interval(int, 1, MAX_TIMES), doc=f"number of times when times is None (at most {MAX_TIMES}: "
                         "heat at more times than eigenpairs repeats information, at 8 bytes a vertex each)"),
        "K": K_PARAM,
        "alpha": Param(Interval(float, 0, 1, closed="neither"), doc="scree-rule level of the first time"),
        "time_ratio": Param(Interval(float, 1, None, closed="neither"), doc="ratio of consecutive times"),
        "weighting": WEIGHTING,
        "laplacian": LAPLACIAN,
    }

    def spectrum_spec(self) -> SpectrumSpec:
        """``2K + 1`` eigenpairs of the ``laplacian`` of the ``weighting`` graph (no mass)."""
        return keypoint_heat_spec(self.K, self.weighting, self.laplacian)  # type: ignore[attr-defined]

    def n_times_out(self) -> int:
        """``tau``, the number of times (given, or the scree rule's ``n_times``)."""
        if self.times is None:  # type: ignore[attr-defined]
            return int(self.n_times)  # type: ignore[attr-defined]
        return int(np.size(self.times))  # type: ignore[attr-defined]  # one number is one time

    def inputs(
        self, shape: Shape, spectrum: Spectrum | None, keypoints: np.ndarray | Sequence[int] | None
    ) -> tuple[Spectrum, int, np.ndarray, np.ndarray]:
        """``(spectrum, K, times, keypoints)`` as :meth:`compute` uses them."""
        spectrum = own_spectrum(self, shape, spectrum)
        K, t, kp = keypoint_heat_inputs(
            shape, spectrum, keypoints, K=self.K, times=self.times, n_times=self.n_times,  # type: ignore[attr-defined]
            alpha=self.alpha, time_ratio=self.time_ratio, who=self._who,  # type: ignore[attr-defined]
        )
        return spectrum, K, t, kp

    def descriptor_times(self, shape: Shape, *, spectrum: Spectrum | None = None) -> np.ndarray:
        """The times ``(tau,)`` :meth:`compute` uses on ``shape`` (``times``, or the scree rule on
        its spectrum). To compare two shapes, compute them on one and set them on both."""
        spectrum = own_spectrum(self, shape, spectrum)
        if self.times is not None:  # type: ignore[attr-defined]
            return check_times(self.times)  # type: ignore[attr-defined]
        avail = spectrum.k - null_count(spectrum.eigenvalues)
        kk = min(check_K(self.K, DEFAULT_K), avail)  # type: ignore[attr-defined]
        return descriptor_times(
            spectrum, kk, None, n_times=self.n_times, alpha=self.alpha, ratio=self.time_ratio,  # type: ignore[attr-defined]
        )[1]
