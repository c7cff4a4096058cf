"""core.geometry.rigid_rotation: the weighted Kabsch rotation (best-of's frame estimate)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from shape_toolkit.core.geometry import rigid_rotation
from shape_toolkit.errors import ParameterError


def test_a_rigid_motion_is_recovered_exactly():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(50, 3))
    R = Rotation.from_rotvec([0.3, -2.0, 0.7]).as_matrix()
    Y = X @ R.T + np.array([1.0, -2.0, 3.0])
    np.testing.assert_allclose(rigid_rotation(X, Y), R, atol=1e-12)


def test_weights_ignore_outliers_and_reflections_give_a_proper_rotation():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(40, 3))
    R = Rotation.from_rotvec([0.0, 0.0, 2.5]).as_matrix()
    Y = X @ R.T
    Y[:10] = rng.normal(size=(10, 3)) * 5  # wrong matches, given no weight
    w = np.r_[np.zeros(10), np.ones(30)]
    np.testing.assert_allclose(rigid_rotation(X, Y, w), R, atol=1e-12)
    mirrored = X * np.array([1.0, 1.0, -1.0])  # no rotation explains a mirror image: still det +1
    assert np.linalg.det(rigid_rotation(X, mirrored)) == pytest.approx(1.0)


@pytest.mark.parametrize("args", [(np.zeros((5, 2)), np.zeros((5, 2))), (np.zeros((5, 3)), np.zeros((4, 3))),
                                  (np.eye(3), np.eye(3), np.zeros(3)), (np.eye(3), np.eye(3), -np.ones(3))])
def test_bad_input_is_refused(args):
    with pytest.raises(ParameterError):
        rigid_rotation(*args)
