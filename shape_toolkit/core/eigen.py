"""Smallest eigenpairs of sparse symmetric positive semi-definite (generalized) problems.

The problem class is a graph or mesh Laplacian ``A`` (symmetric PSD, singular on a connected
graph) with ``M`` either the identity or a positive diagonal (lumped) mass matrix. The default
sparse solver is a shift-invert **block Krylov-Schur** iteration: ``A - sigma M`` (with ``sigma``
slightly negative, so the matrix is SPD) is factored once by CHOLMOD (through ``cholespy``), the
operator ``M^1/2 (A - sigma M)^-1 M^1/2`` is applied to blocks of vectors (one multi-right-hand-side
solve per block), and the basis is orthogonalised with matrix-matrix products (BLAS 3) instead of
ARPACK's one-vector-at-a-time Gram-Schmidt; converged Ritz pairs are locked at a restart.
``benchmarks/configs/eigensolver.toml`` (``shape-toolkit bench run``, SciPy as ``peer = "scipy-eigsh"``)
measures it against the usual ``scipy.sparse.linalg.eigsh`` shift-invert approach.
"""

from __future__ import annotations

import contextlib
import functools
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
import scipy.linalg as la
import scipy.linalg.blas as blas
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from shape_toolkit.errors import ParameterError, SolverError

__all__ = ["DEFAULT_BLAS_THREADS", "METHODS", "EigenSolver", "fix_signs", "smallest_eigenpairs"]

#: Accepted values of ``method``.
METHODS = ("auto", "dense", "krylov", "arpack", "arpack-splu")

#: ``method="auto"`` uses the dense solver when ``n <= max(DENSE_MAX_N, DENSE_PER_K * k)`` (or ``3 k >= n``):
#: dense LAPACK costs ~n^3 whatever k, the block Krylov solver grows with k. Measured crossover (one BLAS
#: thread, CPU time, bumpy spheres n = 252 ... 1962, table in ``benchmarks/results/eigensolver_notes.md``;
#: re-measured by ``benchmarks/configs/eigensolver_crossover.toml``, ``results/eigensolver_crossover.md``).
DENSE_MAX_N = 400
DENSE_PER_K = 8

#: LAPACK driver of the dense solver for a diagonal M: bisection + inverse iteration on the wanted k only
#: (``evx``) measured 0-10% faster than MRRR (``evr``) at n = 492 ... 1212, k = 20 ... 100, and 2-3x faster
#: than divide and conquer (``evd``) on all n eigenpairs (same crossover run).
DENSE_DRIVER = "evx"

#: Largest problem the dense solver accepts (an ``n x n`` dense matrix is formed).
DENSE_LIMIT_N = 20000

#: The block Krylov solver's tightest residual tolerance (``tol=0`` means this).
KRYLOV_MIN_TOL = 1e-11

#: BLAS threads inside the sparse solvers when ``blas_threads`` is None. Their dense operations are
#: many small BLAS-3 calls (``n x basis`` times ``basis x block``) that a threaded BLAS splits badly:
#: measured in ``benchmarks/results/eigensolver_notes.md`` (``krylov-threaded`` against ``auto``), two
#: OpenBLAS threads cost 1.4x (200k vertices) to 48x (500) the CPU time of one on a shared 2-core machine
#: and never won in CPU or wall time; the dense path (n <= 500) lost 100x. So every method runs
#: single-threaded by default.
DEFAULT_BLAS_THREADS = 1

_Operator = Callable[[np.ndarray, np.ndarray], None]

# LAPACK called directly in the iteration: scipy.linalg's wrappers cost ~20-50 us per call in input
# validation, as much as the 8 x 8 Cholesky factor itself
_potrf = la.get_lapack_funcs("potrf", dtype=np.float64)
_syevd = la.get_lapack_funcs("syevd", dtype=np.float64)


_CONTROLLER: list = []  # the process's threadpoolctl controller, made on first use (a library scan)


def _env_threads() -> str | None:
    """The BLAS thread count the environment sets (OpenBLAS's own variable first), if any."""
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
        if os.environ.get(var):
            return os.environ[var].strip()
    return None


@contextlib.contextmanager
def _blas_limit(threads: int | None) -> Iterator[None]:
    """Cap the BLAS thread pools at ``threads`` inside the block (threadpoolctl), restoring them after.

    A no-op for None, without threadpoolctl, or when the environment already asks for ``threads``
    (the library scan behind the cap costs ~10 ms, as much as a whole small solve).
    """
    if threads is None or (os.cpu_count() or 1) <= int(threads) or _env_threads() == str(int(threads)):
        yield
        return
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:  # optional: without it the caller's thread count is used
        yield
        return
    if not _CONTROLLER:
        _CONTROLLER.append(ThreadpoolController())
    with _CONTROLLER[0].limit(limits=int(threads), user_api="blas"):
        yield


