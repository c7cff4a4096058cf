"""Issue 27, the report and config parts: the report writes only the files it owns, shows every
user string literally (escaped in HTML, no mathtext in figures), survives every row the reader
accepts while the reader accepts only what it can show; configs refuse bad strings, bad nested
parameters and grids above the row cap before any work."""

from __future__ import annotations

import json
import re
import shutil
import textwrap
import warnings
from html.parser import HTMLParser
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shape_toolkit.bench import read_rows, write_report
from shape_toolkit.bench.store import BenchWarning, _row_problem
from shape_toolkit.cli import main
from shape_toolkit.errors import ParameterError

CONFIG = """
[run]
name = "hardening"
[[datasets]]
name = "synth"
kind = "synthetic"
limit = 1
params = { n_poses = 2, subdivisions = 2 }
[[corruptions]]
name = "noise"
kind = "gaussian-noise"
params = { strength = [0.01, 0.02] }
[[tasks]]
task = "spectrum"
spectrum = { k = 6 }
metrics = ["eigenvalues", "lambda2"]
[[tasks.methods]]
plugin = "gaussian"
[[tasks]]
task = "segmentation"
name = "seg"
corruptions = ["none", "noise"]
metrics = ["n_segments", "segmentation"]
[[tasks.methods]]
plugin = "spectral-clustering"
preset = "luxburg-unnormalized"
params = { n_segments = 3 }
"""


MANIFEST = ".bench-report.json"  # shape_toolkit.bench.report.MANIFEST


def _write(folder: Path, text: str = CONFIG, name: str = "bench.toml") -> Path:
    p = folder / name
    p.write_text(textwrap.dedent(text))
    return p


@pytest.fixture(scope="module")
def made_run(tmp_path_factory) -> Path:
    """One small run (a spectrum task with curves, a segmentation task under two corruption
    strengths), made once; tests copy it."""
    folder = tmp_path_factory.mktemp("made")
    run = folder / "run"
    assert main(["bench", "run", str(_write(folder)), "-o", str(run), "--no-progress"]) == 0
    return run


@pytest.fixture
def run(made_run, tmp_path) -> Path:
    dst = tmp_path / "run"
    shutil.copytree(made_run, dst)
    return dst


def _rows(run: Path) -> list[dict]:
    return [json.loads(x) for x in (run / "results.jsonl").read_text().splitlines() if x.strip()]


def _put_rows(run: Path, rows: list[dict]) -> None:
    """Replace the run's rows (and its plan: these rows are what the folder's config planned)."""
    (run / "results.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    (run / "planned.json").write_text(json.dumps(sorted({r["key"] for r in rows if isinstance(r, dict)
                                                         and isinstance(r.get("key"), str)})))


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


# -- 1. the report writes only the files it owns ---------------------------------------------
def test_report_never_deletes_or_replaces_a_users_files(run, tmp_path, capsys):
    out = tmp_path / "out"
    first = write_report(run, output=out, renders=0)
    ours = [Path(f).name for f in first["figures"]]
    assert ours
    shutil.rmtree(out)
    (out / "figures").mkdir(parents=True)
    mine = {"holiday.png": b"my holiday", ours[0]: b"my figure with the report's name", "notes.txt": b"notes"}
    for name, data in mine.items():
        (out / "figures" / name).write_bytes(data)
    inputs = _snapshot(run)
    for _ in range(2):  # the second report replaces the first one's figures, and only those
        res = write_report(run, output=out, renders=0)
        for name, data in mine.items():
            assert (out / "figures" / name).read_bytes() == data
        assert all(Path(f).name not in mine for f in res["figures"])
        assert len(res["figures"]) == len(ours)
    on_disk = {p.name for p in (out / "figures").iterdir()}
    ours_now = {Path(f).name for f in res["figures"] + res["vector_figures"]}  # PNG and PDF of each figure
    assert on_disk == set(mine) | ours_now  # the first report's are gone
    assert _snapshot(run) == inputs  # the run's own files are untouched
    # a figure the user changed after the report is no longer the report's: it stays
    changed = Path(res["figures"][-1])
    changed.write_bytes(b"edited by hand")
    write_report(run, output=out, renders=0)
    assert changed.read_bytes() == b"edited by hand"
    # the CLI the same
    assert main(["bench", "report", str(run), "-o", str(out), "--renders", "0", "-q"]) == 0
    assert (out / "figures" / "holiday.png").read_bytes() == b"my holiday"
    capsys.readouterr()


