"""Bad parameters of the matchers (shell-alignment, eigvec-alignment, replicator, umeyama, rrwm, photometric):
values found by fuzzing that hung, ran out of memory, crashed or printed numpy warnings are refused up front with
one ParameterError line (exit 2 in the CLI); the bounds themselves run, quickly and without warnings, and counts
that saturate stop early with the saturated result."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from helpers import run_cli, time_budget

from shape_toolkit.api.registry import create_plugin
from shape_toolkit.core.shape import Shape
from shape_toolkit.data.generate import icosphere
from shape_toolkit.errors import ParameterError
from shape_toolkit.io.mesh import save_shape

#: seconds any call here may take (each is well under 10 s; the old code hung on several)
BUDGET = 60




@pytest.fixture(scope="module")
def pair() -> tuple[Shape, Shape]:
    """The fuzzed input: a 162-vertex icosphere and the same scaled by 1.1."""
    s = icosphere(2)
    return s, Shape(s.vertices * 1.1, s.faces)


KEYPOINTS = np.arange(0, 162, 9)

BAD = [
    ("dense_matchers", "shell-alignment", {"iters": 10**9}),
    ("dense_matchers", "shell-alignment", {"beta": 1e308}),
    ("dense_matchers", "shell-alignment", {"alpha": 1e308}),
    ("dense_matchers", "shell-alignment", {"mu": 1e308}),
    ("dense_matchers", "eigvec-alignment", {"beam": 10**9}),
    ("dense_matchers", "eigvec-alignment", {"bins": 10**9}),
    ("dense_matchers", "eigvec-alignment", {"k": 100}),  # in k's range, but not with the search alignment
    ("sparse_matchers", "replicator", {"sigma": 1e308}),
    ("sparse_matchers", "replicator", {"sigma": 1e-308}),
    ("sparse_matchers", "replicator", {"time": 1e308}),
    ("sparse_matchers", "umeyama", {"sigma": 1e308}),
    ("sparse_matchers", "umeyama", {"sigma": 1e-308}),
    ("sparse_matchers", "rrwm", {"inflation": 1e308}),
    ("sparse_matchers", "rrwm", {"sigma": 1e308}),
    ("sparse_matchers", "photometric", {"n_rings": 10**9}),
]


def _match(family: str, name: str, params: dict, pair: tuple[Shape, Shape]):
    s, t = pair
    m = create_plugin(family, name, **params)
    if family == "dense_matchers":
        return m.match(s, t)
    return m.match(s, t, KEYPOINTS, KEYPOINTS)


@pytest.mark.parametrize(("family", "name", "params"), BAD, ids=[f"{n}-{p}" for _, n, p in BAD])
def test_bad_values_are_refused_with_one_line(family, name, params, pair):
    """Each fuzzed value raises a one-line ParameterError naming the parameter, before any work."""
    with warnings.catch_warnings(), time_budget(), pytest.raises(ParameterError) as err:
        warnings.simplefilter("error")
        _match(family, name, params, pair)
    msg = str(err.value)
    assert "\n" not in msg and next(iter(params)) in msg


GOOD = [
    ("dense_matchers", "shell-alignment", {"alpha": 1e3, "beta": 1e3, "mu": 1e6, "iters": 1000}),
    ("dense_matchers", "eigvec-alignment", {"k": 100, "alignment": "histogram", "bins": 1000}),
    ("sparse_matchers", "replicator", {"sigma": 1e-8, "time": 1e100}),
    ("sparse_matchers", "replicator", {"sigma": 1e8}),
    ("sparse_matchers", "umeyama", {"sigma": 1e-8, "time": 1e100}),
    ("sparse_matchers", "umeyama", {"sigma": 1e8}),
    ("sparse_matchers", "rrwm", {"inflation": 600.0}),
    ("sparse_matchers", "photometric", {"n_rings": 100, "ring_width": 10**9}),
]


@pytest.mark.parametrize(("family", "name", "params"), GOOD, ids=[f"{n}-{p}" for _, n, p in GOOD])
def test_bounds_run_without_warnings(family, name, params, pair):
    """The largest (and smallest) accepted values run within the budget and print no numpy warning."""
    with warnings.catch_warnings(), time_budget():
        warnings.simplefilter("error")
        out = _match(family, name, params, pair)
    assert out is not None


def test_photometric_rings_stop_at_saturation(pair):
    """Rings wider than the mesh stop growing once they cover it: the same matches as a width just past the
    mesh's extent (162-vertex icosphere: a few rings), at once for any width."""
    s, t = pair
    with time_budget():
        wide = create_plugin("sparse_matchers", "photometric", ring_width=10**9).match(s, t, KEYPOINTS, KEYPOINTS)
    past = create_plugin("sparse_matchers", "photometric", ring_width=50).match(s, t, KEYPOINTS, KEYPOINTS)
    np.testing.assert_array_equal(wide, past)


def test_shell_alignment_many_iters_stop_at_a_fixed_point(pair):
    """A resolution stops once both maps repeat (exact, so the result is that of fewer steps); the most steps
    run within the budget."""
    s, t = pair
    kw = {"k_schedule": (6, 12)}
    with time_budget():
        many = create_plugin("dense_matchers", "shell-alignment", iters=1000, **kw).match(s, t)
    few = create_plugin("dense_matchers", "shell-alignment", iters=50, **kw).match(s, t)
    np.testing.assert_array_equal(many.target_of, few.target_of)
    assert many.info["residual"] == few.info["residual"]


def test_cli_bad_matcher_param_exits_2_with_one_line(pair, tmp_path, capsys):
    """Through the CLI: exit 2 and one stderr line, nothing written."""
    s, t = pair
    save_shape(s, tmp_path / "s.off")
    save_shape(t, tmp_path / "t.off")
    toml = tmp_path / "p.toml"
    toml.write_text('[dense]\nplugin = "shell-alignment"\nparams = { iters = 1000000000 }\n')
    with time_budget():
        code, out, err = run_cli(capsys, "match", tmp_path / "s.off", tmp_path / "t.off", "--pipeline", toml,
                                 "-o", tmp_path / "m.txt", "-q")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "iters" in err
    assert not (tmp_path / "m.txt").exists()
