"""Bad ``times`` of the heat descriptors (hks, the default of ``shape-toolkit describe``, and the keypoint ones,
heat-diffusion and heat-distance): one number is one time, as the plugins' help says; negative, NaN, empty and
absurdly large times are refused with one line, never an internal error, numpy warnings or a NaN / all-zero
descriptor."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from helpers import run_cli

from shape_toolkit.api.registry import create_plugin
from shape_toolkit.core.shape import Shape
from shape_toolkit.data.generate import icosphere
from shape_toolkit.errors import ParameterError
from shape_toolkit.io.mesh import save_shape


@pytest.fixture(scope="module")
def ellipsoid() -> Shape:
    """A closed 162-vertex ellipsoid (the fuzzed input)."""
    s = icosphere(2)
    return Shape(s.vertices * np.array([1.0, 0.7, 0.5]), s.faces)


@pytest.fixture(scope="module")
def off_file(ellipsoid, tmp_path_factory):
    path = tmp_path_factory.mktemp("bad_descriptors") / "small.off"
    save_shape(ellipsoid, path)
    return path


@pytest.mark.parametrize("t", [1, 0.5, 0.0, np.float64(2.0)])
@pytest.mark.parametrize("scale", ["none", "trace"])
def test_hks_scalar_time_is_one_time(ellipsoid, t, scale):
    one = create_plugin("descriptors", "hks", times=t, scale=scale)
    listed = create_plugin("descriptors", "hks", times=[float(t)], scale=scale)
    assert one.output_width() == 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        d = one.compute(ellipsoid)
    assert d.shape == (ellipsoid.n_vertices, 1) and np.all(np.isfinite(d))
    np.testing.assert_array_equal(d, listed.compute(ellipsoid))


@pytest.mark.parametrize("times", [1e300, 1e308, [1.0, 1e300], 1e4])
@pytest.mark.parametrize("scale", ["none", "trace"])
@pytest.mark.parametrize("log", [False, True])
def test_hks_refuses_times_where_the_heat_vanishes(ellipsoid, times, scale, log):
    desc = create_plugin("descriptors", "hks", times=times, scale=scale, log=log)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ParameterError, match="times must be at most"):
            desc.compute(ellipsoid)


def test_hks_times_up_to_the_limit_stay_finite(ellipsoid):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        d = create_plugin("descriptors", "hks", times=[0.0, 1.0, 1000.0], scale="trace", log=True).compute(ellipsoid)
    assert np.all(np.isfinite(d))


@pytest.mark.parametrize("times", [-1.0, float("nan"), float("inf"), [], [1.0, -1.0], "1"])
def test_hks_refuses_invalid_times(ellipsoid, times):
    with pytest.raises(ParameterError, match="times must be"):
        create_plugin("descriptors", "hks", times=times).compute(ellipsoid)


def test_cli_describe_scalar_time(off_file, tmp_path, capsys):
    out = tmp_path / "one.npz"
    code, _, err = run_cli(capsys, "describe", off_file, "--param", "times=1", "-o", out)
    assert code == 0 and err == "", err
    d = np.load(out)["descriptor"]
    assert d.shape == (162, 1) and np.all(np.isfinite(d))


@pytest.mark.parametrize("value", ["1e300", "1e308", "[1, 1e300]", "-1", "nan", "[]"])
@pytest.mark.parametrize("scale", ["none", "trace"])
def test_cli_describe_bad_times_is_one_line(off_file, tmp_path, capsys, value, scale):
    code, _, err = run_cli(capsys, "describe", off_file, "--param", f"times={value}", "--param", f"scale={scale}",
                           "-o", tmp_path / "bad.npz")
    assert code == 2 and err.count("\n") == 1 and "times must be" in err, err
    assert not (tmp_path / "bad.npz").exists()


@pytest.mark.parametrize("name", ["heat-diffusion", "heat-distance"])
def test_keypoint_heat_descriptors_take_one_time_and_refuse_vanished_heat(ellipsoid, name):
    """The same rules through the keypoint heat descriptors' shared inputs (found by fuzzing: times=1 was an
    internal error, times=1e300 an all-zero descriptor)."""
    kp = np.array([0, 5, 50, 100])
    one = create_plugin("descriptors", name, times=1.0)
    assert one.n_times_out() == 1
    d = one.compute(ellipsoid, keypoints=kp)
    np.testing.assert_array_equal(d, create_plugin("descriptors", name, times=[1.0]).compute(ellipsoid, keypoints=kp))
    for times in (1e300, [1.0, 1e4]):
        with pytest.raises(ParameterError, match="times must be at most"):
            create_plugin("descriptors", name, times=times).compute(ellipsoid, keypoints=kp)


def test_describe_refuses_keypoints_a_descriptor_would_ignore(off_file, tmp_path, capsys):
    """hks and wks read no keypoints: --keypoints is refused with one line, as segment refuses constraints an
    unsupervised method would ignore (found by fuzzing: silently ignored); the keypoint descriptors take them."""
    kp = tmp_path / "kp.txt"
    kp.write_text("0\n5\n50\n")
    for name in ("hks", "wks"):
        code, _, err = run_cli(capsys, "describe", off_file, "--descriptor", name, "--keypoints", kp,
                               "-o", tmp_path / f"{name}.npz")
        assert code == 2 and err.count("\n") == 1 and "would ignore them" in err, err
    code, _, err = run_cli(capsys, "describe", off_file, "--descriptor", "heat-distance", "--keypoints", kp,
                           "-o", tmp_path / "hd.npz")
    assert code == 0, err
    assert np.load(tmp_path / "hd.npz")["descriptor"].shape[0] == 162


@pytest.mark.parametrize("variance", [1e-308, 1e308, 1e160])
def test_wks_variance_float64_cannot_hold_is_refused(ellipsoid, variance):
    """Filters whose squared width under- or overflows (found by fuzzing: exit 0 with a NaN/inf descriptor and a
    numpy warning); an ordinary width still works."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ParameterError, match="variance"):
            create_plugin("descriptors", "wks", variance=variance).compute(ellipsoid)
        assert np.all(np.isfinite(create_plugin("descriptors", "wks", variance=26.0).compute(ellipsoid)))


@pytest.mark.parametrize("params", [{"time_ratio": 1e300}, {"n_times": 400, "time_ratio": 10.0}])
def test_scree_times_that_overflow_are_refused_without_warnings(ellipsoid, params):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ParameterError, match="overflow float64"):
            create_plugin("descriptors", "heat-diffusion", **params).compute(ellipsoid, keypoints=np.array([0, 5]))