def test_report_refuses_an_index_html_it_did_not_write(run, tmp_path, capsys):
    out = tmp_path / "site"
    out.mkdir()
    (out / "index.html").write_text("<p>my home page</p>")
    with pytest.raises(ParameterError, match="not written by bench report"):
        write_report(run, output=out, renders=0)
    assert main(["bench", "report", str(run), "-o", str(out), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "index.html" in err
    assert (out / "index.html").read_text() == "<p>my home page</p>"
    assert not (out / "figures").exists()  # refused before any work
    # a report folder that is a file
    with pytest.raises(ParameterError, match="not a folder"):
        write_report(run, output=out / "index.html", renders=0)


def test_a_report_of_before_the_manifest_is_replaced_and_its_figures_kept(run):
    """A report folder written by an older version (no manifest): its page is recognised and
    replaced; its figures cannot be told from a user's, so they stay."""
    old = run / "report"
    (old / "figures").mkdir(parents=True)
    (old / "index.html").write_text("<!DOCTYPE html><html><head><meta charset='utf-8'><title>x</title>"
                                    "<style></style></head><body><h1>Benchmark report: x</h1></body></html>")
    (old / "figures" / "00-seg-cost.png").write_bytes(b"old figure")
    res = write_report(run, renders=0)
    assert "Benchmark report: hardening" in res["html"].read_text()
    assert (old / "figures" / "00-seg-cost.png").read_bytes() == b"old figure"


def test_bench_run_report_checks_the_report_folder_before_the_run(tmp_path, capsys):
    run = tmp_path / "run"
    (run / "report").mkdir(parents=True)
    (run / "report" / "index.html").write_text("mine")
    config = _write(tmp_path)
    assert main(["bench", "run", str(config), "-o", str(run), "--report", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not written by bench report" in err
    assert not (run / "results.jsonl").exists()  # nothing run
    assert (run / "report" / "index.html").read_text() == "mine"


def test_planted_manifest_and_links_cannot_make_the_report_touch_other_files(run, tmp_path):
    out = tmp_path / "out"
    res = write_report(run, output=out, renders=0)
    inputs = _snapshot(run)
    # a manifest claiming the run's results and a user's file, with their true digests
    import hashlib

    victim = out / "figures" / "victim.png"
    victim.write_bytes(b"user data")
    files = {"../run/results.jsonl": hashlib.sha256((run / "results.jsonl").read_bytes()).hexdigest(),
             "figures/../../run/config.json": "0" * 64,
             "figures/victim.png": "0" * 64}
    (out / MANIFEST).write_text(json.dumps({"generator": "shape-toolkit bench report", "files": files}))
    # a link where the report's next figure would go, pointing at the run's results
    for f in res["figures"]:
        Path(f).unlink()
        Path(f).symlink_to(run / "results.jsonl")
    write_report(run, output=out, renders=0)
    assert _snapshot(run) == inputs
    assert victim.read_bytes() == b"user data"
    assert all(Path(f).is_symlink() for f in res["figures"])
    # a manifest that is not one is refused, not overwritten
    (out / MANIFEST).write_text("my own notes")
    with pytest.raises(ParameterError, match="not written by bench report"):
        write_report(run, output=out, renders=0)
    assert (out / MANIFEST).read_text() == "my own notes"


def test_a_report_into_the_run_folder_leaves_its_inputs_alone(run):
    inputs = _snapshot(run)
    write_report(run, output=run, renders=1)
    write_report(run, output=run, renders=1)
    after = _snapshot(run)
    assert {k: v for k, v in after.items() if k in inputs} == inputs


# -- 2. user strings escaped in every report field -------------------------------------------
PAYLOADS = ("<script>alert(1)</script>", '"><img src=x onerror=alert(1)>', "'><svg onload=alert(1)>")
_TAGS = {"html", "head", "meta", "title", "style", "body", "h1", "h2", "h3", "p", "code", "ul", "li", "b",
         "span", "table", "tr", "th", "td", "small", "details", "summary", "figure", "img", "figcaption", "a",
         "div", "caption", "wbr"}  # a table's scroll box, the caption of a table cut by columns, header breaks


class _Tags(HTMLParser):
    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.tags: list[tuple[str, list]] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, attrs))


def _assert_no_markup_from_data(text: str) -> None:
    parser = _Tags()
    parser.feed(text)
    for tag, attrs in parser.tags:
        assert tag in _TAGS, f"unexpected tag <{tag}>"
        for name, value in attrs:
            assert name in ("charset", "name", "content", "title", "class", "style", "alt", "src", "href",
                            "data-part", "data-keys"), (tag, name)
            if name in ("data-part", "data-keys"):  # a table cut by columns: part i/n, number of key columns
                assert tag == "table" and re.fullmatch(r"\d+(/\d+)?", value), (name, value)
            if tag == "img" and name == "src":
                assert value.startswith("data:image/png;base64,")
            if name == "href":  # links to the report's own table and figure files only
                assert tag == "a" and re.fullmatch(r"(tables/[\w.-]+\.(csv|tex)|figures/[\w.-]+\.pdf)", value), value
    for p in PAYLOADS:
        assert p not in text


def _plant(rows: list[dict], payload: str) -> list[dict]:
    """``payload`` in every string field of every row, in the keys and values of its tables
    (parameters, corruption parameters, spectra, versions) and in its metric names; one row failed
    with the payload as its error."""
    out = []
    for i, r in enumerate(rows):
        r = dict(r)
        for k in ("run_name", "task_name", "task_kind", "dataset", "item", "plugin", "family", "method_label",
                  "preset", "corruption", "corruption_kind", "corruption_group", "worker"):
            r[k] = f"{k}{payload}"
        r["key"] = f"{r['key']}{payload}"
        r["params"] = {f"p{payload}": payload, "n": 3}
        r["corruption_params"] = {f"c{payload}": payload}
        r["spectra"] = [{f"s{payload}": payload, "k": 6}]
        r["versions"] = {f"v{payload}": payload}
        r["metrics"] = {f"{k}{payload}": v for k, v in r["metrics"].items()}
        if i == 0:
            r.update(status="failed", error=f"error {payload}", metrics={})
        out.append(r)
    return out


def test_strings_from_the_rows_are_escaped_in_every_report_field(run):
    """One report for the three payloads: each in every field of its own copy of the rows, and all three
    together in the first row (what the report takes from one row, its title's run name, sees them all)."""
    rows = _rows(run)
    planted = [r for payload in PAYLOADS for r in _plant(rows, payload)]
    planted[0] = _plant(rows[:1], "".join(PAYLOADS))[0]
    _put_rows(run, planted + [dict(r, key=r["key"] + "x") for r in rows])  # planted and clean rows
    res = write_report(run, renders=1)
    text = res["html"].read_text()
    _assert_no_markup_from_data(text)
    assert "&lt;" in text and len(res["figures"]) >= 3


# -- 3. labels that look like LaTeX are shown literally --------------------------------------
LATEX = (r"$\frac{a$", r"\begin{x}", "$x^2$ and $", r"$\undefinedmacro$", "$$", "_hidden", "a\x00b\x07", "\ud800",
         "emoji \U0001f600")


def test_latex_like_labels_and_names_are_shown_literally(run, capsys):
    rows = _rows(run)
    every = " ".join(LATEX)
    planted = []
    for i, label in enumerate(LATEX):  # each label in the legends, the cost figure and the tables
        planted += [dict(r, key=f"{r['key']}-{i}", method_label=label) for r in rows]
    for r in planted[: len(rows)]:  # and all of them in every other text of one copy
        r.update(task_name=every, dataset=every, corruption=every + r["corruption"],
                 corruption_group=every + r["corruption_group"],
                 metrics={every + k: v for k, v in r["metrics"].items()})
    _put_rows(run, planted)
    assert main(["bench", "report", str(run), "--renders", "1"]) == 0
    cap = capsys.readouterr()
    assert "error" not in cap.err and "warning" not in cap.err
    assert all(line.isprintable() for line in cap.err.splitlines())  # no control characters on the terminal
    text = (run / "report" / "index.html").read_text()
    assert r"$\frac{a$" in text and r"\begin{x}" in text


# -- 4. the reader accepts only what the report can show -------------------------------------
@pytest.mark.parametrize(
    "field,value",
    [("corruption", ["noise", "0.1"]), ("corruption_group", ["noise"]), ("corruption", {"a": 1}),
     ("dataset", [1]), ("strength", [0.1]), ("strength", "0.1"), ("strength", True), ("params", ["n", 3]),
     ("corruption_params", [1]), ("seconds", "fast"), ("spectra", [1]), ("spectra", {"k": 1}), ("error", 5),
     ("output", 3), ("preset", ["a"]), ("run_name", 7), ("versions", []), ("random_state", 1.5),
     ("spectrum_cache_hit", "yes")],
)
def test_rows_the_report_cannot_show_are_set_aside(run, field, value):
    rows = _rows(run)
    bad = dict(rows[-1], **{field: value})
    _put_rows(run, rows[:-1] + [bad])
    with pytest.warns(BenchWarning, match=rf"'{field}' is a JSON|'spectra' holds"):
        kept = read_rows(run)
    assert [r["key"] for r in kept] == [r["key"] for r in rows[:-1]]


def test_a_list_valued_corruption_is_one_warning_not_a_crash(run, capsys):
    rows = _rows(run)
    _put_rows(run, [dict(r, corruption=["noise", 1], corruption_group=["noise"]) for r in rows[:2]] + rows[2:])
    assert main(["bench", "report", str(run), "--renders", "0", "-q"]) == 0
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "warning" in err and "skipped 2 invalid line(s)" in err


def test_rows_written_by_the_runner_are_accepted(run):
    rows = _rows(run)
    assert rows and all(_row_problem(r) is None for r in rows)


_TEXTS = st.one_of(st.sampled_from(LATEX + PAYLOADS + ("", "none", "-", "a/b", "..")), st.text(max_size=10))
_NUMS = st.one_of(st.none(), st.integers(-10**6, 10**6), st.floats(allow_nan=True, allow_infinity=True))
_JSON = st.recursive(
    st.one_of(st.none(), st.booleans(), _NUMS, _TEXTS),
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(_TEXTS, inner, max_size=3)),
    max_leaves=8,
)
_CURVES = st.lists(st.lists(st.one_of(_NUMS, _TEXTS), min_size=2, max_size=2), min_size=1, max_size=5)


@st.composite
def _accepted_rows(draw):
    rows = []
    for i in range(draw(st.integers(1, 5))):
        row = {
            "key": f"k{i}",
            "status": draw(st.sampled_from(["ok", "failed"])),
            "task_name": draw(st.sampled_from(["t", "$t$", "<b>"])),
            "task_kind": draw(_TEXTS),
            "item": draw(_TEXTS),
            "method_label": draw(_TEXTS),
            "metrics": draw(st.dictionaries(_TEXTS, st.one_of(_JSON, _CURVES), max_size=4)),
        }
        optional = {
            "dataset": _TEXTS, "corruption": _TEXTS, "corruption_group": st.sampled_from(["none", "g", "$g"]),
            "family": st.sampled_from(["pipelines", "segmenters"]), "run_name": _TEXTS,
            "strength": _NUMS, "seconds": _NUMS, "peak_memory_mb": _NUMS, "spectrum_seconds": _NUMS,
            "spectrum_cache_hit": st.one_of(st.none(), st.booleans()),
            "params": st.dictionaries(_TEXTS, _JSON, max_size=3),
            "versions": st.dictionaries(_TEXTS, _JSON, max_size=2),
            "spectra": st.lists(st.dictionaries(_TEXTS, _JSON, max_size=2), max_size=2),
            "error": st.one_of(st.none(), _TEXTS), "output": st.one_of(st.none(), _TEXTS),
            "prepare_key": _TEXTS,
        }
        for k, strategy in optional.items():
            if draw(st.booleans()):
                row[k] = draw(strategy)
        rows.append(row)
    return rows


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                                                  HealthCheck.function_scoped_fixture])
@given(rows=_accepted_rows())
def test_the_report_survives_every_row_the_reader_accepts(rows, tmp_path_factory):
    run = tmp_path_factory.mktemp("prop")
    _put_rows(run, rows)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        assert len(read_rows(run)) == len(rows)  # the reader accepts them all
        res = write_report(run, renders=1)
    assert not [str(w.message) for w in seen]  # no warning line either (glyphs, overflow, legends)
    _assert_no_markup_from_data(res["html"].read_text())


