"""Dense probabilistic matching by EM registration of spectral embeddings (thesis Algorithm 7, section 7.4.1;
Horaud et al. 2011). The source embedding points ``x_i`` (first ``k`` non-null Laplace-Beltrami eigenvectors,
area normalized) are the means of an isotropic Gaussian mixture with a uniform outlier class; the target
embedding points ``x'_j`` are the data. EM estimates an orthogonal ``k x k`` transform ``Q`` (eigenvector
signs, order and mixing) and the variance ``sigma`` (eq. 7.1-7.3). Memory stays linear: the E-step keeps the
``n_neighbors`` nearest source means of each target point; the posteriors are a sparse ``(n_src, n_tgt)``
matrix of ``P(source i | target j)`` (columns sum to at most 1; the rest is the outlier class).
Orientation repair: :mod:`.orientation_repair`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from shape_toolkit.api.interfaces import DenseMatcher, merge_specs
from shape_toolkit.api.params import RANDOM_STATE, InstanceOf, Interval, Options, Param
from shape_toolkit.core.geometry import nearest_neighbors
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.errors import InvalidShapeError, ParameterError
from shape_toolkit.features.basis import Basis, basis_of
from shape_toolkit.plugins._params import FRACTION, NON_NEGATIVE, ORIENTATION, POSITIVE_INT
from shape_toolkit.plugins.matching.dense.orientation_repair import ORIENTATION_K, OrientationRepair
from shape_toolkit.plugins.matching.em import em_register, procrustes
from shape_toolkit.plugins.matching.validation import check_seeds
from shape_toolkit.results.correspondence import Correspondence
from shape_toolkit.spectra import SpectrumSpec, default_spec
from shape_toolkit.validation import check_random_state

__all__ = ["EMFit", "EMRegistrationMatcher", "Embedding", "em_register", "hard_map", "procrustes"]

#: most EM iterations (``max_iter``'s doc)
MAX_ITER = 1000


def _nearest(points: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Index of the nearest of ``points`` ``(m, d)`` for each query ``(q, d)``: int64 ``(q,)``; in
    high dimension a single-precision brute force in chunks of at most ``2**23`` distances (never
    ``q x m``; near-ties within ~1e-6 relative may resolve differently from double precision)."""
    chunk = int(np.clip(2**23 // max(1, len(points)), 16, 1024))
    return np.asarray(nearest_neighbors(points, queries, k=1, chunk=chunk, dtype=np.float32)[1], dtype=np.int64)


def hard_map(P: sp.csr_matrix, threshold: float = 0.5, one_to_one: bool = False) -> tuple[np.ndarray, np.ndarray]:
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


@dataclass
class EMFit:
    """One EM registration (Algorithm 7) and its hard map (section 7.5): the orthogonal ``Q`` ``(K, K)``
    (target points ~ ``Q`` times source points), the variance ``sigma`` (squared embedding units), the
    ``posteriors`` CSR ``(n_src, n_tgt)`` of ``P(source i | target j)``, ``target_of`` int64 ``(n_src,)``
    (-1: unmatched), ``confidence`` ``(n_src,)`` (largest posterior; 0 for a filled or replaced match) and
    ``n_confident``, the source vertices matched above ``threshold``."""

    Q: np.ndarray
    sigma: float
    posteriors: sp.csr_matrix | None
    target_of: np.ndarray
    confidence: np.ndarray
    n_confident: int


@dataclass
class Embedding:
    """What EM registers: source ``X`` ``(n, K)``, target ``Y`` ``(n', K)``, their bases (None: no refinement)."""

    X: np.ndarray
    Y: np.ndarray
    bases: tuple[Basis, Basis] | None = None

    @property
    def K(self) -> int:
        """The embedding dimension."""
        return int(self.X.shape[1])


class EMRegistrationMatcher(DenseMatcher):
    """Algorithm 7: EM registration of the ``k``-dimensional Laplacian embeddings, started by orthogonal
    Procrustes on the ``seeds`` (required; e.g. seed growing's map). Returns section 7.5's hard map (largest
    posterior above ``threshold``, optionally ``one_to_one``; ``fill_unmatched``: the others get the target
    nearest their transformed point, confidence 0) and sparse posteriors (``n_neighbors`` per target vertex).
    Embedding (7.4.1): ``spectrum`` ``"lbo"`` or ``"graph"`` (``D - W``, ``weighting``, no mass: eq. 6.24),
    ``scaling`` (commute-time: eq. 2.92), ``dimension`` fixed or by the scree rule (eq. 2.97-2.99). Preset
    ``thesis`` is 7.4.1 as written (Gaussian graph, t = 0, scree ``k <= 10``, posterior > 0.5 or unmatched, no
    orientation repair); ``topo-robust`` adds commute-time scaling. Extensions: ``k_final`` refines the map while
    the embedding grows (7.5.2 blames small ``k``), ``polish_k`` on the Laplace-Beltrami basis; ``max_samples``
    and ``refine_samples`` bound the work on large shapes.

    EM cannot tell a map from its mirror image: unless ``orientation`` is ``"none"``, :meth:`match` runs inside
    :class:`~shape_toolkit.plugins.matching.dense.orientation_repair.OrientationRepair` (the pipelines'
    ``[orient]`` stage) with ``landmarks`` (None: the seeds when ``trust_seeds``). Measurements: ``benchmarks/
    results/em_registration_notes.md``."""

    presets = {"thesis": {"spectrum": "graph", "weighting": "gaussian", "scaling": "none", "dimension": "scree",
                          "k": 10, "threshold": 0.5, "fill_unmatched": False, "orientation": "none"},
               "topo-robust": {"spectrum": "graph", "scaling": "commute-time", "dimension": "scree", "k": 10}}
    parameter_constraints = {
        "k": Param(Interval(int, 1, 100), doc="embedding dimension"),
        "outlier_weight": Param(Interval(float, 0, 1, closed="left"), doc="weight of the uniform outlier class"),
        "n_neighbors": Param(POSITIVE_INT, doc="target neighbours of each source point in the E-step"),
        "max_iter": Param(Interval(int, 1, MAX_ITER), doc="EM iterations (at most 1000, 20x the default: EM "
                          "converges linearly, to rounding (changes ~1e-15) within 100-200 iterations on TOSCA cats "
                          "and spheres, after which the iterations only repeat rounding, and tol 0 never stops them; "
                          "each is a k-d tree query of every target point, 25 ms on 5,000 vertices)"),
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
        "trust_seeds": Param(bool, doc="the seeds are right (a user's): they decide the sides; False: they only "
                             "start the registration (a pipeline's dense map)"),
        "landmarks": Param(None, InstanceOf(np.ndarray, list, tuple), doc="right matches (q, 2) deciding the sides"),
        "k_final": Param(None, Interval(int, None, 200), doc="refine the map up to this many eigenvectors"),
        "refine_step": Param(POSITIVE_INT, doc="eigenvectors added per refinement step"),
        "max_samples": Param(None, POSITIVE_INT, doc="target points EM samples (None: all)"),
        "refine_samples": Param(None, POSITIVE_INT, doc="target points of the refinement (None: all)"),
        "polish_k": Param(None, Interval(int, 1, 200), doc="final Laplace-Beltrami refinement size (None: off)"),
        "random_state": RANDOM_STATE,
    }

    def __init__(
        self, k: int = 8, outlier_weight: float = 0.1, n_neighbors: int = 10, max_iter: int = 50, tol: float = 1e-5,
        threshold: float = 0.5, one_to_one: bool = False, fill_unmatched: bool = True, spectrum: str = "lbo",
        weighting: str | None = None, scaling: str = "none", dimension: str = "fixed",
        dimension_threshold: float = 0.95, orientation: str = "preserving", k_final: int | None = None,
        refine_step: int = 4, max_samples: int | None = None, refine_samples: int | None = 5000,
        polish_k: int | None = None, random_state: Any = 0, trust_seeds: bool = True, landmarks: Any = None,
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
        self.trust_seeds, self.landmarks = trust_seeds, landmarks

    def _check(self) -> None:
        self._validate_params()
        check_random_state(self.random_state)

    def _k_needed(self, min_dim: int = 0) -> int:
        extra = ORIENTATION_K if self.orientation != "none" else 0  # the orientation repair scores in 30 dimensions
        return int(max(self.k, self.k_final or 0, extra, min_dim))

    def _nested_plugins(self) -> list:
        return OrientationRepair(orientation=self.orientation).reference_plugins()

    def spectrum_specs(self) -> list[SpectrumSpec]:
        """The embedding's spectrum, the polishing one (``polish_k``: ``polish_k + 1`` cotangent
        Laplace-Beltrami eigenpairs) and the nested side, symmetry and fine matchers', one per kind."""
        specs = super().spectrum_specs()
        if self.polish_k:
            specs = merge_specs([*specs, default_spec(int(self.polish_k) + 1)])
        return specs

    def _polish(self, t: np.ndarray, K: int, source, target, source_spectrum, target_spectrum) -> np.ndarray:
        """``polish_k``: ``t`` refined on the cotangent Laplace-Beltrami bases from ``K`` to ``polish_k``."""
        spec = default_spec(int(self.polish_k) + 1)
        bs = basis_of(self._given(spec, source, source_spectrum))
        bt = basis_of(self._given(spec, target, target_spectrum))
        return self._refine(t, bs, bt, K, int(self.polish_k))

    def spectrum_spec(self) -> SpectrumSpec:
        """The embedding's spectrum (:meth:`embedding_spec`)."""
        return self.embedding_spec()

    def embedding_spec(self, min_dim: int = 0) -> SpectrumSpec:
        """``max(k, k_final, min_dim) + 1`` eigenpairs (the first is constant; ``min_dim`` 30 with orientation
        repair) of the Laplace-Beltrami operator (``spectrum="lbo"``) or of the combinatorial graph Laplacian
        ``D - W`` without mass (``spectrum="graph"``, weighting ``weighting`` or Gaussian)."""
        extra = {"weighting": self.weighting} if self.weighting else {}
        if self.spectrum == "graph":
            return default_spec(self._k_needed(min_dim) + 1, "graph", **{"use_mass": False, **extra})
        return default_spec(self._k_needed(min_dim) + 1, **extra)

    def _given(self, spec: SpectrumSpec, shape: Shape, given: Spectrum | list[Spectrum] | None) -> Spectrum:
        """The spectrum of ``spec`` among ``given`` (one or several), checked; computed when None."""
        if given is None:
            return spec.compute(shape)
        if isinstance(given, (list, tuple)):
            return spec.pick(given, shape)
        return spec.check(given, shape, who=type(self).__name__)

    def _bases(self, source, target, source_spectrum, target_spectrum, min_dim: int = 0) -> tuple[Basis, Basis]:
        spec = self.embedding_spec(min_dim)
        s, t = self._given(spec, source, source_spectrum), self._given(spec, target, target_spectrum)
        return basis_of(s, spec.k), basis_of(t, spec.k)

    @staticmethod
    def _shared_dimension(K: int, bs: Basis, bt: Basis) -> int:
        """``K`` capped to the non-constant eigenvectors both bases have (at most ``n - 1``): one embedding
        size for both shapes. :class:`InvalidShapeError` when a shape has none."""
        k = int(min(K, bs.k - 1, bt.k - 1))
        if k < 1:
            which = "source" if bs.k <= bt.k else "target"
            raise InvalidShapeError(f"the {which} shape has {min(bs.k, bt.k)} Laplacian eigenvector(s), only the "
                                    "constant one: a spectral embedding needs at least 2 vertices joined by an edge")
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

    def embedding(self, source: Shape, target: Shape, source_spectrum=None, target_spectrum=None,
                  min_dim: int = 0) -> Embedding:
        """The embeddings of section 7.4.1 and their bases (at least ``min_dim + 1`` eigenpairs)."""
        bs, bt = self._bases(source, target, source_spectrum, target_spectrum, min_dim)
        K = self._shared_dimension(self._dimension(bs, bt, source.n_vertices, target.n_vertices), bs, bt)
        return Embedding(self._embed(bs, K), self._embed(bt, K), (bs, bt))

    def _refine(self, t: np.ndarray, bs: Basis, bt: Basis, K: int, k_final: int | None = None,
                rows: np.ndarray | None = None) -> np.ndarray:
        """Coarse-to-fine extension (``k_final``): the hard map re-estimated while the embedding grows from
        ``K`` to ``k_final`` by ``refine_step`` (mass-weighted Procrustes, the M-step with hard posteriors, then
        nearest neighbours, on the unscaled eigenvectors); intermediate steps on ``refine_samples`` source
        vertices, the last on ``rows`` (None: all; other entries keep ``t`` or an intermediate step's)."""
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

    def initial_transform(self, emb: Embedding, seeds: np.ndarray | None) -> np.ndarray:
        """Orthogonal Procrustes ``(K, K)`` on the seed matches ``(q, 2)``."""
        if seeds is None or len(seeds) == 0:
            raise ParameterError("em-registration needs seed matches to initialize (e.g. from seed-growing); "
                                 "use eigvec-alignment for an unsupervised start")
        return procrustes(emb.Y[seeds[:, 1]].T @ emb.X[seeds[:, 0]])

    def start(self, source: Shape, target: Shape, seeds: np.ndarray | None, source_spectrum=None,
              target_spectrum=None, min_dim: int = 0) -> tuple[Embedding, np.ndarray, dict[str, Any]]:
        """The embedding (bases of at least ``min_dim`` dimensions), the initial ``Q0`` and the first ``info``."""
        self._check()
        seeds = check_seeds(seeds, source.n_vertices, target.n_vertices)
        emb = self.embedding(source, target, source_spectrum, target_spectrum, min_dim)
        return emb, self.initial_transform(emb, seeds), {"n_seeds": 0 if seeds is None else len(seeds)}

    def transform_of(self, emb: Embedding, target_of: np.ndarray) -> np.ndarray:
        """The orthogonal ``Q`` ``(K, K)`` of a map ``(n,)`` (Procrustes on its matched vertices)."""
        ok = target_of >= 0
        return procrustes(emb.Y[target_of[ok]].T @ emb.X[ok])

    def refines(self, emb: Embedding) -> bool:
        """Whether :meth:`solve` refines its map (``k_final`` above the embedding's size, bases known)."""
        return bool(self.k_final and emb.bases is not None and self.k_final > emb.K)

    def refine(self, emb: Embedding, t: np.ndarray, k_final: int | None = None,
               rows: np.ndarray | None = None) -> np.ndarray:
        """The map ``t`` ``(n,)`` refined on the embedding's bases to ``k_final`` (None: this matcher's)."""
        return self._refine(t, emb.bases[0], emb.bases[1], emb.K, k_final, rows=rows)

    def solve(self, emb: Embedding, Q0: np.ndarray) -> EMFit:
        """EM from ``Q0`` and the hard map of section 7.5 (filled and refined as the parameters ask)."""
        X, Y = emb.X, emb.Y
        Q, sigma, P = em_register(X, Y, Q0, outlier_weight=self.outlier_weight, n_neighbors=self.n_neighbors,
                                  max_iter=self.max_iter, tol=self.tol, max_samples=self.max_samples,
                                  random_state=self.random_state)
        t, conf = hard_map(P, self.threshold, self.one_to_one)
        n_confident = int((t >= 0).sum())
        if self.fill_unmatched:
            miss = np.flatnonzero(t < 0)
            if miss.size:
                _, j = cKDTree(Y).query(X[miss] @ Q.T, k=1)
                t[miss] = j
                conf[miss] = 0.0
            if self.refines(emb):
                t = self.refine(emb, t)
        return EMFit(Q, sigma, P, t, conf, n_confident)

    def finish(self, emb: Embedding, fit: EMFit, source: Shape, target: Shape, info: dict[str, Any],
               k_done: int | None = None, source_spectrum=None, target_spectrum=None) -> Correspondence:
        """The :class:`Correspondence` of ``fit``, polished (``polish_k``) from ``k_done`` dimensions (None: ``K``;
        a map already finer is not polished); ``Q``, ``sigma`` and the posteriors stay EM's."""
        k_done = emb.K if k_done is None else k_done
        t = fit.target_of
        if self.polish_k and k_done < self.polish_k and self.fill_unmatched and np.all(t >= 0):
            t = self._polish(t, k_done, source, target, source_spectrum, target_spectrum)
            info["polish_k"] = int(self.polish_k)
            info.setdefault("posteriors_of", "em-before-polish")
        if self.refines(emb) and self.fill_unmatched:
            info["k_final"] = int(min(self.k_final, emb.bases[0].k - 1, emb.bases[1].k - 1))
        info.setdefault("posteriors_of", "target_of")
        info.update({"Q": fit.Q, "sigma": fit.sigma, "n_confident": fit.n_confident, "embedding_dim": emb.K,
                     "posteriors": "P(source i | target j), columns sum <= 1"})
        return Correspondence(t, target.n_vertices, fit.confidence, fit.posteriors, info)

    def match(self, source: Shape, target: Shape, *, seeds: np.ndarray | None = None,
              source_spectrum: Spectrum | None = None, target_spectrum: Spectrum | None = None,
              source_descriptors: np.ndarray | None = None, target_descriptors: np.ndarray | None = None,
              n_times: int | None = None, progress: Callable[[str], None] | None = None) -> Correspondence:
        """Dense map source -> target with sparse posteriors (descriptors, ``n_times``, ``progress``: unused)."""
        self._check()
        if self.orientation != "none":
            landmarks = self.landmarks if self.landmarks is not None else seeds if self.trust_seeds else None
            return OrientationRepair(self, self.orientation, landmarks).match(
                source, target, seeds=seeds, source_spectrum=source_spectrum, target_spectrum=target_spectrum)
        emb, Q0, info = self.start(source, target, seeds, source_spectrum, target_spectrum)
        return self.finish(emb, self.solve(emb, Q0), source, target, info, None, source_spectrum, target_spectrum)
