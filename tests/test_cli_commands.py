"""The one consistent CLI (issue 12): --ply exports read back in Open3D, the -o default rule,
--faces wherever labels are read, hints, new commands (describe, geodesics, plugins show, view,
examples), one-line errors with exit 2."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import articulated_pair_files, run_cli

from shape_toolkit.io.mesh import save_shape
from shape_toolkit.results.labels import vertex_to_face_labels


@pytest.fixture(scope="module")
def pose(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    a, b = articulated_pair_files(d)
    np.savetxt(d / "a.labels.txt", a.labels, fmt="%d")
    np.savetxt(d / "a.seg", vertex_to_face_labels(a.shape.faces, a.labels), fmt="%d")
    np.savetxt(d / "b.seg", vertex_to_face_labels(b.shape.faces, b.labels), fmt="%d")
    return d, a, b


def _ply_colors(path: Path, n: int) -> np.ndarray:
    o3d = pytest.importorskip("open3d")
    m = o3d.io.read_triangle_mesh(str(path))
    assert len(m.vertices) == n and m.has_vertex_colors()
    return np.asarray(m.vertex_colors)


def test_segment_ply_and_default_output(pose, capsys, monkeypatch, tmp_path):
    d, a, _ = pose
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(capsys, "segment", d / "a.off", "--method", "eigvec-gmm", "-k", "6",
                          "--ply", tmp_path / "seg.ply", "--json")
    assert code == 0, err
    res = json.loads(out)
    assert res["labels_file"] == "a.eigvec-gmm.labels.txt" and (tmp_path / "a.eigvec-gmm.labels.txt").exists()
    cols = _ply_colors(tmp_path / "seg.ply", a.shape.n_vertices)
    assert len(np.unique(cols.round(3), axis=0)) == res["n_segments"]


def test_segment_defaults_to_ncut_which_needs_k(pose, capsys, monkeypatch, tmp_path):
    d, a, _ = pose
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(capsys, "segment", d / "a.off", "-k", "5", "--json")
    assert code == 0, err
    res = json.loads(out)
    assert res["method"] == "ncut" and res["n_segments"] == 5 and (tmp_path / "a.ncut.labels.txt").exists()
    code, out, err = run_cli(capsys, "segment", d / "a.off")
    assert code == 2 and err.count("\n") == 1 and "-k N" in err


def test_keypoints_spectrum_ply(pose, capsys, tmp_path):
    d, a, _ = pose
    code, out, err = run_cli(capsys, "keypoints", d / "a.off", "--preset", "sparse", "--ply", tmp_path / "k.ply",
                             "--json")
    assert code == 0, err
    ids = json.loads(out)["keypoints"]
    cols = _ply_colors(tmp_path / "k.ply", a.shape.n_vertices)
    assert np.allclose(cols[ids], [0.85, 0.1, 0.1], atol=0.01)
    code, out, err = run_cli(capsys, "spectrum", d / "a.off", "-k", "6", "--ply", tmp_path / "e.ply",
                          "--eigenvector", "2", "--json")
    assert code == 0, err
    cols = _ply_colors(tmp_path / "e.ply", a.shape.n_vertices)
    assert cols[:, 0].max() > 0.6 and cols[:, 2].max() > 0.6  # both signs: red and blue
    code = run_cli(capsys, "spectrum", d / "a.off", "-k", "6", "--ply", tmp_path / "e.ply", "--eigenvector", "9")[0]
    assert code == 2


def test_match_ply_pullback_every_source_vertex_coloured(pose, capsys, tmp_path):
    d, a, _ = pose
    code, out, err = run_cli(capsys, "match", d / "a.off", d / "b.off", "--pipeline", "zoomout-fast",
                          "-o", tmp_path / "m.txt", "--ply", tmp_path / "m.ply", "--json", "--quiet")
    assert code == 0, err and not err
    res = json.loads(out)
    cs = _ply_colors(tmp_path / "m.source.ply", a.shape.n_vertices)
    ct = _ply_colors(tmp_path / "m.target.ply", a.shape.n_vertices)
    t = np.loadtxt(tmp_path / "m.txt", dtype=int)
    assert res["n_matched"] == a.shape.n_vertices
    np.testing.assert_allclose(cs, ct[t], atol=1e-6)  # pull-back: source = target colour at its image


def test_match_default_output_name(pose, capsys, monkeypatch, tmp_path):
    d, _, _ = pose
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(capsys, "match", d / "a.off", d / "b.off", "--pipeline", "zoomout-fast", "--no-progress")
    assert code == 0, err
    assert (tmp_path / "a.to-b.map.txt").exists()


def test_transfer_labels_accepts_psb_face_labels(pose, capsys, tmp_path):
    d, a, b = pose
    code, out, err = run_cli(capsys, "transfer-labels", d / "a.off", d / "a.seg", d / "b.off", "--faces",
                          "--truth", d / "b.seg", "-o", tmp_path / "b.out.seg", "--json")
    assert code == 0, err
    res = json.loads(out)
    assert res["per"] == "face" and len(np.loadtxt(tmp_path / "b.out.seg")) == b.shape.n_faces
    assert res["proxy"] is None  # small shapes are labelled directly
    # shapes above 1.5 --proxy vertices through proxies; faces labelled from the lifted vertex labels
    code, out, err = run_cli(capsys, "transfer-labels", d / "a.off", d / "a.seg", d / "b.off", "--faces",
                             "--truth", d / "b.seg", "-o", tmp_path / "b.proxy.seg", "--proxy", "100", "--json")
    assert code == 0, err
    prox = json.loads(out)
    assert prox["proxy"]["test_vertices"] == b.shape.n_vertices and max(prox["proxy"]["proxy_vertices"]) < 150
    assert len(np.loadtxt(tmp_path / "b.proxy.seg")) == b.shape.n_faces and prox["recall"] > 0.5 * res["recall"]
    # without --faces: one line naming the flag
    code, _, err = run_cli(capsys, "transfer-labels", d / "a.off", d / "a.seg", d / "b.off", "-o", tmp_path / "x.txt")
    assert code == 2 and "--faces" in err and len(err.strip().splitlines()) == 1


def test_evaluate_segmentation_suggests_faces(pose, capsys):
    d, _, _ = pose
    code, _, err = run_cli(capsys, "evaluate-segmentation", d / "a.off", d / "a.seg", "--truth", d / "a.seg")
    assert code == 2 and "add --faces" in err and len(err.strip().splitlines()) == 1
    code, out, err = run_cli(capsys, "evaluate-segmentation", d / "a.off", d / "a.seg", "--faces", "--truth",
                             d / "a.seg")
    assert code == 0 and "lower is better" in out


#: every command reading a labels file, as ``argv(folder, labels file, out folder)``
LABEL_READERS = {
    "evaluate-segmentation": lambda d, lab, o: ["evaluate-segmentation", d / "a.off", lab, "--truth", d / "a.seg"],
    "constraints": lambda d, lab, o: ["constraints", d / "a.off", lab, "-o", o / "c.json"],
    "transfer-labels": lambda d, lab, o: ["transfer-labels", d / "a.off", lab, d / "b.off", "-o", o / "t.txt"],
    "view": lambda d, lab, o: ["view", d / "a.off", "--labels", lab, "--png", o / "v.png"],
}


@pytest.mark.parametrize("command", sorted(LABEL_READERS))
def test_a_label_count_of_the_other_kind_names_the_flag_the_same_way_everywhere(pose, capsys, tmp_path, command):
    """One rule checks a labels file's count (cli.commands._common.read_labels_as_given): per-face labels
    without --faces, or per-vertex labels with it, are one line and exit 2 naming the flag, worded alike in
    every command."""
    d, a, _ = pose
    n, f = a.shape.n_vertices, a.shape.n_faces
    argv = LABEL_READERS[command]
    code, out, err = run_cli(capsys, *argv(d, d / "a.seg", tmp_path))
    assert (code, out, len(err.strip().splitlines())) == (2, "", 1), err
    assert f"has {f} labels, expected one per vertex ({n}) (one per face, PSB .seg: add --faces)" in err
    code, out, err = run_cli(capsys, *argv(d, d / "a.labels.txt", tmp_path), "--faces")
    assert (code, out, len(err.strip().splitlines())) == (2, "", 1), err
    assert f"has {n} labels, expected one per face ({f}) (one per vertex: drop --faces)" in err
    assert not any(tmp_path.iterdir())


def test_evaluate_map_prints_symmetric(pose, capsys, tmp_path):
    d, a, _ = pose
    n = a.shape.n_vertices
    np.savetxt(tmp_path / "id.txt", np.arange(n), fmt="%d")
    ids = np.arange(1, n + 1, 7)
    np.savetxt(tmp_path / "t.vts", ids, fmt="%d")
    code, out, err = run_cli(capsys, "evaluate-map", d / "a.off", d / "a.off", tmp_path / "id.txt",
                          "--truth-src", tmp_path / "t.vts", "--truth-dst", tmp_path / "t.vts",
                          "--truth-dst-sym", tmp_path / "t.vts", "--geodesics", "dijkstra")
    assert code == 0, err
    assert "symmetric-aware mean geodesic error 0.0000" in out


def test_describe_and_geodesics(pose, capsys, tmp_path, monkeypatch):
    d, a, _ = pose
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(capsys, "describe", d / "a.off", "--descriptor", "hks", "--json")
    assert code == 0, err
    with np.load(tmp_path / "a.hks.npz") as z:
        assert z["descriptor"].shape[0] == a.shape.n_vertices and np.isfinite(z["descriptor"]).all()
    code, out, err = run_cli(capsys, "geodesics", d / "a.off", "--sources", "0,5", "--method", "dijkstra", "--json")
    assert code == 0, err
    with np.load(tmp_path / "a.geodesics.npz") as z:
        assert z["distances"].shape == (2, a.shape.n_vertices) and z["distances"][0, 0] == 0
    code, _, err = run_cli(capsys, "geodesics", d / "a.off", "--sources", "0,99999")
    assert code == 2 and "out of range" in err


def test_geodesics_time_limit_exits_2_with_one_line(pose, capsys, tmp_path, monkeypatch):
    """geodesics takes evaluate-map's --time-limit: a tiny limit on an exact solve stops it with one
    line naming the option and exit 2, writing nothing; without a limit it reports its progress
    (source counts) to the status line."""
    from shape_toolkit.cli.commands import _common

    d, a, _ = pose
    monkeypatch.chdir(tmp_path)
    args = ["geodesics", d / "a.off", "--sources", "3,7,11", "--method", "exact"]
    code, out, err = run_cli(capsys, *args, "--time-limit", "0.000001")
    assert code == 2 and not out
    assert len(err.strip().splitlines()) == 1
    assert "time limit of 1e-06 s exceeded after 1 of 3 sources" in err and "(--time-limit 1e-06)" in err
    assert not (tmp_path / "a.geodesics.npz").exists()
    code, out, err = run_cli(capsys, *args, "--time-limit", "-3")
    assert code == 2 and "--time-limit" in err and len(err.strip().splitlines()) == 1
    seen = []
    monkeypatch.setattr(_common._Status, "count", lambda self, done, total=None: seen.append((done, total)))
    monkeypatch.setenv(_common.PROGRESS_ENV, "1")
    code, out, err = run_cli(capsys, *args[:-2], "--method", "dijkstra", "--time-limit", "0")  # 0: no limit
    assert code == 0, err
    assert seen == [(3, 3)]
    with np.load(tmp_path / "a.geodesics.npz") as z:
        assert z["distances"].shape == (3, a.shape.n_vertices)


def test_plugins_show(capsys):
    code, out, _ = run_cli(capsys, "plugins", "show", "hks", "--json")
    info = json.loads(out)
    assert code == 0 and info["family"] == "descriptors"
    assert {p["name"] for p in info["parameters"]} >= {"n_times"} and info["spectra"][0]["k"] >= 1
    code, out, _ = run_cli(capsys, "plugins", "show", "adf-maxima")
    assert code == 0 and "preset sparse" in out and "spectrum:" in out
    code, out, _ = run_cli(capsys, "plugins", "show", "zoomout")
    assert code == 0 and "pipelines" in out
    code, _, err = run_cli(capsys, "plugins", "show", "nope")
    assert code == 2 and len(err.strip().splitlines()) == 1


def test_view_missing_extra_and_colours(pose, capsys, monkeypatch, tmp_path):
    d, a, _ = pose
    monkeypatch.setitem(sys.modules, "polyscope", None)  # as if the extra were not installed
    code, _, err = run_cli(capsys, "view", d / "a.off", "--labels", d / "a.labels.txt")
    assert code == 2 and "viz" in err and "pip install" in err and len(err.strip().splitlines()) == 1
    from argparse import Namespace

    from shape_toolkit.cli.commands.view import view_items

    base = dict(shape=str(d / "a.off"), labels=None, map=None, scalar=None, faces=False, column=0, points=None)
    items = view_items(Namespace(**{**base, "labels": str(d / "a.seg"), "faces": True}))
    assert items[0]["colors"].shape == (a.shape.n_vertices, 3)
    n = a.shape.n_vertices
    np.savetxt(tmp_path / "id.txt", np.arange(n), fmt="%d")
    items = view_items(Namespace(**{**base, "map": [str(d / "a.off"), str(tmp_path / "id.txt")]}))
    np.testing.assert_allclose(items[0]["colors"], items[1]["colors"])  # identity map: same colours
    np.save(tmp_path / "s.npy", np.arange(n, dtype=float))
    items = view_items(Namespace(**{**base, "scalar": str(tmp_path / "s.npy")}))
    assert items[0]["colors"].std() > 0
    with pytest.raises(Exception, match="--faces"):
        view_items(Namespace(**{**base, "labels": str(d / "a.seg")}))


def test_examples_copy(capsys, tmp_path):
    code, out, err = run_cli(capsys, "examples", "copy", tmp_path / "ex")
    assert code == 0, err
    assert (tmp_path / "ex" / "README.md").exists() and (tmp_path / "ex" / "label_transfer" / "config.toml").exists()
    assert run_cli(capsys, "examples", "copy", tmp_path / "ex")[0] == 2  # no silent overwrite


def test_quiet_is_the_one_flag(pose, capsys):
    d, _, _ = pose
    from shape_toolkit.cli import build_parser

    help_text = build_parser()._subparsers._group_actions[0].choices["bench"].format_help()
    assert help_text
    for cmd in ("segment", "match", "keypoints", "spectrum", "describe", "geodesics", "transfer-labels"):
        h = build_parser()._subparsers._group_actions[0].choices[cmd].format_help()
        assert "--quiet" in h and "--no-progress" not in h, cmd


def test_terminal_progress_is_silent_without_tty(pose, capsys):
    d, _, _ = pose
    code, _, err = run_cli(capsys, "spectrum", d / "a.off", "-k", "5")
    assert code == 0 and err == ""


# -- evaluate-map: r-smoothness (Table 7.2), label transfer (Table 7.3), time limit ---------------
def _strict_json(text: str):
    def no_constant(name):
        raise AssertionError(f"{name} in JSON output")

    return json.loads(text, parse_constant=no_constant)


@pytest.fixture(scope="module")
def noisy_map(pose, tmp_path_factory):
    d, a, b = pose
    n = a.shape.n_vertices
    rng = np.random.default_rng(0)
    t = np.arange(n)  # the poses share their connectivity: the identity is the truth
    hit = rng.choice(n, n // 5, replace=False)
    t[hit] = rng.integers(0, n, hit.size)
    t[hit[:10]] = -1
    path = tmp_path_factory.mktemp("map") / "noisy.map.txt"
    np.savetxt(path, t, fmt="%d")
    return path, t


def test_evaluate_map_r_smoothness_equals_the_metric(pose, noisy_map, capsys):
    from shape_toolkit.metrics import R_SMOOTH_RS, r_smoothness_table

    d, a, b = pose
    path, t = noisy_map
    code, out, err = run_cli(capsys, "evaluate-map", d / "a.off", d / "b.off", path, "--r-smoothness", "--json")
    assert code == 0, err
    res = _strict_json(out)
    direct = r_smoothness_table(a.shape, b.shape, t, R_SMOOTH_RS, 0.9, sample=None)
    assert res["r_smoothness"]["table"] == [[r, v] for r, v in direct.items()]
    assert res["r_smoothness"]["n_evaluated"] == a.shape.n_vertices and "mean_geodesic_error" not in res
    code, out, err = run_cli(capsys, "evaluate-map", d / "a.off", d / "b.off", path, "--r-smoothness", "2", "5",
                          "--r-theta", "0.8", "--r-sample", "100", "--random-state", "4")
    assert code == 0, err
    direct = r_smoothness_table(a.shape, b.shape, t, (2, 5), 0.8, sample=100, random_state=4)
    assert f"r=2%: {direct[2.0]:.2f}  r=5%: {direct[5.0]:.2f}" in out and "100 source vertices" in out


def test_evaluate_map_labels_equal_the_metric(pose, noisy_map, capsys, tmp_path):
    from shape_toolkit.metrics import map_label_scores
    from shape_toolkit.results.labels import face_to_vertex_labels

    d, a, b = pose
    path, t = noisy_map
    np.savetxt(tmp_path / "b.labels.txt", b.labels, fmt="%d")
    ids = np.arange(1, a.shape.n_vertices + 1)
    np.savetxt(tmp_path / "t.vts", ids, fmt="%d")
    code, out, err = run_cli(capsys, "evaluate-map", d / "a.off", d / "b.off", path, "--labels",
                          d / "a.labels.txt", tmp_path / "b.labels.txt", "--truth-src", tmp_path / "t.vts",
                          "--truth-dst", tmp_path / "t.vts", "--geodesics", "dijkstra", "--json")
    assert code == 0, err
    res = _strict_json(out)
    direct = map_label_scores(t, a.labels, b.labels, b.shape)
    assert res["labels"]["recall"] == direct["recall"] and res["labels"]["precision"] == direct["precision"]
    assert res["labels"]["per"] == "vertex" and 0 < res["mean_geodesic_error"] < 1
    code, out, err = run_cli(capsys, "evaluate-map", d / "a.off", d / "b.off", path, "--labels",
                          d / "a.seg", d / "b.seg", "--faces")
    assert code == 0, err
    fa = face_to_vertex_labels(a.shape.faces, np.loadtxt(d / "a.seg", dtype=int), a.shape.n_vertices,
                               a.shape.face_areas)
    fb = face_to_vertex_labels(b.shape.faces, np.loadtxt(d / "b.seg", dtype=int), b.shape.n_vertices,
                               b.shape.face_areas)
    direct = map_label_scores(t, fa, fb, b.shape)
    assert f"mean recall {direct['recall']:.4f}  mean precision {direct['precision']:.4f}" in out
    # per-face files without --faces: one line naming the flag
    code, _, err = run_cli(capsys, "evaluate-map", d / "a.off", d / "b.off", path, "--labels", d / "a.seg", d / "b.seg")
    assert code == 2 and "--faces" in err and len(err.strip().splitlines()) == 1


def test_evaluate_map_json_has_no_nan(pose, capsys, tmp_path):
    d, a, _ = pose
    n = a.shape.n_vertices
    t = np.arange(n)
    t[:5] = -1  # every ground-truth point unmatched: the mean error is undefined
    np.savetxt(tmp_path / "m.txt", t, fmt="%d")
    np.savetxt(tmp_path / "t.vts", np.arange(1, 6), fmt="%d")
    args = ["evaluate-map", d / "a.off", d / "a.off", tmp_path / "m.txt", "--truth-src", tmp_path / "t.vts",
            "--truth-dst", tmp_path / "t.vts", "--geodesics", "dijkstra", "--json"]
    code, out, err = run_cli(capsys, *args)  # no error to report: refused in one line, not a null (issue 27)
    assert code == 2 and "unmatched" in err and len(err.strip().splitlines()) == 1 and not out
    t[:5] = np.arange(5)
    t[2] = -1  # one point unmatched: the mean is over the others, a number
    np.savetxt(tmp_path / "m.txt", t, fmt="%d")
    code, out, err = run_cli(capsys, *args)
    assert code == 0, err
    assert _strict_json(out)["mean_geodesic_error"] == 0.0


@pytest.mark.parametrize("extra, problem", [
    ([], "nothing to evaluate"),
    (["--truth-src", "X.vts"], "--truth-src and --truth-dst go together"),
    (["--r-smoothness", "0"], "must be a percent of the vertices in (0, 100]"),
    (["--r-smoothness", "--r-theta", "1.5"], "must be a fraction in (0, 1]"),
    (["--r-smoothness", "--faces"], "--faces applies to --labels"),
])
def test_evaluate_map_usage_errors_are_one_line(pose, noisy_map, capsys, extra, problem):
    d, _, _ = pose
    code, out, err = run_cli(capsys, "evaluate-map", d / "a.off", d / "b.off", noisy_map[0], *extra)
    assert code == 2 and problem in err and len(err.strip().splitlines()) == 1 and not out


def test_evaluate_map_time_limit_exits_2_with_one_line(pose, capsys, tmp_path):
    d, a, _ = pose
    n = a.shape.n_vertices
    np.savetxt(tmp_path / "id.txt", np.arange(n), fmt="%d")
    np.savetxt(tmp_path / "t.vts", np.arange(1, n + 1, 5), fmt="%d")
    args = ["evaluate-map", d / "a.off", d / "a.off", tmp_path / "id.txt", "--truth-src", tmp_path / "t.vts",
            "--truth-dst", tmp_path / "t.vts", "--geodesics", "exact"]
    code, out, err = run_cli(capsys, *args, "--time-limit", "0.000001")
    assert code == 2 and not out
    assert len(err.strip().splitlines()) == 1
    assert "time limit of 1e-06 s exceeded" in err and "(--time-limit 1e-06)" in err and "heat" in err
    code, out, err = run_cli(capsys, *args, "--time-limit", "-3")
    assert code == 2 and "--time-limit" in err
    # r-smoothness is always Dijkstra: its way out is fewer evaluated vertices, not another method
    code, out, err = run_cli(capsys, *args[:4], "--r-smoothness", "--time-limit", "0.000001")
    assert code == 2 and not out and len(err.strip().splitlines()) == 1
    assert "r-smoothness" in err and "--r-sample N" in err and "heat" not in err


def test_number_args_share_one_parser():
    """Every numeric option is one number_arg: finite, inside its interval with the ends as
    declared, and refused with 'must be <what>' otherwise (NaN, inf and words alike)."""
    import argparse

    from shape_toolkit.cli.commands._common import number_arg, positive_float_arg, time_limit_arg
    from shape_toolkit.cli.commands.evaluate_map import _percent_arg, _theta_arg

    half_open = number_arg("in (0, 1]", 0, 1, open_low=True)
    assert half_open("1") == 1.0 and half_open("1e-300") == 1e-300
    assert _percent_arg("100") == 100.0 and _theta_arg("0.9") == 0.9 and positive_float_arg("2.5") == 2.5
    assert time_limit_arg("0") is None and time_limit_arg("1.5") == 1.5
    for parse, bad in [(half_open, "0"), (half_open, "1.0000001"), (_percent_arg, "0"), (_percent_arg, "100.5"),
                       (_theta_arg, "-0.1"), (positive_float_arg, "0"), (positive_float_arg, "inf"),
                       (positive_float_arg, "nan"), (time_limit_arg, "-1"), (time_limit_arg, "inf"),
                       (time_limit_arg, "ten"), (number_arg("x", open_high=True), "1e999")]:
        with pytest.raises(argparse.ArgumentTypeError, match="must be "):
            parse(bad)
    closed = number_arg("in [0, 1]", 0, 1)
    assert closed("0") == 0.0 and closed("1") == 1.0


def test_constraints_from_a_segmentation_feed_segment(pose, capsys, monkeypatch, tmp_path):
    """``constraints`` draws the PSB protocol's clicks from face labels; ``segment --faces`` then writes
    CSC's own face labels (dual graph) and every click pair ends where the truth puts it."""
    from shape_toolkit.api.registry import create_plugin
    from shape_toolkit.results.labels import clicks_from_segmentation, load_constraints

    d, a, _ = pose
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(capsys, "constraints", d / "a.off", d / "a.seg", "--faces", "--json")
    assert code == 0, err
    res = json.loads(out)
    assert res["constraints_file"] == "a.constraints.json"
    cons = load_constraints(tmp_path / "a.constraints.json", a.shape.n_vertices)
    face_truth = np.loadtxt(d / "a.seg", dtype=np.int64)
    api = clicks_from_segmentation(a.shape, face_truth, faces=True)
    assert np.array_equal(cons.must_link, api.must_link) and np.array_equal(cons.cannot_link, api.cannot_link)
    assert (res["must_link"], res["cannot_link"]) == (cons.n_must, cons.n_cannot) and cons.n_must == 6
    code, out, err = run_cli(capsys, "segment", d / "a.off", "--method", "csc", "-k", "6", "--constraints",
                          "a.constraints.json", "--faces", "-o", "a.csc.seg", "--json")
    assert code == 0, err
    written = np.loadtxt(tmp_path / "a.csc.seg", dtype=np.int64)
    seg = create_plugin("segmenters", "csc", n_segments=6)
    import warnings

    with warnings.catch_warnings(record=True):  # broken clicks are reported as a ConstraintWarning
        warnings.simplefilter("always")
        res = seg.segment(a.shape, constraints=cons)
    assert np.array_equal(written, res.face_labels)  # not the vertex labels converted back
    # errors: one line, exit 2, nothing written
    for bad in (["constraints", d / "a.off", d / "a.seg"],  # per-face labels without --faces
                ["constraints", d / "a.off", d / "a.seg", "--faces", "--min-segment-fraction", "1.5"],
                ["constraints", d / "a.off", d / "a.seg", "--faces", "-o", "c.txt"],
                ["constraints", d / "a.off", d / "a.seg", "--faces", "--cannot-offset", "-1"]):
        code, out, err = run_cli(capsys, *bad)
        assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "c.txt").exists()


