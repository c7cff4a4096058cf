"""Bad parameter values of the segmenter plugins are refused up front with one ParameterError line (CLI: one
stderr line, exit 2), before they can hang, run out of memory, overflow (numpy warnings) or fail inside numpy.
Every case that hung or ran for long before the bounds is guarded by an alarm, so it fails instead of hanging."""

from __future__ import annotations

import warnings

import pytest
from helpers import run_cli, time_budget

from shape_toolkit.api.registry import create_plugin
from shape_toolkit.data.generate import icosphere
from shape_toolkit.errors import ParameterError
from shape_toolkit.io.mesh import save_shape

#: (segmenter, parameter, refused value): the values found by fuzzing, and the first value past each bound
BAD = [
    ("csc", "n_init", 1_000_000_000),
    ("ccskl", "n_init", 1_000_000_000),
    ("sdf", "n_init", 1001),
    ("eigvec-gmm", "n_init", 1001),
    ("sdf", "filter_iterations", 1_000_000_000),
    ("sdf", "n_rays", 1_000_000_000),
    ("sdf", "n_rays", 10**21),
    ("smoothed", "spread", 1_000_000_000),
    ("eigvec-gmm", "max_components_1d", 100_000),
    ("eigvec-gmm", "max_components_1d", 21),
    ("sdf", "smoothing_lambda", 1e308),
    ("smoothed", "smoothing_lambda", 1e308),
    ("seeded-walk", "smoothing_lambda", 1e308),
    ("csc", "convex_factor", 1e308),
    ("ncut", "convex_factor", 1e308),
    ("seeded-walk", "convex_factor", 1e308),
    ("sdf", "convex_factor", 1.5),
    ("smoothed", "convex_factor", 1e308),
    ("ncut", "concavity_scale", 1e-308),
    ("seeded-walk", "concavity_scale", 1e-308),
]




@pytest.fixture(scope="module")
def ico():
    return icosphere(2)


def _kwargs(name: str) -> dict:
    return {} if name == "seeded-walk" else {"n_segments": 3}


@pytest.mark.parametrize(("name", "key", "value"), BAD, ids=[f"{n}-{k}-{v:g}" for n, k, v in BAD])
def test_bad_value_refused(ico, name, key, value):
    seg = create_plugin("segmenters", name, **_kwargs(name), **{key: value})
    with time_budget(20), warnings.catch_warnings():
        warnings.simplefilter("error")  # an overflow warning before the error fails the test
        with pytest.raises(ParameterError, match=key) as info:
            seg.segment(ico)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(("name", "key", "value"), [
    ("csc", "convex_factor", 1e6),
    ("ncut", "convex_factor", 1e6),
    ("ncut", "concavity_scale", 1e-6),
    ("sdf", "smoothing_lambda", 1e6),
    ("sdf", "convex_factor", 1.0),
    ("sdf", "filter_iterations", 1000),
    ("smoothed", "spread", 1000),
    ("smoothed", "smoothing_lambda", 1e6),
])
def test_bound_value_runs_quietly(ico, name, key, value):
    """The bounds themselves are accepted, run in reasonable time and warn nothing."""
    seg = create_plugin("segmenters", name, n_segments=3, **{key: value})
    with time_budget(60), warnings.catch_warnings():
        warnings.simplefilter("error")
        labels = seg.segment(ico).face_labels
    assert len(labels) == ico.n_faces


def test_cli_one_line_exit_2(tmp_path, capsys, ico):
    save_shape(ico, tmp_path / "s.off")
    with time_budget(20):
        code, out, err = run_cli(capsys, "segment", tmp_path / "s.off", "--method", "sdf", "-k", "3",
                                 "--param", "n_rays=1000000000", "-o", tmp_path / "o.txt", "-q")
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "n_rays" in lines[0], err
