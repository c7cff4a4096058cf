"""Segmentation metrics against hand-computed examples (PSB metrics and thesis 5.5 recall/precision)."""

from __future__ import annotations

import numpy as np
import pytest

from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.metrics.segmentation import (
    SEGMENTATION_METRICS,
    _average_radius,
    consistency_errors,
    cut_discrepancy,
    hamming_distance,
    matched_recall_precision,
    rand_index_error,
    segmentation_scores,
)


def grid(nx: int = 10, ny: int = 6) -> Shape:
    """A flat unit-spaced grid mesh, x in [0, nx], y in [0, ny]."""
    xs, ys = np.meshgrid(np.arange(nx + 1.0), np.arange(ny + 1.0), indexing="ij")
    v = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    idx = np.arange(v.shape[0]).reshape(nx + 1, ny + 1)
    f = []
    for i in range(nx):
        for j in range(ny):
            a, b, c, d = idx[i, j], idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]
            f += [[a, b, c], [a, c, d]]
    return Shape(v, np.array(f), "grid")


def split_at(mesh: Shape, x: float) -> np.ndarray:
    """Face labels: 0 left of the vertical line at ``x``, 1 right of it."""
    return (mesh.vertices[mesh.faces].mean(axis=1)[:, 0] > x).astype(np.int64)


def test_identical_segmentations_score_perfectly():
    mesh = grid()
    lab = split_at(mesh, 4)
    s = segmentation_scores(lab, [lab, lab], mesh=mesh)
    for name in ("rand_index_error", "cut_discrepancy", "hamming", "hamming_rm", "hamming_rf", "gce", "lce"):
        assert s[name] == pytest.approx(0.0, abs=1e-12), name
    assert s["recall"] == pytest.approx(1.0) and s["precision"] == pytest.approx(1.0)
    assert s["n_truths"] == 2 and set(SEGMENTATION_METRICS) <= set(s)


def test_label_permutation_invariance():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 4, 200)
    b = rng.integers(0, 3, 200)
    w = rng.uniform(0.5, 2.0, 200)
    perm = np.array([7, 2, 9, 4])  # relabel a: 0->7, 1->2, ...
    a2 = perm[a]
    assert rand_index_error(a, b, w) == pytest.approx(rand_index_error(a2, b, w))
    assert hamming_distance(a, b, w) == pytest.approx(hamming_distance(a2, b, w))
    assert consistency_errors(a, b, w) == pytest.approx(consistency_errors(a2, b, w))
    assert matched_recall_precision(a, b, w) == pytest.approx(matched_recall_precision(a2, b, w))


def test_rand_index_known_values():
    # 6 pairs; a groups (0,1) and (2,3); b groups everything: 4 pairs disagree
    assert rand_index_error([0, 0, 1, 1], [0, 0, 0, 0]) == pytest.approx(4 / 6)
    # a: (0,1),(2,3) together; b: (0,2),(1,3) together; agree only on (0,3),(1,2) apart
    assert rand_index_error([0, 0, 1, 1], [0, 1, 0, 1]) == pytest.approx(4 / 6)
    # a uniform scaling of the weights changes nothing; unit weights = classic Rand index
    assert rand_index_error([0, 0, 1, 1], [0, 1, 1, 1], np.full(4, 3.0)) == pytest.approx(3 / 6)
    # weights: pair weight w_i w_j over pairs i != j; element 3 weighs 2
    w = np.array([1.0, 1.0, 1.0, 2.0])
    # disagreeing pairs of ([0,0,1,1], [0,1,1,1]): (0,1) w=1, (1,2) w=1, (1,3) w=2 -> 4
    # all pairs: (1+1+1+2)^2 - (1+1+1+4) = 18, halved for unordered pairs -> 9
    assert rand_index_error([0, 0, 1, 1], [0, 1, 1, 1], w) == pytest.approx(4 / 9)