def test_segment_a_mesh_of_two_components(pose, capsys, tmp_path):
    """No spectrum of the whole is computed for a mesh of several components (it would mix them):
    the spectral segmenters segment it component by component."""
    from shape_toolkit.core.shape import Shape

    _, a, _ = pose
    n = a.shape.n_vertices
    two = Shape(np.vstack([a.shape.vertices, a.shape.vertices + [5.0, 0, 0]]),
                np.vstack([a.shape.faces, a.shape.faces + n]))
    save_shape(two, tmp_path / "two.off")
    code, out, err = run_cli(capsys, "segment", tmp_path / "two.off", "--method", "spectral-clustering", "-k", "12",
                          "-o", tmp_path / "two.txt", "--json")
    assert code == 0, err
    labels = np.loadtxt(tmp_path / "two.txt", dtype=np.int64)
    assert json.loads(out)["n_segments"] == 12 and not set(labels[:n]) & set(labels[n:])
    # the same as a point cloud: its kNN graph has two components (the command said DisconnectedGraphError)
    save_shape(Shape(two.vertices, None), tmp_path / "two.xyz")
    code, out, err = run_cli(capsys, "segment", tmp_path / "two.xyz", "--method", "eigvec-gmm", "-k", "4",
                          "-o", tmp_path / "cloud.txt", "--json")
    assert code == 0, err
    labels = np.loadtxt(tmp_path / "cloud.txt", dtype=np.int64)
    assert json.loads(out)["n_segments"] == 4 and not set(labels[:n]) & set(labels[n:])


