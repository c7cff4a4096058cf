"""Matching large shapes through proxies: solve on a decimated copy, lift to full resolution.

Every matching pipeline costs more than linearly in the vertex count (spectra with many eigenpairs,
nearest neighbours in spectral space over all vertex pairs), so a scan of 10^5-10^6 vertices is
matched through proxies of :data:`PROXY_VERTICES` vertices:

1. **Proxy.** A mesh is decimated by quadric edge collapse (pymeshlab) *without* moving vertices, so
   every proxy vertex is a vertex of the input; a point cloud is subsampled by farthest points.
2. **Solve** the pipeline on the two proxies (its own spectra, hypotheses and checks, as at 5k).
3. **Lift.** A mesh's proxy map is interpolated on the proxies' triangles (:func:`interpolated_map`):
   each vertex's closest point on the source proxy, the images of its triangle's corners averaged with its
   barycentric weights, and the target vertex whose closest point on the target proxy is nearest that point
   (the nearest corner's image where the corners' images are far apart: a seam of the map). O(n log n): libigl's
   AABB trees and a k-d tree; no eigenproblem of the full size.

   On tuning pairs (dogs, FAUST people 0-1; 7 pairs) remeshed independently to 58k vertices it gave 0.0143-0.0259
   where the spectral lift below gave 0.0204-0.0289 (better on all 7, by 0.007-0.011 on FAUST), for 0.55-0.71 s
   of CPU against 2.6-4.8 s, and slightly better than each vertex through its nearest proxy vertex (0.0146-0.0274):
   40 eigenfunctions localise a vertex more coarsely than the proxy map does.

   A cloud's proxy has no triangles: its map is lifted spectrally. On ``LIFT_K`` Laplace-Beltrami eigenfunctions
   of the full shapes, the functional map the ``q`` proxy correspondences imply is fitted (least squares), refined
   by ZoomOut iterations on the proxy vertices, and turned into the full point map by a *local* search: each
   source vertex starts at the target vertex, among the ``candidates`` nearest (in space) to the image of its
   nearest proxy vertex, whose spectral coordinates best match its own through the functional map, and then
   descends along the target's edges (a cloud: its kNN graph) while a neighbour matches better. No all-pairs
   search, and no search whose size grows with the input: cost ``O(n (candidates + log n + walk))`` after the
   spectra.

The proxy size is a vertex count, so the result does not depend on units or on the input's
resolution; ``PROXY_VERTICES`` is the resolution the pipelines were built and measured at (the
5k-vertex datasets).
"""

from __future__ import annotations

import time

import numpy as np

from shape_toolkit.core.geometry import edge_components, farthest_point_sampling, nearest_neighbors
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import InvalidShapeError, ParameterError
from shape_toolkit.features.basis import basis_of, fmap_from_p2p
from shape_toolkit.plugins.weightings.cotangent import flat_faces

__all__ = ["PROXY_VERTICES", "LIFT_K", "LIFT_CANDIDATES", "make_proxy", "lift_map", "descend", "interpolated_map",
           "on_surface"]

#: vertices of each proxy; shapes up to 1.5x this are matched directly
PROXY_VERTICES = 5000
#: eigenfunctions of the full shapes the lift uses
LIFT_K = 40
#: target vertices of the first guess of the lift's local search (then a descent along edges)
LIFT_CANDIDATES = 32
#: a proxy triangle whose corners' images are this many times further apart than its corners (in units of the
#: proxies' spacings) straddles a seam of the map: a continuous map of a near-isometry stretches it about 1x
SEAM_STRETCH = 3.0
#: neighbours of a cloud's point in the graph the descent walks (a mesh: its edges)
WALK_NEIGHBOURS = 8
#: a mesh above 4x this many times the proxy size is first clustered to this many times it
CLUSTER_FIRST = 20
#: pieces of a proxy holding less than this fraction of its vertices are dropped (their input vertices
#: are lifted through the nearest kept proxy vertex)
DEBRIS = 0.05


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


def make_proxy(shape: Shape, n_vertices: int = PROXY_VERTICES) -> tuple[Shape, np.ndarray]:
    """A proxy of about ``n_vertices`` vertices and the input vertex ``(p,)`` of each of its vertices
    (decimation moves no vertex; clouds: farthest-point samples)."""
    if not isinstance(n_vertices, (int, np.integer)) or n_vertices < 100:
        raise ParameterError(f"the proxy size must be an integer >= 100, got {n_vertices!r}")
    V = np.asarray(shape.vertices, dtype=np.float64)
    if not shape.is_mesh:
        ids = np.sort(farthest_point_sampling(V, int(n_vertices)))
        return Shape(V[ids], None, name=f"{shape.name}-proxy"), ids
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
        raise InvalidShapeError(f"{shape!r}: decimation to {n_vertices} vertices left no face")
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
        raise InvalidShapeError(f"{shape!r}: decimation to {n_vertices} vertices left no surface")
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


def _spread(P: np.ndarray) -> np.ndarray:
    """Longest side ``(n,)`` of each triangle of corner positions ``P`` ``(n, 3, 3)``."""
    return np.linalg.norm(P - P[:, [1, 2, 0]], axis=2).max(axis=1)


