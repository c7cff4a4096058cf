"""Input-handling defects of issue 27 (the bad-input corpus, items 7-8): each is a typed error in the
API and one line with exit 2 from the CLI, or a correct result; never an internal error or a null."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from shape_toolkit.cli import main
from shape_toolkit.core.shape import Shape
from shape_toolkit.data.generate import icosphere
from shape_toolkit.errors import InvalidShapeError
from shape_toolkit.io.mesh import save_shape


def _cli(capsys, *args: str) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def _one_line_rejection(code: int, out: str, err: str, needle: str) -> None:
    assert code == 2, (code, err)
    assert len(err.strip().splitlines()) == 1, err
    assert needle in err, err


def _ints(path: Path, values) -> Path:
    path.write_text("".join(f"{int(v)}\n" for v in values))
    return path


# ------------------------------------------------------------------------------------------------
# evaluate-map on degenerate targets: no null error
# ------------------------------------------------------------------------------------------------
DEGENERATE = {
    "zero_area": ([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]]),
    "identical_vertices": ([[1, 1, 1]] * 3, [[0, 1, 2]]),
    "repeated_index": ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 1, 2]]),
    "collinear_fan": ([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], [[0, 1, 2], [0, 2, 3]]),
}


@pytest.mark.parametrize("name", sorted(DEGENERATE))
def test_geodesic_errors_refuse_a_target_of_zero_area(name):
    from shape_toolkit.metrics.correspondence import error_normalization, geodesic_errors

    v, f = DEGENERATE[name]
    s = Shape(np.asarray(v, dtype=float), np.asarray(f))
    ids = np.arange(s.n_vertices)
    with pytest.raises(InvalidShapeError, match="zero surface area.*undefined"):
        geodesic_errors(s, ids, ids, ids, method="dijkstra")
    with pytest.raises(InvalidShapeError, match="zero surface area"):
        error_normalization(s)
    # unnormalized distances are defined
    assert np.isfinite(geodesic_errors(s, ids, ids, ids, method="dijkstra", normalize=False)).all()


@pytest.mark.parametrize("name", sorted(DEGENERATE))
@pytest.mark.parametrize("sym", [False, True])
def test_evaluate_map_on_a_degenerate_mesh_is_a_one_line_rejection(tmp_path, capsys, name, sym):
    v, f = DEGENERATE[name]
    p = tmp_path / "m.off"
    save_shape(Shape(np.asarray(v, dtype=float), np.asarray(f)), p)
    n = len(v)
    m, t = _ints(tmp_path / "id.map", range(n)), _ints(tmp_path / "t.vts", range(1, n + 1))
    extra = ["--truth-dst-sym", t] if sym else []
    code, out, err = _cli(capsys, "evaluate-map", p, p, m, "--truth-src", t, "--truth-dst", t,
                          "--geodesics", "dijkstra", "--json", *extra)
    _one_line_rejection(code, out, err, "zero surface area")
    assert out == ""


def test_evaluate_map_refuses_when_no_truth_pair_is_matched(tmp_path, capsys):
    s = icosphere(2)
    p = tmp_path / "s.off"
    save_shape(s, p)
    tmap = np.arange(s.n_vertices)
    tmap[:10] = -1  # the truth points only
    m = _ints(tmp_path / "m.map", tmap)
    t = _ints(tmp_path / "t.vts", range(1, 11))
    code, out, err = _cli(capsys, "evaluate-map", p, p, m, "--truth-src", t, "--truth-dst", t,
                          "--geodesics", "dijkstra", "--json")
    _one_line_rejection(code, out, err, "mean geodesic error is undefined")


def test_evaluate_map_on_a_mesh_with_repeated_vertices_gives_numbers(tmp_path, capsys):
    p = tmp_path / "rep.off"
    save_shape(Shape(np.array([[0, 0, 0], [1, 0, 0], [1, 0, 0], [0, 1, 0.0]]), np.array([[0, 1, 3], [1, 2, 3]])), p)
    m, t = _ints(tmp_path / "id.map", range(4)), _ints(tmp_path / "t.vts", range(1, 5))
    code, out, err = _cli(capsys, "evaluate-map", p, p, m, "--truth-src", t, "--truth-dst", t,
                          "--geodesics", "dijkstra", "--json")
    assert code == 0, err
    res = json.loads(out)
    assert res["mean_geodesic_error"] == 0.0 and res["matched_fraction"] == 1.0
