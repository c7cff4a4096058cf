"""Dense probabilistic matching by EM registration of spectral embeddings (thesis Algorithm 7,
section 7.4.1; Horaud et al. 2011).

The source embedding points ``x_i`` (first ``k`` non-null Laplace-Beltrami eigenvectors, area
normalized) are the means of an isotropic Gaussian mixture with a uniform outlier class; the
target embedding points ``x'_j`` are the data. EM estimates an orthogonal ``k x k`` transform
``Q`` (eigenvector signs, order and mixing) and the variance ``sigma`` (eq. 7.1-7.3).

Memory stays linear: the E-step keeps, for each target point, only its ``n_neighbors`` nearest
transformed source means (KD-tree); the other posteriors are below ``exp(-d^2 / 2 sigma)`` of the
kept ones and are dropped. Posteriors are returned as a sparse ``(n_src, n_tgt)`` matrix holding
``P(source i | target j)`` (columns sum to at most 1; the rest is the outlier class).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from shape_toolkit.api.hookspecs import hookimpl
from shape_toolkit.api.interfaces import DenseMatcher
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum, SpectrumSpec, default_spec
from shape_toolkit.errors import ParameterError
from shape_toolkit.plugins.matching._common import Basis, basis_of, check_seeds
from shape_toolkit.results.correspondence import Correspondence

__all__ = ["EMRegistrationMatcher", "em_register", "procrustes"]


def procrustes(S: np.ndarray) -> np.ndarray:
    """The orthogonal ``Q`` maximizing ``tr(Q^T S)`` for a ``(k, k)`` correlation ``S``."""
    U, _, Vt = np.linalg.svd(S)
    return U @ Vt


def em_register(
    X: np.ndarray,
    Y: np.ndarray,
    Q0: np.ndarray,
    *,
    sigma0: float | None = None,
    outlier_weight: float = 0.1,
    n_neighbors: int = 10,
    max_iter: int = 50,
    tol: float = 1e-5,
) -> tuple[np.ndarray, float, sp.csr_matrix]:
    """EM of Algorithm 7 on source means ``X`` ``(n, k)`` and target data ``Y`` ``(n', k)`` from an
    initial orthogonal ``Q0``; returns ``Q``, ``sigma`` and the truncated posteriors
    ``alpha`` as CSR ``(n, n')`` (entry ``(i, j)`` = ``P(i | y_j)``, eq. 7.3)."""
    n, k = X.shape
    m = Y.shape[0]
    if Y.shape[1] != k or Q0.shape != (k, k):
        raise ParameterError("X, Y and Q0 must share the embedding dimension")
    nn = int(min(n_neighbors, n))
    Q = Q0.copy()
    # uniform outlier density over the target's bounding box
    volume = float(np.prod(np.maximum(Y.max(0) - Y.min(0), 1e-12)))
    if sigma0 is None:
        d, _ = cKDTree(X @ Q.T).query(Y, k=1)
        sigma0 = float(np.mean(d**2)) / k * 4.0
    sigma = max(float(sigma0), 1e-12)
    w = float(np.clip(outlier_weight, 0.0, 0.99))
    cols = np.repeat(np.arange(m), nn)
    P = None
    for _ in range(max_iter):
        MX = X @ Q.T
        d, idx = cKDTree(MX).query(Y, k=nn)
        d = np.asarray(d).reshape(m, nn)
        idx = np.asarray(idx).reshape(m, nn)
        logits = -(d**2) / (2.0 * sigma)
        # outlier term theta sigma^(k/2): (2 pi sigma)^(k/2) w/(1-w) n / V   (CPD-style constant)
        log_out = -np.inf
        if w > 0:
            log_out = (k / 2.0) * np.log(2 * np.pi * sigma) + np.log(w / (1 - w) * n / volume)
        top = np.maximum(logits.max(axis=1), log_out)
        e = np.exp(logits - top[:, None])
        denom = e.sum(axis=1) + np.exp(log_out - top)
        alpha = e / denom[:, None]  # (m, nn)
        P = sp.csr_matrix((alpha.ravel(), (idx.ravel(), cols)), shape=(n, m))
        # M-step: weighted orthogonal Procrustes and the variance
        S = np.zeros((k, k))
        for c in range(nn):
            S += (Y * alpha[:, c : c + 1]).T @ X[idx[:, c]]
        Q_new = procrustes(S)
        MX = X @ Q_new.T
        total = float(alpha.sum())
        if total <= 1e-12:
            break
        resid = np.einsum("jc,jc->", alpha, ((Y[:, None, :] - MX[idx]) ** 2).sum(axis=2))
        sigma_new = max(resid / (k * total), 1e-12)
        change = abs(sigma_new - sigma) / sigma + np.abs(Q_new - Q).max()
        Q, sigma = Q_new, sigma_new
        if change < tol:
            break
    return Q, sigma, P


def hard_map(
    P: sp.csr_matrix, threshold: float = 0.5, one_to_one: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Hard assignment of section 7.5 from posteriors ``(n_src, n_tgt)``: each source vertex
    takes the target of its largest posterior when it exceeds ``threshold`` (else -1); with
    ``one_to_one`` each target keeps its best source. Returns ``(target_of, confidence)``."""
    P = P.tocsr()
    n = P.shape[0]
    target_of = np.full(n, -1, dtype=np.int64)
    conf = np.zeros(n)
    counts = np.diff(P.indptr)
    has = np.flatnonzero(counts)
    if has.size:
        best = np.asarray(P[has].argmax(axis=1)).ravel()
        val = np.asarray(P[has].max(axis=1).todense()).ravel()
        ok = val > threshold
        target_of[has[ok]] = best[ok]
        conf[has] = val
    if one_to_one:
        src = np.flatnonzero(target_of >= 0)
        order = src[np.argsort(-conf[src], kind="stable")]
        _, first = np.unique(target_of[order], return_index=True)
        keep = np.zeros(n, dtype=bool)
        keep[order[first]] = True
        target_of[~keep] = -1
    return target_of, conf


class EMRegistrationMatcher(DenseMatcher):
    """Algorithm 7: EM registration of the ``k``-dimensional Laplacian embeddings, initialized
    by orthogonal Procrustes on the ``seeds`` (e.g. the output of seed-growing; required).

    Returns the hard map of section 7.5 (largest posterior above ``threshold``, optionally
    ``one_to_one``) and the sparse posteriors. ``fill_unmatched`` gives every source vertex left
    without a confident match the target nearest to its transformed embedding point
    (confidence 0), for a map defined everywhere. ``n_neighbors`` caps the posteriors kept per
    target vertex (memory ``O(n' n_neighbors)``).
    """

    def __init__(
        self,
        k: int = 8,
        outlier_weight: float = 0.1,
        n_neighbors: int = 10,
        max_iter: int = 50,
        tol: float = 1e-5,
        threshold: float = 0.5,
        one_to_one: bool = False,
        fill_unmatched: bool = True,
    ):
        self.k = k
        self.outlier_weight = outlier_weight
        self.n_neighbors = n_neighbors
        self.max_iter = max_iter
        self.tol = tol
        self.threshold = threshold
        self.one_to_one = one_to_one
        self.fill_unmatched = fill_unmatched

    def _check(self) -> None:
        if not isinstance(self.k, (int, np.integer)) or not 1 <= self.k <= 100:
            raise ParameterError(f"k must be an integer in [1, 100], got {self.k!r}")
        if not 0 <= self.outlier_weight < 1:
            raise ParameterError("outlier_weight must be in [0, 1)")
        if self.n_neighbors < 1 or self.max_iter < 1:
            raise ParameterError("n_neighbors and max_iter must be >= 1")

    def spectrum_spec(self) -> SpectrumSpec:
        """The Laplace-Beltrami spectrum with ``k + 1`` eigenpairs (the first is constant)."""
        return default_spec(int(self.k) + 1)

    def _bases(self, source, target, source_spectrum, target_spectrum) -> tuple[Basis, Basis]:
        spec_s = self._spectrum(source, source_spectrum)
        spec_t = self._spectrum(target, target_spectrum)
        return basis_of(spec_s, self.k + 1), basis_of(spec_t, self.k + 1)

    def _embeddings(self, source, target, source_spectrum, target_spectrum):
        bs, bt = self._bases(source, target, source_spectrum, target_spectrum)
        return bs.evecs[:, 1 : self.k + 1], bt.evecs[:, 1 : self.k + 1]

    def _initial_transform(self, X, Y, seeds, source, target, **kw) -> np.ndarray:
        if seeds is None or len(seeds) == 0:
            raise ParameterError(
                "em-registration needs seed matches to initialize (e.g. from seed-growing); "
                "use eigvec-alignment for an unsupervised start"
            )
        return procrustes(Y[seeds[:, 1]].T @ X[seeds[:, 0]])

    def _finish(self, X, Y, Q0, target: Shape, info: dict) -> Correspondence:
        Q, sigma, P = em_register(
            X, Y, Q0, outlier_weight=self.outlier_weight, n_neighbors=self.n_neighbors,
            max_iter=self.max_iter, tol=self.tol,
        )
        t, conf = hard_map(P, self.threshold, self.one_to_one)
        n_confident = int((t >= 0).sum())
        if self.fill_unmatched:
            miss = np.flatnonzero(t < 0)
            if miss.size:
                _, j = cKDTree(Y).query(X[miss] @ Q.T, k=1)
                t[miss] = j
                conf[miss] = 0.0
        info.update({"Q": Q, "sigma": sigma, "n_confident": n_confident,
                     "posteriors": "P(source i | target j), columns sum <= 1"})
        return Correspondence(t, target.n_vertices, conf, P, info)

    def match(
        self,
        source: Shape,
        target: Shape,
        *,
        seeds: np.ndarray | None = None,
        source_spectrum: Spectrum | None = None,
        target_spectrum: Spectrum | None = None,
    ) -> Correspondence:
        """Dense map source -> target with sparse posteriors."""
        self._check()
        seeds = check_seeds(seeds, source.n_vertices, target.n_vertices)
        X, Y = self._embeddings(source, target, source_spectrum, target_spectrum)
        Q0 = self._initial_transform(X, Y, seeds, source, target)
        return self._finish(X, Y, Q0, target, {"n_seeds": 0 if seeds is None else len(seeds)})


@hookimpl
def toolkit_dense_matchers() -> dict[str, type]:
    return {"em-registration": EMRegistrationMatcher}
