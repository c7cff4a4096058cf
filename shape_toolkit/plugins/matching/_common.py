"""Helpers shared by the matching plugins: area-normalized Laplace-Beltrami bases, functional map
<-> point-to-point conversions, descriptor and seed checks. Not a plugin (no hook)."""

from __future__ import annotations

import weakref
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum, SpectrumSpec, default_spec
from shape_toolkit.errors import ParameterError
from shape_toolkit.results.correspondence import nearest_neighbors
from shape_toolkit.validation import check_seeds as _check_seeds


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


def check_descriptors(desc: np.ndarray, n: int, what: str) -> np.ndarray:
    """``desc`` as float64 ``(n, d)``; raises :class:`ParameterError` on a bad shape or NaN."""
    d = np.asarray(desc, dtype=np.float64)
    if d.ndim == 1:
        d = d[:, None]
    if d.ndim != 2 or d.shape[0] != n:
        raise ParameterError(f"{what} descriptors must be ({n}, d), got shape {d.shape}")
    if not np.isfinite(d).all():
        raise ParameterError(f"{what} descriptors contain NaN or infinite values")
    return d


def check_seeds(seeds: np.ndarray | None, n_src: int, n_tgt: int) -> np.ndarray | None:
    """Seeds as int64 ``(q, 2)`` ``[source, target]`` inside both shapes, or None."""
    return None if seeds is None else _check_seeds(seeds, n_src, n_tgt)


def resolve_plugin(family: str, spec: Any, params: dict | None, *, method: str, what: str, kind: str) -> Any:
    """The plugin of ``family`` a parameter names: an instance (anything with ``method``, used as is), a
    registry name with ``params``, or a table ``{plugin, preset, params}`` (as written in TOML configs).
    ``what`` names the parameter and ``kind`` the instance type in the errors."""
    from shape_toolkit.api.registry import create_plugin

    if params is not None and not isinstance(params, dict):
        raise ParameterError(f"{what}_params must be a table of {what} parameters, got {params!r}")
    if hasattr(spec, method) and not isinstance(spec, (str, dict, type)):
        if params:
            raise ParameterError(f"{what}_params apply to a {what} given by name, not to an instance")
        return spec
    if isinstance(spec, dict):
        bad = sorted(set(spec) - {"plugin", "preset", "params"})
        if bad or "plugin" not in spec:
            raise ParameterError(
                f"a {what} table needs 'plugin' (and optional preset, params); got {sorted(spec)}"
            )
        return create_plugin(family, str(spec["plugin"]), spec.get("preset"),
                             **{**(spec.get("params") or {}), **(params or {})})
    if isinstance(spec, str):
        return create_plugin(family, spec, **(params or {}))
    raise ParameterError(f"{what} must be a plugin name, a table or a {kind}, got {spec!r}")


def descriptor_plugin(descriptor: Any, params: dict | None = None) -> Any:
    """The descriptor plugin a matcher names (:func:`resolve_plugin`: an instance, a registry name with
    ``params``, or a table ``{plugin, preset, params}``)."""
    return resolve_plugin("descriptors", descriptor, params, method="compute", what="descriptor", kind="Descriptor")


class UsesDescriptor:
    """Mixin of the dense matchers that compute a descriptor plugin (``descriptor`` and
    ``descriptor_params`` parameters): the plugin instance, and its spectra in ``spectrum_specs()``."""

    def _descriptor_plugin(self) -> Any:
        return descriptor_plugin(self.descriptor, self.descriptor_params)

    def _nested_plugins(self) -> list:
        return [self._descriptor_plugin()]