# -- 5. config strings and options -----------------------------------------------------------
@pytest.mark.parametrize(
    "old,new,key",
    [
        ('params = { n_segments = 3 }', 'label = 5\nparams = { n_segments = 3 }', "tasks[1].methods[0].label"),
        ('params = { n_segments = 3 }', 'label = ""\nparams = { n_segments = 3 }', "tasks[1].methods[0].label"),
        ('plugin = "spectral-clustering"', "plugin = 5", "tasks[1].methods[0].plugin"),
        ('preset = "luxburg-unnormalized"', 'preset = ["luxburg-unnormalized"]', "tasks[1].methods[0].preset"),
        ('name = "hardening"', "name = 5", "run.name"),
        ('name = "hardening"', 'name = "h"\ndescription = [1]', "run.description"),
        ('kind = "synthetic"', 'kind = ["synthetic"]', "datasets[0].kind"),
        ('name = "synth"', 'name = { a = 1 }', "datasets[0].name"),
        ('kind = "gaussian-noise"', 'kind = ["gaussian-noise"]', "corruptions[0].kind"),
        ('name = "noise"', "name = 1.5", "corruptions[0].name"),
        ('task = "spectrum"', 'task = ["spectrum"]', "tasks[0].task"),
        ('name = "seg"', 'name = ["seg"]', "tasks[1].name"),
        ('corruptions = ["none", "noise"]', 'corruptions = ["none", ["noise"]]', "tasks[1].corruptions[1]"),
        ('corruptions = ["none", "noise"]', "corruptions = []", "tasks[1].corruptions"),
        ('metrics = ["n_segments", "segmentation"]', 'metrics = [["n_segments"]]', "tasks[1].metrics[0]"),
        ('task = "spectrum"', 'task = "spectrum"\ndatasets = [7]', "tasks[0].datasets[0]"),
        ('task = "spectrum"', 'task = "spectrum"\ndatasets = []', "tasks[0].datasets"),
        ('metrics = ["n_segments", "segmentation"]', 'metrics = ["n_segments"]\noptions = { nope = 1 }',
         "tasks[1].options.nope"),
    ],
)
def test_config_strings_and_options_are_checked_naming_the_key(tmp_path, capsys, old, new, key):
    _refused_naming_the_key(tmp_path, capsys, old, new, key)


