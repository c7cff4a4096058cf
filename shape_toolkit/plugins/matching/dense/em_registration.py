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

from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from shape_toolkit.api.interfaces import DenseMatcher
from shape_toolkit.api.params import RANDOM_STATE, Interval, Options, Param
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum, SpectrumSpec, default_spec
from shape_toolkit.errors import InvalidShapeError, ParameterError
from shape_toolkit.plugins._params import FRACTION, NON_NEGATIVE, ORIENTATION, POSITIVE_INT
from shape_toolkit.plugins.matching._common import Basis, basis_of, check_seeds
from shape_toolkit.results.correspondence import Correspondence, nearest_neighbors
from shape_toolkit.validation import check_random_state

__all__ = ["EMRegistrationMatcher", "em_register", "procrustes"]


def procrustes(S: np.ndarray) -> np.ndarray:
    """The orthogonal ``Q`` maximizing ``tr(Q^T S)`` for a ``(k, k)`` correlation ``S``."""
    U, _, Vt = np.linalg.svd(S)
    return U @ Vt


def _e_step(tree: cKDTree, Y: np.ndarray, sigma: float, log_out: float, nn: int) -> tuple[np.ndarray, np.ndarray]:
    """Truncated posteriors of eq. 7.3 for targets ``Y`` ``(q, k)``: the ``nn`` nearest transformed
    source means (``tree``) of each, ``alpha`` and their indices, both ``(q, nn)``; never ``(q, n)``."""
    d, idx = tree.query(Y, k=nn)
    d = np.asarray(d).reshape(len(Y), nn)
    idx = np.asarray(idx).reshape(len(Y), nn)
    logits = -(d**2) / (2.0 * sigma)
    top = np.maximum(logits.max(axis=1), log_out)
    e = np.exp(logits - top[:, None])
    denom = e.sum(axis=1) + np.exp(log_out - top)
    return e / denom[:, None], idx


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
    max_samples: int | None = None,
    random_state: Any = 0,
) -> tuple[np.ndarray, float, sp.csr_matrix]:
    """EM of Algorithm 7 on source means ``X`` ``(n, k)`` and target data ``Y`` ``(n', k)`` from an
    initial orthogonal ``Q0``; returns ``Q``, ``sigma`` and the truncated posteriors
    ``alpha`` as CSR ``(n, n')`` (entry ``(i, j)`` = ``P(i | y_j)``, eq. 7.3).

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
    Q = Q0.copy()
    # uniform outlier density over the target's bounding box
    volume = float(np.prod(np.maximum(Y.max(0) - Y.min(0), 1e-12)))
    sample = None
    if max_samples is not None and m > int(max_samples):
        sample = np.sort(check_random_state(random_state).choice(m, int(max_samples), replace=False))
    Ys = Y if sample is None else Y[sample]
    if sigma0 is None:
        d, _ = cKDTree(X @ Q.T).query(Ys, k=1)
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
        alpha, idx = _e_step(cKDTree(X @ Q.T), Ys, sigma, log_outlier(sigma), nn)
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
        if change < tol:
            break
    if sample is not None or alpha is None:  # posteriors of every target point under the final fit
        alpha, idx = _e_step(cKDTree(X @ Q.T), Y, sigma, log_outlier(sigma), nn)
    cols = np.repeat(np.arange(m), nn)
    P = sp.csr_matrix((alpha.ravel(), (idx.ravel(), cols)), shape=(n, m))
    return Q, sigma, P


def _nearest(points: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Index of the nearest of ``points`` ``(m, d)`` for each query ``(q, d)``: int64 ``(q,)``; in
    high dimension a single-precision brute force in chunks of at most ``2**23`` distances (never
    ``q x m``; near-ties within ~1e-6 relative may resolve differently from double precision)."""
    chunk = int(np.clip(2**23 // max(1, len(points)), 16, 1024))
    return np.asarray(nearest_neighbors(points, queries, k=1, chunk=chunk, dtype=np.float32)[1], dtype=np.int64)


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

    Scale (memory linear in the vertex counts, never an ``n x n'`` block; see
    ``benchmarks/results/scale.md``):

    - ``refine_samples`` (default 5000): the intermediate steps of the coarse-to-fine refinements
      (``k_final`` and the orientation scoring, below) estimate their ``Q`` on at most this many
      source vertices (a uniform sample drawn with ``random_state``); only the last step maps every
      vertex (the orientation scoring: only its 120 samples). None: always all (time ``O(n n' k)``
      per step). Nearest neighbours in more than 12 dimensions are a chunked single-precision BLAS
      brute force (a KD-tree is no faster there), at most ``2**23`` distances at a time.
    - ``max_samples`` (default None: off): the EM iterations fit ``Q`` and ``sigma`` to at most
      this many target vertices (uniform sample), then one E-step on every target vertex gives the
      posteriors. Faster (an EM iteration costs ``O(n' log n)``), but not always as accurate: on
      the thesis embedding, where EM leaves ``Q`` poorly determined, a 10,000-vertex sample of a
      20k-vertex TOSCA pair moved the final error from 0.062 to 0.068.

    The embedding (section 7.4.1):

    - ``spectrum``: ``"lbo"`` (default; cotangent Laplace-Beltrami operator with the mass
      matrix, area normalized) or ``"graph"``: the combinatorial Laplacian ``L = D - W``
      (eq. 2.63) of the shape graph with ``weighting`` (Gaussian by default, section 3.3.3.2), no
      mass matrix -- the Laplacian of the thesis's eq. 6.24.
    - ``scaling``: ``"none"`` -- ``X = U^T``, eq. 6.24 at ``t = 0``, as written in 7.4.1 -- or
      ``"commute-time"`` -- ``X = Lambda^(-1/2) U^T``, eq. 2.92 (the principal components of
      the commute-time embedding, Theorem 3; low frequencies dominate).
    - ``dimension``: ``"fixed"`` (``k``) or ``"scree"``: the smallest ``K`` whose lower bound
      ``theta_min`` of the scree ratio (eq. 2.97-2.99) reaches ``dimension_threshold``, kept in
      ``[3, k]`` ("3 <= k <= 10 in our experiments", 7.4.1); ``k`` is then the maximum and is
      what ``spectrum_spec()`` declares (``k + 1`` eigenpairs).
    - with ``orientation`` on, ``max(k, k_final, 30) + 1`` eigenpairs are declared: maps are
      scored for orientation after a refinement to 30 dimensions (only for scoring).
    - ``k_final`` (default None: off; an extension, not in the thesis): after EM, the hard map
      is refined while the embedding grows to ``k_final`` dimensions (see :meth:`_refine`);
      7.5.2 blames the small ``k <= 10`` for the loss of local accuracy.
    - ``polish_k`` (default None: off; an extension): after the orientation check, the returned
      map is refined once more, as ``k_final`` does, from the embedding's ``K`` to ``polish_k``
      cotangent Laplace-Beltrami eigenvectors (with the mass matrix), whatever ``spectrum`` is:
      the thesis's graph Laplacian is the embedding EM needs, but its high frequencies follow the
      mesh's edge lengths more than the surface (FAUST development pairs, ``polish_k=100`` after
      ``k_final=40`` on the graph: 0.036 -> 0.018 on tr_reg_033-039, 0.027 -> 0.016 on 012-015).
      Refining the EM map on the Laplace-Beltrami basis *before* the orientation check instead
      was tried and lost a local side repair (033-039: 0.091). The returned ``target_of`` is the
      polished map; ``Q``, ``sigma`` and the posteriors describe EM's fit before polishing
      (``info["posteriors_of"] = "em-before-polish"``; without polishing ``"target_of"``).
    - preset ``thesis``: ``spectrum="graph", scaling="commute-time", dimension="scree", k=10``.

    ``orientation`` (``"preserving"`` default, ``"reversing"``, ``"none"``): EM is intrinsic, so
    a map and its mirror image fit equally well, and on articulated bodies EM can also settle on a
    map that is right on some parts and mirrored on others (FAUST humans: legs swapped). The side
    is decided against an orientation-aware functional map, the yardstick of
    :func:`~shape_toolkit.plugins.matching._common.side_reference` (Ren et al. 2018's
    orientation term, outward normals): each source vertex ``x`` takes, from the map ``T(x)`` and
    its mirror image ``T(S(x))`` (``S`` the source's intrinsic symmetry,
    :func:`~shape_toolkit.plugins.matching._common.symmetry_map`), the one nearer the reference,
    decided per region (the difference of squared spectral distances low-pass filtered on the
    source's first 20 eigenfunctions). Where the reference prefers the mirror image but ``S`` fails
    :func:`~shape_toolkit.plugins.matching._common.symmetry_validity` (a part ``S`` does not map onto its
    twin), and where neither ``T`` nor ``T(S)`` is near the reference while ``T`` piles two parts onto
    one, the reference's own map ``R(x)`` is taken instead. When any region changes, that combined map (refined when
    ``k_final`` is set) and EM run again from it are candidates next to the first map, and the one
    nearest the reference on average wins. ``info``: ``orientation_mirrored_area`` (share of the
    source's area that the reference puts on the other side), ``orientation_reference`` (mean
    squared distances of the candidates), ``orientation_flipped`` (False, ``"all"`` when more
    than half the area swapped, ``"local"``) and ``orientation_score`` -- the local triple-product
    cue of :func:`~shape_toolkit.plugins.matching._common.orientation_score` on 120 farthest-point
    samples of the map refined to 30 dimensions. Per region it does not decide (on FAUST a limb
    twisted on its axis scores against a map that is right on that limb); on the whole, a map whose
    score is still negative after the side check is usually a mirror image, and :meth:`_rescue`
    replaces it by one that scores positive (``info["orientation_rescue"]``). The matchers' spectra are
    declared through ``spectrum_specs()``.
    """

    presets = {
        "thesis": {"spectrum": "graph", "scaling": "commute-time", "dimension": "scree", "k": 10},
    }
    parameter_constraints = {
        "k": Param(Interval(int, 1, 100), doc="embedding dimension"),
        "outlier_weight": Param(Interval(float, 0, 1, closed="left"), doc="weight of the uniform outlier class"),
        "n_neighbors": Param(POSITIVE_INT, doc="target neighbours of each source point in the E-step"),
        "max_iter": Param(POSITIVE_INT, doc="EM iterations"),
        "tol": Param(NON_NEGATIVE, doc="stop when the variance changes less than this"),
        "threshold": Param(FRACTION, doc="posterior below which a vertex stays unmatched"),
        "one_to_one": Param(bool, doc="keep one source vertex per target vertex"),
        "fill_unmatched": Param(bool, doc="give unmatched vertices their nearest neighbour"),
        "spectrum": Param(Options("lbo", "graph"), doc="embedding eigenvectors: Laplace-Beltrami or graph"),
        "weighting": Param(None, str, doc="weighting of the graph spectrum (None: the default)"),
        "scaling": Param(Options("none", "commute-time"), doc="scaling of the embedding"),
        "dimension": Param(Options("fixed", "scree"), doc="embedding dimension: k, or the scree rule"),
        "dimension_threshold": Param(Interval(float, 0, 1, closed="neither"), doc="level of the scree rule"),
        "orientation": ORIENTATION,
        "k_final": Param(None, Interval(int, None, 200), doc="refine the map up to this many eigenvectors"),
        "refine_step": Param(POSITIVE_INT, doc="eigenvectors added per refinement step"),
        "max_samples": Param(None, POSITIVE_INT, doc="target points EM samples (None: all)"),
        "refine_samples": Param(None, POSITIVE_INT, doc="target points of the refinement (None: all)"),
        "polish_k": Param(None, Interval(int, 1, 200), doc="final Laplace-Beltrami refinement size (None: off)"),
        "random_state": RANDOM_STATE,
    }

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
        spectrum: str = "lbo",
        weighting: str | None = None,
        scaling: str = "none",
        dimension: str = "fixed",
        dimension_threshold: float = 0.95,
        orientation: str = "preserving",
        k_final: int | None = None,
        refine_step: int = 4,
        max_samples: int | None = None,
        refine_samples: int | None = 5000,
        polish_k: int | None = None,
        random_state: Any = 0,
    ):
        self.k = k
        self.outlier_weight = outlier_weight
        self.n_neighbors = n_neighbors
        self.max_iter = max_iter
        self.tol = tol
        self.threshold = threshold
        self.one_to_one = one_to_one
        self.fill_unmatched = fill_unmatched
        self.spectrum = spectrum
        self.weighting = weighting
        self.scaling = scaling
        self.dimension = dimension
        self.dimension_threshold = dimension_threshold
        self.orientation = orientation
        self.k_final = k_final
        self.refine_step = refine_step
        self.max_samples = max_samples
        self.refine_samples = refine_samples
        self.polish_k = polish_k
        self.random_state = random_state

    def _check(self) -> None:
        self._validate_params()
        check_random_state(self.random_state)

    #: embedding size of the refined maps the orientation is scored on (see :meth:`_orientation`)
    ORIENTATION_K = 30

    def _k_needed(self) -> int:
        extra = self.ORIENTATION_K if self.orientation != "none" else 0
        return int(max(self.k, self.k_final or 0, extra))

    def spectrum_specs(self) -> list[SpectrumSpec]:
        """The embedding's spectrum, the polishing one (``polish_k``: ``polish_k + 1`` cotangent
        Laplace-Beltrami eigenpairs) and the nested side, symmetry and fine matchers', one per kind."""
        specs = super().spectrum_specs()
        if self.polish_k:
            specs = type(specs[0]).merge_all([*specs, default_spec(int(self.polish_k) + 1)])
        return specs

    def _polish(self, t: np.ndarray, K: int, source, target, source_spectrum, target_spectrum) -> np.ndarray:
        """``polish_k``: the returned map ``t`` refined on the cotangent Laplace-Beltrami bases from
        ``K`` to ``polish_k`` eigenvectors (:meth:`_refine`)."""
        spec = default_spec(int(self.polish_k) + 1)

        def one(shape, given):
            if given is None:
                return spec.compute(shape)
            return spec.pick(given if isinstance(given, (list, tuple)) else [given], shape, type(self).__name__)

        bs, bt = basis_of(one(source, source_spectrum)), basis_of(one(target, target_spectrum))
        return self._refine(t, bs, bt, K, int(self.polish_k))

    def spectrum_spec(self) -> SpectrumSpec:
        """``max(k, k_final) + 1`` eigenpairs (the first is constant) of the Laplace-Beltrami operator
        (``spectrum="lbo"``) or of the combinatorial graph Laplacian ``D - W`` without mass
        (``spectrum="graph"``, weighting ``weighting`` or Gaussian)."""
        extra = {"weighting": self.weighting} if self.weighting else {}
        if self.spectrum == "graph":
            return default_spec(self._k_needed() + 1, "graph", **{"use_mass": False, **extra})
        return default_spec(self._k_needed() + 1, **extra)

    def _bases(self, source, target, source_spectrum, target_spectrum) -> tuple[Basis, Basis]:
        spec_s = self._spectrum(source, source_spectrum)
        spec_t = self._spectrum(target, target_spectrum)
        k = self._k_needed() + 1
        return basis_of(spec_s, k), basis_of(spec_t, k)

    @staticmethod
    def _shared_dimension(K: int, bs: Basis, bt: Basis) -> int:
        """``K`` capped to the non-constant eigenvectors both bases have: one embedding size for both
        shapes (a mesh of ``n`` vertices has at most ``n - 1`` of them, so a 3-vertex mesh against a
        4-vertex one embeds in 2 dimensions; unequal sizes made the histogram alignment index past
        its ``(k, k)`` matrix, an IndexError). :class:`InvalidShapeError` when a shape has none."""
        k = int(min(K, bs.k - 1, bt.k - 1))
        if k < 1:
            which = "source" if bs.k <= bt.k else "target"
            raise InvalidShapeError(
                f"the {which} shape has {min(bs.k, bt.k)} Laplacian eigenvector(s), only the constant one: "
                "a spectral embedding needs at least 2 vertices joined by an edge"
            )
        return k

    def _dimension(self, bs: Basis, bt: Basis, n_s: int, n_t: int) -> int:
        if self.dimension == "fixed":
            return int(self.k)
        from shape_toolkit.features.embedding import theta_min

        k = int(self.k)
        for K in range(3, k + 1):  # the rule on both shapes: the larger K serves both
            if min(theta_min(bs.evals, K, n_s), theta_min(bt.evals, K, n_t)) >= self.dimension_threshold:
                return K
        return k

    def _embed(self, b: Basis, K: int) -> np.ndarray:
        X = b.evecs[:, 1 : K + 1]
        if self.scaling == "commute-time":
            X = X / np.sqrt(np.maximum(b.evals[1 : K + 1], 1e-300))[None, :]
        return X

    def _embeddings(self, source, target, source_spectrum, target_spectrum, with_bases: bool = False):
        bs, bt = self._bases(source, target, source_spectrum, target_spectrum)
        K = self._shared_dimension(self._dimension(bs, bt, source.n_vertices, target.n_vertices), bs, bt)
        if with_bases:
            return self._embed(bs, K), self._embed(bt, K), bs, bt
        return self._embed(bs, K), self._embed(bt, K)

    def _refine(self, t: np.ndarray, bs: Basis, bt: Basis, K: int, k_final: int | None = None,
                rows: np.ndarray | None = None) -> np.ndarray:
        """Coarse-to-fine extension (``k_final``): the hard map re-estimated while the embedding
        grows from ``K`` to ``k_final`` by ``refine_step`` -- at each size, the orthogonal ``Q``
        of the current map by mass-weighted Procrustes (the M-step of Algorithm 7 with hard
        posteriors), then nearest neighbours (the assignment step), on the unscaled eigenvectors.
        The map keeps the orientation found by EM.

        Intermediate steps use a uniform sample of ``refine_samples`` source vertices (all when
        there are fewer); the last step maps the source vertices ``rows`` (None: all). The other
        entries of the returned map are those of ``t`` or of an intermediate step: only ``rows``
        are refined."""
        kf = int(min(self.k_final if k_final is None else k_final, bs.k - 1, bt.k - 1))
        n = len(t)
        sample = self._sample(n, self.refine_samples)
        k = K
        t = np.array(t, dtype=np.int64)
        while k < kf:
            k = min(k + int(self.refine_step), kf)
            Xs, Yt = bs.evecs[:, 1 : k + 1], bt.evecs[:, 1 : k + 1]  # unscaled: every frequency counts
            use = slice(None) if sample is None else sample
            Q = procrustes(Yt[t[use]].T @ (bs.mass[use, None] * Xs[use]))
            q = (slice(None) if rows is None else rows) if k >= kf else use
            t[q] = _nearest(Yt, Xs[q] @ Q.T)
        return t

    def _sample(self, n: int, size: int | None) -> np.ndarray | None:
        """Sorted uniform sample of ``size`` of ``n`` ids (``random_state``), None when ``size >= n``."""
        if size is None or n <= int(size):
            return None
        return np.sort(check_random_state(self.random_state).choice(n, int(size), replace=False))

    def _initial_transform(self, X, Y, seeds, source, target, **kw) -> np.ndarray:
        if seeds is None or len(seeds) == 0:
            raise ParameterError(
                "em-registration needs seed matches to initialize (e.g. from seed-growing); "
                "use eigvec-alignment for an unsupervised start"
            )
        return procrustes(Y[seeds[:, 1]].T @ X[seeds[:, 0]])

    def _em(self, X, Y, Q0):
        return em_register(
            X, Y, Q0, outlier_weight=self.outlier_weight, n_neighbors=self.n_neighbors,
            max_iter=self.max_iter, tol=self.tol, max_samples=self.max_samples,
            random_state=self.random_state,
        )

    def _solve(self, X, Y, Q0, bases):
        """EM from ``Q0``, the hard map of section 7.5 (filled, refined): ``(Q, sigma, P, t, conf, n_conf)``."""
        Q, sigma, P = self._em(X, Y, Q0)
        t, conf = hard_map(P, self.threshold, self.one_to_one)
        n_confident = int((t >= 0).sum())
        if self.fill_unmatched:
            miss = np.flatnonzero(t < 0)
            if miss.size:
                _, j = cKDTree(Y).query(X[miss] @ Q.T, k=1)
                t[miss] = j
                conf[miss] = 0.0
            if self.k_final and bases is not None and self.k_final > X.shape[1]:
                t = self._refine(t, bases[0], bases[1], X.shape[1])
        return Q, sigma, P, t, conf, n_confident

    @staticmethod
    def _orientation_rows(source: Shape) -> np.ndarray:
        from shape_toolkit.plugins.matching.dense.fmap_zoomout import farthest_point_sampling

        return farthest_point_sampling(np.asarray(source.vertices), min(120, source.n_vertices))

    def _orientation(self, source: Shape, target: Shape, t: np.ndarray, bases=None, K: int = 0) -> float:
        """Signed :func:`orientation_score` of the map ``t`` on 120 farthest-point samples of the
        source (spacing ~ 10 % of the shape's size: local enough for articulations, coarse enough
        for the map's local noise); unmatched samples are skipped. With ``bases``, the map is
        first refined to ``ORIENTATION_K`` dimensions (:meth:`_refine`; only for scoring: a coarse
        EM map is too noisy locally for its triplets to vote reliably)."""
        from shape_toolkit.plugins.matching._common import orientation_score

        rows = self._orientation_rows(source)
        if bases is not None and 0 < K < self.ORIENTATION_K and np.all(t >= 0):
            t = self._refine(t, bases[0], bases[1], K, self.ORIENTATION_K, rows=rows)
        rows = rows[t[rows] >= 0]
        want = 1.0 if self.orientation == "preserving" else -1.0
        return want * orientation_score(source, target, np.column_stack([rows, t[rows]]))

    def _nested_plugins(self) -> list:
        from shape_toolkit.plugins.matching._common import fine_matcher, side_matcher, symmetry_matcher

        if self.orientation == "none":
            return []
        return [symmetry_matcher(), side_matcher(self.orientation), fine_matcher(self.orientation)]

    def _orient(self, X, Y, first, source: Shape, target: Shape, info: dict, bases, source_spectrum,
                target_spectrum=None):
        """Orientation check of the class docstring: the chosen :meth:`_solve` result."""
        from shape_toolkit.plugins.matching._common import side_reference, symmetry_map, symmetry_validity

        K = X.shape[1]
        ref = side_reference(source, target, source_spectrum, target_spectrum, self.orientation)
        t = first[3]
        sym = symmetry_map(source, source_spectrum)
        valid = symmetry_validity(source, sym, ref.basis, ref.k_smooth)
        area = ref.basis.mass.sum()
        info["orientation_symmetry_valid_area"] = float(ref.basis.mass[valid].sum() / area)
        swap = ref.prefer(t, np.where(valid, t[sym], -1))
        info["orientation_mirrored_area"] = float(ref.basis.mass[swap].sum() / area)
        t_c = np.where(swap, t[sym], t)
        # neither T nor T(S) where the reference is, and T piles two parts onto one: a wrong part
        # (where T is one-to-one the reference may be the one that is wrong); and the parts the
        # reference puts on the other side where S is no symmetry (its mirror image cannot be trusted)
        lost = (ref.disagrees(t_c) & ref.overlaps(t_c)) | (ref.prefer(t, t[sym]) & ~valid)
        info["orientation_replaced_area"] = float(ref.basis.mass[lost].sum() / area)
        info["orientation_flipped"] = False
        if not swap.any() and not lost.any():
            return first
        # the parts the reference puts on the other side take their mirror image T(S(x)), the parts
        # neither agrees with take the reference's own map R(x): that map (refined when k_final is
        # set) and EM run again from it (EM smooths the seams, but may fall back to the first map)
        # are candidates; the one that agrees best with the reference wins
        t_c = np.where(lost, ref.target_of, t_c)
        ok = t_c >= 0
        Qc = procrustes(Y[t_c[ok]].T @ X[ok])
        if self.k_final and bases is not None and self.k_final > K and ok.all():
            t_c = self._refine(t_c, bases[0], bases[1], K)
        cands = {"first": first, "combined": (Qc, first[1], first[2], t_c, np.zeros(len(t_c)), 0),
                 "em_again": self._solve(X, Y, Qc, bases)}
        errs = {name: ref.mean_sq_distance(c[3]) for name, c in cands.items()}
        info["orientation_reference"] = errs
        best = min(errs, key=errs.get)
        info["orientation_choice"] = best
        if best == "first":
            return first
        info["orientation_flipped"] = "all" if info["orientation_mirrored_area"] > 0.5 else "local"
        return cands[best]

    def _rescue(self, X, Y, first, source: Shape, target: Shape, info: dict, bases, source_spectrum,
                target_spectrum=None) -> tuple[tuple, int]:
        """The orientation rescue: the map after the side check still reverses orientation on the whole
        (local triple products, :meth:`_orientation`, below zero; the true map scores near +1). Usually EM
        settled on a mirror image the side check could not undo -- left and right (the side reference
        itself mirrored) or front and back (a reflection no intrinsic symmetry map describes) -- but an
        imperfect map that is on the right side can score below zero too (twisted limbs), so this is a
        replacement by a map that scores positive, not a proof. The candidates, in this order: EM run
        again from the side reference's map, EM run again from
        :func:`~shape_toolkit.plugins.matching._common.fine_matcher`'s orientation-aware functional map,
        then those two maps themselves; the first whose score is positive replaces the first map (none:
        it stays). EM's results come first (the thesis's method), the reference before the finer map (the
        map every side decision of the pipeline follows; on a coarse synthetic pair the finer one is wrong).
        A positive score does not prove a map right (a left-right *and* front-back swap preserves
        orientation), so the order matters.

        Returns the chosen result and the embedding size it is already refined to (``polish_k`` goes on
        from there: polishing a functional map's map again from EM's few dimensions would undo it). When a
        functional map's own map is chosen, ``Q``, ``sigma`` and the posteriors stay those of EM's first
        run (``info["posteriors_of"] = "em-before-rescue"``) and every vertex is matched (confidence 0).
        ``info["orientation_rescue"]``: the scores, the choice."""
        from shape_toolkit.plugins.matching._common import _given, fine_matcher, side_reference

        K = X.shape[1]
        rescue = {"score_before": info["orientation_score"], "choice": "first"}
        info["orientation_rescue"] = rescue
        starts: dict[str, tuple[np.ndarray, int]] = {}

        def start(name: str) -> tuple[np.ndarray, int]:
            if name not in starts:
                if name == "reference_map":
                    ref = side_reference(source, target, source_spectrum, target_spectrum, self.orientation)
                    starts[name] = (np.asarray(ref.target_of), int(ref.source_points.shape[1]))
                else:
                    m = fine_matcher(self.orientation)
                    ss = m._spectrum(source, _given(source_spectrum))
                    st = m._spectrum(target, _given(target_spectrum))
                    res = m.match(source, target, source_spectrum=[ss], target_spectrum=[st])
                    starts[name] = (np.asarray(res.target_of), int(res.info["k_final"]))
            return starts[name]

        for name in ("em_from_reference_map", "em_from_fine_map", "reference_map", "fine_map"):
            t, k_map = start(name.removeprefix("em_from_"))
            ok = t >= 0
            Q = procrustes(Y[t[ok]].T @ X[ok])
            if name.startswith("em_from_"):
                cand, k_done = self._solve(X, Y, Q, bases), K
                score = self._orientation(source, target, cand[3], bases, K)
            else:  # a functional map's own map is already fine: scored as it is
                cand, k_done = (Q, first[1], first[2], t, np.zeros(len(t)), 0), k_map
                score = self._orientation(source, target, t)
            rescue[f"score_{name}"] = score
            if score > 0:
                rescue["choice"] = name
                info["orientation_score"] = score
                if not name.startswith("em_from_"):
                    info["posteriors_of"] = "em-before-rescue"
                return cand, k_done
        return first, K

    def _finish(self, X, Y, Q0, target: Shape, info: dict, source: Shape | None = None,
                bases: tuple[Basis, Basis] | None = None, source_spectrum=None,
                target_spectrum=None) -> Correspondence:
        res = self._solve(X, Y, Q0, bases)
        k_done = X.shape[1]  # the embedding size the returned map is refined to (polish_k goes on from it)
        if self.orientation != "none" and source is not None and source.is_mesh and target.is_mesh:
            res = self._orient(X, Y, res, source, target, info, bases, source_spectrum, target_spectrum)
            info["orientation_score"] = self._orientation(source, target, res[3], bases, X.shape[1])
            if info["orientation_score"] < 0:
                res, k_done = self._rescue(X, Y, res, source, target, info, bases, source_spectrum,
                                           target_spectrum)
        Q, sigma, P, t, conf, n_confident = res
        # (a functional map's map the rescue chose may already be finer than polish_k: nothing to polish)
        if self.polish_k and k_done < self.polish_k and source is not None and self.fill_unmatched \
                and np.all(t >= 0):
            t = self._polish(t, k_done, source, target, source_spectrum, target_spectrum)
            info["polish_k"] = int(self.polish_k)
            # Q, sigma and P are EM's, not the polished map's
            info.setdefault("posteriors_of", "em-before-polish")
        if self.k_final and bases is not None and self.k_final > X.shape[1] and self.fill_unmatched:
            info["k_final"] = int(min(self.k_final, bases[0].k - 1, bases[1].k - 1))
        info.setdefault("posteriors_of", "target_of")
        info.update({"Q": Q, "sigma": sigma, "n_confident": n_confident, "embedding_dim": int(X.shape[1]),
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
        X, Y, bs, bt = self._embeddings(source, target, source_spectrum, target_spectrum, with_bases=True)
        Q0 = self._initial_transform(X, Y, seeds, source, target)
        info = {"n_seeds": 0 if seeds is None else len(seeds)}
        return self._finish(X, Y, Q0, target, info, source, (bs, bt), source_spectrum, target_spectrum)