def test_hamming_missing_and_false_alarm_rates():
    pred = np.array([0, 0, 0, 0])  # under-segmentation: nothing missed, half falsely merged
    truth = np.array([0, 0, 1, 1])
    hd, rm, rf = hamming_distance(pred, truth)
    assert (rm, rf, hd) == pytest.approx((0.0, 0.5, 0.25))
    hd, rm, rf = hamming_distance(truth, pred)  # over-segmentation: the reverse
    assert (rm, rf, hd) == pytest.approx((0.5, 0.0, 0.25))


def test_consistency_errors_known_values():
    # a refinement has no consistency error at all
    assert consistency_errors([0, 0, 1, 1], [0, 0, 0, 0]) == pytest.approx((0.0, 0.0))
    # crossing halves: every element loses half of its region in both directions
    assert consistency_errors([0, 0, 1, 1], [0, 1, 0, 1]) == pytest.approx((0.5, 0.5))
    # GCE >= LCE always
    rng = np.random.default_rng(1)
    a, b = rng.integers(0, 5, 300), rng.integers(0, 3, 300)
    gce, lce = consistency_errors(a, b)
    assert gce >= lce - 1e-12


def test_matched_recall_precision_known_values():
    truth = np.array([0, 0, 0, 0, 1, 1, 1, 1])
    pred = np.array([0, 0, 1, 1, 2, 2, 2, 2])  # truth segment 0 split in two
    rec, prec = matched_recall_precision(pred, truth)
    assert rec == pytest.approx((2 / 4 + 4 / 4) / 2)
    assert prec == pytest.approx((1 + 0 + 1) / 3)
    # weights count: element 0 weighs 3, so the best match of truth 0 is pred 0 (weight 4 of 6)
    w = np.array([3.0, 1, 1, 1, 1, 1, 1, 1])
    rec, _ = matched_recall_precision(pred, truth, w)
    assert rec == pytest.approx((4 / 6 + 1) / 2)


def test_cut_discrepancy_of_parallel_cuts():
    mesh = grid(10, 6)
    truth, pred = split_at(mesh, 4), split_at(mesh, 6)
    # every point of one straight cut is exactly 2 edges from the other one, in both directions
    expected = (2.0 + 2.0) / _average_radius(mesh)
    assert cut_discrepancy(pred, truth, mesh) == pytest.approx(expected)
    assert cut_discrepancy(truth, pred, mesh) == pytest.approx(expected)
    # the radius is the area-weighted mean distance of the surface to its centroid
    c = mesh.vertices[mesh.faces].mean(axis=1)
    assert _average_radius(mesh) == pytest.approx(np.mean(np.linalg.norm(c - [5, 3, 0], axis=1)))
    # no cut on either side: 0; on one side only: undefined
    zeros = np.zeros(mesh.n_faces, dtype=np.int64)
    assert cut_discrepancy(zeros, zeros, mesh) == 0.0
    assert np.isnan(cut_discrepancy(zeros, truth, mesh))


def test_scores_use_face_areas():
    mesh = grid(10, 6)
    truth, pred = split_at(mesh, 4), split_at(mesh, 6)
    # scaling the mesh scales every area equally: nothing changes, cut discrepancy is normalised
    big = Shape(mesh.vertices * 3.0, mesh.faces)
    a = segmentation_scores(pred, [truth], mesh=mesh)
    b = segmentation_scores(pred, [truth], mesh=big)
    for name in SEGMENTATION_METRICS:
        assert a[name] == pytest.approx(b[name]), name
    # 2 of 10 columns on the wrong side: each truth segment (and each predicted one) loses at most
    # that strip to its best match, so both Hamming rates equal the strip's area fraction
    assert a["hamming_rf"] == pytest.approx(0.2) and a["hamming_rm"] == pytest.approx(0.2)


