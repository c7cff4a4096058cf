"""K-means for the segmenters: independent of the vertex order, single-threaded, and constrained by
must-link groups (Basu, Banerjee and Mooney 2002: seeded centres, clamped groups, blocks moving whole)."""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp
from sklearn.cluster import KMeans
from threadpoolctl import threadpool_limits

from shape_toolkit.core.spectrum import fix_signs
from shape_toolkit.errors import ParameterError
from shape_toolkit.results.labels import relabel_consecutive


def single_thread() -> threadpool_limits:
    """Context limiting OpenMP/BLAS pools to one thread: k-means and GMM fits on a few thousand
    low-dimensional points are much faster without thread start-up and contention."""
    return threadpool_limits(limits=1)


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
