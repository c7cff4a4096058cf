"""shape_toolkit.core.eigen.smallest_eigenpairs: analytic spectra, dense agreement, every method, errors."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as la
import scipy.sparse as sp

from shape_toolkit.core.eigen import METHODS, smallest_eigenpairs
from shape_toolkit.errors import ParameterError, SolverError

SPARSE_METHODS = [m for m in METHODS if m not in ("auto", "dense")]


def path_laplacian(n: int) -> sp.csr_matrix:
    """Combinatorial Laplacian of the path graph on ``n`` vertices."""
    e = np.ones(n - 1)
    A = sp.diags([-e, np.r_[1.0, 2.0 * np.ones(n - 2), 1.0], -e], [-1, 0, 1])
    return sp.csr_matrix(A)


def grid_laplacian(nx: int, ny: int) -> sp.csr_matrix:
    """Laplacian of the ``nx x ny`` grid graph (Kronecker sum of two paths)."""
    return sp.csr_matrix(
        sp.kron(path_laplacian(nx), sp.identity(ny)) + sp.kron(sp.identity(nx), path_laplacian(ny))
    )


def grid_eigenvalues(nx: int, ny: int, k: int) -> np.ndarray:
    """The ``k`` smallest eigenvalues of :func:`grid_laplacian`, analytically."""
    px = 2.0 - 2.0 * np.cos(np.pi * np.arange(nx) / nx)
    py = 2.0 - 2.0 * np.cos(np.pi * np.arange(ny) / ny)
    return np.sort((px[:, None] + py[None, :]).ravel())[:k]


@pytest.fixture(scope="module")
def grid():
    nx, ny = 47, 43  # n = 2021: the sparse path; distinct sizes keep the spectrum mostly simple
    return nx, ny, grid_laplacian(nx, ny)


@pytest.fixture(scope="module")
def generalized():
    """A 24 x 25 grid Laplacian with a random positive diagonal mass, and its dense solution."""
    A = grid_laplacian(24, 25)
    d = np.random.default_rng(1).uniform(0.5, 2.0, A.shape[0])
    s = 1 / np.sqrt(d)  # D^-1/2 A D^-1/2 y = lambda y, u = D^-1/2 y
    vals, y = la.eigh(A.toarray() * s[:, None] * s[None, :], subset_by_index=(0, 29))
    vecs = y * s[:, None]
    return A, d, vals, vecs


def subspace_cosines(U: np.ndarray, V: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Cosines of the principal angles between two M-orthonormal bases (M = diag(d))."""
    return la.svdvals(U.T @ (d[:, None] * V))


@pytest.mark.parametrize("method", ["auto", *SPARSE_METHODS])
def test_standard_grid_matches_analytic_spectrum(grid, method):
    nx, ny, A = grid
    k = 15
    vals, vecs = smallest_eigenpairs(A, k, method=method)
    ref = grid_eigenvalues(nx, ny, k)
    np.testing.assert_allclose(vals, ref, rtol=1e-9, atol=1e-12)
    assert vecs.shape == (A.shape[0], k)
    np.testing.assert_allclose(vecs.T @ vecs, np.eye(k), atol=1e-10)
    # each returned pair really is an eigenpair
    res = np.linalg.norm(A @ vecs - vecs * vals, axis=0)
    assert res.max() < 1e-6


@pytest.mark.parametrize("method", list(METHODS))
def test_generalized_matches_dense(generalized, method):
    A, d, ref_vals, ref_vecs = generalized
    k = 12
    vals, vecs = smallest_eigenpairs(A, k, sp.diags(d), method=method)
    np.testing.assert_allclose(vals[1:], ref_vals[1:k], rtol=1e-9)
    assert abs(vals[0]) < 1e-10
    # M-orthonormal, ascending
    np.testing.assert_allclose(vecs.T @ (d[:, None] * vecs), np.eye(k), atol=1e-10)
    assert np.all(np.diff(vals) >= 0)
    # same invariant subspace as LAPACK (the random mass makes the eigenvalues simple)
    np.testing.assert_allclose(subspace_cosines(vecs, ref_vecs[:, :k], d), 1.0, atol=1e-8)
    # and the same vectors up to sign, one by one
    cos = np.abs(np.einsum("ij,ij->j", vecs, d[:, None] * ref_vecs[:, :k]))
    np.testing.assert_allclose(cos, 1.0, atol=1e-7)


