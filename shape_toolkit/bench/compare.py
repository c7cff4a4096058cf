"""What changed between two runs: ``shape-toolkit bench compare RUN_A RUN_B``.

Rows are paired by what they measured, not by their keys (a changed parameter changes the key):
task, dataset, item, corruption and its strength, and the method's display label. For each task,
method and numeric metric the comparison gives the paired difference ``B - A`` over the items both
runs scored, its standard error, and a verdict: ``better`` / ``worse`` when the mean difference
is more than two standard errors from zero in the metric's better direction, ``changed`` for a
metric with no better direction, ``same`` otherwise. The items that moved most are listed, and
rows that failed in one run but not the other. Written as text, JSON, CSV and a self-contained
HTML page (every string from the runs escaped).
"""

from __future__ import annotations

import csv
import html
import io
import math
import os
from collections import defaultdict
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from shape_toolkit.bench.report import metric_direction
from shape_toolkit.bench.store import RESULTS, read_rows
from shape_toolkit.errors import ParameterError
from shape_toolkit.validation import atomic_output

__all__ = ["MetricChange", "Comparison", "compare_runs", "write_comparison", "COST_METRICS"]

#: row fields compared beside the metrics (cost of the method)
COST_METRICS = ("seconds", "cpu_seconds", "peak_memory_mb")
#: items listed per (task, method, metric) among those that moved most
TOP_MOVED = 3


@dataclass
class MetricChange:
    """One task, method and metric: means over the paired items, the paired difference ``B - A``
    with its standard error (None with fewer than 2 pairs), the verdict and the items that moved
    most ``[(item label, a, b), ...]``."""

    task: str
    method: str
    metric: str
    n_pairs: int
    mean_a: float
    mean_b: float
    mean_diff: float
    se_diff: float | None
    direction: str | None
    verdict: str
    moved: list[tuple[str, float, float]] = field(default_factory=list)


