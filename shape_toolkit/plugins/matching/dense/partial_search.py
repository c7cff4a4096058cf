"""A part matched to a whole shape when the part's share of the whole's area is not known (issue 29, item 3).

The slanted diagonal of a partial functional map (Rodola et al. 2017) has the area ratio as its slope, and
``fmap-zoomout``'s partial maps depend on it sharply (on the tuning half, 10% off the ratio turns a 0.03 map into a
0.5 one). The ratio of the two shapes' areas is exact only when they are in the same units. Here each candidate
ratio gives a map, and the map kept is the one of least geodesic distortion: the isometry every functional map
assumes, tested on distances between farthest-point samples of the part, up to one global scale (so the shapes'
units do not matter). Each candidate's map is also refined by ZoomOut on the Laplacian eigenbasis of its own
support on the whole (a submesh slightly larger than the part's image), whose functions are localized on the region
the part covers (the idea of localized manifold harmonics), and the map of least distortion among the candidates
and their refinements is kept. With ``part_shells`` (the ``partial`` preset), the kept map also places the part's
smooth shells on the whole (:func:`with_part_shells`: extrinsic, only the part pulls), and those maps compete on
the same distortion (tuning half, 30% crops: dogs 0.147 -> 0.085, FAUST people 0-1 unchanged;
benchmarks/results/partial_matching_notes.md, round 4).

The WKS of a part and of the whole at shared energies (:func:`part_wave_kernel_signatures`), which every partial
``fmap-zoomout`` map is fitted on, lives here too.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from shape_toolkit.core.geometry import farthest_point_sampling
from shape_toolkit.core.inspect import largest_face_piece
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.errors import InvalidShapeError
from shape_toolkit.features.basis import (
    Basis,
    SharedPairWork,
    basis_of,
    fmap_from_p2p,
    part_support,
    slanted_size,
    spectral_basis,
    zoomout,
)
from shape_toolkit.features.geodesics import geodesic_distances
from shape_toolkit.plugins.descriptors.wks import wave_kernel_signature as _wks
from shape_toolkit.results.correspondence import Correspondence

__all__ = [
    "part_wave_kernel_signatures", "geodesic_distortion", "support_submesh", "match_over_area_ratios",
    "with_part_shells",
]


def part_wave_kernel_signatures(
    part: Spectrum, whole: Spectrum, scale: float, n_energies: int = 100, variance: float = 7.0, band: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """WKS of a part ``(n_part, n_energies)`` and of the whole shape ``(n_whole, n_energies)`` at the same
    energies. A part has fewer eigenvalues below a frequency, so per-shape energy ranges would not line up: the
    eigenvalues are taken in common units (each area-normalized, the part's times ``scale = area_whole /
    area_part``); the part keeps its first ``round(band * K)`` non-null eigenpairs (at least
    ``PART_WKS_LOWEST + 2``) and the whole its eigenpairs up to the same frequency. The energies start at the
    part's ``PART_WKS_LOWEST``-th non-null eigenvalue: the cut changes the lowest eigenfunctions over the whole
    part, the higher ones mostly near the cut."""
    vp, Up = spectral_basis(part)
    vw, Uw = spectral_basis(whole)
    vp = vp * part.area * float(scale)
    vw = vw * whole.area
    low = min(PART_WKS_LOWEST, vp.size - 2)
    if band < 1.0:
        K = max(low + 2, int(round(band * vp.size)))
        vp, Up = vp[:K], Up[:, :K]
    keep = vw <= vp[-1] * (1 + 1e-9)
    if keep.sum() >= 2:
        vw, Uw = vw[keep], Uw[:, keep]
    rng = (float(np.log(max(vp[low], vw[0]))), float(np.log(min(vp[-1], vw[-1]))))
    return _wks(vp, Up, n_energies, variance, rng), _wks(vw, Uw, n_energies, variance, rng)


#: the part's WKS energies start at its non-null eigenvalue of this index (0: the first). Chosen on the tuning
#: half only (TOSCA dogs, FAUST people 0-1; 6 pairs with 30% cut away, true area ratio): mean error 0.24 with 0,
#: 0.19 with 10, 0.22 with 20 (benchmarks/results/partial_matching_notes.md)
PART_WKS_LOWEST = 10


#: farthest-point samples of the part whose pairwise geodesic distances measure a map's distortion
DISTORTION_SAMPLES = 40

#: the supports tried for the refinement, as multiples of the part's share of the whole's area (a support a
#: little larger than the part: one smaller than it cuts the part's own boundary off and misleads ZoomOut);
#: chosen on the tuning half only (benchmarks/results/partial_matching_notes.md)
SUPPORT_GROWTH = (1.3,)

#: how many candidates, the least distorted first, are refined on their support (None: every one); the map of
#: least distortion among the candidates and every refinement is kept. Every one: with half the area cut away
#: the unrefined maps are all far from an isometry and their distortions do not tell them apart, the refined
#: ones do (tuning half only: 50% cut TOSCA 0.486 -> 0.274 against the least distorted candidate alone;
#: benchmarks/results/partial_matching_notes.md)
REFINED_CANDIDATES: int | None = None


def geodesic_distortion(part_distances: np.ndarray, whole: Shape, images: np.ndarray) -> tuple[float, float]:
    """How far a map is from an isometry up to scale: ``part_distances`` ``(q, q)`` geodesic distances between
    ``q`` samples of the part and ``images`` ``(q,)`` their vertices on ``whole``. Returns the mean absolute
    difference of the distances, the whole's divided by their median ratio to the part's, over the mean part
    distance (unitless, 0 for an isometry), and that median ratio (whole's length units per part's)."""
    dw = geodesic_distances(whole, images, images, method="dijkstra", cache=False)
    iu = np.triu_indices(len(images), 1)
    a, b = part_distances[iu], dw[iu]
    ok = np.isfinite(b) & (a > 0)
    if not ok.any():
        return float("inf"), float("nan")
    scale = float(np.median(b[ok] / a[ok]))
    if not scale > 0:
        return float("inf"), scale
    return float(np.mean(np.abs(b[ok] / scale - a[ok])) / np.mean(a[ok])), scale


def support_submesh(whole: Shape, keep: np.ndarray) -> tuple[Shape, np.ndarray]:
    """The faces of ``whole`` with their three vertices in ``keep`` (boolean ``(n,)``), its largest edge-connected
    piece: the submesh and its vertices' ids on ``whole``."""
    sub, ids = whole.submesh(np.flatnonzero(keep))
    sub2, ids2 = sub.submesh(largest_face_piece(sub))
    return sub2, ids[ids2]


