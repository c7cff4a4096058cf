"""Spectral bases and the functional maps between them (thesis 2.6, 6.2; Ovsjanikov et al. 2012).

- :func:`spectral_basis`: which eigenpairs of a (truncated) :class:`~shape_toolkit.core.spectrum.Spectrum`
  are "the non-null ones", in which normalisation; the heat kernels, scales and embeddings use it.
- :class:`Basis` (:func:`basis_of`): the area-normalized Laplace-Beltrami eigenbasis the matchers use,
  with its projection and its low-pass filter.
- functional maps ``C`` between two bases and point maps: :func:`fmap_from_p2p`, :func:`p2p_from_fmap`,
  ZoomOut's refinement (:func:`zoomout`, Melzi et al. 2019) and its residual (:func:`zoomout_residual`).
- the functional-map energy (:func:`fit_functional_map`): descriptor preservation, Laplacian and descriptor
  commutativity (:func:`multiplication_operators`) and the orientation term of Ren et al. 2018
  (:func:`orientation_operators`: ``sum_f ||C O_t(f) - O_s(f) C||^2``, ``O(f) g = <n x grad f, grad g>`` with
  outward normals, which changes sign under a reflection and so favours orientation-preserving maps). The
  energy is quadratic in ``vec(C)``: its normal equations (Kronecker identities) are solved exactly as one
  small dense SPD system. It is invariant under one orthogonal mixing of the descriptor columns of both
  shapes, so the columns are first rotated onto their principal directions and the weak ones dropped
  (:func:`compress_descriptors`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from shape_toolkit.core.geometry import farthest_point_sampling, nearest_neighbors, outward_face_normals
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum, null_count
from shape_toolkit.core.surface import cloud_surface
from shape_toolkit.errors import ParameterError

__all__ = [
    "spectral_basis", "shifted_weights", "Basis", "basis_of", "normalized_spectrum", "fmap_from_p2p",
    "p2p_from_fmap", "slanted_size", "zoomout", "POLISH_START", "polish_map", "zoomout_residual", "map_residual",
    "zoomout_select",
    "fit_functional_map", "GradientFrame", "gradient_frame", "SharedPairWork", "orientation_operators",
    "multiplication_operators", "compress_descriptors",
]


def spectral_basis(
    spectrum: Spectrum, K: int | None = None, *, deflate: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """The eigenvalues ``(k,)`` and orthonormal eigenvectors ``(n, k)`` the kernel is built from:
    the null eigenpairs (:func:`~shape_toolkit.core.spectrum.null_count`) dropped when ``deflate``,
    then the first ``K`` non-null ones (None: all of them). Random-walk eigenvectors ``v`` are
    returned as the normalized ones ``D^1/2 v`` (same eigenvalues, symmetric kernel)."""
    vals = np.asarray(spectrum.eigenvalues, dtype=np.float64)
    vecs = np.asarray(spectrum.eigenvectors, dtype=np.float64)
    if spectrum.laplacian == "random-walk":
        vecs = vecs * np.sqrt(np.asarray(spectrum.degrees, dtype=np.float64))[:, None]
    null = null_count(vals)
    avail = vals.size - null
    if K is None:
        K = avail
    if isinstance(K, bool) or not isinstance(K, (int, np.integer)):
        raise ParameterError(f"K must be an integer, got {K!r}")
    if not 1 <= K <= avail:
        raise ParameterError(
            f"K must be in [1, {avail}]: the spectrum holds {vals.size} eigenpairs, {null} of them "
            f"null; compute a larger spectrum (K = {K} asked)"
        )
    start = null if deflate else 0
    stop = null + int(K)
    return vals[start:stop], vecs[:, start:stop]


def shifted_weights(vals: np.ndarray, t: float) -> np.ndarray:
    """``exp(-t (lambda_k - lambda_min))``: the heat weights up to a common factor, which the
    normalized embeddings and the scree ratios cancel; never underflows to all zeros at large ``t``."""
    return np.exp(-t * (vals - vals.min()))


# -- the area-normalized eigenbasis of the matchers ---------------------------------------------------
@dataclass(frozen=True)
class Basis:
    """An area-normalized Laplacian eigenbasis: ``evals`` ``(k,)``, ``evecs`` ``(n, k)`` with
    ``evecs.T @ diag(mass) @ evecs = I`` and ``mass.sum() == 1`` (unit total area)."""

    evals: np.ndarray
    evecs: np.ndarray
    mass: np.ndarray

    @property
    def k(self) -> int:
        """Number of basis functions."""
        return int(self.evals.size)

    def project(self, f: np.ndarray, k: int | None = None) -> np.ndarray:
        """Coefficients ``(k, d)`` of functions ``f`` ``(n, d)`` on the first ``k`` vectors."""
        k = self.k if k is None else k
        return self.evecs[:, :k].T @ (self.mass[:, None] * f)

    def low_pass(self, f: np.ndarray, k: int | None = None) -> np.ndarray:
        """Functions ``f`` ``(n,)`` or ``(n, d)`` low-pass filtered: projected on the first ``k`` vectors
        and back, ``Phi_k Phi_k^T M f`` (same shape as ``f``)."""
        phi = self.evecs[:, :k]
        w = self.mass if np.ndim(f) == 1 else self.mass[:, None]
        return phi @ (phi.T @ (w * f))


def basis_of(spectrum: Spectrum, k: int | None = None) -> Basis:
    """The area-normalized :class:`Basis` of the first ``k`` eigenpairs of ``spectrum``
    (eigenvalues times total mass, eigenvectors times ``sqrt(total mass)``)."""
    k = spectrum.k if k is None else min(k, spectrum.k)
    n = spectrum.n_vertices
    mass = np.ones(n) if spectrum.mass is None else np.asarray(spectrum.mass, dtype=np.float64)
    total = float(mass.sum())
    return Basis(
        np.asarray(spectrum.eigenvalues[:k]) * total,
        np.asarray(spectrum.eigenvectors[:, :k]) * np.sqrt(total),
        mass / total,
    )


def normalized_spectrum(spectrum: Spectrum) -> Spectrum:
    """The same spectrum scaled to unit total mass (area-normalized eigenpairs)."""
    b = basis_of(spectrum)
    return Spectrum(
        b.evals, b.evecs, spectrum.laplacian, spectrum.weighting,
        b.mass if spectrum.mass is not None else None, spectrum.degrees, spectrum.sign_fixed,
    )


# -- functional maps and point maps --------------------------------------------------------------------
def fmap_from_p2p(
    src: Basis, tgt: Basis, target_of: np.ndarray, ks: int, kt: int, *, weights: np.ndarray | None = None,
    rows: np.ndarray | None = None,
) -> np.ndarray:
    """Functional map ``C_ts`` ``(ks, kt)`` pulling target functions back to the source through
    the point map ``target_of`` (all entries >= 0) of the source vertices ``rows`` (default all):
    least squares ``argmin ||Phi_s C - Phi_t[T]||`` weighted by the source mass."""
    if rows is None:
        w = src.mass if weights is None else weights
        return src.evecs[:, :ks].T @ (w[:, None] * tgt.evecs[target_of, :kt])
    A = src.evecs[rows, :ks]
    w = src.mass[rows] if weights is None else weights
    AtA = A.T @ (w[:, None] * A)
    return np.linalg.solve(AtA + 1e-10 * np.eye(ks), A.T @ (w[:, None] * tgt.evecs[target_of, :kt]))


def p2p_from_fmap(C_ts: np.ndarray, src: Basis, tgt: Basis, rows: np.ndarray | None = None) -> np.ndarray:
    """Point map (target vertex of each source vertex, or of ``rows``) of the functional map
    ``C_ts`` ``(ks, kt)``: nearest neighbour of ``Phi_s[i]`` among the rows of ``Phi_t C_ts^T``."""
    ks, kt = C_ts.shape
    points = tgt.evecs[:, :kt] @ C_ts.T
    queries = src.evecs[:, :ks] if rows is None else src.evecs[rows, :ks]
    return nearest_neighbors(points, queries)[1]


def _point_map(C: np.ndarray, emb_s: np.ndarray, emb_t: np.ndarray) -> np.ndarray:
    """Nearest row of ``emb_t[:, :kt] @ C.T`` for each row of ``emb_s[:, :ks]`` (single precision)."""
    ks, kt = C.shape
    points = emb_t[:, :kt] @ C.T.astype(emb_t.dtype)
    return nearest_neighbors(points, emb_s[:, :ks], dtype=np.float32)[1]


def slanted_size(src: Basis, tgt: Basis, k: int, scale: float | None) -> int:
    """How many target basis functions span the frequencies of the first ``k`` source ones: ``k`` when
    ``scale`` is None (two whole shapes), else the count of target eigenvalues at most the source's ``k``-th
    in the same units (``scale = area_t / area_s`` of the shapes in their common units: a part of a shape
    has fewer eigenvalues below a frequency, Weyl's law ``lambda_i ~ 4 pi i / area``, so the functional map
    of a part is rectangular with a slanted diagonal; Rodola et al. 2017). Between 1 and ``tgt.k``."""
    if scale is None:
        return min(int(k), tgt.k)
    top = float(src.evals[min(int(k), src.k) - 1]) * float(scale)
    return int(np.clip(np.searchsorted(tgt.evals, top * (1 + 1e-9), side="right"), 1, tgt.k))


def zoomout(
    C: np.ndarray, src: Basis, tgt: Basis, k_final: int, step: int = 1,
    rows: np.ndarray | None = None, cols: np.ndarray | None = None,
    progress: Callable[[str], None] | None = None, final: bool = True, scale: float | None = None,
    weights: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """ZoomOut (Melzi et al. 2019): alternate point map and functional map while the source basis grows
    from ``C.shape[0]`` to ``k_final`` by ``step``; returns the final ``C_ts`` and the point map of
    every source vertex. ``rows``/``cols`` (source/target vertex samples) speed up the iterations; with ``rows``,
    one more iteration at ``k_final`` queries every source vertex, so the returned ``C_ts`` is the projection of a
    full point map. ``weights`` ``(len(rows),)``: the share of the source's mass each row stands for in the
    least-squares fits (default: the rows' own vertex masses; the area of each sample's Voronoi cell,
    :func:`~shape_toolkit.core.geometry.sample_weights`, keeps the fits close to the full ones). Point
    maps are nearest neighbours in single precision (:func:`~shape_toolkit.core.geometry.nearest_neighbors`);
    ``progress`` receives one message per iteration. ``final=False`` skips the point map of every source
    vertex: the returned map then covers ``rows`` only (``-1`` elsewhere).

    ``scale`` (None: two whole shapes) makes the source a part of the target with ``area_t / area_s =
    scale`` in common units: each functional map is rectangular, ``(k, slanted_size(k))``, the target basis
    spanning the frequencies of the source's (:func:`slanted_size`; ZoomOut's partial variant, Melzi et al.
    2019 after Rodola et al. 2017)."""
    k = C.shape[0]
    e_s = np.asarray(src.evecs[:, :k_final], dtype=np.float32)
    e_t = np.asarray(tgt.evecs[:, :slanted_size(src, tgt, k_final, scale)], dtype=np.float32)
    q_s = e_s if rows is None else e_s[rows]
    q_t = e_t if cols is None else e_t[cols]
    n_iter = max(0, -(-(k_final - k) // step))
    it = 0
    while k < k_final:
        T = _point_map(C, q_s, q_t)
        if cols is not None:
            T = cols[T]
        k = min(k + step, k_final)
        C = fmap_from_p2p(src, tgt, T, k, slanted_size(src, tgt, k, scale), rows=rows, weights=weights)
        it += 1
        if progress is not None:
            progress(f"zoomout: iteration {it}/{n_iter} (k = {k})")
    if not final and rows is not None:
        T = np.full(e_s.shape[0], -1, dtype=np.int64)
        T[rows] = _point_map(C, q_s, e_t)
        return C, T
    T = _point_map(C, e_s, e_t)
    if rows is not None:
        C = fmap_from_p2p(src, tgt, T, k_final, slanted_size(src, tgt, k_final, scale))
        T = _point_map(C, e_s, e_t)
    return C, T


#: where a ZoomOut polish of a point map starts (fmap-zoomout's initial size): best-of's and the orientation repair's
POLISH_START = 20


def polish_map(
    target_of: np.ndarray, src: Basis, tgt: Basis, start: int = POLISH_START, step: int = 5,
    seeds: np.ndarray | None = None, rows: np.ndarray | None = None, samples: np.ndarray | None = None,
    sample_mass: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """A point map ``target_of`` ``(n_s,)`` (all entries >= 0) refined by ZoomOut from its functional map in
    ``start`` functions to ``src.k``, ``step`` at a time; the pairs ``seeds`` ``(q, 2)`` are kept. ``rows``: the
    start is fitted on those source vertices only (the map is trusted there; elsewhere ZoomOut infers it).
    ``samples`` (source vertex ids) and ``sample_mass``: :func:`zoomout`'s ``rows`` and ``weights`` (the iterations
    query the samples, then one queries every vertex).
    Returns the final ``C_ts`` and the refined map ``(n_s,)``."""
    t = np.asarray(target_of)
    C0 = fmap_from_p2p(src, tgt, t if rows is None else t[rows], start, start, rows=rows)
    C, T = zoomout(C0, src, tgt, src.k, step, rows=samples, weights=sample_mass)
    if seeds is not None and len(seeds):
        T[seeds[:, 0]] = seeds[:, 1]
    return C, T


def part_support(target_of: np.ndarray, src: Basis, tgt: Basis, area_ratio: float, k_smooth: int = 30) -> np.ndarray:
    """Where on the whole shape ``tgt`` a part ``src`` lies, from a point map ``target_of`` ``(n_s,)`` of the part
    into it: the target vertices ``(n_t,)`` boolean where the image's density (the part's vertex areas landing on
    each target vertex over its area) low-passed on the first ``k_smooth`` target functions is largest, holding
    ``area_ratio`` of the target's area. The membership function of Rodola et al. 2017's partial functional maps,
    hardened to the part's area; a map scattered by a few points keeps its bulk."""
    T = np.asarray(target_of, dtype=np.int64)
    density = np.bincount(T, weights=src.mass, minlength=tgt.mass.size) / np.maximum(tgt.mass, 1e-300)
    smooth = tgt.low_pass(density, min(int(k_smooth), tgt.k))
    order = np.argsort(-smooth, kind="stable")
    filled = np.cumsum(tgt.mass[order]) / float(tgt.mass.sum())
    keep = np.zeros(tgt.mass.size, dtype=bool)
    keep[order[: int(np.searchsorted(filled, float(area_ratio))) + 1]] = True
    return keep