def test_methods_agree_with_each_other(generalized):
    A, d, _, _ = generalized
    k = 20
    out = {m: smallest_eigenpairs(A, k, d, method=m) for m in METHODS}
    v0, u0 = out["dense"]
    for m, (v, u) in out.items():
        np.testing.assert_allclose(v, v0, rtol=1e-8, atol=1e-10, err_msg=m)
        # vectors agree including sign (largest-magnitude entry positive)
        np.testing.assert_allclose(u, u0, atol=1e-6, err_msg=m)


def test_null_eigenvector_is_constant_on_connected_graph(grid):
    _, _, A = grid
    vals, vecs = smallest_eigenpairs(A, 4, method="krylov")
    assert abs(vals[0]) < 1e-12
    assert vals[1] > 1e-4
    u = vecs[:, 0]
    np.testing.assert_allclose(u, np.full_like(u, 1.0 / np.sqrt(len(u))), atol=1e-10)


def test_two_null_eigenvalues_on_two_components():
    A = sp.block_diag([grid_laplacian(20, 25), grid_laplacian(22, 21)]).tocsr()
    vals, vecs = smallest_eigenpairs(A, 5, method="krylov")
    np.testing.assert_allclose(vals[:2], 0.0, atol=1e-12)
    assert vals[2] > 1e-4
    # the null space is spanned by the two component indicators
    ind = np.zeros((A.shape[0], 2))
    ind[:500, 0] = 1 / np.sqrt(500)
    ind[500:, 1] = 1 / np.sqrt(462)
    np.testing.assert_allclose(la.svdvals(ind.T @ vecs[:, :2]), 1.0, atol=1e-10)


def test_deterministic(generalized):
    A, d, _, _ = generalized
    for method in ("auto", "krylov", "arpack"):
        v1, u1 = smallest_eigenpairs(A, 10, d, method=method)
        v2, u2 = smallest_eigenpairs(A, 10, d, method=method)
        assert np.array_equal(v1, v2) and np.array_equal(u1, u2), method


def test_diagonal_vector_equals_diagonal_matrix(generalized):
    A, d, _, _ = generalized
    v1, u1 = smallest_eigenpairs(A, 8, d)
    v2, u2 = smallest_eigenpairs(A, 8, sp.diags(d))
    np.testing.assert_array_equal(v1, v2)
    np.testing.assert_array_equal(u1, u2)


def test_non_diagonal_mass_matrix():
    n = 400
    A = path_laplacian(n)
    # consistent (tridiagonal) P1 mass of a uniform path: SPD, not diagonal
    M = sp.csr_matrix(sp.diags([np.ones(n - 1), 4 * np.ones(n), np.ones(n - 1)], [-1, 0, 1]) / 6)
    ref = la.eigh(A.toarray(), M.toarray(), eigvals_only=True)[:6]
    info: dict = {}
    vals, vecs = smallest_eigenpairs(A, 6, M, method="krylov", info=info)
    assert info["method"] == "arpack"  # the block solver needs a diagonal M
    np.testing.assert_allclose(vals[1:], ref[1:], rtol=1e-9)
    np.testing.assert_allclose(vecs.T @ (M @ vecs), np.eye(6), atol=1e-10)


def test_small_and_k_close_to_n_use_dense():
    A = grid_laplacian(23, 24)  # n = 552
    info: dict = {}
    vals, vecs = smallest_eigenpairs(A, 500, info=info)
    assert info["method"] == "dense"
    np.testing.assert_allclose(vals, grid_eigenvalues(23, 24, 500), atol=1e-10)
    np.testing.assert_allclose(vecs.T @ vecs, np.eye(500), atol=1e-10)
    info = {}
    vals, _ = smallest_eigenpairs(path_laplacian(50), 50, info=info)
    assert info["method"] == "dense"
    np.testing.assert_allclose(vals, 2 - 2 * np.cos(np.pi * np.arange(50) / 50), atol=1e-12)
    with pytest.raises(ParameterError, match="too close"):
        smallest_eigenpairs(A, 545, method="krylov")


def test_auto_uses_block_krylov_on_cholmod(grid):
    _, _, A = grid
    info: dict = {}
    smallest_eigenpairs(A, 10, info=info)
    assert info["method"] == "krylov"
    assert info["backend"] in ("cholmod", "splu")


