"""Smallest eigenpairs of sparse symmetric positive semi-definite (generalized) problems."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from .errors import ParameterError, SolverError

__all__ = ["smallest_eigenpairs"]


def smallest_eigenpairs(
    A: sp.spmatrix,
    k: int,
    M: sp.spmatrix | None = None,
    *,
    tol: float = 1e-10,
    method: str = "auto",
) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` smallest eigenpairs of ``A u = lambda M u`` (``M = I`` when None).

    ``A`` is a symmetric PSD ``(n, n)`` sparse matrix, ``M`` a symmetric positive definite
    (usually diagonal) ``(n, n)`` matrix. Returns eigenvalues ``(k,)`` ascending and
    eigenvectors ``(n, k)``, M-orthonormal.
    """
    n = A.shape[0]
    if not 1 <= k <= n:
        raise ParameterError(f"k must be in [1, {n}], got {k}")
    A = sp.csc_matrix(A, dtype=np.float64)
    if n <= 300 or k >= n - 1:
        import scipy.linalg as la

        vals, vecs = la.eigh(A.toarray(), None if M is None else M.toarray())
        return vals[:k], vecs[:, :k]
    sigma = -1e-8 * max(abs(A.diagonal()).max(), 1e-300)
    try:
        vals, vecs = sla.eigsh(A, k=k, M=M, sigma=sigma, which="LM", tol=tol)
    except (sla.ArpackNoConvergence, RuntimeError) as exc:
        raise SolverError(f"eigensolver did not converge: {exc}") from exc
    order = np.argsort(vals)
    return vals[order], vecs[:, order]