@dataclass
class Comparison:
    """Everything :func:`compare_runs` found: per-metric changes, row identities present in one
    run only, and rows ok in one run and failed in the other."""

    run_a: str
    run_b: str
    changes: list[MetricChange]
    only_a: list[str]
    only_b: list[str]
    newly_failed: list[str]
    newly_ok: list[str]

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (finite numbers only)."""
        return asdict(self)


def _label(row: dict) -> str:
    parts = [str(row.get("dataset")), str(row.get("item"))]
    if row.get("corruption") not in (None, "none"):
        parts.append(f"{row.get('corruption')}@{row.get('strength')}")
    return " / ".join(parts)


def _identity(row: dict) -> tuple:
    return (str(row.get("task_name")), str(row.get("method_label") or row.get("plugin")), _label(row))


def _numbers(row: dict) -> dict[str, float]:
    out: dict[str, float] = {}
    metrics = row.get("metrics") if isinstance(row.get("metrics"), dict) else {}
    for k, v in list(metrics.items()) + [(c, row.get(c)) for c in COST_METRICS]:
        if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
            out[str(k)] = float(v)
    return out


def _rows(run: str | os.PathLike) -> list[dict]:
    path = Path(run)
    if not (path / RESULTS).is_file():
        raise ParameterError(f"{run} is not a run folder: it has no {RESULTS} (run 'bench run' first)")
    return read_rows(path, planned_only=True)


def _verdict(mean: float, se: float | None, direction: str | None) -> str:
    if se is None:
        return "same" if mean == 0 else "changed (1 pair)"
    if abs(mean) <= 2 * se or mean == 0:
        return "same"
    if direction is None:
        return "changed"
    return "better" if (mean > 0) == (direction == "higher") else "worse"


def compare_runs(run_a: str | os.PathLike, run_b: str | os.PathLike) -> Comparison:
    """Compare the rows of two run folders (see the module docstring); ``ParameterError`` when
    either is not a run folder or holds no valid row."""
    rows_a, rows_b = _rows(run_a), _rows(run_b)
    for run, rows in ((run_a, rows_a), (run_b, rows_b)):
        if not rows:  # empty, or every line invalid: an empty table would read as "no change"
            raise ParameterError(f"{run} holds no valid row: nothing to compare (run 'bench run' first)")
    by_a = {_identity(r): r for r in rows_a}
    by_b = {_identity(r): r for r in rows_b}
    common = sorted(set(by_a) & set(by_b))
    pairs: dict[tuple[str, str, str], list[tuple[str, float, float]]] = defaultdict(list)
    newly_failed, newly_ok = [], []
    for ident in common:
        ra, rb = by_a[ident], by_b[ident]
        ok_a, ok_b = ra.get("status") == "ok", rb.get("status") == "ok"
        if ok_a != ok_b:
            (newly_failed if ok_a else newly_ok).append(" | ".join(ident))
        if not (ok_a and ok_b):
            continue
        na, nb = _numbers(ra), _numbers(rb)
        for metric in sorted(set(na) & set(nb)):
            pairs[(ident[0], ident[1], metric)].append((ident[2], na[metric], nb[metric]))
    changes = []
    for (task, method, metric), items in sorted(pairs.items()):
        a = np.array([x[1] for x in items])
        b = np.array([x[2] for x in items])
        d = b - a
        m = len(d)
        se = float(np.std(d, ddof=1) / math.sqrt(m)) if m >= 2 else None
        direction = metric_direction(metric)
        order = np.argsort(-np.abs(d), kind="stable")[:TOP_MOVED]
        moved = [(items[i][0], float(a[i]), float(b[i])) for i in order if d[i] != 0]
        changes.append(MetricChange(task, method, metric, m, float(a.mean()), float(b.mean()), float(d.mean()), se,
                                    direction, _verdict(float(d.mean()), se, direction), moved))
    return Comparison(
        str(run_a), str(run_b), changes,
        sorted(" | ".join(i) for i in set(by_a) - set(by_b)),
        sorted(" | ".join(i) for i in set(by_b) - set(by_a)),
        newly_failed, newly_ok,
    )


def _n(v: float | None) -> str:
    if v is None:
        return "-"
    return f"{v:.4g}"


def format_text(comp: Comparison) -> str:
    """The comparison as a plain-text table (one line per task, method and metric)."""
    lines = [f"A = {comp.run_a}", f"B = {comp.run_b}", ""]
    head = (f"{'task':<16} {'method':<24} {'metric':<26} {'pairs':>5} {'A':>10} {'B':>10} {'B-A':>10} "
            f"{'+-SE':>9}  verdict")
    lines += [head, "-" * len(head)]
    for c in comp.changes:
        lines.append(f"{c.task[:16]:<16} {c.method[:24]:<24} {c.metric[:26]:<26} {c.n_pairs:>5} {_n(c.mean_a):>10} "
                     f"{_n(c.mean_b):>10} {_n(c.mean_diff):>10} {_n(c.se_diff):>9}  {c.verdict}")
    for title, items in (("only in A", comp.only_a), ("only in B", comp.only_b),
                         ("ok in A, failed in B", comp.newly_failed), ("failed in A, ok in B", comp.newly_ok)):
        if items:
            lines += ["", f"{title} ({len(items)}):"] + [f"  {i}" for i in items[:20]]
    return "\n".join(lines) + "\n"


def _csv(comp: Comparison) -> str:
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["task", "method", "metric", "pairs", "mean_a", "mean_b", "mean_diff", "se_diff", "direction",
                "verdict", "moved_most"])
    for c in comp.changes:
        moved = "; ".join(f"{lbl}: {_n(a)} -> {_n(b)}" for lbl, a, b in c.moved)
        w.writerow([c.task, c.method, c.metric, c.n_pairs, c.mean_a, c.mean_b, c.mean_diff,
                    "" if c.se_diff is None else c.se_diff, c.direction or "", c.verdict, moved])
    return buf.getvalue()


_COLOURS = {"better": "#d9f2d9", "worse": "#f8d7d7", "changed": "#fff3cd"}


def _html(comp: Comparison) -> str:
    e = html.escape
    rows = []
    for c in comp.changes:
        moved = "; ".join(f"{e(lbl)}: {_n(a)} &rarr; {_n(b)}" for lbl, a, b in c.moved)
        colour = _COLOURS.get(c.verdict, "")
        style = f" style='background:{colour}'" if colour else ""
        rows.append(
            f"<tr{style}><td>{e(c.task)}</td><td>{e(c.method)}</td><td>{e(c.metric)}</td><td>{c.n_pairs}</td>"
            f"<td>{_n(c.mean_a)}</td><td>{_n(c.mean_b)}</td><td>{_n(c.mean_diff)}</td><td>{_n(c.se_diff)}</td>"
            f"<td>{e(c.direction or '-')}</td><td>{e(c.verdict)}</td><td>{moved}</td></tr>"
        )
    extra = []
    for title, items in (("Only in A", comp.only_a), ("Only in B", comp.only_b),
                         ("Ok in A, failed in B", comp.newly_failed), ("Failed in A, ok in B", comp.newly_ok)):
        if items:
            extra.append(f"<h2>{title} ({len(items)})</h2><ul>" + "".join(f"<li>{e(i)}</li>" for i in items) + "</ul>")
    return (
        "<!doctype html><html><head><meta charset='utf-8'><title>bench compare</title><style>"
        "body{font-family:sans-serif;max-width:1400px;margin:1em auto}table{border-collapse:collapse;width:100%}"
        "td,th{border:1px solid #ccc;padding:3px 6px;font-size:13px;text-align:left}</style></head><body>"
        f"<h1>What changed from A to B</h1><p>A = <code>{e(comp.run_a)}</code><br>B = <code>{e(comp.run_b)}</code></p>"
        "<p>Rows paired by task, dataset, item, corruption and method label. B-A: the mean paired difference; "
        "SE: its standard error; better/worse: more than 2 SE from zero in the metric's better direction.</p>"
        "<table><tr><th>task</th><th>method</th><th>metric</th><th>pairs</th><th>A</th><th>B</th><th>B-A</th>"
        "<th>SE</th><th>better is</th><th>verdict</th><th>moved most</th></tr>"
        + "".join(rows) + "</table>" + "".join(extra) + "</body></html>\n"
    )


def write_comparison(comp: Comparison, out_dir: str | os.PathLike) -> list[str]:
    """Write ``compare.html`` and ``compare.csv`` into ``out_dir`` (created; only these two files
    are written); returns their paths."""
    d = Path(out_dir)
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ParameterError(f"cannot create {out_dir}: {exc.strerror or exc}") from None
    written = []
    for name, text in (("compare.html", _html(comp)), ("compare.csv", _csv(comp))):
        with atomic_output(d / name, "comparison") as tmp:
            tmp.write_text(text, encoding="utf-8")
        written.append(str(d / name))
    return written
