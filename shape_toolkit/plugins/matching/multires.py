"""Matching large shapes through proxies: solve on a decimated copy, lift to full resolution.

Every matching pipeline costs more than linearly in the vertex count (spectra with many eigenpairs,
nearest neighbours in spectral space over all vertex pairs), so a scan of 10^5-10^6 vertices is
matched through proxies of :data:`PROXY_VERTICES` vertices:

1. **Proxy.** A mesh is decimated by quadric edge collapse (pymeshlab) *without* moving vertices, so
   every proxy vertex is a vertex of the input; a point cloud is subsampled by farthest points.
2. **Solve** the pipeline on the two proxies (its own spectra, hypotheses and checks, as at 5k).
3. **Lift.** The proxy point map gives ``q`` correspondences between full-resolution vertices. On
   ``LIFT_K`` Laplace-Beltrami eigenfunctions of the full shapes (for meshes, the proxies' eigenfunctions
   upsampled: interpolated linearly on the proxy's triangles at each vertex's closest point, so no
   eigenproblem of the full size is solved; :func:`upsampled_basis`), the functional map they imply is
   fitted (least squares), refined by ZoomOut iterations on the proxy vertices, and turned into the
   full point map by a *local* search: each source vertex starts at the target vertex, among the
   ``candidates`` nearest (in space) to the image of its nearest proxy vertex, whose spectral
   coordinates best match its own through the functional map, and then descends along the target's
   edges (its kNN graph for a cloud) while a neighbour matches better. No all-pairs search, and no
   search whose size grows with the input (a fixed ball of ``4 n / p`` vertices made the lift
   ``O(n^2 / p)``: 60 s CPU of a 10^6 pair): cost ``O(n (candidates + log n + walk))`` after the
   spectra, the walk a few edges (about the proxy spacing in edges, ``sqrt(n / p)``, at most).

   Upsampled against solved eigenfunctions, on tuning pairs (dogs, FAUST people 0-1) remeshed independently to
   58k vertices: the same error (0.0257-0.0306 against 0.0254-0.0289; +0.0017 at worst) for 0.9-1.0 s of lift
   CPU instead of 3.0-3.8 s (the full shapes' spectra were 2.3-2.9 s of it, 65 s at 10^6 vertices). A cloud
   (proxy without triangles) keeps the solved spectra.

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
from shape_toolkit.features.basis import Basis, basis_of, fmap_from_p2p
from shape_toolkit.plugins.weightings.cotangent import flat_faces

__all__ = ["PROXY_VERTICES", "LIFT_K", "LIFT_CANDIDATES", "make_proxy", "lift_map", "descend", "upsampled_basis"]

#: vertices of each proxy; shapes up to 1.5x this are matched directly
PROXY_VERTICES = 5000
#: eigenfunctions of the full shapes the lift uses
LIFT_K = 40
#: target vertices of the first guess of the lift's local search (then a descent along edges)
LIFT_CANDIDATES = 32
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


def upsampled_basis(shape: Shape, proxy: Shape, k: int) -> Basis:
    """The first ``k`` Laplace-Beltrami eigenfunctions of the mesh ``proxy``, carried to every vertex of ``shape``
    (which it approximates) by linear interpolation on the proxy's triangles at the vertex's closest point on the
    proxy surface (libigl's AABB tree): evecs ``(n, k)``, mass ``shape``'s vertex areas over its area."""
    import igl

    from shape_toolkit.spectra import shape_spectrum

    bp = basis_of(shape_spectrum(proxy, k + 1), k)
    V = np.asarray(shape.vertices, dtype=np.float64)
    Vp, Fp = np.asarray(proxy.vertices, dtype=np.float64), np.asarray(proxy.faces, dtype=np.int64)
    _, face, closest = igl.point_mesh_squared_distance(V, Vp, Fp)
    tri = Fp[face]
    w = igl.barycentric_coordinates(closest, *(np.ascontiguousarray(Vp[tri[:, j]]) for j in range(3)))
    w = np.clip(np.nan_to_num(w, nan=1.0 / 3.0), 0.0, None)  # closest points lie on their triangle
    w /= np.maximum(w.sum(axis=1, keepdims=True), 1e-300)
    evecs = sum(w[:, j, None] * bp.evecs[tri[:, j]] for j in range(3))
    mass = np.asarray(shape.vertex_areas, dtype=np.float64)
    return Basis(bp.evals, evecs, mass / mass.sum())


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
    docstring. ``candidates``: target vertices of each source vertex's first guess (default
    :data:`LIFT_CANDIDATES`, whatever the sizes), refined by the descent of :func:`descend`. Returns the
    map and an info dict (``cpu_seconds``: of the full shapes' spectra and of the descent)."""
    from scipy.spatial import cKDTree

    from shape_toolkit.spectra import shape_spectrum

    proxy_map = np.asarray(proxy_map, dtype=np.int64)
    ok = proxy_map >= 0
    if ok.sum() < 3 * k:
        raise ParameterError(f"the proxy map matched {int(ok.sum())} vertices: too few to lift (need {3 * k})")
    k = int(min(k, source.n_vertices - 2, target.n_vertices - 2))
    c0 = time.process_time()
    if proxies is not None and all(s.is_mesh for s in (source, target, *proxies)):
        bs, bt = upsampled_basis(source, proxies[0], k), upsampled_basis(target, proxies[1], k)
        how = "upsampled from the proxies"
    else:
        bs = basis_of(shape_spectrum(source, k + 1), k)
        bt = basis_of(shape_spectrum(target, k + 1), k)
        how = "full shapes"
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
    info = {"proxy_vertices": [int(len(src_ids)), int(len(tgt_ids))], "lift_k": k, "candidates": candidates,
            "lift_iterations": int(iterations), "lift_basis": how, "walk_steps": steps, "cpu_seconds": cpu}
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
