"""Fault corpus for run folders: every file of a finished run swapped, truncated, emptied, filled
with garbage or a pickle, replaced by a link to a file outside, deleted, or joined by a planted
file; then ``bench run`` (resume) and ``bench report`` on it. Each case is classified:

- ``ok``: exit 0, the rows equal the clean run's (status, metrics, output labels), nothing outside
  the run folder changed, every stderr line a one-line warning;
- ``refused``: exit 2 or 3 with exactly one stderr line, nothing outside changed;
- ``mishandled``: anything else (a wrong row, a traceback, an internal error, a write outside).

The clean run is ``benchmarks/fixtures/run_folder_corpus.toml``. Writes
``benchmarks/results/run_folder_corpus.md``.

    python benchmarks/run_folder_corpus.py [--quick]

``tests/test_run_folder_corpus.py`` runs a subset (one case of each fault kind).
"""

from __future__ import annotations

import argparse
import io
import pickle
import shutil
import sys
import tempfile
import time
from collections import Counter
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "run_folder_corpus.md"

#: the clean run the faults are planted in (2 synthetic items x 2 segmenters)
CONFIG = HERE / "fixtures" / "run_folder_corpus.toml"

#: what each fault does to one file (``rel``) of a run folder
FAULTS = ("swap", "truncate", "empty", "garbage", "pickle", "link-out", "delete", "plant")
#: what a case can come to (the columns of the results table)
OUTCOMES = ("ok", "refused", "mishandled")


class _Payload:
    """Unpickling this writes ``path``: a stand-in for code that must never run."""

    def __init__(self, path: str):
        self.path = path

    def __reduce__(self):
        return (open, (self.path, "w"))


@dataclass
class Case:
    """One fault on one file; the outcome is filled in by :func:`run_case`."""

    fault: str
    rel: str
    outcome: str = ""
    detail: str = ""
    codes: list[int] = field(default_factory=list)


def _main(argv: list[str]) -> tuple[int, str, str]:
    """Exit code, stdout and stderr of ``shape-toolkit ARGV`` run in this process (usage errors included)."""
    from shape_toolkit.cli import main

    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


def _rows(run: Path) -> dict[str, tuple]:
    """Row key -> (status, metrics, output labels) of a run folder (warnings silenced)."""
    import warnings

    from shape_toolkit.bench.store import load_output, read_rows

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rows = read_rows(run)
    got = {}
    for r in rows:
        labels = None
        if r.get("output"):
            try:
                labels = tuple(load_output(run, r["output"], key=r["key"]).get("labels", np.zeros(0)).tolist())
            except ValueError:
                labels = "unreadable"
        got[r["key"]] = (r["status"], repr(sorted(r.get("metrics", {}).items())), labels)
    return got


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def reference(work: Path) -> tuple[Path, Path]:
    """A finished clean run folder and its config, under ``work``."""
    cfg = work / "bench.toml"
    cfg.write_text(CONFIG.read_text())
    run = work / "reference"
    code, _, err = _main(["bench", "run", str(cfg), "-o", str(run), "--no-progress"])
    if code != 0:
        raise SystemExit(f"the reference run failed: {err}")
    return cfg, run


def cases(run: Path) -> list[Case]:
    """Every fault on every file of the reference run folder (``.lock`` aside)."""
    files = sorted(str(p.relative_to(run)) for p in run.rglob("*") if p.is_file() and p.name != ".lock")
    return [Case(f, rel) for rel in files for f in FAULTS]