def test_outputs_never_replace_an_input(pose, capsys, tmp_path):
    """keypoints -o onto its mesh, match --ply whose derived files are the inputs (issue 27): refused, inputs kept."""
    import shutil

    d, _, _ = pose
    a = tmp_path / "a.off"
    shutil.copy(d / "a.off", a)
    before = a.read_bytes()
    code, _, err = run_cli(capsys, "keypoints", a, "--detector", "adf-maxima", "-o", a, "--quiet")
    assert code == 2 and "must differ from the input" in err and a.read_bytes() == before
    src, tgt = tmp_path / "m.source.ply", tmp_path / "m.target.ply"
    for name, p in (("a.off", src), ("b.off", tgt)):
        from shape_toolkit.io.mesh import load_shape, save_shape

        save_shape(load_shape(d / name), p)
    kept = src.read_bytes(), tgt.read_bytes()
    code, _, err = run_cli(capsys, "match", src, tgt, "--pipeline", "zoomout-fast", "-o", tmp_path / "m.txt",
                        "--ply", tmp_path / "m.ply", "--quiet")
    assert code == 2 and "must differ from the input" in err and (src.read_bytes(), tgt.read_bytes()) == kept


def test_two_outputs_of_one_command_on_one_path_are_named_as_outputs(pose, capsys, tmp_path):
    """segment -o s.ply --ply s.ply: refused, and the message says the clash is with the other output, not an input
    (found by fuzzing: it called s.ply 'the input file')."""
    d, _, _ = pose
    out = tmp_path / "s.ply"
    code, _, err = run_cli(capsys, "segment", d / "a.off", "-k", "2", "-o", out, "--ply", out, "--quiet")
    assert code == 2 and "must differ from the command's other output" in err and not out.exists()
    code, _, err = run_cli(capsys, "match", d / "a.off", d / "b.off", "-o", tmp_path / "m.target.ply",
                           "--ply", tmp_path / "m.ply", "--quiet")
    assert code == 2 and "must differ from the command's other output" in err