def point_map_within(C: np.ndarray, src: Basis, tgt: Basis, support: np.ndarray) -> np.ndarray:
    """The point map ``(n_s,)`` of the functional map ``C`` ``(ks, kt)``, each source vertex sent to its nearest
    target vertex in the spectral embedding among those of ``support`` (target boolean ``(n_t,)``) only."""
    ids = np.flatnonzero(support)
    ks, kt = C.shape
    e_s = np.asarray(src.evecs[:, :ks], dtype=np.float32)
    e_t = np.asarray(tgt.evecs[ids, :kt], dtype=np.float32)
    return ids[_point_map(C, e_s, e_t)]


def zoomout_residual(C: np.ndarray, src: Basis, tgt: Basis, target_of: np.ndarray,
                     rows: np.ndarray | None = None) -> float:
    """ZoomOut's own energy at a fixed point: the mass-weighted mean over the source vertices ``rows``
    (default all) of ``||Phi_s(x) C - Phi_t(T(x))||^2`` for the functional map ``C`` ``(k, k)`` and the
    point map ``target_of`` ``(n_s,)``, in the area-normalized bases (unitless). A flipped or swapped
    part leaves high-frequency disagreement, so between two refined maps of one pair the smaller
    residual is the more plausible map."""
    ks, kt = C.shape
    ids = np.arange(src.evecs.shape[0]) if rows is None else np.asarray(rows)
    diff = src.evecs[ids, :ks] @ C - tgt.evecs[np.asarray(target_of)[ids], :kt]
    w = src.mass[ids]
    return float((w * (diff**2).sum(axis=1)).sum() / max(float(w.sum()), 1e-300))