def test_splu_fallback_when_cholmod_unavailable(grid, monkeypatch):
    import shape_toolkit.core.eigen as eigen

    def broken(_S):
        raise ImportError("no cholespy")

    monkeypatch.setattr(eigen, "_cholmod_solver", broken)
    nx, ny, A = grid
    info: dict = {}
    vals, _ = smallest_eigenpairs(A, 6, info=info)
    assert info["backend"] == "splu"
    np.testing.assert_allclose(vals, grid_eigenvalues(nx, ny, 6), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("k", [0, -1, 2022, 2.5, True, "3", None])
def test_bad_k_raises(grid, k):
    _, _, A = grid
    with pytest.raises(ParameterError):
        smallest_eigenpairs(A, k)


def test_bad_inputs_raise(grid):
    _, _, A = grid
    n = A.shape[0]
    with pytest.raises(ParameterError, match="method"):
        smallest_eigenpairs(A, 3, method="magic")
    with pytest.raises(ParameterError, match="square"):
        smallest_eigenpairs(A[:, :-1], 3)
    with pytest.raises(ParameterError, match="symmetric"):
        smallest_eigenpairs(A + sp.csr_matrix(([1.0], ([0], [5])), shape=A.shape), 3)
    with pytest.raises(ParameterError, match="positive definite"):
        smallest_eigenpairs(A, 3, -np.ones(n))
    with pytest.raises(ParameterError, match="shape"):
        smallest_eigenpairs(A, 3, np.ones(n + 1))
    with pytest.raises(ParameterError, match="sigma"):
        smallest_eigenpairs(A, 3, sigma=0.0)
    bad = A.copy().astype(float)
    bad.data[0] = np.nan
    with pytest.raises(ParameterError, match="NaN"):
        smallest_eigenpairs(bad, 3)


@pytest.mark.parametrize("method", ["auto", "krylov", "arpack"])
def test_indefinite_matrix_is_refused(grid, method):
    _, _, A = grid
    shifted = sp.csr_matrix(A - 0.5 * sp.identity(A.shape[0]))
    with pytest.raises(ParameterError, match="positive"):
        smallest_eigenpairs(shifted, 5, method=method)


def test_non_convergence_raises_solver_error(grid):
    _, _, A = grid
    with pytest.raises(SolverError, match="converge"):
        smallest_eigenpairs(A, 20, method="krylov", max_basis=28, block_size=4, max_restarts=1)


def test_auto_falls_back_to_arpack_when_the_block_iteration_stalls(grid):
    _, _, A = grid
    info: dict = {}
    vals, _ = smallest_eigenpairs(A, 20, max_basis=28, block_size=4, max_restarts=1, info=info)
    assert "krylov" in info["fallback_from"] and info["method"] == "arpack"
    ref, _ = smallest_eigenpairs(A, 20, method="dense")
    np.testing.assert_allclose(vals, ref, rtol=1e-7, atol=1e-10)


def test_highly_symmetric_graph_with_clusters_cut_at_k():
    """Icosphere graph: eigenvalue multiplicities 3-5, and k = 20 cuts a 5-fold cluster.

    The block solver must find every copy; single-vector ARPACK ("arpack", "arpack-splu") is known
    to miss copies of a multiple eigenvalue at the cut, so it is not asked to here.
    """
    from shape_toolkit.data.generate import icosphere

    e = icosphere(3).edges  # 642 vertices
    n = int(e.max()) + 1
    W = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    W = sp.csr_matrix(W + W.T)
    A = sp.csr_matrix(sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W)
    ref = la.eigh(A.toarray(), eigvals_only=True)
    assert ref[20] - ref[19] < 1e-9  # the cut really goes through a cluster
    for method in ("auto", "krylov"):
        vals, vecs = smallest_eigenpairs(A, 20, method=method)
        np.testing.assert_allclose(vals, ref[:20], atol=1e-9, err_msg=method)
        np.testing.assert_allclose(vecs.T @ vecs, np.eye(20), atol=1e-10, err_msg=method)
        res = np.linalg.norm(A @ vecs - vecs * vals, axis=0)
        assert res.max() < 1e-6, method


# -- the round sphere: analytic eigenvalues l(l+1) with multiplicity 2l+1 ------------------------------
def sphere_cotangent(subdivisions: int) -> tuple[sp.csr_matrix, np.ndarray]:
    """Cotangent Laplacian and barycentric lumped mass of the unit icosphere (computed here)."""
    from shape_toolkit.data.generate import icosphere

    shape = icosphere(subdivisions)
    V, F = np.asarray(shape.vertices, dtype=float), np.asarray(shape.faces)
    n = len(V)
    rows, cols, vals = [], [], []
    for a, b, c in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):  # the angle at c weighs the edge (a, b)
        u, w = V[F[:, a]] - V[F[:, c]], V[F[:, b]] - V[F[:, c]]
        cot = np.einsum("ij,ij->i", u, w) / np.linalg.norm(np.cross(u, w), axis=1)
        rows += [F[:, a], F[:, b]]
        cols += [F[:, b], F[:, a]]
        vals += [0.5 * cot, 0.5 * cot]
    W = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    A = sp.csr_matrix(sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W)
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    mass = np.bincount(F.ravel(), weights=np.repeat(area / 3, 3), minlength=n)
    return A, mass


