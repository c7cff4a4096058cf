"""Gaussian weights ``w_ij = exp(-||v_i - v_j||^2 / (2 sigma^2))`` (thesis eq. 3.7)."""

from __future__ import annotations

import numpy as np

from shape_toolkit.api.hookspecs import hookimpl
from shape_toolkit.api.interfaces import Weighting, Weights
from shape_toolkit.core.graph import weights_from_edges
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError


class GaussianWeighting(Weighting):
    """Heat-kernel weights on graph edges.

    ``bandwidth`` is ``sigma`` in the shape's length units. When None it defaults to
    ``bandwidth_scale`` times the mean length of the graph's edges, which makes the weights
    invariant to a global scaling of the shape and keeps a typical edge at ``exp(-1/2)``.
    """

    def __init__(self, bandwidth: float | None = None, bandwidth_scale: float = 1.0):
        self.bandwidth = bandwidth
        self.bandwidth_scale = bandwidth_scale

    def weigh(self, shape: Shape, edges: np.ndarray) -> Weights:
        """Gaussian weights on the ``(e, 2)`` edges."""
        d2 = np.sum((shape.vertices[edges[:, 0]] - shape.vertices[edges[:, 1]]) ** 2, axis=1)
        if self.bandwidth is not None:
            sigma = float(self.bandwidth)
        else:
            if not self.bandwidth_scale > 0:
                raise ParameterError(f"bandwidth_scale must be > 0, got {self.bandwidth_scale}")
            sigma = self.bandwidth_scale * float(np.sqrt(d2).mean())
        if not sigma > 0 or not np.isfinite(sigma):
            raise ParameterError(f"Gaussian bandwidth must be positive and finite, got {sigma}")
        w = np.exp(-d2 / (2.0 * sigma**2))
        return Weights(weights_from_edges(shape.n_vertices, edges, w), info={"bandwidth": sigma})


@hookimpl
def toolkit_weightings() -> dict[str, type]:
    return {"gaussian": GaussianWeighting}
