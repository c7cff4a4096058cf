"""Binary weights: ``w_ij = 1`` on every graph edge (thesis 3.3.3)."""

from __future__ import annotations

import numpy as np

from shape_toolkit.api.interfaces import Weighting, Weights
from shape_toolkit.core.graph import weights_from_edges
from shape_toolkit.core.shape import Shape


class BinaryWeighting(Weighting):
    """Connectivity only: every edge weighs 1, so ``L = D - A`` with ``D`` the vertex valences."""

    def weigh(self, shape: Shape, edges: np.ndarray) -> Weights:
        """Unit weights on the ``(e, 2)`` edges."""
        return Weights(weights_from_edges(shape.n_vertices, edges, np.ones(len(edges))))