def map_residual(src: Basis, tgt: Basis, target_of: np.ndarray, k: int) -> float:
    """:func:`zoomout_residual` of a point map ``target_of`` ``(n_s,)`` against its own least-squares functional map
    in the first ``k`` functions of both bases: how far the map is from a smooth one (between maps of one pair, or
    self-maps of one shape, the smaller the more plausible). A partial map (``-1``) is judged on its matched
    vertices; ``inf`` when none is matched."""
    t = np.asarray(target_of)
    if np.all(t >= 0):
        return zoomout_residual(fmap_from_p2p(src, tgt, t, k, k), src, tgt, t)
    ok = np.flatnonzero(t >= 0)
    if not len(ok):
        return float("inf")
    return zoomout_residual(fmap_from_p2p(src, tgt, t[ok], k, k, rows=ok), src, tgt, t, rows=ok)


def zoomout_select(
    fits: list[np.ndarray], src: Basis, tgt: Basis, k_final: int, step: int, rows: np.ndarray,
    cols: np.ndarray | None = None, scale: float | None = None,
) -> tuple[int, list[float], np.ndarray]:
    """Which of several functional maps ``fits`` (each ``(k, k)``) ZoomOut refines best: each refined to
    ``k_final`` by ``step`` on the source vertices ``rows`` (:func:`zoomout`), the one of smallest
    :func:`zoomout_residual`. Returns its index, every residual, and where its full refinement starts:
    the leading block, half way to ``k_final``, of its refined map (the small-k steps are done; the
    costly large-k ones then see every vertex)."""
    residuals, refined = [], []
    for C0 in fits:
        Cz, Tz = zoomout(C0, src, tgt, k_final, step, rows, cols, final=False, scale=scale)
        residuals.append(zoomout_residual(Cz, src, tgt, Tz, rows))
        refined.append(Cz)
    chosen = int(np.argmin(residuals))
    k_mid = (fits[chosen].shape[0] + k_final) // 2
    return chosen, residuals, refined[chosen][:k_mid, :slanted_size(src, tgt, k_mid, scale)]


