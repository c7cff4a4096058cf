"""A fast subset of the adversarial corpus (benchmarks/adversarial_corpus.py) through the CLI,
in-process: every run is a clean one-line rejection (exit 2) or a success with valid JSON and no
unexplained null. The cheap commands run on every file; every command runs on the issue-27 cases
(extreme and degenerate coordinates, tiny meshes, markup in names, constraints and --param tables);
of the five copies of the good mesh named with markup, the default run gives every command to the first
and the cheap ones to the others, a slow test the computing commands on those four, and transfer-labels
both ways on each tiny mesh (tests/test_bad_inputs.py transfers labels between tiny meshes by default)."""

from __future__ import annotations

import io
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import pytest
from helpers import REPO, load_script

from shape_toolkit.cli import main

corpus = load_script("adversarial_corpus", REPO / "benchmarks" / "adversarial_corpus.py")

#: cheap subcommands only: the loaders and validation are shared by all of them
FAST = ("info", "clean", "evaluate-segmentation", "geodesics", "constraints")

#: the meshes of issue 27 (extreme and degenerate coordinates, tiny and odd meshes, names with markup):
#: every command runs on them
ISSUE_27 = ("coords_1e200", "coords_1e250", "coords_1e300", "coords_mixed", "coords_1e-300", "all_identical",
            "repeated_vertices", "collinear_fan", "zero_area", "triangle_1e-300", "repeated_index_faces",
            "two_triangles", "polygon_fan", "polygon_hexagon", "non_manifold_fan", "tetrahedron", "single_triangle",
            "polygons.obj", "bowtie", "<script>", "$\\frac", "\\begin", "new\nline")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("adversarial")
    out = corpus.build(folder)
    mesh_runs = [r for r in out if " | " in r.case and not r.case.startswith(("labels:", "map:", "vts:", "seeds:",
                                                                              "constraints:"))]
    keep = [r for r in mesh_runs if r.argv[0] in FAST or r.case.split(" | ")[0].startswith(ISSUE_27)]
    # side files: everything except the runs that compute a match or a segmentation
    keep += [r for r in out if r.case.startswith(("labels:", "map:", "vts:"))]
    keep += [r for r in out if r.case.startswith("args:") and r.argv[0] not in ("match", "track")
             or r.case.startswith("args:nasty") and "--pipeline" in r.case]
    return folder, keep


#: the tiny and degenerate meshes of issue 27 (not the extreme coordinates, refused before any work)
TINY_27 = ("all_identical", "repeated_vertices", "collinear_fan", "zero_area", "repeated_index_faces",
           "two_triangles", "polygon_fan", "polygon_hexagon", "non_manifold_fan", "tetrahedron", "single_triangle",
           "polygons.obj", "bowtie")


def _slow_part(run) -> bool:
    """The runs of the slow test: a computing command on the 2nd to 5th copy of the good mesh under a name
    with markup (the first name runs every command by default, the others the cheap ones), and
    transfer-labels both ways between the good mesh and each tiny mesh of issue 27 (an eigvec-alignment
    search each, ~0.35 s; tests/test_bad_inputs.py runs the same command on tiny meshes by default)."""
    if " | " not in run.case:
        return False
    mesh = run.case.split(" | ")[0]
    nasty = mesh.endswith(".off") and mesh[: -len(".off")] in corpus.NASTY_NAMES[1:]
    return (nasty and run.argv[0] not in FAST + ("view",)
            or run.argv[0] == "transfer-labels" and mesh.startswith(TINY_27))


def _run_inprocess(run, cwd: Path):
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        try:
            code = main(run.argv)
        except SystemExit as exc:  # argparse --help and usage errors
            code = exc.code if isinstance(exc.code, int) else 2
    run.code, run.stdout, run.stderr = code, out.getvalue(), err.getvalue()
    return corpus.classify(run)


def _no_failure(runs, folder: Path) -> dict[str, str]:
    """Every run in-process from ``folder / "out"``: no failure; the verdict of each case."""
    done = [_run_inprocess(r, folder / "out") for r in runs]
    failures = [f"{r.case}: {r.why} | {r.stderr.strip()[-300:]}" for r in done if r.verdict == "failure"]
    assert not failures, "\n".join(failures)
    return {r.case: r.verdict for r in done}


# about 15 s: transfer-labels, segment, match... on four more copies of the good mesh, and transfer-labels
# between the good mesh and each tiny mesh
@pytest.mark.slow
def test_every_command_on_every_name_with_markup_and_tiny_mesh_has_no_failure(runs, monkeypatch):
    folder, selected = runs
    monkeypatch.chdir(folder / "out")
    slow = [r for r in selected if _slow_part(r)]
    assert len(slow) > 50
    verdicts = _no_failure(slow, folder)
    for name in corpus.NASTY_NAMES[1:]:
        assert verdicts[f"{name}.off | transfer-labels"] == "success", name
    # tiny meshes transfer labels both ways
    for name in ("single_triangle.off", "two_triangles.off", "polygon_fan.off", "non_manifold_fan.off",
                 "tetrahedron.off", "polygons.obj"):
        assert verdicts[f"{name} | transfer-labels"] == "success", name
        assert verdicts[f"{name} | transfer-labels from"] == "success", name


