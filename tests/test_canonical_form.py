"""features.canonical.canonical_form: geodesic MDS, invariant to pose (bending), rigid motion and vertex order."""

from __future__ import annotations

import numpy as np
import pytest

from shape_toolkit.core.geometry import rigid_rotation
from shape_toolkit.core.shape import Shape
from shape_toolkit.data.synthetic import articulated_shape
from shape_toolkit.errors import InvalidShapeError, ParameterError
from shape_toolkit.features.canonical import _signed_volume, canonical_form
from shape_toolkit.features.geodesics import geodesic_distances


@pytest.fixture(scope="module")
def poses():
    lengths = np.array([0.8, 1.1, 1.4, 1.7, 2.0])  # unequal limbs: no symmetry to hide a mirror
    return tuple(articulated_shape(subdivisions=3, random_state=r, limb_length=lengths).shape for r in (1, 2))


def _rigid_gap(A: np.ndarray, B: np.ndarray) -> float:
    """RMS distance between ``A`` and ``B`` (same vertex order) after the best proper rigid motion, over
    the RMS radius of ``B``."""
    R = rigid_rotation(A, B)
    Ac, Bc = A - A.mean(axis=0), B - B.mean(axis=0)
    return float(np.sqrt(((Ac @ R.T - Bc) ** 2).sum(axis=1).mean() / (Bc**2).sum(axis=1).mean()))


def test_distances_approximate_the_geodesic_ones(poses):
    a = poses[0]
    Y = canonical_form(a)
    ids = np.arange(0, a.n_vertices, 97)
    G = geodesic_distances(a, ids, ids, method="dijkstra")
    E = np.linalg.norm(Y[ids][:, None] - Y[ids][None], axis=2)
    assert np.median(np.abs(E - G)[G > 0] / G[G > 0]) < 0.25
    # the raw coordinates are far from it: a bent limb is shorter in space than along the surface
    X = np.asarray(a.vertices)
    R = np.linalg.norm(X[ids][:, None] - X[ids][None], axis=2)
    assert np.mean(G - E) < np.mean(G - R)


def test_two_poses_give_the_same_form_up_to_a_rigid_motion(poses):
    a, b = poses
    Xa, Xb = np.asarray(a.vertices), np.asarray(b.vertices)
    gap_poses = _rigid_gap(Xa, Xb)
    gap_forms = _rigid_gap(canonical_form(a), canonical_form(b))
    assert gap_forms < 0.6 * gap_poses, (gap_forms, gap_poses)  # 0.071 against 0.129 (642 vertices)


def test_rigid_motion_mirror_and_vertex_order(poses):
    a = poses[0]
    Y = canonical_form(a)
    th = 0.7
    R = np.array([[np.cos(th), 0.0, np.sin(th)], [0.0, 1.0, 0.0], [-np.sin(th), 0.0, np.cos(th)]])
    moved = a.with_vertices(np.asarray(a.vertices) @ R.T + [3.0, -1.0, 2.0])
    # equal up to the landmarks (a near-tie of the first one may resolve differently after rounding)
    assert _rigid_gap(canonical_form(moved), Y) < 0.02
    # a shuffled vertex order gives the same form at the same vertices
    rng = np.random.default_rng(0)
    perm = rng.permutation(a.n_vertices)
    inv = np.argsort(perm)
    shuffled = Shape(np.asarray(a.vertices)[perm], inv[np.asarray(a.faces)])
    assert _rigid_gap(canonical_form(shuffled)[inv], Y) < 0.02
    # the form keeps the input's orientation; a mirrored input gives a mirrored form
    faces = np.asarray(a.faces)
    assert _signed_volume(Y, faces) * _signed_volume(np.asarray(a.vertices), faces) > 0
    mirrored = a.with_vertices(np.asarray(a.vertices) * [-1.0, 1.0, 1.0])
    Ym = canonical_form(mirrored)
    assert _signed_volume(Ym, faces) * _signed_volume(Y, faces) < 0
    assert _rigid_gap(Ym * [-1.0, 1.0, 1.0], Y) < 0.02


def test_bad_inputs_are_refused(poses):
    a = poses[0]
    X, F = np.asarray(a.vertices), np.asarray(a.faces)
    two = Shape(np.vstack([X, X + 10.0]), np.vstack([F, F + len(X)]))
    with pytest.raises(InvalidShapeError, match="not connected"):
        canonical_form(two)
    with pytest.raises(InvalidShapeError):
        canonical_form(Shape(X))
    for bad in (3, 2.5, True):
        with pytest.raises(ParameterError):
            canonical_form(a, landmarks=bad)
