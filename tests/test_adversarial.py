"""A fast subset of the adversarial corpus (benchmarks/adversarial_corpus.py) through the CLI,
in-process: every run is a clean one-line rejection (exit 2) or a success with valid JSON."""

from __future__ import annotations

import importlib.util
import io
import sys
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import pytest

from shape_toolkit.cli import main

ROOT = Path(__file__).resolve().parents[1]


def _corpus_module():
    spec = importlib.util.spec_from_file_location("adversarial_corpus", ROOT / "benchmarks" / "adversarial_corpus.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["adversarial_corpus"] = mod
    spec.loader.exec_module(mod)
    return mod


corpus = _corpus_module()

#: cheap subcommands only: the loaders and validation are shared by all of them
FAST = ("info", "clean", "evaluate-segmentation")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("adversarial")
    out = corpus.build(folder, commands=FAST)
    # side files: everything except the runs that compute a match or a segmentation
    keep = [r for r in out if r.argv[0] in FAST or r.argv[0] == "evaluate-map" and "dijkstra" in r.argv
            and "coords" not in r.case]
    keep += [r for r in out if r.case.startswith("args:") and r.argv[0] in ("spectrum", "keypoints", "segment")
             and any(w in r.case for w in ("output", "param", "random state", "k zero", "n segments", "unknown"))]
    return folder, keep


def _run_inprocess(run, cwd: Path):
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        try:
            code = main(run.argv)
        except SystemExit as exc:  # argparse --help and usage errors
            code = exc.code if isinstance(exc.code, int) else 2
    run.code, run.stdout, run.stderr = code, out.getvalue(), err.getvalue()
    return corpus.classify(run)


def test_fast_adversarial_subset_has_no_failure(runs, monkeypatch):
    folder, selected = runs
    monkeypatch.chdir(folder / "out")
    assert len(selected) > 150
    done = [_run_inprocess(r, folder / "out") for r in selected]
    failures = [f"{r.case}: {r.why} | {r.stderr.strip()[-300:]}" for r in done if r.verdict == "failure"]
    assert not failures, "\n".join(failures)
    verdicts = {r.case: r.verdict for r in done}
    # controls succeed, the issue-11 cases are refused or handled
    assert verdicts["good.off | info"] == "success"
    assert verdicts["coords_1e300.off | info"] == "rejected"  # squared lengths overflow: refused (issue 27)
    assert verdicts["coords_1e300.off | clean"] == "rejected"
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
    assert corpus.classify(R("a", [], code=0, stdout='{"a": null}')).verdict == "success"
    assert corpus.classify(R("a", [], code=1, stderr="internal error")).verdict == "failure"
    assert corpus.classify(R("a", [], code=None)).verdict == "failure"
