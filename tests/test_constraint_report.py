"""Constraints kept or reported (issue 30, item 4): a constrained segmenter either keeps every
must-link and cannot-link, or says how many it could not keep and why, in ``info["constraints"]``,
in the CLI's JSON and as one warning line on stderr."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from shape_toolkit.api.registry import create_plugin
from shape_toolkit.cli import main
from shape_toolkit.data.synthetic import articulated_shape
from shape_toolkit.io.mesh import save_shape
from shape_toolkit.plugins.segmenters.constraints import ConstraintWarning
from shape_toolkit.results.labels import (
    Constraints,
    clicks_from_segmentation,
    constraint_report,
    save_constraints,
)


def test_constraint_report_counts():
    labels = np.array([0, 0, 1, 1, 2, 2])
    c = Constraints([[0, 1], [2, 4]], [[0, 2], [1, 4], [2, 3]])
    rep = constraint_report(labels, c)
    assert rep["must_link_broken"] == 1  # 2 and 4 apart
    assert rep["cannot_link_broken"] == 1  # 2 and 3 together
    assert rep["clicked_parts"] == 2  # {0, 1} and {2, 4}; 3 is a cannot-link end, not a part
    assert rep["n_segments"] == 3 and "does not enforce" in rep["reason"]
    kept = constraint_report(np.array([0, 0, 1, 2, 1, 3]), c)
    assert kept["must_link_broken"] == kept["cannot_link_broken"] == 0 and kept["reason"] is None


@pytest.fixture(scope="module")
def limbs():
    gen = articulated_shape(subdivisions=3, random_state=0)  # a body and five limbs: 6 parts
    return gen.shape, clicks_from_segmentation(gen.shape, gen.labels, random_state=0)


@pytest.mark.parametrize("method", ["csc", "ccskl", "spectral-learning"])
def test_too_few_segments_for_the_clicked_parts_is_reported(limbs, method):
    shape, clicks = limbs
    seg = create_plugin("segmenters", method, n_segments=3)
    with pytest.warns(ConstraintWarning, match=r"3 segments for 6 clicked parts") as got:
        res = seg.segment(shape, constraints=clicks)
        labels = res.labels
    assert len(got) == 1
    rep = res.info["constraints"]
    assert rep == constraint_report(labels, clicks)  # the counts are those of the labels returned
    assert rep["cannot_link_broken"] > 0 and rep["clicked_parts"] == 6


def test_kept_constraints_are_said_kept_without_a_warning():
    gen = articulated_shape(subdivisions=3, random_state=0)
    shape, lab = gen.shape, gen.labels
    centre = shape.vertices[lab == 0].mean(axis=0)

    def tip(limb: int, rank: int) -> int:  # the rank-th farthest vertex of a limb from the body
        ids = np.flatnonzero(lab == limb)
        return int(ids[np.argsort(-np.linalg.norm(shape.vertices[ids] - centre, axis=1))[rank]])

    clicks = Constraints([[tip(1, 0), tip(1, 5)], [tip(2, 0), tip(2, 5)]], [[tip(1, 0), tip(2, 0)]])
    for method in ("seeded-walk", "spectral-learning"):
        seg = create_plugin("segmenters", method, **({} if method == "seeded-walk" else {"n_segments": 2}))
        with warnings.catch_warnings():
            warnings.simplefilter("error", ConstraintWarning)
            res = seg.segment(shape, constraints=clicks)
            labels = res.labels
        rep = res.info["constraints"]
        assert rep["reason"] is None and rep == constraint_report(labels, clicks)
        assert rep["must_link_broken"] == rep["cannot_link_broken"] == 0


def test_cli_segment_reports_broken_clicks(limbs, tmp_path, capsys):
    shape, clicks = limbs
    mesh, cons = tmp_path / "limbs.ply", tmp_path / "clicks.json"
    save_shape(shape, mesh)
    save_constraints(cons, clicks)
    capsys.readouterr()
    code = main(["segment", str(mesh), "--method", "csc", "-k", "3", "--constraints", str(cons), "--json",
                 "-o", str(tmp_path / "l.txt")])
    out, err = capsys.readouterr()
    assert code == 0
    rep = json.loads(out)["info"]["constraints"]
    assert rep["clicked_parts"] == 6 and rep["cannot_link_broken"] > 0
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "warning:" in lines[0] and "clicked parts" in lines[0]
