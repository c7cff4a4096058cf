"""Spectral matching of Leordeanu and Hebert 2005: the principal eigenvector of the
association-graph affinity (pairwise consistency plus unary similarity on the diagonal) scores
the candidate matches, which are then discretized greedily under the one-to-one constraint."""

from __future__ import annotations

import numpy as np

from shape_toolkit.api.interfaces import SparseMatcher
from shape_toolkit.plugins._params import ASSOCIATION
from shape_toolkit.plugins.matching.association import THESIS_SPARSE, AssociationGraph, AssociationMatcherBase

__all__ = ["SpectralMatcher"]


class SpectralMatcher(AssociationMatcherBase, SparseMatcher):
    """Leordeanu-Hebert spectral relaxation on the association graph of section 7.2.1."""

    presets = {"thesis": dict(THESIS_SPARSE)}
    parameter_constraints = ASSOCIATION

    def __init__(
        self,
        k: int = 20,
        time: float | None = None,
        sigma: float = 0.3,
        adf_ratio: float = 2.0,
        max_candidates: int = 8,
        min_score: float = 0.1,
        orientation: str = "preserving",
        spectrum: str = "lbo",
    ):
        self.k = k
        self.time = time
        self.sigma = sigma
        self.adf_ratio = adf_ratio
        self.max_candidates = max_candidates
        self.min_score = min_score
        self.orientation = orientation
        self.spectrum = spectrum

    def _solve(self, graph: AssociationGraph) -> np.ndarray:
        M = graph.affinity
        _, vecs = np.linalg.eigh(M)  # N is small (candidate matches of sparse keypoints)
        x = vecs[:, -1]
        return np.abs(x) if x.sum() >= 0 else np.abs(-x)