def test_match_names_a_target_whose_faces_are_not_consistently_oriented(pose, capsys, tmp_path):
    """Half the target's faces flipped: the orientation verdict, read from the faces' normals, cannot decide; the
    warning names the shape whose faces disagree and the cleanup that orients them (after which it is gone)."""
    from shape_toolkit.core.cleanup import clean_shape
    from shape_toolkit.core.shape import Shape
    from shape_toolkit.io.mesh import load_shape

    d, _, b = pose
    V, F = np.asarray(b.shape.vertices), np.asarray(b.shape.faces).copy()
    half = V[F].mean(axis=1)[:, 0] > np.median(V[:, 0])
    F[half] = F[half][:, ::-1]
    save_shape(Shape(V, F), tmp_path / "flip.off")
    code, out, err = run_cli(capsys, "match", d / "a.off", tmp_path / "flip.off", "-o", tmp_path / "m.txt")
    assert code == 0, err
    assert "orientation is undecided" in out and "faces of" in out and "flip.off are not consistently" in out
    assert "'shape-toolkit clean' orients them" in out
    save_shape(clean_shape(load_shape(tmp_path / "flip.off"))[0], tmp_path / "fixed.off")
    code, out, err = run_cli(capsys, "match", d / "a.off", tmp_path / "fixed.off", "-o", tmp_path / "m.txt")
    assert code == 0 and "not consistently" not in out


