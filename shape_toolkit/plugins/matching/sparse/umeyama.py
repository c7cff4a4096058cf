"""Umeyama's spectral graph matching (1988; thesis 2.4.4) as a keypoint-matching baseline: the
keypoint graphs are weighted by the heat-kernel affinity of their spectral distances, and the
Hungarian algorithm maximizes ``tr(|U_A| |U_B|^T P^T)`` (eq. 2.59) over assignments, with ``|U|``
the absolute eigenvector matrices (sign-invariant)."""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from shape_toolkit.api.interfaces import SparseMatcher
from shape_toolkit.features.basis import normalized_spectrum
from shape_toolkit.features.heat import heat_distances
from shape_toolkit.plugins._params import ASSOCIATION
from shape_toolkit.plugins.matching.association import association_spec
from shape_toolkit.plugins.matching.validation import check_keypoints
from shape_toolkit.spectra import SpectrumSpec

__all__ = ["UmeyamaMatcher", "umeyama_assignment"]


def umeyama_assignment(WA: np.ndarray, WB: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows/columns of the Hungarian assignment maximizing ``|U_A| |U_B|^T`` for symmetric
    weight matrices ``WA`` ``(p, p)`` and ``WB`` ``(q, q)`` (the ``min(p, q)`` eigenvectors of
    largest eigenvalue are compared when the sizes differ)."""
    r = min(len(WA), len(WB))
    _, UA = np.linalg.eigh(WA)
    _, UB = np.linalg.eigh(WB)
    UA, UB = np.abs(UA[:, -r:]), np.abs(UB[:, -r:])
    return linear_sum_assignment(-(UA @ UB.T))


class UmeyamaMatcher(SparseMatcher):
    """Umeyama's method on keypoint affinity matrices ``exp(-d^2 / (2 sigma^2))`` of unit-sphere
    heat distances (eq. 6.43, same time for both shapes, as in the association graph).
    Pairs scoring below ``min_score`` times the best are dropped."""

    presets = {"thesis": {"spectrum": "graph"}}  # 2.4.4 on the Gaussian graph's D - W, no mass
    parameter_constraints = {p: ASSOCIATION[p] for p in ("k", "time", "sigma", "min_score", "spectrum")}

    def __init__(
        self, k: int = 20, time: float | None = None, sigma: float = 0.5, min_score: float = 0.0,
        spectrum: str = "lbo",
    ):
        self.k = k
        self.time = time
        self.sigma = sigma
        self.min_score = min_score
        self.spectrum = spectrum

    def spectrum_spec(self) -> SpectrumSpec:
        """``k + 1`` eigenpairs of the ``spectrum`` (:func:`~shape_toolkit.plugins.matching.association.
        association_spec`: cotangent Laplace-Beltrami, or the Gaussian graph's ``D - W`` without mass)."""
        return association_spec(int(self.k), self.spectrum)

    def match(self, source, target, source_keypoints, target_keypoints, *,
              source_spectrum=None, target_spectrum=None) -> np.ndarray:
        """Matched ``[source_vertex, target_vertex]`` pairs, int64 ``(q, 2)``."""
        kp_s = check_keypoints(source_keypoints, source.n_vertices, "source")
        kp_t = check_keypoints(target_keypoints, target.n_vertices, "target")
        ss, st = self._spectrum(source, source_spectrum), self._spectrum(target, target_spectrum)
        ns = normalized_spectrum(ss.truncated(min(ss.k, int(self.k) + 1)))
        nt = normalized_spectrum(st.truncated(min(st.k, int(self.k) + 1)))
        vals = ns.eigenvalues[ns.eigenvalues > 1e-9 * ns.eigenvalues.max()]
        t = self.time if self.time is not None else 1.0 / float(vals[min(4, vals.size - 1)])
        Ds = heat_distances(ns, t, kp_s, kp_s, normalization="unit-sphere")[0]
        Dt = heat_distances(nt, t, kp_t, kp_t, normalization="unit-sphere")[0]
        WA = np.exp(-(Ds**2) / (2 * self.sigma**2))
        WB = np.exp(-(Dt**2) / (2 * self.sigma**2))
        rows, cols = umeyama_assignment(WA, WB)
        r = min(len(WA), len(WB))
        _, UA = np.linalg.eigh(WA)
        _, UB = np.linalg.eigh(WB)
        score = (np.abs(UA[:, -r:]) @ np.abs(UB[:, -r:]).T)[rows, cols]
        keep = score >= float(self.min_score) * float(score.max())
        return np.column_stack([kp_s[rows[keep]], kp_t[cols[keep]]]).astype(np.int64)
