"""Keypoint matching by replicator dynamics on the association graph (thesis 7.2.1; Pelillo
1999): the candidate matches that survive are a (weighted) maximal clique, i.e. a large set of
mutually consistent matches; like every intrinsic method it is defined up to the shape's
symmetries."""

from __future__ import annotations

import numpy as np

from shape_toolkit.api.interfaces import SparseMatcher
from shape_toolkit.api.params import Param
from shape_toolkit.plugins._params import ASSOCIATION, POSITIVE_INT
from shape_toolkit.plugins.matching.association import THESIS_SPARSE, AssociationGraph, AssociationMatcherBase

__all__ = ["ReplicatorMatcher", "replicator_dynamics"]



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
    parameter_constraints = {**ASSOCIATION, "max_iter": Param(POSITIVE_INT, doc="replicator iterations")}

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