def test_fast_adversarial_subset_has_no_failure(runs, monkeypatch):
    folder, selected = runs
    monkeypatch.chdir(folder / "out")
    selected = [r for r in selected if not _slow_part(r)]
    assert len(selected) > 700
    verdicts = _no_failure(selected, folder)
    first_nasty = f"{corpus.NASTY_NAMES[0]}.off"  # every command runs on it
    assert {case.split(" | ")[1] for case in verdicts if case.startswith(first_nasty + " | ")} >= {
        "info", "clean", "spectrum", "keypoints", "segment", "evaluate-map", "geodesics", "describe", "view",
        "transfer-labels", "transfer-labels from"}
    # controls succeed, the issue-11 cases are refused or handled
    assert verdicts["good.off | info"] == "success"
    # issue 27: squared lengths that overflow or underflow float64 are refused by every command
    for name in ("coords_1e200.off", "coords_1e250.off", "coords_1e300.off", "coords_mixed_1e300.off",
                 "coords_mixed_1e200.off", "coords_mixed_1e250.xyz", "coords_1e-300.off", "triangle_1e-300.off"):
        for cmd in ("info", "clean", "spectrum", "keypoints", "segment", "evaluate-map", "geodesics", "describe",
                    "view"):
            assert verdicts[f"{name} | {cmd}"] == "rejected", (name, cmd)
    # degenerate meshes: evaluate-map refuses (no null error); tiny meshes transferring labels: the slow test
    for name in ("zero_area.off", "all_identical.off", "collinear_fan.off", "repeated_index_faces.off"):
        assert verdicts[f"{name} | evaluate-map"] == "rejected", name
    assert verdicts["repeated_vertices.off | evaluate-map"] == "success"
    for method in ("eigvec-gmm", "spectral-clustering", "ncut", "sdf", "smoothed"):
        assert verdicts[f"args:constraints to {method}"] == "rejected", method
    assert verdicts["args:constraints to smoothed csc"] == "success"
    for case, verdict in verdicts.items():
        if '={"a":1}' in case or "param weighting=" in case or "param variant=" in case:
            assert verdict == "rejected", case
    assert verdicts["args:param times=[1,2] (describe)"] == "success"  # a list of diffusion times is one
    for name in corpus.NASTY_NAMES:  # markup in a file name is just a name
        assert verdicts[f"{name}.off | info"] == "success" and verdicts[f"{name}.off | view"] == "success", name
    for case in ("duplicate_faces.off | evaluate-segmentation", "index_float_binary.ply | info",
                 "pcd_count0.pcd | info", "index_huge.off | info", "list_count_negative.ply | info",
                 "huge_count_binary.ply | info", "empty_faces_binary.ply | info",
                 "args:output missing folder", "args:output onto folder", "args:param not a number",
                 "args:random state negative", "labels:huge | evaluate-segmentation pred",
                 "labels:double_minus | evaluate-segmentation pred", "vts:utf16 | evaluate-map"):
        assert verdicts[case] == "rejected", case


def test_classify():
    R = corpus.Run
    assert corpus.classify(R("a", [], code=2, stderr="x: error: bad\n")).verdict == "rejected"
    assert corpus.classify(R("a", [], code=2, stderr="Traceback\nboom\n")).verdict == "failure"
    assert corpus.classify(R("a", [], code=0, stdout='{"a": NaN}')).verdict == "failure"
    assert corpus.classify(R("a", [], code=0, stdout='{"a": Infinity}')).verdict == "failure"
    # issue 27: the auditor's cases are failures
    assert corpus.classify(R("a", [], code=0, stdout='{"mean_geodesic_error": null}')).verdict == "failure"
    assert corpus.classify(R("a", [], code=0, stdout='{"x": {"curve": [[0.0, null]]}}')).verdict == "failure"
    assert corpus.classify(R("a", [], code=0, stdout='{"ply": null, "output": null}')).verdict == "success"
    assert corpus.classify(R("a", [], code=0, stdout='{"genus": null, "undefined": {"genus": "why"}}')).verdict \
        == "success"
    assert corpus.classify(R("a", [], code=0, stdout='{"genus": null, "undefined": {}}')).verdict == "failure"
    two_warnings = "x: warning: overflow encountered in multiply\nx: warning: again\n"
    assert corpus.classify(R("a", [], code=0, stdout="{}", stderr=two_warnings)).verdict == "failure"
    assert corpus.classify(R("a", [], code=0, stdout="{}", stderr="x: warning: once\n")).verdict == "success"
    assert corpus.classify(R("a", [], code=2, stderr="x: warning: overflow\nx: error: bad\n")).verdict == "failure"
    assert corpus.classify(R("a", [], code=2, stderr="x: error: bad\n", stdout="{}")).verdict == "failure"
    assert corpus.classify(R("a", [], code=2, stderr="x: internal error: boom\n")).verdict == "failure"
    assert corpus.classify(R("a", [], code=1, stderr="internal error")).verdict == "failure"
    assert corpus.classify(R("a", [], code=None)).verdict == "failure"
    # exit 3 out of memory is the machine's doing (another process's memory): retried once, not a verdict on the input
    oom = corpus.classify(R("a", [], code=3, stderr="x: error: out of memory; reduce the memory needed\n"))
    assert oom.verdict == "failure" and corpus.is_transient(oom)
    assert not corpus.is_transient(corpus.classify(R("a", [], code=1, stderr="x: internal error: boom\n")))
