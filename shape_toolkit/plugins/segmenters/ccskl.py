"""Constrained clustering by spectral kernel learning, CCSKL (Li & Liu 2009): a Table 5.1 baseline.

With ``u_1 .. u_m`` the ``m`` smallest eigenvectors of the normalized Laplacian
``I - D^-1/2 W D^-1/2``, the kernel ``K = sum_l beta_l u_l u_l^T`` is learnt by the convex quadratic
program

    min_beta  sum_{(i, j) in M u C u {(i, i)}} (K_ij - t_ij)^2
    s.t.      beta_1 >= beta_2 >= ... >= beta_m >= 0

with ``t_ij = 1`` for must-links and for the diagonal of the constrained vertices and ``t_ij = 0``
for cannot-links; the ordering keeps the smoothest eigenvectors dominant. We solve it exactly as a
non-negative least-squares problem (``beta = B gamma``, ``gamma >= 0``, ``B`` upper triangular of
ones). The vertices are then embedded as ``u(i) * sqrt(beta)``, rows scaled to unit length, and
clustered with k-means (the spectral clustering step on the learnt kernel).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.optimize import nnls

from shape_toolkit.api.params import RANDOM_STATE, Param
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.errors import ParameterError
from shape_toolkit.plugins._params import N_INIT, N_SEGMENTS, POSITIVE_INT, WEIGHTING
from shape_toolkit.plugins.segmenters.base import BaseSegmenter, segmenter_spec
from shape_toolkit.plugins.segmenters.embedding import row_normalize
from shape_toolkit.plugins.segmenters.kmeans import kmeans_labels
from shape_toolkit.plugins.segmenters.n_segments import check_n_segments
from shape_toolkit.results.labels import coerce_constraints
from shape_toolkit.results.segmentation import Segmentation
from shape_toolkit.spectra import SpectrumSpec
from shape_toolkit.validation import seed_of


def learn_spectral_weights(U: np.ndarray, must: np.ndarray, cannot: np.ndarray) -> np.ndarray:
    """The CCSKL weights ``beta`` ``(m,)`` (non-increasing, >= 0) for eigenvectors ``U`` ``(n, m)``."""
    m = U.shape[1]
    pairs = [np.asarray(must, np.int64).reshape(-1, 2), np.asarray(cannot, np.int64).reshape(-1, 2)]
    nodes = np.unique(np.concatenate([p.ravel() for p in pairs]))
    diag = np.stack([nodes, nodes], axis=1)
    allp = np.concatenate([pairs[0], pairs[1], diag])
    t = np.concatenate([np.ones(len(pairs[0])), np.zeros(len(pairs[1])), np.ones(len(diag))])
    if len(allp) == 0:
        return np.ones(m)
    rows = U[allp[:, 0]] * U[allp[:, 1]]  # K_ij = sum_l beta_l u_l(i) u_l(j)
    B = np.triu(np.ones((m, m))).T  # beta = B gamma: beta_l = sum_{j >= l} gamma_j
    scale = float(np.abs(rows).max()) or 1.0
    gamma, _ = nnls((rows / scale) @ B, t, maxiter=50 * m)
    beta = B @ gamma / scale
    return beta if np.any(beta > 0) else np.ones(m)


class CCSKL(BaseSegmenter):
    """Li & Liu 2009 spectral kernel learning from pairwise constraints (see module doc).

    ``n_eigenvectors`` (``m``, default 20) smallest eigenvectors of the normalized Laplacian.
    Diagnostics: ``beta_`` (learnt spectral weights), ``n_segments_``.
    """

    takes_constraints = True
    requires_n_segments = True
    split_clouds = True

    parameter_constraints = {
        "n_segments": N_SEGMENTS,
        "n_eigenvectors": Param(POSITIVE_INT, doc="eigenvectors of the embedding (at least n_segments)"),
        "weighting": WEIGHTING,
        "n_init": N_INIT,
        "random_state": RANDOM_STATE,
    }

    def __init__(
        self,
        n_segments: int | None = None,
        *,
        n_eigenvectors: int = 20,
        weighting: str = "gaussian",
        n_init: int = 10,
        random_state: int = 0,
    ):
        self.n_segments = n_segments
        self.n_eigenvectors = n_eigenvectors
        self.weighting = weighting
        self.n_init = n_init
        self.random_state = random_state

    def spectrum_spec(self) -> SpectrumSpec:
        """``n_eigenvectors`` eigenpairs of the normalized Laplacian of the ``weighting`` graph."""
        return segmenter_spec(int(self.n_eigenvectors), self.weighting, "normalized")

    def _segment(self, shape: Shape, *, spectrum: Spectrum | None, constraints: Any) -> Segmentation:
        """The segmentation of a shape of one piece (``constraints``: Constraints, dict or JSON path)."""
        n = shape.n_vertices
        k = check_n_segments(self.n_segments, n, allow_none=False)
        m = self.n_eigenvectors
        if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or not k <= m <= n:
            raise ParameterError(f"n_eigenvectors must be an integer in [n_segments={k}, {n}], got {m!r}")
        cons = coerce_constraints(constraints, n)
        spectrum = self._spectrum(shape, spectrum)
        seed = seed_of(self.random_state)
        U = spectrum.eigenvectors[:, : int(m)]
        if cons is None:
            beta = np.ones(int(m))
        else:
            beta = learn_spectral_weights(U, cons.must_link, cons.cannot_link)
        X = row_normalize(U * np.sqrt(np.maximum(beta, 0.0))[None, :])
        labels = kmeans_labels(X, k, seed, self.n_init)
        self.beta_ = beta.tolist()
        self.n_segments_ = int(labels.max() + 1)
        return Segmentation.of_vertices(shape, labels)
