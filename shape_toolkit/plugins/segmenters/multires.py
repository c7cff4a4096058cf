"""Segmenting large shapes through a proxy: segment a decimated copy, carry its labels to every vertex.

A segmenter's eigenproblems and graphs grow faster than the vertex count (``ncut`` on a 10^6-vertex mesh: 103 s
CPU, and its segments change with the resolution), so a shape of more than 1.5 ``proxy`` vertices is segmented
through the proxy the matching pipelines use (:func:`~shape_toolkit.plugins.matching.multires.make_proxy`: on a
mesh, quadric edge collapse that moves no vertex; on a point cloud, farthest-point samples) and the labels are
carried back (:func:`~shape_toolkit.plugins.matching.multires.values_from_proxy`): a vertex takes the label of the
nearest corner of its closest point on a mesh proxy, of its nearest proxy point on a cloud one; a face (for a
segmenter of faces) the label of the proxy face its centroid is closest to. Constraint vertices move to their
nearest proxy vertex, and keep that vertex's label exactly, so a must-link kept on the proxy is kept on the shape.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from shape_toolkit.core.geometry import edge_components
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import DisconnectedGraphError, NumericallyDisconnectedGraphError
from shape_toolkit.plugins.matching.multires import PROXY_VERTICES, make_proxy, values_from_proxy
from shape_toolkit.plugins.segmenters.constraints import inner_segmentation, report_constraints
from shape_toolkit.results.labels import ConstraintError, Constraints, constraint_report
from shape_toolkit.results.segmentation import Segmentation

__all__ = ["SEGMENT_MEMORY", "SEGMENT_FULL_MEMORY", "segment_memory", "segment_through_proxy"]

#: peak memory of ``shape-toolkit segment`` (the default method, through a proxy), in bytes: a fixed part and a part
#: per vertex the file declares, from its measured peaks (``benchmarks/results/scale_1m.md``, 2026-12-06: 643 MB at
#: 244,904 vertices, 862 MB at 979,610; 0.3 kB more a vertex between them). An estimate for refusing a shape too
#: large for the memory before reading it (``--memory-limit``), not a bound
SEGMENT_MEMORY = (570e6, 300.0)
#: the same at full resolution (``--proxy 0``): 180 MB + 3 kB a vertex, from its measured peaks (``memory_models.md``,
#: 2026-12-06: 80k to 500k vertices)
SEGMENT_FULL_MEMORY = (180e6, 3000.0)


def segment_memory(n: int, proxy: int | None) -> float:
    """Estimated peak bytes of ``shape-toolkit segment`` (the default method) on a shape of ``n`` vertices: at full
    resolution (``proxy`` 0 or None, or ``n`` at most 1.5 ``proxy``: :data:`SEGMENT_FULL_MEMORY`), or through a proxy
    (:data:`SEGMENT_MEMORY`, and never less than segmenting 1.5 ``proxy`` vertices directly)."""
    a, b = SEGMENT_FULL_MEMORY
    if not proxy or n <= 1.5 * proxy:
        return a + b * n
    return max(SEGMENT_MEMORY[0] + SEGMENT_MEMORY[1] * n, a + b * 1.5 * proxy)


def _proxy_constraints(constraints: Constraints, nearest: np.ndarray) -> Constraints:
    """``constraints`` moved to the proxy: each vertex to its nearest proxy vertex ``nearest`` ``(n,)``. A
    cannot-link whose two ends land on one proxy vertex, or on two that the moved must-links join (transitively),
    cannot be kept on the proxy: a :class:`ConstraintError` naming the user's pair."""
    ml, cl = nearest[constraints.must_link], nearest[constraints.cannot_link]
    if len(cl):
        ends, inv = np.unique(np.concatenate([ml.ravel(), cl.ravel()]), return_inverse=True)
        _, comp = edge_components(len(ends), inv[: ml.size].reshape(-1, 2))
        c = comp[inv[ml.size:].reshape(-1, 2)]
        clash = np.flatnonzero(c[:, 0] == c[:, 1])
        if clash.size:
            i = int(clash[0])
            why = ("joins two vertices closer than the proxy's spacing (one proxy vertex)" if cl[i, 0] == cl[i, 1]
                   else "joins two vertices that the must-links put in one segment on the proxy (must-link ends "
                   "closer than the proxy's spacing share a proxy vertex)")
            raise ConstraintError(
                f"cannot-link {constraints.cannot_link[i].tolist()} {why}; segment at full resolution "
                "(`segment --proxy 0`, or the segmenter's own segment()) or click further apart")
    return Constraints(ml[ml[:, 0] != ml[:, 1]] if len(ml) else ml, cl)


