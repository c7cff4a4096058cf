"""Face-based part segmenters (issue 13): ``ncut`` (recursive normalized cuts on the concavity-weighted
dual graph), ``seeded-walk`` (random walks from must-link clicks) and the connected-part relabelling
they share with ``sdf`` (``_common.merge_to_segments``)."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from shape_toolkit.api.registry import create_plugin, get_registry
from shape_toolkit.core.shape import Shape
from shape_toolkit.data.synthetic import articulated_shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.metrics.segmentation import rand_index_error
from shape_toolkit.plugins.segmenters._common import face_segments_to_vertices, merge_to_segments
from shape_toolkit.results.labels import ConstraintError, Constraints, draw_constraints, vertex_to_face_labels

NEW = {"ncut": "shape_toolkit.plugins.segmenters.ncut", "seeded-walk": "shape_toolkit.plugins.segmenters.seeded_walk"}


def ensure_registered() -> None:
    """The new built-ins through their hook modules when the installed metadata predates their entry
    points (``pip install -e .`` after pyproject.toml lists them makes this a no-op)."""
    reg = get_registry()
    for name, module in NEW.items():
        if not reg.has("segmenters", name):
            reg.register(importlib.import_module(module), name=f"builtin-{name}")


@pytest.fixture(scope="module", autouse=True)
def _registered():
    ensure_registered()


@pytest.fixture(scope="module")
def body():
    """Body + 5 limbs (2,562 vertices, 5,120 faces); truth per face by vertex majority."""
    b = articulated_shape(subdivisions=4, random_state=1)
    return b, vertex_to_face_labels(b.shape.faces, b.labels)


def _baselines(truth: np.ndarray) -> float:
    """The better Rand index error of a constant and of a uniformly random 6-labelling."""
    rng = np.random.default_rng(0)
    return min(rand_index_error(np.zeros_like(truth), truth), rand_index_error(rng.integers(0, 6, truth.size), truth))


def _strip(labels: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Dual-graph pairs of a chain of faces 0-1-2-..., and the labels as an array."""
    n = len(labels)
    return np.column_stack([np.arange(n - 1), np.arange(1, n)]), np.asarray(labels)


# -- connected-part relabelling -----------------------------------------------------------------
def test_merge_to_segments_splits_disconnected_labels_and_merges_the_smallest():
    pairs, lab = _strip([0, 0, 1, 1, 0, 0, 0])
    areas = np.ones(7)
    # label 0 occurs in two separate runs: two segments; numbered by decreasing area
    out = merge_to_segments(lab, pairs, areas, None)
    assert out.tolist() == [1, 1, 2, 2, 0, 0, 0]
    # down to 2: the smallest part (faces 0-1, tie with 2-3 broken by the first face) joins its neighbour
    out2 = merge_to_segments(lab, pairs, areas, 2)
    assert len(np.unique(out2)) == 2 and out2[0] == out2[1] == out2[2] == out2[3] and out2[4] != out2[0]
    # a bigger area wins the numbering
    out3 = merge_to_segments(lab, pairs, np.array([5, 5, 1, 1, 1, 1, 1.0]), None)
    assert out3[0] == 0


def test_merge_to_segments_never_merges_separate_components():
    pairs = np.array([[0, 1], [2, 3]])  # two components of two faces each
    lab = np.array([0, 1, 2, 2])
    out = merge_to_segments(lab, pairs, np.ones(4), 1)
    # faces 0 and 1 merge; the component {2, 3} has no neighbour and stays
    assert out[0] == out[1] and out[2] == out[3] and out[0] != out[2]


def test_face_segments_to_vertices_covers_isolated_vertices():
    s = Shape(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5.0]]), np.array([[0, 1, 2]]))
    assert face_segments_to_vertices(s, np.array([3])).tolist() == [3, 3, 3, 3]


# -- ncut ---------------------------------------------------------------------------------------
def test_ncut_finds_the_limbs(body):
    b, truth = body
    seg = create_plugin("segmenters", "ncut", n_segments=6)
    assert seg.spectrum_spec() is None and seg.spectrum_specs() == []
    v = seg.segment(b.shape)
    assert v.shape == (b.shape.n_vertices,) and v.dtype == np.int64
    fl = seg.face_labels_
    assert fl.shape == (b.shape.n_faces,) and len(np.unique(fl)) == 6 == seg.n_segments_
    err = rand_index_error(fl, truth)
    # the truth's limbs reach onto the sphere (cap_angle) while cuts follow the concave junction
    assert err < 0.2 < 0.5 * _baselines(truth)
    assert len(seg.ncut_values_) == 5 and all(np.isfinite(seg.ncut_values_))
    # each limb is one segment: the five smallest segments are the five limbs
    sizes = np.bincount(fl)
    assert sizes.argmax() == 0 and np.all(sizes[1:] < 0.2 * b.shape.n_faces)


def test_ncut_components_are_separate_segments(sphere):
    far = Shape(sphere.vertices + [5.0, 0, 0], sphere.faces)
    two = Shape(np.vstack([sphere.vertices, far.vertices]), np.vstack([sphere.faces, sphere.faces + sphere.n_vertices]))
    seg = create_plugin("segmenters", "ncut", n_segments=2)
    seg.segment(two)
    fl = seg.face_labels_
    assert len(np.unique(fl[: sphere.n_faces])) == 1 and len(np.unique(fl[sphere.n_faces:])) == 1
    assert fl[0] != fl[-1]


def test_ncut_bad_parameters(body):
    b, _ = body
    for params in ({"n_segments": None}, {"n_segments": 1}, {"n_segments": 3, "n_vectors": 0},
                   {"n_segments": 3, "min_fraction": 0.7}, {"n_segments": 3, "concavity_scale": -1.0},
                   {"n_segments": 3, "min_weight": 0.0}):
        with pytest.raises(ParameterError):
            create_plugin("segmenters", "ncut", **params).segment(b.shape)


