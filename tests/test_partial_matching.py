"""Partial shapes (issue 29, item 3): the slanted functional-map size against Weyl's law on a sphere and a
hemisphere, a crop of a shape matched to the shape itself (the crop's back-map is the ground truth), and the bad
inputs of the ``partial`` pipeline."""

from __future__ import annotations

import numpy as np
import pytest

from shape_toolkit.core.shape import Shape
from shape_toolkit.data.corruptions import crop
from shape_toolkit.data.generate import icosphere
from shape_toolkit.errors import DisconnectedGraphError, InvalidShapeError, ParameterError
from shape_toolkit.features.basis import Basis, basis_of, slanted_size
from shape_toolkit.plugins.matching.dense.fmap_zoomout import FmapZoomOutMatcher
from shape_toolkit.spectra import default_spec


def _hemisphere(sphere: Shape) -> Shape:
    """The faces of ``sphere`` with every vertex at z >= 0, unreferenced vertices dropped."""
    keep = sphere.vertices[:, 2] >= -1e-9
    f = sphere.faces[keep[sphere.faces].all(axis=1)]
    used = np.unique(f)
    remap = np.full(sphere.n_vertices, -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    return Shape(sphere.vertices[used], remap[f])


@pytest.fixture(scope="module")
def sphere_and_hemisphere() -> tuple[Basis, Basis, float]:
    s = icosphere(4)  # 2,562 vertices
    h = _hemisphere(s)
    return basis_of(default_spec(200).compute(s)), basis_of(default_spec(200).compute(h)), s.area / h.area


@pytest.mark.parametrize("k, L", [(36, 7), (64, 10), (100, 13)])
def test_slanted_size_counts_the_spheres_eigenvalues_below_the_hemispheres(sphere_and_hemisphere, k, L):
    """Analytic spectra: the unit sphere's eigenvalues are l(l+1) with multiplicity 2l+1, the hemisphere's
    (free boundary) l(l+1) with multiplicity l+1 (the modes even across the equator). The hemisphere's k-th
    eigenvalue is l = L, so the sphere has (L+1)^2 eigenvalues up to it: about twice k (Weyl's law, area ratio
    2, less a boundary term). ``slanted_size`` with the mesh areas' ratio finds that count on the meshes."""
    whole, part, scale = sphere_and_hemisphere
    assert abs(scale - 2.0) < 0.05
    assert sum(l + 1 for l in range(L)) < k <= sum(l + 1 for l in range(L + 1))  # the part's k-th is l = L
    kt = slanted_size(part, whole, k, scale)
    assert abs(kt - (L + 1) ** 2) <= 2  # the discrete clusters spread a little
    assert 1.7 * k < kt <= 2 * k


def test_slanted_size_of_two_whole_shapes_is_k_and_stays_in_the_target_basis(sphere_and_hemisphere):
    whole, part, _ = sphere_and_hemisphere
    assert slanted_size(part, whole, 40, None) == 40
    assert slanted_size(part, whole, 150, 2.0) == whole.k  # beyond the computed spectrum: truncated, not past it
    # the same shape: at least k, at most the end of the k-th eigenvalue's cluster (l = 7: eigenvalues 50-64)
    assert 50 <= slanted_size(whole, whole, 50, 1.0) <= 64


@pytest.mark.slow
def test_a_crop_matched_to_its_whole_shape_recovers_the_back_map(shared_data):
    """TOSCA dog0 with 30% of its area cut away, matched to dog0 itself: the crop's back-map is the exact
    answer. ``partial`` finds it to within about one edge on average, its support on the whole being the kept region;
    the whole-shape ``zoomout`` cannot (the part's spectrum is not the whole's)."""
    from shape_toolkit.io.mesh import load_shape
    from shape_toolkit.metrics.correspondence import geodesic_errors

    whole = load_shape(shared_data / "tosca5k" / "dog0.off")
    part, back = crop(whole, strength=0.3, random_state=1, attempts=20)
    assert 0.65 < part.area / whole.area < 0.75
    sel = np.arange(0, part.n_vertices, 10)
    err = {}
    for partial in (False, True):
        c = FmapZoomOutMatcher(partial=partial).match(part, whole)
        err[partial] = float(geodesic_errors(whole, c.target_of, sel, back[sel], method="dijkstra").mean())
        if partial:
            assert abs(c.info["partial"]["area_ratio"] - part.area / whole.area) < 1e-9
            assert c.info["partial"]["k_target_final"] > c.info["k_final"]
            # the recovered support is the kept region (up to its rim) and the map stays inside it
            support, kept = c.info["partial"]["support"], np.zeros(whole.n_vertices, dtype=bool)
            kept[back] = True
            assert support[c.target_of].all()
            assert _iou(support, kept) > 0.85
    assert err[True] < 0.03  # measured 0.011 (sqrt(area) units)
    assert err[False] > 5 * err[True]  # measured 0.46


def test_partial_parameters_are_refused_in_one_line(sphere_and_hemisphere):
    s = icosphere(2)
    h = _hemisphere(s)
    with pytest.raises(ParameterError, match="needs partial"):
        FmapZoomOutMatcher(area_ratio=0.5).match(h, s)
    for bad in (0.0, 1.5, -0.2):
        with pytest.raises(ParameterError, match="area_ratio"):
            FmapZoomOutMatcher(partial=True, area_ratio=bad).match(h, s)
    # a "part" with 4x the whole's area: the units differ, and the message names the way out
    big = Shape(h.vertices * 3.0, h.faces)
    with pytest.raises(ParameterError, match="same units.*area_ratio"):
        FmapZoomOutMatcher(partial=True, k=10, zoomout_iters=1).match(big, s)


def test_the_whole_given_as_the_part_is_matched_with_a_warning():
    """Whole -> part within the unit tolerance (here the sphere -> its hemisphere scaled to the sphere's area) is
    in range, but no part: it runs as two whole shapes and says the part must be the source."""
    s = icosphere(2)
    h = _hemisphere(s)
    h_as_big = Shape(h.vertices * np.sqrt(s.area / h.area / 1.2), h.faces)  # the sphere is 1.2x its area
    with pytest.warns(UserWarning, match="not smaller than the target.*part must be the source"):
        corr = FmapZoomOutMatcher(partial=True, k=10, zoomout_iters=1).match(s, h_as_big)
    assert corr.info["partial"]["area_ratio"] == 1.0
    import warnings

    with warnings.catch_warnings():  # the right way round: no warning
        warnings.simplefilter("error")
        FmapZoomOutMatcher(partial=True, k=10, zoomout_iters=1).match(h, s)


def test_a_part_in_two_pieces_is_refused_naming_the_ways_out():
    """Two hemispheres far apart as one part: its spectrum mixes the pieces, so the pipeline refuses it with
    the ways out (keep the largest piece) instead of matching nonsense."""
    from shape_toolkit.pipeline import run_pipeline

    s = icosphere(2)
    h = _hemisphere(s)
    two = Shape(np.vstack([h.vertices, h.vertices + [5.0, 0, 0]]), np.vstack([h.faces, h.faces + h.n_vertices]))
    with pytest.raises(DisconnectedGraphError, match="keep-largest"):
        run_pipeline("partial", two, s)


def test_crop_attempts_retry_other_centres_deterministically():
    """``attempts``: a seed whose first centre falls on a piece smaller than the cut gets the next centre of the
    same draw; a seed whose first centre works gives the same crop whatever ``attempts``; attempts < 1 is
    refused."""
    a, b = icosphere(1), icosphere(2)  # a small sphere (42 vertices, 1% of the area) and a large one
    shape = Shape(np.vstack([a.vertices, 10 * b.vertices + [30.0, 0, 0]]), np.vstack([a.faces, b.faces + a.n_vertices]))
    first = [int(np.random.default_rng(rs).integers(shape.n_vertices)) for rs in range(40)]
    failing = next(rs for rs in range(40) if first[rs] < a.n_vertices)  # a centre on the small sphere
    working = next(rs for rs in range(40) if first[rs] >= a.n_vertices)
    with pytest.raises(InvalidShapeError, match="random_state"):
        crop(shape, strength=0.3, random_state=failing)
    part, back = crop(shape, strength=0.3, random_state=failing, attempts=40)
    assert back.min() >= a.n_vertices  # cut from the large sphere, kept in one piece
    assert abs(shape.vertex_areas[back].sum() / shape.area - 0.7) <= 0.05  # the kept vertices hold 70% of it
    np.testing.assert_array_equal(crop(shape, strength=0.3, random_state=working, attempts=40)[1],
                                  crop(shape, strength=0.3, random_state=working)[1])
    with pytest.raises(ParameterError, match="attempts"):
        crop(shape, strength=0.3, attempts=0)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def test_part_support_recovers_the_cut_region_from_a_scattered_map():
    """A crop of an icosphere mapped by its exact back-map, a tenth of its vertices sent to random vertices of the
    whole: the support holds the crop's share of the area where the image is dense, so it is the kept region up
    to its rim (the scattered tenth does not move it); fed a map onto the wrong half, it finds that half."""
    from shape_toolkit.features.basis import part_support

    whole = icosphere(4)
    part, back = crop(whole, strength=0.3, random_state=3)
    bs, bw = basis_of(default_spec(40).compute(part)), basis_of(default_spec(40).compute(whole))
    truth = np.zeros(whole.n_vertices, dtype=bool)
    truth[back] = True
    T = back.copy()
    rng = np.random.default_rng(0)
    noisy = rng.choice(part.n_vertices, part.n_vertices // 10, replace=False)
    T[noisy] = rng.integers(whole.n_vertices, size=noisy.size)
    ratio = part.area / whole.area
    support = part_support(T, bs, bw, ratio)
    assert abs(float(bw.mass[support].sum()) - ratio) < 0.01  # the part's share of the area, to one vertex
    assert _iou(support, truth) > 0.9
    mirrored = np.flatnonzero(~truth)[rng.integers((~truth).sum(), size=part.n_vertices)]  # all onto the cut ball
    assert _iou(part_support(mirrored, bs, bw, 0.3), ~truth) > 0.7



def test_geodesic_distortion_is_nil_for_an_isometry_in_other_units_and_large_for_a_shuffle():
    """The identity of a sphere onto the same sphere twice as large: no distortion, and the scale is 2 (the units
    do not matter); the samples' images shuffled: far from an isometry."""
    from shape_toolkit.features.geodesics import geodesic_distances
    from shape_toolkit.plugins.matching.dense.partial_search import geodesic_distortion

    s = icosphere(3)
    big = Shape(2.0 * s.vertices, s.faces)
    ids = np.arange(0, s.n_vertices, 23)
    dp = geodesic_distances(s, ids, ids, method="dijkstra", cache=False)
    d, scale = geodesic_distortion(dp, big, ids)
    assert d < 1e-9 and abs(scale - 2.0) < 1e-9
    d_shuffled, _ = geodesic_distortion(dp, big, np.random.default_rng(0).permutation(ids))
    assert d_shuffled > 0.3


def test_area_ratios_need_partial():
    s = icosphere(2)
    with pytest.raises(ParameterError, match="area_ratios.*needs partial"):
        FmapZoomOutMatcher(area_ratios=[0.5, 1.0]).match(_hemisphere(s), s)
    for bad in ({"partial": True}, {"partial": True, "area_ratios": [0.5], "area_ratio": 0.5}):
        with pytest.raises(ParameterError, match="part_shells.*area_ratios"):
            FmapZoomOutMatcher(part_shells=True, **bad).match(_hemisphere(s), s)


@pytest.mark.slow
def test_the_partial_pipeline_finds_the_area_ratio_of_a_part_in_other_units(shared_data):
    """dog0 with 30% cut away (0.686 of its area), scaled by 1.3, against dog0: the areas' ratio is then 1.16 (a part
    larger than the whole, taken as 1) and the areas-only match fails; the ``partial`` preset keeps the map of least
    geodesic distortion among the candidate ratios' maps and their refinements on their supports: one of a candidate
    next to the truth (0.6 or 0.7: each refinement re-finds the part's region), at the right scale, mapping most of
    the part to its own vertices."""
    from shape_toolkit.io.mesh import load_shape
    from shape_toolkit.metrics.correspondence import geodesic_errors
    from shape_toolkit.pipeline import run_pipeline

    whole = load_shape(shared_data / "tosca5k" / "dog0.off")
    part, back = crop(whole, strength=0.3, random_state=1, attempts=20)
    ratio = part.area / whole.area
    part = Shape(1.3 * part.vertices, part.faces)
    sel = np.arange(0, part.n_vertices, 10)
    corr = run_pipeline("partial", part, whole)
    found = corr.info["partial"]
    assert abs(found["area_ratio"] - ratio) < 0.1  # a candidate next to the truth (measured 0.6)
    assert abs(found["scale"] - 1 / 1.3) < 0.05
    search = found["search"]
    assert search["distortion"] == min(c["distortion"] for c in search["candidates"] + search["refined"])
    shells = found["shells"]  # the part's shells placed from the search's map compete on the same distortion
    assert shells["distortion"] == min([search["distortion"]] + [c["distortion"] for c in shells["candidates"]])
    assert {c["frame"] for c in shells["candidates"]} >= {"given", "given+zoomout"}
    err = geodesic_errors(whole, corr.target_of, sel, back[sel], method="dijkstra")
    with pytest.warns(UserWarning, match="not smaller than the target"):
        areas_only = FmapZoomOutMatcher(partial=True).match(part, whole)
    err_areas = geodesic_errors(whole, areas_only.target_of, sel, back[sel], method="dijkstra")
    assert np.median(err) < 0.01 and err.mean() < 0.5 * err_areas.mean()  # measured 0 and 0.017 against 0.54


def test_a_candidate_ratio_with_the_shared_work_is_the_map_of_that_ratio_alone():
    """``match_at_area_ratio`` with a :class:`SharedPairWork` already filled by another candidate (its bases,
    surfaces, gradient frames and samples, the frames grown to a larger target basis) gives, bit for bit, the map
    and functional map of a fresh partial matcher given that ``area_ratio``; without ``partial`` it is refused."""
    from shape_toolkit.features.basis import SharedPairWork

    whole = icosphere(3)
    part, _ = crop(whole, strength=0.3, random_state=2)
    kw = {"k": 12, "zoomout_iters": 4, "zoomout_step": 4, "selection_samples": 100}
    m = FmapZoomOutMatcher(partial=True, **kw)
    spec_s, spec_t = m.spectrum_spec().compute(part), m.spectrum_spec().compute(whole)
    shared = SharedPairWork()
    for r in (0.4, 0.7):  # 0.4 first: the target's gradient frame is then larger than 0.7 needs
        got = m.match_at_area_ratio(part, whole, r, source_spectrum=spec_s, target_spectrum=spec_t, shared=shared)
    alone = FmapZoomOutMatcher(partial=True, area_ratio=0.7, **kw).match(
        part, whole, source_spectrum=spec_s, target_spectrum=spec_t)
    assert got.target_of.tobytes() == alone.target_of.tobytes()
    assert got.info["C"].tobytes() == alone.info["C"].tobytes()
    assert got.info["partial"]["area_ratio"] == alone.info["partial"]["area_ratio"] == 0.7
    assert any(key[0] == "frame" for key in shared._items)  # the orientation term used the kept frames
    with pytest.raises(ParameterError, match="needs partial"):
        FmapZoomOutMatcher(**kw).match_at_area_ratio(part, whole, 0.7)


def test_orientation_operators_from_a_larger_gradient_frame_are_the_same_bits():
    from shape_toolkit.features.basis import gradient_frame, orientation_operators

    s = icosphere(3)
    b = basis_of(default_spec(40).compute(s))
    desc = np.random.default_rng(0).normal(size=(s.n_vertices, 7))
    frame = gradient_frame(s, b, 35)
    assert frame.k == 35
    kept = orientation_operators(s, b, 20, desc, frame=frame)
    assert kept.tobytes() == orientation_operators(s, b, 20, desc).tobytes()


def test_a_part_smaller_than_the_zoomout_basis_is_matched():
    """A part (and so its support on the whole) with fewer vertices than the matcher's ``k``: the refinement on
    the support starts ZoomOut at most at its final size (it began at ``k`` and crashed with a shape mismatch)."""
    s = icosphere(2)  # 162 vertices
    cap = s.submesh(np.flatnonzero(s.vertices[:, 2] > 0.85))[0]
    assert cap.n_vertices < 20
    m = FmapZoomOutMatcher(partial=True, area_ratios=[0.5], k=20, zoomout_iters=1, hypotheses=[{}])
    corr = m.match(cap, s)
    assert corr.n_matched == cap.n_vertices and corr.target_of.max() < s.n_vertices
    assert corr.info["partial"]["search"]["refined"]  # the refinement ran


def test_the_partial_search_refuses_a_cloud_as_the_whole_before_the_candidates():
    """The search refines each candidate on a submesh of the whole: a point-cloud whole is refused in one line
    naming the ways out (it failed after every candidate with 'its largest piece needs a triangle mesh')."""
    s = icosphere(2)
    cap = s.submesh(np.flatnonzero(s.vertices[:, 2] > 0))[0]
    m = FmapZoomOutMatcher(partial=True, area_ratios=[0.5], k=10, zoomout_iters=1, hypotheses=[{}])
    with pytest.raises(InvalidShapeError, match="point cloud: give the whole as a mesh.*area_ratio") as err:
        m.match(cap, Shape(s.vertices, None))
    assert "\n" not in str(err.value)


def test_a_repeated_candidate_area_ratio_is_matched_once():
    """area_ratios = [0.5, 0.5]: the second 0.5 was a third candidate, the same map computed again."""
    s = icosphere(2)
    cap = s.submesh(np.flatnonzero(s.vertices[:, 2] > 0))[0]
    m = FmapZoomOutMatcher(partial=True, area_ratios=[0.5, 0.5], k=10, zoomout_iters=1, hypotheses=[{}])
    rows = m.match(cap, s).info["partial"]["search"]["candidates"]
    assert len(rows) == 2 and rows[1]["area_ratio"] == 0.5  # the areas' ratio, then 0.5


def test_the_partial_search_keeps_the_seed_pairs():
    """Seeds given to the partial search stay in the map it keeps, whichever candidate or refinement that is (as in
    every matcher's map; a pair the rest of the map does not follow included), and not when they are not trusted."""
    s = icosphere(3)  # here a map refined on its support is kept: the search's candidates held the seeds
    cap = s.submesh(np.flatnonzero(s.vertices[:, 2] > 0))[0]
    top, side = int(np.argmax(cap.vertices[:, 2])), int(np.argmin(cap.vertices[:, 2]))
    far = int(np.argmin(s.vertices[:, 2]))  # the bottom of the sphere: no part of the cap maps there
    seeds = np.array([[top, int(np.argmax(s.vertices[:, 2]))], [side, far]])
    kw = {"partial": True, "area_ratios": [0.5], "k": 10, "zoomout_iters": 1, "hypotheses": [{}]}
    corr = FmapZoomOutMatcher(**kw).match(cap, s, seeds=seeds)
    np.testing.assert_array_equal(corr.target_of[seeds[:, 0]], seeds[:, 1])
    assert FmapZoomOutMatcher(trust_seeds=False, **kw).match(cap, s, seeds=seeds).target_of[side] != far


def test_part_shells_with_a_small_k_declare_the_spectrum_the_shells_need():
    """``part_shells`` with ``k = 10``: the matcher's own spectrum (31 eigenpairs) was all it declared and computed,
    and the part's shells refused it (SpectrumMismatchError naming ShellAlignmentMatcher)."""
    from shape_toolkit.plugins.matching.dense.shell_alignment import ShellAlignmentMatcher

    s = icosphere(3)
    cap = s.submesh(np.flatnonzero(s.vertices[:, 2] > 0))[0]
    m = FmapZoomOutMatcher(partial=True, area_ratios=[0.5], k=10, zoomout_iters=1, hypotheses=[{}], part_shells=True)
    assert m.spectrum_spec().k >= ShellAlignmentMatcher(partial=True).spectrum_spec().k
    corr = m.match(cap, s)
    assert corr.n_matched == cap.n_vertices and corr.info["partial"]["shells"]["candidates"]