@pytest.fixture(scope="module")
def sphere():
    A, mass = sphere_cotangent(4)  # 2562 vertices: the sparse path
    s = 1 / np.sqrt(mass)
    ref = la.eigh(A.toarray() * s[:, None] * s[None, :], eigvals_only=True, subset_by_index=(0, 24))
    return A, mass, ref


@pytest.mark.parametrize("method", list(METHODS))
def test_round_sphere_analytic_eigenvalues_and_multiplicities(sphere, method):
    """l(l+1) with multiplicity 2l+1 (l = 0, 1, 2): every copy of each cluster is found."""
    A, mass, ref = sphere
    k = 9  # 1 + 3 + 5: the cut falls after the l = 2 cluster
    vals, vecs = smallest_eigenpairs(A, k, mass, method=method)
    if method.startswith("arpack"):
        # single-vector Lanczos (documented): may return a later eigenvalue instead of a copy, but
        # what it returns are eigenvalues, to 1e-10
        gap = np.min(np.abs(vals[1:, None] - ref[None, 1:]) / ref[None, 1:], axis=1)
        assert gap.max() <= 1e-10 and abs(vals[0]) < 1e-9
        return
    analytic = np.repeat([0.0, 2.0, 6.0], [1, 3, 5])
    np.testing.assert_allclose(vals, analytic, rtol=5e-3, atol=1e-9)  # discretisation error only
    np.testing.assert_allclose(vals[1:], ref[1:k], rtol=1e-10)  # the solver itself: to 1e-10
    for lo, hi in ((1, 4), (4, 9)):  # exactly degenerate by the icosahedral symmetry
        assert np.ptp(vals[lo:hi]) <= 1e-9 * vals[lo]
    np.testing.assert_allclose(vecs.T @ (mass[:, None] * vecs), np.eye(k), atol=1e-10)


@pytest.mark.parametrize("method", ["auto", "krylov", "dense"])
def test_round_sphere_cut_inside_a_cluster(sphere, method):
    """k = 6 cuts the 5-fold l = 2 cluster after two copies: the block solver returns two of them."""
    A, mass, ref = sphere
    vals, vecs = smallest_eigenpairs(A, 6, mass, method=method)
    np.testing.assert_allclose(vals[1:], ref[1:6], rtol=1e-10)
    np.testing.assert_allclose(vals[4:], 6.0, rtol=5e-3)
    res = np.linalg.norm(A @ vecs - (mass[:, None] * vecs) * vals, axis=0)
    assert res.max() < 1e-6


# -- BLAS thread cap -----------------------------------------------------------------------------------
def _blas_threads_now() -> list[int]:
    from threadpoolctl import threadpool_info

    return [d["num_threads"] for d in threadpool_info() if d.get("user_api") == "blas"]


@pytest.mark.parametrize("threads", [1, 2, None, "auto"])
def test_blas_threads_setting_keeps_accuracy_and_restores_pools(sphere, threads, monkeypatch):
    pytest.importorskip("threadpoolctl")
    import shape_toolkit.core.eigen as eigen

    A, mass, ref = sphere
    before = _blas_threads_now()
    seen: list[list[int]] = []
    real = eigen._cholmod_solver

    def spying(S):
        seen.append(_blas_threads_now())
        return real(S)

    monkeypatch.setattr(eigen, "_cholmod_solver", spying)
    info: dict = {}
    vals, _ = smallest_eigenpairs(A, 20, mass, blas_threads=threads, info=info)
    np.testing.assert_allclose(vals[1:], ref[1:20], rtol=1e-10)
    assert info["method"] == "krylov"
    expected = eigen.DEFAULT_BLAS_THREADS if threads == "auto" else threads
    assert info["blas_threads"] == expected
    if expected is not None and seen and seen[0]:
        assert max(seen[0]) <= max(expected, min(before))  # capped inside the solver
    assert _blas_threads_now() == before  # and restored afterwards


