"""Bad parameters of the harris3d keypoint detector: a ring count far beyond the mesh's saturation gives the
saturated result at the saturation's cost (never a hang), ``k`` outside the range where the Harris response
tells corners from edges is refused up front with one line (no numpy warnings)."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from helpers import run_cli, time_budget

from shape_toolkit.api.registry import create_plugin
from shape_toolkit.core.shape import Shape
from shape_toolkit.data.generate import icosphere
from shape_toolkit.errors import ParameterError
from shape_toolkit.features.geodesics import adjacency, k_ring_all
from shape_toolkit.io.mesh import save_shape

#: seconds a call with a huge ring count may take (the saturated work is well under a second)
BUDGET = 60




@pytest.fixture(scope="module")
def ellipsoid() -> Shape:
    """A closed 162-vertex ellipsoid (the fuzzed input)."""
    s = icosphere(2)
    return Shape(s.vertices * np.array([1.0, 0.7, 0.5]), s.faces)


def _saturation(shape: Shape) -> int:
    """The ring count at which the rings of every vertex cover the (connected) mesh."""
    A = adjacency(shape)
    r = 1
    while k_ring_all(A, r).nnz < shape.n_vertices**2:
        r += 1
    return r


# -- ring counts beyond saturation ------------------------------------------------------------------------------
def _rings_without_early_stop(A, k: int):
    """The k-rings as k_ring_all computed them before it stopped at saturation (the reference)."""
    import scipy.sparse as sp

    R = sp.csr_matrix(A + sp.identity(A.shape[0], format="csr"))
    B = sp.identity(A.shape[0], format="csr")
    for _ in range(k):
        B = B @ R
        B.data[:] = 1.0
    return sp.csr_matrix(B, dtype=bool)


def test_rings_and_ring_maxima_stop_at_saturation(ellipsoid):
    """k_ring_all and ring_maxima stop growing once nothing changes: the same answers up to saturation, the
    saturated ones beyond it, at once for any count (found by fuzzing: 1e6 rings ran for hours)."""
    from shape_toolkit.features.geodesics import ring_maxima

    A = adjacency(ellipsoid)
    sat = _saturation(ellipsoid)
    for r in range(1, sat + 1):
        a, b = k_ring_all(A, r), _rings_without_early_stop(A, r)
        np.testing.assert_array_equal(a.indptr, b.indptr)
        np.testing.assert_array_equal(a.indices, b.indices)
    full = k_ring_all(A, sat)
    values = np.random.default_rng(0).normal(size=ellipsoid.n_vertices)
    with time_budget(BUDGET):
        for r in (sat + 1, 10**6, 10**300):
            b = k_ring_all(A, r)
            np.testing.assert_array_equal(b.indptr, full.indptr)
            np.testing.assert_array_equal(b.indices, full.indices)
            np.testing.assert_array_equal(ring_maxima(values, A, r), ring_maxima(values, A, sat))
    assert ring_maxima(values, A, 10**300).tolist() == [int(np.argmax(values))]  # one component, one maximum


@pytest.mark.parametrize("rings", [10**6, 1e6, 1e300])
def test_harris3d_rings_beyond_saturation_equal_saturation(ellipsoid, rings):
    sat = _saturation(ellipsoid)
    ref = create_plugin("keypoints", "harris3d", neighbourhood="rings", neighbourhood_param=sat)
    det = create_plugin("keypoints", "harris3d", neighbourhood="rings", neighbourhood_param=rings)
    with time_budget(BUDGET):
        resp = det.response(ellipsoid)
        kp = det.detect(ellipsoid)
    np.testing.assert_array_equal(resp, ref.response(ellipsoid))
    np.testing.assert_array_equal(kp, ref.detect(ellipsoid))


def test_harris3d_candidate_ring_beyond_the_diameter(ellipsoid):
    ref = create_plugin("keypoints", "harris3d", ring=_saturation(ellipsoid), selection_param=0.05).detect(ellipsoid)
    with time_budget(BUDGET):
        kp = create_plugin("keypoints", "harris3d", ring=10**12, selection_param=0.05).detect(ellipsoid)
    np.testing.assert_array_equal(kp, ref)


def test_harris3d_rings_need_a_whole_count(ellipsoid):
    with pytest.raises(ParameterError, match="whole ring count"):
        create_plugin("keypoints", "harris3d", neighbourhood="rings", neighbourhood_param=2.5).detect(ellipsoid)


def test_cli_harris3d_huge_ring_count(ellipsoid, tmp_path, capsys):
    path = tmp_path / "small.off"
    save_shape(ellipsoid, path)
    sat = _saturation(ellipsoid)
    base = ["keypoints", path, "--detector", "harris3d", "--param", "neighbourhood=rings", "--json"]
    with time_budget(BUDGET):
        code, out, err = run_cli(capsys, *base, "--param", "neighbourhood_param=1e6", "-o", tmp_path / "a.txt")
    assert code == 0 and err == "", err
    code, ref, err = run_cli(capsys, *base, "--param", f"neighbourhood_param={sat}", "-o", tmp_path / "b.txt")
    assert code == 0, err
    assert json.loads(out)["keypoints"] == json.loads(ref)["keypoints"]


# -- the Harris parameter k -------------------------------------------------------------------------------------
@pytest.mark.parametrize("k", [1e308, -1e308, 0.25, 0.3, 0.0, -0.04, 1.0])
def test_harris3d_refuses_k_outside_the_response_range(ellipsoid, k):
    det = create_plugin("keypoints", "harris3d", k=k)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ParameterError, match="k must be"):
            det.detect(ellipsoid)


def test_harris3d_k_inside_the_range_still_detects(ellipsoid):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for k in (1e-6, 0.04, 0.2499):
            assert create_plugin("keypoints", "harris3d", k=k).detect(ellipsoid).size >= 1


@pytest.mark.parametrize("value", ["1e308", "-1e308", "0.25"])
def test_cli_harris3d_bad_k_is_one_line(ellipsoid, tmp_path, capsys, value):
    path = tmp_path / "small.off"
    save_shape(ellipsoid, path)
    code, _, err = run_cli(capsys, "keypoints", path, "--detector", "harris3d", "--param", f"k={value}",
                           "-o", tmp_path / "kp.txt")
    assert code == 2 and err.count("\n") == 1 and "k must be" in err, err


@pytest.mark.parametrize("value", [1e308, 1.5])
def test_harris3d_selection_param_is_a_fraction_or_a_distance_within_the_diagonal(ellipsoid, value):
    """Above 1 a fraction of the vertices means every vertex and a distance past the diagonal one keypoint (found
    by fuzzing: 1e308 was an internal OverflowError)."""
    with pytest.raises(ParameterError, match="selection_param"):
        create_plugin("keypoints", "harris3d", selection_param=value).detect(ellipsoid)
    assert len(create_plugin("keypoints", "harris3d", selection_param=1.0).detect(ellipsoid)) >= 1