# -- input checks ------------------------------------------------------------------------------
def _as_square_sparse(X: object, name: str, n: int | None = None) -> sp.csr_matrix:
    if not (sp.issparse(X) or isinstance(X, np.ndarray)):
        raise ParameterError(f"{name} must be a scipy.sparse matrix or a numpy array")
    try:
        Xs = sp.csr_matrix(X, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name} must be a real matrix: {exc}") from exc
    if Xs.ndim != 2 or Xs.shape[0] != Xs.shape[1]:
        raise ParameterError(f"{name} must be square, got shape {Xs.shape}")
    if n is not None and Xs.shape[0] != n:
        raise ParameterError(f"{name} must be ({n}, {n}) like A, got {Xs.shape}")
    if not np.all(np.isfinite(Xs.data)):
        raise ParameterError(f"{name} has NaN or infinite entries")
    return Xs


def _check_symmetric(X: sp.csr_matrix, name: str) -> None:
    scale = float(np.abs(X.data).max()) if X.nnz else 0.0
    diff = X - X.T
    if diff.nnz and float(np.abs(diff.data).max()) > 1e-10 * scale:
        raise ParameterError(f"{name} must be symmetric")


def _diagonal_of(M: sp.csr_matrix) -> np.ndarray | None:
    """The diagonal of ``M`` if ``M`` is diagonal, else None."""
    coo = M.tocoo()
    off = (coo.row != coo.col) & (coo.data != 0)
    return None if off.any() else M.diagonal()


# -- linear solvers for A - sigma M ---------------------------------------------------------------
def _cholmod_solver(S: sp.csr_matrix) -> _Operator:
    """``solve(B, X)`` writing ``S^-1 B`` into ``X`` via CHOLMOD (cholespy); raises on failure."""
    from cholespy import CholeskySolverD, MatrixType

    n = S.shape[0]
    # CHOLMOD reads the lower triangle only: hand it that, in CSC (of a symmetric S, the CSC arrays of
    # tril(S) are the CSR arrays of triu(S)), sparing cholespy a transposition and half the copying
    U = sp.triu(S, format="csr")
    U.sort_indices()
    chol = CholeskySolverD(
        n,
        np.ascontiguousarray(U.indptr, dtype=np.int32),
        np.ascontiguousarray(U.indices, dtype=np.int32),
        np.ascontiguousarray(U.data, dtype=np.float64),
        MatrixType.CSC,
    )

    def solve(B: np.ndarray, X: np.ndarray) -> None:
        chol.solve(B, X)

    return solve


def _splu_solver(S: sp.csr_matrix) -> _Operator:
    """``solve(B, X)`` writing ``S^-1 B`` into ``X`` via SuperLU (scipy)."""
    try:
        lu = sla.splu(sp.csc_matrix(S))
    except RuntimeError as exc:  # exactly singular
        raise SolverError(f"A - sigma*M could not be factored: {exc}") from exc

    def solve(B: np.ndarray, X: np.ndarray) -> None:
        X[...] = lu.solve(B)

    return solve


class _NotPositiveDefinite(Exception):
    """CHOLMOD found a non-positive pivot."""


def _factor(S: sp.csr_matrix, backend: str) -> tuple[_Operator, str]:
    """Factor the SPD matrix ``S``; 'cholmod' falls back to 'splu' if cholespy is unusable.

    Raises :class:`_NotPositiveDefinite` when CHOLMOD reports that ``S`` is not positive definite.
    """
    if backend == "cholmod":
        try:
            return _cholmod_solver(S), "cholmod"
        except ValueError as exc:
            if "positive definite" in str(exc):
                raise _NotPositiveDefinite(str(exc)) from exc
        except Exception:  # noqa: BLE001 - missing wheel or a CHOLMOD failure: use SuperLU
            pass
    return _splu_solver(S), "splu"


# -- block Krylov-Schur for the largest eigenvalues of a symmetric operator ------------------------
def _right_solve_upper(W: np.ndarray, R: np.ndarray) -> None:
    """``W <- W R^-1`` in place for a Fortran-ordered ``W`` and upper triangular ``R``."""
    out = blas.dtrsm(1.0, R, W, side=1, lower=0, trans_a=0, diag=0, overwrite_b=1)
    if out is not W:  # not expected for a Fortran-ordered float64 W
        W[...] = out


