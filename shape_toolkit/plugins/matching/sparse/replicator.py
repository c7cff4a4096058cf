"""Keypoint matching by replicator dynamics on the association graph (thesis 7.2.1; Pelillo
1999): the candidate matches that survive are a (weighted) maximal clique, i.e. a large set of
mutually consistent matches; like every intrinsic method it is defined up to the shape's
symmetries."""

from __future__ import annotations

import numpy as np

from shape_toolkit.api.interfaces import SparseMatcher
from shape_toolkit.api.params import Interval, Param
from shape_toolkit.plugins._params import ASSOCIATION, POSITIVE_INT
from shape_toolkit.plugins.matching.association import THESIS_SPARSE, AssociationGraph, AssociationMatcherBase

__all__ = ["ReplicatorMatcher", "replicator_dynamics", "SIGMA", "TIME"]

#: the consistency kernel's width: unit-sphere heat distances lie in [0, pi] and their differences carry the
#: rounding of arccos, ~sqrt(eps) = 1.5e-8 radians, so a narrower kernel measures rounding (and sigma^2 underflows
#: towards 1e-154); above 1e8, Delta^2 / (2 sigma^2) <= 5e-16 is below eps and every weight is exactly 1
SIGMA = Param(Interval(float, 1e-8, 1e8), doc="width of the pairwise consistency kernel in radians of unit-sphere "
              "heat distance (in [1e-8, 1e8]: distances lie in [0, pi] with rounding ~1.5e-8; from 1e8 on every "
              "weight is exactly 1, as for any larger sigma, which would only overflow sigma^2)")
#: the heat kernels' diffusion time (t lambda_k must stay finite)
TIME = Param(None, Interval(float, 0, 1e100, closed="right"), doc="diffusion time of the heat-kernel affinities "
             "(None: from the spectrum; at most 1e100: once t lambda_1 > 745 every non-constant term exp(-t lambda) "
             "is 0 in float64, so larger times change nothing unless lambda_1 < 1e-97, while t lambda_k must stay "
             "finite, below 1.8e308)")


def replicator_dynamics(
    A: np.ndarray, x0: np.ndarray | None = None, max_iter: int = 2000, tol: float = 1e-10
) -> np.ndarray:
    """Discrete replicator equation ``x <- x * (A x) / (x^T A x)`` on the simplex from ``x0``
    (default the barycenter); returns the limit ``(N,)`` (a local maximizer of ``x^T A x``)."""
    N = A.shape[0]
    x = np.full(N, 1.0 / N) if x0 is None else np.asarray(x0, dtype=np.float64) / np.sum(x0)
    for _ in range(max_iter):
        Ax = A @ x
        s = float(x @ Ax)
        if s <= 0:
            break
        x_new = x * Ax / s
        if np.abs(x_new - x).sum() < tol:
            x = x_new
            break
        x = x_new
    return x


class ReplicatorMatcher(AssociationMatcherBase, SparseMatcher):
    """Association graph (spectral-distance consistency, ADF pruning; see
    :func:`shape_toolkit.plugins.matching.association.association_graph`) + replicator dynamics on ``W + I/2``
    (Pelillo's regularization, whose strict maximizers are maximal cliques). Matches are read
    from the support of the limit (``x > min_score * max(x)``), one-to-one, most weight first."""

    presets = {"thesis": dict(THESIS_SPARSE)}
    parameter_constraints = {**ASSOCIATION, "time": TIME, "sigma": SIGMA,
                             "max_iter": Param(POSITIVE_INT, doc="replicator iterations")}

    def __init__(
        self,
        k: int = 20,
        time: float | None = None,
        sigma: float = 0.3,
        adf_ratio: float = 2.0,
        max_candidates: int = 8,
        min_score: float = 0.05,
        max_iter: int = 2000,
        orientation: str = "preserving",
        spectrum: str = "lbo",
    ):
        self.k = k
        self.time = time
        self.sigma = sigma
        self.adf_ratio = adf_ratio
        self.max_candidates = max_candidates
        self.min_score = min_score
        self.max_iter = max_iter
        self.orientation = orientation
        self.spectrum = spectrum

    def _solve(self, graph: AssociationGraph) -> np.ndarray:
        A = graph.W + 0.5 * np.eye(len(graph.nodes))
        return replicator_dynamics(A, graph.unary, int(self.max_iter))
