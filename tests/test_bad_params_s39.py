"""Bad parameters found by fuzzing eigvec-alignment's window, em-registration and ``shape-toolkit spectrum``: each
either crashed (an untyped exception: exit 1 in the CLI), hung, allocated a graph of every pair of points, or
returned a silently wrong result; now a ParameterError (exit 2 and one stderr line in the CLI) or a sane result."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from helpers import run_cli, time_budget

from shape_toolkit.core.shape import Shape
from shape_toolkit.data.generate import icosphere
from shape_toolkit.errors import ParameterError
from shape_toolkit.io.mesh import save_shape
from shape_toolkit.plugins.matching.dense.eigvec_alignment import EigvecAlignmentMatcher, joint_alignment_candidates
from shape_toolkit.plugins.matching.dense.em_registration import EMRegistrationMatcher
from shape_toolkit.spectra import build_graph

#: seconds any call here may take (each is well under 10 s; the old code hung on max_iter)
BUDGET = 60


@pytest.fixture(scope="module")
def pair() -> tuple[Shape, Shape]:
    """A 42-vertex icosphere and the same stretched."""
    s = icosphere(1)
    return s, Shape(s.vertices * np.array([1.2, 1.0, 0.9]), s.faces)


# -- eigvec-alignment's window -----------------------------------------------------------------
@pytest.mark.parametrize("window", [30, 10**30, np.int64(2**63 - 1)])
def test_eigvec_window_above_every_place_is_refused(pair, window):
    """From k - 1 <= 29 on, every eigenvector may go anywhere: a wider window was accepted and meant nothing more."""
    with time_budget(BUDGET), pytest.raises(ParameterError, match="window must be an int in \\[1, 29\\]"):
        EigvecAlignmentMatcher(window=window).match(*pair)


def test_eigvec_window_bound_is_declared():
    m = EigvecAlignmentMatcher(window=29)
    m._validate_params()  # the bound itself is accepted
    assert EigvecAlignmentMatcher.parameter_constraints["window"].accepts(3)  # the default


@pytest.mark.parametrize("window", [-1, 2.5, float("nan")])
def test_joint_alignment_candidates_refuses_bad_window(window):
    """A negative window returned no candidate at all, 2.5 a TypeError, NaN any permutation."""
    X = np.random.default_rng(0).standard_normal((50, 4))
    with pytest.raises(ParameterError, match="window must be a non-negative int"):
        joint_alignment_candidates(X, X, window=window)


@pytest.mark.parametrize("beam", [0, -3])
def test_joint_alignment_candidates_refuses_bad_beam(beam):
    X = np.random.default_rng(0).standard_normal((50, 4))
    with pytest.raises(ParameterError, match="beam"):
        joint_alignment_candidates(X, X, beam=beam)


def test_joint_alignment_candidates_huge_numpy_window_is_the_whole_spectrum():
    """np.int64's largest window overflowed (a RuntimeWarning) and returned no candidate; it is every place."""
    X = np.random.default_rng(0).standard_normal((50, 4))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        wide = joint_alignment_candidates(X, X, window=np.int64(2**63 - 1), beam=6)
    assert len(wide) == 6
    assert all(np.array_equal(a, b) for a, b in zip(wide, joint_alignment_candidates(X, X, window=3, beam=6)))


# -- em-registration ---------------------------------------------------------------------------
def test_em_max_iter_is_bounded(pair):
    """max_iter = 1e9 with tol = 0 ran for ever (EM's change never goes below 0)."""
    seeds = np.stack([np.arange(0, 42, 5)] * 2, axis=1)
    with time_budget(BUDGET), pytest.raises(ParameterError, match="max_iter must be an int in \\[1, 1000\\]"):
        EMRegistrationMatcher(max_iter=10**9, tol=0.0, orientation="none").match(*pair, seeds=seeds)
    with time_budget(BUDGET):  # the bound itself runs
        c = EMRegistrationMatcher(max_iter=1000, tol=0.0, orientation="none").match(*pair, seeds=seeds)
    assert np.all(c.target_of >= 0)


