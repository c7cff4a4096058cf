"""The PSB benchmark script: split, k rule, and one real mesh through sdf and smoothed (skipped without data)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

_SCRIPT = Path(__file__).resolve().parent.parent / "benchmarks" / "psb_segmentation.py"


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("psb_segmentation", _SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_categories_and_split(bench):
    assert bench.category_of("1") == "human" and bench.category_of("387") == "fourleg"
    assert bench.category_of("287") == "armadillo" and bench.category_of("247") == "bird"
    ids = ["1", "2", "7", "8", "27", "28", "47"]
    split = bench.split_of(ids)
    assert split == bench.split_of(list(reversed(ids)))  # order independent
    for cat_ids in (["1", "2", "7", "8"], ["27", "28"]):
        assert sum(split[i] == "tuning" for i in cat_ids) == len(cat_ids) // 2
    assert split["47"] == "held-out"  # a lone mesh is never used for tuning


def test_human_k(bench):
    assert bench.human_k([np.array([0, 1, 2]), np.array([0, 1, 1]), np.array([0, 0, 0])]) == 2
    assert bench.human_k([np.arange(5), np.arange(6)]) == 6  # median 5.5 rounds half up


@pytest.mark.slow
def test_one_real_mesh(bench, shared_data):
    psb = shared_data / "psb"
    if not (psb / "off" / "121.off").is_file():
        pytest.skip("PSB mesh 121 not in the shared data")
    methods = [m for m in bench.METHODS if m[0] in ("sdf", "spectral-clustering+smooth")]
    r = bench.run_mesh(psb, "121", 0, lambda s: None, methods,
                       {"sdf": {"n_clusters": 5, "smoothing_lambda": 0.26}, "smoothed": {"smoothing_lambda": 0.5}})
    for name in ("sdf", "spectral-clustering+smooth"):
        row = r["rows"][name]
        assert "error" not in row, row
        assert 0.0 <= row["rand_index_error"] < 0.5
    assert r["rows"]["human"]["rand_index_error"] < 0.2
