"""CLI of the foundation: spectrum, plugins, demo, and one-line errors with non-zero exits."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import panel_empty_fractions

from shape_toolkit.cli import main
from shape_toolkit.core.shape import Shape
from shape_toolkit.data.generate import icosphere
from shape_toolkit.io.mesh import save_shape


def run_cli(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "shape_toolkit", *args], capture_output=True, text=True, timeout=300, cwd=cwd
    )


@pytest.fixture(scope="module")
def sphere_file(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("cli") / "sphere.off"
    save_shape(icosphere(3), p)
    return p


def test_spectrum_json_and_npz(sphere_file, tmp_path, capsys):
    out = tmp_path / "spec.npz"
    args = ["spectrum", str(sphere_file), "-k", "9", "--weighting", "cotangent", "--json", "-o", str(out)]
    code = main(args)
    assert code == 0
    res = json.loads(capsys.readouterr().out)
    assert res["n_vertices"] == 642 and res["weighting"] == "cotangent"
    assert res["laplacian"] == "combinatorial" and res["generalized"] is True
    lam = np.array(res["eigenvalues"])
    assert np.all(np.diff(lam) >= 0)
    np.testing.assert_allclose(lam[1:], [2] * 3 + [6] * 5, rtol=0.05)
    with np.load(out) as z:
        assert z["eigenvectors"].shape == (642, 9)


@pytest.mark.parametrize("laplacian", ["normalized", "random-walk"])
def test_spectrum_other_laplacians(sphere_file, capsys, laplacian):
    assert main(["spectrum", str(sphere_file), "-k", "4", "--weighting", "gaussian",
                 "--laplacian", laplacian, "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["laplacian"] == laplacian and 0 <= res["eigenvalues"][-1] <= 2


def test_plugins_list_json(capsys):
    assert main(["plugins", "list", "--json"]) == 0
    fams = json.loads(capsys.readouterr().out)
    assert set(fams) == {"weightings", "keypoints", "descriptors", "sparse_matchers",
                         "dense_matchers", "segmenters", "pipelines"}
    assert "zoomout" in fams["pipelines"]
    assert "cotangent" in fams["weightings"]


def _bad_files(d: Path) -> dict[str, tuple[Path, str]]:
    s = icosphere(1)
    files = {}
    files["missing"] = (d / "nope.off", "no such file")
    files["directory"] = (d, "directory")
    (d / "shape.xyzw").write_text("1 2 3\n")
    files["unknown format"] = (d / "shape.xyzw", "format")
    (d / "trunc.off").write_text("OFF\n10 2 0\n0 0 0\n1 0 0\n")
    files["truncated"] = (d / "trunc.off", "")
    (d / "text.off").write_text("OFF\n3 1 0\n0 0 0\n1 zero 0\n0 1 0\n3 0 1 2\n")
    files["malformed"] = (d / "text.off", "")
    (d / "empty.off").write_text("")
    files["empty"] = (d / "empty.off", "empty")
    (d / "nan.off").write_text("OFF\n3 1 0\n0 0 0\nnan 0 0\n0 1 0\n3 0 1 2\n")
    files["nan"] = (d / "nan.off", "NaN")
    (d / "range.off").write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n")
    files["index out of range"] = (d / "range.off", "range")
    (d / "line.off").write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n2 0 1\n")
    files["not a triangle"] = (d / "line.off", "")
    save_shape(Shape(s.vertices, s.faces), d / "ok.off")
    return files


def _slow_but(fast: tuple[str, ...], cases: tuple[str, ...]) -> list:
    """The cases as parameters, all but ``fast`` marked slow: each is a Python process of its own (a second
    or two), and tests/test_adversarial.py makes the same rejections in process."""
    return [c if c in fast else pytest.param(c, marks=pytest.mark.slow) for c in cases]


BAD_FILES = ("missing", "directory", "unknown format", "truncated", "malformed", "empty", "nan",
             "index out of range", "not a triangle")


@pytest.mark.parametrize("case", _slow_but(("malformed",), BAD_FILES))
def test_every_bad_input_is_one_line_and_nonzero(tmp_path, case):
    files = _bad_files(tmp_path)
    assert set(files) == set(BAD_FILES)
    path, needle = files[case]
    r = run_cli("spectrum", str(path), "-k", "3")
    assert r.returncode == 2, (case, r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, (case, r.stderr)
    assert str(path.name) in lines[0], (case, lines[0])
    assert needle.lower() in lines[0].lower(), (case, lines[0])


def _parameter_errors(sphere_file: Path, tmp_path: Path) -> dict[str, tuple[list[str], str]]:
    return {
        "k": (["spectrum", str(sphere_file), "-k", "0"], "k must be"),
        "plugin": (["spectrum", str(sphere_file), "--weighting", "nope"], "available: binary"),
        "parameter": (["spectrum", str(sphere_file), "--param", "sigma=1", "--weighting", "gaussian"], "no parameter"),
        "key=value": (["spectrum", str(sphere_file), "--param", "oops"], "KEY=VALUE"),
        "suffix": (["spectrum", str(sphere_file), "-o", str(tmp_path / "x.txt")], ".npz"),
        "choice": (["spectrum", str(sphere_file), "--laplacian", "bogus"], "invalid choice"),
        "command": (["nonexistent-command"], "invalid choice"),
    }


PARAMETER_ERRORS = ("k", "plugin", "parameter", "key=value", "suffix", "choice", "command")


@pytest.mark.parametrize("case", _slow_but(("k", "plugin"), PARAMETER_ERRORS))
def test_parameter_and_plugin_errors_are_one_line(sphere_file, tmp_path, case):
    cases = _parameter_errors(sphere_file, tmp_path)
    assert set(cases) == set(PARAMETER_ERRORS)
    args, needle = cases[case]
    r = run_cli(*args)
    assert r.returncode == 2, (args, r.stderr)
    assert len(r.stderr.strip().splitlines()) == 1 and needle in r.stderr, (args, r.stderr)


def test_disconnected_mesh_is_refused_then_analysed(tmp_path):
    a, b = icosphere(2), icosphere(2)
    two = Shape(np.vstack([a.vertices, b.vertices + 4]), np.vstack([a.faces, b.faces + a.n_vertices]))
    p = tmp_path / "two.ply"
    save_shape(two, p)
    r = run_cli("spectrum", str(p), "-k", "4")
    assert r.returncode == 2 and "2 connected components" in r.stderr
    r = run_cli("spectrum", str(p), "-k", "4", "--largest-component", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["eigenvalues"][0] == pytest.approx(0, abs=1e-8)


def test_python_m_toolkit_and_help():
    r = run_cli("--help")
    assert r.returncode == 0 and "spectrum" in r.stdout and "plugins" in r.stdout


def _demo(out: Path, *flags: str) -> dict:
    """Run ``demo -o out`` with ``flags``; check its figures and summary; return the summary."""
    r = run_cli("demo", "-o", str(out), *flags)
    assert r.returncode == 0, r.stderr
    assert str(out) in r.stdout
    for name in ("eigenvectors.png", "spectrum.png", "match.png"):
        assert (out / name).stat().st_size > 10_000
        assert (out / name).with_suffix(".pdf").read_bytes()[:5] == b"%PDF-"  # every figure also as PDF
    for name in ("eigenvectors.png", "match.png"):  # shapes upright and cropped tight, as in the reports
        assert max(panel_empty_fractions(out / name)) <= 0.15, (name, panel_empty_fractions(out / name))
    assert summary_ok(out)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["eigenvalues"][0] == pytest.approx(0, abs=1e-8)
    return summary


@pytest.mark.slow  # the README's first command end to end: its showcase benchmark and report take ~25 s
def test_demo_writes_results(tmp_path):
    summary = _demo(tmp_path / "demo")
    assert summary["benchmark"]["failed"] == 0 and Path(summary["benchmark"]["report"]).is_file()


def test_demo_without_its_benchmark_writes_the_figures_and_the_match(tmp_path):
    """The demo's own part (spectrum, figures, the zoomout match); the whole demo is the slow test above,
    its showcase benchmark the config checked below, run by the bench runner and report tests."""
    out = tmp_path / "demo"
    summary = _demo(out, "--no-bench")
    assert "benchmark" not in summary and not (out / "bench").exists()


def test_demo_showcase_config_is_valid_and_plans_every_task(tmp_path):
    from shape_toolkit.bench.config import parse_config
    from shape_toolkit.cli.commands.demo import showcase_config

    cfg = parse_config(showcase_config(3), base=tmp_path)
    assert [t.task_kind for t in cfg.tasks] == ["spectrum", "keypoints", "segmentation", "matching"]
    assert cfg.planned_rows == 33


def summary_ok(out: Path) -> bool:
    s = json.loads((out / "summary.json").read_text())
    return s["match"]["pipeline"] == "zoomout" and s["match"]["mean_error_euclidean_sqrt_area"] < 0.1


def _inprocess(capsys, *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_output_paths_are_checked_before_any_work(sphere_file, tmp_path, capsys):
    cases = [
        (["spectrum", str(sphere_file), "-o", str(tmp_path / "no" / "x.npz")], "does not exist"),
        (["clean", str(sphere_file), "-o", str(tmp_path / "no" / "x.off")], "does not exist"),
        (["clean", str(sphere_file), "-o", str(tmp_path)], "must end with"),
        (["keypoints", str(sphere_file), "-o", str(tmp_path)], "is a directory"),
        (["segment", str(sphere_file), "--method", "eigvec-gmm", "-o", str(tmp_path)], "is a directory"),
        (["match", str(sphere_file), str(sphere_file), "-o", str(tmp_path)], "is a directory"),
        (["clean", str(sphere_file), "-o", str(sphere_file)], "must differ"),
    ]
    for args, needle in cases:
        code, _, err = _inprocess(capsys, *args)
        assert code == 2 and len(err.strip().splitlines()) == 1 and needle in err, (args, err)


def test_parameters_are_typed(sphere_file, tmp_path, capsys):
    cases = [
        (["keypoints", str(sphere_file), "--param", "t=abc"], "t expects a number"),
        (["keypoints", str(sphere_file), "--param", "t=NaN"], "not a usable value"),
        (["segment", str(sphere_file), "--method", "eigvec-gmm", "--param", "n_init=2.5",
          "-o", str(tmp_path / "s.txt")], "expects an integer"),
        (["segment", str(sphere_file), "--method", "eigvec-gmm", "--random-state", "-1",
          "-o", str(tmp_path / "s.txt")], "random_state must be in"),
        (["clean", str(sphere_file), "-o", str(tmp_path / "c.off"), "--remesh", "nan"], "positive number"),
    ]
    for args, needle in cases:
        code, _, err = _inprocess(capsys, *args)
        assert code == 2 and len(err.strip().splitlines()) == 1 and needle in err, (args, err)


def test_info_json_is_valid_for_huge_coordinates(tmp_path, capsys):
    s = icosphere(2)
    p = tmp_path / "huge.off"
    save_shape(Shape(s.vertices * 1e150, s.faces), p)
    code, out, _ = _inprocess(capsys, "info", str(p), "--json")
    assert code == 0
    info = json.loads(out, parse_constant=lambda c: pytest.fail(f"{c} in JSON"))
    assert info["degenerate_faces"] == 0 and info["total_area"] == pytest.approx(1e300 * s.area)
    assert info["mean_edge_length"] == pytest.approx(1e150 * s.mean_edge_length)


@pytest.mark.parametrize("command", ["info", "clean", "keypoints", "segment", "spectrum"])
@pytest.mark.parametrize("scale", [1e200, 1e300, 1e-300])
def test_coordinates_beyond_float64_squares_are_one_line_rejections(tmp_path, capsys, command, scale):
    """Issue 27: info and clean exited 0 with infinite lengths and areas, keypoints and segment printed an
    overflow warning before their error. Now every command refuses with one line naming the fix."""
    s = icosphere(2)
    p = tmp_path / "far.off"
    p.write_text(f"OFF\n{s.n_vertices} {s.n_faces} 0\n"
                 + "".join(f"{x * scale!r} {y * scale!r} {z * scale!r}\n" for x, y, z in s.vertices.tolist())
                 + "".join(f"3 {a} {b} {c}\n" for a, b, c in s.faces))
    extra = {"clean": ["-o", str(tmp_path / "c.off")], "segment": ["--method", "eigvec-gmm", "-o",
                                                                      str(tmp_path / "s.txt")]}.get(command, [])
    code, out, err = _inprocess(capsys, command, str(p), *extra, "--json")
    assert code == 2 and out == "", out
    assert len(err.strip().splitlines()) == 1 and "rescale the shape" in err, err


@pytest.mark.parametrize("scale", [1e-150, 1e150])
def test_evaluate_map_identity_at_any_scale(tmp_path, capsys, scale):
    s = icosphere(2)
    p = tmp_path / "s.off"
    save_shape(Shape(s.vertices * scale, s.faces), p)
    (tmp_path / "id.map").write_text("".join(f"{i}\n" for i in range(s.n_vertices)))
    (tmp_path / "t.vts").write_text("".join(f"{i}\n" for i in range(1, s.n_vertices + 1, 7)))
    code, out, err = _inprocess(capsys, "evaluate-map", str(p), str(p), str(tmp_path / "id.map"),
                                "--truth-src", str(tmp_path / "t.vts"), "--truth-dst", str(tmp_path / "t.vts"),
                                "--json")
    assert code == 0, err
    assert json.loads(out)["mean_geodesic_error"] == pytest.approx(0.0, abs=1e-9)


def test_duplicate_faces_are_refused_naming_clean(tmp_path, capsys):
    s = icosphere(2)
    p = tmp_path / "dup.off"
    save_shape(Shape(s.vertices, np.vstack([s.faces, s.faces[:10]])), p)
    code, _, err = _inprocess(capsys, "spectrum", str(p), "-k", "4")
    assert code == 2 and "duplicate faces" in err and "shape-toolkit clean" in err
    code, out, _ = _inprocess(capsys, "info", str(p), "--json")
    assert code == 0 and json.loads(out)["duplicate_faces"] == 10
    fixed = tmp_path / "fixed.off"
    assert _inprocess(capsys, "clean", str(p), "-o", str(fixed))[0] == 0
    code, out, _ = _inprocess(capsys, "spectrum", str(fixed), "-k", "4", "--json")
    assert code == 0 and json.loads(out)["eigenvalues"][1] == pytest.approx(2.0, rel=0.1)
