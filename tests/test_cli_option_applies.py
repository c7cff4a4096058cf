"""An option given without the option (or the output) it applies to would be silently ignored: every command refuses
it through the one helper :func:`~shape_toolkit.cli.commands._common.check_applies`, before any work, in one line
on stderr with exit 2, naming the option and what it applies to."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import run_cli

from shape_toolkit.cli.commands._common import check_applies
from shape_toolkit.data.generate import icosphere
from shape_toolkit.errors import ParameterError
from shape_toolkit.io.mesh import save_shape


@pytest.fixture(autouse=True)
def _in_process(monkeypatch):
    monkeypatch.setenv("SHAPE_TOOLKIT_IN_PROCESS", "1")


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """An icosphere ``s.ply`` (162 vertices), the identity map ``map.txt`` and 20 truth ids ``truth.txt``."""
    d = tmp_path_factory.mktemp("applies")
    s = icosphere(2)
    save_shape(s, d / "s.ply")
    np.savetxt(d / "map.txt", np.arange(s.n_vertices), fmt="%d")
    np.savetxt(d / "truth.txt", np.arange(20), fmt="%d")
    return d


def test_check_applies_refuses_only_an_option_given_without_what_it_applies_to():
    with pytest.raises(ParameterError) as info:
        check_applies("--tail", 2, "the drawings", None, "; give --png FIG.png")
    assert str(info.value) == "--tail applies to the drawings; give --png FIG.png"
    with pytest.raises(ParameterError, match=r"^--faces applies to --labels$"):
        check_applies("--faces", True, "--labels", [])
    check_applies("--tail", None, "the drawings", None)  # not given: nothing to refuse
    check_applies("--tail", 0, "the drawings", None)  # a falsy value (the default) is not given
    check_applies("--tail", 2, "the drawings", "fig.png")  # given with what it applies to


S, MAP, TRUTH, OUT = "S", "MAP", "TRUTH", "OUT"
EVAL = ["evaluate-map", S, S, MAP]
IGNORED = ", not given here: it would be ignored"

CASES = [  # the command line (placeholders above), the whole message
    (["clean", S, "--remesh-iterations", "5", "-o", OUT + ".ply"],
     "--remesh-iterations applies to remeshing; give --remesh EDGE_LEN too"),
    (["clean", S, "--binary", "-o", OUT + ".off"], "--binary applies to PLY and STL output; "),
    (["demo", "--workers", "2", "--no-bench", "-q", "-o", OUT],
     "--workers applies to the benchmark showcase, which --no-bench skips"),
    (["track", S, S, "--workers", "3", "-o", OUT + ".npz"],
     "--workers applies to --dask local (a local cluster of that many workers)"),
    (["track", S, S, "--dask", "tcp://127.0.0.1:1", "--workers", "3", "-o", OUT + ".npz"],
     "--workers applies to --dask local (a local cluster of that many workers)"),
    (["track", S, S, "--tracks", "5", "-o", OUT + ".npz"],
     "--tracks applies to the drawings; give --png FIG.png or --gif ANIM.gif"),
    (["track", S, S, "--tail", "2", "-o", OUT + ".npz"],
     "--tail applies to the drawings; give --png FIG.png or --gif ANIM.gif"),
    (["view", S, "--column", "2", "--png", OUT + ".png"],
     "--column applies to a 2D --scalar array; give --scalar FILE"),
    (["view", S, "--faces", "--png", OUT + ".png"], "--faces applies to --labels"),
    (["view", S, "--json"], "--json applies to --png (the window prints nothing)"),
    ([*EVAL, "--truth-dst-sym", TRUTH], "--truth-dst-sym applies to --truth-src and --truth-dst" + IGNORED),
    ([*EVAL, "--r-smoothness", "--faces"], "--faces applies to --labels files; give --labels SRC_LABELS TGT_LABELS"),
    ([*EVAL, "--r-smoothness", "--zero-based"], "--zero-based applies to --truth-src and --truth-dst" + IGNORED),
    ([*EVAL, "--r-smoothness", "--geodesics", "exact"], "--geodesics applies to --truth-src and --truth-dst" + IGNORED),
    ([*EVAL, "--truth-src", TRUTH, "--truth-dst", TRUTH, "--zero-based", "--r-theta", "0.5"],
     "--r-theta applies to --r-smoothness" + IGNORED),
    ([*EVAL, "--truth-src", TRUTH, "--truth-dst", TRUTH, "--zero-based", "--r-sample", "5"],
     "--r-sample applies to --r-smoothness" + IGNORED),
    ([*EVAL, "--r-smoothness", "--random-state", "3"], "--random-state applies to --r-sample" + IGNORED),
    (["bench", "run", "CONFIG", "--markdown", OUT + ".md", "-o", OUT],
     "--markdown applies to the report, whose tables it writes; give --report too"),
]


@pytest.mark.parametrize("argv, message", CASES, ids=[f"{c[0][0]} {c[1].split()[0]}" for c in CASES])
def test_an_option_without_what_it_applies_to_is_refused_in_one_line(files, capsys, tmp_path, argv, message):
    (tmp_path / "CONFIG").write_text("")  # never read: the refusal comes first
    where = {S: files / "s.ply", MAP: files / "map.txt", TRUTH: files / "truth.txt", "CONFIG": tmp_path / "CONFIG"}
    args = [where.get(a, str(tmp_path / a) if a.startswith(OUT) else a) for a in argv]
    code, out, err = run_cli(capsys, *args)
    assert code == 2, (code, err)
    assert not out, out
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err and "internal error" not in err, err
    assert lines[0].startswith(f"shape-toolkit {argv[0]}: error: {message}"), err
    assert not any(p.name.startswith(OUT) for p in tmp_path.iterdir()), "work was done before the refusal"
