"""Left and right of matches.

- Extrinsic: whether matches keep orientation, from local triple products of outward normals
  (:func:`orientation_votes`, :func:`orientation_score`, the test :func:`orientation_verdict`).
- Intrinsic: a shape's symmetry (:func:`symmetry_map`, where it is one: :func:`symmetry_validity`) and
  an orientation-aware functional map as a yardstick of sides (:class:`SideReference`,
  :func:`side_reference`), which decide the side of each sparse match (:func:`orient_pairs`).

The symmetry maps and side references are computed once per pair for a caller that owns a :class:`SideCache`
or opens a ``side_cache_scope()`` (:mod:`.side_cache`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from shape_toolkit.core.geometry import farthest_point_sampling, outward_vertex_normals
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.core.surface import cloud_normals
from shape_toolkit.features.basis import Basis, basis_of, map_residual
from shape_toolkit.plugins.matching.descriptors import shared_spectra
from shape_toolkit.plugins.matching.side_cache import SideCache, cached, scoped, side_cache_scope

__all__ = [
    "orientation_votes", "orientation_score", "ORIENTATION_Z", "orientation_verdict", "reversing_region",
    "side_matcher", "fine_matcher", "symmetry_matcher", "SideCache", "symmetry_map", "symmetry_validity",
    "SideReference", "side_reference", "orient_pairs", "side_cache_scope", "SYMMETRY_FITS",
]


def _outward(shape: Shape) -> np.ndarray:
    """Unit outward normals ``(n, 3)`` of a mesh's vertices, or of a point cloud's points (its own, else PCA normals
    signed by visibility: :func:`~shape_toolkit.core.surface.cloud_normals`, estimated once per cloud)."""
    return outward_vertex_normals(shape) if shape.is_mesh else cloud_normals(shape)


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
    Ns = _outward(source)[p[:, 0]]
    Nt = _outward(target)[p[:, 1]]
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
    front and back (a half turn) keeps orientation, so this test does not see it. Point clouds vote with
    their outward normals (:func:`~shape_toolkit.core.surface.cloud_normals`); maps of fewer than 4 matches
    are ``undecided``."""
    t = np.asarray(target_of, dtype=np.int64).ravel()
    out: dict[str, Any] = {"verdict": "undecided", "score": 0.0, "z": 0.0, "samples": 0}
    matched = np.flatnonzero(t >= 0)
    if len(matched) < 4:
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


def reversing_region(
    source: Shape, target: Shape, target_of: np.ndarray, basis: Basis, k_smooth: int = 20,
) -> np.ndarray:
    """Where the dense map ``target_of`` ``(n_source,)`` (every entry >= 0) reverses orientation on a part of the
    source: boolean ``(n_source,)``, all False when no part does.

    A map can keep orientation on the whole and mirror a part (FAUST: the feet or the arms swapped left for
    right). Every source vertex votes with the local triple products of :func:`orientation_votes`; the votes
    (weighted by their triplets' weight) are low-pass filtered on the first ``k_smooth`` eigenfunctions of
    ``basis`` (a part is judged as a whole, as in :func:`symmetry_validity`), and the region is where that is
    negative. It counts only when the map restricted to it is judged ``reversing`` by
    :func:`orientation_verdict` (3 standard errors, farthest-point samples of the region): a few noisy votes
    are not a mirrored part."""
    t = np.asarray(target_of, dtype=np.int64).ravel()
    n = len(t)
    none = np.zeros(n, dtype=bool)
    if n < 4 or np.any(t < 0):
        return none
    vote, w = orientation_votes(source, target, np.column_stack([np.arange(n), t]))
    region = basis.low_pass(vote * w, k_smooth) < 0
    if region.sum() < 4:
        return none
    if orientation_verdict(source, target, np.where(region, t, -1))["verdict"] != "reversing":
        return none
    return region


def side_matcher(orientation: str = "preserving"):
    """The coarse functional map matcher with the orientation term of Ren et al. 2018
    (``fmap-zoomout``: WKS, k = 20, ZoomOut to 50 on 1000 target samples) that the thesis
    pipelines use to tell left from right between two shapes (:func:`side_reference`);
    ``orientation="reversing"`` gives the same coarse matcher with the reversing term (a shape's
    self-symmetry is :func:`symmetry_matcher`'s)."""
    from shape_toolkit.api.registry import create_plugin  # by name: no import of the plugin module

    return create_plugin("dense_matchers", "fmap-zoomout", k=20, orientation=orientation, zoomout_iters=6,
                         zoomout_step=5, zoomout_samples=1000, hypotheses=({},))