# -- the functional-map energy ------------------------------------------------------------------------
@dataclass(frozen=True)
class GradientFrame:
    """The part of :func:`orientation_operators` that does not depend on the descriptors, for one shape and one
    basis: the gradient operator ``G`` (sparse ``(3m, n)``, per face, 1/length units), the first ``k`` basis
    gradients turned by the outward face normals ``Q`` ``(3, m, k)`` (``grad phi_j x n``), the basis averaged on
    the faces with area weights ``phi_face`` ``(m, k)`` (unit total area) and the total area ``total``."""

    G: Any
    Q: np.ndarray
    phi_face: np.ndarray
    total: float

    @property
    def k(self) -> int:
        """Number of basis functions covered (any first ``k`` of them are slices)."""
        return int(self.Q.shape[2])


def gradient_frame(shape: Shape, basis: Basis, k: int) -> GradientFrame:
    """The :class:`GradientFrame` of the first ``k`` functions of ``basis`` on the mesh ``shape``: computed once, it
    serves every :func:`orientation_operators` call on this shape and basis with at most ``k`` functions."""
    import igl

    F = np.asarray(shape.faces)
    m = F.shape[0]
    G = igl.grad(np.asarray(shape.vertices, dtype=np.float64), F).tocsr()
    N = outward_face_normals(shape)
    # per-face area weights redistributed to the three corners (lumped, mass-normalized)
    fa = np.asarray(shape.face_areas, dtype=np.float64)
    total = float(fa.sum())
    phi = basis.evecs[:, :k]
    phi_face = (phi[F[:, 0]] + phi[F[:, 1]] + phi[F[:, 2]]) * (fa / (3.0 * total))[:, None]  # (m, k)
    # <n x grad f, grad phi_j> = <grad f, grad phi_j x n>: rotate the k basis gradients once,
    # Q_a = g_b n_c - g_c n_b with (a, b, c) cyclic, one gradient component g_b (m, k) at a time
    Q = np.zeros((3, m, phi.shape[1]))
    for b in range(3):
        g = G[b * m : (b + 1) * m] @ phi
        Q[(b - 1) % 3] += g * N[:, (b + 1) % 3, None]
        Q[(b + 1) % 3] -= g * N[:, (b - 1) % 3, None]
    return GradientFrame(G, Q, phi_face, total)