def test_ncut_is_scale_invariant(body):
    b, _ = body
    big = Shape(b.shape.vertices * 37.0, b.shape.faces)
    a = create_plugin("segmenters", "ncut", n_segments=4)
    c = create_plugin("segmenters", "ncut", n_segments=4)
    a.segment(b.shape)
    c.segment(big)
    assert rand_index_error(a.face_labels_, c.face_labels_) < 1e-3


# -- seeded-walk --------------------------------------------------------------------------------
def test_seeded_walk_follows_one_click_pair_per_part(body):
    b, truth = body
    cons = draw_constraints(b.labels, b.shape.edges, n_must_per_segment=1, n_cannot_per_boundary=1, random_state=0)
    seg = create_plugin("segmenters", "seeded-walk")
    v = seg.segment(b.shape, constraints=cons)
    assert v.shape == (b.shape.n_vertices,) and seg.n_segments_ == 6
    assert rand_index_error(seg.face_labels_, truth) < 0.2 < 0.5 * _baselines(truth)
    # every must-linked pair ends in one segment, every cannot-linked pair in two
    assert np.all(v[cons.must_link[:, 0]] == v[cons.must_link[:, 1]])
    assert seg.n_cannot_violated_ == 0
    p = seg.probabilities_
    assert p.shape == (b.shape.n_faces, 6) and np.allclose(p.sum(axis=1), 1.0, atol=1e-4)


def test_seeded_walk_repairs_a_violated_cannot_link():
    """Two clicks on a flat strip, a cannot-link between two unclicked vertices that the walk alone
    puts in one segment: the repair separates them."""
    xs, ys = np.meshgrid(np.linspace(0, 4, 41), np.linspace(0, 1, 6), indexing="ij")
    v = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
    idx = np.arange(v.shape[0]).reshape(41, 6)
    a, bb, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    strip = Shape(v, np.concatenate([np.column_stack([a, bb, c]), np.column_stack([a, c, d])]))
    must = [[idx[0, 2], idx[1, 3]], [idx[40, 2], idx[39, 3]]]
    u, w = idx[5, 2], idx[12, 2]  # both near the left seed
    seg = create_plugin("segmenters", "seeded-walk")
    lab = seg.segment(strip, constraints=Constraints(must, []))
    assert lab[u] == lab[w]
    lab2 = seg.segment(strip, constraints=Constraints(must, [[u, w]]))
    assert lab2[u] != lab2[w] and seg.n_cannot_violated_ == 0
    assert create_plugin("segmenters", "seeded-walk", cannot_rounds=0).segment(
        strip, constraints=Constraints(must, [[u, w]]))[u] == lab[u]


def test_seeded_walk_errors_and_unseeded_components(sphere):
    seg = create_plugin("segmenters", "seeded-walk")
    with pytest.raises(ParameterError, match="must-link"):
        seg.segment(sphere)
    with pytest.raises(ParameterError, match="must-link"):
        seg.segment(sphere, constraints=Constraints([], [[0, 5]]))
    with pytest.raises(ConstraintError, match="cannot_link"):
        seg.segment(sphere, constraints=Constraints([[0, 1], [1, 2]], [[0, 2]]))
    for bad in ({"cannot_rounds": -1}, {"smoothing_lambda": -1.0}):
        with pytest.raises(ParameterError):
            create_plugin("segmenters", "seeded-walk", **bad).segment(sphere, constraints=Constraints([[0, 1]], []))
    # a second component without any click becomes its own segment
    far = sphere.vertices + [5.0, 0, 0]
    two = Shape(np.vstack([sphere.vertices, far]), np.vstack([sphere.faces, sphere.faces + sphere.n_vertices]))
    lab = seg.segment(two, constraints=Constraints([[0, 1]], []))
    assert seg.n_segments_ == 2 and lab[0] != lab[-1]
    assert len(np.unique(lab[: sphere.n_vertices])) == 1


def test_seeded_walk_smoothing_option(body):
    b, truth = body
    cons = draw_constraints(b.labels, b.shape.edges, n_must_per_segment=1, random_state=0)
    seg = create_plugin("segmenters", "seeded-walk", smoothing_lambda=0.5)
    seg.segment(b.shape, constraints=cons)
    assert rand_index_error(seg.face_labels_, truth) < 0.2


# -- csc on the dual graph ----------------------------------------------------------------------
def test_csc_on_the_dual_graph(body):
    b, truth = body
    cons = draw_constraints(b.labels, b.shape.edges, n_must_per_segment=1, n_cannot_per_boundary=1, random_state=0)
    seg = create_plugin("segmenters", "csc", n_segments=6, graph="dual")
    assert seg.spectrum_spec() is None and seg.spectrum_specs() == []
    v = seg.segment(b.shape, constraints=cons)
    assert v.shape == (b.shape.n_vertices,) and seg.face_labels_.shape == (b.shape.n_faces,)
    assert len(np.unique(seg.face_labels_)) == 6
    assert rand_index_error(seg.face_labels_, truth) < 0.2 < 0.5 * _baselines(truth)
    assert seg.n_must_edges_ > 0 and seg.n_cannot_edges_ > 0
    W = seg.modified_weights(b.shape, cons)
    assert W.shape == (b.shape.n_faces, b.shape.n_faces) and 0 < W.data.min() and W.data.max() <= 1.0
    with pytest.raises(ParameterError, match="graph"):
        create_plugin("segmenters", "csc", n_segments=6, graph="faces").segment(b.shape, constraints=cons)
