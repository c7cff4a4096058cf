"""Spectral learning, SL (Kamvar, Klein & Manning 2003): a constrained baseline of Table 5.1.

The affinity of every must-link pair is set to 1 (an edge is added when the two vertices are not
adjacent: this is the topology change the thesis criticises, 5.1.1) and the affinity of every
cannot-link pair to 0 (the edge is removed when present). Kamvar et al. take the ``k`` largest
eigenvectors of ``N = (A + d_max I - D) / d_max``, which are the ``k`` smallest eigenvectors of the
unnormalized Laplacian ``D - A``, scale the rows to unit length and run k-means.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from shape_toolkit.api.params import RANDOM_STATE
from shape_toolkit.core.eigen import smallest_eigenpairs
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.plugins._params import N_INIT, N_SEGMENTS, WEIGHTING
from shape_toolkit.plugins.segmenters.base import BaseSegmenter
from shape_toolkit.plugins.segmenters.embedding import row_normalize
from shape_toolkit.plugins.segmenters.kmeans import kmeans_labels
from shape_toolkit.plugins.segmenters.n_segments import check_n_segments
from shape_toolkit.results.labels import coerce_constraints
from shape_toolkit.results.segmentation import Segmentation
from shape_toolkit.spectra import build_graph
from shape_toolkit.validation import seed_of


class SpectralLearning(BaseSegmenter):
    """Kamvar et al. 2003 on the shape graph (Gaussian weights): constrained affinities, then
    row-normalised k-means on the ``k`` smallest eigenvectors of ``D - A``.

    It declares no spectrum: the eigenproblem of the constraint-modified affinities is the algorithm
    itself, so a ``spectrum`` argument is ignored.

    Diagnostics: ``n_added_edges_``, ``n_removed_edges_``, ``n_segments_``.
    """

    takes_constraints = True
    requires_n_segments = True

    parameter_constraints = {
        "n_segments": N_SEGMENTS,
        "weighting": WEIGHTING,
        "n_init": N_INIT,
        "random_state": RANDOM_STATE,
    }

    def __init__(
        self,
        n_segments: int | None = None,
        *,
        weighting: str = "gaussian",
        n_init: int = 10,
        random_state: int = 0,
    ):
        self.n_segments = n_segments
        self.weighting = weighting
        self.n_init = n_init
        self.random_state = random_state

    def component_graph(self, shape: Shape) -> None:
        """None: the shape is segmented whole (its graph may be in pieces)."""
        return None

    def _segment(self, shape: Shape, *, spectrum: Spectrum | None, constraints: Any) -> Segmentation:
        """The segmentation; the spectrum is recomputed on the modified affinities."""
        n = shape.n_vertices
        k = check_n_segments(self.n_segments, n, allow_none=False)
        seed = seed_of(self.random_state)
        cons = coerce_constraints(constraints, n)
        A = sp.lil_matrix(build_graph(shape, self.weighting).W)
        added = removed = 0
        if cons is not None:
            for i, j in cons.must_link.tolist():
                added += int(A[i, j] == 0)
                A[i, j] = A[j, i] = 1.0
            for i, j in cons.cannot_link.tolist():
                removed += int(A[i, j] != 0)
                A[i, j] = A[j, i] = 0.0
        A = sp.csr_matrix(A)
        A.eliminate_zeros()
        d = np.asarray(A.sum(axis=1)).ravel()
        _, vecs = smallest_eigenpairs(sp.csr_matrix(sp.diags(d) - A), k)
        labels = kmeans_labels(row_normalize(vecs), k, seed, self.n_init)
        self.n_added_edges_, self.n_removed_edges_ = added, removed
        self.n_segments_ = int(labels.max() + 1)
        return Segmentation.of_vertices(shape, labels)