def interpolated_map(source: Shape, target: Shape, source_proxy: Shape, target_proxy: Shape,
                     proxy_map: np.ndarray) -> np.ndarray:
    """Full point map ``(n_source,)`` from the map ``proxy_map`` between the mesh proxies (source proxy vertex ->
    target proxy vertex, ``-1``: unmatched), interpolated on the proxies' surfaces: each source vertex's closest
    point on the source proxy has barycentric weights on its triangle's corners; the corners' images, averaged
    with those weights, give a point on the target proxy; the image is the target vertex whose own closest point
    on the target proxy is nearest it (so a shape onto itself through one proxy is the identity). Where the
    corners' images are more than :data:`SEAM_STRETCH` times further apart than the corners (scaled by the two
    proxies' spacings: shapes in any units), the triangle straddles a seam of the map and the nearest corner's
    image is taken instead of a point between. Unmatched proxy vertices take the image of their nearest matched
    one."""
    from scipy.spatial import cKDTree

    pm = np.asarray(proxy_map, dtype=np.int64)
    if pm.shape != (source_proxy.n_vertices,) or (pm.size and pm.max() >= target_proxy.n_vertices):
        raise ParameterError(f"the proxy map must give one target proxy vertex (< {target_proxy.n_vertices}, or -1) "
                             f"for each of the {source_proxy.n_vertices} source proxy vertices")
    ok = np.flatnonzero(pm >= 0)
    if len(ok) < 3:
        raise ParameterError(f"the proxy map matched {len(ok)} vertices: too few to lift (need 3)")
    Ps, Pt = np.asarray(source_proxy.vertices, dtype=np.float64), np.asarray(target_proxy.vertices, dtype=np.float64)
    if len(ok) < len(pm):
        pm = pm.copy()
        bad = np.flatnonzero(pm < 0)
        pm[bad] = pm[ok[cKDTree(Ps[ok]).query(Ps[bad])[1]]]
    _, tri, w = on_surface(source.vertices, source_proxy)
    img = Pt[pm[tri]]  # (n, 3 corners, 3)
    point = np.einsum("nc,ncd->nd", w, img)
    scale = np.median(cKDTree(Pt).query(Pt, k=2)[0][:, 1]) / np.median(cKDTree(Ps).query(Ps, k=2)[0][:, 1])
    seam = _spread(img) > SEAM_STRETCH * scale * _spread(Ps[tri])
    point[seam] = img[seam, np.argmax(w[seam], axis=1)]
    return np.asarray(cKDTree(on_surface(target.vertices, target_proxy)[0]).query(point)[1], dtype=np.int64)


