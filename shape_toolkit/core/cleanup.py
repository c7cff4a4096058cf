"""Repair common mesh defects and report exactly what changed.

Topological repairs are done here with numpy (exact, deterministic, and every output vertex
keeps track of the input vertex it came from); isotropic remeshing calls pymeshlab, and the coherent
orientation of the faces libigl's breadth-first orientation (which flips faces and moves no vertex). The
libraries' filters do not do the same job (checked with Open3D 0.19.0 and pymeshlab 2025.7):
none returns the index map that :attr:`CleanupReport.vertex_map` reports; Open3D's
``remove_degenerate_triangles`` keeps zero-area faces with three distinct vertices and its
``remove_duplicated_triangles`` keeps face (2, 1, 0) next to (0, 1, 2); pymeshlab's
``meshing_remove_duplicate_faces`` keeps the later face of that pair, (2, 1, 0), where the report
counts the earlier one as kept.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from shape_toolkit.core.inspect import (
    _unique_rows,
    connected_components,
    degenerate_face_mask,
    duplicate_face_mask,
    duplicate_vertex_map,
    edge_face_counts,
    face_fans,
    inconsistent_edges,
)
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import InvalidShapeError, ParameterError
from shape_toolkit.validation import shown_value

__all__ = ["CleanupReport", "clean_shape", "close_holes", "MAX_REMESH_VERTICES", "MAX_REMESH_ITERATIONS",
           "estimate_remesh_vertices"]

#: Remeshing targets whose estimated vertex count exceeds this are refused (memory: pymeshlab needs
#: a few hundred bytes per vertex, so the budget keeps a remesh well under a few GB).
MAX_REMESH_VERTICES = 2_000_000
#: the most iterations of an isotropic remeshing (``shape-toolkit clean --remesh-iterations``, the ``remesh``
#: corruption's ``iterations``): it settles in a few (pymeshlab's default is 10); 1e9 ran for hours, and an integer
#: past C++ int range raised an internal error in pymeshlab
MAX_REMESH_ITERATIONS = 100


@dataclass
class CleanupReport:
    """What :func:`clean_shape` changed. ``vertex_map[i]`` is the input vertex of output vertex i.

    ``vertex_map`` is int64 ``(n_vertices_after,)``; -1 marks vertices created by remeshing
    (remeshed vertices keep their source only when their coordinates are exactly unchanged).
    Vertices split off a non-manifold vertex map to that vertex.
    """

    n_vertices_before: int = 0
    n_faces_before: int = 0
    n_vertices_after: int = 0
    n_faces_after: int = 0
    duplicate_vertices_merged: int = 0
    duplicate_faces_removed: int = 0
    degenerate_faces_removed: int = 0
    unreferenced_vertices_removed: int = 0
    non_manifold_edges_repaired: int = 0
    non_manifold_vertices_repaired: int = 0
    faces_reoriented: int = 0
    components_removed: int = 0
    remeshed: bool = False
    notes: list[str] = field(default_factory=list)
    vertex_map: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64), repr=False)

    def to_dict(self) -> dict:
        """The counts and notes as a JSON-ready dict (without the vertex map)."""
        d = asdict(self)
        d.pop("vertex_map")
        return d


def _largest_cloud_piece(shape: Shape, v: np.ndarray, vmap: np.ndarray, rep: CleanupReport):
    """The points ``v`` (of ``shape``, through ``vmap``) of the largest piece of their kNN graph: the graph the
    spectra of a cloud are taken on (:data:`~shape_toolkit.core.graph.KNN_NEIGHBORS` neighbours, pieces of one
    surface joined: :func:`~shape_toolkit.core.graph.cloud_knn_edges`), so a cloud of two objects keeps the larger."""
    from shape_toolkit.core.geometry import edge_components
    from shape_toolkit.core.graph import KNN_NEIGHBORS, cloud_knn_edges

    normals = shape.normals[vmap] if shape.normals is not None else None
    edges = cloud_knn_edges(Shape(v, None, shape.name, normals=normals), min(KNN_NEIGHBORS, len(v) - 1))
    k, labels = edge_components(len(v), edges)
    if k > 1:
        rep.components_removed = int(k - 1)
        keep = labels == np.argmax(np.bincount(labels, minlength=k))  # most points (ties: the first piece)
        v, _, vmap = _keep_vertices(v, None, vmap, keep)
    return v, vmap


def _keep_vertices(v, f, vmap, keep: np.ndarray):
    """Restrict to vertices where ``keep`` (bool (n,)) is True, renumbering faces."""
    remap = np.cumsum(keep) - 1
    return v[keep], (remap[f] if f is not None else None), vmap[keep]


def clean_shape(
    shape: Shape,
    *,
    remove_duplicates: bool = True,
    remove_degenerate: bool = True,
    remove_unreferenced: bool = True,
    repair_non_manifold: bool = True,
    orient_faces: bool = True,
    keep_largest_component: bool = False,
    remesh_target_edge: float | None = None,
    remesh_iterations: int = 3,
) -> tuple[Shape, CleanupReport]:
    """Clean a shape; return the new shape and a :class:`CleanupReport` of what changed.

    Steps, in order: merge exactly coincident vertices, drop degenerate faces (repeated index
    or zero area), drop duplicate faces (same vertex set), repair non-manifold edges (keep the
    two largest faces on each) and vertices (split each extra fan into a new vertex), orient the faces
    coherently (each piece as most of its faces already were; a piece that cannot be, as a Moebius strip, is said in
    the notes), drop unreferenced vertices, keep the component with most faces, isotropic remeshing to
    ``remesh_target_edge`` (file units). A point cloud only gets duplicate points merged and, with
    ``keep_largest_component``, the largest piece of its kNN graph kept (the graph its spectra are taken on).
    """
    if remesh_target_edge is not None and not (np.isfinite(remesh_target_edge) and remesh_target_edge > 0):
        raise ParameterError(f"remesh_target_edge must be > 0, got {remesh_target_edge!r}")
    if (isinstance(remesh_iterations, (bool, np.bool_)) or not isinstance(remesh_iterations, (int, np.integer))
            or not 1 <= remesh_iterations <= MAX_REMESH_ITERATIONS):
        raise ParameterError(f"remesh_iterations must be an integer in [1, {MAX_REMESH_ITERATIONS}], got "
                             f"{shown_value(remesh_iterations)}")
    rep = CleanupReport(n_vertices_before=shape.n_vertices, n_faces_before=shape.n_faces)
    v = np.array(shape.vertices)
    f = None if shape.faces is None else np.array(shape.faces)
    vmap = np.arange(len(v), dtype=np.int64)

    if remove_duplicates:
        first = duplicate_vertex_map(v)
        keep = first == np.arange(len(v))
        rep.duplicate_vertices_merged = int((~keep).sum())
        if f is not None:
            f = first[f]
        v, f, vmap = _keep_vertices(v, f, vmap, keep)

    if f is None:
        if remesh_target_edge is not None:
            raise InvalidShapeError("remeshing needs a triangle mesh, got a point cloud")
        rep.notes.append("point cloud: only exactly duplicate points were merged"
                         + (", and the largest piece of its kNN graph kept" if keep_largest_component else ""))
        if keep_largest_component and len(v) > 1:
            v, vmap = _largest_cloud_piece(shape, v, vmap, rep)
        return _finish(shape, v, None, vmap, rep)

    if remove_degenerate:
        bad = degenerate_face_mask(v, f)
        rep.degenerate_faces_removed = int(bad.sum())
        f = f[~bad]
    if remove_duplicates:
        dup = duplicate_face_mask(f)
        rep.duplicate_faces_removed = int(dup.sum())
        f = f[~dup]
    if repair_non_manifold and len(f):
        f, rep.non_manifold_edges_repaired = _repair_non_manifold_edges(v, f)
        v, f, vmap, rep.non_manifold_vertices_repaired = _split_non_manifold_vertices(v, f, vmap)
        if rep.non_manifold_vertices_repaired:
            rep.notes.append(
                "split vertices are exact copies (they count as duplicate vertices in mesh_info)"
            )
    if orient_faces and len(f) and len(inconsistent_edges(f)):
        f, rep.faces_reoriented = _orient_coherently(f)
        left = len(inconsistent_edges(f))
        if left:
            rep.notes.append(f"{left} edges are still inconsistently oriented: a piece is not orientable")
    if remove_unreferenced:
        used = np.zeros(len(v), dtype=bool)
        used[f.ravel()] = True
        rep.unreferenced_vertices_removed = int((~used).sum())
        v, f, vmap = _keep_vertices(v, f, vmap, used)
    if len(f) == 0:
        raise InvalidShapeError(f"cleaning {shape!r} removed every face")

    if keep_largest_component:
        k, labels = connected_components(Shape(v, f))
        if k > 1:
            n_faces_per = np.bincount(labels[f[:, 0]], minlength=k)
            n_verts_per = np.bincount(labels, minlength=k)
            best = np.lexsort((-n_verts_per, -n_faces_per))[0]  # most faces, then most vertices
            rep.components_removed = int(k - 1)
            f = f[labels[f[:, 0]] == best]
            v, f, vmap = _keep_vertices(v, f, vmap, labels == best)

    if remesh_target_edge is not None:
        est = estimate_remesh_vertices(Shape(v, f), float(remesh_target_edge))
        if est > MAX_REMESH_VERTICES:
            raise ParameterError(
                f"remeshing to edge length {remesh_target_edge:g} would create about {est:.3g} vertices "
                f"(surface area / edge length^2), above the budget of {MAX_REMESH_VERTICES:,} vertices "
                "(shape_toolkit.core.cleanup.MAX_REMESH_VERTICES); choose a longer edge length"
            )
        v, f, vmap = _remesh(v, f, vmap, float(remesh_target_edge), int(remesh_iterations))
        rep.remeshed = True
    return _finish(shape, v, f, vmap, rep)


def _orient_coherently(f: np.ndarray) -> tuple[np.ndarray, int]:
    """Faces ``(m, 3)`` flipped so that every two faces across a manifold edge run along it in opposite directions
    (libigl's breadth-first orientation over each piece), each piece keeping the orientation most of its faces
    had; and how many faces were flipped."""
    import igl

    f = np.asarray(f, dtype=np.int64)
    g, piece = igl.bfs_orient(np.ascontiguousarray(f))
    piece = np.asarray(piece, dtype=np.int64).ravel()
    flipped = ~np.all(np.asarray(g) == f, axis=1)  # bfs_orient reverses whole faces, or leaves them
    pieces = int(piece.max()) + 1 if len(piece) else 0
    back = np.bincount(piece, weights=flipped, minlength=pieces) > 0.5 * np.bincount(piece, minlength=pieces)
    flip = flipped ^ back[piece]  # a piece mostly flipped: the other way round
    return np.where(flip[:, None], f[:, ::-1], f), int(flip.sum())


def close_holes(shape: Shape) -> tuple[Shape, int]:
    """The mesh with every hole closed by a fan: one new vertex at the mean of each boundary loop's vertices
    (appended after the original ones, which keep their ids), joined to each boundary edge by a triangle oriented
    as the face across that edge. Returns the closed shape and the number of loops closed (0: ``shape`` itself).
    Meant for intrinsic computations that a hole changes (a Laplacian spectrum), not for display: the fans are
    cones, not a smooth patch. Loops that share a vertex are closed by one fan; open chains of free edges (not
    a loop) are left as they are, and so are slits: loops whose every fan triangle would be numerically flat
    (:func:`~shape_toolkit.core.geometry.flat_faces`; a loop along a line, as a cut that did not open), which enclose
    no area and whose centre would have none."""
    from shape_toolkit.core.geometry import edge_components, flat_faces

    f = np.asarray(shape.require_faces("close_holes"), dtype=np.int64)
    half = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    key = np.sort(half, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    bnd = half[counts[inv.ravel()] == 1]  # half edges (a, b) with no face across
    if len(bnd) == 0:
        return shape, 0
    verts, local = np.unique(bnd, return_inverse=True)
    local = local.reshape(-1, 2)
    n_comp, lab = edge_components(len(verts), local)
    # a hole is a closed loop of at least 3 boundary edges (every vertex of even degree); open chains (the
    # free edges of a bridge glued onto a surface) are left alone
    degree = np.bincount(local.ravel(), minlength=len(verts))
    comp_edges = np.bincount(lab[local[:, 0]], minlength=n_comp)
    odd = np.bincount(lab, weights=degree % 2, minlength=n_comp) > 0
    loops = np.flatnonzero((comp_edges >= 3) & ~odd)
    if loops.size == 0:
        return shape, 0
    new_id = -np.ones(n_comp, dtype=np.int64)
    new_id[loops] = np.arange(loops.size)
    n_loops = int(loops.size)
    keep_e = new_id[lab[local[:, 0]]] >= 0
    bnd, loop_of_edge = bnd[keep_e], new_id[lab[local[keep_e, 0]]]
    on = new_id[lab] >= 0
    verts, lab = verts[on], new_id[lab[on]]
    v = np.asarray(shape.vertices, dtype=np.float64)
    centres = np.zeros((n_loops, 3))
    np.add.at(centres, lab, v[verts])
    centres /= np.bincount(lab, minlength=n_loops)[:, None]
    fans = np.column_stack([bnd[:, 1], bnd[:, 0], shape.n_vertices + loop_of_edge])
    solid = np.bincount(loop_of_edge, weights=~flat_faces(np.concatenate([v, centres]), fans), minlength=n_loops) > 0
    if not solid.all():  # slits: left open, the others renumbered
        renum = np.cumsum(solid) - 1
        keep = solid[loop_of_edge]
        fans, loop_of_edge = fans[keep], renum[loop_of_edge[keep]]
        fans[:, 2] = shape.n_vertices + loop_of_edge
        on_loop = solid[lab]
        verts, lab, centres = verts[on_loop], renum[lab[on_loop]], centres[solid]
        n_loops = int(solid.sum())
        if n_loops == 0:
            return shape, 0
    colors = None
    if shape.colors is not None:
        c = np.asarray(shape.colors)
        extra = np.zeros((n_loops,) + c.shape[1:], dtype=np.float64)
        np.add.at(extra, lab, c[verts])
        colors = (extra / np.bincount(lab, minlength=n_loops).reshape((-1,) + (1,) * (c.ndim - 1))).astype(c.dtype)
        colors = np.concatenate([c, colors])
    closed = Shape(np.concatenate([v, centres]), np.concatenate([f, fans]), shape.name, colors)
    return closed, int(n_loops)


def estimate_remesh_vertices(shape: Shape, target_edge: float) -> float:
    """Vertices of an isotropic remesh of ``shape`` to ``target_edge``: area over the area per
    vertex of a regular triangulation (two equilateral triangles, sqrt(3)/2 edge^2). Computed on
    rescaled units, so it is inf only when the count really is astronomically large."""
    s = shape.scale
    area = float(0.5 * np.linalg.norm(shape._scaled_cross(), axis=1).sum())  # in units of s^2
    t = float(target_edge) / s
    if t == 0.0:
        return float("inf")
    with np.errstate(over="ignore", under="ignore", divide="ignore"):  # a tiny edge: inf, no warning
        return float(area / (np.sqrt(3.0) / 2.0 * t * t))


def _finish(shape: Shape, v, f, vmap, rep: CleanupReport) -> tuple[Shape, CleanupReport]:
    colors = None
    if shape.colors is not None:  # kept vertices keep theirs; remeshed ones take the nearest input's
        src = np.array(vmap, dtype=np.int64)
        new = src < 0
        if new.any():
            from scipy.spatial import cKDTree

            src[new] = cKDTree(shape.vertices).query(v[new])[1]
        colors = shape.colors[src]
    # a cloud's points keep their normals (a merged duplicate, its first point's); a mesh's come from its faces
    normals = shape.normals[vmap] if shape.normals is not None and f is None else None
    out = Shape(v, f, shape.name, colors=colors, normals=normals)
    rep.n_vertices_after, rep.n_faces_after = out.n_vertices, out.n_faces
    rep.vertex_map = vmap.astype(np.int64)
    return out, rep


def _repair_non_manifold_edges(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, int]:
    """Drop faces so no edge has more than two: keep the two largest (ties: lower index)."""
    edges, counts = edge_face_counts(f)
    if not (counts > 2).any():
        return f, 0
    he = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    fid = np.tile(np.arange(len(f)), 3)
    bad_edges = edges[counts > 2]
    # half edges lying on a non-manifold edge
    n = len(v)
    on_bad = np.isin(he[:, 0] * n + he[:, 1], bad_edges[:, 0] * n + bad_edges[:, 1])
    he, fid = he[on_bad], fid[on_bad]
    area = Shape(v, f).face_areas[fid]
    order = np.lexsort((fid, -area, he[:, 1], he[:, 0]))
    he, fid = he[order], fid[order]
    _, inv, _ = _unique_rows(he)
    start = np.searchsorted(inv, inv)  # first position of each half edge's group (inv sorted)
    rank = np.arange(len(inv)) - start
    drop = np.zeros(len(f), dtype=bool)
    drop[fid[rank >= 2]] = True
    return f[~drop], len(bad_edges)


def _split_non_manifold_vertices(v, f, vmap):
    """Give every fan but the first around a bow-tie vertex its own copy of the vertex."""
    corner_v, fan = face_fans(f)
    ok = fan >= 0
    idx = np.flatnonzero(ok)
    pairs = np.stack([corner_v[idx], fan[idx]], 1)
    first, inv, _ = _unique_rows(pairs)  # one group per (vertex, fan), sorted by vertex then fan
    gv = pairs[first, 0]
    is_extra = np.zeros(len(first), dtype=bool)
    is_extra[1:] = gv[1:] == gv[:-1]  # not the first fan of its vertex
    n_extra = int(is_extra.sum())
    if n_extra == 0:
        return v, f, vmap, 0
    new_id = np.full(len(first), -1, dtype=np.int64)
    new_id[is_extra] = len(v) + np.arange(n_extra)
    corners = f.ravel().copy()
    moved = new_id[inv] >= 0
    corners[idx[moved]] = new_id[inv][moved]
    src = gv[is_extra]
    n_repaired = int(np.unique(src).size)
    return (
        np.concatenate([v, v[src]]),
        corners.reshape(-1, 3),
        np.concatenate([vmap, vmap[src]]),
        n_repaired,
    )


def _remesh(v, f, vmap, target: float, iterations: int):
    """Isotropic explicit remeshing (pymeshlab); vertices exactly unchanged keep their source."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=v, face_matrix=f.astype(np.int32)))
    ms.meshing_isotropic_explicit_remeshing(iterations=iterations, targetlen=pymeshlab.PureValue(target))
    m = ms.current_mesh()
    nv = np.asarray(m.vertex_matrix(), dtype=np.float64)
    nf = np.asarray(m.face_matrix(), dtype=np.int64)
    if len(nf) == 0:
        raise InvalidShapeError(f"remeshing to edge length {target} produced an empty mesh")
    both = np.concatenate([v, nv]) + 0.0
    firsts, inv, _ = _unique_rows(both)
    src = firsts[inv[len(v) :]]
    new_map = np.where(src < len(v), vmap[np.minimum(src, len(v) - 1)], -1)
    return nv, nf, new_map.astype(np.int64)
