"""Segments as connected parts of equal labels on the dual graph, merged down to ``k`` (CGAL's rule),
numbered by decreasing area."""

from __future__ import annotations

import numpy as np


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
