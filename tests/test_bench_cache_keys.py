"""Every cache entry carries its key and is verified on read: a swapped, copied, truncated or
empty cache file is a miss (recomputed, reported once), never a wrong result (issue 27)."""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from helpers import SPECTRAL_CLUSTERING, bench_run, segmentation_config, write_config

from shape_toolkit.bench import read_rows
from shape_toolkit.bench.store import load_output, load_prepared, prepared_path
from shape_toolkit.core import spectrum as spm
from shape_toolkit.core.spectrum import CacheWarning, compute_spectrum
from shape_toolkit.data.generate import icosphere
from shape_toolkit.spectra import build_graph


@pytest.fixture
def disk_cache(tmp_path):
    d = tmp_path / "spectra"
    spm.set_cache_dir(d)
    spm.clear_cache()
    spm._REPORTED.clear()
    yield d
    spm.set_cache_dir(None)
    spm.clear_cache()


def _files(d: Path) -> list[Path]:
    return sorted(d.glob("*.npz"))


def _same(a, b) -> bool:
    return a.k == b.k and a.laplacian == b.laplacian and np.allclose(a.eigenvalues, b.eigenvalues)


def test_swapped_spectrum_files_are_misses_not_wrong_spectra(disk_cache):
    shape = icosphere(2)
    cot, gauss = build_graph(shape, "cotangent"), build_graph(shape, "gaussian")
    a, b = compute_spectrum(cot, 8), compute_spectrum(gauss, 8)
    fa, fb = (disk_cache / "a.tmp"), None
    files = _files(disk_cache)
    assert len(files) == 2
    fa, fb = files
    tmp = disk_cache / "swap"
    shutil.move(fa, tmp)
    shutil.move(fb, fa)
    shutil.move(tmp, fb)
    spm.clear_cache()
    with pytest.warns(CacheWarning, match="another key"):
        a2 = compute_spectrum(cot, 8)
    with pytest.warns(CacheWarning, match="another key"):
        b2 = compute_spectrum(gauss, 8)
    assert _same(a2, a) and _same(b2, b) and a2.weighting == a.weighting and b2.weighting == b.weighting
    spm.clear_cache()  # the recomputed files replaced the swapped ones: hits, no warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _same(compute_spectrum(cot, 8), a) and spm.is_cached(cot, 8)


def test_a_small_spectrum_copied_over_a_larger_key_is_a_miss(disk_cache):
    g = build_graph(icosphere(2), "gaussian")
    small = compute_spectrum(g, 7, laplacian="normalized")
    (f_small,) = _files(disk_cache)
    big = compute_spectrum(g, 20)
    (f_big,) = [f for f in _files(disk_cache) if f != f_small]
    shutil.copyfile(f_small, f_big)
    spm.clear_cache()
    with pytest.warns(CacheWarning):
        again = compute_spectrum(g, 20)
    assert again.k == 20 and again.laplacian == "combinatorial" and _same(again, big)
    assert small.k == 7


@pytest.mark.parametrize("damage", ["truncate", "empty", "garbage"])
def test_a_corrupt_spectrum_file_is_a_miss_reported_once(disk_cache, damage):
    g = build_graph(icosphere(2), "cotangent")
    ref = compute_spectrum(g, 6)
    (f,) = _files(disk_cache)
    data = f.read_bytes()
    f.write_bytes({"truncate": data[: len(data) // 2], "empty": b"", "garbage": b"PK\x03\x04junk"}[damage])
    spm.clear_cache()
    with pytest.warns(CacheWarning, match="unreadable") as got:
        assert _same(compute_spectrum(g, 6), ref)
    assert len(got) == 1
    spm.clear_cache()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # rewritten: a clean hit now
        assert _same(compute_spectrum(g, 6), ref)


# -- run folders ------------------------------------------------------------------------------
CONFIG = segmentation_config("keys", limit=2, n_poses=3, methods=SPECTRAL_CLUSTERING + """[[tasks.methods]]
plugin = "spectral-clustering"
preset = "luxburg-unnormalized"
label = "norm"
params = { n_segments = 4, weighting = "cotangent" }
""")


def _run(tmp_path: Path, run: Path, *extra: str) -> int:
    return bench_run(write_config(tmp_path, CONFIG), run, *extra)


def _results(run: Path) -> dict[tuple, object]:
    return {r["key"]: (r["status"], r["metrics"]) for r in read_rows(run)}


def _labels(run: Path) -> dict[str, np.ndarray]:
    return {r["key"]: load_output(run, r["output"], key=r["key"])["labels"] for r in read_rows(run)}


def _rerun(tmp_path, run, capsys) -> str:
    (run / "results.jsonl").unlink()
    capsys.readouterr()
    assert _run(tmp_path, run) == 0
    return capsys.readouterr().err


def test_swapped_cache_files_in_a_run_folder_give_the_same_rows(tmp_path, capsys):
    run = tmp_path / "run"
    assert _run(tmp_path, run) == 0
    before, labels = _results(run), _labels(run)
    assert len(before) == 4 and all(s == "ok" for s, _ in before.values())
    for folder in ("cache/prepared", "cache/spectra"):
        files = sorted((run / folder).glob("*.npz"))
        assert len(files) >= 2, folder
        a, b = files[0], files[-1]
        data_a = a.read_bytes()
        a.write_bytes(b.read_bytes())
        b.write_bytes(data_a)
    err = _rerun(tmp_path, run, capsys)
    assert "ignored" in err and "Traceback" not in err
    assert _results(run) == before
    after = _labels(run)
    assert all(np.array_equal(after[k], v) for k, v in labels.items())


def test_truncated_and_empty_cache_files_are_misses_not_failed_rows(tmp_path, capsys):
    run = tmp_path / "run"
    assert _run(tmp_path, run) == 0
    before = _results(run)
    for i, f in enumerate(sorted((run / "cache").rglob("*.npz"))):
        f.write_bytes(b"" if i % 2 else f.read_bytes()[:100])
    err = _rerun(tmp_path, run, capsys)
    assert _results(run) == before
    assert "Traceback" not in err
    for r in read_rows(run):  # rebuilt: each prepared item holds its own key again
        load_prepared(prepared_path(run, r["prepare_key"]), key=r["prepare_key"])


def test_an_output_file_written_for_another_row_is_refused(tmp_path):
    run = tmp_path / "run"
    assert _run(tmp_path, run) == 0
    rows = read_rows(run)
    a, b = (run / rows[0]["output"]), (run / rows[1]["output"])
    a.write_bytes(b.read_bytes())
    with pytest.raises(ValueError, match="another row"):
        load_output(run, rows[0]["output"], key=rows[0]["key"])
    assert load_output(run, rows[1]["output"], key=rows[1]["key"])