def test_match_notes_a_part_against_a_whole(pose, capsys, tmp_path):
    """One mesh open (a region cut away) and the other closed: `match` notes that the partial pipeline matches a part
    to a whole, naming the files in that order; `--json` gives each boundary's length in sqrt(area). No note for two
    closed meshes, nor under `--pipeline partial`."""
    from shape_toolkit.core.inspect import boundary_length
    from shape_toolkit.data.corruptions import crop

    d, a, _ = pose
    part = crop(a.shape, strength=0.3, attempts=10)[0]
    save_shape(part, tmp_path / "part.off")
    length = boundary_length(part) / np.sqrt(part.area)
    assert length > 0 and boundary_length(a.shape) == 0.0
    fast = ["--pipeline", "zoomout", "-o", tmp_path / "m.txt"]
    code, out, err = run_cli(capsys, "match", d / "b.off", tmp_path / "part.off", *fast)
    assert code == 0, err
    assert f"part.off has an open boundary ({length:.2f} sqrt(area) long)" in out
    assert f"'shape-toolkit match {tmp_path / 'part.off'} {d / 'b.off'} --pipeline partial'" in out
    code, out, err = run_cli(capsys, "match", tmp_path / "part.off", d / "b.off", *fast, "--json")
    assert json.loads(out)["open_boundary"] == {"source": round(length, 4), "target": 0.0}
    code, out, err = run_cli(capsys, "match", d / "a.off", d / "b.off", *fast)
    assert code == 0 and "open boundary" not in out
    code, out, err = run_cli(capsys, "match", tmp_path / "part.off", d / "b.off", "--pipeline", "partial",
                             "-o", tmp_path / "m.txt")
    assert code == 0 and "open boundary" not in out
