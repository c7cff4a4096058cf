"""Unsupervised dense matching of Mateus et al. 2008 (the baseline of thesis 7.5) and the soft assignments of
Algorithm 5 (PLT, section 5.4): the sign and order of the Laplacian eigenvectors of the two shapes are aligned,
and the aligned embeddings are registered by EM (Algorithm 7,
:mod:`shape_toolkit.plugins.matching.dense.em_registration`).

Two alignments (``alignment``):

- ``"histogram"`` (the text, preset ``thesis``): each eigenvector's histogram compared with each of the other
  shape's, Hungarian assignment over eigenvector pairs, each with its better sign (:func:`histogram_alignment`).
- ``"search"`` (default): candidate signed permutations from a beam search on the *joint* distribution of the
  embedded points (:func:`joint_alignment_candidates`; eigenvectors matched only within ``window`` places), the
  histogram's among them, and (``fmap_candidate``, meshes) the rotation that best carries one embedding onto the
  other through a descriptor functional map's map (:func:`fmap_alignment`); EM is run from each on a sample, and
  the candidate whose map distorts geodesic distances least on average (:func:`map_distortion`) is kept, among
  those that keep orientation (``side``) when any does; then (``rotations="greedy"``) greedy Givens rotations of
  two of its eigenvectors, each re-fitted by EM, while one makes the map distort less.

``holes="close"`` (default; ``"keep"`` in preset ``thesis``): the spectrum of a shape with holes is that of its
copy with every hole closed by a fan (:func:`shape_toolkit.core.cleanup.close_holes`), read on its own vertices.

Why: holes and shortcuts change the eigenfunctions (a new boundary, a bridge): the eigenvectors of a corrupted
shape are those of the clean one up to swaps of neighbours in the spectrum and some mixing, and their marginal
histograms then hardly tell a sign or a place; EM started from the true signed permutation recovers the map
(measurements: ``benchmarks/results/plt_alignment_notes.md``).

Histograms are mass-weighted (each vertex counts with its area) on area-normalized
eigenvectors, so they do not depend on the sampling density. Like every purely intrinsic
method it cannot tell left from right: a sign flip of an antisymmetric eigenvector is exactly
as good as the original; ``side`` (meshes) uses the extrinsic orientation of the surface for that.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from shape_toolkit.api.params import Interval, Options, Param
from shape_toolkit.core.geometry import farthest_point_sampling
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.plugins.matching.dense.em_registration import Embedding, EMRegistrationMatcher
from shape_toolkit.plugins.matching.distortion import map_distortion
from shape_toolkit.plugins.matching.em import em_register, procrustes
from shape_toolkit.validation import check_random_state, shown_value

__all__ = ["EigvecAlignmentMatcher", "fmap_alignment", "histogram_alignment", "joint_alignment_candidates",
           "map_distortion"]

#: target points the EM of each candidate alignment is fitted to (the final EM uses every point)
SEARCH_SAMPLES = 1000
#: most eigenvectors of the search alignment, histogram bins and search beam (the parameters' docs)
MAX_SEARCH_K, MAX_BINS, MAX_BEAM = 30, 1000, 50
#: the arguments of :func:`joint_alignment_candidates` (window 0: signs only; n_samples above a point count: every
#: point of that set)
_WINDOW_ARG, _BEAM_ARG, _SAMPLES_ARG = Interval(int, 0), Interval(int, 1), Interval(int, 1)
#: angles (degrees) and most rounds of the greedy rotations that refine the kept alignment (``rotations``)
ROTATION_ANGLES, ROTATION_ROUNDS = (30.0, -30.0, 60.0, -60.0, 90.0), 8


def _histograms(U: np.ndarray, w: np.ndarray, edges: np.ndarray) -> np.ndarray:
    H = np.empty((U.shape[1], edges.size - 1))
    for c in range(U.shape[1]):
        H[c] = np.histogram(U[:, c], bins=edges, weights=w)[0]
    return H / np.maximum(H.sum(axis=1, keepdims=True), 1e-300)


def histogram_alignment(
    X: np.ndarray, Y: np.ndarray, wx: np.ndarray, wy: np.ndarray, bins: int = 40
) -> tuple[np.ndarray, np.ndarray]:
    """Signed permutation ``Q`` ``(k, k)`` (``Y ~ X Q^T``) matching source eigenvectors ``X``
    ``(n, k)`` to target eigenvectors ``Y`` ``(n', k)`` by L1 distance between their
    ``wx``/``wy``-weighted histograms; also returns the ``(k, k)`` cost matrix."""
    if X.ndim != 2 or Y.ndim != 2 or X.shape[1] != Y.shape[1]:
        raise ParameterError(f"X and Y must be (n, k) and (n', k) with one k, got {X.shape} and {Y.shape}")
    r = float(max(np.abs(X).max(), np.abs(Y).max()))
    edges = np.linspace(-r, r, bins + 1)
    hx = _histograms(X, wx, edges)
    hy_pos = _histograms(Y, wy, edges)
    hy_neg = _histograms(-Y, wy, edges)
    d_pos = np.abs(hx[:, None, :] - hy_pos[None, :, :]).sum(axis=2)  # (i source, j target)
    d_neg = np.abs(hx[:, None, :] - hy_neg[None, :, :]).sum(axis=2)
    cost = np.minimum(d_pos, d_neg)
    rows, cols = linear_sum_assignment(cost)
    k = X.shape[1]
    Q = np.zeros((k, k))
    for i, j in zip(rows, cols):
        Q[j, i] = 1.0 if d_pos[i, j] <= d_neg[i, j] else -1.0
    return Q, cost


def _fit(A: np.ndarray, B: np.ndarray, trim: float = 0.9) -> float:
    """Trimmed mean squared distance from each point of ``B`` ``(q, d)`` to its nearest in ``A`` ``(p, d)``."""
    d = np.sort(np.asarray(cKDTree(A).query(B, k=1)[0]) ** 2)
    return float(d[: max(1, int(trim * len(d)))].mean())


def _signed_permutation(cols: tuple[int, ...], signs: tuple[float, ...]) -> np.ndarray:
    Q = np.zeros((len(cols), len(cols)))
    for i, (j, s) in enumerate(zip(cols, signs)):
        Q[j, i] = s
    return Q


def joint_alignment_candidates(
    X: np.ndarray, Y: np.ndarray, *, window: int = 3, beam: int = 20, n_samples: int = SEARCH_SAMPLES,
    random_state: Any = 0,
) -> list[np.ndarray]:
    """Signed permutations ``(k, k)`` (``Y ~ X Q^T``), best first, aligning embeddings ``X`` ``(n, k)`` and ``Y``
    ``(n', k)`` by their joint distribution: source coordinate ``i`` goes to target coordinate ``j`` with
    ``|i - j| <= window`` and a sign; a beam of ``beam`` partial alignments grows one coordinate at a time, each
    scored by the symmetric trimmed nearest-neighbour fit of the two point sets (``n_samples`` points of each,
    drawn with ``random_state``; a positive int, all of a set above its size) in the coordinates aligned so far.
    The histograms of :func:`histogram_alignment` compare one coordinate at a time; this compares them together."""
    if X.ndim != 2 or Y.ndim != 2 or X.shape[1] != Y.shape[1]:
        raise ParameterError(f"X and Y must be (n, k) and (n', k) with one k, got {X.shape} and {Y.shape}")
    if not _WINDOW_ARG.accepts(window) or not _BEAM_ARG.accepts(beam):  # a negative window or beam kept nothing
        raise ParameterError(f"window must be {_WINDOW_ARG.describe()} and beam {_BEAM_ARG.describe()}, got "
                             f"{window!r} and {beam!r}")
    if not _SAMPLES_ARG.accepts(n_samples):  # 0 fitted empty point sets, 2.5 a TypeError, -1 a ValueError
        raise ParameterError(f"n_samples must be {_SAMPLES_ARG.describe()} (points of each set the fit compares; "
                             f"above a set's size: all of it), got {shown_value(n_samples)}")
    rng = check_random_state(random_state)
    k = X.shape[1]
    window = min(int(window), k)  # a wider window moves nothing further (and a numpy int64 could overflow)
    Xs = X[np.sort(rng.choice(len(X), int(min(n_samples, len(X))), replace=False))]
    Ys = Y[np.sort(rng.choice(len(Y), int(min(n_samples, len(Y))), replace=False))]
    states: list[tuple[tuple[int, ...], tuple[float, ...], float]] = [((), (), 0.0)]
    for i in range(k):
        grown = []
        for cols, signs, _ in states:
            for j in range(max(0, i - window), min(k, i + window + 1)):
                if j in cols:
                    continue
                for s in (1.0, -1.0):
                    c2, s2 = cols + (j,), signs + (s,)
                    A, B = Xs[:, : i + 1] * np.asarray(s2), Ys[:, list(c2)]
                    grown.append((c2, s2, _fit(A, B) + _fit(B, A)))
        if not grown:  # no free target coordinate within the window: keep the states as they are
            break
        grown.sort(key=lambda c: c[2])
        states = grown[: int(beam)]
    return [_signed_permutation(c, s) for c, s, _ in states if len(c) == k]


def fmap_alignment(emb: Embedding, source: Shape, target: Shape) -> np.ndarray:
    """The orthogonal ``Q`` ``(k, k)`` that best carries the source embedding onto the target's through the map
    of the descriptor functional map (``fmap-zoomout``'s defaults): least squares ``sum |Q x_i - y_t(i)|^2``
    (orthogonal Procrustes). Holes and bridges mix close eigenvectors, so the right start of EM is often not a
    signed permutation; a map from descriptors gives it whatever the mixing."""
    from shape_toolkit.plugins.matching.dense.fmap_zoomout import FmapZoomOutMatcher

    t = np.asarray(FmapZoomOutMatcher().match(source, target).target_of, dtype=np.int64)
    return procrustes(emb.Y[t].T @ emb.X)


class EigvecAlignmentMatcher(EMRegistrationMatcher):
    """Mateus et al. 2008 and Algorithm 5's soft assignments: the eigenvectors aligned (``alignment``), then EM
    registration (parameters as ``em-registration``, plus ``bins``, ``alignment``, ``window``, ``beam``,
    ``rotations``, ``fmap_candidate``, ``side`` and ``holes``). Seeds are ignored.

    Default: area-normalized Laplace-Beltrami eigenvectors, unscaled, the ``"search"`` alignment (module
    docstring) keeping orientation, the functional map's candidate among its starts. Preset ``thesis``
    (Algorithm 5, section 5.4): the histogram alignment of the text, the unnormalized Laplacian ``D - W`` of the
    Gaussian graph (eq. 3.7) and its L-embedding, the commute-time scaling ``Lambda^{-1/2} U^T`` of eq. 5.1; the
    histograms are those of the eigenvectors themselves (a scaling per column would only move them between bins),
    no orientation cue (it matches up to symmetry)."""

    presets: dict = {"thesis": {"spectrum": "graph", "weighting": "gaussian", "scaling": "commute-time",
                                "alignment": "histogram", "side": "none", "holes": "keep",
                                "rotations": "none", "fmap_candidate": False}}
    parameter_constraints = {
        **{p: c for p, c in EMRegistrationMatcher.parameter_constraints.items()
           if p in ("k", "outlier_weight", "n_neighbors", "max_iter", "tol", "threshold", "one_to_one",
                    "fill_unmatched", "spectrum", "weighting", "scaling", "random_state")},
        "k": Param(Interval(int, 1, 100), doc="embedding dimension (alignment 'search': at most 30, checked when "
                   "matching: the beam search fits k x beam x 2 (2 window + 1) point sets in up to k dimensions and "
                   "each rotation round runs ~5 k window EMs of k x k SVDs, ~k^4 in all (k = 100: 100 s on 162 "
                   "vertices); eigenvectors that far up come mixed in near-degenerate groups that signed "
                   "permutations cannot align, the thesis's range ends at 10)"),
        "bins": Param(Interval(int, 1, MAX_BINS), doc="histogram bins of the eigenvector alignment (at most 1000: "
                      "finer bins hold single vertices, so the L1 distance compares samplings, not shapes, and the "
                      "k x k x bins cost arrays take 80 MB each at k = 100)"),
        "alignment": Param(Options("histogram", "search"), doc="eigenvector alignment: histograms (the text) or "
                           "the search over joint-distribution candidates scored by their maps' distortion"),
        "window": Param(Interval(int, 1, MAX_SEARCH_K - 1), doc="search: places an eigenvector may move in the "
                        "spectrum (at most 29: the search takes k <= 30 eigenvectors, so from k - 1 <= 29 on any of "
                        "them may go to any place, as with any wider window)"),
        "beam": Param(Interval(int, 1, MAX_BEAM), doc="search: candidate alignments kept (each gets a sampled EM "
                      "and a distortion measure, and each grows 2 (2 window + 1) scored extensions per eigenvector; "
                      "at most 50: the candidates differ then only in late, near-degenerate eigenvectors, which "
                      "the EM and the rotations re-fit anyway; k = 30, window 29, beam 50 take 30 s on 162 vertices)"),
        "holes": Param(Options("keep", "close"), doc="spectra of the shapes as they are, or with every hole "
                       "closed by a fan (core.cleanup.close_holes) and the eigenvectors read on the original vertices"),
        "rotations": Param(Options("greedy", "none"), doc="search: refine the kept alignment by greedy Givens "
                           "rotations of two eigenvectors, each re-fitted by EM and kept when the map distorts less"),
        "fmap_candidate": Param(bool, doc="search: one more candidate, the rotation that best aligns the embeddings "
                                "through the map of a descriptor functional map (fmap-zoomout; meshes)"),
        "side": Param(Options("preserving", "reversing", "none"),
                      doc="search: orientation the kept candidate keeps, when one does (meshes; none: the least "
                      "distorting)"),
    }

    def __init__(
        self,
        k: int = 8,
        bins: int = 40,
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
        alignment: str = "search",
        window: int = 3,
        beam: int = 20,
        side: str = "preserving",
        holes: str = "close",
        rotations: str = "greedy",
        fmap_candidate: bool = True,
        random_state: Any = 0,
    ):
        super().__init__(
            k=k, outlier_weight=outlier_weight, n_neighbors=n_neighbors, max_iter=max_iter,
            tol=tol, threshold=threshold, one_to_one=one_to_one, fill_unmatched=fill_unmatched,
            spectrum=spectrum, weighting=weighting, scaling=scaling, orientation="none", random_state=random_state,
        )
        self.bins = bins
        self.alignment = alignment
        self.window = window
        self.beam = beam
        self.side = side
        self.holes = holes
        self.rotations = rotations
        self.fmap_candidate = fmap_candidate

    def _check(self) -> None:
        super()._check()
        if self.alignment == "search" and self.k > MAX_SEARCH_K:
            raise ParameterError(f"{type(self).__name__}: k must be at most {MAX_SEARCH_K} with alignment 'search' "
                                 f"(its cost grows as k^4; see plugins show eigvec-alignment), got {self.k!r}")

    def _bases(self, source, target, source_spectrum, target_spectrum, min_dim: int = 0):
        """The embedding bases; with ``holes="close"`` a shape with a boundary gets the basis of its closed copy
        (computed here through the spectrum cache, the given spectrum is not used), restricted to its own
        vertices (mass renormalized)."""
        if self.holes != "close":
            return super()._bases(source, target, source_spectrum, target_spectrum, min_dim)
        from shape_toolkit.core.cleanup import close_holes
        from shape_toolkit.features.basis import Basis, basis_of

        spec = self.embedding_spec(min_dim)
        out = []
        for shape, given in ((source, source_spectrum), (target, target_spectrum)):
            closed, n_loops = close_holes(shape) if shape.is_mesh else (shape, 0)
            if n_loops == 0:
                out.append(basis_of(self._given(spec, shape, given), spec.k))
                continue
            n = shape.n_vertices
            b = basis_of(spec.compute(closed), min(spec.k, n))  # no more eigenpairs than the shape has vertices
            mass = b.mass[:n] / b.mass[:n].sum()
            out.append(Basis(b.evals, b.evecs[:n], mass))
        return out[0], out[1]

    def start(self, source: Shape, target: Shape, seeds: np.ndarray | None, source_spectrum=None,
              target_spectrum=None, min_dim: int = 0) -> tuple[Embedding, np.ndarray, dict]:
        """The embeddings (``scaling``; no bases: no refinement) and ``Q0``: the histogram alignment of their
        eigenvectors, or (``alignment="search"``) the sampled EM fit of the chosen candidate; ``seeds`` are
        ignored. ``info`` records the alignment (``Q0``; the search's ``alignment_*`` scores; the rotations'
        ``rotations_tried`` and ``rotation_distortion``)."""
        self._check()
        bs, bt = self._bases(source, target, source_spectrum, target_spectrum, min_dim)
        K = self._shared_dimension(int(self.k), bs, bt)  # one size on both shapes, however small
        X, Y = bs.evecs[:, 1 : K + 1], bt.evecs[:, 1 : K + 1]
        Q0, _ = histogram_alignment(X, Y, bs.mass, bt.mass, int(self.bins))
        emb = Embedding(self._embed(bs, K), self._embed(bt, K))
        info: dict[str, Any] = {"alignment": self.alignment}
        if self.alignment == "search":
            Q0 = self._search(emb, Q0, source, target, info)
        info["Q0"] = Q0
        return emb, Q0, info

    def _search(self, emb: Embedding, Q_hist: np.ndarray, source: Shape, target: Shape,
                info: dict[str, Any]) -> np.ndarray:
        """The search alignment: EM (on ``SEARCH_SAMPLES`` target points) from the histogram's and the joint
        candidates; the kept fit's ``Q`` (least mean :func:`map_distortion`, among the candidates that keep ``side``
        when any does; on point clouds, the best embedding fit)."""
        cands = [Q_hist] + joint_alignment_candidates(emb.X, emb.Y, window=int(self.window), beam=int(self.beam),
                                                      random_state=self.random_state)
        seen: list[np.ndarray] = []
        for Q in cands:
            if not any(np.array_equal(Q, q) for q in seen):
                seen.append(Q)
        meshes = source.is_mesh and target.is_mesh
        if self.fmap_candidate and meshes:
            seen.append(fmap_alignment(emb, source, target))
        tree = cKDTree(emb.Y)
        src_d = None
        scores, sides, fits = [], [], []
        for Qc in seen:
            Q, _, _ = em_register(emb.X, emb.Y, Qc, outlier_weight=self.outlier_weight, n_neighbors=self.n_neighbors,
                                  max_iter=self.max_iter, tol=self.tol, max_samples=SEARCH_SAMPLES,
                                  random_state=self.random_state, posteriors=False)
            fits.append(Q)
            if not meshes:
                scores.append(_fit(emb.X @ Q.T, emb.Y))
                sides.append(0.0)
                continue
            t = np.asarray(tree.query(emb.X @ Q.T, k=1)[1], dtype=np.int64)
            d, src_d = map_distortion(source, target, t, random_state=self.random_state, source_distances=src_d)
            scores.append(d)
            sides.append(self._side_of(source, target, t))
        order = np.argsort(scores, kind="stable")
        want = {"preserving": 1.0, "reversing": -1.0}.get(self.side, 0.0)
        keep = [i for i in order if want and sides[i] * want > 0]
        best = int(keep[0] if keep else order[0])
        info.update({"alignment_candidates": len(seen), "alignment_distortion": [float(x) for x in scores],
                     "alignment_side": [float(x) for x in sides], "alignment_chosen": best})
        if not meshes or self.rotations == "none":
            return fits[best]
        return self._rotate(emb, fits[best], scores[best], sides[best], source, target, tree, src_d, info)

    def _rotate(self, emb: Embedding, Q: np.ndarray, d: float, side: float, source: Shape, target: Shape,
                tree: cKDTree, src_d: np.ndarray | None, info: dict[str, Any]) -> np.ndarray:
        """Greedy rotations of the kept fit: each round tries a Givens rotation of two target coordinates at most
        ``window`` places apart (``ROTATION_ANGLES``), each followed by the sampled EM, and takes the one that
        lowers the mean :func:`map_distortion` most without losing ``side``; rounds until none does. Eigenvectors
        of a corrupted shape are mixed, not only permuted and flipped: a signed permutation can only start EM in
        the basin of the right rotation."""
        k, want = Q.shape[0], {"preserving": 1.0, "reversing": -1.0}.get(self.side, 0.0)
        pairs = [(i, j) for i in range(k) for j in range(i + 1, min(k, i + int(self.window) + 1))]
        tried = 0
        for _ in range(ROTATION_ROUNDS):
            best = None
            for i, j in pairs:
                for a in np.deg2rad(ROTATION_ANGLES):
                    G = np.eye(k)
                    G[i, i] = G[j, j] = np.cos(a)
                    G[i, j], G[j, i] = -np.sin(a), np.sin(a)
                    Qr, _, _ = em_register(emb.X, emb.Y, G @ Q, outlier_weight=self.outlier_weight,
                                           n_neighbors=self.n_neighbors, max_iter=self.max_iter, tol=self.tol,
                                           max_samples=SEARCH_SAMPLES, random_state=self.random_state,
                                           posteriors=False, attractor=Q)
                    tried += 1
                    if Qr is Q:  # back in the kept fit's basin
                        continue
                    t = np.asarray(tree.query(emb.X @ Qr.T, k=1)[1], dtype=np.int64)
                    dr, src_d = map_distortion(source, target, t, random_state=self.random_state,
                                               source_distances=src_d)
                    if dr >= (best[0] if best else d):
                        continue
                    sr = self._side_of(source, target, t)
                    if want and side * want > 0 and sr * want <= 0:  # never trade a kept orientation away
                        continue
                    best = (dr, sr, Qr)
            if best is None:
                break
            d, side, Q = best
        info.update({"rotations_tried": tried, "rotation_distortion": float(d)})
        return Q

    def _side_of(self, source: Shape, target: Shape, t: np.ndarray) -> float:
        """Orientation score (:func:`~shape_toolkit.plugins.matching.orientation.orientation_score`) of the map
        ``t`` on farthest-point samples of the source (0 when ``side`` is ``"none"``)."""
        if self.side == "none":
            return 0.0
        from shape_toolkit.plugins.matching.orientation import orientation_score

        rows = farthest_point_sampling(np.asarray(source.vertices), min(300, source.n_vertices))
        return orientation_score(source, target, np.column_stack([rows, t[rows]]))
