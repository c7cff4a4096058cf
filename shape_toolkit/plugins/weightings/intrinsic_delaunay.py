"""Robust cotangent Laplacian on the intrinsic Delaunay triangulation (Sharp and Crane 2020)."""

from __future__ import annotations

import numpy as np
import robust_laplacian
import scipy.sparse as sp

from shape_toolkit.api.interfaces import Weighting, Weights
from shape_toolkit.api.params import Interval, Options, Param
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.surface import check_triangulable, sheet_triangulation
from shape_toolkit.errors import InvalidShapeError, ParameterError


def centred(points: np.ndarray) -> np.ndarray:
    """``points`` ``(n, 3)`` moved so that their centroid is the origin (same units), C-contiguous.

    robust_laplacian's point-cloud Laplacian is not invariant to a translation of the cloud: moving a
    642-point shape by 1.6 times its size changed its eigenvalues by 22 % and its area by 11 % (rotations
    about the origin: under 1 %). A cloud's Laplacian is built on its centred copy, so it no longer
    depends on where the cloud sits (``tests/test_graph_spectrum.py``)."""
    v = np.asarray(points, dtype=np.float64)
    return np.ascontiguousarray(v - v.mean(axis=0))


class IntrinsicDelaunayWeighting(Weighting):
    """Cotangent weights of the intrinsic Delaunay triangulation of the (tufted) mesh, or of
    local Delaunay triangulations for point clouds, with the matching lumped mass.

    Weights are non-negative even on poor, non-manifold triangulations. ``mollify_factor``
    (relative to the mean edge length) guards against degenerate triangles; ``n_neighbors``
    is used for point clouds only. The graph's edges are ignored: the scheme builds its own. A cloud is
    centred at its centroid first (:func:`centred`: the library's cloud Laplacian depends on the position).

    ``cloud_neighbors`` (point clouds): ``'sheet'`` (default) triangulates around each point only the
    neighbours on its own sheet of the surface (:func:`shape_toolkit.core.surface.local_delaunay_triangles`,
    with the outward normals of :func:`~shape_toolkit.core.surface.cloud_normals`: the cloud's own, else
    estimated), so that parts touching
    in space are not linked; ``'all'`` takes all ``n_neighbors`` (robust_laplacian's point-cloud Laplacian, the
    former default). On the tune half of the cloud benchmark (``benchmarks/results/cloud_matching_notes.md``)
    the sheets brought the spectra of TOSCA dogs and FAUST people closer to their meshes'.

    ``cloud_smoothing`` (point clouds, ``'sheet'``): ``'jet'`` computes the cotangent weights and areas of those
    triangles on the points projected onto their local quadric fits (:func:`~shape_toolkit.core.surface.jet_projected`,
    the same ``n_neighbors``, own side only); the triangles themselves are chosen on the points as given. ``'none'``
    (default) uses the points as given. Noise across the surface acts on matching through the Laplacian (on the tune
    half, noisy clouds matched as well as clean ones with the Laplacian of the clean positions of the same points);
    the jet halves a noisy cloud's departure from the clean cloud's spectrum, but on the tune half's matches it was
    within their scatter and cost clean vertex clouds 0.010, so it is not the default
    (``benchmarks/results/cloud_matching_notes.md``, round 4).
    """

    #: builds its own edges (intrinsic or local Delaunay triangulations); build_graph honours
    #: connectivity='knn' on a mesh by treating its vertices as a point cloud
    uses_edges = False

    parameter_constraints = {
        "mollify_factor": Param(
            Interval(float, 0, 1),
            doc="mollification against degenerate triangles, x mean edge length (at most 1: every edge is lengthened "
                "until each triangle's slack a + b - c reaches this margin, and an equilateral triangle of mean size "
                "has a slack of exactly 1, so from 1 on even the best meshes are inflated, their eigenvalues falling "
                "as 1/factor^2: 2e-18 at 1e9 on a unit sphere, not a repair but another shape)",
        ),
        "n_neighbors": Param(Interval(int, 3), doc="neighbours of the local triangulations (point clouds only)"),
        "cloud_neighbors": Param(
            Options("sheet", "all"),
            doc="point clouds: triangulate the neighbours on the point's own sheet of the surface, or all",
        ),
        "cloud_smoothing": Param(
            Options("jet", "none"),
            doc="point clouds, 'sheet': build the Laplacian on the points projected onto their local quadric (jet) "
                "fits, or on the points as given",
        ),
    }

    def __init__(self, mollify_factor: float = 1e-5, n_neighbors: int = 30, cloud_neighbors: str = "sheet",
                 cloud_smoothing: str = "none"):
        self.mollify_factor = mollify_factor
        self.n_neighbors = n_neighbors
        self.cloud_neighbors = cloud_neighbors
        self.cloud_smoothing = cloud_smoothing

    def weigh(self, shape: Shape, edges: np.ndarray) -> Weights:
        """Intrinsic-Delaunay cotangent weights and lumped vertex areas."""
        if self.cloud_smoothing == "jet" and self.cloud_neighbors == "all":  # robust_laplacian's own triangles
            raise ParameterError("cloud_smoothing='jet' needs cloud_neighbors='sheet' (the triangles it denoises)")
        v = np.ascontiguousarray(shape.vertices)
        if shape.is_mesh:
            L, M = robust_laplacian.mesh_laplacian(
                v, np.ascontiguousarray(shape.faces), mollify_factor=self.mollify_factor
            )
        else:
            no_triangle = "its points' neighbourhoods hold no triangle (they lie on lines: a curve, not a surface)"
            try:  # geometry-central aborts with a RuntimeError on a cloud with no local triangle at all
                if self.cloud_neighbors == "all":
                    check_triangulable(shape, self.n_neighbors)
                    L, M = robust_laplacian.point_cloud_laplacian(
                        centred(v), mollify_factor=self.mollify_factor, n_neighbors=self.n_neighbors
                    )
                else:
                    v, triangles = sheet_triangulation(shape, self.n_neighbors, self.cloud_smoothing)
                    L, M = robust_laplacian.mesh_laplacian(
                        centred(v), np.ascontiguousarray(triangles), mollify_factor=self.mollify_factor
                    )
                    L, M = L / 3.0, M / 3.0  # each triangle is in up to three points' triangulations
            except RuntimeError as exc:  # the library's own words, and the likely cause
                said = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                raise InvalidShapeError(f"{shape!r}: robust_laplacian's cloud Laplacian failed ({said}); the likely "
                                        f"cause: {no_triangle}") from None
        L = sp.csr_matrix(L)
        W = -(L - sp.diags(L.diagonal()))
        W = sp.csr_matrix((W + W.T) * 0.5)
        W.eliminate_zeros()
        negative = int(np.count_nonzero(W.data < -1e-12) // 2)
        return Weights(W, np.asarray(M.diagonal(), dtype=np.float64), {"negative_weights": negative})
