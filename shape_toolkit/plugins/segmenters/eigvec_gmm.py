"""Unsupervised segmentation by eigenvector selection and Gaussian mixtures (thesis 4.3).

1. the first ``p`` non-null Laplacian eigenvectors ``u_2 .. u_{p+1}``;
2. for each one, drop the vertices whose value is near zero (the nodal set), fit 1D Gaussian
   mixtures with 1..``max_components_1d`` components and keep the one of lowest BIC, take the
   leftmost and rightmost components (smallest / largest mean);
3. keep the eigenvector when one of these outer clusters is a single connected component of the
   shape graph (a single nodal domain): this selects ``q <= p`` eigenvectors;
4. embed the shape in the selected eigenvectors and fit a ``q``-dimensional GMM (Mahalanobis
   distances instead of k-means' Euclidean ones) with ``k`` given, or chosen by BIC.

The thesis observed that on regularly connected shape graphs the BIC curve can keep improving
with ``k`` (no minimum, Fig. 4.4). When the BIC minimum falls on the last ``k`` tried, we say so
(``bic_monotone_ = True``) and take the knee of the curve instead (the ``k`` farthest below the chord
joining its end points), recorded in ``n_segments_rule_``; ``k_rule="bic-minimum"`` keeps the minimum.

Preset ``thesis`` (4.3-4.4): ``p = 10`` eigenvectors of the Gaussian graph's ``D - W`` (no mass), the strict
single-component test, full-covariance GMMs fitted on every vertex (MCLUST in the thesis; no subsample) and
``k`` at the BIC minimum, even when it is the last ``k`` tried (Fig. 4.4).
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from sklearn.exceptions import ConvergenceWarning
from sklearn.mixture import GaussianMixture

from shape_toolkit.api.params import RANDOM_STATE, Interval, Options, Param
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum, fix_signs, null_count
from shape_toolkit.errors import ParameterError
from shape_toolkit.plugins._params import LAPLACIAN, N_INIT, N_SEGMENTS, POSITIVE_INT, WEIGHTING
from shape_toolkit.plugins.segmenters.base import BaseSegmenter, segmenter_spec
from shape_toolkit.plugins.segmenters.kmeans import canonical_order, fit_predict_invariant, single_thread
from shape_toolkit.plugins.segmenters.n_segments import check_n_segments
from shape_toolkit.results.labels import relabel_consecutive
from shape_toolkit.results.segmentation import Segmentation
from shape_toolkit.spectra import SpectrumSpec, build_graph
from shape_toolkit.validation import seed_of


def _knee(ks: np.ndarray, values: np.ndarray) -> int:
    """The ``k`` whose value lies farthest below the chord from the first to the last point."""
    if len(ks) < 3:
        return int(ks[-1])
    x = (ks - ks[0]) / (ks[-1] - ks[0])
    span = values[0] - values[-1]
    y = (values - values[-1]) / span if span != 0 else np.zeros_like(values)
    # chord from (0, 1) to (1, 0): distance below it is proportional to 1 - x - y
    return int(ks[int(np.argmax(1.0 - x - y))])


class EigvecGMMSegmenter(BaseSegmenter):
    """Thesis 4.3: eigenvector selection by 1D GMMs at the extremities, then a ``q``-D GMM.

    Parameters: ``n_segments`` (None: chosen by BIC in ``[2, max_segments]``), ``n_eigenvectors``
    (``p``, default 10 as in 4.4), ``zero_threshold`` (vertices with ``|u| <= zero_threshold *
    max|u|`` are dropped before the 1D fits), ``max_components_1d``, ``min_component_fraction``
    (an outer cluster counts as one connected component when its largest component holds at
    least this fraction of it; 1.0 is the strict test of the thesis), ``laplacian`` (default
    combinatorial, as in 4.2; Fig. 4.1 used the normalized one, which selects fewer eigenvectors on
    the PSB meshes, ~5 of 10 as the thesis reports, but segmented them worse: mean Rand index error
    0.174 vs 0.162 over the 12 shared PSB meshes), ``weighting`` (Gaussian, 4.1.2),
    ``max_fit_samples_1d`` / ``max_fit_samples`` (the 1D fits / the BIC sweep use an evenly spaced
    subsample of at most this many vertices, taken in an order of the embedding values, not of the
    vertex ids; the final GMM uses all), ``random_state`` (the GMM initialisations).

    Vertex-order independent: the eigenvectors are sign-fixed, the subsamples are chosen by value and
    every GMM is fitted on the vertices in a canonical order of their embedding
    (:func:`~shape_toolkit.plugins.segmenters.kmeans.canonical_order`), so a permuted mesh gets the
    permuted labels (up to label names; exactly degenerate eigenvalues, as on symmetric shapes, leave
    the eigenbasis itself undetermined).

    Diagnostics of the last run: ``selected_eigenvectors_`` (1-based eigenvector indices,
    ``u_2`` = 2, as in the thesis), ``eigenvector_analysis_`` (per eigenvector: 1D components,
    sizes and component counts of the outer clusters, selected), ``selection_fallback_``,
    ``bic_curve_`` (``{k: BIC}``, sklearn's convention: lower is better; None when ``k`` is
    given), ``bic_monotone_``, ``n_segments_rule_``, ``n_segments_``.
    """

    split_clouds = True
    presets = {"thesis": {"n_eigenvectors": 10, "laplacian": "combinatorial", "weighting": "gaussian",
                          "min_component_fraction": 1.0, "covariance_type": "full", "k_rule": "bic-minimum",
                          "max_fit_samples_1d": 10**9, "max_fit_samples": 10**9}}
    parameter_constraints = {
        "n_segments": N_SEGMENTS,
        "n_eigenvectors": Param(POSITIVE_INT, doc="eigenvectors u_2 .. u_{p+1} clustered"),
        "zero_threshold": Param(Interval(float, 0, 1, closed="left"), doc="eigenvector values treated as zero"),
        "max_components_1d": Param(Interval(int, 1, 20),
                                   doc="GMM components tried per eigenvector; <= 20: only the two outer ones are used, "
                                       "MCLUST (the thesis's tool) tries 1 to 9, and each size is one more EM fit"),
        "min_component_fraction": Param(Interval(float, 0, 1, closed="right"), doc="smallest component kept"),
        "max_segments": Param(POSITIVE_INT, doc="most segments when n_segments is None"),
        "laplacian": LAPLACIAN,
        "weighting": WEIGHTING,
        "covariance_type": Param(Options("full", "diag", "tied", "spherical"), doc="GMM covariance"),
        "n_init": N_INIT,
        "max_fit_samples_1d": Param(POSITIVE_INT, doc="samples of each 1-D GMM fit"),
        "max_fit_samples": Param(POSITIVE_INT, doc="samples of the final GMM fit"),
        "random_state": RANDOM_STATE,
        "k_rule": Param(Options("knee", "bic-minimum"), doc="k when BIC keeps improving: the knee, or the minimum"),
    }

    def __init__(
        self,
        n_segments: int | None = None,
        *,
        n_eigenvectors: int = 10,
        zero_threshold: float = 0.05,
        max_components_1d: int = 6,
        min_component_fraction: float = 1.0,
        max_segments: int = 15,
        laplacian: str = "combinatorial",
        weighting: str = "gaussian",
        covariance_type: str = "full",
        n_init: int = 2,
        max_fit_samples_1d: int = 1500,
        max_fit_samples: int = 3000,
        random_state: int = 0,
        k_rule: str = "knee",
    ):
        self.k_rule = k_rule
        self.n_segments = n_segments
        self.n_eigenvectors = n_eigenvectors
        self.zero_threshold = zero_threshold
        self.max_components_1d = max_components_1d
        self.min_component_fraction = min_component_fraction
        self.max_segments = max_segments
        self.laplacian = laplacian
        self.weighting = weighting
        self.covariance_type = covariance_type
        self.n_init = n_init
        self.max_fit_samples_1d = max_fit_samples_1d
        self.max_fit_samples = max_fit_samples
        self.random_state = random_state

    def spectrum_spec(self) -> SpectrumSpec:
        """``n_eigenvectors + 1`` eigenpairs (the null one and ``u_2 .. u_{p+1}``) of the chosen
        Laplacian of the ``weighting`` graph, no mass matrix."""
        return segmenter_spec(int(self.n_eigenvectors) + 1, self.weighting, self.laplacian)

    def _check(self, n: int) -> tuple[int | None, int]:
        k = check_n_segments(self.n_segments, n, allow_none=True)
        p = int(self.n_eigenvectors)  # an int, as declared
        if not 1 <= p <= n - 1:
            raise ParameterError(f"n_eigenvectors must be an integer in [1, {n - 1}], got {p!r}")
        if k is None:
            check_n_segments(self.max_segments, n, allow_none=False)
        return k, p

    @staticmethod
    def _subsample(idx: np.ndarray, order_key: np.ndarray, m: int) -> np.ndarray:
        """At most ``m`` of ``idx``, evenly spaced along ``order_key`` ``(len(idx),)`` (a vertex-order
        independent ranking of them), returned in that ranking."""
        ranked = idx[np.argsort(order_key, kind="stable")]
        m = int(m)
        if m <= 0 or len(ranked) <= m:
            return ranked
        return ranked[np.round(np.linspace(0, len(ranked) - 1, m)).astype(np.int64)]

    def _outer_cluster_components(self, A: sp.csr_matrix, ids: np.ndarray) -> tuple[int, float]:
        """(number of connected components, fraction held by the largest) of vertex set ``ids``."""
        if len(ids) == 0:
            return 0, 0.0
        ncomp, lab = connected_components(A[ids][:, ids], directed=False)
        return int(ncomp), float(np.bincount(lab).max() / len(ids))

    def _segment(self, shape: Shape, *, spectrum: Spectrum | None, constraints: Any) -> Segmentation:
        """The segmentation of a shape of one piece (an unsupervised method: no constraints)."""
        with single_thread(), warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            return Segmentation.of_vertices(shape, self._labels(shape, spectrum))

    def _labels(self, shape: Shape, spectrum: Spectrum | None) -> np.ndarray:
        n = shape.n_vertices
        k, p = self._check(n)
        spectrum = self._spectrum(shape, spectrum)
        seed = seed_of(self.random_state)
        skip = max(null_count(spectrum.eigenvalues), 1)
        if skip > 1:
            raise ParameterError(
                f"the Laplacian has {skip} null eigenvalues: the shape graph is disconnected; "
                "segment each component (or clean the shape) first"
            )
        U = fix_signs(spectrum.eigenvectors[:, skip : skip + p])
        A = sp.csr_matrix(build_graph(shape, self.weighting).W)

        analysis = []
        selected = []
        for j in range(p):
            u = U[:, j]
            amax = float(np.abs(u).max())
            keep = np.flatnonzero(np.abs(u) > self.zero_threshold * amax)
            info: dict[str, Any] = {"eigenvector": j + skip + 1, "n_kept": int(len(keep))}
            if len(keep) < 2:
                info.update(n_components_1d=0, selected=False)
                analysis.append(info)
                continue
            x = (u / amax)[:, None]
            fit_ids = self._subsample(keep, x[keep, 0], self.max_fit_samples_1d)
            best, best_bic = None, np.inf
            for c in range(1, min(int(self.max_components_1d), len(fit_ids)) + 1):
                gm = GaussianMixture(c, random_state=seed, reg_covar=1e-6).fit(x[fit_ids])
                bic = gm.bic(x[fit_ids])
                if bic < best_bic - 1e-9:
                    best, best_bic = gm, bic
            comp = best.predict(x[keep])
            means = best.means_.ravel()
            outer = {"left": int(np.argmin(means)), "right": int(np.argmax(means))}
            info["n_components_1d"] = int(best.n_components)
            single = False
            for side, c in outer.items():
                ids = keep[comp == c]
                ncomp, frac = self._outer_cluster_components(A, ids)
                ok = len(ids) > 0 and frac >= self.min_component_fraction
                info[side] = {"size": int(len(ids)), "n_components": ncomp, "largest_fraction": frac,
                              "connected": bool(ok)}
                single = single or ok
            info["selected"] = bool(single)
            analysis.append(info)
            if single:
                selected.append(j)

        self.selection_fallback_ = not selected
        if not selected:  # nothing qualifies: fall back to the leading eigenvectors
            selected = list(range(min(p, k if k is not None else p)))
        self.eigenvector_analysis_ = analysis
        self.selected_eigenvectors_ = [j + skip + 1 for j in selected]
        X = U[:, selected] * np.sqrt(n)  # unit mean square per column: keeps reg_covar negligible

        self.bic_curve_ = None
        self.bic_monotone_ = None
        if k is None:
            fit_ids = self._subsample(np.arange(n), np.argsort(canonical_order(X)), self.max_fit_samples)
            ks = np.arange(2, int(self.max_segments) + 1)
            bics = np.array([
                GaussianMixture(int(c), covariance_type=self.covariance_type, n_init=1,
                                random_state=seed).fit(X[fit_ids]).bic(X[fit_ids])
                for c in ks
            ])
            self.bic_curve_ = {int(c): float(b) for c, b in zip(ks, bics)}
            best_k = int(ks[int(np.argmin(bics))])
            self.bic_monotone_ = bool(best_k == ks[-1])
            if self.bic_monotone_ and self.k_rule == "knee":
                k = _knee(ks.astype(np.float64), bics)
                self.n_segments_rule_ = "bic-knee (BIC kept improving up to max_segments: no minimum)"
            else:
                k = best_k
                self.n_segments_rule_ = "bic-minimum"
        else:
            self.n_segments_rule_ = "given"
        gm = GaussianMixture(int(k), covariance_type=self.covariance_type, n_init=int(self.n_init),
                             random_state=seed)
        labels = relabel_consecutive(fit_predict_invariant(gm, X))
        self.n_segments_ = int(labels.max() + 1)
        self.embedding_dim_ = int(X.shape[1])
        return labels