def fine_matcher(orientation: str = "preserving", fit: dict | None = None):
    """The finer functional map matcher of the thesis pipelines' orientation checks
    (``fmap-zoomout``: WKS, k = 30, ZoomOut to 110 in 8 steps of 10, the ``fast`` schedule; every
    vertex queries, and the candidates of the inner steps are all vertices up to 5000 -- every shape
    of the shared 5k sets -- and 5000 farthest-point samples beyond, so that at 245k vertices each
    step is not an exact n x n search; the final map is). ``orientation="reversing"`` is
    :func:`symmetry_matcher`; ``"preserving"`` is the restart of EM's orientation rescue
    (:class:`~shape_toolkit.plugins.matching.dense.em_registration.EMRegistrationMatcher`). ``fit``: a
    functional map fit overriding ``k`` and the weights (one of ``fmap-zoomout``'s hypotheses)."""
    from shape_toolkit.api.registry import create_plugin

    return create_plugin("dense_matchers", "fmap-zoomout", k=30, orientation=orientation, zoomout_iters=8,
                         zoomout_step=10, zoomout_samples=5000, hypotheses=(dict(fit or {}),))


#: the fits :func:`symmetry_map` starts from: pyFM's fit (k = 30) and two coarser fits whose orientation term
#: weighs 10 (where a pose bends the finer eigenfunctions apart, a coarse map still holds left and right)
SYMMETRY_FITS: tuple[dict, ...] = ({}, {"k": 15, "w_orient": 10.0}, {"k": 10, "w_orient": 10.0})
#: eigenfunctions of the ZoomOut residuals the orientation code judges maps by (best-of's when it polishes nothing):
#: the choice among the refined symmetry maps, and a rescue from a conflict with the side reference
#: (``OrientationRepair.rescue``)
RESIDUAL_K = 64


def symmetry_matcher(fit: dict | None = None):
    """The functional map matcher with the orientation-*reversing* term: its self-map of a shape
    is the shape's intrinsic (left-right) symmetry (:func:`fine_matcher` with ``"reversing"``, from ``fit``).

    Finer than :func:`side_matcher`'s coarse map: S depends on the source shape alone (never on a
    corrupted target) and is used per region (:func:`symmetry_validity`); the measurements behind the
    choice: ``benchmarks/results/fmap_zoomout_notes.md``."""
    return fine_matcher("reversing", fit)