def _refined_on_support(matcher, part: Shape, whole: Shape, bs: Basis, bt: Basis,
                        target_of: np.ndarray, ratio: float, growth: float) -> tuple[np.ndarray, np.ndarray]:
    """``target_of`` refined by partial ZoomOut from the part to the support of ``growth`` times its area: the
    refined map ``(n_s,)`` and the support (target boolean ``(n_t,)``); ``bs``, ``bt``: the full bases of the
    part's and the whole's spectra."""
    keep = part_support(target_of, bs, bt, min(1.0, ratio * growth))
    keep[target_of] = True
    sub, ids = support_submesh(whole, keep)
    inv = np.full(whole.n_vertices, -1, dtype=np.int64)
    inv[ids] = np.arange(ids.size)
    start = np.maximum(inv[target_of], 0)  # a vertex cut off with a sliver of the support: any, refined away
    bsub = basis_of(matcher.spectrum_spec().compute(sub))
    scale = max(1.0, float(bt.mass[ids].sum()) / ratio)  # the support's area over the part's, common units
    k_final = min(matcher.final_basis_size(), part.n_vertices - 1, sub.n_vertices - 1)
    k0 = min(matcher.k, k_final)  # a tiny part or support: ZoomOut starts no larger than it ends
    C0 = fmap_from_p2p(bs, bsub, start, k0, slanted_size(bs, bsub, k0, scale))
    _, T = zoomout(C0, bs, bsub, k_final, matcher.zoomout_step, scale=scale)
    support = np.zeros(whole.n_vertices, dtype=bool)
    support[ids] = True
    return ids[T], support


