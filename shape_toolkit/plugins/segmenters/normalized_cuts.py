"""Recursive two-way normalized cuts (Shi and Malik 2000) of a weighted graph: the exact sweep of
eigenvector thresholds, the best cut of a node set, and the recursion down to ``k`` segments, with
must-link groups that no cut separates. Used by ``ncut`` and by ``csc`` when the clicked parts are not
``k``."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from shape_toolkit.results.labels import relabel_consecutive


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