def lift_map(
    source: Shape,
    target: Shape,
    src_ids: np.ndarray,
    tgt_ids: np.ndarray,
    proxy_map: np.ndarray,
    *,
    k: int = LIFT_K,
    candidates: int | None = None,
    iterations: int = 3,
    proxies: tuple[Shape, Shape] | None = None,
) -> tuple[np.ndarray, dict]:
    """Full point map ``(n_source,)`` from the proxy map ``proxy_map`` (proxy source vertex -> proxy
    target vertex; ``src_ids`` / ``tgt_ids``: the full vertex of each proxy vertex); see the module
    docstring. With two mesh ``proxies`` (of the vertices ``src_ids`` and ``tgt_ids``), the map is interpolated on
    their triangles (:func:`interpolated_map`); else (clouds) lifted spectrally: ``k`` eigenfunctions of the full
    shapes, ``candidates`` target vertices for each source vertex's first guess (default
    :data:`LIFT_CANDIDATES`, whatever the sizes), refined by the descent of :func:`descend`. Returns the map and
    an info dict (``lift``: which; ``cpu_seconds``: of the interpolation, or of the full shapes' spectra and of
    the descent)."""
    from scipy.spatial import cKDTree

    from shape_toolkit.spectra import shape_spectrum

    proxy_map = np.asarray(proxy_map, dtype=np.int64)
    if proxies is not None and proxies[0].is_mesh and proxies[1].is_mesh:
        if proxies[0].n_vertices != len(proxy_map) or len(src_ids) != len(proxy_map):
            raise ParameterError(f"the source proxy has {proxies[0].n_vertices} vertices, the proxy map "
                                 f"{len(proxy_map)} and src_ids {len(src_ids)}: they must agree")
        c0 = time.process_time()
        out = interpolated_map(source, target, proxies[0], proxies[1], proxy_map)
        return out, {"proxy_vertices": [int(len(src_ids)), int(len(tgt_ids))],
                     "lift": "interpolated on the proxies' triangles",
                     "cpu_seconds": {"interpolation": time.process_time() - c0}}
    ok = proxy_map >= 0
    if ok.sum() < 3 * k:
        raise ParameterError(f"the proxy map matched {int(ok.sum())} vertices: too few to lift (need {3 * k})")
    k = int(min(k, source.n_vertices - 2, target.n_vertices - 2))
    c0 = time.process_time()
    bs = basis_of(shape_spectrum(source, k + 1), k)
    bt = basis_of(shape_spectrum(target, k + 1), k)
    cpu = {"spectra": time.process_time() - c0}
    rows = np.asarray(src_ids, dtype=np.int64)[ok]
    cols = np.asarray(tgt_ids, dtype=np.int64)
    T_rows = cols[proxy_map[ok]]
    C = fmap_from_p2p(bs, bt, T_rows, k, k, rows=rows)
    e_s = np.asarray(bs.evecs[:, :k], dtype=np.float64)
    e_t = np.asarray(bt.evecs[:, :k], dtype=np.float64)
    for _ in range(int(iterations)):  # ZoomOut at fixed k on the proxy vertices, full-resolution bases
        T_rows = cols[nearest_neighbors(e_t[cols] @ C.T, e_s[rows], dtype=np.float32)[1]]
        C = fmap_from_p2p(bs, bt, T_rows, k, k, rows=rows)
    # local search: the image of each source vertex's nearest proxy vertex, and its spatial neighbours
    n_s, n_t = source.n_vertices, target.n_vertices
    candidates = int(min(LIFT_CANDIDATES if candidates is None else candidates, n_t))
    if candidates < 1:
        raise ParameterError(f"candidates must be >= 1, got {candidates}")
    _, near = cKDTree(np.asarray(source.vertices)[rows]).query(np.asarray(source.vertices))
    centre = T_rows[near]  # (n_s,) full target vertex
    tree_t = cKDTree(np.asarray(target.vertices))
    pts = (e_t @ C.T).astype(np.float32)  # target vertices in the source's spectral coordinates
    q = e_s.astype(np.float32)
    out = np.empty(n_s, dtype=np.int64)
    # blocks of source vertices: memory ~ block x candidates x k, never n x candidates (12 GB at 10^6)
    step = max(1, 2**22 // max(1, candidates * k))
    for a in range(0, n_s, step):
        c = np.asarray(tree_t.query(np.asarray(target.vertices)[centre[a : a + step]], k=candidates)[1],
                       dtype=np.int64).reshape(-1, candidates)
        d = ((pts[c] - q[a : a + step, None, :]) ** 2).sum(axis=2)
        out[a : a + step] = c[np.arange(len(c)), np.argmin(d, axis=1)]
    c0 = time.process_time()
    out, steps = descend(target, pts, q, out)
    cpu["descent"] = time.process_time() - c0
    info = {"proxy_vertices": [int(len(src_ids)), int(len(tgt_ids))], "lift": "spectral", "lift_k": k,
            "candidates": candidates, "lift_iterations": int(iterations), "walk_steps": steps, "cpu_seconds": cpu}
    return out, info


def descend(target: Shape, pts: np.ndarray, q: np.ndarray, start: np.ndarray) -> tuple[np.ndarray, int]:
    """Greedy descent on ``target``'s graph (mesh edges; a cloud's symmetrised kNN graph): each query
    ``q[i]`` ``(m, d)`` moves from target vertex ``start[i]`` ``(m,)`` to the neighbour whose ``pts`` row
    ``(n_target, d)`` is nearest to it, while that is nearer than where it stands. Returns the final
    vertices ``(m,)`` and the number of sweeps (each query moves at most one edge per sweep)."""
    import scipy.sparse as sp

    from shape_toolkit.core.graph import knn_edges

    n = target.n_vertices
    if target.is_mesh:
        e = target.edges
    else:
        e = knn_edges(np.asarray(target.vertices), min(WALK_NEIGHBOURS, n - 1))
    adj = sp.coo_matrix((np.ones(2 * len(e), dtype=np.int8), (np.concatenate([e[:, 0], e[:, 1]]),
                                                              np.concatenate([e[:, 1], e[:, 0]]))),
                        shape=(n, n)).tocsr()
    ptr, nbr = adj.indptr, adj.indices
    cur = np.asarray(start, dtype=np.int64).copy()
    best = ((pts[cur] - q) ** 2).sum(axis=1)
    active = np.arange(len(cur))
    sweeps = 0
    block = max(1, 2**20 // max(1, q.shape[1]))  # queries per block: memory ~ block x degree x d
    while active.size:
        sweeps += 1
        moved_all = []
        for a in range(0, active.size, block):
            act = active[a : a + block]
            deg = ptr[cur[act] + 1] - ptr[cur[act]]
            owner = np.repeat(np.arange(act.size), deg)  # row of ``act`` each neighbour belongs to
            cand = nbr[np.repeat(ptr[cur[act]] - np.cumsum(deg) + deg, deg) + np.arange(owner.size)].astype(np.int64)
            d = ((pts[cand] - q[act[owner]]) ** 2).sum(axis=1)
            order = np.lexsort((d, owner))  # per owner, the nearest neighbour first
            head = order[np.r_[True, owner[order][1:] != owner[order][:-1]]] if order.size else order
            moved = d[head] < best[act[owner[head]]]
            idx = act[owner[head][moved]]
            cur[idx], best[idx] = cand[head[moved]], d[head][moved]
            moved_all.append(idx)
        active = np.concatenate(moved_all)
    return cur, sweeps