def match_over_area_ratios(
    matcher, source: Shape, target: Shape, spec_s: Spectrum, spec_t: Spectrum,
    progress: Callable[[str], None] | None = None, **kwargs,
) -> Correspondence:
    """``matcher`` (a partial ``fmap-zoomout`` with ``area_ratios``) run at each of its candidate area ratios and
    at the shapes' areas' ratio, each map (:data:`REFINED_CANDIDATES`) refined on its support
    (:data:`SUPPORT_GROWTH`), the map of least :func:`geodesic_distortion` among them all kept.
    ``info["partial"]["search"]`` records every candidate's ratio and distortion, the refinements' and the choice;
    ``info["partial"]["area_ratio"]`` is the chosen ratio and ``info["partial"]["scale"]`` the whole's length
    units per the part's. What does not depend on the ratio (the bases, the orientation term's gradient frames,
    the samples) is computed once for every candidate (:class:`~shape_toolkit.features.basis.SharedPairWork`).
    The whole ``target`` must be a mesh (the supports are its submeshes)."""
    if not target.is_mesh:  # before the candidates: each refinement's support is a submesh of the whole
        raise InvalidShapeError(
            f"the partial search over area ratios refines each map on a submesh of the whole shape, but the target "
            f"{target!r} is a point cloud: give the whole as a mesh, or pass the part's share of its area "
            "(fmap-zoomout with partial = true and area_ratio = R takes clouds)")
    areas = float(np.sum(spec_s.mass)) / float(np.sum(spec_t.mass)) if spec_s.mass is not None else None
    ratios = [min(areas, 1.0)] if areas is not None and 0 < areas <= 1.5 else []
    for r in map(float, matcher.area_ratios):  # each candidate once (a repeated one was matched again)
        if not any(abs(r - q) < 1e-9 for q in ratios):
            ratios.append(r)
    samples = farthest_point_sampling(np.asarray(source.vertices), min(DISTORTION_SAMPLES, source.n_vertices))
    dp = geodesic_distances(source, samples, samples, method="dijkstra", cache=False)
    shared = SharedPairWork()
    found, rows = [], []  # (distortion, ratio, scale, correspondence) of each candidate

    for r in ratios:
        corr = matcher.match_at_area_ratio(source, target, r, source_spectrum=spec_s, target_spectrum=spec_t,
                                           shared=shared, **kwargs)
        d, scale = geodesic_distortion(dp, target, corr.target_of[samples])
        rows.append({"area_ratio": r, "distortion": d})
        if progress is not None:
            progress(f"partial: area ratio {r:.3g}, geodesic distortion {d:.3g}")
        found.append((d, r, scale, corr))
    order = sorted(range(len(found)), key=lambda i: found[i][0])  # stable: the first of equal distortions
    d, r, scale, corr = found[order[0]]
    T, support, refined = corr.target_of, corr.info["partial"]["support"], []
    bs, bt = shared.basis(spec_s, None), shared.basis(spec_t, None)
    for i in order[:REFINED_CANDIDATES]:
        _, ri, _, ci = found[i]
        for growth in SUPPORT_GROWTH:
            T2, keep = _refined_on_support(matcher, source, target, bs, bt, ci.target_of, ri, growth)
            d2, s2 = geodesic_distortion(dp, target, T2[samples])
            refined.append({"area_ratio": ri, "growth": growth, "distortion": d2})
            if d2 < d:
                d, r, corr, T, scale, support = d2, ri, ci, T2, s2, keep
    info = dict(corr.info)
    info["partial"] = {**info["partial"], "area_ratio": r, "scale": scale, "support": support, "search": {
        "candidates": rows, "refined": refined, "distortion": d}}
    found_map = Correspondence(T, target.n_vertices, info=info)
    if getattr(matcher, "part_shells", False):
        found_map = with_part_shells(matcher, source, target, spec_s, spec_t, found_map, dp, samples, bs, bt, progress)
    seeds = kwargs.get("seeds")
    if getattr(matcher, "trust_seeds", False) and seeds is not None and len(seeds):  # refined or shells maps too
        found_map = found_map.with_pairs(seeds)
    return found_map


def with_part_shells(
    matcher, source: Shape, target: Shape, spec_s: Spectrum, spec_t: Spectrum, found: Correspondence,
    part_distances: np.ndarray, samples: np.ndarray, bs: Basis, bt: Basis,
    progress: Callable[[str], None] | None = None,
) -> Correspondence:
    """The map ``found`` of :func:`match_over_area_ratios` against the part's smooth shells placed on the whole
    from it (:meth:`~shape_toolkit.plugins.matching.dense.shell_alignment.ShellAlignmentMatcher.match_part` at
    its area ratio): in the given frame and, when ``found`` keeps orientation, in the frame it estimates (the
    rotation of the ``best-of`` pipeline, :func:`~shape_toolkit.plugins.matching.frames.estimated_frame`),
    each also refined on its support (:data:`SUPPORT_GROWTH`'s first growth); the map of least
    :func:`geodesic_distortion` (``part_distances`` ``(q, q)`` between the part's ``samples``) kept.
    ``info["partial"]["shells"]`` lists every shells map's distortion and which map was kept
    (``"search"``: ``found``); ``bs``, ``bt``: the full bases of the two spectra."""
    from shape_toolkit.plugins.matching.dense.shell_alignment import ShellAlignmentMatcher
    from shape_toolkit.plugins.matching.frames import estimated_frame

    part = found.info["partial"]
    d, ratio, T, support, chosen = part["search"]["distortion"], part["area_ratio"], found.target_of, None, "search"
    scale, shells, rows = part["scale"], ShellAlignmentMatcher(partial=True), []
    # every estimated frame is run (same = 0 degrees): measured so; a part's start is less certain than a whole's
    turned, frame = estimated_frame(source, target, np.asarray(T), bs.mass, "partial search", 0.0)
    growth = SUPPORT_GROWTH[0]
    for label, src in [("given", source)] + ([("estimated", turned)] if turned is not None else []):
        c = shells.match_part(src, target, np.asarray(found.target_of), ratio, source_spectrum=spec_s,
                              target_spectrum=spec_t)
        T2, keep = _refined_on_support(matcher, source, target, bs, bt, c.target_of, ratio, growth)
        for name, Tc, sup in ((label, c.target_of, None), (f"{label}+zoomout", T2, keep)):
            dc, sc = geodesic_distortion(part_distances, target, Tc[samples])
            rows.append({"frame": name, "distortion": dc})
            if progress is not None:
                progress(f"partial: shells ({name}), geodesic distortion {dc:.3g}")
            if dc < d:
                d, T, scale, support, chosen = dc, Tc, sc, sup, name
    if support is None and chosen != "search":  # the shells' own map: its support as the search's maps have one
        support = part_support(T, bs, bt, ratio)
    info = dict(found.info)
    info["partial"] = {**part, "scale": scale, "support": part["support"] if support is None else support,
                       "shells": {"candidates": rows, "chosen": chosen, "distortion": d,
                                  "estimated_frame": frame}}
    return Correspondence(T, target.n_vertices, info=info)