def segment_through_proxy(segmenter: Any, shape: Shape, *, proxy: int = PROXY_VERTICES,
                          constraints: Constraints | None = None) -> Segmentation:
    """:class:`~shape_toolkit.results.segmentation.Segmentation` of the mesh or point cloud ``shape`` by
    ``segmenter`` run on a proxy of about ``proxy`` vertices (module docstring), with the spectra it declares computed
    on the proxy; ``info["proxy"]`` gives the proxy's size."""
    from scipy.spatial import cKDTree

    from shape_toolkit.spectra import compute_declared, declared_specs

    if constraints is not None:  # as the segmenter itself would, before its ids index anything
        constraints.validate(shape.n_vertices)
    ps, ids = make_proxy(shape, proxy)
    pc = None
    if constraints is not None:  # only the constraint vertices need their nearest proxy vertex
        ends = np.unique(np.concatenate([constraints.must_link.ravel(), constraints.cannot_link.ravel()]))
        V = np.asarray(shape.vertices)
        nearest = np.full(shape.n_vertices, -1, dtype=np.int64)
        nearest[ends] = cKDTree(V[ids]).query(V[ends])[1]
        pc = _proxy_constraints(constraints, nearest)
    specs = declared_specs(segmenter)
    try:
        spectra = compute_declared(ps, specs) if specs else None
    except DisconnectedGraphError as exc:
        if isinstance(exc, NumericallyDisconnectedGraphError):
            raise
        spectra = None  # a proxy in pieces: the segmenter segments it piece by piece, or raises this itself
    with inner_segmentation():  # no report (nor warning) in the proxy's counts: the user's constraints get theirs
        inner = segmenter.segment(ps, spectrum=spectra, constraints=pc)
    info = {k: v for k, v in inner.info.items() if k not in ("constraints", "per")}  # "per": set below
    info["proxy"] = {"proxy_vertices": int(ps.n_vertices), "vertices": int(shape.n_vertices)}
    if pc is not None and len(pc):  # what the segmenter kept on the proxy: the lift keeps the same
        info["proxy"]["constraints"] = constraint_report(inner.labels, pc)
    if inner.info.get("per") == "face" and inner.face_labels is not None:
        faces = np.asarray(shape.faces)
        centroids = np.asarray(shape.vertices)[faces].mean(axis=1)
        import igl

        _, face, _ = igl.point_mesh_squared_distance(centroids, np.asarray(ps.vertices, dtype=np.float64),
                                                     np.asarray(ps.faces, dtype=np.int64))
        out = Segmentation.of_faces(shape, inner.face_labels[face], **info)
    else:
        out = Segmentation.of_vertices(shape, values_from_proxy(inner.labels, shape, ps), **info)
    if constraints is not None and len(constraints):  # no pair: nothing to report, as the segmenter's own segment()
        labels = out.labels.copy()  # each constraint vertex: its proxy vertex's label, as the segmenter gave it
        labels[ends] = inner.labels[nearest[ends]]
        out = report_constraints(segmenter, Segmentation(labels, out.face_labels, out.info), constraints,
                                 shape.n_vertices)  # info["constraints"], and the one warning, in the user's counts
    return out