def _orthonormalize_block(
    P: np.ndarray, W: np.ndarray, tmp: np.ndarray, rng: np.random.Generator, local: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Make ``W`` orthogonal to the orthonormal ``P`` and orthonormal itself, in place.

    Returns ``(h, R)`` with ``W_in = P h + W_out R``. Block classical Gram-Schmidt (BLAS 3), then
    Cholesky-QR twice; a rank-deficient block (an invariant subspace was found) falls back to
    Householder QR and random completion.

    Gram-Schmidt: a first pass against ``P[:, local:]``, then full passes against ``P`` until one removes
    less than 1 - 1/sqrt(2) of the norm of every column (the DGKS criterion; at most two). With
    ``local = 0`` this is classical Gram-Schmidt twice ("twice is enough"). In block Lanczos on a
    symmetric operator, ``op(q_j)`` is orthogonal in exact arithmetic to all but the last two blocks, so
    the caller passes ``local`` = the start of the previous block: the local pass does the real work and
    one full pass mops up the rounding, half the memory traffic of two full passes; should the operator
    be less symmetric than assumed, the criterion adds the second full pass.
    """
    if local:
        Pl = P[:, local:]
        h = np.zeros((P.shape[1], W.shape[1]))
        hl = Pl.T @ W
        np.matmul(Pl, hl, out=tmp)
        W -= tmp
        h[local:] = hl
        passes = 2
    else:
        h = P.T @ W
        np.matmul(P, h, out=tmp)
        W -= tmp
        passes = 1
    while passes:
        before = np.einsum("ij,ij->j", W, W)
        h2 = P.T @ W
        np.matmul(P, h2, out=tmp)
        W -= tmp
        h += h2
        passes -= 1
        if np.all(np.einsum("ij,ij->j", W, W) >= 0.5 * before):
            break
    b = W.shape[1]
    R = np.eye(b)
    for _ in range(2):
        Rc, bad = _potrf(W.T @ W, lower=0, clean=1, overwrite_a=1)
        if bad:
            break
        d = np.abs(np.diag(Rc))
        if not d.min() > 1e-6 * d.max():
            break
        _right_solve_upper(W, Rc)
        R = Rc @ R
    else:
        return h, R
    Qw, Rq = la.qr(W, mode="economic", check_finite=False)
    R = Rq @ R
    # columns of Qw that only carry rounding noise get random directions instead
    small = np.abs(np.diag(R)) <= 1e-12 * max(float(np.abs(R).max()), 1e-300)
    if small.any():
        Qw[:, small] = rng.standard_normal((W.shape[0], int(small.sum())))
    for _ in range(2):
        Qw -= P @ (P.T @ Qw)
        Qw, R2 = la.qr(Qw, mode="economic", check_finite=False)
        R = R2 @ R
    W[...] = Qw[:, :b]
    return h, R


def _next_check(j: int, k: int, b: int, m: int, n: int) -> int:
    """The basis size of the next Rayleigh-Ritz check (an ``evd`` of the projected matrix).

    A check costs ~``10 m^3`` flops, a block step ~``8 n m b`` (two Gram-Schmidt passes); checking every
    ``s`` blocks wastes ``s / 2`` block steps on average once converged and ``L / s`` checks per cycle of
    ``L`` blocks, so ``s = sqrt(2 L r)`` with ``r`` the cost ratio minimises the sum. At 2k vertices and
    k = 100 this is about once per cycle (the full basis, where the restart needs the eigh anyway); at
    50k+ vertices it is every block. The first check is at ``k + b`` at the earliest.
    """
    blocks = max(1, (m - j) // b)
    ratio = 1.25 * m * m / (n * b)
    step = max(1, int(np.ceil(np.sqrt(2.0 * blocks * ratio))))
    return min(max(k + b, j + step * b), m)


def _block_krylov_schur(
    op: _Operator,
    n: int,
    k: int,
    *,
    tol: float,
    block: int,
    max_basis: int,
    max_restarts: int,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """The ``k`` largest-magnitude eigenpairs of the symmetric operator ``op`` (``op(B, out)``).

    Thick-restarted block Lanczos with full reorthogonalisation (block Krylov-Schur) and locking: at a
    restart, wanted Ritz pairs that meet the tolerance are locked (kept in the basis, orthogonalised
    against, but no longer rotated or re-solved in the projected problem). A Ritz pair
    ``(theta, y)`` is accepted when ``||op(y) - theta y|| <= tol * |theta|``. Returns ``theta``
    by decreasing magnitude ``(k,)``, orthonormal Ritz vectors ``(n, k)`` and iteration statistics.
    """
    b, m = block, max_basis
    rng = np.random.default_rng(seed)
    Q = np.empty((n, m + b), order="F")  # orthonormal basis
    H = np.zeros((m + b, m))  # projected operator (upper part) and the coupling blocks
    Bin = np.empty((n, b))  # C-contiguous in/out buffers for the solver
    Bout = np.empty((n, b))
    tmp = np.empty((n, b), order="F")
    W = np.empty((n, b), order="F")
    Q[:, :b] = la.qr(rng.standard_normal((n, b)), mode="economic")[0]
    j, restarts, n_op = 0, 0, 0
    j_full = 0  # the block at j_full couples with the whole basis (the start, or the kept Ritz vectors)
    nl, theta_l = 0, np.zeros(0)  # locked (converged) Ritz vectors Q[:, :nl] and their values
    next_check = _next_check(0, k, b, m, n)  # Rayleigh-Ritz (an eigh of the j x j projection) only there
    while True:
        Bin[...] = Q[:, j : j + b]
        op(Bin, Bout)
        n_op += b
        W[...] = Bout
        h, R = _orthonormalize_block(Q[:, : j + b], W, tmp, rng, local=max(j - b, 0) if j > j_full else 0)
        H[: j + b, j : j + b] = h
        H[j + b : j + 2 * b, j : j + b] = R
        Q[:, j + b : j + 2 * b] = W
        j += b
        if j < next_check and j + b <= m:
            continue
        next_check = _next_check(j, k, b, m, n)
        # Rayleigh-Ritz on the active part only: the locked columns Q[:, :nl] are converged Ritz vectors,
        # decoupled from the rest (their couplings, at most tol |theta|, were dropped when they were locked)
        T = np.triu(H[nl:j, nl:j])
        T += np.triu(T, 1).T
        theta_a, S, bad = _syevd(T, compute_v=1, lower=0, overwrite_a=1)
        if bad:
            raise SolverError(f"LAPACK dsyevd failed on the projected problem (info={bad})")
        theta = np.concatenate([theta_l, theta_a])  # locked first, then active (index i >= nl: S[:, i - nl])
        order = np.argsort(-np.abs(theta), kind="stable")  # largest magnitude first
        want = order[:k]
        res = np.zeros(theta.size)
        res[nl:] = np.linalg.norm(R @ S[j - nl - b : j - nl], axis=0)
        ok = res[want] <= tol * np.abs(theta[want])
        if np.all(ok):
            Y = np.empty((n, k))
            lw, aw = want < nl, want >= nl
            Y[:, lw] = Q[:, want[lw]]
            Y[:, aw] = Q[:, nl:j] @ S[:, want[aw] - nl]
            return theta[want], Y, {"n_op": n_op, "restarts": restarts, "basis": j, "locked": nl}
        if j + b <= m:
            continue
        restarts += 1
        if restarts > max_restarts:
            worst = float(np.max(res[want] / np.abs(theta[want])))
            raise SolverError(
                f"block Krylov eigensolver did not converge in {max_restarts} restarts "
                f"(worst relative residual {worst:.1e} > tol {tol:.1e}); "
                "try a larger max_basis or a looser tol"
            )
        # thick restart (Krylov-Schur): keep p Ritz vectors and the last block. Wanted active pairs that have
        # converged are locked: rotated once more, then left in place and out of every later Rayleigh-Ritz
        # and rotation (their coupling to the basis, <= tol |theta|, is dropped: a perturbation within the
        # accuracy asked). The rest of the p, the best active ones, keep their coupling to the last block.
        p = min(j - b, max(k + b, (k + m) // 2))
        lock = want[ok & (want >= nl)] - nl  # active indices of the newly locked
        active = order[order >= nl] - nl
        rest = active[~np.isin(active, lock)][: p - nl - lock.size]
        keep = np.concatenate([lock, rest])
        p = nl + keep.size
        Sk = S[:, keep]
        W[...] = Q[:, j : j + b]
        step = max(1, (1 << 21) // max(j - nl, 1))  # row chunks: no (n, p) temporary
        for r0 in range(0, n, step):
            Q[r0 : r0 + step, nl:p] = Q[r0 : r0 + step, nl:j] @ Sk
        Q[:, p : p + b] = W
        nl_new = nl + lock.size
        C = R @ S[j - nl - b : j - nl, keep[lock.size :]]
        theta_l = np.concatenate([theta_l, theta_a[lock]])
        H[:] = 0.0
        H[np.arange(nl_new), np.arange(nl_new)] = theta_l
        H[np.arange(nl_new, p), np.arange(nl_new, p)] = theta_a[keep[lock.size :]]
        H[p : p + b, nl_new:p] = C
        H[nl_new:p, p : p + b] = C.T
        nl = nl_new
        j = j_full = p
        next_check = _next_check(p, k, b, m, n)


# -- the solvers ------------------------------------------------------------------------------------
def _basis_size(n: int, k: int, b: int, max_basis: int | None) -> int:
    """The block solver's basis size (columns) for ``k`` eigenpairs in blocks of ``b`` on ``n`` unknowns."""
    # a basis of at least 16 blocks: at k = 20 (5k vertices) 64 columns instead of 48 halve the restarts for
    # 5-15% less CPU time (5 meshes of 500-5k vertices, best of 7-9 interleaved runs; eigensolver_notes.md)
    m = int(max_basis) if max_basis is not None else max(2 * k + 2 * b, k + 6 * b, 16 * b)
    return min(m, n - b)


def _largest_cluster(vals: np.ndarray, rtol: float, atol: float) -> int:
    """The size of the largest group of equal values in ``vals`` ``(k,)``: neighbours (sorted) within
    ``rtol`` of their magnitude plus ``atol`` are one group."""
    v = np.sort(np.asarray(vals, dtype=np.float64))
    if v.size == 0:
        return 0
    close = np.diff(v) <= rtol * np.maximum(np.abs(v[1:]), np.abs(v[:-1])) + atol
    best = run = 1
    for c in close:
        run = run + 1 if c else 1
        best = max(best, run)
    return best


def _prefer_dense(n: int, k: int) -> bool:
    """Whether ``method="auto"`` solves an ``n x n`` problem for ``k`` eigenpairs with dense LAPACK."""
    return n <= max(DENSE_MAX_N, DENSE_PER_K * k) or 3 * k >= n


def _dense(
    A: sp.csr_matrix, k: int, M: sp.csr_matrix | None, dM: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """LAPACK on dense copies; a diagonal ``M`` (``dM``) is folded into a standard problem."""
    n = A.shape[0]
    if n > DENSE_LIMIT_N:
        raise ParameterError(
            f"method='dense' would form a {n} x {n} dense matrix (limit {DENSE_LIMIT_N})"
        )
    try:
        if dM is not None:
            s = 1.0 / np.sqrt(dM)
            B = A.toarray()
            B *= s[:, None]
            B *= s[None, :]
            vals, Y = la.eigh(B, subset_by_index=(0, k - 1), overwrite_a=True, driver=DENSE_DRIVER)
            return vals, Y * s[:, None]
        return la.eigh(A.toarray(), M.toarray(), subset_by_index=(0, k - 1))
    except la.LinAlgError as exc:
        raise SolverError(f"dense eigensolver failed: {exc}") from exc


def _arpack(
    A: sp.csr_matrix,
    k: int,
    M: sp.csr_matrix | None,
    sigma: float,
    solve: _Operator,
    tol: float,
    ncv: int | None,
) -> tuple[np.ndarray, np.ndarray]:
    n = A.shape[0]

    def matvec(x: np.ndarray) -> np.ndarray:
        out = np.empty(n)
        solve(np.ascontiguousarray(x, dtype=np.float64).ravel(), out)
        return out

    opinv = sla.LinearOperator((n, n), matvec=matvec, dtype=np.float64)
    v0 = np.random.default_rng(0).standard_normal(n)  # deterministic start vector
    try:
        vals, vecs = sla.eigsh(
            A, k=k, M=M, sigma=sigma, which="LM", OPinv=opinv, tol=tol, ncv=ncv, v0=v0
        )
    except (sla.ArpackNoConvergence, sla.ArpackError) as exc:
        raise SolverError(f"ARPACK did not converge: {exc}") from exc
    return vals, vecs


def _rayleigh_quotients(A: sp.csr_matrix, U: np.ndarray) -> np.ndarray:
    """``diag(U^T A U)``, ``(k,)``, computed by column blocks (no ``(n, k)`` temporary)."""
    k = U.shape[1]
    out = np.empty(k)
    for c in range(0, k, 16):
        blk = U[:, c : c + 16]
        out[c : c + 16] = np.einsum("ij,ij->j", blk, A @ blk)
    return out


def fix_signs(vectors: np.ndarray, *, copy: bool = True) -> np.ndarray:
    """The one sign rule: flip each column of ``(n, k)`` ``vectors`` so that its third moment is
    positive, falling back to its largest-magnitude entry when the moment vanishes (symmetric
    columns); invariant to vertex permutation and to sign flips."""
    U = np.array(vectors, dtype=np.float64, copy=True) if copy else vectors
    if U.size == 0:
        return U
    sq = U * U
    skew = np.einsum("ij,ij->j", sq, U)
    absu = np.abs(U)
    scale = np.einsum("ij,ij->j", sq, absu)  # sum |u|^3 (no pow: this is a hot path at 5k x 200)
    # argmax down the columns of a C-ordered (n, k) array strides through memory (0.6 s at 245k x 100): take
    # it on Fortran-ordered copies of 16 columns at a time (same first-maximum rule, bounded memory)
    arg = np.concatenate([np.argmax(np.asfortranarray(absu[:, c : c + 16]), axis=0)
                          for c in range(0, U.shape[1], 16)])  # fmt: skip
    peak = U[arg, np.arange(U.shape[1])]
    s = np.where(np.abs(skew) > 1e-8 * np.maximum(scale, 1e-300), np.sign(skew), np.sign(peak))
    s[s == 0] = 1.0
    U *= s
    return U


def smallest_eigenpairs(
    A: sp.spmatrix,
    k: int,
    M: sp.spmatrix | np.ndarray | None = None,
    *,
    tol: float = 1e-8,
    method: str = "auto",
    sigma: float | None = None,
    block_size: int | None = None,
    max_basis: int | None = None,
    max_restarts: int = 100,
    blas_threads: int | str | None = "auto",
    info: dict | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` smallest eigenpairs of ``A u = lambda M u`` (``M = I`` when None).

    ``A`` is a symmetric PSD ``(n, n)`` sparse matrix, ``M`` a symmetric positive definite
    (usually diagonal) ``(n, n)`` matrix or a positive ``(n,)`` vector of its diagonal. Returns
    eigenvalues ``(k,)`` ascending and eigenvectors ``(n, k)``, M-orthonormal
    (``U.T @ M @ U = I``), each signed by :func:`fix_signs` (positive third moment).
    Deterministic: the same call gives bit-identical results.

    ``method``:

    - ``"krylov"``: shift-invert block Krylov-Schur on a CHOLMOD factor of ``A - sigma M``
      (non-diagonal ``M``: ARPACK with that factor); the fastest for large sparse problems.
    - ``"arpack"``: ``scipy.sparse.linalg.eigsh`` shift-invert with the CHOLMOD factor (single-vector
      Lanczos: on very symmetric shapes it can miss a copy of a multiple eigenvalue at the cut).
    - ``"arpack-splu"``: ``eigsh`` shift-invert with SuperLU, what most peers do.
    - ``"dense"``: LAPACK on a dense copy (``n <= DENSE_LIMIT_N``).
    - ``"auto"``: ``"dense"`` for ``n <= max(DENSE_MAX_N, DENSE_PER_K * k)`` or ``3 k >= n`` (measured
      crossover), else ``"krylov"``, falling
      back to ``"arpack"`` if the block iteration does not converge (``info['fallback_from']``).

    CHOLMOD comes from the ``cholespy`` wheel; if it is missing or fails, SuperLU is used. ``tol``
    is the relative residual of the shift-inverted problem (ARPACK's meaning; 0 = as tight as the
    method can), which bounds the relative eigenvalue error; the eigenvalues returned by
    ``"krylov"`` are Rayleigh quotients, whose error is in practice about ``tol**2``.
    ``sigma`` (default ``-1e-8 * max(diag(A) / diag(M))``) must be negative. ``block_size``,
    ``max_basis`` and ``max_restarts`` tune ``"krylov"``; by default the block is 4 vectors up to k = 64,
    else 8, and doubles (a new solve) while a returned eigenvalue has as many copies as the block
    (``info['escalated_from']``), since a block of b vectors can miss copies beyond b.
    ``blas_threads`` caps the BLAS thread pools during the call (through ``threadpoolctl``, restored
    afterwards): ``"auto"`` uses
    :data:`DEFAULT_BLAS_THREADS`, an integer is used as is, None leaves the process's setting.
    ``info``, if given, is filled with what was done (method, factorization backend, operator
    applications, restarts, BLAS threads).

    Raises :class:`ParameterError` for a bad ``k`` or input (including an ``A`` found not to be
    PSD) and :class:`SolverError` when the iteration does not converge.
    """
    info = {} if info is None else info
    if method not in METHODS:
        raise ParameterError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    if not (blas_threads is None or blas_threads == "auto" or (
        isinstance(blas_threads, (int, np.integer)) and not isinstance(blas_threads, bool) and blas_threads >= 1
    )):
        raise ParameterError(f"blas_threads must be 'auto', None or a positive integer, got {blas_threads!r}")
    threads = DEFAULT_BLAS_THREADS if blas_threads == "auto" else blas_threads
    info["blas_threads"] = threads
    with _blas_limit(threads):  # type: ignore[arg-type]
        A, k, Ms, dM = _checked_problem(A, k, M, tol)
        solve = functools.partial(_solve_checked, A, k, Ms, dM, tol=tol, sigma=sigma, block_size=block_size,
                                  max_basis=max_basis, max_restarts=max_restarts, info=info)
        if method == "auto":
            if _prefer_dense(A.shape[0], k):
                method = "dense"
            else:
                # the block solver is the fast path; single-vector ARPACK is the safety net
                try:
                    return solve(method="krylov")
                except SolverError as exc:
                    info.clear()
                    info.update(blas_threads=threads, fallback_from=f"krylov: {exc}")
                    return solve(method="arpack")
        return solve(method=method)


@dataclass(frozen=True)
class EigenSolver:
    """:func:`smallest_eigenpairs` with its choices fixed, as an object to inject
    (``compute_spectrum(graph, k, solver=EigenSolver(method="arpack"))``); called as ``solver(A, k, M)``
    it returns eigenvalues ``(k,)`` ascending and M-orthonormal eigenvectors ``(n, k)``."""

    method: str = "auto"
    tol: float = 1e-8
    blas_threads: int | str | None = "auto"

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ParameterError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")

    def __call__(
        self, A: sp.spmatrix, k: int, M: sp.spmatrix | np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` smallest eigenpairs of ``A u = lambda M u``."""
        return smallest_eigenpairs(A, k, M, method=self.method, tol=self.tol, blas_threads=self.blas_threads)


def _checked_problem(
    A: sp.spmatrix, k: int, M: sp.spmatrix | np.ndarray | None, tol: float
) -> tuple[sp.csr_matrix, int, sp.csr_matrix | None, np.ndarray | None]:
    """``(A, k, Ms, dM)``: the input of :func:`smallest_eigenpairs` checked, ``A`` and ``M`` as CSR ``(n, n)``
    (``Ms`` None without ``M``), ``dM`` the diagonal ``(n,)`` of the mass when it is diagonal (ones without
    ``M``), else None."""
    A = _as_square_sparse(A, "A")
    n = A.shape[0]
    if isinstance(k, (bool, np.bool_)) or not isinstance(k, (int, np.integer)):
        raise ParameterError(f"k must be an integer, got {k!r}")
    k = int(k)
    if not 1 <= k <= n:
        raise ParameterError(f"k must be in [1, {n}], got {k}")
    if not (isinstance(tol, (int, float)) and 0 <= tol < 1):
        raise ParameterError(f"tol must be a number in [0, 1), got {tol!r}")
    _check_symmetric(A, "A")

    Ms: sp.csr_matrix | None = None
    if M is not None:
        if isinstance(M, np.ndarray) and M.ndim == 1:
            if M.shape != (n,):
                raise ParameterError(f"a diagonal M must have shape ({n},), got {M.shape}")
            if not np.all(np.isfinite(M)):
                raise ParameterError("M has NaN or infinite entries")
            Ms = sp.diags(M.astype(np.float64)).tocsr()
        else:
            Ms = _as_square_sparse(M, "M", n)
            _check_symmetric(Ms, "M")
        if not np.all(Ms.diagonal() > 0):
            raise ParameterError("M must be positive definite (its diagonal must be > 0)")
    if Ms is None:
        dM = np.ones(n)
    elif isinstance(M, np.ndarray) and M.ndim == 1:
        dM = Ms.diagonal()  # given as its diagonal: no need to look for off-diagonal entries
    else:
        dM = _diagonal_of(Ms)
    return A, k, Ms, dM


def _solve_checked(
    A: sp.csr_matrix,
    k: int,
    Ms: sp.csr_matrix | None,
    dM: np.ndarray | None,
    *,
    tol: float,
    method: str,
    sigma: float | None,
    block_size: int | None,
    max_basis: int | None,
    max_restarts: int,
    info: dict,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`smallest_eigenpairs` by one ``method`` on validated input (``dM``: the diagonal of ``Ms``
    when ``Ms`` is diagonal, else None)."""
    n = A.shape[0]
    info["method"] = method
    if method == "dense":
        vals, vecs = _dense(A, k, Ms, dM)
        return vals, fix_signs(vecs, copy=False)

    # block 4 up to k = 64 (at 5k vertices, k = 50: 10% less CPU than block 8; at 2k / k = 20: 20% less), else
    # 8. A block Krylov method finds at most b copies of a repeated eigenvalue in exact arithmetic, so when
    # b copies (or more) of one eigenvalue come back, more may have been missed (block 4 once returned 4 of
    # a round sphere's 5-fold l = 2 cluster): the default block then doubles until every cluster found is
    # smaller than the block (_escalate_block). Shapes without exact symmetry never pay for this.
    b = int(block_size) if block_size is not None else (4 if k <= 64 else 8)
    if b < 1:
        raise ParameterError(f"block_size must be >= 1, got {block_size}")
    m = _basis_size(n, k, b, max_basis)
    if m < k + 2 * b:
        raise ParameterError(
            f"k={k} is too close to n={n} for a sparse solver: use method='dense'"
        )

    dvals = A.diagonal()
    scale = float(np.max(dvals / (dM if dM is not None else Ms.diagonal())))
    Mop = Ms if Ms is not None else sp.identity(n, format="csr")
    user_sigma = sigma is not None
    if sigma is None:
        sigma = -1e-8 * scale if scale > 0 else -1.0
    if not sigma < 0:
        raise ParameterError(f"sigma must be negative (A - sigma*M must be SPD), got {sigma}")
    backend = "splu" if method == "arpack-splu" else "cholmod"
    for attempt in range(2):
        try:
            solve, backend = _factor(sp.csr_matrix(A - sigma * Mop), backend)
            break
        except _NotPositiveDefinite as exc:
            if user_sigma or attempt:
                raise ParameterError(
                    f"A - sigma*M (sigma={sigma:.3e}) is not positive definite: "
                    "A must be symmetric positive semi-definite"
                ) from exc
            sigma *= 100.0  # rounding at a tiny shift: retry once with a larger one
    info.update(backend=backend, sigma=sigma)

    if method in ("arpack", "arpack-splu") or dM is None:
        info["method"] = "arpack" if method == "krylov" else method
        vals, vecs = _arpack(A, k, Ms, sigma, solve, tol, None)
        order = np.argsort(vals)
        vals, vecs = vals[order], vecs[:, order]
    else:
        sq = np.sqrt(dM)
        sqc = sq[:, None]

        def op(B: np.ndarray, X: np.ndarray) -> None:
            B *= sqc
            solve(B, X)
            X *= sqc

        while True:
            theta, Y, stats = _block_krylov_schur(
                op, n, k, tol=max(tol, KRYLOV_MIN_TOL), block=b, max_basis=m, max_restarts=max_restarts
            )
            info.update(stats, block_size=b, max_basis=m)
            if block_size is not None:
                break
            # equal within the solver's tolerance; the absolute part only joins repeated null eigenvalues
            # (their Ritz values are off by <= tol |sigma|): |sigma| itself would join distinct eigenvalues
            # of a fine mesh (at 1M vertices |sigma| exceeds the gaps between the first 100)
            rtol = max(tol, KRYLOV_MIN_TOL)
            cluster = _largest_cluster(sigma + 1.0 / theta, rtol, 100.0 * rtol * abs(sigma))
            b2 = 2 * b
            m2 = _basis_size(n, k, b2, max_basis)
            if cluster < b or m2 < k + 2 * b2:
                break
            info.setdefault("escalated_from", []).append({"block_size": b, "cluster": cluster,
                                                          "n_op": stats["n_op"]})  # fmt: skip
            b, m = b2, m2
        vecs = Y
        vecs /= sqc  # in place: the (n, k) blocks are the memory peak after the basis
        lam_theta = sigma + 1.0 / theta
        vals = _rayleigh_quotients(A, vecs)
        # the Rayleigh quotient and the Ritz value must agree: else the solves were inaccurate
        bad = np.abs(vals - lam_theta) > 1e-3 * (np.abs(lam_theta) + abs(sigma))
        if bad.any():
            raise SolverError(
                "eigensolver lost accuracy (Ritz values and Rayleigh quotients disagree); "
                "is A symmetric positive semi-definite?"
            )
        order = np.argsort(vals, kind="stable")
        if np.any(order != np.arange(k)):
            vals, vecs = vals[order], vecs[:, order]
    if vals[0] < sigma:
        raise ParameterError(
            f"A is not positive semi-definite (found eigenvalue {vals[0]:.3e} < sigma={sigma:.3e})"
        )
    return vals, fix_signs(vecs, copy=False)
