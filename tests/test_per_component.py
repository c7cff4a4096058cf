"""``PerComponent``, the meta-segmenter of shapes in several pieces (issue 26), and the ``Segmentation``
every segmenter returns."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from sklearn.base import clone

from shape_toolkit.api.registry import create_plugin
from shape_toolkit.core.shape import Shape
from shape_toolkit.data.synthetic import articulated_shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.plugins.segmenters.constraints import ConstraintWarning
from shape_toolkit.plugins.segmenters.per_component import PerComponent
from shape_toolkit.results.labels import Constraints, clicks_from_segmentation, vertex_to_face_labels
from shape_toolkit.results.segmentation import Segmentation


@pytest.fixture(scope="module")
def two():
    """Two bodies side by side, their truth, and the first body alone."""
    a = articulated_shape(subdivisions=2, random_state=1)
    b = articulated_shape(subdivisions=2, random_state=2)
    shape = Shape(np.vstack([a.shape.vertices, b.shape.vertices + [5.0, 0, 0]]),
                  np.vstack([a.shape.faces, b.shape.faces + a.shape.n_vertices]))
    return a, shape, np.r_[a.labels, b.labels + 6]


def test_per_component_is_a_meta_estimator():
    wrapped = PerComponent(create_plugin("segmenters", "ncut", n_segments=6, n_vectors=2))
    params = wrapped.get_params(deep=True)
    assert params["segmenter__n_segments"] == 6 and params["segmenter__n_vectors"] == 2 and params["pieces"] == "auto"
    copy = clone(wrapped)
    assert copy is not wrapped and copy.segmenter is not wrapped.segmenter and repr(copy) == repr(wrapped)
    copy.set_params(segmenter__n_segments=4)
    assert copy.segmenter.n_segments == 4 and wrapped.segmenter.n_segments == 6
    assert wrapped.accepts_constraints() is False
    assert PerComponent(create_plugin("segmenters", "csc")).accepts_constraints() is True
    with pytest.raises(ParameterError, match="pieces"):
        PerComponent(wrapped.segmenter, pieces="faces").segment(articulated_shape(subdivisions=1).shape)


@pytest.mark.parametrize("name", ["ncut", "spectral-clustering", "csc"])
def test_the_registry_segmenter_on_pieces_is_per_component_of_itself(two, name):
    """The built-ins wrap themselves: the same labels as PerComponent around them, explicitly."""
    a, shape, truth = two
    seg = create_plugin("segmenters", name, n_segments=12)
    cons = clicks_from_segmentation(shape, truth, faces=False) if seg.accepts_constraints() else None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConstraintWarning)
        own = seg.segment(shape, constraints=cons)
        wrapped = PerComponent(create_plugin("segmenters", name, n_segments=12))
        explicit = wrapped.segment(shape, constraints=cons)
    np.testing.assert_array_equal(own.labels, explicit.labels)
    np.testing.assert_array_equal(own.face_labels, explicit.face_labels)
    assert own.info["segments_per_component"] == explicit.info["segments_per_component"] == [6, 6]
    assert len(wrapped.segmenters_) == 2 and all(s.n_segments == 6 for s in wrapped.segmenters_)
    if cons is not None:
        assert own.info["constraints"] == explicit.info["constraints"]
    # one piece: the wrapper hands the shape to the segmenter itself
    alone = PerComponent(create_plugin("segmenters", name, n_segments=6)).segment(
        a.shape, constraints=None if cons is None else Constraints([], []))
    direct = create_plugin("segmenters", name, n_segments=6).segment(a.shape)
    np.testing.assert_array_equal(alone.labels, direct.labels)
    assert "segments_per_component" not in alone.info


def test_segmentation_holds_labels_face_labels_and_info():
    gen = articulated_shape(subdivisions=2)
    shape = gen.shape
    res = create_plugin("segmenters", "spectral-clustering", n_segments=6).segment(shape)
    assert isinstance(res, Segmentation) and res.info == {"per": "vertex"}
    assert res.labels.dtype == np.int64 and res.labels.shape == (shape.n_vertices,)
    np.testing.assert_array_equal(res.face_labels, vertex_to_face_labels(shape.faces, res.labels))
    assert res.n_segments == 6
    with pytest.raises(AttributeError):  # frozen
        res.labels = res.labels
    cloud = create_plugin("segmenters", "spectral-clustering", n_segments=6).segment(Shape(shape.vertices))
    assert cloud.face_labels is None
    faces = create_plugin("segmenters", "ncut", n_segments=6).segment(shape)
    assert faces.info["per"] == "face" and faces.face_labels.shape == (shape.n_faces,)
    with pytest.raises(ParameterError):
        Segmentation(np.zeros((2, 2), dtype=np.int64))
    with pytest.raises(ParameterError):
        Segmentation(np.zeros(3), None)
