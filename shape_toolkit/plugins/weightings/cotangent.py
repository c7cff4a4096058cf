"""Cotangent weights (thesis eq. 3.6) with the Voronoi mass matrix, via libigl."""

from __future__ import annotations

import igl
import numpy as np
import scipy.sparse as sp

from shape_toolkit.api.interfaces import Weighting, Weights
from shape_toolkit.api.params import Param
from shape_toolkit.core.geometry import FLAT_FACE, flat_faces
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import InvalidShapeError


class CotangentWeighting(Weighting):
    """``w_ij = (cot alpha_ij + cot beta_ij) / 2`` from ``igl.cotmatrix`` and the Voronoi mass.

    The factor 1/2 is libigl's convention; with it ``L u = lambda M u`` approximates the
    Laplace-Beltrami eigenvalues (``l(l+1)`` on the unit sphere). Obtuse triangles give negative
    weights: they are counted in ``info['negative_weights']`` and set to zero when ``clamp_negative``.
    A numerically flat triangle (area below ``DEGENERATE`` times its longest edge squared: its
    cotangents exceed about 10^8) has no defined stiffness, and one made the eigensolver crawl for
    minutes on a remeshed scan: such faces are left out of the weights and the mass
    (``info['degenerate_faces_skipped']``).
    """

    #: a face whose area is below this times its longest edge squared is numerically a segment
    DEGENERATE = FLAT_FACE

    needs_faces = True
    #: builds its edges from the triangles: the graph's connectivity must be the mesh's
    uses_edges = False
    #: the weighting a spectrum declared with this one uses on a point cloud (no triangles)
    point_cloud_weighting = "intrinsic-delaunay"
    #: what to do when the Laplacian is numerically disconnected (``NumericallyDisconnectedGraphError``)
    disconnection_hint = (
        "use the 'intrinsic-delaunay' weighting (non-negative weights on poor triangulations) "
        "or clean degenerate triangles"
    )

    parameter_constraints = {"clamp_negative": Param(bool, doc="set negative cotangent weights to 0")}

    def __init__(self, clamp_negative: bool = False):
        self.clamp_negative = clamp_negative

    def weigh(self, shape: Shape, edges: np.ndarray) -> Weights:
        """Cotangent weights and Voronoi vertex areas of a triangle mesh (``edges`` unused)."""
        v, f = shape.vertices, shape.require_faces("cotangent weights")
        flat = flat_faces(v, f)
        if flat.any():
            f = f[~flat]
        if len(f) == 0:  # libigl's mass matrix of no face asks for gigabytes (std::bad_alloc, or the OOM killer)
            raise InvalidShapeError(
                f"every face of {shape!r} is numerically flat (zero area: collinear or coincident vertices), so "
                "cotangent weights are undefined; clean the shape (shape-toolkit clean) or use a weighting on its "
                "edges (binary, gaussian)"
            )
        C = sp.csr_matrix(igl.cotmatrix(v, f))
        W = C - sp.diags(C.diagonal())
        W.eliminate_zeros()
        W = sp.csr_matrix((W + W.T) * 0.5)
        negative = int(np.count_nonzero(W.data < 0) // 2)
        if self.clamp_negative and negative:
            W.data[W.data < 0] = 0.0
            W.eliminate_zeros()
        # libigl sizes the mass by the largest vertex id of a face: the last vertices, when on no (kept) face, get
        # theirs here (zero), so that they are reported as vertices of zero mass, as any other such vertex
        mass = np.zeros(len(v))
        m = sp.csr_matrix(igl.massmatrix(v, f, igl.MASSMATRIX_TYPE_VORONOI)).diagonal()
        mass[: len(m)] = m
        info = {"negative_weights": negative, "clamped": bool(self.clamp_negative and negative),
                "degenerate_faces_skipped": int(flat.sum())}
        return Weights(W, np.asarray(mass, dtype=np.float64), info)
