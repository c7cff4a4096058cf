"""Shape corruptions with the ground truth carried through (SHREC'10 transforms, thesis Table 5.2).

Every corruption is a seeded, parameterised function ``Shape -> (Shape, vertex_map)`` where
``vertex_map`` is an int64 ``(n_new,)`` array giving, for each new vertex, the original vertex it
comes from (for resampled vertices: the nearest original vertex). ``strength`` is the one knob
every corruption has, so results can be plotted against it; its unit is given per function.
:func:`carry_labels` and :func:`carry_correspondence` move ground truth onto the corrupted shape.

Corruptions compose: the name ``"glue+color-noise"`` applies ``glue`` and then ``color-noise`` to its
result (:func:`apply_corruption` with ``steps=[{glue's params}, {color-noise's params}]``), each step with
its own random state (:func:`step_seeds`), and the vertex maps composed (:func:`compose_vertex_maps`), so
the result maps straight back to the original shape.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from shape_toolkit.api.params import InstanceOf, Interval, Param, validate_params
from shape_toolkit.core.cleanup import MAX_REMESH_ITERATIONS, MAX_REMESH_VERTICES
from shape_toolkit.core.geometry import edge_components
from shape_toolkit.core.inspect import largest_face_piece
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import InvalidShapeError, ParameterError
from shape_toolkit.io.mesh import MAX_VERTICES

__all__ = [
    "CORRUPTIONS",
    "CORRUPTION_PARAMS",
    "check_corruption_params",
    "MAX_ATTEMPTS",
    "rigid_motion",
    "scaling",
    "gaussian_noise",
    "shot_noise",
    "color_noise",
    "remesh",
    "holes",
    "micro_holes",
    "shortcut",
    "glue",
    "partial",
    "crop",
    "subdivide",
    "split_triangles",
    "point_cloud",
    "apply_corruption",
    "CHAIN",
    "chain_kinds",
    "step_seeds",
    "compose_vertex_maps",
    "RESAMPLING",
    "resamples",
    "invert_vertex_map",
    "carry_labels",
    "carry_correspondence",
]

Corruption = tuple[Shape, np.ndarray]


def _identity(shape: Shape) -> np.ndarray:
    return np.arange(shape.n_vertices, dtype=np.int64)


def _checked(name: str, **values: Any) -> None:
    """The parameters ``values`` of the corruption ``name`` within their declarations (:data:`CORRUPTION_PARAMS`):
    the first check of every corruption."""
    validate_params(f"corruption {name!r}", CORRUPTION_PARAMS[name], values)


def _random_rotation(rng: np.random.Generator, angle: float) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def rigid_motion(
    shape: Shape, *, strength: float = 1.0, scale: float = 1.0, random_state: int = 0
) -> Corruption:
    """Rotate by ``strength * pi`` rad about a random axis, translate by ``strength`` bounding-box
    diagonals in a random direction and scale by ``scale`` (a point cloud's own normals turn with it); the vertex
    map is the identity."""
    _checked("rigid", strength=strength, scale=scale)
    s = float(strength)
    rng = np.random.default_rng(random_state)
    R = _random_rotation(rng, s * np.pi)
    t = rng.normal(size=3)
    t *= s * shape.diagonal / max(np.linalg.norm(t), 1e-300)
    c = shape.vertices.mean(axis=0)
    v = scale * (shape.vertices - c) @ R.T + c + t
    moved = shape.with_vertices(v)  # a cloud's own normals turn with it
    return (moved if shape.normals is None else moved.with_normals(shape.normals @ R.T)), _identity(shape)


def scaling(shape: Shape, *, strength: float = 0.5, random_state: int = 0) -> Corruption:
    """Scale about the centroid by ``1 + strength`` (uniform); the vertex map is the identity."""
    _checked("scale", strength=strength)
    s = float(strength)
    c = shape.vertices.mean(axis=0)
    return shape.with_vertices((1.0 + s) * (shape.vertices - c) + c), _identity(shape)


def _length_unit(shape: Shape) -> float:
    return shape.mean_edge_length if shape.is_mesh and shape.n_faces else 0.01 * shape.diagonal


def gaussian_noise(shape: Shape, *, strength: float = 0.1, random_state: int = 0) -> Corruption:
    """Add isotropic Gaussian noise of standard deviation ``strength`` mean edge lengths to every
    coordinate (1 % of the diagonal for point clouds); the vertex map is the identity."""
    _checked("gaussian-noise", strength=strength)
    s = float(strength)
    rng = np.random.default_rng(random_state)
    v = shape.vertices + rng.normal(scale=s * _length_unit(shape), size=shape.vertices.shape)
    return shape.with_vertices(v), _identity(shape)


def shot_noise(
    shape: Shape, *, strength: float = 0.02, magnitude: float = 3.0, random_state: int = 0
) -> Corruption:
    """Displace a fraction ``strength`` of the vertices by ``magnitude`` mean edge lengths in
    random directions (impulse noise); the vertex map is the identity."""
    _checked("shot-noise", strength=strength, magnitude=magnitude)
    s = float(strength)
    rng = np.random.default_rng(random_state)
    n = shape.n_vertices
    ids = rng.choice(n, size=int(round(s * n)), replace=False)
    d = rng.normal(size=(len(ids), 3))
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    v = np.array(shape.vertices)
    v[ids] += magnitude * _length_unit(shape) * d
    return shape.with_vertices(v), _identity(shape)


def color_noise(
    shape: Shape, *, strength: float = 0.05, gain: float = 0.9, random_state: int = 0
) -> Corruption:
    """The surface's colours as another capture would see them: each channel times ``gain`` (lighting) plus
    Gaussian noise of standard deviation ``strength`` (colour units: colours are in [0, 1]), clipped to [0, 1].
    Geometry is unchanged and the vertex map is the identity. A shape without colours is refused."""
    _checked("color-noise", strength=strength, gain=gain)
    s, g = float(strength), float(gain)
    if shape.colors is None:
        raise InvalidShapeError(f"{shape!r} has no vertex colours for 'color-noise' to change "
                                "(read a coloured file, or give Shape(..., colors=...))")
    rng = np.random.default_rng(random_state)
    c = np.clip(g * shape.colors + rng.normal(scale=s, size=shape.colors.shape), 0.0, 1.0)
    return shape.with_colors(c), _identity(shape)


def _carried_colors(shape: Shape, vmap: np.ndarray) -> np.ndarray | None:
    """Colours of the corrupted shape: they move with the surface, so each new vertex takes the
    colour of the original vertex ``vmap`` names (None when ``shape`` has none)."""
    return None if shape.colors is None else shape.colors[vmap]


def _nearest(original: np.ndarray, points: np.ndarray) -> np.ndarray:
    return cKDTree(original).query(points)[1].astype(np.int64)


def remesh(
    shape: Shape,
    *,
    strength: float = 1.0,
    n_vertices: int | None = None,
    iterations: int = 5,
    random_state: int = 0,
) -> Corruption:
    """Independent isotropic remeshing (pymeshlab, ``iterations`` passes) to about ``n_vertices`` vertices
    (default: ``strength`` times the original count), at most :data:`~shape_toolkit.core.cleanup.MAX_REMESH_VERTICES`
    (the remeshing memory budget). Every new vertex maps to its nearest original vertex.
    ``random_state`` jitters the input slightly so the new connectivity is unrelated to the old."""
    _checked("remesh", strength=strength, n_vertices=n_vertices, iterations=iterations)
    f = shape.require_faces("remesh")
    s = float(strength)
    target = int(n_vertices) if n_vertices is not None else int(round(s * shape.n_vertices))
    if target < 20:
        raise ParameterError(f"remesh target must be at least 20 vertices, got {target}")
    if target > MAX_REMESH_VERTICES:  # only from strength: n_vertices is declared within the budget
        raise ParameterError(
            f"remesh strength {s:g} asks for {target:,} vertices ({s:g} times {shape.n_vertices:,}), above the "
            f"budget of {MAX_REMESH_VERTICES:,} (shape_toolkit.core.cleanup.MAX_REMESH_VERTICES); give a smaller "
            "strength or n_vertices"
        )
    import pymeshlab

    edge = float(np.sqrt(2.0 * shape.area / (np.sqrt(3.0) * target)))
    rng = np.random.default_rng(random_state)
    v = shape.vertices + rng.normal(scale=1e-3 * shape.mean_edge_length, size=shape.vertices.shape)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=v, face_matrix=f.astype(np.int32)))
    ms.meshing_isotropic_explicit_remeshing(
        iterations=int(iterations), targetlen=pymeshlab.PureValue(edge), featuredeg=180.0
    )
    m = ms.current_mesh()
    nv = np.asarray(m.vertex_matrix(), dtype=np.float64)
    nf = np.asarray(m.face_matrix(), dtype=np.int64)
    if len(nf) == 0:
        raise InvalidShapeError("remeshing produced an empty mesh")
    used = np.zeros(len(nv), dtype=bool)
    used[nf.ravel()] = True
    remap = np.cumsum(used) - 1
    nv, nf = nv[used], remap[nf]
    vmap = _nearest(shape.vertices, nv)
    return Shape(nv, nf, shape.name, _carried_colors(shape, vmap)), vmap


def _keep(shape: Shape, keep: np.ndarray, largest: bool = True) -> Corruption:
    """Keep the vertices where ``keep`` (bool) and the faces inside them, then (optionally) the
    largest connected component; the map lists kept original ids."""
    sub, ids = shape.submesh(np.flatnonzero(keep))
    if sub.faces is None:
        raise InvalidShapeError("the corruption removed every face")
    sub2, ids2 = sub.submesh(largest_face_piece(sub) if largest else np.unique(sub.faces))
    return Shape(sub2.vertices, sub2.faces, shape.name, sub2.colors), ids[ids2]


def holes(
    shape: Shape,
    *,
    strength: float = 3,
    radius: float = 0.05,
    attempts: int = 50,
    sliver: float = 0.002,
    random_state: int = 0,
) -> Corruption:
    """Punch ``strength`` (rounded) holes in the surface, as SHREC'10's holes transform (thesis Table 5.2):
    each hole removes one patch, the vertices within ``radius`` bounding-box diagonals of a random centre
    vertex that are connected to it inside that ball.

    A hole stays a hole: one whose removal would cut a piece of more than ``sliver`` of the vertices (a paw, a
    tail, a hand) off its connected component, or remove a component, is redrawn around the next centre drawn
    from ``random_state`` (:func:`crop` is the corruption that amputates). Smaller pieces cut loose at a hole's
    rim are dropped with it, so the number of connected components never changes. After ``attempts`` centres
    for one hole without a fit, :class:`InvalidShapeError` asks for a smaller ``radius`` or fewer holes. The
    map lists the kept original ids (vertices on no triangle are dropped)."""
    _checked("holes", strength=strength, radius=radius, attempts=attempts, sliver=sliver)
    f = shape.require_faces("holes")
    k = int(round(float(strength)))
    max_piece = int(np.floor(float(sliver) * shape.n_vertices))
    if k == 0:
        return shape, _identity(shape)
    n = shape.n_vertices
    alive = np.zeros(n, dtype=bool)
    alive[f.ravel()] = True
    e = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    n0, comp0 = edge_components(n, e)
    adj = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    adj = (adj + adj.T).tocsr()
    tree = cKDTree(shape.vertices)
    rng = np.random.default_rng(random_state)
    for h in range(k):
        for _ in range(int(attempts)):
            live = np.flatnonzero(alive)
            centre = int(live[rng.integers(live.size)])
            ball = np.asarray(tree.query_ball_point(shape.vertices[centre], radius * shape.diagonal))
            ball = ball[alive[ball]]
            _, lab = connected_components(adj[ball][:, ball], directed=False)
            trial = alive.copy()
            trial[ball[lab == lab[np.flatnonzero(ball == centre)[0]]]] = False
            ok_face = trial[f].all(axis=1)
            used = np.zeros(n, dtype=bool)
            used[f[ok_face].ravel()] = True
            if np.unique(comp0[used]).size < np.unique(comp0[alive]).size:
                continue  # a whole component removed
            _, piece = edge_components(n, e[np.repeat(ok_face, 3)])
            sizes = np.bincount(piece[used], minlength=n)
            pid = np.flatnonzero(sizes)
            owner = np.zeros(n, dtype=np.int64)
            owner[piece[used]] = comp0[used]
            porig, psize = owner[pid], sizes[pid]
            order = np.lexsort((-psize, porig))  # per original component, its largest piece first
            first = np.ones(order.size, dtype=bool)
            first[1:] = porig[order][1:] != porig[order][:-1]
            cut_off = np.bincount(porig[order][~first], psize[order][~first], minlength=n0)
            if cut_off.max() > max_piece:
                continue  # the hole would detach a part
            kept = np.zeros(n, dtype=bool)
            kept[pid[order][first]] = True
            alive = used & kept[piece]
            break
        else:
            raise InvalidShapeError(
                f"holes: no place for hole {h + 1} of {k} (radius {radius} diagonals) that keeps every part "
                f"attached, after {attempts} centres; try a smaller radius, fewer holes or another random_state"
            )
    return _keep(shape, alive, largest=False)


def micro_holes(shape: Shape, *, strength: float = 0.02, random_state: int = 0) -> Corruption:
    """Remove a fraction ``strength`` of single vertices at random (each leaves a one-ring
    hole); the largest remaining component is kept."""
    _checked("micro-holes", strength=strength)
    shape.require_faces("micro_holes")
    s = float(strength)
    rng = np.random.default_rng(random_state)
    keep = np.ones(shape.n_vertices, dtype=bool)
    keep[rng.choice(shape.n_vertices, size=int(round(s * shape.n_vertices)), replace=False)] = False
    return _keep(shape, keep)


def shortcut(
    shape: Shape, *, strength: float = 1, min_ratio: float = 1.5, random_state: int = 0
) -> Corruption:
    """Topological shortcuts ("merging hands"): glue ``strength`` (rounded) pairs of vertices
    that are close in space but far along the surface (the largest geodesic / Euclidean ratios
    from random seeds, at least ``min_ratio``) with a bridge of two triangles. Vertices are
    unchanged: the map is the identity."""
    _checked("shortcut", strength=strength, min_ratio=min_ratio)
    f = shape.require_faces("shortcut")
    k = int(round(float(strength)))
    rng = np.random.default_rng(random_state)
    v, e, n = shape.vertices, shape.edges, shape.n_vertices
    G = sp.coo_matrix((shape.edge_lengths, (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    nbrs = sp.csr_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    nbrs = (nbrs + nbrs.T).tocsr()
    seeds = rng.choice(n, size=min(n, max(8 * k, 16)), replace=False)
    geo = dijkstra(G, directed=False, indices=seeds)
    new_faces = []
    used: set[int] = set()
    candidates = []
    for row, a in zip(geo, seeds):
        eu = np.linalg.norm(v - v[a], axis=1)
        ratio = np.where(np.isfinite(row) & (eu > 0), row / np.maximum(eu, 1e-300), 0.0)
        b = int(np.argmax(ratio))
        if ratio[b] >= min_ratio:
            candidates.append((-float(ratio[b]), int(a), b))
    for _, a, b in sorted(candidates):
        if len(new_faces) // 2 >= k:
            break
        if a in used or b in used:
            continue
        na = nbrs.indices[nbrs.indptr[a] : nbrs.indptr[a + 1]]
        c = int(na[np.argmin(np.linalg.norm(v[na] - v[b], axis=1))])
        nb = nbrs.indices[nbrs.indptr[b] : nbrs.indptr[b + 1]]
        nb = nb[nb != c]
        d = int(nb[np.argmin(np.linalg.norm(v[nb] - v[c], axis=1))])
        new_faces += [[a, b, c], [b, d, c]]
        used.update((a, b, c, d))
    if k and not new_faces:
        raise InvalidShapeError(
            f"shortcut: no vertex pair with geodesic/Euclidean ratio above {min_ratio}"
        )
    faces = np.concatenate([f, np.array(new_faces, dtype=np.int64).reshape(-1, 3)])
    return Shape(v, faces, shape.name, shape.colors), _identity(shape)


def glue(
    shape: Shape,
    *,
    strength: float = 4,
    radius: float = 0.03,
    min_geodesic: float = 0.25,
    max_gap: float | None = None,
    candidates: int = 600,
    random_state: int = 0,
) -> Corruption:
    """Glued contacts, as a visual hull (or a voxel carving) fuses parts that touch in space: the
    ``strength`` (rounded) closest approaches between parts of the surface are welded.

    A contact is a pair of vertices ``(a, b)`` at the smallest Euclidean gap among pairs more
    than ``min_geodesic * sqrt(area)`` apart along the surface (``a`` among ``candidates``
    random vertices, ``b`` its nearest geodesically-far vertex; ``max_gap``, in units of
    ``sqrt(area)``, skips wider gaps); contacts are taken by increasing gap, their patches
    disjoint. Patch ``P_a``: the vertices within ``radius * sqrt(area)`` of ``a`` in space and
    twice that along the surface; ``P_b`` likewise. Every vertex of ``P_b`` is welded onto its
    nearest vertex of ``P_a`` (faces that collapse or duplicate are dropped): the two parts
    now share vertices, so their Laplacian and heat diffusion change as in the thesis's merged
    hands (Fig. 7.1). Works on any mesh and pose (nothing is assumed about the shape). The map
    names, for every kept vertex, its original id; welded vertices are gone, so ground truth on
    them is moved with :func:`carry_correspondence` (``resampled=True`` sends them to the
    vertex they were welded onto) or scored on the clean shape through the map."""
    _checked("glue", strength=strength, radius=radius, min_geodesic=min_geodesic, max_gap=max_gap,
             candidates=candidates)
    f = shape.require_faces("glue")
    k = int(round(float(strength)))
    if k == 0:
        return shape, _identity(shape)
    v, e, n = np.asarray(shape.vertices), shape.edges, shape.n_vertices
    unit = float(np.sqrt(shape.area))
    G = sp.coo_matrix((shape.edge_lengths, (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    rng = np.random.default_rng(random_state)
    sample = np.sort(rng.choice(n, size=min(n, int(candidates)), replace=False))
    far_limit = min_geodesic * unit
    geo = dijkstra(G, directed=False, indices=sample, limit=far_limit)
    gaps = np.full(sample.size, np.inf)
    partner = np.full(sample.size, -1, dtype=np.int64)
    for r, a in enumerate(sample):
        far = np.flatnonzero(~np.isfinite(geo[r]))
        if far.size:
            d = np.linalg.norm(v[far] - v[a], axis=1)
            j = int(np.argmin(d))
            gaps[r], partner[r] = d[j], far[j]
    rho = radius * unit
    used = np.zeros(n, dtype=bool)
    weld = np.arange(n)
    contacts = []
    for r in np.argsort(gaps, kind="stable"):
        if len(contacts) >= k or not np.isfinite(gaps[r]):
            break
        if max_gap is not None and gaps[r] > max_gap * unit:
            break
        a, b = int(sample[r]), int(partner[r])
        rows = dijkstra(G, directed=False, indices=[a, b], limit=2 * rho)
        pa = np.flatnonzero((np.linalg.norm(v - v[a], axis=1) <= rho) & np.isfinite(rows[0]))
        pb = np.flatnonzero((np.linalg.norm(v - v[b], axis=1) <= rho) & np.isfinite(rows[1]))
        pa, pb = np.setdiff1d(pa, pb), pb
        if pa.size == 0 or pb.size == 0 or used[pa].any() or used[pb].any():
            continue
        used[pa] = used[pb] = True
        weld[pb] = pa[cKDTree(v[pa]).query(v[pb])[1]]
        contacts.append((a, b, float(gaps[r] / unit)))
    if not contacts:
        raise InvalidShapeError("glue: no pair of geodesically distant vertices to weld")
    nf = weld[f]
    ok = (nf[:, 0] != nf[:, 1]) & (nf[:, 1] != nf[:, 2]) & (nf[:, 0] != nf[:, 2])
    nf = nf[ok]
    _, first = np.unique(np.sort(nf, axis=1), axis=0, return_index=True)
    nf = nf[np.sort(first)]
    keep = np.zeros(n, dtype=bool)
    keep[nf.ravel()] = True
    ids = np.flatnonzero(keep)
    remap = np.full(n, -1, dtype=np.int64)
    remap[ids] = np.arange(ids.size)
    return Shape(v[ids], remap[nf], shape.name, _carried_colors(shape, ids)), ids.astype(np.int64)


def partial(shape: Shape, *, strength: float = 0.3, random_state: int = 0) -> Corruption:
    """Partiality: cut away the fraction ``strength`` of the vertices lying furthest along a
    random direction; the largest remaining component is kept."""
    _checked("partial", strength=strength)
    s = float(strength)
    rng = np.random.default_rng(random_state)
    d = rng.normal(size=3)
    proj = shape.vertices @ (d / np.linalg.norm(d))
    keep = proj <= np.quantile(proj, 1.0 - s) if s > 0 else np.ones(shape.n_vertices, dtype=bool)
    if not shape.is_mesh:
        sub, ids = shape.submesh(np.flatnonzero(keep))
        return sub, ids
    return _keep(shape, keep)


#: most centres a corruption that draws them until one fits tries (``holes``, ``crop``: each is one Dijkstra run)
MAX_ATTEMPTS = 10_000


def crop(shape: Shape, *, strength: float = 0.3, random_state: int = 0, attempts: int = 1) -> Corruption:
    """A partial shape: cut away one connected region holding the fraction ``strength`` of the surface area, a
    geodesic ball (along the mesh edges) around a random centre vertex; every vertex keeps its back-map, so the
    ground truth survives. When the cut splits the rest (a limb cut at its root), the largest piece is kept;
    when what is kept is not ``1 - strength`` of the area to within 0.05 (by its vertices' areas; its faces' to
    within 0.1: a split, a centre on a piece smaller than the cut, a mesh too coarse to cut finely), the next
    of ``attempts`` centres (drawn in turn from ``random_state``) is tried, and after the last
    :class:`InvalidShapeError` asks for another ``random_state`` (or more ``attempts``)."""
    shape.require_faces("crop")
    _checked("crop", strength=strength, attempts=attempts)
    s = float(strength)
    if s == 0:
        return shape, _identity(shape)
    n, e = shape.n_vertices, shape.edges
    rng = np.random.default_rng(random_state)
    G = sp.coo_matrix((shape.edge_lengths, (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    area = shape.vertex_areas
    for _ in range(int(attempts)):
        centre = int(rng.integers(n))
        dist = dijkstra(G, directed=False, indices=centre)
        order = np.argsort(dist, kind="stable")
        reach = np.isfinite(dist[order])
        removed = reach & (np.cumsum(np.where(reach, area[order], 0.0)) <= s * area.sum())  # never another piece
        keep = np.ones(n, dtype=bool)
        keep[order[removed]] = False
        out, vmap = _keep(shape, keep)
        kept = float(area[vmap].sum() / area.sum())
        # the kept vertices' areas also count the ring of faces cut at the border: on the 5k-vertex TOSCA and FAUST
        # shapes at most 0.028 more than the kept surface (207 crops), on a mesh of a few faces most of it (a
        # tetrahedron cropped by 30% kept 21% of its surface): the surface must be within twice the tolerance too
        surface = float(out.area / shape.area)
        if abs(kept - (1.0 - s)) <= 0.05 and abs(surface - (1.0 - s)) <= 0.1:
            return out, vmap
    # the cut split the rest, or the centre's piece is smaller than the cut; or the mesh is in pieces such that no
    # centre can work: one in the largest piece keeps about share - s, one elsewhere about share
    share = float(area[largest_face_piece(shape)].sum() / area.sum())
    if 1.0 - share > 0.05 and abs(share - (1.0 - s)) > 0.05:
        way_out = (f"the mesh is in pieces (the largest holds {share:.0%} of the area) and a crop keeps one, so no "
                   "random_state gives that share: crop its largest piece (shape-toolkit clean --keep-largest)")
    else:
        way_out = "try another random_state" + (" or more attempts" if attempts > 1 else "")
    raise InvalidShapeError(
        f"crop: cutting {s:.0%} of the area around vertex {centre} keeps one piece with {surface:.0%} of the "
        f"area (asked: {1 - s:.0%}); {way_out}"
    )


def split_triangles(vertices: np.ndarray, faces: np.ndarray, s: int) -> tuple[np.ndarray, np.ndarray]:
    """Every triangle split into ``s * s`` congruent ones on a flat barycentric grid, shared edges shared:
    vertices ``(n', 3)`` with the original ``n`` first (same ids) and triangles ``(s^2 m, 3)``;
    ``n' = n + (s - 1) E + (s - 1)(s - 2) m / 2`` for ``E`` edges and ``m`` triangles."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    s = int(s)
    if s == 1:
        return v.copy(), f.copy()
    grid = [(i, j) for i in range(s + 1) for j in range(s + 1 - i)]
    w = np.array([(i, j, s - i - j) for i, j in grid])
    pos = {t: q for q, t in enumerate(grid)}
    tris = []
    for i in range(s):
        for j in range(s - i):
            tris.append((pos[i, j], pos[i + 1, j], pos[i, j + 1]))
            if i + j < s - 1:
                tris.append((pos[i + 1, j], pos[i + 1, j + 1], pos[i, j + 1]))
    tris = np.array(tris)
    nf, npt = len(f), len(w)
    # a grid point's identity: its (vertex id, weight) pairs with non-zero weight, sorted by vertex id
    vid = np.where(w[None] > 0, f[:, None, :], -1)
    ww = np.broadcast_to(w, (nf, npt, 3))
    o = np.argsort(vid, axis=2)
    key = np.concatenate([np.take_along_axis(vid, o, 2), np.take_along_axis(ww, o, 2)], axis=2).reshape(-1, 6)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inv = inv.ravel().reshape(nf, npt)
    xyz = np.einsum("pk,fkd->fpd", w / s, v[f]).reshape(-1, 3)[first]
    # renumber: the original vertices first, with their ids (a corner of the grid is the original vertex)
    new_id = np.full(len(first), -1, dtype=np.int64)
    for c in range(3):
        q = int(np.flatnonzero(w[:, c] == s)[0])
        new_id[inv[:, q]] = f[:, c]
        xyz[inv[:, q]] = v[f[:, c]]  # exact copies (the barycentric sum may round)
    rest = new_id < 0
    new_id[rest] = len(v) + np.arange(int(rest.sum()))
    out_v = np.empty((len(v) + int(rest.sum()), 3))
    out_v[: len(v)] = v  # every original vertex, also one no triangle uses
    out_v[new_id] = xyz
    return out_v, new_id[inv[:, tris]].reshape(-1, 3)


def subdivide(shape: Shape, *, splits: int = 2, random_state: int = 0) -> Corruption:
    """A finer mesh of the same surface: every triangle split ``splits x splits`` (flat, so the geometry
    and the Laplacian's continuum limit are unchanged; ``splits^2`` times the triangles). The original
    vertices keep their ids and positions; every new vertex maps to the nearest original vertex.
    ``random_state`` is unused (the split is deterministic). A result of more than
    :data:`~shape_toolkit.io.mesh.MAX_VERTICES` vertices (more than any shape has) is refused before it is built."""
    _checked("subdivide", splits=splits)
    f = shape.require_faces("subdivide")
    k = int(splits)
    n_new = shape.n_vertices + (k - 1) * len(shape.edges) + (k - 1) * (k - 2) * len(f) // 2  # as split_triangles
    if n_new > MAX_VERTICES:
        raise ParameterError(
            f"subdivide splits={k} would make {n_new:,} vertices from the {len(f):,} triangles of {shape!r}, above "
            f"the limit of {MAX_VERTICES:,} (shape_toolkit.io.mesh.MAX_VERTICES); give fewer splits"
        )
    v, nf = split_triangles(shape.vertices, f, k)
    n = shape.n_vertices
    vmap = np.arange(len(v), dtype=np.int64)
    if len(v) > n:
        from scipy.spatial import cKDTree

        vmap[n:] = cKDTree(shape.vertices).query(v[n:], k=1)[1]
    return Shape(v, nf, shape.name, _carried_colors(shape, vmap)), vmap


def point_cloud(
    shape: Shape, *, strength: float = 0.0, points: int = 0, normals: bool = False, random_state: int = 0
) -> Corruption:
    """The shape as a point cloud (no faces): its distinct vertices (``points = 0``; coincident vertices are
    one point) or ``points`` samples uniform in area on its triangles, each moved by isotropic Gaussian noise
    of standard deviation ``strength`` bounding-box diagonals per coordinate (0.005: 0.5 % of the diagonal).
    The vertex map names, for each point, its vertex (the first of coincident ones) or the vertex nearest to
    where it was sampled (before the noise), so a map to the cloud is scored on the mesh it came from.
    ``normals``: the cloud carries the mesh's outward normals, as a scanner's or a mesh export's cloud does
    (``Shape.normals``): a vertex's own, or at a sample the normals of its triangle's corners interpolated
    barycentrically (where the point was sampled, before the noise)."""
    _checked("point-cloud", strength=strength, points=points, normals=normals)
    s = float(strength)
    rng = np.random.default_rng(random_state)
    V = np.asarray(shape.vertices, dtype=np.float64)
    N = None
    if normals:
        from shape_toolkit.core.geometry import outward_vertex_normals

        VN = outward_vertex_normals(shape.normalized()[0])  # unit normals, whatever the units
    if points == 0:
        first = np.sort(np.unique(V, axis=0, return_index=True)[1]).astype(np.int64)
        P, vmap = V[first], first
        if normals:
            N = VN[first]
            lone = np.flatnonzero(~np.any(N, axis=1))
            if len(lone):  # a vertex on no face has no normal
                raise InvalidShapeError(
                    f"{shape!r}: {len(lone)} vertices are on no face (first: vertex {int(first[lone[0]])}), so they "
                    "have no normal to carry: remove them first (shape-toolkit clean; clean_shape), or make the cloud "
                    "without normals")
    else:
        f = shape.require_faces("point_cloud with points > 0")
        area = np.asarray(shape.face_areas, dtype=np.float64)
        if not area.sum() > 0:
            raise InvalidShapeError(f"{shape!r}: no triangle has an area to sample points on")
        tri = rng.choice(len(f), size=int(points), p=area / area.sum())
        u = rng.random((int(points), 2))
        out = u.sum(axis=1) > 1  # folded back into the triangle: uniform in its area
        u[out] = 1.0 - u[out]
        T = V[f[tri]]
        P = T[:, 0] + u[:, :1] * (T[:, 1] - T[:, 0]) + u[:, 1:] * (T[:, 2] - T[:, 0])
        vmap = cKDTree(V).query(P)[1].astype(np.int64)
        if normals:
            Nf = VN[f[tri]]
            N = Nf[:, 0] + u[:, :1] * (Nf[:, 1] - Nf[:, 0]) + u[:, 1:] * (Nf[:, 2] - Nf[:, 0])
    if s > 0:
        P = P + rng.normal(scale=s * shape.diagonal, size=P.shape)
    if len(np.unique(P, axis=0)) < len(P):
        raise InvalidShapeError(f"{shape!r}: the cloud has coincident points; use another random_state")
    return Shape(P, None, shape.name, _carried_colors(shape, vmap), N), vmap


#: corruption name (as used in configs) -> function
CORRUPTIONS: dict[str, Callable[..., Corruption]] = {
    "rigid": rigid_motion,
    "scale": scaling,
    "gaussian-noise": gaussian_noise,
    "shot-noise": shot_noise,
    "color-noise": color_noise,
    "remesh": remesh,
    "holes": holes,
    "micro-holes": micro_holes,
    "shortcut": shortcut,
    "glue": glue,
    "partial": partial,
    "crop": crop,
    "subdivide": subdivide,
    "point-cloud": point_cloud,
}


def _strength(low: float, high: float | None, doc: str) -> Param:
    return Param(Interval(float, low, high), doc=f"strength: {doc}")


_POSITIVE = Interval(float, 0, None, closed="neither")

#: every corruption's declared parameters (those besides ``shape`` and ``random_state`` that take a bounded value):
#: checked first thing when it is applied, and when a benchmark config is read (:func:`check_corruption_params`), so a
#: bad value is refused before any row runs; the one place their bounds are written
CORRUPTION_PARAMS: dict[str, dict[str, Param]] = {
    "rigid": {"strength": _strength(0, None, "rotation by strength * pi rad, translation by strength diagonals"),
              "scale": Param(_POSITIVE, doc="scale factor")},
    "scale": {"strength": _strength(-0.99, 1e6, "scale by 1 + strength")},
    "gaussian-noise": {"strength": _strength(0, None, "standard deviation in mean edge lengths")},
    "shot-noise": {"strength": _strength(0, 1, "fraction of the vertices displaced"),
                   "magnitude": Param(Interval(float), doc="displacement in mean edge lengths")},
    "color-noise": {"strength": _strength(0, 1, "standard deviation in colour units"),
                    "gain": Param(Interval(float, 0, None), doc="factor of each colour channel")},
    "remesh": {"strength": _strength(0.05, 20, "vertex count as a multiple of the original's"),
               "n_vertices": Param(None, Interval(int, 20, MAX_REMESH_VERTICES),
                                   doc="vertex count (None: from strength), at most the remeshing memory budget "
                                       "shape_toolkit.core.cleanup.MAX_REMESH_VERTICES"),
               "iterations": Param(Interval(int, 1, MAX_REMESH_ITERATIONS),
                                   doc="isotropic remeshing passes (it settles in a few), at most "
                                       "shape_toolkit.core.cleanup.MAX_REMESH_ITERATIONS, as clean's "
                                       "--remesh-iterations")},
    "holes": {"strength": _strength(0, 1000, "number of holes (rounded)"),
              "radius": Param(_POSITIVE, doc="hole radius in bounding-box diagonals"),
              "attempts": Param(Interval(int, 1, MAX_ATTEMPTS), doc="centres drawn per hole until one fits (more "
                                "only repeat centres already tried)"),
              "sliver": Param(Interval(float, 0, 0.5), doc="largest fraction of the vertices a hole may cut off")},
    "micro-holes": {"strength": _strength(0, 0.5, "fraction of the vertices removed")},
    "shortcut": {"strength": _strength(0, 100, "number of shortcuts (rounded)"),
                 "min_ratio": Param(Interval(float, 1, None), doc="least geodesic / Euclidean ratio of a shortcut "
                                   "(at least 1: a surface path is never shorter than the straight line, and below "
                                   "1 a pair of ratio 0, a vertex with itself, would be bridged)")},
    "glue": {"strength": _strength(0, 100, "number of contacts (rounded)"),
             "radius": Param(_POSITIVE, doc="patch radius in sqrt(area)"),
             "min_geodesic": Param(_POSITIVE, doc="least surface distance of a contact in sqrt(area)"),
             "max_gap": Param(None, _POSITIVE, doc="widest gap welded in sqrt(area) (None: any)"),
             "candidates": Param(Interval(int, 1, MAX_VERTICES),
                                 doc="random vertices tried as a contact's first end (the shape's vertex count or "
                                     "more: every vertex), at most shape_toolkit.io.mesh.MAX_VERTICES as no shape "
                                     "has more vertices")},
    "partial": {"strength": _strength(0, 0.95, "fraction of the vertices cut away")},
    "crop": {"strength": _strength(0, 0.9, "fraction of the area cut away"),
             "attempts": Param(Interval(int, 1, MAX_ATTEMPTS), doc="centres drawn until one fits (more only repeat "
                               "centres already tried)")},
    "subdivide": {"splits": Param(Interval(int, 1, 64), doc="each triangle split splits x splits")},
    "point-cloud": {"strength": _strength(0, 1, "noise in bounding-box diagonals"),
                    "points": Param(Interval(int, 0, 0), Interval(int, 2, MAX_VERTICES),
                                    doc="points sampled (0: the vertices), at most shape_toolkit.io.mesh.MAX_VERTICES "
                                        "as no shape has more vertices"),
                    "normals": Param(InstanceOf(bool), doc="the cloud carries the mesh's outward normals")},
}


def check_corruption_params(name: str, params: dict[str, Any]) -> None:
    """Refuse, before any shape is at hand, a parameter value the corruption ``name`` (one kind of
    :data:`CORRUPTIONS`) never takes: one-line :class:`ParameterError` naming the corruption, the parameter, the value
    and what it takes (:data:`CORRUPTION_PARAMS`, the declarations the corruption itself checks first); a parameter
    it does not have is refused too. Checks against the shape (a remesh target of fewer than 20 vertices, a hole
    with no place to go) are left to the corruption, as are the values of a corruption added to
    :data:`CORRUPTIONS` without declarations."""
    if name not in CORRUPTIONS:
        raise ParameterError(f"unknown corruption {name!r}; known: none, {', '.join(CORRUPTIONS)}")
    import inspect

    valid = [p for p in inspect.signature(CORRUPTIONS[name]).parameters if p not in ("shape", "random_state")]
    bad = sorted(set(params) - set(valid))
    if bad:
        raise ParameterError(f"corruption {name!r} has no parameter {', '.join(bad)}; valid: {', '.join(valid)}")
    # a corruption registered elsewhere (CORRUPTIONS is open to extension) may declare nothing: it checks its own
    validate_params(f"corruption {name!r}", CORRUPTION_PARAMS.get(name, {}), params)


#: joins the kinds of a composed corruption: ``"glue+color-noise"`` is ``glue``, then ``color-noise``
CHAIN = "+"


def chain_kinds(name: str) -> list[str]:
    """The corruption kinds ``name`` applies in order: ``["glue", "color-noise"]`` for
    ``"glue+color-noise"``, ``[name]`` for a single kind."""
    return name.split(CHAIN)


def step_seeds(random_state: int, n_steps: int) -> list[int]:
    """The ``random_state`` of each of the ``n_steps`` steps of a composed corruption drawn with
    ``random_state``: independent streams spawned from it (``numpy.random.SeedSequence``), each in
    ``[0, 2**31 - 2]``, so two steps of one kind never draw alike and a step's draw depends on its place."""
    children = np.random.SeedSequence(int(random_state)).spawn(int(n_steps))
    return [int(c.generate_state(1, np.uint64)[0] % (2**31 - 1)) for c in children]


def compose_vertex_maps(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """The vertex map of two corruptions in sequence: ``first`` (int64 ``(n_1,)``, result of the first
    -> original) after ``second`` (int64 ``(n_2,)``, result of the second -> result of the first) is
    ``first[second]`` (int64 ``(n_2,)``), -1 where either map has none."""
    a = np.asarray(first, dtype=np.int64)
    b = np.asarray(second, dtype=np.int64)
    return np.where(b >= 0, a[np.maximum(b, 0)], -1) if a.size else np.full(b.shape, -1, dtype=np.int64)


def apply_corruption(shape: Shape, name: str, *, random_state: int = 0, **params: Any) -> Corruption:
    """Apply the corruption registered as ``name`` (see :data:`CORRUPTIONS`) with ``params``;
    ``name='none'`` returns the shape with the identity map. A composed name (``"glue+color-noise"``,
    kinds joined by :data:`CHAIN`) takes ``steps``, one parameter table per kind, and applies them in
    order, step ``j`` with ``random_state=step_seeds(random_state, n)[j]``; its map is the composition of
    the steps' maps (a new vertex -> the vertex of ``shape`` it comes from). A step's error is raised
    with the same type, naming the step."""
    if name == "none":
        return shape, _identity(shape)
    if CHAIN in name:
        return _apply_chain(shape, name, random_state, params)
    if name not in CORRUPTIONS:
        raise ParameterError(f"unknown corruption {name!r}; known: none, {', '.join(CORRUPTIONS)}")
    fn = CORRUPTIONS[name]
    import inspect

    valid = [p for p in inspect.signature(fn).parameters if p != "shape"]
    bad = sorted(set(params) - set(valid))
    if bad:
        raise ParameterError(
            f"corruption {name!r} has no parameter {', '.join(bad)}; valid: {', '.join(valid)}"
        )
    return fn(shape, random_state=random_state, **params)


def _apply_chain(shape: Shape, name: str, random_state: int, params: dict[str, Any]) -> Corruption:
    """The composed corruption ``name`` (see :func:`apply_corruption`)."""
    kinds = chain_kinds(name)
    steps = params.get("steps")
    if set(params) != {"steps"} or not isinstance(steps, (list, tuple)) or len(steps) != len(kinds) or not all(
        isinstance(st, dict) for st in steps
    ):
        raise ParameterError(f"composed corruption {name!r} takes steps = a list of {len(kinds)} parameter "
                             f"tables (one per step), got {params!r}")
    for k in kinds:
        if k not in CORRUPTIONS:
            raise ParameterError(f"composed corruption {name!r}: unknown step {k!r}; known: {', '.join(CORRUPTIONS)}")
    out, vmap = shape, _identity(shape)
    for j, (kind, prm, seed) in enumerate(zip(kinds, steps, step_seeds(random_state, len(kinds)))):
        try:
            out, m = apply_corruption(out, kind, random_state=seed, **prm)
        except (InvalidShapeError, ParameterError) as exc:
            raise type(exc)(f"step {j + 1} of {len(kinds)} of {name!r} ({kind}): {exc}") from None
        vmap = compose_vertex_maps(vmap, m)
    return out, vmap


#: corruptions that resample the surface: their maps name the *nearest* original vertex, so an
#: original vertex nobody maps to still exists (near its neighbours) rather than being removed
RESAMPLING = frozenset({"remesh", "glue", "subdivide", "point-cloud"})


def resamples(name: str) -> bool:
    """Whether the corruption ``name`` (composed ones included: when any step does) resamples the
    surface (:data:`RESAMPLING`)."""
    return any(k in RESAMPLING for k in chain_kinds(name))


def invert_vertex_map(
    vertex_map: np.ndarray,
    original: Shape,
    *,
    resampled: bool = False,
    max_distance: float | None = None,
) -> np.ndarray:
    """Original vertex -> new vertex (int64 ``(n_original,)``, -1 when removed).

    An original vertex named by the map gets the first new vertex mapping to it. Others are
    removed, unless ``resampled`` (the map of :func:`remesh`): then they get the new vertex whose
    source is nearest, within ``max_distance`` (default 2 mean edge lengths of ``original``).
    """
    vm = np.asarray(vertex_map, dtype=np.int64)
    n = original.n_vertices
    inv = -np.ones(n, dtype=np.int64)
    valid = np.flatnonzero(vm >= 0)
    order = valid[::-1]  # assign in reverse so the first new vertex wins
    inv[vm[order]] = order
    missing = np.flatnonzero(inv < 0)
    if resampled and missing.size and valid.size:
        lim = 2.0 * _length_unit(original) if max_distance is None else float(max_distance)
        dist, j = cKDTree(original.vertices[vm[valid]]).query(original.vertices[missing])
        ok = dist <= lim
        inv[missing[ok]] = valid[j[ok]]
    return inv


def carry_labels(labels: np.ndarray, vertex_map: np.ndarray) -> np.ndarray:
    """Per-vertex labels of the corrupted shape: ``labels[vertex_map]`` (-1 for unmapped)."""
    lab = np.asarray(labels, dtype=np.int64)
    vm = np.asarray(vertex_map, dtype=np.int64)
    return np.where(vm >= 0, lab[np.maximum(vm, 0)], -1)


def carry_correspondence(
    pairs: np.ndarray, vertex_map: np.ndarray, original: Shape, *, side: int = 1, resampled: bool = False
) -> np.ndarray:
    """Ground-truth pairs ``(q, 2)`` with column ``side`` moved onto the corrupted shape; pairs
    whose vertex was removed are dropped (``resampled``: see :func:`invert_vertex_map`)."""
    p = np.array(pairs, dtype=np.int64, copy=True)
    inv = invert_vertex_map(vertex_map, original, resampled=resampled)
    p[:, side] = inv[p[:, side]]
    return p[p[:, side] >= 0]
