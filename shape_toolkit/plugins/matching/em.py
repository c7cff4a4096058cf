"""EM registration of two point sets by an orthogonal transform (thesis Algorithm 7, section 7.4.1; Horaud et al.
2011): the source points are the means of an isotropic Gaussian mixture with a uniform outlier class, the target
points the data; EM estimates the orthogonal ``Q`` and the variance ``sigma`` (eq. 7.1-7.3). Shared by the
``em-registration`` and ``eigvec-alignment`` matchers.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from shape_toolkit.errors import ParameterError
from shape_toolkit.validation import check_random_state

__all__ = ["ATTRACTOR_TOL", "em_register", "procrustes"]

#: how close (largest entry difference) an EM iterate must come to a known fixed point to be taken as bound there
ATTRACTOR_TOL = 1e-2


def procrustes(S: np.ndarray) -> np.ndarray:
    """The orthogonal ``Q`` maximizing ``tr(Q^T S)`` for a ``(k, k)`` correlation ``S``."""
    U, _, Vt = np.linalg.svd(S)
    return U @ Vt


def _e_step(tree: cKDTree, Y: np.ndarray, sigma: float, log_out: float, nn: int) -> tuple[np.ndarray, np.ndarray]:
    """Truncated posteriors of eq. 7.3 for targets ``Y`` ``(q, k)`` already rotated into the means' frame
    (``y Q``): the ``nn`` nearest source means (``tree``) of each, ``alpha`` and their indices, both ``(q, nn)``;
    never ``(q, n)``."""
    d, idx = tree.query(Y, k=nn)
    d = np.asarray(d).reshape(len(Y), nn)
    idx = np.asarray(idx).reshape(len(Y), nn)
    logits = -(d**2) / (2.0 * sigma)
    top = np.maximum(logits.max(axis=1), log_out)
    e = np.exp(logits - top[:, None])
    denom = e.sum(axis=1) + np.exp(log_out - top)
    return e / denom[:, None], idx


def em_register(
    X: np.ndarray, Y: np.ndarray, Q0: np.ndarray, *, sigma0: float | None = None, outlier_weight: float = 0.1,
    n_neighbors: int = 10, max_iter: int = 50, tol: float = 1e-5, max_samples: int | None = None,
    random_state: Any = 0, posteriors: bool = True, attractor: np.ndarray | None = None,
) -> tuple[np.ndarray, float, sp.csr_matrix | None]:
    """EM of Algorithm 7 on source means ``X`` ``(n, k)`` and target data ``Y`` ``(n', k)`` from an
    initial orthogonal ``Q0``; returns ``Q``, ``sigma`` and the truncated posteriors
    ``alpha`` as CSR ``(n, n')`` (entry ``(i, j)`` = ``P(i | y_j)``, eq. 7.3; None without ``posteriors``).
    ``attractor``: a ``Q`` this same EM (same data, sample and ``tol``) converged to; once an iterate comes
    within ``ATTRACTOR_TOL`` of it the fit would end there, so it is returned at once.

    Memory is ``O((n + n') (k + n_neighbors))``: each E-step keeps the ``n_neighbors`` nearest means
    of each target point (KD-tree), never an ``(n, n')`` block. With ``max_samples`` below ``n'``,
    the iterations fit ``Q`` and ``sigma`` to a fixed uniform sample of that many target points
    (drawn with ``random_state``; the M-step sums are then unbiased estimates of the full ones)
    and one last E-step on every target point gives the posteriors."""
    n, k = X.shape
    m = Y.shape[0]
    if Y.shape[1] != k or Q0.shape != (k, k):
        raise ParameterError("X, Y and Q0 must share the embedding dimension")
    nn = int(min(n_neighbors, n))
    if not np.allclose(Q0 @ Q0.T, np.eye(k), atol=1e-8):
        raise ParameterError("Q0 must be orthogonal (a rotation or reflection of the embedding)")
    Q = Q0.copy()
    # Q is orthogonal, so |y - Q x| = |y Q - x|: one tree of the means serves every iteration
    tree = cKDTree(X)
    # uniform outlier density over the target's bounding box
    volume = float(np.prod(np.maximum(Y.max(0) - Y.min(0), 1e-12)))
    sample = None
    if max_samples is not None and m > int(max_samples):
        sample = np.sort(check_random_state(random_state).choice(m, int(max_samples), replace=False))
    Ys = Y if sample is None else Y[sample]
    if sigma0 is None:
        d, _ = tree.query(Ys @ Q, k=1)
        sigma0 = float(np.mean(d**2)) / k * 4.0
    sigma = max(float(sigma0), 1e-12)
    w = float(np.clip(outlier_weight, 0.0, 0.99))

    def log_outlier(sigma: float) -> float:
        # outlier term theta sigma^(k/2): (2 pi sigma)^(k/2) w/(1-w) n / V   (CPD-style constant)
        if w <= 0:
            return -np.inf
        return (k / 2.0) * np.log(2 * np.pi * sigma) + np.log(w / (1 - w) * n / volume)

    alpha = idx = None
    for _ in range(max_iter):
        alpha, idx = _e_step(tree, Ys @ Q, sigma, log_outlier(sigma), nn)
        # M-step: weighted orthogonal Procrustes and the variance, one neighbour rank at a time
        S = np.zeros((k, k))
        for c in range(nn):
            S += (Ys * alpha[:, c : c + 1]).T @ X[idx[:, c]]
        Q_new = procrustes(S)
        MX = X @ Q_new.T
        total = float(alpha.sum())
        if total <= 1e-12:
            break
        resid = 0.0
        for c in range(nn):
            resid += float(alpha[:, c] @ ((Ys - MX[idx[:, c]]) ** 2).sum(axis=1))
        sigma_new = max(resid / (k * total), 1e-12)
        change = abs(sigma_new - sigma) / sigma + np.abs(Q_new - Q).max()
        Q, sigma = Q_new, sigma_new
        if change <= tol:  # an exact fixed point stops even with tol = 0
            break
        if attractor is not None and np.abs(Q - attractor).max() < ATTRACTOR_TOL:
            Q = attractor
            break
    if not posteriors:
        return Q, sigma, None
    if sample is not None or alpha is None:  # posteriors of every target point under the final fit
        alpha, idx = _e_step(tree, Y @ Q, sigma, log_outlier(sigma), nn)
    cols = np.repeat(np.arange(m), nn)
    P = sp.csr_matrix((alpha.ravel(), (idx.ravel(), cols)), shape=(n, m))
    return Q, sigma, P