def symmetry_map(shape: Shape, spectrum: Spectrum | Sequence[Spectrum] | None = None,
                 cache: SideCache | None = None) -> np.ndarray:
    """The intrinsic symmetry of ``shape`` as a vertex map ``(n,)`` (read-only): its self-map by
    :func:`symmetry_matcher` (descriptor-preserving and orientation-reversing) from each of
    :data:`SYMMETRY_FITS`, refined in full, the one of least ZoomOut residual kept (the fine fit alone
    was wrong on 9 of the 20 FAUST tuning shapes, these three on 3:
    ``benchmarks/results/fmap_zoomout_notes.md``); computed on the caller's spectra (``spectrum``: the
    list a pipeline hands the stages; None: the spectrum cache).
    With a :class:`SideCache`, computed once per ``shape`` and spectrum used."""
    given = shared_spectra(spectrum)
    spec = symmetry_matcher()._spectrum(shape, given)

    def compute() -> np.ndarray:
        b = basis_of(spec, RESIDUAL_K)
        best: tuple[float, np.ndarray] | None = None
        for fit in SYMMETRY_FITS:
            res = symmetry_matcher(fit).match(shape, shape, source_spectrum=[spec], target_spectrum=[spec])
            t = np.array(res.target_of, dtype=np.int64)
            r = map_residual(b, b, t, b.k)
            if best is None or r < best[0]:
                best = (r, t)
        best[1].setflags(write=False)
        return best[1]

    cache = scoped(cache)
    return cached(None if cache is None else cache.symmetry, (shape, spec), None, compute)


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
    ok = basis.low_pass(inv, k_smooth) > 0
    if shape.is_mesh and shape.n_vertices >= 4:
        rows = farthest_point_sampling(V, min(120, shape.n_vertices))
        if orientation_score(shape, shape, np.column_stack([rows, s[rows]])) >= 0:
            ok[:] = False
    return ok


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
        return ok & (self.basis.low_pass(vote, self.k_smooth) > 0)

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
        smooth = self.basis.low_pass(excess, self.k_smooth)
        q1, q3 = _weighted_quantiles(smooth, self.basis.mass, (0.25, 0.75))
        return ~ok | (smooth > q3 + 3.0 * (q3 - q1))

    def conflict_area(self, target_of: np.ndarray) -> float:
        """Share of the source's area where the dense map ``target_of`` ``(n_s,)`` is farther from the reference
        than the reference's own map almost ever is: ``d(x, T(x))`` beyond Tukey's far fence (``Q3 + 3 IQR``,
        area-weighted) of the reference's own ``d(y, R(y))`` (scale-free). About 0 for a map that follows the
        reference, the area of the parts it puts elsewhere otherwise; unmatched entries (-1) count as in
        conflict. 0 without the reference's own map."""
        t = np.asarray(target_of)
        if self.target_of is None:
            return 0.0
        own = self.sq_distances(np.arange(len(t)), np.asarray(self.target_of))
        q1, q3 = _weighted_quantiles(own, self.basis.mass, (0.25, 0.75))
        ok = np.flatnonzero(t >= 0)
        far = np.ones(len(t), dtype=bool)
        far[ok] = self.sq_distances(ok, t[ok]) > q3 + 3.0 * (q3 - q1)
        return float(self.basis.mass[far].sum() / max(float(self.basis.mass.sum()), 1e-300))

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
    cache: SideCache | None = None, landmarks: np.ndarray | None = None,
) -> SideReference:
    """The :class:`SideReference` of :func:`side_matcher` (``orientation``) from ``source`` to
    ``target``, on the caller's spectra (lists as a pipeline hands them; None: the cache).

    Intrinsic descriptors and embeddings cannot tell a map from its mirror image; the functional
    map's orientation term (``sum_f ||C O_t(f) - O_s(f) C||^2``, outward normals) can, and being
    fitted globally at low frequency it also tells which of two mirror-image limbs is which --
    what local triple products of matched points (:func:`orientation_score`) cannot when a
    tubular limb is mapped onto its mirror twin with a twist.

    ``landmarks`` int ``(q, 2)``: matches known to be right (a caller's seeds); they enter the
    functional map as one heat-kernel descriptor per pair, so that where they reach they, not the
    intrinsic descriptors, decide left and right.

    With a :class:`SideCache`, computed once per pair of shapes, spectra and landmarks used."""
    m = side_matcher(orientation)
    lm = None if landmarks is None or len(landmarks) == 0 else np.asarray(landmarks, dtype=np.int64).reshape(-1, 2)
    ss, st = m._spectrum(source, shared_spectra(source_spectrum)), m._spectrum(target, shared_spectra(target_spectrum))

    def compute() -> SideReference:
        res = m.match(source, target, seeds=lm, source_spectrum=[ss], target_spectrum=[st])
        C = np.asarray(res.info["C"])
        k = C.shape[0]
        bs, bt = basis_of(ss, k), basis_of(st, k)
        t = np.array(res.target_of, dtype=np.int64)
        for a in (t, C):
            a.setflags(write=False)
        return SideReference(bs.evecs[:, :k], bt.evecs[:, : C.shape[1]] @ C.T, bs, int(min(m.k, k)), t, bt)

    cache = scoped(cache)
    key = orientation if lm is None else (orientation, hashlib.sha1(lm.tobytes()).hexdigest())
    return cached(None if cache is None else cache.sides, (source, target, ss, st), key, compute)


def orient_pairs(
    source: Shape, target: Shape, pairs: np.ndarray, source_spectrum: Spectrum | Sequence[Spectrum] | None = None,
    target_spectrum: Spectrum | Sequence[Spectrum] | None = None, orientation: str = "preserving",
    cache: SideCache | None = None,
) -> np.ndarray:
    """Matches ``pairs`` ``(q, 2)`` with each one's side decided: ``(a, b)`` is replaced by its
    mirror image ``(S(a), b)`` (``S`` = :func:`symmetry_map` of the source) when that agrees better
    with :func:`side_reference` -- only where ``S`` passes :func:`symmetry_validity`; a match that,
    after this, still disagrees with the reference far more than the others (its excess
    ``d(a, b) - d(a, R(a))`` over the reference's own map is beyond Tukey's fence ``Q3 + 3 IQR`` of
    the matches' excesses) is dropped: neither it nor its mirror image is where the reference puts
    it. int64 ``(q', 2)``, in the order of ``pairs``. ``cache``: a :class:`SideCache` the caller owns (None: the
    symmetry map and reference are computed here).

    Contract: ``pairs`` come in decreasing preference (the association matchers pass them by decreasing score, the
    order :func:`~shape_toolkit.plugins.matching.association.greedy_discretize` chose them in). A source vertex that
    ends up in two matches (one mirrored onto another's source vertex, or given twice) keeps the earlier, preferred
    one: no score is passed here, so a caller with pairs in another order sorts them first."""
    p = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if len(p) == 0:
        return p
    ref = side_reference(source, target, source_spectrum, target_spectrum, orientation, cache)
    sym = symmetry_map(source, source_spectrum, cache)
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