# -- weightings (spectrum --param) -------------------------------------------------------------
@pytest.mark.parametrize("scale", [1e-200, 1e-300])
def test_gaussian_local_tiny_scale_is_a_parameter_error(scale):
    """bandwidth='local' squared the scale in Python floats: 0.0, then ZeroDivisionError."""
    with pytest.raises(ParameterError, match="bandwidth_scale is too small"):
        build_graph(icosphere(1), "gaussian", bandwidth="local", bandwidth_scale=scale)


def test_gaussian_local_huge_scale_weighs_every_edge_one():
    """bandwidth='local' with scale 1e308 raised OverflowError; it is the binary graph, as for any scale >= 1e8."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        g = build_graph(icosphere(1), "gaussian", bandwidth="local", bandwidth_scale=1e308)
    assert g.info["weight_lower_bound"] == 1.0 and g.info["min_weight"] == 1.0


@pytest.mark.parametrize("value", [10**400, -(10**400), 10**5000], ids=["1e400", "-1e400", "1e5000"])
def test_int_beyond_float_range_is_a_parameter_error(value):
    """An int too large for a float raised OverflowError in the check (10**5000: ValueError printing it)."""
    with pytest.raises(ParameterError, match="bandwidth must be"):
        build_graph(icosphere(1), "gaussian", bandwidth=value)


@pytest.mark.parametrize("factor", [1e9, 1e23, 1.5])
def test_intrinsic_delaunay_mollify_factor_is_bounded(factor):
    """1e9 inflated every edge by a billion mean lengths: eigenvalues of 2e-18 on a unit sphere, silently."""
    with pytest.raises(ParameterError, match="mollify_factor must be a float in \\[0, 1\\]"):
        build_graph(icosphere(1), "intrinsic-delaunay", mollify_factor=factor)


def test_intrinsic_delaunay_mollify_factor_bound_runs():
    g = build_graph(icosphere(1), "intrinsic-delaunay", mollify_factor=1.0)
    assert np.isfinite(g.W.data).all()


# -- shape-toolkit spectrum --------------------------------------------------------------------
def _one_line_exit_2(capsys, *args) -> str:
    code, _, err = run_cli(capsys, "spectrum", *args)
    assert code == 2 and len(err.strip().splitlines()) == 1, (code, err)
    return err


def test_spectrum_param_n_neighbors_points_to_the_option(capsys, tmp_path):
    """--param n_neighbors=5 collided with build_graph's keyword: TypeError, an internal error (exit 1)."""
    cloud = tmp_path / "cloud.xyz"
    np.savetxt(cloud, icosphere(2).vertices)
    err = _one_line_exit_2(capsys, cloud, "-q", "-k", "5", "--weighting", "intrinsic-delaunay",
                           "--param", "n_neighbors=5")
    assert "--neighbors" in err


@pytest.mark.parametrize("graph", [["--connectivity", "epsilon", "--radius", "1e9"], ["--neighbors", "641"]])
def test_spectrum_graph_of_every_pair_is_checked_against_the_memory_limit(capsys, tmp_path, graph):
    """A radius or neighbour count linking every pair built n^2 / 2 edges whatever --memory-limit said (25 GB at
    20,000 points); the pairs are now counted first (642 points: 205,761 pairs, ~0.104 GB with the spectrum's)."""
    s = icosphere(3)
    path = tmp_path / ("s.off" if "--radius" in graph else "s.xyz")
    if "--radius" in graph:
        save_shape(s, path)
    else:
        np.savetxt(path, s.vertices)
    err = _one_line_exit_2(capsys, path, "-q", "-k", "5", "--weighting", "gaussian", *graph, "--memory-limit", "0.1")
    assert "memory limit" in err
    code, _, _ = run_cli(capsys, "spectrum", path, "-q", "-k", "5", "--weighting", "gaussian", *graph,
                         "--memory-limit", "0.2")
    assert code == 0
