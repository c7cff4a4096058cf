"""Matching large shapes through proxies: solve on a decimated copy, lift to full resolution.

Every matching pipeline costs more than linearly in the vertex count (spectra with many eigenpairs,
nearest neighbours in spectral space over all vertex pairs), so a scan of 10^5-10^6 vertices is
matched through proxies of :data:`PROXY_VERTICES` vertices:

1. **Proxy.** A mesh is decimated by quadric edge collapse (pymeshlab) *without* moving vertices, so
   every proxy vertex is a vertex of the input; a point cloud is subsampled by farthest points.
2. **Solve** the pipeline on the two proxies (its own spectra, hypotheses and checks, as at 5k).
3. **Lift.** The proxy map is interpolated (:func:`interpolated_map`): each source vertex has weights on three
   proxy vertices (a mesh: the corners of the proxy triangle its closest point lies on, barycentric; a cloud: its
   three nearest proxy points, by inverse distance); their images, averaged with those weights, give a point,
   and the image is the target vertex nearest it (a mesh: whose closest point on the target proxy is nearest it).
   Where the images are far apart (a seam of the map), the heaviest corner's image is taken. O(n log n): libigl's
   AABB trees and k-d trees; no eigenproblem of the full size.

   It replaced a spectral lift (the functional map on 40 eigenfunctions of the full shapes, a local search and a
   descent along the target's edges), which localised a vertex more coarsely than the proxy map itself. On tuning
   pairs (dogs, FAUST people 0-1) remeshed independently to 58k vertices the interpolation gave 0.0143-0.0259
   against 0.0204-0.0289 (better on all 7 pairs, by 0.007-0.011 on FAUST), for 0.55-0.71 s of CPU against 2.6-4.8
   s. On their vertex clouds at 29k points: 0.0178-0.0199 against 0.0268-0.0277 on FAUST (3 pairs), 0.0249-0.1231
   against 0.0240-0.1201 on dogs (3 pairs, 0.001-0.003 worse), for 0.4-0.6 s against 8.7-10 s.

The proxy size is a vertex count, so the result does not depend on units or on the input's
resolution; ``PROXY_VERTICES`` is the resolution the pipelines were built and measured at (the
5k-vertex datasets).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from shape_toolkit.core.geometry import edge_components, farthest_point_sampling, flat_faces
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import InvalidShapeError, ParameterError
from shape_toolkit.validation import check_seeds, check_vertex_ids, first_per_source

__all__ = ["PROXY_VERTICES", "MATCH_MEMORY", "MATCH_FULL_MEMORY", "match_memory", "check_proxy_size", "make_proxy",
           "lift_map", "interpolated_map", "on_surface", "values_from_proxy", "proxy_seeds",
           "transfer_labels_through_proxies", "LABEL_TRANSFER_MEMORY", "LABEL_TRANSFER_FULL_MEMORY",
           "label_transfer_memory"]

#: vertices of each proxy; shapes up to 1.5x this are matched directly
PROXY_VERTICES = 5000
#: peak memory of ``shape-toolkit match`` through proxies, in bytes: a fixed part and a part per vertex of the two
#: shapes (the vertices the files declare), from its measured peaks (``benchmarks/results/scale_1m.md``, 2026-12-06:
#: 552 MB for two shapes of 244,904 vertices, 845 MB for two of 979,610; 0.2 kB more a vertex between them). An
#: estimate for refusing shapes too large for the memory before reading them (``--memory-limit``), not a bound
MATCH_MEMORY = (450e6, 200.0)
#: the same at full resolution (``--proxy 0``; pipeline ``auto``): 100 MB + 8.9 kB a vertex of the two shapes, from its
#: measured peaks (``benchmarks/results/memory_models.md``, 2026-12-06: 2 x 20k to 2 x 80k vertices)
MATCH_FULL_MEMORY = (100e6, 8900.0)
#: peak memory of ``shape-toolkit transfer-labels`` through proxies, in bytes: a fixed part and a part per vertex of the
#: two shapes (the vertices the files declare), least squares on its measured peaks (``benchmarks/results/
#: memory_models.md``, 2026-12-06: 302 to 578 MB for 2 x 80k to 2 x 500k vertices)
LABEL_TRANSFER_MEMORY = (330e6, 270.0)
#: the same at full resolution (``--proxy 0``; ``eigvec-alignment``): 212 and 421 MB for 2 x 5k and 2 x 20k vertices
#: (and 1.1 GB for 42k + 90k, one run)
LABEL_TRANSFER_FULL_MEMORY = (140e6, 7000.0)
#: a proxy triangle whose corners' images are this many times further apart than its corners (in units of the
#: proxies' spacings) straddles a seam of the map: a continuous map of a near-isometry stretches it about 1x
SEAM_STRETCH = 3.0
#: a mesh above 4x this many times the proxy size is first clustered to this many times it
CLUSTER_FIRST = 20
#: pieces of a proxy holding less than this fraction of its vertices are dropped (their input vertices
#: are lifted through the nearest kept proxy vertex)
DEBRIS = 0.05
#: the way out named by the errors of a proxy
_FULL_RESOLUTION = "work at full resolution (`--proxy 0`; from Python: run(proxy=0), or the segmenter's segment())"


def _canonical(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mesh ``V`` ``(n, 3)``, ``F`` ``(m, 3)`` with its vertices in lexicographic order of their coordinates,
    each face rotated to start at its least vertex (orientation kept) and the faces sorted: one order
    whatever order the mesh came in."""
    order = np.lexsort(np.asarray(V).T[::-1])
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    G = rank[np.asarray(F, dtype=np.int64)]
    first = np.argmin(G, axis=1)
    G = np.stack([G[np.arange(len(G)), (first + j) % 3] for j in range(3)], axis=1)
    return np.asarray(V, dtype=np.float64)[order], G[np.lexsort(G.T[::-1])].astype(np.int32)