def _apply(case: Case, run: Path, outside: Path) -> None:
    p = run / case.rel
    data = p.read_bytes()
    if case.fault == "swap":  # with a sibling of the same kind, else with the first other file
        sib = sorted(q for q in p.parent.iterdir() if q.is_file() and q != p and q.suffix == p.suffix)
        sib = sib or sorted(q for q in run.rglob("*") if q.is_file() and q != p and q.name != ".lock")
        other = sib[0]
        p.write_bytes(other.read_bytes())
        other.write_bytes(data)
    elif case.fault == "truncate":
        p.write_bytes(data[: len(data) // 2])
    elif case.fault == "empty":
        p.write_bytes(b"")
    elif case.fault == "garbage":
        p.write_bytes(b"PK\x03\x04" + bytes(range(256)) * 4)
    elif case.fault == "pickle":
        p.write_bytes(pickle.dumps(_Payload(str(outside / "PWNED"))))
    elif case.fault == "link-out":
        victim = outside / "victim"
        victim.write_bytes(data)
        p.unlink()
        p.symlink_to(victim)
    elif case.fault == "delete":
        p.unlink()
    elif case.fault == "plant":  # a file of the same kind beside it, named like a cache entry
        (p.parent / ("0" * 16 + p.suffix)).write_bytes(pickle.dumps(_Payload(str(outside / "PWNED"))))


def run_case(case: Case, cfg: Path, ref: Path, ref_rows: dict, work: Path) -> Case:
    """Apply ``case`` to a copy of the reference run, then resume it and report it."""
    root = Path(tempfile.mkdtemp(dir=work))
    run, outside = root / "run", root / "outside"
    shutil.copytree(ref, run, symlinks=True)
    outside.mkdir()
    (outside / "keep.txt").write_text("the user's file\n")
    _apply(case, run, outside)
    if case.rel != "results.jsonl" and not (run / "results.jsonl").is_symlink():
        (run / "results.jsonl").unlink(missing_ok=True)  # every row again: each cache file is read back
    before = _tree(outside)
    problems = []
    for argv in (["bench", "run", str(cfg), "-o", str(run), "--no-progress"], ["bench", "report", str(run)]):
        code, _, err = _main(argv)
        case.codes.append(code)
        lines = err.strip().splitlines()
        if "Traceback" in err or "internal error" in err:
            problems.append(f"{argv[1]}: {lines[-1] if lines else ''}")
        elif code in (2, 3):
            if len(lines) != 1:
                problems.append(f"{argv[1]}: exit {code} with {len(lines)} stderr lines")
        elif code != 0:
            problems.append(f"{argv[1]}: exit {code}")
        elif any("error" in ln and "warning" not in ln for ln in lines):
            problems.append(f"{argv[1]}: exit 0 with an error line")
        if code != 0:
            break
    if (outside / "PWNED").exists():
        problems.append("a planted pickle was loaded")
    if _tree(outside) != before:
        problems.append("a file outside the run folder changed")
    if case.codes[0] == 0 and _rows(run) != ref_rows:
        problems.append("rows differ from the clean run")
    case.outcome = "mishandled" if problems else ("ok" if case.codes[0] == 0 else "refused")
    case.detail = "; ".join(problems)
    shutil.rmtree(root, ignore_errors=True)
    return case


def run_corpus(work: Path, quick: bool = False) -> list[Case]:
    """Build the reference run in ``work`` and run every case (``quick``: each fault on the first file of
    each folder only)."""
    cfg, ref = reference(work)
    ref_rows = _rows(ref)
    todo = cases(ref)
    if quick:
        firsts: dict[tuple[str, str], Case] = {}
        for c in todo:
            firsts.setdefault((c.fault, str(Path(c.rel).parent)), c)
        todo = list(firsts.values())
    return [run_case(c, cfg, ref, ref_rows, work) for c in todo]


def write_results(done: list[Case], seconds: float) -> None:
    """``benchmarks/results/run_folder_corpus.md``."""
    from shape_toolkit.bench.report import markdown_table

    by = Counter(c.outcome for c in done)
    lines = [
        "# Run-folder fault corpus",
        "",
        "Regenerate: `python benchmarks/run_folder_corpus.py`. Every file of a finished run folder (2 items x",
        "2 methods: results, prepare log, config, mark, prepared items, spectra, outputs) gets each fault:",
        f"{', '.join(FAULTS)}; then `bench run` resumes it and `bench report` renders it.",
        "",
        f"- cases: {len(done)}; wall time {seconds:.0f} s",
        f"- **ok** (exit 0, rows equal to the clean run's, nothing outside changed): {by['ok']}",
        f"- **refused** (exit 2 or 3, one line, nothing outside changed): {by['refused']}",
        f"- **mishandled** (a wrong row, a traceback, a write outside, a loaded pickle): {by['mishandled']}",
        "",
        *markdown_table(["fault", *OUTCOMES],
                        [[f, *(Counter(c.outcome for c in done if c.fault == f)[o] for o in OUTCOMES)]
                         for f in FAULTS]),
    ]
    lines += ["", "## Mishandled", ""]
    bad = [c for c in done if c.outcome == "mishandled"]
    lines += [f"- `{c.fault} {c.rel}`: {c.detail}" for c in bad] or ["none"]
    lines += ["", "## Refused", ""]
    lines += [f"- `{c.fault} {c.rel}` (exit {c.codes[0]})" for c in done if c.outcome == "refused"] or ["none"]
    RESULTS.write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one file of each folder only")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        done = run_corpus(Path(tmp), args.quick)
    write_results(done, time.perf_counter() - t0)
    bad = sum(c.outcome == "mishandled" for c in done)
    print(f"{len(done)} cases, {bad} mishandled -> {RESULTS}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
