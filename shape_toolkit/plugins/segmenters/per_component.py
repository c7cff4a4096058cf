"""Segmenting a shape of several pieces piece by piece: :class:`PerComponent`, a meta-segmenter in the
style of scikit-learn's ``OneVsRestClassifier``.

A mesh of several connected components (of the vertex graph, or of the dual graph, where faces meeting
only at a vertex are apart), with vertices on no face, or a point cloud whose kNN graph falls apart, is
segmented one piece at a time by copies of the wrapped segmenter, ``n_segments`` shared between the
pieces (:func:`segments_per_component`); specks and debris join their nearest segment
(:func:`nearest_label_per_piece`). The built-in segmenters wrap themselves when the shape asks for it
(:class:`~shape_toolkit.plugins.segmenters.base.BaseSegmenter`); wrap any other segmenter explicitly.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import scipy.sparse as sp

from shape_toolkit.api.interfaces import Segmenter
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.plugins.segmenters.constraints import inner_segmentation, must_link_groups, report_constraints
from shape_toolkit.plugins.segmenters.n_segments import check_n_segments
from shape_toolkit.results.labels import ConstraintError, coerce_constraints, face_to_vertex_labels
from shape_toolkit.results.segmentation import Segmentation

__all__ = ["PerComponent", "MIN_SPLIT_SIZE", "segments_per_component", "nearest_label_per_piece"]

#: a mesh component with fewer vertices or faces than this is never split (one segment at most)
MIN_SPLIT_SIZE = 20


def _unwelded(shape: Shape, vcomp: np.ndarray) -> bool:
    """Whether two pieces (``vcomp``: each vertex's piece, -1 on no face) share two or more vertex positions through
    distinct vertices: an edge's worth of seam, which merging the vertices would join (pieces touching at one point,
    as the cleanup leaves a non-manifold vertex split, share one)."""
    from shape_toolkit.core.inspect import duplicate_vertex_map

    group = duplicate_vertex_map(shape.vertices)  # one id per position: its first vertex
    on = vcomp >= 0
    pairs = np.unique(np.column_stack([group[on], vcomp[on]]), axis=0)  # (position, piece), once each
    first = np.unique(pairs[:, 0], return_index=True)[1]
    many = np.flatnonzero(np.diff(np.append(first, len(pairs))) > 1)  # positions held by two pieces or more
    if not len(many):
        return False
    a, b = pairs[first[many], 1], pairs[first[many] + 1, 1]  # the first two pieces at each shared position
    _, counts = np.unique(np.column_stack([a, b]), axis=0, return_counts=True)
    return bool(np.any(counts >= 2))


def segments_per_component(
    k: int,
    areas: np.ndarray,
    minimum: np.ndarray,
    keys: np.ndarray,
    capacity: np.ndarray | None = None,
    required: np.ndarray | None = None,
) -> np.ndarray:
    """How many of ``k`` segments each mesh component gets, int64 ``(c,)``. ``required[i]`` is a hard
    floor (what the constraints need: one for a component holding a constraint end, two for one holding
    a cannot-link); ``minimum[i]`` (its clicked parts) and one per component of non-zero area that may be
    split (``capacity > 1``) while there are no more components than ``k`` are wished for, and granted in
    proportion when they do not all fit; the rest is shared in proportion to the components' ``areas`` by
    largest remainder. Never above ``capacity`` (what is left over goes to the others). Ties: larger
    area, then the smaller row of ``keys`` ``(c, d)``, e.g. each component's lowest corner, so the share
    does not depend on the vertex order. With more components than ``k`` a small one may get 0 (it joins
    a neighbour: debris). Raises :class:`ParameterError` when the hard floors exceed ``k``."""
    a = np.asarray(areas, dtype=np.float64)
    c = len(a)
    cap = np.full(c, int(k), dtype=np.int64) if capacity is None else np.minimum(np.asarray(capacity), int(k))
    splittable = np.ones(c, dtype=bool) if capacity is None else np.asarray(capacity) > 1
    cap = np.maximum(cap, 1)
    hard = np.zeros(c, dtype=np.int64) if required is None else np.minimum(np.asarray(required, dtype=np.int64), cap)
    if hard.sum() > k:
        raise ParameterError(f"the constraints need {int(hard.sum())} segments on separate pieces, "
                             f"more than n_segments = {k}")
    wish = np.minimum(np.maximum(np.asarray(minimum, dtype=np.int64), hard), cap)
    if c <= k:  # one each, except for specks (too small to split) and pieces of no area
        wish = np.maximum(wish, (splittable & (a > 1e-12 * a.sum())).astype(np.int64))
    keys = np.asarray(keys, dtype=np.float64)

    def share(total: int, weight: np.ndarray, start: np.ndarray, limit: np.ndarray) -> np.ndarray:
        """Largest remainder of ``total - start.sum()`` by ``weight``; a component whose quota would pass
        its ``limit`` is held there and the quotas of the others computed again."""
        out, active = start.copy(), start < limit
        while True:
            extra = int(total - out.sum())
            if extra <= 0 or not active.any():
                return out
            w = np.where(active, weight, 0.0)
            quota = extra * w / w.sum() if w.sum() > 0 else extra * active / active.sum()
            over = active & (out + quota >= limit)
            if over.any():
                out[over], active = limit[over], active & ~over
                continue
            add = np.floor(quota).astype(np.int64)
            frac = np.where(active, quota - add, -1.0)
            # equal areas computed in floating point differ in their last bits (a translated copy, another
            # CPU's rounding): remainders and weights equal to 9 digits are ties, decided by the keys
            wr = np.round(w / max(float(w.max()), 1e-300), 9)
            order = np.lexsort((*keys.T[::-1], -wr, -np.round(frac, 9)))
            add[order[: extra - int(add.sum())]] += 1
            return out + add

    if wish.sum() > k:  # the wishes do not fit: the hard floors, then the rest in proportion to the wishes
        return share(k, wish.astype(np.float64), hard, wish)
    return share(k, a, wish, cap)


def _mesh_pieces(shape: Shape, by_faces: bool) -> tuple[np.ndarray, np.ndarray, int]:
    """``(face_piece (m,), vertex_piece (n,), count)``: the connected pieces a segmenter sees, numbered in
    order of their lowest vertex (vertex graph) or lowest face (``by_faces``: the dual graph, where faces
    meeting only at a vertex are apart; a vertex belongs to the piece of largest incident area, the piece
    whose faces give it its label, ties to the lower piece). A vertex in no face is in piece -1."""
    if by_faces:
        from scipy.sparse.csgraph import connected_components as graph_components

        from shape_toolkit.features.smoothing import dual_graph

        m = shape.n_faces
        pairs = dual_graph(shape.faces)[0]
        adj = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(m, m))
        count, face_piece = graph_components(adj, directed=False)
        vertex_piece = face_to_vertex_labels(shape.faces, face_piece, shape.n_vertices, shape.face_areas)
        return face_piece.astype(np.int64), vertex_piece.astype(np.int64), int(count)
    from shape_toolkit.core.inspect import connected_components

    n_all, comp = connected_components(shape)
    faced = np.unique(comp[shape.faces[:, 0]])  # components with faces, in order of their lowest vertex
    comp_of = np.full(n_all, -1, dtype=np.int64)
    comp_of[faced] = np.arange(len(faced))
    vertex_piece = comp_of[comp]
    return vertex_piece[shape.faces[:, 0]], vertex_piece, len(faced)


def nearest_label_per_piece(
    points: np.ndarray, piece: np.ndarray, ref_points: np.ndarray, ref_labels: np.ndarray
) -> dict[int, int]:
    """``{piece id: label}``: for every piece (``points`` ``(p, 3)`` with their ``piece`` ids ``(p,)``), the
    label of the labelled reference point (``ref_labels >= 0``; ``ref_points`` ``(r, 3)``) nearest to any
    of its points, so that a piece joins one segment whole (ties: the first point of the piece)."""
    from scipy.spatial import cKDTree

    ok = np.flatnonzero(np.asarray(ref_labels) >= 0)
    dist, j = cKDTree(ref_points[ok]).query(points)
    got = np.asarray(ref_labels)[ok[j]]
    order = np.lexsort((dist, piece))  # per piece, its point nearest to a labelled one first
    first = np.r_[True, piece[order][1:] != piece[order][:-1]]
    return dict(zip(piece[order][first].tolist(), got[order][first].tolist()))


class PerComponent(Segmenter):
    """Segments each connected piece of a shape with its own copy of ``segmenter``.

    ``pieces``: which pieces of a mesh: ``"vertex"`` (connected components of the vertex graph),
    ``"dual"`` (of the dual graph: faces meeting only at a vertex are apart; a vertex shared by several
    pieces goes with the one of largest incident area, which labels it and holds its constraints) or
    ``"auto"`` (the segmenter's own ``component_graph(shape)``, else ``"vertex"``). A point cloud is
    split into the components of the segmenter's kNN graph (``build_graph(shape, segmenter.weighting)``),
    each point counting as a unit of area. A shape of one piece is segmented by ``segmenter`` itself
    (with the given spectrum). The copies are ``type(segmenter)(**segmenter.get_params(deep=False))``
    with their share of ``n_segments``. ``get_params(deep=True)`` holds the segmenter's parameters as
    ``segmenter__name``; ``sklearn.base.clone`` works. After :meth:`segment`: ``segmenters_``, the
    fitted copies (one per piece given two segments or more).
    """

    def __init__(self, segmenter: Any, *, pieces: str = "auto"):
        self.segmenter = segmenter
        self.pieces = pieces

    def accepts_constraints(self) -> bool:
        """Whether the wrapped segmenter uses constraints (they are shared out between the pieces)."""
        return bool(self.segmenter.accepts_constraints())

    def lacks_n_segments(self) -> bool:
        """Whether the wrapped segmenter needs ``n_segments`` and has none."""
        return bool(self.segmenter.lacks_n_segments())

    def _by_faces(self, shape: Shape) -> bool:
        if self.pieces not in ("auto", "vertex", "dual"):
            raise ParameterError(f"pieces must be 'auto', 'vertex' or 'dual', got {self.pieces!r}")
        if not isinstance(self.segmenter, Segmenter):
            raise ParameterError(f"PerComponent wraps a segmenter, got {self.segmenter!r}")
        graph = self.pieces
        if not shape.is_mesh:
            return False
        if graph == "auto":
            own = getattr(self.segmenter, "component_graph", None)
            graph = (own(shape) if callable(own) else None) or "vertex"
        return graph == "dual"

    def segment(self, shape: Shape, *, spectrum: Any = None, constraints: Any | None = None) -> Segmentation:
        """The :class:`Segmentation` of ``shape``, piece by piece (:meth:`segment_pieces`), or by the
        segmenter itself when the shape is one piece; ``info["constraints"]`` reports the constraints."""
        self.check_constraints(constraints)
        vars(self).pop("segmenters_", None)
        with inner_segmentation():
            result = self.segment_pieces(shape, constraints)
            if result is None:
                result = self.segmenter.segment(shape, spectrum=spectrum, constraints=constraints)
        return report_constraints(self.segmenter, result, constraints, shape.n_vertices)

    def segment_pieces(self, shape: Shape, constraints: Any | None = None) -> Segmentation | None:
        """The segmentation of ``shape`` piece by piece, or None when it is one piece (a connected mesh
        whose every vertex is on a face, a point cloud whose graph is connected).

        Each piece is segmented by a copy of the segmenter with its share of ``n_segments``
        (:func:`segments_per_component`: by area; at least one for a piece holding a constraint end, two
        for one holding a cannot-link, and its clicked parts; a piece of fewer than ``MIN_SPLIT_SIZE``
        vertices or faces is never split, larger ones at most one segment per ``MIN_SPLIT_SIZE // 2``),
        labels numbered piece after piece. A piece given no segment (more pieces than ``n_segments``:
        debris) joins, whole, the segment nearest to it; vertices on no face take their nearest vertex's.
        With ``n_segments`` None every piece that may be split is segmented by the segmenter's own choice.
        A must-link across two pieces raises :class:`~shape_toolkit.results.labels.ConstraintError`.
        ``info``: ``per`` (what the segmenter labels), ``n_components``, ``segments_per_component``."""
        seg, by_faces = self.segmenter, self._by_faces(shape)
        mesh = shape.is_mesh
        if mesh:
            face_comp, vcomp, n_comp = _mesh_pieces(shape, by_faces)
        else:  # a point cloud: the components of the segmenter's own (kNN) graph
            from shape_toolkit.spectra import build_graph

            n_comp, vcomp = build_graph(shape, getattr(seg, "weighting", "gaussian")).components
            face_comp, vcomp = np.zeros(0, dtype=np.int64), np.asarray(vcomp, dtype=np.int64)
        if n_comp < 2 and (vcomp >= 0).all():
            return None
        if mesh and n_comp > 1 and _unwelded(shape, vcomp):
            warnings.warn(f"{shape!r} is in {n_comp} pieces, some of which lie on one another along seams without "
                          "sharing their vertices (an unwelded mesh): each piece is segmented apart; 'shape-toolkit "
                          "clean FILE' (clean_shape) merges them first", UserWarning, stacklevel=2)
        k = check_n_segments(getattr(seg, "n_segments", None), shape.n_vertices, allow_none=True)
        cons = coerce_constraints(constraints, shape.n_vertices)
        if cons is not None and len(cons.must_link):
            across = np.flatnonzero(vcomp[cons.must_link[:, 0]] != vcomp[cons.must_link[:, 1]])
            if len(across):
                raise ConstraintError(f"must_link[{int(across[0])}] = {cons.must_link[across[0]].tolist()} joins two "
                                      "separate pieces of the shape, which are segmented one by one")
        if mesh:
            areas = np.bincount(face_comp, weights=shape.face_areas, minlength=n_comp)
            corner_comp = np.repeat(face_comp, 3)  # each component's vertices: those of its faces
            corner_ids = shape.faces.ravel()
            used = np.unique(corner_comp * shape.n_vertices + corner_ids) // shape.n_vertices
            size = np.minimum(np.bincount(used, minlength=n_comp), np.bincount(face_comp, minlength=n_comp))
        else:  # points count as area
            corner_comp, corner_ids = vcomp, np.arange(shape.n_vertices)
            size = np.bincount(vcomp, minlength=n_comp)
            areas = size.astype(np.float64)
        capacity = np.where(size < MIN_SPLIT_SIZE, 1, size // (MIN_SPLIT_SIZE // 2))
        clicked = np.zeros(n_comp, dtype=np.int64)  # must-link groups per component (wished for)
        required = np.zeros(n_comp, dtype=np.int64)  # what the constraints need (hard)
        if cons is not None:
            for g in must_link_groups(cons.must_link):
                if vcomp[g[0]] >= 0:
                    clicked[vcomp[g[0]]] += 1
            touched = vcomp[np.concatenate([cons.must_link.ravel(), cons.cannot_link.ravel()])]
            required[touched[touched >= 0]] = 1
            cl = cons.cannot_link
            inside = vcomp[cl[:, 0]][(vcomp[cl[:, 0]] == vcomp[cl[:, 1]]) & (vcomp[cl[:, 0]] >= 0)]
            required[inside] = 2
            if (required > capacity).any():
                c = int(np.flatnonzero(required > capacity)[0])
                raise ConstraintError(f"a cannot-link inside a piece of {int(size[c])} vertices or faces, "
                                      f"which is never split (fewer than {MIN_SPLIT_SIZE})")
        corner = np.full((n_comp, 3), np.inf)
        np.minimum.at(corner, corner_comp, shape.vertices[corner_ids])
        if k is not None:
            share = segments_per_component(k, areas, clicked, corner, capacity, required)
        else:  # the segmenter chooses, on every component that may be split
            share = np.where(capacity > 1, 2, 1)
        rank = np.full(n_comp + 1, -1, dtype=np.int64)  # index n_comp: vertices on no face (vcomp = -1)
        single = np.flatnonzero(share == 1)
        rank[single] = np.arange(len(single))
        labels = np.full(shape.n_vertices, -1, dtype=np.int64)
        face_labels = np.full(shape.n_faces if mesh else 0, -1, dtype=np.int64)
        offset, fitted, per = 0, [], None
        for c in np.flatnonzero(share > 1):
            fmask = face_comp == c  # the component's faces, kept in their original order
            keep = np.unique(shape.faces[fmask]) if mesh else np.flatnonzero(vcomp == c)
            new = np.full(shape.n_vertices, -1, dtype=np.int64)
            new[keep] = np.arange(len(keep))
            colors = None if shape.colors is None else shape.colors[keep]
            sub = Shape(shape.vertices[keep], new[shape.faces[fmask]] if mesh else None, shape.name, colors)
            sub_cons = None
            if cons is not None:
                pairs = [p[(vcomp[p[:, 0]] == c) & (vcomp[p[:, 1]] == c)] for p in (cons.must_link, cons.cannot_link)]
                sub_cons = type(cons)(new[pairs[0]], new[pairs[1]])
            params = seg.get_params(deep=False)  # the same parameter objects (a shared random generator too)
            if k is not None:
                params["n_segments"] = int(share[c])
            part = type(seg)(**params)
            with inner_segmentation():
                res = part.segment(sub, constraints=sub_cons)
            fitted.append(part)
            per = per or res.info.get("per")
            vl = res.labels
            fl = res.face_labels if mesh else vl[:0]
            owned = vcomp[keep] == c  # every vertex of the component on the vertex graph
            labels[keep[owned]], face_labels[fmask] = vl[owned] + offset, fl + offset
            offset += int(max(vl.max(), fl.max(initial=0)) + 1)
        # a component of one segment is that segment (vectorised, as a mesh may hold thousands of pieces)
        in_single = rank[vcomp] >= 0
        labels[in_single] = offset + rank[vcomp[in_single]]
        f_single = rank[face_comp] >= 0
        face_labels[f_single] = offset + rank[face_comp[f_single]]
        if by_faces:
            debris = np.flatnonzero(face_labels < 0)  # faces of components given no segment
            if len(debris):
                centre = shape.vertices[shape.faces].mean(axis=1)
                piece = face_comp[debris]
                best = nearest_label_per_piece(centre[debris], piece, centre, face_labels)
                face_labels[debris] = [best[p] for p in piece.tolist()]
                orphan = np.flatnonzero((labels < 0) & np.isin(vcomp, piece))  # vertices of those pieces
                labels[orphan] = [best[p] for p in vcomp[orphan].tolist()]
        lone = labels < 0  # debris (components given no segment) and vertices on no face
        if lone.any():
            lone_ids = np.flatnonzero(lone)
            piece = np.where(vcomp[lone_ids] >= 0, vcomp[lone_ids], n_comp + np.arange(len(lone_ids)))
            best = nearest_label_per_piece(shape.vertices[lone_ids], piece, shape.vertices, labels)
            labels[lone_ids] = [best[p] for p in piece.tolist()]
            debris = face_labels < 0
            face_labels[debris] = [best[p] for p in face_comp[debris].tolist()]
        ids = np.unique(np.r_[face_labels, labels])  # one consecutive numbering for faces and vertices
        self.segmenters_ = fitted
        return Segmentation(
            np.searchsorted(ids, labels).astype(np.int64),
            np.searchsorted(ids, face_labels).astype(np.int64) if mesh else None,
            {"per": per or ("face" if by_faces else "vertex"), "n_components": int(n_comp),
             "segments_per_component": share.tolist() if k is not None else None},
        )