def match_memory(n: int, proxy: int | None) -> float:
    """Estimated peak bytes of ``shape-toolkit match`` on two shapes of ``n`` vertices in all: at full resolution
    (``proxy`` 0 or None: :data:`MATCH_FULL_MEMORY`), or through proxies of ``proxy`` vertices (:data:`MATCH_MEMORY`,
    and never less than a full-resolution match of two shapes of 1.5 ``proxy`` vertices, the largest matched
    directly)."""
    return _pair_memory(n, proxy, MATCH_MEMORY, MATCH_FULL_MEMORY)


def _pair_memory(n: int, proxy: int | None, proxied: tuple[float, float], full: tuple[float, float]) -> float:
    """Bytes ``a + b n`` of a command on two shapes of ``n`` vertices in all: ``full`` at full resolution (``proxy`` 0
    or None), else ``proxied``, and never less than ``full`` for two shapes of 1.5 ``proxy`` vertices (the largest
    run directly)."""
    direct = full[0] + full[1] * (min(n, 3 * proxy) if proxy else n)
    return max(proxied[0] + proxied[1] * n, direct) if proxy else direct


def label_transfer_memory(n: int, proxy: int | None) -> float:
    """Estimated peak bytes of ``shape-toolkit transfer-labels`` on two shapes of ``n`` vertices in all: at full
    resolution (``proxy`` 0 or None: :data:`LABEL_TRANSFER_FULL_MEMORY`), or through proxies of ``proxy`` vertices
    (:data:`LABEL_TRANSFER_MEMORY`, and never less than a full-resolution transfer between two shapes of 1.5 ``proxy``
    vertices, the largest labelled directly). An estimate for refusing shapes before reading them, not a bound."""
    return _pair_memory(n, proxy, LABEL_TRANSFER_MEMORY, LABEL_TRANSFER_FULL_MEMORY)


def check_proxy_size(n_vertices: object) -> int:
    """``n_vertices`` as the vertex count of a proxy: an integer >= 100, else a :class:`ParameterError`."""
    if isinstance(n_vertices, (bool, np.bool_)) or not isinstance(n_vertices, (int, np.integer)) or n_vertices < 100:
        raise ParameterError(f"the proxy size must be an integer >= 100, got {n_vertices!r} (0 turns the proxy off: "
                             "`--proxy 0`, or Pipeline.run(proxy=0) from Python)")
    return int(n_vertices)