def test_size_mismatch_is_a_parameter_error():
    mesh = grid()
    lab = split_at(mesh, 4)
    with pytest.raises(ParameterError, match="labels"):
        segmentation_scores(lab, [lab[:-1]], mesh=mesh)
    with pytest.raises(ParameterError):
        segmentation_scores(lab[:-1], [lab[:-1]], mesh=mesh)
    with pytest.raises(ParameterError):
        rand_index_error([0, 1], [0, 1, 1])
    with pytest.raises(ParameterError, match="no ground-truth"):
        segmentation_scores(lab, [], mesh=mesh)


# ------------------------------------------------------------------------------------------------
# O(n) memory implementation against a brute-force O(n^2) reference
# ------------------------------------------------------------------------------------------------
def _brute_force(a, b, w):
    """Pairwise / per-element definitions, O(n^2): the reference for the contingency-table code."""
    n = len(a)
    sa = a[:, None] == a[None, :]
    sb = b[:, None] == b[None, :]
    ww = np.outer(w, w)
    off = ~np.eye(n, dtype=bool)
    ri = float((ww * (sa != sb) * off).sum() / (ww * off).sum())
    # GCE / LCE per element: R(S, p) = weight of p's segment
    ra = (sa * w[None, :]).sum(1)
    rb = (sb * w[None, :]).sum(1)
    inter = (sa & sb) * w[None, :]
    inter = inter.sum(1)
    e12, e21 = (ra - inter) / ra, (rb - inter) / rb
    total = w.sum()
    gce = min((w * e12).sum(), (w * e21).sum()) / total
    lce = (w * np.minimum(e12, e21)).sum() / total
    # Hamming: for each segment of S2, the weight outside its best-overlapping segment of S1
    def dh(s1, s2):
        out = 0.0
        for lab in np.unique(s2):
            m = s2 == lab
            best = max(w[m & (s1 == k)].sum() for k in np.unique(s1[m]))
            out += w[m].sum() - best
        return out / total
    rm, rf = dh(a, b), dh(b, a)
    return {"rand": ri, "gce": gce, "lce": lce, "rm": rm, "rf": rf}


@pytest.mark.parametrize("seed", range(6))
def test_table_metrics_match_brute_force(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(5, 60))
    a = rng.integers(0, rng.integers(1, 8), n) * 7 - 3  # arbitrary label values
    b = rng.integers(0, rng.integers(1, 8), n)
    w = rng.random(n) + (0.0 if seed % 2 else 1.0)
    ref = _brute_force(a, b, w)
    assert rand_index_error(a, b, w) == pytest.approx(ref["rand"], abs=1e-12)
    gce, lce = consistency_errors(a, b, w)
    assert (gce, lce) == pytest.approx((ref["gce"], ref["lce"]), abs=1e-12)
    hd, rm, rf = hamming_distance(a, b, w)
    assert (rm, rf, hd) == pytest.approx((ref["rm"], ref["rf"], 0.5 * (ref["rm"] + ref["rf"])), abs=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_sparse_matching_equals_dense_hungarian(seed, monkeypatch):
    import shape_toolkit.metrics.segmentation as seg

    rng = np.random.default_rng(seed)
    n = 300
    a, b, w = rng.integers(0, 40, n), rng.integers(0, 25, n), rng.random(n)
    dense = matched_recall_precision(a, b, w)
    monkeypatch.setattr(seg, "DENSE_ASSIGNMENT_CELLS", 0)  # force the sparse bipartite matching
    sparse = matched_recall_precision(a, b, w)
    assert sparse == pytest.approx(dense, abs=1e-12)


def test_many_segments_use_linear_memory():
    """A per-element labelling of 200k elements: a dense 200k x 200k table would need 320 GB."""
    import tracemalloc

    rng = np.random.default_rng(0)
    n = 200_000
    a = np.arange(n)
    b = rng.integers(0, 10, n)
    tracemalloc.start()
    rand_index_error(a, b)
    consistency_errors(a, b)
    hamming_distance(a, b)
    matched_recall_precision(a, b)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 400 * 2**20