def paired_descriptors(
    plugin: Any, source: Shape, target: Shape, kp_source: np.ndarray, kp_target: np.ndarray, *,
    source_spectrum: Spectrum | Sequence[Spectrum] | None = None,
    target_spectrum: Spectrum | Sequence[Spectrum] | None = None,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Keypoint descriptors ``(n, M * tau)`` of both shapes on matched keypoints, and ``tau``.

    Multi-scale heat descriptors must use the *same* times on both shapes to be comparable
    (thesis 7.3.1): when the plugin has a ``times`` parameter left to None, the times it would use
    on the source (its ``descriptor_times``, the scree rule on its own spectrum) are set on a copy
    and reused on the target."""
    import copy

    if getattr(plugin, "times", "absent") is None and hasattr(plugin, "descriptor_times"):
        times = plugin.descriptor_times(source, spectrum=source_spectrum)
        plugin = copy.deepcopy(plugin)
        plugin.set_params(times=[float(t) for t in times])
    ds = plugin.compute(source, spectrum=source_spectrum, keypoints=kp_source)
    dt = plugin.compute(target, spectrum=target_spectrum, keypoints=kp_target)
    times = getattr(plugin, "times", None)
    n_times = len(times) if times is not None else int(getattr(plugin, "n_times", 1))
    return ds, dt, n_times


def normalize_columns(desc: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """Descriptor columns divided by their ``mass``-weighted L2 norm (constant columns kept)."""
    norms = np.sqrt((mass[:, None] * desc**2).sum(axis=0))
    norms[norms <= 1e-300] = 1.0
    return desc / norms


# -- association graph for sparse keypoint matching (thesis 7.2.1) ---------------------------------
@dataclass(frozen=True)
class AssociationGraph:
    """Candidate matches ``nodes`` ``(N, 2)`` (indices into the two keypoint lists), symmetric
    pairwise consistency ``W`` ``(N, N)`` (0 between conflicting candidates and on the diagonal)
    and unary similarity ``unary`` ``(N,)`` in ``(0, 1]``."""

    nodes: np.ndarray
    W: np.ndarray
    unary: np.ndarray


def normalized_spectrum(spectrum: Spectrum) -> Spectrum:
    """The same spectrum scaled to unit total mass (area-normalized eigenpairs)."""
    b = basis_of(spectrum)
    return Spectrum(
        b.evals, b.evecs, spectrum.laplacian, spectrum.weighting,
        b.mass if spectrum.mass is not None else None, spectrum.degrees, spectrum.sign_fixed,
    )


def check_keypoints(kp: np.ndarray, n: int, what: str, minimum: int = 3) -> np.ndarray:
    """Keypoints as unique int64 ids inside the shape; fewer than ``minimum`` raise."""
    k = np.asarray(kp)
    if k.ndim != 1:
        raise ParameterError(f"{what} keypoints must be a 1-D array of vertex ids")
    if k.size and not np.issubdtype(k.dtype, np.integer):
        raise ParameterError(f"{what} keypoints must be integer vertex ids")
    k = k.astype(np.int64)
    if k.size and (k.min() < 0 or k.max() >= n):
        raise ParameterError(f"{what} keypoints must lie in [0, {n - 1}]")
    _, first = np.unique(k, return_index=True)
    k = k[np.sort(first)]
    if k.size < minimum:
        raise ParameterError(
            f"not enough {what} keypoints to match: {k.size} (need at least {minimum}); "
            "use a denser keypoint preset or give seeds"
        )
    return k


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


def farthest_point_sampling(points: np.ndarray, n: int, start: int = 0) -> np.ndarray:
    """``n`` indices of ``points`` ``(N, d)`` chosen by Euclidean farthest point sampling."""
    P = np.asarray(points, dtype=np.float64)
    n = min(n, len(P))
    idx = np.empty(n, dtype=np.int64)
    if n == 0:
        return idx
    idx[0] = start
    coords = [np.ascontiguousarray(P[:, c]) for c in range(P.shape[1])]
    d = np.full(len(P), np.inf)
    t, u = np.empty(len(P)), np.empty(len(P))
    j = int(start)
    for i in range(1, n):  # squared distance to the newest sample, in place (no temporaries)
        t.fill(0.0)
        for c, x in zip(coords, P[j]):
            np.subtract(c, x, out=u)
            np.multiply(u, u, out=u)
            t += u
        np.minimum(d, t, out=d)
        j = int(d.argmax())
        idx[i] = j
    return idx


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit vertex normals ``(n, 3)`` of ``vertices`` ``(n, 3)`` (any positions on the mesh's ``faces``, e.g.
    a deformed copy): area-weighted face normals, in the faces' winding."""
    X, F = np.asarray(vertices, dtype=np.float64), np.asarray(faces)
    fn = np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])  # length = 2 * area
    N = np.zeros_like(X)
    for c in range(3):
        np.add.at(N, F[:, c], fn)
    return N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-300)