def test_capped_and_uncapped_agree(generalized):
    A, d, _, _ = generalized
    v1, u1 = smallest_eigenpairs(A, 12, d, blas_threads=1)
    v2, u2 = smallest_eigenpairs(A, 12, d, blas_threads=None)
    np.testing.assert_allclose(v1, v2, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(u1, u2, atol=1e-7)


@pytest.mark.parametrize("bad", [0, -1, "two", True, 1.5])
def test_bad_blas_threads_raise(grid, bad):
    _, _, A = grid
    with pytest.raises(ParameterError, match="blas_threads"):
        smallest_eigenpairs(A, 3, blas_threads=bad)


# -- the method chosen by size: both sides of every crossover --------------------------------------------
def _grid_case(nx: int, ny: int, k: int, seed: int = 3):
    """A grid Laplacian with a random diagonal mass (simple eigenvalues) and its dense reference."""
    A = grid_laplacian(nx, ny)
    d = np.random.default_rng(seed).uniform(0.5, 2.0, A.shape[0])
    s = 1 / np.sqrt(d)
    vals, y = la.eigh(A.toarray() * s[:, None] * s[None, :], subset_by_index=(0, k - 1))
    return A, d, vals, y * s[:, None]


@pytest.mark.parametrize(
    "nx, ny, k, expected",
    [
        (18, 22, 10, "dense"),  # n = 396 <= DENSE_MAX_N = 400
        (17, 24, 10, "krylov"),  # n = 408
        (14, 34, 60, "dense"),  # n = 476 <= DENSE_PER_K * k = 480
        (18, 27, 60, "krylov"),  # n = 486
        (20, 22, 150, "dense"),  # n = 440 <= 3 k
    ],
)
def test_auto_choice_on_both_sides_of_the_crossover_matches_dense_reference(nx, ny, k, expected):
    """auto's method at each side of DENSE_MAX_N / DENSE_PER_K: the choice, and 1e-10 accuracy with it."""
    import shape_toolkit.core.eigen as eigen

    A, d, ref, ref_vecs = _grid_case(nx, ny, k)
    n = A.shape[0]
    assert eigen._prefer_dense(n, k) == (expected == "dense")
    info: dict = {}
    vals, vecs = smallest_eigenpairs(A, k, d, info=info)
    assert info["method"] == expected
    # both methods forced, on the same problem: the same answer to 1e-10
    for method in ("dense", "krylov") if 3 * k < n - 8 else ("dense",):
        v, u = smallest_eigenpairs(A, k, d, method=method)
        np.testing.assert_allclose(v[1:], ref[1:], rtol=1e-10, err_msg=method)
        assert abs(v[0]) <= 1e-10 * ref[1]
        np.testing.assert_allclose(u.T @ (d[:, None] * u), np.eye(k), atol=1e-10, err_msg=method)
        cos = np.abs(np.einsum("ij,ij->j", u, d[:, None] * ref_vecs))
        np.testing.assert_allclose(cos[1:], 1.0, atol=1e-7, err_msg=method)
    np.testing.assert_allclose(vals[1:], ref[1:], rtol=1e-10)


def test_crossover_rule_is_monotone_in_n():
    """Dense below the crossover, the block solver above it, for every k (no islands)."""
    import shape_toolkit.core.eigen as eigen

    for k in (1, 5, 20, 50, 64, 100, 200):
        picks = [eigen._prefer_dense(n, k) for n in range(k, 4000, 7)]
        switch = picks.index(False)
        assert all(picks[:switch]) and not any(picks[switch:]), k
        n_cross = range(k, 4000, 7)[switch]
        assert n_cross > max(eigen.DENSE_MAX_N, eigen.DENSE_PER_K * k, 3 * k) - 7


@pytest.mark.parametrize("method", ["dense", "krylov"])
def test_round_sphere_small_mesh_every_size_path(method):
    """642-vertex round icosphere, cotangent + lumped mass: l(l+1) clusters, 1e-10 against LAPACK."""
    A, mass = sphere_cotangent(3)
    s = 1 / np.sqrt(mass)
    ref = la.eigh(A.toarray() * s[:, None] * s[None, :], eigvals_only=True, subset_by_index=(0, 15))
    vals, vecs = smallest_eigenpairs(A, 16, mass, method=method)  # 1 + 3 + 5 + 7: cut after l = 3
    np.testing.assert_allclose(vals[1:], ref[1:16], rtol=1e-10)
    np.testing.assert_allclose(vals[:9], np.repeat([0.0, 2.0, 6.0], [1, 3, 5]), rtol=2e-2, atol=1e-9)
    np.testing.assert_allclose(vecs.T @ (mass[:, None] * vecs), np.eye(16), atol=1e-10)


@pytest.mark.parametrize("method", ["auto", "dense", "krylov"])
def test_deterministic_and_sign_invariant_under_vertex_permutation(method):
    """Same input, same bits; a permuted problem gives the permuted vectors, signs included."""
    A, d, _, _ = _grid_case(21, 23, 12, seed=5)
    v1, u1 = smallest_eigenpairs(A, 12, d, method=method)
    v2, u2 = smallest_eigenpairs(A, 12, d, method=method)
    assert np.array_equal(v1, v2) and np.array_equal(u1, u2)
    perm = np.random.default_rng(7).permutation(A.shape[0])
    Ap = sp.csr_matrix(A[perm][:, perm])
    vp, up = smallest_eigenpairs(Ap, 12, d[perm], method=method)
    np.testing.assert_allclose(vp, v1, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(up, u1[perm], atol=1e-7)  # the sign rule does not depend on vertex order


def test_fix_signs_is_invariant_to_sign_flips():
    from shape_toolkit.core.eigen import fix_signs

    U = np.random.default_rng(2).standard_normal((300, 9))
    U[:, 3] = np.r_[np.ones(150), -np.ones(150)] / np.sqrt(300)  # zero third moment: the peak rule
    flips = np.where(np.arange(9) % 2 == 0, 1.0, -1.0)
    np.testing.assert_array_equal(fix_signs(U), fix_signs(U * flips))
    assert np.all(np.einsum("ij,ij,ij->j", fix_signs(U), fix_signs(U), fix_signs(U))[[0, 1, 2, 4]] > 0)


def test_local_gram_schmidt_falls_back_to_full_passes_when_needed():
    """A block with large components along the whole basis (not Lanczos-local) still comes out
    orthogonal to it: the DGKS criterion adds the second full pass."""
    from shape_toolkit.core.eigen import _orthonormalize_block

    rng = np.random.default_rng(0)
    n, j, b = 500, 40, 4
    P = np.asfortranarray(la.qr(rng.standard_normal((n, j + b)), mode="economic")[0])
    W0 = P @ rng.standard_normal((j + b, b)) * 1e6 + rng.standard_normal((n, b))
    W = np.asfortranarray(W0.copy())
    h, R = _orthonormalize_block(P, W, np.empty((n, b), order="F"), rng, local=j - b)
    assert np.abs(P.T @ W).max() < 1e-12
    np.testing.assert_allclose(W.T @ W, np.eye(b), atol=1e-12)
    np.testing.assert_allclose(P @ h + W @ R, W0, rtol=0, atol=1e-8 * np.abs(W0).max())


# -- default block size: escalation when a cluster fills the block ------------------------------------
def test_largest_cluster_counts_equal_neighbours():
    from shape_toolkit.core.eigen import _largest_cluster

    vals = np.array([0.0, 1e-14, 2.0, 2.0 * (1 + 1e-12), 2.0, 6.0, 6.0 * (1 + 1e-6)])
    assert _largest_cluster(vals, 1e-8, 1e-10) == 3  # the 2s; 0 twice; 6 and 6(1 + 1e-6) are distinct
    assert _largest_cluster(vals, 1e-5, 1e-10) == 3
    assert _largest_cluster(np.array([3.0]), 1e-8, 0.0) == 1


@pytest.mark.parametrize("k", [9, pytest.param(25, marks=pytest.mark.slow)])
def test_default_block_escalates_until_every_copy_of_a_round_sphere_cluster_is_found(sphere, k):
    """k = 9 / 25 end on the l = 2 / l = 4 cluster (5 / 9 copies; on the icosphere the icosahedral symmetry
    keeps l = 2 exactly 5-fold and splits l = 4 into exact 4 + 5): a cluster as large as the default block
    of 4 makes it double, and every copy comes back (1e-10 against LAPACK)."""
    from shape_toolkit.core.eigen import _largest_cluster

    A, mass, ref = sphere  # LAPACK's 25 smallest, computed once for the module
    assert k <= len(ref)
    ref = ref[:k]
    info: dict = {}
    vals, vecs = smallest_eigenpairs(A, k, mass, info=info)
    np.testing.assert_allclose(vals[1:], ref[1:], rtol=1e-10)
    ell = int(round(np.sqrt(k))) - 1  # the last full cluster: l(l + 1), 2l + 1 copies
    assert np.sum(np.abs(vals - ell * (ell + 1)) < 0.05 * ell * (ell + 1)) == 2 * ell + 1
    exact = _largest_cluster(ref[1:], 1e-9, 0.0)
    assert exact == 5  # the l = 2 cluster (and l = 4's 5-fold part)
    assert info["escalated_from"][0]["block_size"] == 4  # it started at 4 and saw a full block
    assert info["block_size"] == 8 > exact  # and stopped at the first block larger than every cluster
    np.testing.assert_allclose(vecs.T @ (mass[:, None] * vecs), np.eye(k), atol=1e-10)


def test_default_block_does_not_escalate_without_symmetry():
    """A grid with a random mass (no repeated eigenvalues) keeps the first block: one solve."""
    A, d, ref, _ = _grid_case(31, 37, 20, seed=3)
    info: dict = {}
    vals, _ = smallest_eigenpairs(A, 20, d, info=info)
    assert info["method"] == "krylov" and info["block_size"] == 4 and "escalated_from" not in info
    np.testing.assert_allclose(vals[1:], ref[1:20], rtol=1e-10)


def test_default_block_does_not_escalate_when_the_shift_exceeds_the_gaps():
    """One tiny mass entry makes |sigma| = 1e-8 max(diag(A) / M) larger than the gaps between the wanted
    eigenvalues (as on a 1M-vertex mesh): distinct eigenvalues must not be taken for copies."""
    A, d, _, _ = _grid_case(31, 37, 20, seed=3)
    d = d.copy()
    d[500] = 1e-7
    s = 1 / np.sqrt(d)
    ref = la.eigh(A.toarray() * s[:, None] * s[None, :], eigvals_only=True, subset_by_index=(0, 19))
    sigma = 1e-8 * np.max(A.diagonal() / d)
    assert sigma > np.min(np.diff(ref))  # the situation this test is about
    info: dict = {}
    vals, _ = smallest_eigenpairs(A, 20, d, info=info)
    assert "escalated_from" not in info and info["block_size"] == 4
    # the dense reference itself is off by ~eps * max(diag(A) / d) ~ 4e-9 here (1e-6 relative)
    np.testing.assert_allclose(vals[1:], ref[1:], rtol=1e-5)


@pytest.mark.parametrize("k, basis", [(30, 48), (60, 96)])
def test_locked_restarts_keep_eigenvalues_and_subspace(generalized, k, basis):
    """A small basis forces several thick restarts, so converged Ritz pairs are locked (decoupled from
    the basis at tol): eigenvalues still match LAPACK to 1e-10, the eigenvectors span LAPACK's
    subspace (every principal-angle cosine 1 to 1e-8), M-orthonormal."""
    A, d, _, _ = generalized
    s = 1 / np.sqrt(d)
    ref, y = la.eigh(A.toarray() * s[:, None] * s[None, :], subset_by_index=(0, k))  # one more: the cut
    info: dict = {}
    vals, vecs = smallest_eigenpairs(A, k, d, method="krylov", block_size=4, max_basis=basis, info=info)
    assert info["restarts"] >= 2 and info["locked"] > 0
    np.testing.assert_allclose(vals[1:], ref[1:k], rtol=1e-10)
    assert abs(vals[0]) < 1e-10 * ref[1]
    assert ref[k] - ref[k - 1] > 1e-6 * ref[k]  # the cut is not inside a cluster, so the subspace is defined
    cos = subspace_cosines(vecs, y[:, :k] * s[:, None], d)
    np.testing.assert_allclose(cos, 1.0, atol=1e-8)
    np.testing.assert_allclose(vecs.T @ (d[:, None] * vecs), np.eye(k), atol=1e-10)
