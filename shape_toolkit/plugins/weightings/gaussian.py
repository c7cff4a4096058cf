"""Gaussian weights ``w_ij = exp(-||v_i - v_j||^2 / (2 sigma^2))`` (thesis eq. 3.7).

Default bandwidth (``bandwidth=None``, "auto"): one global ``sigma``, the mean edge length (the
thesis's choice, so that weights read the metric: a long edge is a weak link), raised only as far
as needed for no edge of the graph to weigh less than ``MIN_WEIGHT`` (1e-4):

    sigma = bandwidth_scale * max(mean edge length, longest edge / sqrt(2 ln(1 / MIN_WEIGHT)))

On a regular mesh (longest edge < 4.3 x the mean) this is exactly the mean edge length. On an
irregular remeshing (a TOSCA horse, a PSB model) the plain mean lets the long edges of sparsely
sampled regions weigh ~1e-11, and the graph falls apart numerically (Laplacian eigenvalues that are
zero to solver precision); the floor keeps every weight four orders of magnitude above the
eigensolver's relative resolution (1e-8), with no constant fitted to any data set. Both rules are
invariant to a global scaling of the shape.

``bandwidth="local"`` offers the self-tuning local scaling of Zelnik-Manor and Perona (2004),
``sigma_ij = s sqrt(sigma_i sigma_j)`` with ``sigma_i`` the longest edge at vertex ``i``: every
weight then lies in ``[exp(-1/(2 s^2)), 1]`` (0.61 to 1 for ``s = 1``), which also never underflows
but makes the weights nearly uniform, i.e. close to the binary graph: the heat-kernel methods of
chapter 6 then lose the metric signal they read (keypoints drift off protrusion tips). It is not the
default for that reason.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse.csgraph import connected_components

from shape_toolkit.api.interfaces import Weighting, Weights
from shape_toolkit.api.params import Options, Param
from shape_toolkit.core.graph import weights_from_edges
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.plugins._params import POSITIVE

#: a weight below this fraction of the largest weight is zero to solver precision (the relative
#: resolution of the eigensolver, ``shape_toolkit.core.eigen``: shift ``-1e-8 * scale``, tol 1e-8)
NEGLIGIBLE_WEIGHT = 1e-8

#: the default bandwidth keeps every edge weight at or above this (1e4 x NEGLIGIBLE_WEIGHT)
MIN_WEIGHT = 1e-4

_MODES = ("auto", "local", "mean")


class GaussianWeighting(Weighting):
    """Heat-kernel weights on graph edges (eq. 3.7).

    ``bandwidth``: ``"auto"`` (default, also ``None``): the mean edge length, raised where needed so
    that no edge weighs less than ``MIN_WEIGHT`` (module docstring); ``"mean"``: the plain mean edge
    length (long edges of irregular meshes may underflow); ``"local"``: self-tuning local bandwidths
    ``sigma_ij = bandwidth_scale * sqrt(sigma_i sigma_j)``; or a positive number, a global ``sigma`` in
    the shape's length units. ``bandwidth_scale`` multiplies the automatic bandwidths.

    A global bandwidth that leaves some edges with weights below ``1e-8`` of the largest and thereby
    cuts the graph into more pieces than it structurally has (a numerically disconnected graph,
    whose spectrum would have spurious zero eigenvalues) is refused with a
    :class:`~shape_toolkit.errors.ParameterError` giving the smallest safe bandwidth.
    """

    #: what to do when the Laplacian is numerically disconnected (``NumericallyDisconnectedGraphError``)
    disconnection_hint = (
        "leave the Gaussian bandwidth unset (local, scale-free bandwidths keep every weight "
        ">= exp(-1/2)) or give a larger one"
    )
    parameter_constraints = {
        "bandwidth": Param(None, Options(*_MODES), POSITIVE,
                           doc="sigma in length units, or a rule (None: 'auto', the mean edge length, floored)"),
        "bandwidth_scale": Param(POSITIVE, doc="factor on the automatic bandwidths ('auto', 'mean', 'local')"),
    }

    def __init__(self, bandwidth: float | str | None = None, bandwidth_scale: float = 1.0):
        self.bandwidth = bandwidth
        self.bandwidth_scale = bandwidth_scale

    def weigh(self, shape: Shape, edges: np.ndarray) -> Weights:
        """Gaussian weights on the ``(e, 2)`` edges."""
        n = shape.n_vertices
        edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
        length = np.linalg.norm(shape.vertices[edges[:, 0]] - shape.vertices[edges[:, 1]], axis=1)
        bw = "auto" if self.bandwidth is None else self.bandwidth
        if len(edges) == 0:
            return Weights(weights_from_edges(n, edges, np.zeros(0)), info={"bandwidth": bw})

        info: dict = {}
        if bw == "local":
            sigma_v = np.zeros(n)
            np.maximum.at(sigma_v, edges[:, 0], length)
            np.maximum.at(sigma_v, edges[:, 1], length)
            scale = np.float64(self.bandwidth_scale)
            # numpy, not Python floats: a scale whose square underflows (< 1e-154) or overflows (> 1e154) gives the
            # bound 0 or 1 (vanishing weights are then refused below; huge scales weigh every edge 1, a binary graph)
            with np.errstate(under="ignore", over="ignore", divide="ignore"):
                sigma = scale * np.sqrt(sigma_v[edges[:, 0]] * sigma_v[edges[:, 1]])
                lower = float(np.exp(-0.5 / scale**2))
            info.update(bandwidth="local", bandwidth_median=float(np.median(sigma)),
                        bandwidth_range=[float(sigma.min()), float(sigma.max())], weight_lower_bound=lower)
        else:
            if bw == "auto":
                floor_sigma = float(length.max()) / np.sqrt(2.0 * np.log(1.0 / MIN_WEIGHT))
                sigma = float(self.bandwidth_scale) * max(float(length.mean()), floor_sigma)
            elif bw == "mean":
                sigma = float(self.bandwidth_scale) * float(length.mean())
            else:
                sigma = float(bw)
            info["bandwidth"] = sigma
        with np.errstate(under="ignore", over="ignore", invalid="ignore", divide="ignore"):
            # an edge between coincident vertices weighs 1 (and may have sigma_ij = 0 when local)
            w = np.where(length > 0, np.exp(-0.5 * (length / sigma) ** 2), 1.0)
        self._check_not_vanishing(n, edges, length, w, bw == "local", sigma)
        info["min_weight"] = float(w.min())
        return Weights(weights_from_edges(n, edges, w), info=info)

    @staticmethod
    def _check_not_vanishing(
        n: int, edges: np.ndarray, length: np.ndarray, w: np.ndarray, local: bool, sigma: np.ndarray | float
    ) -> None:
        """Refuse a global bandwidth whose negligible weights cut the graph apart."""
        wmax = float(w.max())
        keep = w > NEGLIGIBLE_WEIGHT * wmax if wmax > 0 else np.zeros(len(w), bool)
        if keep.all():
            return
        import scipy.sparse as sp

        def count(mask: np.ndarray) -> int:
            e = edges[mask]
            A = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
            return int(connected_components(A, directed=False)[0])

        structural, numerical = count(np.ones(len(w), bool)), count(keep)
        if numerical == structural:
            return
        # the bandwidth keeping every weight above NEGLIGIBLE_WEIGHT: exp(-l^2 / 2 sigma^2) >= eps
        factor = np.sqrt(2.0 * np.log(1.0 / NEGLIGIBLE_WEIGHT))
        if local:
            raise ParameterError(
                f"bandwidth_scale is too small: {int(np.sum(~keep))} of {len(w)} local Gaussian weights vanish "
                f"(below {NEGLIGIBLE_WEIGHT:g} of the largest), leaving a numerically disconnected graph "
                f"({numerical} pieces instead of {structural}). Use bandwidth_scale >= {_round_up(1.0 / factor):.3g} "
                "(1, the default, keeps every weight >= exp(-1/2))"
            )
        safe = _round_up(float(length.max()) / factor)
        raise ParameterError(
            f"Gaussian bandwidth {sigma:.4g} is too small for this shape's edges (lengths "
            f"{length.min():.3g} to {length.max():.3g}): {int(np.sum(~keep))} of {len(w)} weights vanish "
            f"(below {NEGLIGIBLE_WEIGHT:g} of the largest), leaving a numerically disconnected graph "
            f"({numerical} pieces instead of {structural}) whose spectrum has spurious zero eigenvalues. "
            f"Use bandwidth >= {safe:.3g}, or leave bandwidth unset (the automatic bandwidth keeps every "
            "weight >= 1e-4)"
        )


def _round_up(x: float, digits: int = 3) -> float:
    """``x`` rounded up to ``digits`` significant digits (a printed lower bound that still holds)."""
    if not x > 0 or not np.isfinite(x):
        return x
    q = 10.0 ** (np.floor(np.log10(x)) - digits + 1)
    return float(np.ceil(x / q * (1 - 1e-12)) * q)
