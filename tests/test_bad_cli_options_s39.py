"""Bad values of the commands' own options (not --param), found by fuzzing them: each is refused with one line
and exit 2 before any work, instead of an internal error, a hang, a misattributed message or a value silently
ignored. Every case here failed on the former code."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import run_cli

from shape_toolkit.core.shape import Shape
from shape_toolkit.data.generate import icosphere
from shape_toolkit.io.mesh import save_shape

BIG = "9" * 400  # an integer past float range


@pytest.fixture(autouse=True)
def _in_process(monkeypatch):
    monkeypatch.setenv("SHAPE_TOOLKIT_IN_PROCESS", "1")


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> Path:
    """An icosphere (162 vertices) ``s.ply``, a stretched copy ``t.ply``, the identity map, two-part vertex labels,
    per-vertex values (``col.txt``, one column) and a 3-column ``cols.npy``."""
    d = tmp_path_factory.mktemp("opts")
    s = icosphere(2)
    save_shape(s, d / "s.ply")
    save_shape(Shape(s.vertices * np.array([1.5, 1.0, 0.8]), s.faces, "t"), d / "t.ply")
    np.savetxt(d / "map.txt", np.arange(s.n_vertices), fmt="%d")
    np.savetxt(d / "lab.txt", (s.vertices[:, 2] > 0).astype(int), fmt="%d")
    np.savetxt(d / "truth.txt", np.arange(20), fmt="%d")
    np.savetxt(d / "col.txt", s.vertices[:, 0])
    np.save(d / "cols.npy", s.vertices)
    return d


def _refused(code: int, out: str, err: str, *words: str) -> None:
    assert code == 2, (code, err)
    assert len(err.strip().splitlines()) == 1 and "internal error" not in err, err
    assert not out, out
    for w in words:
        assert w in err, err


def _child(*args: object, timeout: float = 60) -> tuple[int, str, str]:
    """``shape-toolkit ARGS`` in a child process, killed (the test failing) past ``timeout`` seconds: for values that
    once ran for hours inside native code, where no alarm in this process could stop them."""
    env = {**os.environ, "SHAPE_TOOLKIT_IN_PROCESS": "1"}
    code = "import sys; from shape_toolkit.cli import main; sys.exit(main(sys.argv[1:]))"
    r = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True,
                       timeout=timeout, env=env)
    return r.returncode, r.stdout, r.stderr


# -- --proxy: an integer past float range was an internal OverflowError in the memory estimate ----------------------
@pytest.mark.parametrize("command", ["match", "segment", "transfer-labels", "track"])
def test_proxy_past_float_range_is_refused(files, capsys, tmp_path, command):
    d = files
    inputs = {"match": [d / "s.ply", d / "t.ply"], "segment": [d / "s.ply", "-k", "3"],
              "transfer-labels": [d / "s.ply", d / "lab.txt", d / "t.ply"], "track": [d / "s.ply", d / "t.ply"]}
    out_name = "o.npz" if command == "track" else "o.txt"
    code, out, err = run_cli(capsys, command, *inputs[command], "--proxy", BIG, "-o", tmp_path / out_name)
    _refused(code, out, err, "--proxy", "an integer of 400 digits")
    assert not (tmp_path / out_name).exists()


# -- geodesics --sources ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("ids", ["99999999999999999999", "0," + "9" * 250])
def test_geodesics_source_id_past_int64_is_out_of_range(files, capsys, tmp_path, ids):
    code, out, err = run_cli(capsys, "geodesics", files / "s.ply", "--sources", ids, "-o", tmp_path / "g.npz")
    _refused(code, out, err, "--sources", "out of range")


def test_geodesics_sources_too_long_for_a_file_name_are_read_as_ids(files, capsys, tmp_path):
    code, out, err = run_cli(capsys, "geodesics", files / "s.ply", "--sources", "9" * 5000, "-o", tmp_path / "g.npz")
    _refused(code, out, err, "--sources")  # was the system's 'File name too long'
    assert "File name too long" not in err


# -- clean ---------------------------------------------------------------------------------------------------------
def test_clean_remesh_iterations_are_bounded(files, capsys, tmp_path):
    out_file = tmp_path / "c.ply"
    code, out, err = run_cli(capsys, "clean", files / "s.ply", "--remesh", "0.2", "--remesh-iterations", BIG,
                             "-o", out_file)  # was pybind11's internal 'Unable to cast Python instance'
    _refused(code, out, err, "--remesh-iterations", "[1, 100]")
    code, out, err = _child("clean", files / "s.ply", "--remesh", "0.2", "--remesh-iterations", "1000000000",
                            "-o", out_file)  # ran for hours
    _refused(code, out, err, "--remesh-iterations")
    assert not out_file.exists()
    code, out, err = run_cli(capsys, "clean", files / "s.ply", "--remesh", "0.2", "--remesh-iterations", "100",
                             "-o", out_file, "--json")
    assert code == 0, err


@pytest.mark.parametrize("extra, name, problem", [
    (["--remesh-iterations", "5"], "c.ply", "--remesh-iterations applies to remeshing"),
    (["--binary"], "c.off", "--binary applies to PLY and STL"),
    (["--binary"], "c.obj", "--binary applies to PLY and STL"),
])
def test_clean_options_that_would_be_ignored_are_refused(files, capsys, tmp_path, extra, name, problem):
    code, out, err = run_cli(capsys, "clean", files / "s.ply", *extra, "-o", tmp_path / name)
    _refused(code, out, err, problem)
    assert not (tmp_path / name).exists()


# -- constraints ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("value", ["nan", "inf", "-1", "1.5", BIG])
def test_constraints_min_segment_fraction_names_the_option(files, capsys, tmp_path, value):
    # was refused later in words blaming the labels file ('lab.txt: min_segment_fraction must be ...')
    code, out, err = run_cli(capsys, "constraints", files / "s.ply", files / "lab.txt",
                             "--min-segment-fraction", value, "-o", tmp_path / "c.json")
    _refused(code, out, err, "--min-segment-fraction", "[0, 1]")
    assert "lab.txt" not in err


def test_constraints_cannot_per_boundary_past_the_edge_count_is_refused(files, capsys, tmp_path):
    code, out, err = _child("constraints", files / "s.ply", files / "lab.txt", "--cannot-per-boundary", "1000000000",
                            "-o", tmp_path / "c.json")  # drew 1e9 links per boundary, for hours
    _refused(code, out, err, "--cannot-per-boundary", "480 edges")
    assert not (tmp_path / "c.json").exists()
    code, out, err = run_cli(capsys, "constraints", files / "s.ply", files / "lab.txt", "--cannot-per-boundary",
                             "480", "-o", tmp_path / "c.json")
    assert code == 0, err


def test_constraints_default_cannot_per_boundary_fits_a_mesh_of_fewer_edges(capsys, tmp_path):
    """The default (3) on a mesh of two edges (two degenerate faces, as the adversarial corpus's
    repeated_index_faces.off) draws as many as there are; only a value the user gives is refused."""
    (tmp_path / "m.off").write_text("OFF\n3 2 0\n0 0 0\n1 0 0\n0 1 0\n3 0 0 1\n3 1 1 2\n")
    np.savetxt(tmp_path / "lab.txt", [0, 0, 1], fmt="%d")
    code, out, err = run_cli(capsys, "constraints", tmp_path / "m.off", tmp_path / "lab.txt", "-o", tmp_path / "c.json")
    assert code == 0, err
    code, out, err = run_cli(capsys, "constraints", tmp_path / "m.off", tmp_path / "lab.txt", "--cannot-per-boundary",
                             "99", "-o", tmp_path / "d.json")
    assert code == 2 and "at most 2" in err, err


# -- evaluate-map: an option of an evaluation not asked for ------------------------------------------------------
@pytest.mark.parametrize("extra, option", [
    (["--truth-src", "T", "--truth-dst", "T", "--zero-based", "--r-theta", "0.5"], "--r-theta"),
    (["--truth-src", "T", "--truth-dst", "T", "--zero-based", "--r-sample", "5"], "--r-sample"),
    (["--r-smoothness", "1", "--random-state", "3"], "--random-state"),
    (["--r-smoothness", "1", "--zero-based"], "--zero-based"),
    (["--r-smoothness", "1", "--geodesics", "exact"], "--geodesics"),
])
def test_evaluate_map_options_that_would_be_ignored_are_refused(files, capsys, extra, option):
    extra = [str(files / "truth.txt") if a == "T" else a for a in extra]
    code, out, err = run_cli(capsys, "evaluate-map", files / "s.ply", files / "t.ply", files / "map.txt", *extra)
    _refused(code, out, err, f"{option} applies to", "would be ignored")


def test_evaluate_map_defaults_still_apply(files, capsys):
    code, out, err = run_cli(capsys, "evaluate-map", files / "s.ply", files / "t.ply", files / "map.txt",
                             "--truth-src", files / "truth.txt", "--truth-dst", files / "truth.txt", "--zero-based",
                             "--r-smoothness", "1", "--json")
    assert code == 0, err
    res = json.loads(out)
    assert res["geodesics"] == "heat" and res["r_smoothness"]["theta"] == 0.9


# -- evaluate-segmentation --truth ------------------------------------------------------------------------------
def test_evaluate_segmentation_refuses_the_prediction_as_its_own_truth(files, capsys, tmp_path):
    gt = tmp_path / "gt"
    gt.mkdir()
    (gt / "a.txt").write_bytes((files / "lab.txt").read_bytes())
    (gt / "pred.txt").write_bytes((files / "lab.txt").read_bytes())
    # the prediction was scored against itself too, silently averaged in as a perfect truth
    code, out, err = run_cli(capsys, "evaluate-segmentation", files / "s.ply", gt / "pred.txt", "--truth", gt)
    _refused(code, out, err, "--truth folder", "holds the prediction")
    # named as the one truth it is asked for (a sanity check): still scored
    code, out, err = run_cli(capsys, "evaluate-segmentation", files / "s.ply", gt / "pred.txt", "--truth",
                             gt / "pred.txt")
    assert code == 0, err


def test_evaluate_segmentation_empty_truth_is_not_the_current_folder(files, capsys, tmp_path, monkeypatch):
    (tmp_path / "a.txt").write_bytes((files / "lab.txt").read_bytes())
    monkeypatch.chdir(tmp_path)  # the former code read '' as '.' and scored against a.txt
    code, out, err = run_cli(capsys, "evaluate-segmentation", files / "s.ply", files / "lab.txt", "--truth", "")
    _refused(code, out, err, "--truth", "empty")


# -- track ---------------------------------------------------------------------------------------------------------
def test_track_workers_are_bounded_before_any_cluster_starts(files, capsys, tmp_path, monkeypatch):
    from shape_toolkit.bench import executors

    def no_cluster(*_a, **_k):
        raise AssertionError("a local cluster was started")

    monkeypatch.setattr(executors, "dask_client", no_cluster)
    code, out, err = run_cli(capsys, "track", files / "s.ply", files / "t.ply", "--dask", "local",
                             "--workers", "100000", "-o", tmp_path / "tr.npz")  # would have started 100,000 processes
    _refused(code, out, err, "--workers", "4 per core")


@pytest.mark.parametrize("extra, problem", [
    (["--workers", "3"], "--workers applies to --dask local"),
    (["--dask", "tcp://127.0.0.1:1", "--workers", "3"], "--workers applies to --dask local"),
    (["--tracks", "5"], "--tracks applies to the drawings"),
    (["--tail", "2"], "--tail applies to the drawings"),
])
def test_track_options_that_would_be_ignored_are_refused(files, capsys, tmp_path, extra, problem):
    code, out, err = run_cli(capsys, "track", files / "s.ply", files / "t.ply", *extra, "-o", tmp_path / "tr.npz")
    _refused(code, out, err, problem)
    assert not (tmp_path / "tr.npz").exists()


# -- demo ----------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("extra, problem", [
    (["-k", "3", "--no-bench"], "argument -k: must be an integer >= 4"),  # was an internal IndexError (eigenvector 3)
    (["--workers", "2", "--no-bench"], "--workers applies to the benchmark showcase"),
    (["--workers", "100000"], "argument --workers"),  # was refused only after the spectrum and the match
])
def test_demo_options_are_checked_before_any_work(capsys, tmp_path, extra, problem):
    out_dir = tmp_path / "demo"
    code, out, err = run_cli(capsys, "demo", "-o", out_dir, "-q", *extra)
    _refused(code, out, err, problem)
    assert not out_dir.exists()


# -- view --column -----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("extra, problem", [
    (["--column", "2"], "--column applies to a 2D --scalar array"),
    (["--scalar", "COL", "--column", "1"], "no columns to choose from"),
])
def test_view_column_is_refused_where_it_would_be_ignored(files, capsys, tmp_path, extra, problem):
    extra = [str(files / "col.txt") if a == "COL" else a for a in extra]
    code, out, err = run_cli(capsys, "view", files / "s.ply", *extra, "--png", tmp_path / "v.png")
    _refused(code, out, err, problem)
    assert not (tmp_path / "v.png").exists()


def test_view_column_of_a_2d_array_still_draws(files, capsys, tmp_path):
    code, out, err = run_cli(capsys, "view", files / "s.ply", "--scalar", files / "cols.npy", "--column", "2",
                             "--png", tmp_path / "v.png")
    assert code == 0, err
    assert (tmp_path / "v.png").read_bytes()[:4] == b"\x89PNG"


# -- examples copy -------------------------------------------------------------------------------------------------
def test_examples_copy_to_an_empty_name_is_refused(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the former code copied into the current folder
    code, out, err = run_cli(capsys, "examples", "copy", "")
    _refused(code, out, err, "empty name")
    assert not any(tmp_path.iterdir())


def test_clean_remesh_to_a_vanishing_edge_is_one_line(files, tmp_path):
    """An edge length whose square underflows (1e-300) is refused with the budget's one line; numpy's divide-by-zero
    warning had printed a second line first."""
    _refused(*_child("clean", files / "s.ply", "-o", tmp_path / "c.ply", "--remesh", "1e-300"), "remeshing",
             "vertices")


def test_seed_files_with_a_source_vertex_matched_twice(files, tmp_path, capsys):
    """A seed file giving one source vertex two targets is refused naming both lines; a pair repeated as it is counts
    once (both had been accepted silently)."""
    from shape_toolkit.errors import ShapeFileError
    from shape_toolkit.results.correspondence import read_seeds

    bad = tmp_path / "bad.txt"
    bad.write_text("0 1\n5 5\n0 2\n")
    with pytest.raises(ShapeFileError, match="line 3: source vertex 0 is matched to 2 here and to 1 on line 1"):
        read_seeds(bad, 162, 162)
    again = tmp_path / "again.txt"
    again.write_text("0 1\n5 5\n0 1\n")
    assert read_seeds(again, 162, 162).tolist() == [[0, 1], [5, 5]]
    code, out, err = run_cli(capsys, "match", files / "s.ply", files / "t.ply", "--seeds", bad,
                             "-o", tmp_path / "m.txt")
    _refused(code, out, err, "source vertex 0")


def test_ncut_names_faces_when_too_many_segments(files, tmp_path, capsys):
    """ncut segments faces: its bound is the face count, and the message says so (it said vertices)."""
    code, out, err = run_cli(capsys, "segment", files / "s.ply", "--method", "ncut", "-k", "100000",
                             "-o", tmp_path / "l.txt")
    _refused(code, out, err, "number of faces (320)")


def test_an_empty_or_folder_pipeline_is_named_as_such(files, tmp_path, capsys):
    """`--pipeline ""` was read as the current folder ('.: no such pipeline file'), and a folder as a missing file."""
    for value, words in (("", ("empty pipeline name", "auto")), (str(tmp_path), ("is a folder",))):
        code, out, err = run_cli(capsys, "match", files / "s.ply", files / "t.ply", "--pipeline", value,
                                 "-o", tmp_path / "m.txt")
        _refused(code, out, err, *words)


def test_spectrum_of_a_cloud_is_the_one_match_uses(tmp_path, capsys):
    """`spectrum CLOUD` with the defaults: cotangent needs faces, so the cloud takes its point-cloud counterpart as
    match's spectra do (SpectrumSpec.for_shape), with that weighting's own neighbours (before: refused, and with
    --weighting intrinsic-delaunay a 10-neighbour graph where match's has 30)."""
    from shape_toolkit.spectra import SpectrumSpec

    cloud = Shape(icosphere(3).vertices, None, "cloud")
    save_shape(cloud, tmp_path / "c.xyz")
    want = SpectrumSpec(6, "cotangent").for_shape(cloud).compute(cloud).eigenvalues
    for extra in ([], ["--weighting", "intrinsic-delaunay"]):
        code, out, err = run_cli(capsys, "spectrum", tmp_path / "c.xyz", "-k", "6", "--json", *extra)
        assert code == 0, err
        got = json.loads(out)
        assert got["weighting"] == "intrinsic-delaunay"
        np.testing.assert_allclose(got["eigenvalues"], want, rtol=1e-8, atol=1e-10)
    code, out, err = run_cli(capsys, "spectrum", tmp_path / "c.xyz", "--param", "clamp_negative=true")
    _refused(code, out, err, "--weighting intrinsic-delaunay")