def orientation_operators(
    shape: Shape, basis: Basis, k: int, descriptors: np.ndarray, *, frame: GradientFrame | None = None,
) -> np.ndarray:
    """Orientation operators ``(d, k, k)``: ``O(f)_ij = <phi_i, <n x grad f, grad phi_j>>_M`` for
    each descriptor column ``f`` (Ren et al. 2018), with outward face normals. ``frame``: the
    :func:`gradient_frame` of this ``shape`` and ``basis`` (at least ``k`` functions) when the caller keeps it
    for several calls (the operators are the same, bit for bit); None: computed here."""
    if frame is None or frame.k < k:
        frame = gradient_frame(shape, basis, k)
    G, total = frame.G, frame.total
    Q = frame.Q if frame.k == k else frame.Q[:, :, :k]
    phi_face = frame.phi_face if frame.k == k else np.ascontiguousarray(frame.phi_face[:, :k])
    m = phi_face.shape[0]
    d = descriptors.shape[1]
    ops = np.empty((d, k, k))
    # descriptors per block: the block's gradients (3, m, step) and Z (m, step, k), ~8 MB each (x 2
    # temporaries); all gradients at once would be 3 m d values, 88 MB for d = 80 at 23k vertices
    step = max(1, 1_000_000 // max(1, m * k))
    for s in range(0, d, step):
        e = min(d, s + step)
        gf = (G @ descriptors[:, s:e]).reshape(3, m, e - s)
        Z = gf[0][:, :, None] * Q[0][:, None, :]  # (m, e - s, k): sum_x grad_x f * Q_x
        Z += gf[1][:, :, None] * Q[1][:, None, :]
        Z += gf[2][:, :, None] * Q[2][:, None, :]
        ops[s:e] = (phi_face.T @ Z.reshape(m, -1)).reshape(k, e - s, k).transpose(1, 0, 2)
    # gradients carry 1/length: rescale to the unit-area normalization of the basis
    return ops * total


def multiplication_operators(basis: Basis, k: int, descriptors: np.ndarray) -> np.ndarray:
    """Multiplication operators ``(d, k, k)``: ``X(f)_ij = <phi_i, f phi_j>_M`` for each descriptor
    column ``f`` ``(n,)`` of ``descriptors`` ``(n, d)``: BLAS products over the upper triangle, in vertex blocks."""
    phi = basis.evecs[:, :k]
    iu, ju = np.triu_indices(k)
    W = basis.mass[:, None] * descriptors
    # the products phi_i phi_j are formed for a block of vertices at a time (<= 2**21 values, 16 MB):
    # all at once they are n x k(k+1)/2, 86 MB for k = 30 at 23k vertices
    step = max(1, 2**21 // len(iu))
    vals = np.zeros((len(iu), descriptors.shape[1]))  # (k(k+1)/2, d)
    prod = np.empty((min(step, len(phi)), len(iu)))
    for a in range(0, len(phi), step):
        p = phi[a : a + step]
        P = prod[: len(p)]
        o = 0
        for i in range(k):  # the columns phi_i phi_j, j >= i, in triu_indices order (slices: no gathers)
            np.multiply(p[:, i : i + 1], p[:, i:], out=P[:, o : o + k - i])
            o += k - i
        vals += P.T @ W[a : a + step]
    ops = np.empty((descriptors.shape[1], k, k))
    ops[:, iu, ju] = vals.T
    ops[:, ju, iu] = vals.T
    return ops


def compress_descriptors(
    desc_src: np.ndarray, desc_tgt: np.ndarray, mass_src: np.ndarray, mass_tgt: np.ndarray,
    rtol: float = 1e-10,
) -> tuple[np.ndarray, np.ndarray]:
    """Both shapes' descriptors ``(n_s, d)``, ``(n_t, d)`` mixed by one orthogonal ``V`` ``(d, r)``:
    the principal directions of the mass-weighted columns of both shapes together, keeping those
    whose squared singular value exceeds ``rtol`` times the largest. Every term of the functional
    map energy sums over descriptor columns and is linear in each operator, so it is unchanged by
    the full ``V`` and changes by about ``rtol`` relative when the weak directions are dropped."""
    same = desc_src is desc_tgt and mass_src is mass_tgt  # one shape: its Gram matrix alone has the same V
    S = np.sqrt(mass_src)[:, None] * desc_src
    if not same:
        S = np.vstack([S, np.sqrt(mass_tgt)[:, None] * desc_tgt])
    _, sv, Vt = np.linalg.svd(S.T @ S if S.shape[0] > 4 * S.shape[1] else S, full_matrices=False)
    ev = sv if S.shape[0] > 4 * S.shape[1] else sv**2  # eigenvalues of the Gram matrix
    r = max(1, int(np.sum(ev > rtol * ev[0]))) if ev.size and ev[0] > 0 else desc_src.shape[1]
    V = Vt[:r].T
    out = desc_src @ V
    return out, (out if same else desc_tgt @ V)


def _commutativity_hessian(Xs: np.ndarray, Xt: np.ndarray) -> np.ndarray:
    """Hessian ``(ks kt, ks kt)`` of ``sum_f ||C X_t(f) - X_s(f) C||^2 / 2`` in column-major ``vec(C)`` of a
    ``(ks, kt)`` map, for operators ``Xs`` ``(d, ks, ks)`` and ``Xt`` ``(d, kt, kt)``:
    ``sum_f (X_t X_t^T kron I + I kron X_s^T X_s - X_t kron X_s - X_t^T kron X_s^T)``."""
    d, ks, _ = Xs.shape
    kt = Xt.shape[1]
    kk = ks * kt
    XtXt = np.tensordot(Xt, Xt, axes=([0, 2], [0, 2]))
    XsXs = np.tensordot(Xs, Xs, axes=([0, 1], [0, 1]))
    cross = (Xt.reshape(d, kt * kt).T @ Xs.reshape(d, ks * ks)).reshape(kt, kt, ks, ks)
    cross = cross.transpose(0, 2, 1, 3).reshape(kk, kk)
    return np.kron(XtXt, np.eye(ks)) + np.kron(np.eye(kt), XsXs) - cross - cross.T


#: the most unknowns (``k kt``) :func:`fit_functional_map` solves for: its dense normal equations hold ``(k kt)^2``
#: doubles, 800 MB at 10,000 (a 100 x 100 map; the fits of the matchers start at 20-30 and ZoomOut grows them)
FIT_MAX_UNKNOWNS = 10_000


def fit_functional_map(
    src: Basis,
    tgt: Basis,
    desc_src: np.ndarray,
    desc_tgt: np.ndarray,
    k: int,
    *,
    w_descr: float = 1.0,
    w_lap: float = 0.1,
    w_dcomm: float = 1.0,
    w_orient: float = 1.0,
    orient_src: np.ndarray | None = None,
    orient_tgt: np.ndarray | None = None,
    k_target: int | None = None,
    eval_scale: float = 1.0,
    mult_src: np.ndarray | None = None,
    mult_tgt: np.ndarray | None = None,
) -> np.ndarray:
    """The ``(k, kt)`` functional map ``C_ts`` (target functions -> source functions; ``kt = k_target``,
    default ``k``) minimizing ``w_descr ||C A_t - A_s||^2 + w_lap ||C L_t - L_s C||^2 + w_dcomm sum_f
    ||C X_t(f) - X_s(f) C||^2 + w_orient sum_f ||C O_t(f) - O_s(f) C||^2``, each term divided by its size at
    ``C = 0`` or ``C = I`` so the weights are relative; solved exactly through its normal equations.
    ``eval_scale`` multiplies the source eigenvalues into the target's units (a part of the target:
    ``area_t / area_s``, see :func:`~shape_toolkit.features.basis.slanted_size`). ``mult_src``/``mult_tgt``: the
    :func:`multiplication_operators` of ``desc_src``/``desc_tgt`` in at least ``k``/``kt`` functions, when the
    caller keeps them for several fits (their leading blocks are used); None: computed here."""
    kt = k if k_target is None else int(k_target)
    if k * kt > FIT_MAX_UNKNOWNS:  # before the (k kt)^2 normal equations are allocated
        raise ParameterError(
            f"a {k} x {kt} functional map has {k * kt:,} unknowns; its exact fit solves dense normal equations of "
            f"{8 * (k * kt) ** 2 / 1e9:.1f} GB, so at most {FIT_MAX_UNKNOWNS:,} (100 x 100) are fitted: lower k "
            "(ZoomOut then grows the map)")
    A_s = src.project(desc_src, k)
    A_t = tgt.project(desc_tgt, kt)
    kk = k * kt
    H = np.zeros((kk, kk))
    # descriptor preservation: vec(C A_t) = (A_t^T kron I) vec(C)   (column-major vec)
    sd = max(float((A_s**2).sum()), 1e-300)
    H += w_descr / sd * np.kron(A_t @ A_t.T, np.eye(k))
    rhs = w_descr / sd * (A_s @ A_t.T).ravel(order="F")
    # Laplacian commutativity: diagonal (lambda_s,i - lambda_t,j)^2 on C_ij
    ls, lt = src.evals[:k] * float(eval_scale), tgt.evals[:kt]
    D = (ls[:, None] - lt[None, :]) ** 2  # (k, kt) indexed [i, j]
    sl = max(float((ls**2).sum()), 1e-300)
    H[np.diag_indices(kk)] += w_lap / sl * D.ravel(order="F")

    def add_commutativity(Xs: np.ndarray, Xt: np.ndarray, w: float) -> None:
        if w <= 0 or len(Xs) == 0:
            return
        scale = max(float((Xs**2).sum()), 1e-300)
        H[:] += w / scale * _commutativity_hessian(Xs, Xt)

    if w_dcomm > 0:
        def leading(ops: np.ndarray | None, basis: Basis, size: int, desc: np.ndarray) -> np.ndarray:
            if ops is None or ops.shape[1] < size:
                return multiplication_operators(basis, size, desc)
            return ops if ops.shape[1] == size else np.ascontiguousarray(ops[:, :size, :size])

        add_commutativity(leading(mult_src, src, k, desc_src), leading(mult_tgt, tgt, kt, desc_tgt), w_dcomm)
    if w_orient > 0 and orient_src is not None and orient_tgt is not None:
        add_commutativity(orient_src[:, :k, :k], orient_tgt[:, :kt, :kt], w_orient)
    H[np.diag_indices(kk)] += 1e-9 * np.trace(H) / kk
    c = np.linalg.solve(H, rhs)
    return c.reshape(k, kt, order="F")


class SharedPairWork:
    """The work of the ``fmap-zoomout`` matcher on one pair of shapes that does not depend on the part's area
    ratio, done once and reused by every candidate ratio of
    :func:`~shape_toolkit.plugins.matching.dense.partial_search.match_over_area_ratios`
    (``fmap-zoomout``'s ``match_at_area_ratio``): the area-normalized bases of the two spectra, the shapes'
    local surfaces, their :func:`gradient_frame` for the orientation term and the
    farthest-point samples. Each value is what a fresh match computes, so the maps are the same bit for bit.
    Items are keyed by the objects' identity: use one instance for one pair and its spectra only."""

    def __init__(self) -> None:
        self._items: dict[tuple, tuple] = {}  # key -> (the objects keyed on, kept alive; the value)

    def _get(self, key: tuple, owners: tuple, make: Callable[[], object]):
        hit = self._items.get(key)
        if hit is None:
            hit = self._items[key] = (owners, make())
        return hit[1]

    def basis(self, spectrum: Spectrum, k: int | None) -> Basis:
        """:func:`~shape_toolkit.features.basis.basis_of` ``(spectrum, k)``."""
        return self._get(("basis", id(spectrum), k), (spectrum,), lambda: basis_of(spectrum, k))

    def surface(self, shape: Shape) -> Shape:
        """:func:`~shape_toolkit.core.surface.cloud_surface` of ``shape`` (the mesh itself for a mesh)."""
        return self._get(("surface", id(shape)), (shape,), lambda: cloud_surface(shape))

    def samples(self, shape: Shape, n: int) -> np.ndarray:
        """``n`` farthest-point samples of ``shape``'s vertices (int64 ``(n,)``)."""
        return self._get(("samples", id(shape), int(n)), (shape,),
                         lambda: farthest_point_sampling(np.asarray(shape.vertices), int(n)))

    def frame(self, surface: Shape, basis: Basis, k: int) -> GradientFrame:
        """The gradient frame of ``surface`` and ``basis`` covering at least ``k`` functions: the one kept when it
        does, else computed for ``k`` and kept in its place."""
        key = ("frame", id(surface), id(basis))
        hit = self._items.get(key)
        if hit is None or hit[1].k < k:
            hit = self._items[key] = ((surface, basis), gradient_frame(surface, basis, k))
        return hit[1]
