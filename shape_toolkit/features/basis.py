"""Spectral bases and the functional maps between them (thesis 2.6, 6.2; Ovsjanikov et al. 2012).

- :func:`spectral_basis`: which eigenpairs of a (truncated) :class:`~shape_toolkit.core.spectrum.Spectrum`
  are "the non-null ones", in which normalisation; the heat kernels, scales and embeddings use it.
- :class:`Basis` (:func:`basis_of`): the area-normalized Laplace-Beltrami eigenbasis the matchers use,
  with its projection and its low-pass filter.
- functional maps ``C`` between two bases and point maps: :func:`fmap_from_p2p`, :func:`p2p_from_fmap`,
  ZoomOut's refinement (:func:`zoomout`, Melzi et al. 2019) and its residual (:func:`zoomout_residual`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from shape_toolkit.core.geometry import nearest_neighbors
from shape_toolkit.core.spectrum import Spectrum, null_count
from shape_toolkit.errors import ParameterError

__all__ = [
    "spectral_basis", "shifted_weights", "Basis", "basis_of", "normalized_spectrum", "fmap_from_p2p",
    "p2p_from_fmap", "slanted_size", "zoomout", "zoomout_residual", "zoomout_select",
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
) -> tuple[np.ndarray, np.ndarray]:
    """ZoomOut (Melzi et al. 2019): alternate point map and functional map while the source basis grows
    from ``C.shape[0]`` to ``k_final`` by ``step``; returns the final ``C_ts`` and the point map of
    every source vertex. ``rows``/``cols`` (source/target vertex samples) speed up the inner iterations
    (the final point map always covers every source vertex). Point maps are nearest neighbours in single
    precision (:func:`~shape_toolkit.core.geometry.nearest_neighbors`); ``progress`` receives one
    message per iteration. ``final=False`` skips the point map of every source vertex: the returned map
    then covers ``rows`` only (``-1`` elsewhere).

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
        C = fmap_from_p2p(src, tgt, T, k, slanted_size(src, tgt, k, scale), rows=rows)
        it += 1
        if progress is not None:
            progress(f"zoomout: iteration {it}/{n_iter} (k = {k})")
    if not final and rows is not None:
        T = np.full(e_s.shape[0], -1, dtype=np.int64)
        T[rows] = _point_map(C, q_s, e_t)
        return C, T
    return C, _point_map(C, e_s, e_t)


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
