"""Reweighted random walks for graph matching (Cho, Lee and Lee 2010) on the association graph
of thesis 7.2.1: a random walk on the affinity with reweighting jumps towards a
Sinkhorn-normalized (one-to-one) version of its current state."""

from __future__ import annotations

import numpy as np

from shape_toolkit.api.interfaces import SparseMatcher
from shape_toolkit.api.params import Interval, Param
from shape_toolkit.plugins._params import ASSOCIATION, FRACTION, POSITIVE_INT
from shape_toolkit.plugins.matching.association import THESIS_SPARSE, AssociationGraph, AssociationMatcherBase

__all__ = ["RRWMMatcher", "sinkhorn"]


def sinkhorn(X: np.ndarray, n_iter: int = 30) -> np.ndarray:
    """Alternate row and column normalization of a positive matrix (towards bistochastic)."""
    X = np.maximum(X, 1e-300)
    for _ in range(n_iter):
        X = X / X.sum(axis=1, keepdims=True)
        X = X / X.sum(axis=0, keepdims=True)
    return X


class RRWMMatcher(AssociationMatcherBase, SparseMatcher):
    """RRWM: ``x <- alpha P^T x + (1 - alpha) y`` with ``P`` the affinity divided by its largest
    degree and ``y`` the Sinkhorn normalization of ``exp(inflation x / max x)`` arranged as the
    ``(P, Q)`` keypoint matrix; iterated to convergence and discretized one-to-one."""

    presets = {"thesis": dict(THESIS_SPARSE)}
    parameter_constraints = {
        **ASSOCIATION,
        "alpha": Param(FRACTION, doc="weight of the random walk against the reweighting jump"),
        "inflation": Param(Interval(float, 0, 600, closed="right"), doc="sharpness of the reweighting jump "
                           "exp(inflation x / max x) (at most 600: e^600 = 4e260 leaves the Sinkhorn sums of up to "
                           "1e47 such terms finite; exp overflows float64 at 709.8)"),
        "max_iter": Param(POSITIVE_INT, doc="iterations"),
    }

    def __init__(
        self,
        k: int = 20,
        time: float | None = None,
        sigma: float = 0.3,
        adf_ratio: float = 2.0,
        max_candidates: int = 8,
        min_score: float = 0.05,
        alpha: float = 0.2,
        inflation: float = 30.0,
        max_iter: int = 300,
        orientation: str = "preserving",
        spectrum: str = "lbo",
    ):
        self.k = k
        self.time = time
        self.sigma = sigma
        self.adf_ratio = adf_ratio
        self.max_candidates = max_candidates
        self.min_score = min_score
        self.alpha = alpha
        self.inflation = inflation
        self.max_iter = max_iter
        self.orientation = orientation
        self.spectrum = spectrum

    def _solve(self, graph: AssociationGraph) -> np.ndarray:
        W = graph.affinity
        P = W / max(float(W.sum(axis=1).max()), 1e-300)
        a, b = graph.nodes[:, 0], graph.nodes[:, 1]
        shape = (int(a.max()) + 1, int(b.max()) + 1)
        x = np.full(len(a), 1.0 / len(a))
        for _ in range(int(self.max_iter)):
            xb = P.T @ x
            Y = np.zeros(shape)
            Y[a, b] = np.exp(self.inflation * xb / max(float(xb.max()), 1e-300))
            Y = sinkhorn(Y + 1e-12 * (Y > 0))
            y = Y[a, b]
            x_new = self.alpha * xb + (1 - self.alpha) * y / max(float(y.sum()), 1e-300)
            x_new /= max(float(x_new.sum()), 1e-300)
            if np.abs(x_new - x).sum() < 1e-10:
                x = x_new
                break
            x = x_new
        return x
