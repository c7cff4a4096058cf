"""benchmarks/bench_scale.py: the ``--stages`` parsing (``preset:NAME`` whole-pipeline stages), the
presets report's ratios and growth exponents on fake rows, and the committed ``scale.md`` still
regenerating from its JSON. No data, no timing assertions."""

from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path

import pytest

from shape_toolkit.errors import ParameterError
from shape_toolkit.pipeline import PRESETS

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_scale", REPO / "benchmarks" / "bench_scale.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_stages_parse(bench):
    assert bench.parse_stages("spectrum,preset:topo-robust, preset:zoomout") == [
        "spectrum", "preset:topo-robust", "preset:zoomout"]
    assert bench.parse_stages("em,seed,em-core,em-thesis") == ["em", "seed", "em-core", "em-thesis"]
    assert bench.preset_name("preset:sharma2012") == "sharma2012"
    assert bench.preset_name("em") is None
    for name in PRESETS:  # every preset is a valid stage
        assert bench.parse_stages(f"preset:{name}") == [f"preset:{name}"]


@pytest.mark.parametrize("text, message", [
    ("spectrum,preset:no-such-preset", "unknown pipeline preset 'no-such-preset'"),
    ("preset:", "unknown pipeline preset ''"),
    ("preset:Zoomout", "unknown pipeline preset 'Zoomout'"),
    ("spectrum,emm", "unknown stage 'emm'"),
    ("topo-robust", "unknown stage 'topo-robust'"),  # a preset needs its prefix
    ("", "no stage"),
    ("preset:zoomout,preset:zoomout", "repeated"),
])
def test_stages_rejected(bench, text, message):
    with pytest.raises(ParameterError, match=message):
        bench.parse_stages(text)


def test_unknown_preset_is_one_line_and_exit_2(bench, capsys, tmp_path):
    assert bench.main(["--stages", "preset:nope", "--output", str(tmp_path / "x.md")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "unknown pipeline preset 'nope'" in err and "topo-robust" in err
    assert not (tmp_path / "x.md").exists()


def _row(preset, split, n, cpu, peak, err, polish=None):
    r = {"stage": f"preset:{preset}", "pair": "cat0-cat1", "n_source": n, "n_target": n, "split": split,
         "blas_threads": 2, "seconds": 2 * cpu, "cpu_seconds": cpu, "peak_mb": peak, "before_mb": 10.0,
         "mean_error": err, "timings": {"spectra": cpu / 4}, "em": {}, "kind": "scale", "impl": "current",
         "code": {"commit": "abc123def456", "dirty": False}}
    if polish is not None:
        r["em"]["polish"] = {"wall": polish, "cpu": polish, "calls": 1}
    return r


def test_presets_report_ratios_and_exponents(bench, tmp_path):
    """CPU t = c n^1.5 for the thesis preset and t = c' n for the peer: exponents 1.50 and 1.00, the
    ratio to the peer 3.00x at n = 1000 and 12.00x at 16000 (3 * 16^0.5)."""
    rows = []
    for split, n in ((1, 1000), (4, 16000)):
        rows.append(_row("zoomout", split, n, 1e-2 * n, 100.0, 0.04))
        rows.append(_row("topo-robust", split, n, 3e-2 * n ** 1.5 / 1000 ** 0.5, 200.0, 0.03, polish=1e-3 * n ** 2))
    rows.append({"stage": "preset:sharma2012", "pair": "cat0-cat1", "split": 4, "error": "stopped after 900 s",
                 "kind": "scale", "impl": "current"})
    res = {"command": "python benchmarks/bench_scale.py --stages preset:zoomout,preset:topo-robust",
           "date": "today", "machine": "test", "cpu": "test CPU", "load": [0.5, 1.5], "rows": rows, "notes": ""}
    out = tmp_path / "scale_presets.md"
    bench.write_report(res, out)
    text = out.read_text()
    assert json.loads(out.with_suffix(".json").read_text())["rows"] == rows
    assert "| 1 | 1,000 | topo-robust | 3.00x | 3.00x | 2.00x | 0.0300 | 0.0400 |" in text
    assert "| 4 | 16,000 | topo-robust | 12.00x | 12.00x |" in text
    assert "| topo-robust | 1,000 -> 16,000 | 1.50 | 1.50 | 2.00 | 1.50 |" in text
    assert "| zoomout | 1,000 -> 16,000 | 1.00 | 1.00 |  | 1.00 |" in text
    assert "preset:sharma2012 s=4: stopped after 900 s" in text  # a miss is stated
    assert "nan" not in text.lower()


def test_committed_scale_report_regenerates(bench, tmp_path):
    """The single-stage report is unchanged by the preset stages: --report-only on a copy of the
    committed scale.json gives the committed scale.md."""
    results = REPO / "benchmarks" / "results"
    shutil.copy(results / "scale.json", tmp_path / "scale.json")
    assert bench.main(["--report-only", "--output", str(tmp_path / "scale.md")]) == 0
    assert (tmp_path / "scale.md").read_text() == (results / "scale.md").read_text()
