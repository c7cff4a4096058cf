"""Standard spectral clustering baselines: k-means on the first ``k`` Laplacian eigenvectors.

Variants (von Luxburg 2007 names the three classic algorithms):

- ``"ng"`` (default): Ng, Jordan & Weiss 2001, the baseline of thesis chapter 4: the ``k`` smallest
  eigenvectors of the normalized Laplacian ``D^-1/2 (D - W) D^-1/2``, rows scaled to unit length,
  then k-means.
- ``"unnormalized"``: von Luxburg's unnormalized spectral clustering: the ``k`` smallest
  eigenvectors of ``L = D - W``, then k-means.
- ``"random-walk"``: Shi & Malik 2000: the ``k`` smallest generalized eigenvectors of
  ``(D - W) v = lambda D v``, then k-means.
- ``"commute-time"``: k-means on the commute-time embedding of ``L`` (eq. 5.1) with the ``k - 1``
  first non-null eigenpairs: the "SC" column of Table 5.1 (steps 3-4 of CSC without constraints,
  with CSC's default ``output_dim``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from shape_toolkit.api.params import RANDOM_STATE, Options, Param
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.features.embedding import commute_time_embedding
from shape_toolkit.plugins._params import N_INIT, N_SEGMENTS, POSITIVE_INT, WEIGHTING
from shape_toolkit.plugins.segmenters.base import BaseSegmenter, segmenter_spec
from shape_toolkit.plugins.segmenters.embedding import row_normalize
from shape_toolkit.plugins.segmenters.kmeans import kmeans_labels
from shape_toolkit.plugins.segmenters.n_segments import check_n_segments
from shape_toolkit.results.segmentation import Segmentation
from shape_toolkit.spectra import SpectrumSpec
from shape_toolkit.validation import seed_of

_LAPLACIAN = {
    "ng": "normalized",
    "unnormalized": "combinatorial",
    "random-walk": "random-walk",
    "commute-time": "combinatorial",
}


class SpectralClustering(BaseSegmenter):
    """k-means on the first ``n_segments`` eigenvectors of a graph Laplacian (see module doc).

    ``n_segments=None`` picks ``k`` in ``[2, max_segments]`` at the largest eigengap
    ``lambda_{k+1} - lambda_k`` (von Luxburg 2007, 8.3), recorded in ``eigengaps_``.
    Diagnostics of the last run: ``n_segments_``, ``eigenvalues_``, ``embedding_dim_``.
    """

    presets = {"ng2001": {"variant": "ng"}, "luxburg-unnormalized": {"variant": "unnormalized"}}
    split_clouds = True

    parameter_constraints = {
        "n_segments": N_SEGMENTS,
        "variant": Param(Options(*_LAPLACIAN), doc="spectral clustering variant (its Laplacian)"),
        "weighting": WEIGHTING,
        "max_segments": Param(POSITIVE_INT, doc="most segments when n_segments is None (eigengap)"),
        "n_init": N_INIT,
        "random_state": RANDOM_STATE,
    }

    def __init__(
        self,
        n_segments: int | None = None,
        *,
        variant: str = "ng",
        weighting: str = "gaussian",
        max_segments: int = 15,
        n_init: int = 10,
        random_state: int = 0,
    ):
        self.n_segments = n_segments
        self.variant = variant
        self.weighting = weighting
        self.max_segments = max_segments
        self.n_init = n_init
        self.random_state = random_state

    def _kmax(self, n: int | None = None) -> int:
        """Largest ``k`` considered: ``n_segments``, or ``max_segments`` (capped at ``n - 1``)."""
        if self.n_segments is not None:
            return int(check_n_segments(self.n_segments, n if n is not None else self.n_segments,
                                        allow_none=False))
        kmax = self.max_segments if n is None else min(int(self.max_segments), n - 1)
        return int(check_n_segments(kmax, n if n is not None else kmax, allow_none=False))

    def spectrum_spec(self) -> SpectrumSpec:
        """``kmax + 1`` eigenpairs (``kmax``: ``n_segments`` or ``max_segments``) of the variant's
        Laplacian of the ``weighting`` graph, no mass matrix."""
        return segmenter_spec(self._kmax() + 1, self.weighting, _LAPLACIAN[self.variant])

    def _segment(self, shape: Shape, *, spectrum: Spectrum | None, constraints: Any) -> Segmentation:
        """The segmentation of a shape of one piece (an unsupervised baseline: no constraints)."""
        n = shape.n_vertices
        k = check_n_segments(self.n_segments, n, allow_none=True)
        kmax = self._kmax(n)
        spectrum = self._spectrum(shape, spectrum)
        seed = seed_of(self.random_state)
        vals = spectrum.eigenvalues
        self.eigengaps_ = None
        if k is None:
            gaps = np.diff(vals[: kmax + 1])  # gaps[i] = lambda_{i+2} - lambda_{i+1} (1-based)
            self.eigengaps_ = gaps.tolist()
            k = int(np.argmax(gaps[1:]) + 2) if len(gaps) > 1 else 2
        if self.variant == "commute-time":
            X = commute_time_embedding(spectrum, k - 1)
        else:
            X = spectrum.eigenvectors[:, :k]
            if self.variant == "ng":
                X = row_normalize(X)
        labels = kmeans_labels(X, k, seed, self.n_init)
        self.n_segments_ = int(labels.max() + 1)
        self.eigenvalues_ = vals[: k + 1].tolist()
        self.embedding_dim_ = int(X.shape[1])
        return Segmentation.of_vertices(shape, labels)
