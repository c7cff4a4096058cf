"""Helpers shared by the segmenter plugins (not a plugin itself: no entry point).

Default shape graph of the segmenters (thesis 3.3.3, 4.1.2, 5.2): mesh connectivity (kNN for point
clouds) with Gaussian weights ``exp(-d^2 / 2 sigma^2)``, sigma = mean edge length, so that
``0 < w_ij <= 1``; their spectra are declared with :func:`segmenter_spec` (no mass matrix).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import scipy.sparse as sp
from sklearn.cluster import KMeans
from threadpoolctl import threadpool_limits

from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import SpectrumSpec, default_spec, fix_signs
from shape_toolkit.errors import ParameterError
from shape_toolkit.results.labels import face_to_vertex_labels, relabel_consecutive, vertex_to_face_labels


def check_n_segments(k: Any, n: int, *, allow_none: bool) -> int | None:
    """Validate the number of segments: an int in ``[2, n]`` (or None when the method can choose)."""
    if k is None:
        if allow_none:
            return None
        raise ParameterError("n_segments is required for this method (an integer >= 2)")
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)):
        raise ParameterError(f"n_segments must be an integer >= 2, got {k!r}")
    if k < 2:
        raise ParameterError(f"n_segments must be >= 2, got {k}")
    if k > n:
        raise ParameterError(f"n_segments = {k} exceeds the number of vertices ({n})")
    return int(k)


def segmenter_spec(k: int, weighting: str, laplacian: str) -> SpectrumSpec:
    """The spectrum a segmenter declares: ``k`` eigenpairs of the ``laplacian`` of the ``weighting``
    graph, no mass matrix (:func:`shape_toolkit.core.spectrum.default_spec` of kind ``graph``)."""
    return default_spec(int(k), "graph", weighting=weighting, laplacian=laplacian)


def canonical_order(X: np.ndarray) -> np.ndarray:
    """A vertex order that depends on the rows of ``X`` ``(n, d)`` only, not on their numbering:
    lexicographic by the columns (first column first), after :func:`~shape_toolkit.core.spectrum.fix_signs`
    (eigenvectors come with arbitrary signs). Fitting k-means or a GMM on ``X[order]`` makes their
    random initialisation, which draws rows by index, independent of the vertex order."""
    Y = fix_signs(np.asarray(X, dtype=np.float64).reshape(len(X), -1))
    return np.lexsort(Y.T[::-1])


def fit_predict_invariant(model: Any, X: np.ndarray) -> np.ndarray:
    """``model.fit(X[order]).predict(X)`` with :func:`canonical_order`: labels of a permuted ``X``
    are the permuted labels (up to the numerical noise of the eigensolver)."""
    X = np.ascontiguousarray(X, dtype=np.float64)
    order = canonical_order(X)
    model.fit(X[order])
    return np.asarray(model.predict(X), dtype=np.int64)


def kmeans_labels(X: np.ndarray, k: int, random_state: Any, n_init: int = 10) -> np.ndarray:
    """K-means labels of the rows of ``X`` ``(n, d)``, renumbered by first appearance; independent
    of the row order (:func:`fit_predict_invariant`). ``random_state``: an int seed, see
    :func:`shape_toolkit.validation.seed_of`."""
    km = KMeans(n_clusters=k, n_init=n_init, random_state=random_state)
    with single_thread():
        return relabel_consecutive(fit_predict_invariant(km, X))


def must_link_groups(must_link: np.ndarray) -> list[np.ndarray]:
    """The node sets ``[ids, ...]`` joined by the ``(m, 2)`` must-link pairs: connected components of
    the must-link graph over the constrained nodes (a chain of clicks is one group), each sorted, the
    groups in order of first appearance in ``must_link`` (row-major)."""
    from scipy.sparse.csgraph import connected_components

    ml = np.asarray(must_link, dtype=np.int64).reshape(-1, 2)
    if len(ml) == 0:
        return []
    nodes, inv = np.unique(ml, return_inverse=True)
    inv = inv.reshape(-1, 2)
    g = sp.coo_matrix((np.ones(len(ml)), (inv[:, 0], inv[:, 1])), shape=(len(nodes), len(nodes)))
    _, comp = connected_components(g, directed=False)
    seen, first = np.unique(comp[inv.ravel()], return_index=True)
    return [nodes[comp == c] for c in seen[np.argsort(first)]]


def seeded_kmeans_labels(
    X: np.ndarray, k: int, groups: list[np.ndarray], random_state: Any, n_init: int = 10
) -> np.ndarray:
    """K-means labels of the rows of ``X`` ``(n, d)`` from the user's must-link ``groups`` (row ids;
    constrained k-means, Basu, Banerjee & Mooney 2002): the initial centres are the groups' mean rows;
    with more than ``k`` groups, ``k`` of them by farthest-first traversal (from the one farthest from
    their mean); with fewer, the missing centres are drawn by k-means++ given the seeded ones (best
    inertia of ``n_init`` draws, ``random_state`` an int seed). The rows of a seeding group stay in its
    cluster at every Lloyd step, and a group that seeds no cluster (more groups than ``k``) moves as one
    block (:func:`constrained_lloyd`), so two clicks of one must-link never end up in two segments; with
    seeds used only as the start (their "seeded k-means"), the two clicks on a large part could be pulled
    apart when splitting that part lowered the objective (PSB fish 227, held-out split: the body's two
    clicks in two segments). Independent of the row order (computed in :func:`canonical_order`).
    Renumbered by first appearance. Raises :class:`ParameterError` for ids outside ``[0, n)``, groups
    sharing a row, or fewer free rows than the clusters left to fill."""
    X = np.ascontiguousarray(X, dtype=np.float64)
    n = len(X)
    groups = [np.asarray(g, dtype=np.int64).ravel() for g in groups]
    groups = [g for g in groups if g.size]
    if not groups:
        return kmeans_labels(X, k, random_state, n_init)
    ids = np.concatenate(groups)
    if ids.min() < 0 or ids.max() >= n:
        raise ParameterError(f"must-link group ids must be in [0, {n - 1}]")
    if np.unique(ids).size != ids.size:
        raise ParameterError("must-link groups share a row (merge them into one group)")
    order = canonical_order(X)  # ties (farthest-first, argmin, empty clusters) break the same in any row order
    inv = np.empty(n, dtype=np.int64)
    inv[order] = np.arange(n)
    Xo = X[order]
    go = [inv[g] for g in groups]
    cents = np.array([Xo[g].mean(axis=0) for g in go]).reshape(-1, X.shape[1])

    def sq(A: np.ndarray, c: np.ndarray) -> np.ndarray:
        return ((A - c) ** 2).sum(axis=1)

    if len(cents) >= k:
        sel = [int(np.argmax(sq(cents, cents.mean(axis=0))))]
        d = sq(cents, cents[sel[0]])
        while len(sel) < k:
            d[sel] = -np.inf  # a group is chosen once, even where several share a mean
            sel.append(int(np.argmax(d)))
            d = np.minimum(d, sq(cents, cents[sel[-1]]))
        inits = [cents[sel]]
        clamped, blocks = [go[i] for i in sel], [go[i] for i in range(len(go)) if i not in sel]
    else:
        clamped, blocks = go, []
        rng = np.random.default_rng(random_state)
        d0 = np.min(np.stack([sq(Xo, c) for c in cents]), axis=0)
        inits = []
        for _ in range(max(1, int(n_init))):
            c, d = list(cents), d0.copy()
            while len(c) < k:
                tot = float(d.sum())
                j = int(rng.choice(len(Xo), p=d / tot)) if tot > 0 else int(rng.integers(len(Xo)))
                c.append(Xo[j])
                d = np.minimum(d, sq(Xo, Xo[j]))
            inits.append(np.array(c))
    best, best_inertia = None, np.inf
    for init in inits:
        labels, inertia = constrained_lloyd(Xo, init, clamped, blocks)
        if inertia < best_inertia:
            best, best_inertia = labels, inertia
    return relabel_consecutive(best[inv])


def constrained_lloyd(
    X: np.ndarray, centres: np.ndarray, clamped: list[np.ndarray], blocks: list[np.ndarray] | None = None,
    max_iter: int = 300, tol: float = 1e-4,
) -> tuple[np.ndarray, float]:
    """Lloyd's k-means iterations on the rows of ``X`` ``(n, d)`` from ``centres`` ``(k, d)`` with the
    must-links of Basu et al.'s constrained k-means: the rows of ``clamped[i]`` stay in cluster ``i``,
    the rows of each of ``blocks`` go together to the cluster nearest them in sum. Stops when no label
    changes, when the centres move less than ``tol`` times the data's mean variance (squared, in sum;
    scikit-learn's rule), or after ``max_iter`` steps; the labels returned are the assignment to the
    final centres. A free cluster left empty takes the free row farthest from its centre among the
    clusters with more than one row. Returns int64 labels ``(n,)`` and the inertia (sum of squared
    distances to the centres)."""
    C = np.array(centres, dtype=np.float64)
    k, n = len(C), len(X)
    blocks = blocks or []
    rows = np.concatenate([np.asarray(g, dtype=np.int64) for g in clamped]) if clamped else np.zeros(0, np.int64)
    fixed = np.concatenate([np.full(len(g), i, dtype=np.int64) for i, g in enumerate(clamped)]) if clamped \
        else np.zeros(0, np.int64)
    free = np.ones(n, dtype=bool)
    free[rows] = False
    for b in blocks:
        free[b] = False
    if free.sum() < k - len(clamped):
        raise ParameterError(f"cannot form {k} clusters: {int(free.sum())} rows are free of must-links")
    x2 = (X**2).sum(axis=1)
    tol_abs = float(tol) * float(np.mean(np.var(X, axis=0)))

    def assign(C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        D = X @ (-2.0 * C).T  # squared distances less ||x||^2, which no argmin over clusters needs
        D += (C**2).sum(axis=1)[None, :]
        lab = np.argmin(D, axis=1)
        lab[rows] = fixed
        for b in blocks:
            lab[b] = int(np.argmin(D[b].sum(axis=0)))
        counts = np.bincount(lab, minlength=k)
        for j in np.flatnonzero(counts == 0):  # only free clusters can empty
            d = np.where(free & (counts[lab] > 1), D[np.arange(n), lab] + x2, -np.inf)
            far = int(np.argmax(d))
            counts[lab[far]] -= 1
            lab[far], counts[j] = j, 1
        return lab, counts

    labels = None
    with single_thread():
        for _ in range(max_iter):
            new, counts = assign(C)
            if labels is not None and np.array_equal(new, labels):
                break
            labels = new
            member = sp.csr_matrix((np.ones(n), (labels, np.arange(n))), shape=(k, n))
            C_new = np.asarray(member @ X) / np.maximum(counts, 1)[:, None]
            shift = float(((C_new - C) ** 2).sum())
            C = C_new
            if shift <= tol_abs:
                labels, _ = assign(C)
                break
        else:  # max_iter steps: the labels of the last centres
            labels, _ = assign(C)
    return labels, float(((X - C[labels]) ** 2).sum())


def sweep_cut(
    W: sp.csr_matrix,
    vectors: np.ndarray,
    volume: np.ndarray,
    min_volume: float,
    groups: list[np.ndarray] | None = None,
    separate: bool = False,
) -> tuple[float, np.ndarray | None]:
    """The best two-way normalized cut among the threshold cuts of the columns of ``vectors``
    ``(n, q)`` of the graph ``W`` ``(n, n)``: ``(Ncut, mask of one side)``, or ``(inf, None)`` when
    no threshold leaves ``min_volume`` of ``volume`` ``(n,)`` on both sides. ``groups``: node sets
    (e.g. must-link groups) that no accepted cut may separate; with ``separate``, an accepted cut also
    leaves at least one whole group on each side. O(q (e + n log n))."""
    n = W.shape[0]
    coo = sp.triu(W, k=1).tocoo()
    r, c, x = coo.row, coo.col, coo.data
    groups = [np.asarray(g, dtype=np.int64) for g in (groups or []) if len(g)]
    total = float(volume.sum())
    best: tuple[float, np.ndarray | None] = (np.inf, None)

    def count(starts: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
        return np.cumsum(np.bincount(starts, weights=weights, minlength=n + 1))[: n - 1]

    for q in range(vectors.shape[1]):
        order = np.argsort(vectors[:, q], kind="stable")
        rank = np.empty(n, dtype=np.int64)
        rank[order] = np.arange(n)
        lo, hi = np.minimum(rank[r], rank[c]), np.maximum(rank[r], rank[c])
        # an edge is cut by every prefix {order[:t+1]} with lo <= t < hi
        delta = np.bincount(lo, weights=x, minlength=n + 1) - np.bincount(hi, weights=x, minlength=n + 1)
        cut = np.cumsum(delta)[: n - 1]
        vol = np.cumsum(volume[order])[: n - 1]
        ok = (vol >= min_volume) & (total - vol >= min_volume)
        if groups:  # group g lies in the prefix iff max rank <= t, in the rest iff min rank > t
            gmin = np.array([rank[g].min() for g in groups])
            gmax = np.array([rank[g].max() for g in groups])
            ok &= count(gmin) - count(gmax) == 0
            if separate:
                ok &= (count(gmax) >= 1) & (len(groups) - count(gmin) >= 1)
        if not ok.any():
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            score = np.where(ok, cut / vol + cut / (total - vol), np.inf)
        t = int(np.argmin(score))
        if score[t] < best[0]:
            mask = np.zeros(n, dtype=bool)
            mask[order[: t + 1]] = True
            best = (float(score[t]), mask)
    return best


def best_normalized_cut(
    W: sp.csr_matrix,
    idx: np.ndarray,
    volume: np.ndarray,
    n_vectors: int,
    min_volume: float,
    *,
    tol: float = 1e-6,
    groups: list[np.ndarray] | None = None,
) -> tuple[float, np.ndarray | None, bool]:
    """Shi-Malik two-way cut of the nodes ``idx`` of ``W`` ``(n, n)``: the ``n_vectors`` first
    non-trivial generalized eigenvectors of ``(D - W) v = lambda D v`` on the induced subgraph, swept
    (:func:`sweep_cut`; ``volume`` ``(n,)``). ``groups`` (node ids of ``W``; those inside ``idx``
    count): never separated, and when two or more lie inside, the cut must separate them. Returns
    ``(Ncut, mask over idx, whether it had to separate groups)``; ``(inf, None, ...)`` if none."""
    from shape_toolkit.core.eigen import smallest_eigenpairs

    pos = np.full(W.shape[0], -1, dtype=np.int64)
    pos[idx] = np.arange(len(idx))
    local = [pos[g] for g in (groups or []) if len(g) and (pos[g] >= 0).all()]
    separate = len(local) >= 2
    if len(idx) < 4:
        return np.inf, None, separate
    Ws = W[idx][:, idx].tocsr()
    d = np.asarray(Ws.sum(axis=1)).ravel()
    if d.max() <= 0:
        return np.inf, None, separate
    L = sp.csr_matrix(sp.diags(d) - Ws)
    q = min(n_vectors + 1, len(idx) - 1)
    _, vecs = smallest_eigenpairs(L, q, np.maximum(d, 1e-12 * d.max()), tol=tol)
    return (*sweep_cut(Ws, vecs[:, 1:], volume[idx], min_volume, local, separate), separate)


def split_by_normalized_cuts(
    W: sp.csr_matrix,
    labels: np.ndarray,
    k: int,
    *,
    n_vectors: int = 3,
    min_fraction: float = 1e-3,
    tol: float = 1e-6,
    groups: list[np.ndarray] | None = None,
) -> tuple[np.ndarray, list[float]]:
    """Recursive two-way normalized cuts (Shi and Malik 2000) of the nodes of ``W`` ``(n, n)`` starting
    from the segments of ``labels`` ``(n,)``: while fewer than ``k`` exist, the segment whose best cut
    (:func:`best_normalized_cut`, each side at least ``min_fraction`` of the whole graph's volume) has
    the smallest Ncut is split. ``groups`` (e.g. must-link groups): never separated, and segments
    holding two or more of them are split first, each time between groups. Returns the labels
    (renumbered by first appearance) and the Ncut of each split made, in order; fewer than ``k``
    segments when no admissible cut is left. Deterministic."""
    labels = np.asarray(labels, dtype=np.int64).copy()
    volume = np.asarray(W.sum(axis=1)).ravel()
    min_volume = float(min_fraction) * float(volume.sum())
    members = {int(s): np.flatnonzero(labels == s) for s in np.unique(labels)}
    cache: dict[int, tuple[float, np.ndarray | None, bool]] = {}
    next_id = int(labels.max()) + 1 if len(labels) else 0
    values: list[float] = []
    while len(members) < k:
        for s, idx in members.items():
            if s not in cache:
                cache[s] = best_normalized_cut(W, idx, volume, n_vectors, min_volume, tol=tol, groups=groups)
        ready = [s for s, v in cache.items() if v[1] is not None]
        if not ready:
            break
        if any(cache[s][2] for s in ready):  # segments holding several groups first
            ready = [s for s in ready if cache[s][2]]
        s = min(ready, key=lambda t: (cache[t][0], t))
        value, mask, _ = cache.pop(s)
        idx = members.pop(s)
        a, b = next_id, next_id + 1
        next_id += 2
        members[a], members[b] = idx[mask], idx[~mask]
        labels[idx[mask]], labels[idx[~mask]] = a, b
        values.append(value)
    return relabel_consecutive(labels), values


def single_thread() -> threadpool_limits:
    """Context limiting OpenMP/BLAS pools to one thread: k-means and GMM fits on a few thousand
    low-dimensional points are much faster without thread start-up and contention."""
    return threadpool_limits(limits=1)


def row_normalize(X: np.ndarray) -> np.ndarray:
    """Rows of ``X`` scaled to unit Euclidean length (zero rows left at zero)."""
    norms = np.linalg.norm(X, axis=1, keepdims=True)
    return X / np.where(norms > 0, norms, 1.0)


def laplacian_embedding_of(W: sp.csr_matrix, k: int) -> tuple[np.ndarray, np.ndarray]:
    """``(eigenvalues (k,), eigenvectors (n, k))``: the ``k`` first non-null eigenpairs of
    ``D - W`` for a connected graph ``W``."""
    from shape_toolkit.core.eigen import smallest_eigenpairs

    d = np.asarray(W.sum(axis=1)).ravel()
    L = sp.csr_matrix(sp.diags(d) - W)
    vals, vecs = smallest_eigenpairs(L, min(k + 1, W.shape[0]))
    return vals[1:], vecs[:, 1:]


def face_labels_of(seg: Any, faces: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Per-face labels int64 ``(m,)`` of the segmentation ``seg`` just made of a mesh with ``(m, 3)``
    ``faces``: its own ``face_labels_`` when it segments faces (dual graph, graph cut), else the
    majority of each face's vertex ``labels`` ``(n,)``."""
    own = getattr(seg, "face_labels_", None)
    if own is not None and len(own) == len(faces):
        return np.asarray(own, dtype=np.int64)
    return vertex_to_face_labels(faces, labels)


def face_segments_to_vertices(shape: Shape, face_labels: np.ndarray) -> np.ndarray:
    """Per-vertex labels ``(n,)`` from face labels ``(m,)``: the label of the largest incident area;
    vertices in no face take their nearest vertex's (what :meth:`Segmenter.segment` returns for a
    face-based segmenter)."""
    vl = face_to_vertex_labels(shape.faces, face_labels, shape.n_vertices, shape.face_areas)
    lone = vl < 0
    if lone.any():
        from scipy.spatial import cKDTree

        ok = np.flatnonzero(~lone)
        _, j = cKDTree(shape.vertices[ok]).query(shape.vertices[lone])
        vl[lone] = vl[ok[j]]
    return vl


def merge_to_segments(
    face_labels: np.ndarray, pairs: np.ndarray, areas: np.ndarray, k: int | None
) -> np.ndarray:
    """Segments = connected components of equal labels on the dual graph (CGAL's rule); with ``k``,
    the smallest segment is merged into the neighbour it shares the most dual edges with until ``k``
    remain (segments without a neighbour, i.e. whole mesh components, are never merged). Returns
    consecutive labels numbered by decreasing area (ties: smallest face id), independent of the face
    order up to those ties."""
    from scipy.sparse.csgraph import connected_components

    from shape_toolkit.features.smoothing import dual_adjacency

    face_labels = np.asarray(face_labels).ravel()
    m = len(face_labels)
    same = face_labels[pairs[:, 0]] == face_labels[pairs[:, 1]]
    A = dual_adjacency(m, pairs[same], np.ones(int(same.sum())))
    n_comp, comp = connected_components(A, directed=False)
    if k is not None and n_comp > k:
        area = np.bincount(comp, weights=areas, minlength=n_comp)
        cross = pairs[comp[pairs[:, 0]] != comp[pairs[:, 1]]]
        ca, cb = comp[cross[:, 0]], comp[cross[:, 1]]
        nb: list[dict[int, int]] = [dict() for _ in range(n_comp)]
        for a, b in zip(ca.tolist(), cb.tolist()):
            nb[a][b] = nb[a].get(b, 0) + 1
            nb[b][a] = nb[b].get(a, 0) + 1
        parent = np.arange(n_comp)
        alive = n_comp
        import heapq

        heap = [(float(area[i]), i) for i in range(n_comp)]
        heapq.heapify(heap)
        while alive > k and heap:
            ar, i = heapq.heappop(heap)
            if parent[i] != i or ar != area[i] or not nb[i]:
                continue
            j = max(nb[i].items(), key=lambda t: (t[1], -t[0]))[0]
            parent[i] = j
            area[j] += area[i]
            for q, c in nb[i].items():
                if q == j:
                    continue
                nb[j][q] = nb[j].get(q, 0) + c
                del nb[q][i]
                nb[q][j] = nb[q].get(j, 0) + c
            del nb[j][i]
            nb[i] = {}
            alive -= 1
            heapq.heappush(heap, (float(area[j]), j))
        root = parent.copy()
        while True:
            nxt = root[root]
            if np.array_equal(nxt, root):
                break
            root = nxt
        comp = root[comp]
    uniq, comp = np.unique(comp, return_inverse=True)
    comp = comp.ravel()
    tot = np.bincount(comp, weights=areas, minlength=len(uniq))
    first = np.full(len(uniq), m)
    np.minimum.at(first, comp, np.arange(m))
    rank = np.empty(len(uniq), dtype=np.int64)
    rank[np.lexsort((first, -tot))] = np.arange(len(uniq))
    return rank[comp]


#: a mesh component with fewer vertices or faces than this is never split (one segment at most)
MIN_SPLIT_SIZE = 20


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


class ConstraintWarning(UserWarning):
    """A constrained segmenter returned labels that break some of its must-links or cannot-links."""


_REPORT_DEPTH = [0]  # nesting of reported segment calls: per-component copies report through the outer one


def reports_constraints(segment: Callable) -> Callable:
    """Decorator of a constrained segmenter's ``segment(shape, *, spectrum, constraints)``: with
    constraints, sets ``constraints_kept_`` (:func:`~shape_toolkit.results.labels.constraint_report`
    of the returned vertex labels) and warns (:class:`ConstraintWarning`, one line: how many it
    could not keep and why) when some are broken; so a segmenter keeps every click or says so."""
    import functools
    import warnings

    from shape_toolkit.results.labels import coerce_constraints, constraint_report

    @functools.wraps(segment)
    def run(self: Any, shape: Shape, *, spectrum: Any = None, constraints: Any | None = None) -> np.ndarray:
        _REPORT_DEPTH[0] += 1
        try:
            labels = segment(self, shape, spectrum=spectrum, constraints=constraints)
        finally:
            _REPORT_DEPTH[0] -= 1
        cons = coerce_constraints(constraints, shape.n_vertices) if constraints is not None else None
        if cons is None or len(cons) == 0 or _REPORT_DEPTH[0] > 0:
            return labels
        rep = constraint_report(labels, cons)
        self.constraints_kept_ = rep
        if rep["reason"] is not None:
            warnings.warn(
                f"{type(self).__name__} broke {rep['must_link_broken']} of {rep['must_link']} must-links and "
                f"{rep['cannot_link_broken']} of {rep['cannot_link']} cannot-links: {rep['reason']}",
                ConstraintWarning, stacklevel=3,  # the caller of segment (past BasePlugin's parameter check)
            )
        return labels

    return run


def split_disconnected_clouds(constrained: bool) -> Callable:
    """Decorator of a spectral segmenter's ``segment(shape, *, spectrum, constraints)``: when it raises
    :class:`~shape_toolkit.errors.DisconnectedGraphError` on a point cloud given no spectrum (a kNN graph
    in several pieces: two objects in one scan), the cloud is segmented piece by piece instead
    (:func:`segment_per_component` with ``points``; ``constrained``: the constraints are split between the
    pieces, else ignored). Connected clouds pay nothing; a graph that is connected but numerically
    disconnected still raises."""
    import functools

    from shape_toolkit.errors import DisconnectedGraphError, NumericallyDisconnectedGraphError

    def wrap(segment: Callable) -> Callable:
        @functools.wraps(segment)
        def run(self: Any, shape: Shape, *, spectrum: Any = None, constraints: Any | None = None) -> np.ndarray:
            try:
                return segment(self, shape, spectrum=spectrum, constraints=constraints)
            except DisconnectedGraphError as exc:
                if shape.is_mesh or spectrum is not None or isinstance(exc, NumericallyDisconnectedGraphError):
                    raise
                split = segment_per_component(self, shape, constraints if constrained else None, points=True)
                if split is None:
                    raise
                return split

        return run

    return wrap


def segment_per_component(
    seg: Any, shape: Shape, constraints: Any, *, by_faces: bool = False, points: bool = False
) -> np.ndarray | None:
    """Vertex labels ``(n,)`` of a mesh made of several connected components (or with vertices on no
    face), or of a point cloud whose graph falls apart, each component segmented on its own by a copy of
    the segmenter ``seg`` with its share of ``n_segments`` (:func:`segments_per_component`: by area; at
    least one for a component holding a constraint end, two for one holding a cannot-link, and its
    clicked parts; a component of fewer than ``MIN_SPLIT_SIZE`` vertices or faces is never split, larger
    ones at most one segment per ``MIN_SPLIT_SIZE // 2``), labels numbered component after component. A
    component given no segment (more components than ``n_segments``: debris) joins, whole, the segment
    nearest to it; vertices on no face take their nearest vertex's. ``by_faces``: for a segmenter of the
    dual graph, components are those of the dual graph (faces meeting only at a vertex, a "bowtie", are
    apart; a vertex shared by several goes with the one of largest incident area, which labels it and
    holds its constraints). With ``n_segments`` None every component that may be split is
    segmented by the segmenter's own choice. A must-link across two components raises
    :class:`~shape_toolkit.results.labels.ConstraintError`. ``points``: a point cloud is split into the
    components of the segmenter's own graph (``build_graph(shape, seg.weighting)``, kNN), each point
    counting as a unit of area (see :func:`split_disconnected_clouds`). Returns None for a connected mesh
    whose every vertex is on a face, or a point cloud without ``points`` or connected (segment as usual).
    Sets ``face_labels_`` ``(m,)`` (meshes), ``n_segments_``, ``n_components_`` and
    ``segments_per_component_`` on ``seg``, after removing every fitted attribute (``name_``) left by a
    previous call, whatever it returns."""
    from shape_toolkit.results.labels import ConstraintError, coerce_constraints

    for name in [a for a in vars(seg) if a.endswith("_") and not a.startswith("_")]:  # fitted by a previous call
        del vars(seg)[name]
    mesh = shape.is_mesh
    if mesh:
        face_comp, vcomp, n_comp = _mesh_pieces(shape, by_faces)
    elif not points:
        return None
    else:  # a point cloud: the components of the segmenter's own (kNN) graph
        from shape_toolkit.core.graph import build_graph

        n_comp, vcomp = build_graph(shape, getattr(seg, "weighting", "gaussian")).components
        face_comp, vcomp = np.zeros(0, dtype=np.int64), np.asarray(vcomp, dtype=np.int64)
    if n_comp < 2 and (vcomp >= 0).all():
        return None
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
    offset = 0
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
        params = seg.get_params(deep=False)
        if k is not None:
            params["n_segments"] = int(share[c])
        part = type(seg)(**params)
        vl = np.asarray(part.segment(sub, constraints=sub_cons), dtype=np.int64)
        fl = face_labels_of(part, sub.faces, vl) if mesh else vl[:0]
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
    if mesh:
        seg.face_labels_ = np.searchsorted(ids, face_labels).astype(np.int64)
    seg.n_components_ = int(n_comp)
    seg.segments_per_component_ = share.tolist() if k is not None else None
    out = np.searchsorted(ids, labels).astype(np.int64)
    seg.n_segments_ = int(len(ids))
    return out