def make_proxy(shape: Shape, n_vertices: int = PROXY_VERTICES) -> tuple[Shape, np.ndarray]:
    """A proxy of about ``n_vertices`` vertices and the input vertex ``(p,)`` of each of its vertices
    (decimation moves no vertex; clouds: farthest-point samples, with their given normals if any)."""
    n_vertices = check_proxy_size(n_vertices)
    V = np.asarray(shape.vertices, dtype=np.float64)
    if not shape.is_mesh:
        ids = farthest_point_sampling(V, int(n_vertices), ordered=False)
        normals = None if shape.normals is None else shape.normals[ids]
        return Shape(V[ids], None, name=f"{shape.name}-proxy", normals=normals), ids
    import pymeshlab
    from scipy.spatial import cKDTree

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=np.asarray(shape.faces, dtype=np.int32)))
    if len(V) > 4 * CLUSTER_FIRST * n_vertices:
        # quadric edge collapse costs minutes at 10^6 vertices: first a vertex clustering (linear time) to
        # about CLUSTER_FIRST x the proxy size, on cells of the matching size; proxy vertices are then moved
        # to their nearest input vertex below
        cell = float(np.sqrt(shape.area / (CLUSTER_FIRST * n_vertices)))
        ms.meshing_decimation_clustering(threshold=pymeshlab.PureValue(cell))
        # its output comes in an order that changes from run to run (the same mesh otherwise), and the repairs
        # and the collapse below depend on the order: put it in a canonical one, so the proxy is reproducible
        cv, cf = _canonical(ms.current_mesh().vertex_matrix(), ms.current_mesh().face_matrix())
        ms = pymeshlab.MeshSet()  # (the former set, and its meshes, are freed here)
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=cv, face_matrix=cf))
        # clustering leaves duplicate faces and non-manifold edges and vertices, around which a
        # topology-preserving edge collapse refuses to work: a 10^6-vertex scan then stopped at 4-5x the
        # proxy size (22k-26k vertices, and the proxy pipeline took 10x longer). Repaired, it reaches it.
        ms.meshing_remove_duplicate_faces()
        ms.meshing_remove_null_faces()
        ms.meshing_repair_non_manifold_edges()
        ms.meshing_repair_non_manifold_vertices()
        ms.meshing_remove_unreferenced_vertices()
    ms.meshing_decimation_quadric_edge_collapse(
        targetfacenum=int(2 * n_vertices), optimalplacement=False, preservetopology=True, preservenormal=True,
        qualitythr=0.3, autoclean=True,
    )
    m = ms.current_mesh()
    pv = np.asarray(m.vertex_matrix(), dtype=np.float64)
    pf = np.asarray(m.face_matrix(), dtype=np.int64)
    if len(pf) == 0:
        raise InvalidShapeError(f"{shape!r}: decimation to {n_vertices} vertices left no face; {_FULL_RESOLUTION}")
    ids = np.asarray(cKDTree(V).query(pv)[1], dtype=np.int64)  # exact unless clustered: no vertex moved
    # a proxy the spectra can take: no flat face (the cotangent weights' rule), no vertex on no face,
    # no two proxy vertices on one input vertex
    pf = pf[~flat_faces(V[ids], pf)]
    uniq, inv = np.unique(ids, return_inverse=True)
    pf = inv.ravel()[pf]
    pf = pf[(pf[:, 0] != pf[:, 1]) & (pf[:, 1] != pf[:, 2]) & (pf[:, 0] != pf[:, 2])]
    if len(pf):  # debris: pieces of under DEBRIS of the proxy, cut off by the repairs (a whole part is kept)
        _, comp = edge_components(len(uniq), np.concatenate([pf[:, [0, 1]], pf[:, [1, 2]]]))
        size = np.bincount(comp[np.unique(pf)], minlength=comp.max() + 1)
        pf = pf[size[comp[pf[:, 0]]] >= DEBRIS * size.sum()]
    used = np.unique(pf)
    remap = np.full(len(uniq), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    if len(used) < 4:
        raise InvalidShapeError(f"{shape!r}: decimation to {n_vertices} vertices left no surface (every piece under "
                                f"{DEBRIS:.0%} of it: a triangle soup?); {_FULL_RESOLUTION}")
    return Shape(V[uniq[used]], remap[pf], name=f"{shape.name}-proxy"), uniq[used]


def on_surface(points: np.ndarray, mesh: Shape) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest points ``(n, 3)`` of ``points`` on the triangles of ``mesh`` (libigl's AABB tree), the corners
    ``(n, 3)`` of the triangle each lies on and their barycentric weights ``(n, 3)``."""
    import igl

    V, F = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
    _, face, closest = igl.point_mesh_squared_distance(np.asarray(points, dtype=np.float64), V, F)
    tri = F[face]
    w = igl.barycentric_coordinates(closest, *(np.ascontiguousarray(V[tri[:, j]]) for j in range(3)))
    w = np.clip(np.nan_to_num(w, nan=1.0 / 3.0), 0.0, None)  # the closest point lies on its triangle
    return closest, tri, w / np.maximum(w.sum(axis=1, keepdims=True), 1e-300)


def values_from_proxy(values: np.ndarray, shape: Shape, proxy: Shape) -> np.ndarray:
    """Per-vertex ``values`` ``(p, ...)`` of ``proxy`` carried to every vertex of ``shape`` ``(n, ...)``: each takes
    the value of the nearest corner of its closest point on a mesh proxy (as segment labels are carried), of its
    nearest proxy point on a cloud one."""
    from scipy.spatial import cKDTree

    values = np.asarray(values)
    if proxy.is_mesh:
        _, tri, w = on_surface(shape.vertices, proxy)
        return values[tri[np.arange(len(tri)), np.argmax(w, axis=1)]]
    return values[cKDTree(np.asarray(proxy.vertices, dtype=np.float64)).query(np.asarray(shape.vertices))[1]]


def proxy_seeds(seeds: np.ndarray, source: Shape, target: Shape, ids_s: np.ndarray, ids_t: np.ndarray) -> np.ndarray:
    """Seed pairs ``(s, 2)`` (checked against the shapes) moved to the proxies: each end to the nearest of the proxy
    vertices ``ids_s`` of ``source`` and ``ids_t`` of ``target`` (ids into the proxies, int64 ``(s', 2)``). Seeds
    whose sources land on one proxy vertex keep the first one's pair: a proxy vertex gets one target."""
    from scipy.spatial import cKDTree

    seeds = check_seeds(seeds, source.n_vertices, target.n_vertices, allow_empty=False)
    Vs, Vt = np.asarray(source.vertices), np.asarray(target.vertices)
    ns = cKDTree(Vs[ids_s]).query(Vs[seeds[:, 0]])[1]
    nt = cKDTree(Vt[ids_t]).query(Vt[seeds[:, 1]])[1]
    # two seeds near one proxy vertex: check_seeds would refuse both
    return first_per_source(np.column_stack([ns, nt]).astype(np.int64))


def _spread(P: np.ndarray) -> np.ndarray:
    """Longest side ``(n,)`` of each triangle of corner positions ``P`` ``(n, 3, 3)`` (side by side, no ``(n, 3, 3)``
    temporary: at 10^6 vertices those cost 1.5 s a call in fresh memory, this 0.1 s)."""
    sides = [P[:, i] - P[:, (i + 1) % 3] for i in range(3)]
    return np.sqrt(np.maximum.reduce([np.einsum("ij,ij->i", d, d) for d in sides]))


def _weights(points: np.ndarray, proxy: Shape) -> tuple[np.ndarray, np.ndarray]:
    """Three proxy vertices ``(n, 3)`` for each of ``points`` ``(n, 3)`` and their weights ``(n, 3)`` (rows sum to
    1): a mesh proxy, the corners of the triangle of the closest point, barycentric; a cloud, the three nearest
    proxy points by inverse distance (a point on a proxy point: that one alone)."""
    from scipy.spatial import cKDTree

    if proxy.is_mesh:
        _, tri, w = on_surface(points, proxy)
        return tri, w
    k = min(3, proxy.n_vertices)
    d, nb = cKDTree(np.asarray(proxy.vertices, dtype=np.float64)).query(np.asarray(points, dtype=np.float64), k=k)
    d, nb = d.reshape(len(d), k), nb.reshape(len(nb), k)
    w = 1.0 / np.maximum(d, 1e-300)
    w[d[:, 0] == 0] = np.eye(k)[0]
    return nb, w / w.sum(axis=1, keepdims=True)


def interpolated_map(source: Shape, target: Shape, source_proxy: Shape, target_proxy: Shape,
                     proxy_map: np.ndarray) -> np.ndarray:
    """Full point map ``(n_source,)`` from the map ``proxy_map`` between the proxies (source proxy vertex -> target
    proxy vertex, ``-1``: unmatched): each source vertex's three proxy vertices and weights (:func:`_weights`:
    barycentric on a mesh proxy's triangle, inverse distance among a cloud proxy's nearest points); their images,
    averaged with those weights, give a point; the image is the target vertex nearest it (for a mesh target, the
    one whose closest point on the target proxy is nearest it, so a mesh onto itself through one proxy is the
    identity). Where the images are more than :data:`SEAM_STRETCH` times further apart than the three proxy
    vertices (scaled by the two proxies' spacings: shapes in any units), they straddle a seam of the map and the
    heaviest one's image is taken instead of a point between. Unmatched proxy vertices take the image of their
    nearest matched one."""
    from scipy.spatial import cKDTree

    raw = np.asarray(proxy_map)
    integral = raw.dtype.kind in "iu" or (raw.dtype.kind == "f" and bool(np.all(np.isfinite(raw) & (raw % 1 == 0))))
    pm = raw.astype(np.int64) if integral else raw
    if (not integral or pm.shape != (source_proxy.n_vertices,)
            or (pm.size and (pm.max() >= target_proxy.n_vertices or pm.min() < -1))):
        raise ParameterError(f"the proxy map must give one target proxy vertex (an integer < "
                             f"{target_proxy.n_vertices}, or -1) for each of the {source_proxy.n_vertices} source "
                             "proxy vertices")
    ok = np.flatnonzero(pm >= 0)
    if len(ok) < 3:
        raise ParameterError(f"the proxy map matched {len(ok)} vertices: too few to lift (need 3); "
                             f"{_FULL_RESOLUTION}")
    Ps, Pt = np.asarray(source_proxy.vertices, dtype=np.float64), np.asarray(target_proxy.vertices, dtype=np.float64)
    if len(ok) < len(pm):
        pm = pm.copy()
        bad = np.flatnonzero(pm < 0)
        pm[bad] = pm[ok[cKDTree(Ps[ok]).query(Ps[bad])[1]]]
    corners, w = _weights(source.vertices, source_proxy)
    img = Pt[pm[corners]]  # (n, 3 corners, 3)
    point = np.einsum("nc,ncd->nd", w, img)
    scale = np.median(cKDTree(Pt).query(Pt, k=2)[0][:, 1]) / np.median(cKDTree(Ps).query(Ps, k=2)[0][:, 1])
    seam = _spread(img) > SEAM_STRETCH * scale * _spread(Ps[corners])
    point[seam] = img[seam, np.argmax(w[seam], axis=1)]
    Xt = on_surface(target.vertices, target_proxy)[0] if target_proxy.is_mesh else np.asarray(target.vertices)
    return np.asarray(cKDTree(Xt).query(point)[1], dtype=np.int64)


def lift_map(
    source: Shape,
    target: Shape,
    src_ids: np.ndarray,
    tgt_ids: np.ndarray,
    proxy_map: np.ndarray,
    *,
    proxies: tuple[Shape, Shape] | None = None,
) -> tuple[np.ndarray, dict]:
    """Full point map ``(n_source,)`` from the proxy map ``proxy_map`` (proxy source vertex -> proxy target vertex;
    ``src_ids`` / ``tgt_ids``: the full vertex of each proxy vertex), interpolated (:func:`interpolated_map`) on the
    ``proxies`` (meshes of those vertices, as :func:`make_proxy` gives them; None: the proxy vertices as clouds).
    Returns the map and an info dict (``lift``: how; ``cpu_seconds``: of the interpolation)."""
    src_ids = check_vertex_ids(src_ids, source.n_vertices, "src_ids", allow_empty=False)
    tgt_ids = check_vertex_ids(tgt_ids, target.n_vertices, "tgt_ids", allow_empty=False)
    if proxies is None:
        proxies = (Shape(np.asarray(source.vertices)[src_ids], None, name=f"{source.name}-proxy"),
                   Shape(np.asarray(target.vertices)[tgt_ids], None, name=f"{target.name}-proxy"))
    if proxies[0].n_vertices != len(src_ids) or proxies[1].n_vertices != len(tgt_ids):
        raise ParameterError(f"the proxies have {proxies[0].n_vertices} and {proxies[1].n_vertices} vertices, "
                             f"src_ids {len(src_ids)} and tgt_ids {len(tgt_ids)}: they must agree")
    c0 = time.process_time()
    out = interpolated_map(source, target, proxies[0], proxies[1], proxy_map)
    how = {True: "barycentric on the proxy's triangles", False: "inverse distance among the nearest proxy points"}
    return out, {"proxy_vertices": [int(len(src_ids)), int(len(tgt_ids))],
                 "lift": f"interpolated: {how[proxies[0].is_mesh]}",
                 "cpu_seconds": {"interpolation": time.process_time() - c0}}


def transfer_labels_through_proxies(train: Shape, train_labels: np.ndarray, test: Shape, proxy: int = PROXY_VERTICES,
                                    seeds: np.ndarray | None = None, **kwargs: Any) -> tuple[np.ndarray, Any]:
    """Labels ``(n_test,)`` int64 of ``test`` from ``train_labels`` ``(n_train,)`` by
    :func:`~shape_toolkit.results.label_transfer.probabilistic_label_transfer` (``kwargs``: its ``matcher``,
    ``matcher_params``, ``preset``) run on proxies of ``proxy`` vertices of the shapes above 1.5 ``proxy``: the
    training labels read at the training proxy's vertices (each a vertex of the shape), seeds ``[train, test]`` moved
    to their nearest proxy vertices, and each test vertex given the label of its nearest test proxy vertex
    (:func:`values_from_proxy`). Returns the labels and the proxies' correspondence, whose ``info["proxy"]`` holds
    each proxy's vertex ids in its shape (``train_ids``, ``test_ids``). The alignment's search and the EM registration
    cost more than linearly in the vertex count: PSB meshes 1 and 2 split to 42k and 90k vertices took 330 s of CPU
    and 1.1 GB at full resolution, 33 s and 0.3 GB through proxies (one run, 2026-12-06)."""
    from shape_toolkit.results.label_transfer import check_train_labels, probabilistic_label_transfer

    proxy = check_proxy_size(proxy)
    lab = check_train_labels(train, train_labels)
    ptr, ids_tr = make_proxy(train, proxy) if train.n_vertices > 1.5 * proxy else (train, np.arange(train.n_vertices))
    pte, ids_te = make_proxy(test, proxy) if test.n_vertices > 1.5 * proxy else (test, np.arange(test.n_vertices))
    pseeds = None if seeds is None else proxy_seeds(seeds, train, test, ids_tr, ids_te)
    if not np.any(lab[ids_tr] >= 0):
        raise ParameterError(f"no labelled vertex of the train shape is among its proxy's {ptr.n_vertices}; label "
                             "more of it, or transfer at full resolution (`--proxy 0`; probabilistic_label_transfer)")
    out, corr = probabilistic_label_transfer(ptr, lab[ids_tr], pte, seeds=pseeds, **kwargs)
    if pte is not test:
        out = values_from_proxy(out, test, pte)
    corr.info["proxy"] = {"train_vertices": int(train.n_vertices), "test_vertices": int(test.n_vertices),
                          "train_ids": ids_tr, "test_ids": ids_te}
    return np.asarray(out, dtype=np.int64), corr
