"""Segmentation from a user's clicks: random walks on the concavity-weighted dual graph (``seeded-walk``).

What a person clicking expects from must-links and cannot-links, as constraint propagation over the
surface (Lai, Hu, Martin and Rosin 2008, "Fast mesh segmentation using random walks", with the seeds
given by the user instead of chosen automatically). A separate method from CSC (thesis chapter 5,
plugin ``csc``), which propagates the same constraints through the commute-time embedding instead.

1. Seeds: the must-link graph's connected groups of vertices (must-link is transitive); each group
   seeds one segment, numbered in the order the groups first appear in the must-link list. A clicked
   vertex pins the faces around it.
2. The dual graph with the affinities of :func:`shape_toolkit.features.smoothing.concavity_weights`
   (``concavity_scale = 1``: Lai et al.'s ``sigma`` = the mean angular distance).
3. For every segment, the probability that a random walk from each face first reaches one of its seeds
   (the Dirichlet problem ``L_UU X_U = -L_US X_S`` of the dual-graph Laplacian, one sparse
   factorisation for all segments); every face takes its most probable segment.
4. Cannot-links: a pair whose two ends end up in the same segment is repaired by pinning the less
   confident unpinned end to its next most probable segment (and the other end to its own), then
   solving again, at most ``cannot_rounds`` times. A cannot-link inside one must-link group is a
   contradiction (:class:`~shape_toolkit.results.labels.ConstraintError`).
5. Optional: ``smoothing_lambda > 0`` runs the alpha-expansion graph cut of
   :func:`~shape_toolkit.features.smoothing.smooth_labels` on ``-log`` of the probabilities.

Mesh components that hold no seed become segments of their own, except specks (fewer than
``MIN_SPLIT_SIZE`` = 20 faces and no constrained vertex), which join the segment nearest to them. The
number of segments is the number of must-link groups (plus such components), so the method takes no
``n_segments``; it has no randomness and declares no spectrum. Labels are per face (``face_labels`` of
the returned :class:`~shape_toolkit.results.segmentation.Segmentation`; its vertex labels are those of
the largest incident area).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from shape_toolkit.api.params import Interval, Param
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.features.smoothing import EPS, concavity_weights, dual_adjacency, smooth_labels
from shape_toolkit.plugins._params import NON_NEGATIVE
from shape_toolkit.plugins.segmenters._bounds import CONCAVITY_SCALE, CONVEX_FACTOR, smoothing_lambda
from shape_toolkit.plugins.segmenters.base import BaseSegmenter
from shape_toolkit.plugins.segmenters.constraints import must_link_groups
from shape_toolkit.plugins.segmenters.per_component import MIN_SPLIT_SIZE, nearest_label_per_piece
from shape_toolkit.results.labels import ConstraintError, coerce_constraints
from shape_toolkit.results.segmentation import Segmentation


class SeededWalkSegmenter(BaseSegmenter):
    """Random walks from must-link seeds on the concavity-weighted dual graph (see module doc).

    Parameters: ``concavity_scale``, ``convex_factor``, ``min_weight`` (the affinities of
    :func:`~shape_toolkit.features.smoothing.concavity_weights`), ``cannot_rounds`` (cannot-link repair
    rounds; 0 ignores cannot-links), ``smoothing_lambda`` (0: no graph cut).

    After :meth:`segment`: ``probabilities_`` ``(m, k)`` (float32),
    ``n_segments_``, ``n_cannot_violated_`` (cannot-links whose ends share a segment at the end).
    """

    takes_constraints = True

    parameter_constraints = {
        "concavity_scale": CONCAVITY_SCALE,
        "convex_factor": CONVEX_FACTOR,
        "min_weight": Param(NON_NEGATIVE, doc="floor of the dual-graph weights"),
        "cannot_rounds": Param(Interval(int, 0), doc="rounds of separating cannot-linked clicks"),
        "smoothing_lambda": smoothing_lambda("boundary smoothing by graph cut (0: off)"),
    }

    def __init__(
        self,
        *,
        concavity_scale: float = 1.0,
        convex_factor: float = 0.2,
        min_weight: float = 1e-3,
        cannot_rounds: int = 3,
        smoothing_lambda: float = 0.0,
    ):
        self.concavity_scale = concavity_scale
        self.convex_factor = convex_factor
        self.min_weight = min_weight
        self.cannot_rounds = cannot_rounds
        self.smoothing_lambda = smoothing_lambda

    def component_graph(self, shape: Shape) -> None:
        """None: pieces without a seed are handled by the walk itself (see the module doc)."""
        return None

    def _segment(self, shape: Shape, *, spectrum: Any, constraints: Any) -> Segmentation:
        """The face segmentation; ``constraints`` (Constraints, dict or JSON path) are required."""
        from scipy.sparse.csgraph import connected_components
        from scipy.sparse.linalg import splu

        faces = shape.require_faces("seeded random-walk segmentation")
        m, n = len(faces), shape.n_vertices
        rounds = self.cannot_rounds
        lam = float(self.smoothing_lambda)
        cons = coerce_constraints(constraints, n)
        if cons is None or cons.n_must == 0:
            raise ParameterError("seeded-walk needs must-link constraints: each group of must-linked "
                                 "vertices seeds one segment")
        group = np.full(n, -1, dtype=np.int64)  # group id of every vertex, -1: in no must-link
        for g, ids in enumerate(must_link_groups(cons.must_link)):
            group[ids] = g
        cl = cons.cannot_link
        if len(cl):
            same = (group[cl[:, 0]] >= 0) & (group[cl[:, 0]] == group[cl[:, 1]])
            if same.any():
                i = int(np.flatnonzero(same)[0])
                raise ConstraintError(f"cannot_link[{i}] = {cl[i].tolist()} joins two vertices that the "
                                      "must-links put in one segment")
        k = int(group.max() + 1)
        pairs, w = concavity_weights(shape, concavity_scale=self.concavity_scale,
                                     convex_factor=self.convex_factor, min_weight=self.min_weight)
        W = dual_adjacency(m, pairs, w)
        L = (sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W).tocsr()
        vf = sp.csr_matrix((np.ones(3 * m), (faces.ravel(), np.repeat(np.arange(m), 3))), shape=(n, m))

        def faces_of(v: int) -> np.ndarray:
            return vf.indices[vf.indptr[v]:vf.indptr[v + 1]]

        pinned = np.full(m, -1, dtype=np.int64)
        for v in np.flatnonzero(group >= 0)[np.argsort(-group[group >= 0], kind="stable")]:
            pinned[faces_of(int(v))] = group[v]  # shared faces: the smallest group id wins (written last)
        n_comp, comp = connected_components(W, directed=False)
        seeded = np.zeros(n_comp, dtype=bool)
        seeded[comp[pinned >= 0]] = True
        # an unseeded piece is a segment of its own, unless it is a speck (too small to split, holding no
        # constrained vertex, beside a seeded piece): that joins the segment nearest to it
        clicked = np.zeros(n_comp, dtype=bool)
        ends = np.unique(np.concatenate([cons.must_link.ravel(), cl.ravel()]))
        clicked[comp[vf[ends].indices]] = True  # pieces of the faces around every constrained vertex
        speck = ~seeded & ~clicked & (np.bincount(comp, minlength=n_comp) < MIN_SPLIT_SIZE) & seeded.any()
        free_comp = np.flatnonzero(~seeded & ~speck)
        extra = np.full(n_comp, -1, dtype=np.int64)
        extra[free_comp] = k + np.arange(len(free_comp))
        live = seeded[comp]  # faces in a component with a seed

        def solve(pin: np.ndarray) -> np.ndarray:
            X = np.zeros((m, k))
            S = np.flatnonzero(pin >= 0)
            U = np.flatnonzero((pin < 0) & live)
            X[S, pin[S]] = 1.0
            if len(U):
                B = -(L[U][:, S] @ X[S])
                X[U] = splu(L[U][:, U].tocsc()).solve(np.ascontiguousarray(B))
            return np.clip(X, 0.0, 1.0)

        X = solve(pinned)

        def prob(v: int) -> np.ndarray:
            f = faces_of(v)
            return X[f].mean(axis=0) if len(f) else np.zeros(k)

        for _ in range(int(rounds) if len(cl) and k > 1 else 0):
            changed = False
            for u, v in cl.tolist():
                pu, pv = prob(u), prob(v)
                if np.argmax(pu) != np.argmax(pv):
                    continue
                fixed_u, fixed_v = group[u] >= 0, group[v] >= 0
                if fixed_u and fixed_v:
                    continue
                if fixed_u or (not fixed_v and pv.max() < pu.max()):
                    a, pa, b, pb = v, pv, u, pu  # move v
                else:
                    a, pa, b, pb = u, pu, v, pv
                keep = int(np.argmax(pb))
                pa = pa.copy()
                pa[keep] = -1.0
                pinned[faces_of(a)] = int(np.argmax(pa))
                pinned[faces_of(b)] = keep
                changed = True
            if not changed:
                break
            X = solve(pinned)
        if lam > 0 and k > 1:
            fl = smooth_labels(shape, None, -np.log(np.maximum(X, EPS)), lam)
        else:
            fl = np.argmax(X, axis=1).astype(np.int64)
        fl = np.where(live, fl, extra[comp])
        if speck.any():
            centre = shape.vertices[faces].mean(axis=1)
            sf = np.flatnonzero(speck[comp])
            best = nearest_label_per_piece(centre[sf], comp[sf], centre, np.where(speck[comp], -1, fl))
            fl[sf] = [best[p] for p in comp[sf].tolist()]
        self.probabilities_ = X.astype(np.float32)
        self.n_segments_ = int(len(np.unique(fl)))
        result = Segmentation.of_faces(shape, fl)
        vl = result.labels
        self.n_cannot_violated_ = int(np.sum(vl[cl[:, 0]] == vl[cl[:, 1]])) if len(cl) else 0
        return result
