"""The ``sdf`` segmenter (CGAL's SDF method) and the ``smoothed`` wrapper."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("maxflow")

import shape_toolkit as st  # noqa: E402
from shape_toolkit.core.shape import Shape  # noqa: E402
from shape_toolkit.data.synthetic import articulated_shape  # noqa: E402
from shape_toolkit.errors import ParameterError  # noqa: E402
from shape_toolkit.plugins.segmenters.sdf import face_sdf  # noqa: E402


@pytest.fixture(scope="module")
def body():
    return articulated_shape(subdivisions=2).shape


def test_sdf_of_a_sphere_is_about_its_diameter(sphere):
    x = face_sdf(sphere)
    assert np.isfinite(x).all()
    # chords in a 120-degree cone: between cos(60 deg) * 2 and 2 for the unit sphere
    assert 1.0 < np.median(x) < 2.0
    # flipped faces (inward normals) are handled: about the same values (the ray pattern turns)
    y = face_sdf(Shape(sphere.vertices, sphere.faces[:, ::-1]))
    assert np.isfinite(y).all() and np.abs(y - x).max() < 0.05 * np.median(x)


def test_sdf_segmenter_gives_k_face_segments_reproducibly(body):
    seg = st.create_plugin("segmenters", "sdf", n_segments=4, random_state=0)
    assert seg.spectrum_spec() is None and seg.spectrum_specs() == []
    res = seg.segment(body)
    v = res.labels
    assert v.shape == (body.n_vertices,) and v.min() >= 0
    assert res.face_labels.shape == (body.n_faces,)
    assert len(np.unique(res.face_labels)) == 4
    again = st.create_plugin("segmenters", "sdf", n_segments=4, random_state=0)
    again_res = again.segment(body)
    np.testing.assert_array_equal(again_res.face_labels, res.face_labels)


def test_sdf_is_vertex_order_invariant(body):
    rng = np.random.default_rng(0)
    perm = rng.permutation(body.n_vertices)
    inv = np.argsort(perm)
    permuted = Shape(body.vertices[perm], inv[body.faces])
    a = st.create_plugin("segmenters", "sdf", n_segments=3)
    b = st.create_plugin("segmenters", "sdf", n_segments=3)
    a_res = a.segment(body)
    b_res = b.segment(permuted)
    np.testing.assert_array_equal(a_res.face_labels, b_res.face_labels)


def test_sdf_bad_parameters(body):
    with pytest.raises(ParameterError):
        st.create_plugin("segmenters", "sdf", n_segments=1).segment(body)
    with pytest.raises(ParameterError):
        st.create_plugin("segmenters", "sdf", n_segments=None, n_clusters=None).segment(body)


def test_sdf_on_several_components(body):
    two = Shape(np.vstack([body.vertices, body.vertices + [5.0, 0, 0]]),
                np.vstack([body.faces, body.faces + body.n_vertices]))
    seg = st.create_plugin("segmenters", "sdf", n_segments=3)
    res = seg.segment(two)
    assert len(np.unique(res.face_labels)) >= 2  # components are never merged with each other


def test_smoothed_wraps_a_name_or_an_instance_and_clones(body):
    sklearn_base = pytest.importorskip("sklearn.base")
    base = st.create_plugin("segmenters", "spectral-clustering", n_segments=3)
    sm = st.create_plugin("segmenters", "smoothed", base=base, smoothing_lambda=0.5)
    assert sm.get_params(deep=True)["base__n_segments"] == 3
    assert sm.spectrum_specs() == base.spectrum_specs()
    sm_res = sm.segment(body)
    v = sm_res.labels
    assert v.shape == (body.n_vertices,) and sm_res.face_labels.shape == (body.n_faces,)
    clone = sklearn_base.clone(sm)
    clone_res = clone.segment(body)
    np.testing.assert_array_equal(clone_res.face_labels, sm_res.face_labels)
    by_name = st.create_plugin("segmenters", "smoothed", base="spectral-clustering", n_segments=3,
                               smoothing_lambda=0.5)
    by_name_res = by_name.segment(body)
    np.testing.assert_array_equal(by_name_res.face_labels, sm_res.face_labels)
    assert by_name.base_.n_segments == 3
    # the base's spectrum is passed through
    spec = base.spectrum_spec().compute(body)
    by_name.segment(body, spectrum=[spec])
    with pytest.raises(ParameterError):
        st.create_plugin("segmenters", "smoothed", base=3).segment(body)


def test_the_sdf_cache_stays_bounded_over_more_meshes_than_its_size():
    """``SDF_CACHE`` keeps the SDFs of the last few meshes only (most recently used), and
    hands out copies."""
    from shape_toolkit.data.generate import icosphere
    from shape_toolkit.plugins.segmenters.sdf import SDF_CACHE, normalized_sdf

    SDF_CACHE.clear()
    size = SDF_CACHE.max_entries
    assert size is not None and size >= 2
    meshes = [icosphere(1, radius=1.0 + 0.1 * i) for i in range(size + 3)]
    first = normalized_sdf(meshes[0])
    for m in meshes:
        st.create_plugin("segmenters", "sdf", n_segments=2, random_state=0).segment(m)
        assert len(SDF_CACHE) <= size
    assert len(SDF_CACHE) == size
    kept = {k[0] for k in SDF_CACHE.keys()}
    assert kept == {m.content_hash for m in meshes[-size:]}  # the most recent meshes
    again = normalized_sdf(meshes[0])  # recomputed, the same values
    np.testing.assert_array_equal(again, first)
    again[:] = -1.0  # a copy: the cached value is untouched
    assert (normalized_sdf(meshes[0]) >= 0).all()
    SDF_CACHE.clear()
