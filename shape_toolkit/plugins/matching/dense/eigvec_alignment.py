"""Unsupervised dense matching of Mateus et al. 2008 (the baseline of thesis 7.5): the sign and
order of the Laplacian eigenvectors of the two shapes are aligned by comparing their
histograms (Hungarian assignment over eigenvector pairs, each with its better sign), and the
aligned embeddings are registered by EM (Algorithm 7, :mod:`shape_toolkit.plugins.matching.dense.em_registration`).

Histograms are mass-weighted (each vertex counts with its area) on area-normalized
eigenvectors, so they do not depend on the sampling density. Like every purely intrinsic
method it cannot tell left from right: a sign flip of an antisymmetric eigenvector is exactly
as good as the original.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from shape_toolkit.api.params import Param
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.plugins._params import POSITIVE_INT
from shape_toolkit.plugins.matching.dense.em_registration import Embedding, EMRegistrationMatcher

__all__ = ["EigvecAlignmentMatcher", "histogram_alignment"]


def _histograms(U: np.ndarray, w: np.ndarray, edges: np.ndarray) -> np.ndarray:
    H = np.empty((U.shape[1], edges.size - 1))
    for c in range(U.shape[1]):
        H[c] = np.histogram(U[:, c], bins=edges, weights=w)[0]
    return H / np.maximum(H.sum(axis=1, keepdims=True), 1e-300)


def histogram_alignment(
    X: np.ndarray, Y: np.ndarray, wx: np.ndarray, wy: np.ndarray, bins: int = 40
) -> tuple[np.ndarray, np.ndarray]:
    """Signed permutation ``Q`` ``(k, k)`` (``Y ~ X Q^T``) matching source eigenvectors ``X``
    ``(n, k)`` to target eigenvectors ``Y`` ``(n', k)`` by L1 distance between their
    ``wx``/``wy``-weighted histograms; also returns the ``(k, k)`` cost matrix."""
    if X.ndim != 2 or Y.ndim != 2 or X.shape[1] != Y.shape[1]:
        raise ParameterError(f"X and Y must be (n, k) and (n', k) with one k, got {X.shape} and {Y.shape}")
    r = float(max(np.abs(X).max(), np.abs(Y).max()))
    edges = np.linspace(-r, r, bins + 1)
    hx = _histograms(X, wx, edges)
    hy_pos = _histograms(Y, wy, edges)
    hy_neg = _histograms(-Y, wy, edges)
    d_pos = np.abs(hx[:, None, :] - hy_pos[None, :, :]).sum(axis=2)  # (i source, j target)
    d_neg = np.abs(hx[:, None, :] - hy_neg[None, :, :]).sum(axis=2)
    cost = np.minimum(d_pos, d_neg)
    rows, cols = linear_sum_assignment(cost)
    k = X.shape[1]
    Q = np.zeros((k, k))
    for i, j in zip(rows, cols):
        Q[j, i] = 1.0 if d_pos[i, j] <= d_neg[i, j] else -1.0
    return Q, cost


class EigvecAlignmentMatcher(EMRegistrationMatcher):
    """Mateus et al. 2008: histogram alignment of eigenvector signs and order, then EM
    registration (parameters as ``em-registration``, plus ``bins``). Seeds are ignored. The
    baseline as published: its own embedding and no orientation cue (it matches up to symmetry).

    Default: area-normalized Laplace-Beltrami eigenvectors, unscaled. Preset ``thesis`` (Algorithm 5,
    section 5.4): the unnormalized Laplacian ``D - W`` of the Gaussian graph (eq. 3.7) and its L-embedding,
    the commute-time scaling ``Lambda^{-1/2} U^T`` of eq. 5.1; the histograms are those of the eigenvectors
    themselves (a scaling per column would only move them between bins)."""

    presets: dict = {"thesis": {"spectrum": "graph", "weighting": "gaussian", "scaling": "commute-time"}}
    parameter_constraints = {
        **{p: c for p, c in EMRegistrationMatcher.parameter_constraints.items()
           if p in ("k", "outlier_weight", "n_neighbors", "max_iter", "tol", "threshold", "one_to_one",
                    "fill_unmatched", "spectrum", "weighting", "scaling")},
        "bins": Param(POSITIVE_INT, doc="histogram bins of the eigenvector alignment"),
    }

    def __init__(
        self,
        k: int = 8,
        bins: int = 40,
        outlier_weight: float = 0.1,
        n_neighbors: int = 10,
        max_iter: int = 50,
        tol: float = 1e-5,
        threshold: float = 0.5,
        one_to_one: bool = False,
        fill_unmatched: bool = True,
        spectrum: str = "lbo",
        weighting: str | None = None,
        scaling: str = "none",
    ):
        super().__init__(
            k=k, outlier_weight=outlier_weight, n_neighbors=n_neighbors, max_iter=max_iter,
            tol=tol, threshold=threshold, one_to_one=one_to_one, fill_unmatched=fill_unmatched,
            spectrum=spectrum, weighting=weighting, scaling=scaling, orientation="none",
        )
        self.bins = bins

    def start(self, source: Shape, target: Shape, seeds: np.ndarray | None, source_spectrum=None,
              target_spectrum=None, min_dim: int = 0) -> tuple[Embedding, np.ndarray, dict]:
        """The embeddings (``scaling``; no bases: no refinement) and ``Q0``, the histogram alignment of their
        eigenvectors; ``seeds`` are ignored."""
        self._check()
        bs, bt = self._bases(source, target, source_spectrum, target_spectrum, min_dim)
        K = self._shared_dimension(int(self.k), bs, bt)  # one size on both shapes, however small
        X, Y = bs.evecs[:, 1 : K + 1], bt.evecs[:, 1 : K + 1]
        Q0, _ = histogram_alignment(X, Y, bs.mass, bt.mass, int(self.bins))
        return Embedding(self._embed(bs, K), self._embed(bt, K)), Q0, {"Q0": Q0}
