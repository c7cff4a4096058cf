"""Embeddings a segmenter clusters: rows scaled to unit length, and the Laplacian embedding of a raw
weighted graph (one the algorithm built itself, e.g. CSC's modified graph, hence no shared spectrum)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


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
