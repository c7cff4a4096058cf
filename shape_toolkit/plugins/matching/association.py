"""Sparse keypoint matching on an association graph (thesis 7.2.1): candidate matches, their pairwise
consistency, a one-to-one selection, and the shared flow of the replicator, spectral and rrwm matchers."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.features.basis import normalized_spectrum
from shape_toolkit.plugins.matching.orientation import orient_pairs, side_matcher, symmetry_matcher
from shape_toolkit.plugins.matching.validation import check_keypoints
from shape_toolkit.spectra import SpectrumSpec, default_spec

__all__ = ["AssociationGraph", "association_graph", "association_spec", "greedy_discretize", "AssociationMatcherBase"]

#: the literal setting of thesis 7.2.1 (preset ``thesis`` of replicator, spectral, rrwm): spectral distances of
#: the Gaussian graph (eq. 3.7) and its combinatorial Laplacian ``D - W`` without mass (6.2.2), no side check
#: (the thesis matches "only up to the symmetry")
THESIS_SPARSE = {"spectrum": "graph", "orientation": "none"}


def association_spec(k: int, spectrum: str = "lbo") -> SpectrumSpec:
    """``k + 1`` eigenpairs of the cotangent Laplace-Beltrami operator (``"lbo"``) or of the Gaussian graph's
    ``D - W`` without mass (``"graph"``, the thesis's heat kernel, eq. 6.7)."""
    if spectrum == "graph":
        return default_spec(int(k) + 1, "graph", weighting="gaussian", laplacian="combinatorial", use_mass=False)
    return default_spec(int(k) + 1)


@dataclass(frozen=True)
class AssociationGraph:
    """Candidate matches ``nodes`` ``(N, 2)`` (indices into the two keypoint lists), symmetric
    pairwise consistency ``W`` ``(N, N)`` (0 between conflicting candidates and on the diagonal)
    and unary similarity ``unary`` ``(N,)`` in ``(0, 1]``."""

    nodes: np.ndarray
    W: np.ndarray
    unary: np.ndarray

    @property
    def affinity(self) -> np.ndarray:
        """``W`` with the unary similarities on its diagonal ``(N, N)``: the affinity matrix of spectral
        matching and RRWM."""
        return self.W + np.diag(self.unary)


def association_graph(
    source: Shape,
    target: Shape,
    kp_s: np.ndarray,
    kp_t: np.ndarray,
    spec_s: Spectrum,
    spec_t: Spectrum,
    *,
    k: int = 20,
    time: float | None = None,
    sigma: float = 0.3,
    adf_ratio: float = 2.0,
    max_candidates: int = 8,
) -> AssociationGraph:
    """Association graph of section 7.2.1 on keypoints ``kp_s``/``kp_t``.

    Spectral distances: unit-sphere heat distance (eq. 6.43, radians) at one time ``time`` (in
    unit-area units; default ``1 / lambda_5`` of the source) on the area-normalized ``k``-term
    spectra, so both shapes use the same scale. Candidates are pruned by the normalized
    auto-diffusion function (eq. 6.32 on unit-area eigenfunctions, a sampling-independent density)
    at three times: a pair is kept when the values agree within a factor ``adf_ratio`` at every
    time, then the ``max_candidates`` most similar per source keypoint are kept. Edge weight
    ``exp(-(d_s(a, c) - d_t(b, d))^2 / (2 sigma^2))``.
    """
    from shape_toolkit.features.heat import heat_distances, heat_kernel_signature

    ns = normalized_spectrum(spec_s.truncated(min(spec_s.k, k + 1)))
    nt = normalized_spectrum(spec_t.truncated(min(spec_t.k, k + 1)))
    vals = ns.eigenvalues[ns.eigenvalues > 1e-9 * ns.eigenvalues.max()]
    if time is None:
        time = 1.0 / float(vals[min(4, vals.size - 1)])
    times = np.array([0.25, 1.0, 4.0]) * float(time)
    a_s = heat_kernel_signature(ns, times, vertices=kp_s)
    a_t = heat_kernel_signature(nt, times, vertices=kp_t)
    logr = np.abs(np.log(np.maximum(a_s, 1e-300))[:, None, :] - np.log(np.maximum(a_t, 1e-300))[None])
    worst = logr.max(axis=2)  # (P, Q)
    keep = worst <= np.log(adf_ratio)
    for a in range(len(kp_s)):
        cand = np.flatnonzero(keep[a])
        if cand.size > max_candidates:
            drop = cand[np.argsort(worst[a, cand], kind="stable")[max_candidates:]]
            keep[a, drop] = False
    nodes = np.argwhere(keep)
    if len(nodes) == 0:
        return AssociationGraph(np.zeros((0, 2), dtype=np.int64), np.zeros((0, 0)), np.zeros(0))
    Ds = heat_distances(ns, time, kp_s, kp_s, normalization="unit-sphere")[0]
    Dt = heat_distances(nt, time, kp_t, kp_t, normalization="unit-sphere")[0]
    a, b = nodes[:, 0], nodes[:, 1]
    diff = Ds[a][:, a] - Dt[b][:, b]
    W = np.exp(-(diff**2) / (2.0 * sigma**2))
    conflict = (a[:, None] == a[None, :]) | (b[:, None] == b[None, :])
    W[conflict] = 0.0
    unary = np.exp(-(worst[a, b] ** 2) / (2.0 * np.log(adf_ratio) ** 2))
    return AssociationGraph(nodes.astype(np.int64), W, unary)


def greedy_discretize(
    nodes: np.ndarray, scores: np.ndarray, min_score: float = 0.0
) -> np.ndarray:
    """One-to-one selection of candidate ``nodes`` ``(N, 2)`` by decreasing ``scores`` (those
    ``> min_score``): indices of the chosen nodes."""
    order = np.argsort(-scores, kind="stable")
    used_a, used_b, chosen = set(), set(), []
    for u in order:
        if scores[u] <= min_score:
            break
        a, b = int(nodes[u, 0]), int(nodes[u, 1])
        if a in used_a or b in used_b:
            continue
        used_a.add(a)
        used_b.add(b)
        chosen.append(u)
    return np.asarray(chosen, dtype=np.int64)


class AssociationMatcherBase:
    """Shared parameters and flow of the association-graph matchers (replicator, spectral,
    rrwm): build the graph, score its nodes with :meth:`_solve`, discretize one-to-one."""

    def spectrum_spec(self) -> SpectrumSpec:
        """``k + 1`` eigenpairs of the ``spectrum`` (:func:`association_spec`)."""
        return association_spec(int(self.k), getattr(self, "spectrum", "lbo"))

    def _graph_params(self) -> dict:
        return dict(k=int(self.k), time=self.time, sigma=float(self.sigma),
                    adf_ratio=float(self.adf_ratio), max_candidates=int(self.max_candidates))

    def _solve(self, graph: AssociationGraph) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def _select(self, g: AssociationGraph, active: np.ndarray) -> np.ndarray:
        """Chosen node indices of ``g`` restricted to the ``active`` nodes (bool ``(N,)``)."""
        idx = np.flatnonzero(active)
        if idx.size == 0:
            return idx
        sub = AssociationGraph(g.nodes[idx], g.W[np.ix_(idx, idx)], g.unary[idx])
        scores = self._solve(sub)
        if not np.any(scores > 0):
            return np.zeros(0, dtype=np.int64)
        return idx[greedy_discretize(sub.nodes, scores, float(self.min_score) * float(scores.max()))]

    def match(self, source, target, source_keypoints, target_keypoints, *,
              source_spectrum=None, target_spectrum=None) -> np.ndarray:
        """Matched ``[source_vertex, target_vertex]`` pairs, int64 ``(q, 2)``.

        With ``orientation`` ``"preserving"`` (or ``"reversing"``) on two meshes, the side of each
        match is decided by :func:`orient_pairs`: ``(a, b)`` or its mirror image ``(S(a), b)``
        (``S`` the source's intrinsic symmetry), whichever agrees better with an orientation-aware
        functional map (:func:`side_reference`). The spectra of the symmetry and reference
        matchers are declared through ``spectrum_specs()``."""
        orientation = getattr(self, "orientation", "none")  # parameters: declared (_params.ASSOCIATION)
        kp_s = check_keypoints(source_keypoints, source.n_vertices, "source")
        kp_t = check_keypoints(target_keypoints, target.n_vertices, "target")
        ss, st = self._spectrum(source, source_spectrum), self._spectrum(target, target_spectrum)
        g = association_graph(source, target, kp_s, kp_t, ss, st, **self._graph_params())
        if len(g.nodes) == 0:
            return np.zeros((0, 2), dtype=np.int64)

        def pairs_of(chosen: np.ndarray) -> np.ndarray:
            nodes = g.nodes[chosen]
            return np.column_stack([kp_s[nodes[:, 0]], kp_t[nodes[:, 1]]]).astype(np.int64)

        chosen = self._select(g, np.ones(len(g.nodes), dtype=bool))
        pairs = pairs_of(chosen)
        if orientation == "none" or not (source.is_mesh and target.is_mesh) or len(chosen) < 3:
            return pairs
        return orient_pairs(source, target, pairs, source_spectrum, target_spectrum, orientation)

    def _nested_plugins(self) -> list:
        orientation = getattr(self, "orientation", "none")
        return [] if orientation == "none" else [symmetry_matcher(), side_matcher(orientation)]