def _refused_naming_the_key(tmp_path, capsys, old: str, new: str, key: str) -> None:
    """CONFIG with ``old`` replaced by ``new``: load_config raises a ConfigError of ``key``, and ``bench run``
    exits 2 with one line naming it, before any work."""
    from shape_toolkit.bench.config import ConfigError, load_config

    assert old in CONFIG
    config = _write(tmp_path, CONFIG.replace(old, new, 1))
    with pytest.raises(ConfigError) as ei:
        load_config(config)
    assert ei.value.key == key, str(ei.value)
    run = tmp_path / "run"
    assert main(["bench", "run", str(config), "-o", str(run), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and key in err and "internal error" not in err
    assert not run.exists()  # refused before any work


# -- 7. bad nested parameters: one line naming the key, before any work ----------------------
@pytest.mark.parametrize(
    "old,new,key",
    [
        ("params = { n_segments = 3 }", "params = { n_segments = 3, weighting = { a = 1 } }",
         "tasks[1].methods[0].params.weighting"),
        ("params = { n_segments = 3 }", 'params = { n_segments = 3, weighting = "nope" }',
         "tasks[1].methods[0].params.weighting"),
        ("params = { n_segments = 3 }", 'params = { n_segments = [3, "x"] }', "tasks[1].methods[0].params.n_segments"),
        ("params = { n_segments = 3 }", "params = { n_segments = { a = 1 } }",
         "tasks[1].methods[0].params.n_segments"),
        ("params = { n_segments = 3 }", "params = { n_segments = 3, n_init = { a = 1 } }",
         "tasks[1].methods[0].params.n_init"),
        ("params = { strength = [0.01, 0.02] }", "params = { strength = { a = 1 } }", "corruptions[0].params.strength"),
        ("params = { strength = [0.01, 0.02] }", 'params = { strength = [0.01, "x"] }',
         "corruptions[0].params.strength"),
        ('plugin = "gaussian"', 'plugin = "gaussian"\nparams = { bandwidth_scale = "wide" }',
         "tasks[0].methods[0].params.bandwidth_scale"),
        ("params = { strength = [0.01, 0.02] }", "params = { strength = [0.01, nan] }",
         "corruptions[0].params.strength"),
        ("params = { strength = [0.01, 0.02] }", "params = { strength = inf }", "corruptions[0].params.strength"),
        ("subdivisions = 2 }", 'subdivisions = "" }', "datasets[0].params.subdivisions"),
        ('name = "hardening"', 'name = "h"\nrandom_state = 4294967296', "run.random_state"),
    ],
)
def test_bad_nested_parameters_are_one_line_naming_the_key(tmp_path, capsys, old, new, key):
    _refused_naming_the_key(tmp_path, capsys, old, new, key)


# -- 6. grids are counted, and refused above the cap, before anything is expanded ------------
SEVEN = ", ".join(f"{k} = [{', '.join(str(v) for v in range(2, 12))}]" for k in
                  ("n_segments", "n_clusters", "n_rays", "cone_angle", "filter_iterations", "log_alpha", "n_init"))
BOMB = f"""
[[datasets]]
name = "s"
kind = "synthetic"
params = {{ n_poses = 2, subdivisions = 1 }}
[[tasks]]
task = "segmentation"
[[tasks.methods]]
plugin = "sdf"
params = {{ {SEVEN} }}
"""


def test_a_grid_bomb_is_refused_before_anything_is_expanded(tmp_path, capsys, monkeypatch):
    import shape_toolkit.bench.config as config_module

    config = _write(tmp_path, BOMB)
    assert config.stat().st_size < 600  # the 450-byte config with seven 10-value lists
    expanded = []
    real = config_module.expand_grid
    monkeypatch.setattr(config_module, "expand_grid", lambda p: expanded.append(p) or real(p))
    with pytest.raises(config_module.ConfigError, match=r"20,000,000 rows .*--max-rows N"):
        config_module.load_config(config, max_rows=config_module.MAX_ROWS)
    assert not expanded  # refused from the counts, no grid built
    run = tmp_path / "run"
    assert main(["bench", "run", str(config), "-o", str(run)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "20,000,000" in err and "cap of 1,000" in err and "--max-rows" in err
    assert not run.exists()
    # a synthetic dataset of a billion poses is not listed either
    huge = _write(tmp_path, CONFIG.replace("n_poses = 2", "n_poses = 1000000000"), "huge.toml")
    with pytest.raises(config_module.ConfigError) as ei:
        config_module.load_config(huge, max_rows=1000)
    assert ei.value.key == "datasets[0].params.n_poses"


def test_the_row_count_is_the_plan_and_max_rows_moves_the_cap(tmp_path, capsys):
    from shape_toolkit.bench.config import MAX_ROWS, ConfigError, load_config
    from shape_toolkit.bench.plan import plan

    assert MAX_ROWS == 1000
    config = _write(tmp_path, CONFIG)
    for limit in (None, 1):
        cfg = load_config(config, limit=limit)
        assert cfg.planned_rows == len(plan(cfg, tmp_path / "r", limit=limit)[0]) == 4
    wide = _write(tmp_path, CONFIG.replace("limit = 1", "limit = 2").replace("n_segments = 3", "n_segments = [3, 4]"),
                  "wide.toml")
    cfg = load_config(wide)
    assert cfg.planned_rows == len(plan(cfg, tmp_path / "r")[0]) == 2 * (1 + 3 * 2)
    with pytest.raises(ConfigError, match="plans 14 rows"):
        load_config(wide, max_rows=13)
    run = tmp_path / "run"
    assert main(["bench", "run", str(wide), "-o", str(run), "--max-rows", "13", "--no-progress"]) == 2
    assert "--max-rows" in capsys.readouterr().err and not run.exists()
    # --limit counts: one item per dataset fits under the cap
    assert main(["bench", "run", str(wide), "-o", str(run), "--max-rows", "7", "--limit", "1", "--no-progress"]) == 0
    assert len(read_rows(run)) == 7
    for bad in ("0", "-1", "many"):
        assert main(["bench", "run", str(wide), "-o", str(tmp_path / "r2"), "--max-rows", bad]) == 2
    capsys.readouterr()
    # default cap: 1,001 rows are refused
    many = _write(tmp_path, CONFIG.replace("limit = 1", "").replace("n_poses = 2", "n_poses = 1001"), "many.toml")
    assert main(["bench", "run", str(many), "-o", str(tmp_path / "r3")]) == 2
    assert "1,001" in capsys.readouterr().err


def _paths(d, pre=()):
    if isinstance(d, dict):
        items = d.items()
    elif isinstance(d, list):
        items = enumerate(d)
    else:
        return
    for k, v in items:
        yield pre + (k,)
        yield from _paths(v, pre + (k,))


def _fuzz_base() -> dict:
    from shape_toolkit.bench.config import tomllib

    raw = tomllib.loads(textwrap.dedent(CONFIG))
    methods = [{"plugin": "spectral", "keypoints": {"plugin": "adf-maxima", "preset": "sparse"}},
               {"pipeline": "zoomout", "label": "z"}, {"plugin": "eigvec-alignment"}]
    raw["tasks"].append({"task": "matching", "name": "m", "metrics": ["geodesic_error"],
                         "options": {"truth_sample": 50}, "methods": methods})
    return raw


_FUZZ_BASE = _fuzz_base()
_KEYS = st.sampled_from(["a", "k", "plugin", "params", "weighting", "n_segments", "strength", "preset", "label"])
_VALUES = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-3, 10**12), st.floats(), st.text(max_size=5),
              st.sampled_from(["cotangent", "gaussian", "none", "noise", "synth", "spectrum", "sparse", "zoomout"])),
    lambda inner: st.one_of(st.lists(inner, max_size=3), st.dictionaries(_KEYS, inner, max_size=3)),
    max_leaves=6,
)


@settings(max_examples=300, deadline=None)
@given(changes=st.lists(st.tuples(st.sampled_from(list(_paths(_FUZZ_BASE))), _VALUES), min_size=1, max_size=4))
def test_any_value_anywhere_in_a_config_is_valid_or_one_config_error(changes):
    """Every key of a config (a segmentation, spectrum and matching task) set to values of any
    TOML type: validation passes or raises a ToolkitError, never anything else."""
    import copy

    from shape_toolkit.bench.config import parse_config
    from shape_toolkit.errors import ToolkitError

    raw = copy.deepcopy(_FUZZ_BASE)
    for path, value in changes:
        d = raw
        try:
            for k in path[:-1]:
                d = d[k]
            d[path[-1]] = value
        except (KeyError, IndexError, TypeError):
            continue
    try:
        parse_config(raw, max_rows=1000)
    except ToolkitError:
        pass