def outward_vertex_normals(shape: Shape) -> np.ndarray:
    """Unit vertex normals ``(n, 3)`` (:func:`vertex_normals`), oriented outwards: flipped when the signed
    volume of the mesh is negative."""
    V = np.asarray(shape.vertices, dtype=np.float64)
    F = np.asarray(shape.require_faces("outward normals"))
    vol = np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum()
    N = vertex_normals(V, F)
    return -N if vol < 0 else N


def orientation_votes(
    source: Shape, target: Shape, pairs: np.ndarray, n_neighbors: int = 5,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-match orientation votes of :func:`orientation_score`: ``(vote, weight)`` ``(q,)``, the
    weighted mean sign in ``[-1, 1]`` of the triplets centred on each match and their weight."""
    p = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    q = len(p)
    if q < 3:
        return np.zeros(q), np.zeros(q)
    from scipy.spatial import cKDTree

    Ps = np.asarray(source.vertices, dtype=np.float64)[p[:, 0]]
    Pt = np.asarray(target.vertices, dtype=np.float64)[p[:, 1]]
    Ns = outward_vertex_normals(source)[p[:, 0]]
    Nt = outward_vertex_normals(target)[p[:, 1]]
    kk = int(min(n_neighbors, q - 1))
    _, nb = cKDTree(Ps).query(Ps, k=kk + 1)
    nb = np.asarray(nb).reshape(q, kk + 1)[:, 1:]
    jj, kk2 = np.triu_indices(kk, 1)
    i = np.repeat(np.arange(q), len(jj))
    j = nb[:, jj].ravel()
    k = nb[:, kk2].ravel()

    def triple(P: np.ndarray, N: np.ndarray) -> np.ndarray:
        u, v = P[j] - P[i], P[k] - P[i]
        den = np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1)
        return np.einsum("ij,ij->i", np.cross(u, v), N[i]) / np.maximum(den, 1e-300)

    ts, tt = triple(Ps, Ns), triple(Pt, Nt)
    w = np.minimum(np.abs(ts), np.abs(tt))
    wsum = np.bincount(i, w, minlength=q)
    vote = np.bincount(i, np.sign(ts * tt) * w, minlength=q) / np.maximum(wsum, 1e-300)
    return vote, wsum


def orientation_score(
    source: Shape, target: Shape, pairs: np.ndarray, n_neighbors: int = 5,
) -> float:
    """Extrinsic orientation of matches ``pairs`` ``(q, 2)`` in ``[-1, 1]``: +1 when they preserve
    orientation, -1 when they are a mirror image (left and right swapped).

    For each match ``(a_i, b_i)`` and each two of its ``n_neighbors`` nearest other matches
    (Euclidean, on the source), the triple products ``det[p_j - p_i, p_k - p_i, n_i]`` on the
    source and ``det[q_j - q_i, q_k - q_i, m_i]`` on the target (``n``, ``m`` outward vertex
    normals, lengths normalized) vote with the sign of their product, weighted by the smaller of
    the two magnitudes (near-degenerate triplets hardly count). Local triplets keep their
    orientation under articulation, and an intrinsic isometry either keeps all or flips all."""
    vote, w = orientation_votes(source, target, pairs, n_neighbors)
    if w.sum() <= 0:
        return 0.0
    return float((vote * w).sum() / w.sum())


#: how many standard errors the mean orientation vote must lie from 0 for a verdict (the usual 3 sigma
#: of a two-sided test at about 0.3 %, not a value fitted to any data set)
ORIENTATION_Z = 3.0


def orientation_verdict(
    source: Shape, target: Shape, target_of: np.ndarray, n_samples: int = 300, n_neighbors: int = 5,
) -> dict[str, Any]:
    """Whether the dense map ``target_of`` ``(n_source,)`` (``-1``: unmatched) keeps orientation:
    ``{"verdict": "preserving" | "reversing" | "undecided", "score", "z", "samples"}``.

    The votes of :func:`orientation_votes` on ``n_samples`` farthest-point samples of the matched
    source vertices are a sample of signs; ``score`` is their weighted mean in ``[-1, 1]`` and ``z``
    that mean over its standard error (weighted, Kish's effective sample size). The verdict is
    ``preserving`` or ``reversing`` when ``|z| >= ORIENTATION_Z`` (3), else ``undecided``: a mirror image
    (left and right swapped) is never reported as a sound map. A map that swaps left and right *and*
    front and back (a half turn) keeps orientation, so this test does not see it. Point clouds
    (no outward normals) and maps of fewer than 4 matches are ``undecided``."""
    t = np.asarray(target_of, dtype=np.int64).ravel()
    out: dict[str, Any] = {"verdict": "undecided", "score": 0.0, "z": 0.0, "samples": 0}
    matched = np.flatnonzero(t >= 0)
    if not (source.is_mesh and target.is_mesh) or len(matched) < 4:
        return out
    rows = matched[farthest_point_sampling(np.asarray(source.vertices)[matched], min(n_samples, len(matched)))]
    vote, w = orientation_votes(source, target, np.column_stack([rows, t[rows]]), n_neighbors)
    wsum = float(w.sum())
    if wsum <= 0:
        return out
    mean = float((vote * w).sum() / wsum)
    n_eff = wsum**2 / max(float((w**2).sum()), 1e-300)
    var = float((w * (vote - mean) ** 2).sum() / wsum)
    se = np.sqrt(max(var, 1e-12) / max(n_eff - 1.0, 1.0))
    z = mean / se
    verdict = "undecided" if abs(z) < ORIENTATION_Z else ("preserving" if z > 0 else "reversing")
    return {"verdict": verdict, "score": mean, "z": float(z), "samples": int(len(rows))}


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
        """The Laplace-Beltrami spectrum with ``k + 1`` eigenpairs (see :func:`default_spec`)."""
        return default_spec(int(self.k) + 1)

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


def side_matcher(orientation: str = "preserving"):
    """The coarse functional map matcher with the orientation term of Ren et al. 2018
    (``fmap-zoomout``: WKS, k = 20, ZoomOut to 50 on 1000 target samples) that the thesis
    pipelines use to tell left from right between two shapes (:func:`side_reference`);
    ``orientation="reversing"`` gives the same coarse matcher with the reversing term (a shape's
    self-symmetry is :func:`symmetry_matcher`'s)."""
    from shape_toolkit.api.registry import create_plugin  # by name: fmap_zoomout imports this module

    return create_plugin("dense_matchers", "fmap-zoomout", k=20, orientation=orientation, zoomout_iters=6,
                         zoomout_step=5, zoomout_samples=1000, hypotheses=({},))


def fine_matcher(orientation: str = "preserving"):
    """The finer functional map matcher of the thesis pipelines' orientation checks
    (``fmap-zoomout``: WKS, k = 30, ZoomOut to 110 in 8 steps of 10, the ``fast`` schedule; every
    vertex queries, and the candidates of the inner steps are all vertices up to 5000 -- every shape
    of the shared 5k sets -- and 5000 farthest-point samples beyond, so that at 245k vertices each
    step is not an exact n x n search; the final map is). ``orientation="reversing"`` is
    :func:`symmetry_matcher`; ``"preserving"`` is the restart of EM's orientation rescue
    (:class:`~shape_toolkit.plugins.matching.dense.em_registration.EMRegistrationMatcher`)."""
    from shape_toolkit.api.registry import create_plugin

    return create_plugin("dense_matchers", "fmap-zoomout", k=30, orientation=orientation, zoomout_iters=8,
                         zoomout_step=10, zoomout_samples=5000, hypotheses=({},))


def symmetry_matcher():
    """The functional map matcher with the orientation-*reversing* term: its self-map of a shape
    is the shape's intrinsic (left-right) symmetry (:func:`fine_matcher` with ``"reversing"``).

    Finer than :func:`side_matcher`'s coarse map: S depends on the source shape alone (never on a
    corrupted target) and is used per region (:func:`symmetry_validity`). Chosen on development pairs
    only (benchmarks/topological_noise.py DEVELOPMENT; 2026-12-02): against the coarse map, clean FAUST
    0.069 -> 0.064 (14 pairs, none worse), clean TOSCA unchanged (8 pairs), FAUST at 6 glued contacts
    0.257 -> 0.232 (8 pairs; two much better, three worse); about 1 s more per shape."""
    return fine_matcher("reversing")


class _IdentityCache:
    """A small LRU of computed values keyed on the *identity* of objects (shapes, spectra) plus a
    hashable ``extra``: entries hold weak references, and a key only hits while every object is
    alive and is the very object it was computed for (an ``id`` reused by a new object misses).
    Shapes and spectra are frozen, so identity stands for content."""

    def __init__(self, size: int = 2):
        self.size = size
        self._d: OrderedDict = OrderedDict()

    def get(self, objs: tuple, extra: Any, compute: Callable[[], Any]) -> Any:
        key = (tuple(id(o) for o in objs), extra)
        hit = self._d.get(key)
        if hit is not None and all(r() is o for r, o in zip(hit[0], objs)):
            self._d.move_to_end(key)
            return hit[1]
        value = compute()
        self._d[key] = (tuple(weakref.ref(o) for o in objs), value)
        while len(self._d) > self.size:
            self._d.popitem(last=False)
        return value

    def clear(self) -> None:
        self._d.clear()


#: the symmetry maps and side references of the last shapes matched: a pipeline's sparse stage and
#: EM ask for the same ones (keyed on the source/target Shape objects and the Spectrum objects used)
_SYMMETRY_CACHE = _IdentityCache()
_SIDE_CACHE = _IdentityCache()


def clear_side_caches() -> None:
    """Forget the cached symmetry maps and side references (:func:`symmetry_map`, :func:`side_reference`)."""
    _SYMMETRY_CACHE.clear()
    _SIDE_CACHE.clear()


def symmetry_map(shape: Shape, spectrum: Spectrum | Sequence[Spectrum] | None = None) -> np.ndarray:
    """The intrinsic symmetry of ``shape`` as a vertex map ``(n,)``: its self-map by
    :func:`symmetry_matcher` (descriptor-preserving and orientation-reversing), computed on the
    caller's spectra (``spectrum``: the list a pipeline hands the stages; None: the cache).

    Cached on the identity of ``shape`` and of the spectrum used (the last two; read-only array),
    so that a pipeline's sparse stage and EM compute it once."""
    given = _given(spectrum)
    m = symmetry_matcher()
    spec = m._spectrum(shape, given)

    def compute() -> np.ndarray:
        t = np.array(m.match(shape, shape, source_spectrum=[spec], target_spectrum=[spec]).target_of, dtype=np.int64)
        t.setflags(write=False)
        return t

    return _SYMMETRY_CACHE.get((shape, spec), None, compute)


def symmetry_validity(shape: Shape, sym: np.ndarray, basis: Basis, k_smooth: int = 20) -> np.ndarray:
    """Where the self-map ``sym`` ``(n,)`` of ``shape`` behaves as a left-right symmetry: boolean ``(n,)``.

    An intrinsic symmetry is an involution (``S(S(x)) = x``) that reverses orientation. Per vertex,
    a vote without any scale constant: ``S(S(x))`` is nearer (Euclidean) to ``x`` than to ``S(x)``
    (+1) or not (-1); low-pass filtered on the first ``k_smooth`` eigenfunctions of ``basis`` (a
    part is judged as a whole), ``S`` is valid where it is positive (near the symmetry plane, where
    ``S(x) ~ x``, the region's vote decides). Orientation is checked globally: when the local triple
    products of the matches ``(x, S(x))`` (:func:`orientation_score` on 120 farthest-point samples)
    do not say *reversing* on the whole, ``S`` is valid nowhere. (Per region the triple products
    are too noisy on thin limbs to veto a part.)"""
    V = np.asarray(shape.vertices, dtype=np.float64)
    s = np.asarray(sym, dtype=np.int64)
    ss = s[s]
    to_x = np.linalg.norm(V[ss] - V, axis=1)
    to_s = np.linalg.norm(V[ss] - V[s], axis=1)
    inv = np.sign(to_s - to_x)
    phi = basis.evecs[:, :k_smooth]

    def smooth(v: np.ndarray) -> np.ndarray:
        return phi @ (phi.T @ (basis.mass * v))

    ok = smooth(inv) > 0
    if shape.is_mesh and shape.n_vertices >= 4:
        rows = farthest_point_sampling(V, min(120, shape.n_vertices))
        if orientation_score(shape, shape, np.column_stack([rows, s[rows]])) >= 0:
            ok[:] = False
    return ok


def _given(spectrum: Spectrum | Sequence[Spectrum] | None) -> list[Spectrum] | None:
    return None if spectrum is None else (list(spectrum) if isinstance(spectrum, (list, tuple)) else [spectrum])


@dataclass(frozen=True)
class SideReference:
    """An orientation-aware functional map source -> target as a yardstick for left and right:
    the source vertices' spectral coordinates ``source_points`` ``(n_s, k)``, the target vertices
    carried into the same coordinates by the map ``target_points`` ``(n_t, k)`` (rows of
    ``Phi_t C^T``, as :func:`p2p_from_fmap` compares them; ``k`` = the map's size after ZoomOut),
    the source ``basis``, and ``k_smooth``, the size of the map fitted before ZoomOut: the
    resolution at which :meth:`prefer` decides sides."""

    source_points: np.ndarray
    target_points: np.ndarray
    basis: Basis
    k_smooth: int
    #: the reference's own point map ``(n_s,)`` (target vertex of each source vertex)
    target_of: np.ndarray | None = None
    #: the target's basis (same size as ``basis``), for :meth:`overlaps`
    target_basis: Basis | None = None

    def sq_distances(self, src: np.ndarray, tgt: np.ndarray) -> np.ndarray:
        """Squared spectral distances ``(q,)`` between source vertices ``src`` and the reference
        images of target vertices ``tgt`` (both ``(q,)``): small when ``(src, tgt)`` agrees with the map."""
        return ((self.source_points[src] - self.target_points[tgt]) ** 2).sum(axis=1)

    def mean_sq_distance(self, target_of: np.ndarray) -> float:
        """Area-weighted mean of :meth:`sq_distances` of a dense map ``target_of`` ``(n_s,)``
        (unmatched entries, -1, are left out): how well the map agrees with the reference."""
        ok = np.flatnonzero(np.asarray(target_of) >= 0)
        w = self.basis.mass[ok]
        return float((w * self.sq_distances(ok, target_of[ok])).sum() / max(w.sum(), 1e-300))

    def prefer(self, target_of: np.ndarray, alternative: np.ndarray) -> np.ndarray:
        """Boolean ``(n_s,)``: where the dense map ``alternative`` agrees better with the reference
        than ``target_of``, decided per region -- the per-vertex difference of squared distances,
        low-pass filtered on the source's first ``k_smooth`` eigenfunctions (a part is judged as a
        whole; near the symmetry plane, where both candidates coincide, the vote is ~0)."""
        t, a = np.asarray(target_of), np.asarray(alternative)
        ok = (t >= 0) & (a >= 0)
        ids = np.flatnonzero(ok)
        vote = np.zeros(len(t))
        vote[ids] = self.sq_distances(ids, t[ids]) - self.sq_distances(ids, a[ids])
        phi = self.basis.evecs[:, : self.k_smooth]
        smooth = phi @ (phi.T @ (self.basis.mass * vote))
        return ok & (smooth > 0)

    def _smooth(self, v: np.ndarray) -> np.ndarray:
        phi = self.basis.evecs[:, : self.k_smooth]
        return phi @ (phi.T @ (self.basis.mass * v))

    def disagrees(self, target_of: np.ndarray) -> np.ndarray:
        """Boolean ``(n_s,)``: the regions where the dense map ``target_of`` is far from the reference
        -- not a side question but a wrong part (two limbs sent onto one target limb): the excess
        ``d(x, T(x)) - d(x, R(x))`` of squared spectral distances over the reference's own map ``R``
        (``>= 0`` up to ZoomOut's last step), low-pass filtered like :meth:`prefer`, is a far-out
        value of its own distribution over the source (Tukey's fence, ``Q3 + 3 IQR``, area-weighted
        quartiles): scale-free, no fitted constant; assumes under a quarter of the area is wrong.
        Unmatched entries (-1) count as disagreeing."""
        t = np.asarray(target_of)
        if self.target_of is None:
            return np.zeros(len(t), dtype=bool)
        ok = t >= 0
        ids = np.flatnonzero(ok)
        excess = np.zeros(len(t))
        excess[ids] = self.sq_distances(ids, t[ids]) - self.sq_distances(ids, self.target_of[ids])
        smooth = self._smooth(excess)
        q1, q3 = _weighted_quantiles(smooth, self.basis.mass, (0.25, 0.75))
        return ~ok | (smooth > q3 + 3.0 * (q3 - q1))

    def overlaps(self, target_of: np.ndarray) -> np.ndarray:
        """Boolean ``(n_s,)``: source vertices whose image lies where the dense map ``target_of``
        piles up more than one layer of the source (two limbs sent onto one): the push-forward of the
        source's (normalized) area onto the target, low-pass filtered on the target's first
        ``k_smooth`` eigenfunctions, is a density relative to the target's (normalized) area, ~1 for
        a bijection and ~2 over a doubly covered part; a vertex overlaps where it exceeds 1.5 (nearer
        two layers than one)."""
        t = np.asarray(target_of)
        out = np.zeros(len(t), dtype=bool)
        if self.target_basis is None:
            return out
        ok = np.flatnonzero(t >= 0)
        bs, bt = self.basis, self.target_basis
        push = np.bincount(t[ok], bs.mass[ok] / bs.mass.sum(), minlength=len(bt.mass))
        phi = bt.evecs[:, : self.k_smooth]
        # phi is M-orthonormal: the density of the measure ``push`` w.r.t. the area is phi phi^T push
        density = (phi @ (phi.T @ push)) * bt.mass.sum()
        out[ok] = density[t[ok]] > 1.5
        return out


def _weighted_quantiles(v: np.ndarray, w: np.ndarray, qs: Sequence[float]) -> list[float]:
    """Quantiles ``qs`` of the values ``v`` ``(n,)`` under the weights ``w`` ``(n,)``."""
    order = np.argsort(v, kind="stable")
    c = np.cumsum(w[order])
    c = c / max(c[-1], 1e-300)
    return [float(v[order[min(int(np.searchsorted(c, q)), len(v) - 1)]]) for q in qs]


def side_reference(
    source: Shape, target: Shape, source_spectrum: Spectrum | Sequence[Spectrum] | None = None,
    target_spectrum: Spectrum | Sequence[Spectrum] | None = None, orientation: str = "preserving",
) -> SideReference:
    """The :class:`SideReference` of :func:`side_matcher` (``orientation``) from ``source`` to
    ``target``, on the caller's spectra (lists as a pipeline hands them; None: the cache).

    Intrinsic descriptors and embeddings cannot tell a map from its mirror image; the functional
    map's orientation term (``sum_f ||C O_t(f) - O_s(f) C||^2``, outward normals) can, and being
    fitted globally at low frequency it also tells which of two mirror-image limbs is which --
    what local triple products of matched points (:func:`orientation_score`) cannot when a
    tubular limb is mapped onto its mirror twin with a twist.

    Cached on the identity of the two shapes and of the spectra used (the last two references), so
    that a pipeline's sparse stage and EM compute it once."""
    m = side_matcher(orientation)
    ss, st = m._spectrum(source, _given(source_spectrum)), m._spectrum(target, _given(target_spectrum))

    def compute() -> SideReference:
        res = m.match(source, target, source_spectrum=[ss], target_spectrum=[st])
        C = np.asarray(res.info["C"])
        k = C.shape[0]
        bs, bt = basis_of(ss, k), basis_of(st, k)
        t = np.array(res.target_of, dtype=np.int64)
        for a in (t, C):
            a.setflags(write=False)
        return SideReference(bs.evecs[:, :k], bt.evecs[:, : C.shape[1]] @ C.T, bs, int(min(m.k, k)), t, bt)

    return _SIDE_CACHE.get((source, target, ss, st), orientation, compute)


def orient_pairs(
    source: Shape, target: Shape, pairs: np.ndarray, source_spectrum: Spectrum | Sequence[Spectrum] | None = None,
    target_spectrum: Spectrum | Sequence[Spectrum] | None = None, orientation: str = "preserving",
) -> np.ndarray:
    """Matches ``pairs`` ``(q, 2)`` with each one's side decided: ``(a, b)`` is replaced by its
    mirror image ``(S(a), b)`` (``S`` = :func:`symmetry_map` of the source) when that agrees better
    with :func:`side_reference` -- only where ``S`` passes :func:`symmetry_validity`; a match that,
    after this, still disagrees with the reference far more than the others (its excess
    ``d(a, b) - d(a, R(a))`` over the reference's own map is beyond Tukey's fence ``Q3 + 3 IQR`` of
    the matches' excesses) is dropped: neither it nor its mirror image is where the reference puts
    it. Duplicate source vertices keep their first match. int64 ``(q', 2)``."""
    p = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if len(p) == 0:
        return p
    ref = side_reference(source, target, source_spectrum, target_spectrum, orientation)
    sym = symmetry_map(source, source_spectrum)
    valid = symmetry_validity(source, sym, ref.basis, ref.k_smooth)
    mirrored = sym[p[:, 0]]
    d_keep = ref.sq_distances(p[:, 0], p[:, 1])
    d_mirror = ref.sq_distances(mirrored, p[:, 1])
    swap = valid[p[:, 0]] & (d_mirror < d_keep)
    out = np.column_stack([np.where(swap, mirrored, p[:, 0]), p[:, 1]])
    if ref.target_of is not None and len(out) >= 4:
        excess = ref.sq_distances(out[:, 0], out[:, 1]) - ref.sq_distances(out[:, 0], ref.target_of[out[:, 0]])
        q1, q3 = np.quantile(excess, [0.25, 0.75])
        out = out[excess <= q3 + 3.0 * (q3 - q1)]
    _, first = np.unique(out[:, 0], return_index=True)
    return out[np.sort(first)]
