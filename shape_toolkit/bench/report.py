"""``bench report``: a self-contained HTML page (PNG figures inlined as base64) plus the figures as
PNG and PDF files and every table as CSV and LaTeX (booktabs) files, linked from the page.

Sections: a summary first (per task and dataset, the best method of each metric highlighted and
every metric's direction marked, lower or higher is better); then per task and dataset a table of
mean and standard deviation per method and corruption (never averaging different datasets), with
an expandable per-item table. "Best" only where it means something: a best shared within the
printed precision is named a tie, a constant column (memory: within 1 MB) has none, and a metric a
method gives no value of is n/a with a note under the table saying why (never 0, never best);
GCE and LCE are marked as rewarding under-segmentation. Then curve metrics (cumulative geodesic
error, eigenvalues, scree alpha) per method side by side; metric versus corruption strength;
runtime and memory per method; the shared precomputation; failed rows; rendered shapes
(segmentations in the ground truth's palette, matched by the Hungarian method; keypoints; maps by
pull-back colour transfer). Figures are made for a full-width page (about 1200 px), with labelled
axes and units.
"""

from __future__ import annotations

import base64
import csv
import hashlib
import html
import io
import json
import math
import os
import re
import warnings
from collections import Counter, defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from shape_toolkit.bench.config import method_id
from shape_toolkit.bench.store import (
    RESULTS,
    SPLIT,
    load_output,
    load_prepared,
    only_planned,
    prepared_path,
    read_prepare_log,
    read_rows,
    safe_name,
)
from shape_toolkit.errors import ParameterError
from shape_toolkit.validation import atomic_output

__all__ = ["write_report", "check_report_output", "summarize", "method_id", "metric_direction", "latex_escape",
           "rewards_under_segmentation", "report_colors", "MANIFEST", "SPLIT_FIELD", "markdown_summary",
           "markdown_table"]

#: metrics where a larger value is better (everything else with a direction: lower is better)
_HIGHER = ("recall", "precision", "repeatability", "coverage", "within", "matched_fraction", "accuracy", "auc",
           "smooth")
_LOWER = ("error", "discrepancy", "gce", "lce", "hamming", "seconds", "memory", "chance", "flipped", "drift",
          "wrong_part", "lost")
#: units of known columns, shown in the headers
_UNITS = {"seconds": "s", "cpu_seconds": "s", "peak_memory_mb": "MB", "metric_seconds": "s", "metric_cpu_seconds": "s",
          "metric_peak_memory_mb": "MB", "mean_geodesic_error": "sqrt(area)",
          "median_geodesic_error": "sqrt(area)", "lambda2": "1/length^2", "mean_eigenvalue": "1/length^2"}


def metric_direction(name: str) -> str | None:
    """``"higher"`` or ``"lower"`` (which value is better) for a metric name, None when neither
    (counts such as ``n_segments``, eigenvalues)."""
    n = name.lower()
    if n.startswith("n_") or "eigenvalue" in n or n == "lambda2":
        return None
    if any(h in n for h in _HIGHER):
        return "higher"
    if any(w in n for w in _LOWER):
        return "lower"
    return None


def _arrow(name: str) -> str:
    d = metric_direction(name)
    return {"higher": " &uarr;", "lower": " &darr;"}.get(d, "")


#: metrics that reward under-segmentation (one segment for the whole shape scores their best value, 0)
_UNDER_SEGMENTATION = re.compile(r"(?:^|_)(?:gce|lce)(?:$|_)", re.IGNORECASE)
_UNDER_NOTE = ("rewards under-segmentation: GCE and LCE score one segment for the whole shape as perfect (0); "
               "read them with n_segments and the other scores")
#: memory columns: differences below this many MB are noise, never a best
_MEMORY_TOLERANCE_MB = 1.0


def rewards_under_segmentation(name: str) -> bool:
    """Whether a metric rewards under-segmentation (GCE, LCE: a single segment scores 0, the best)."""
    return bool(_UNDER_SEGMENTATION.search(name))


def _unit(name: str) -> str | None:
    return _UNITS.get(name) or ("%" if name.startswith("r_smooth@") else
                                "sqrt(area)" if name.startswith("drift") else None)


def _header(name: str) -> str:
    unit = _unit(name)
    unit = f" ({unit})" if unit else ""
    d = metric_direction(name)
    tip = {"higher": "higher is better", "lower": "lower is better"}.get(d, "no better direction")
    mark = ""
    if rewards_under_segmentation(name):
        tip += "; rewards under-segmentation (see the note under the table)"
        mark = " &dagger;"
    shown = html.escape(name).replace("_", "_<wbr>")  # a long name may break after an underscore
    return f"<th title='{tip}'>{shown}{unit}{_arrow(name)}{mark}</th>"


def _header_text(name: str) -> str:
    """The text of a metric's header cell (as :func:`_header` shows it)."""
    unit = _unit(name)
    d = {"higher": " \u2191", "lower": " \u2193"}.get(metric_direction(name) or "", "")
    return name + (f" ({unit})" if unit else "") + d + (" \u2020" if rewards_under_segmentation(name) else "")


def _is_num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _is_curve(v: Any) -> bool:
    """A curve metric: a non-empty list of ``[x, y]`` pairs of finite numbers."""
    return isinstance(v, list) and len(v) > 0 and all(
        isinstance(x, list) and len(x) == 2 and _is_num(x[0]) and _is_num(x[1]) for x in v
    )


#: the cost columns of every row, shown after the metrics
_COSTS = ("seconds", "cpu_seconds", "peak_memory_mb")
#: the cost of a row's metrics, shown where the task measured it (task option ``metric_costs``)
_METRIC_COSTS = ("metric_seconds", "metric_cpu_seconds", "metric_peak_memory_mb")
_ALL_COSTS = _COSTS + _METRIC_COSTS


def summarize(rows: list[dict]) -> dict[str, dict[tuple[str, str, str], dict[str, tuple[float, float, int]]]]:
    """``{task_name: {(dataset, method_id, corruption): {column: (mean, std, count)}}}`` over ok
    rows, for every scalar metric plus ``seconds``, ``cpu_seconds`` and ``peak_memory_mb``; different datasets are
    never averaged together."""
    acc: dict = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    for r in rows:
        if r.get("status") != "ok":
            continue
        cell = acc[r["task_name"]][(str(r.get("dataset", "-")), method_id(r), str(r.get("corruption", "none")))]
        for k, v in (r.get("metrics") or {}).items():
            if _is_num(v):
                cell[k].append(float(v))
        for k in _COSTS + (_METRIC_COSTS if _is_num(r.get("metric_peak_memory_mb")) else ()):
            if _is_num(r.get(k)):
                cell[k].append(float(r[k]))
    out: dict = {}
    for task, cells in acc.items():
        out[task] = {}
        for key, cols in cells.items():
            out[task][key] = {c: (float(np.mean(v)), float(np.std(v)), len(v)) for c, v in cols.items()}
    return out


class _Figs:
    """The figures of one report: saved under fresh names in ``folder`` (a name held by a file the
    report did not write is never reused), each recorded in ``files``."""

    def __init__(self, folder: Path, say: Callable[[str], None] | None = None):
        self.folder = folder
        self.files: list[Path] = []  # the PNGs the page shows
        self.vector: list[Path] = []  # the same figures as PDF
        self.say = say or (lambda _msg: None)

    def fresh(self, name: str) -> Path:
        """A path ``NN-NAME.png`` in the folder that no file (or link) occupies, nor its ``.pdf``."""
        stem = f"{len(self.files):02d}-{safe_name(name)}"
        p = self.folder / f"{stem}.png"
        n = 2
        while os.path.lexists(p) or os.path.lexists(p.with_suffix(".pdf")):  # someone else's: take another name
            p = self.folder / f"{stem}-{n}.png"
            n += 1
        return p

    def save(self, fig, name: str) -> Path:
        import matplotlib.pyplot as plt

        self.say(f"figure {len(self.files) + 1}: {name}")  # the layout and PNG encoding take the time
        p = self.fresh(name)
        q = p.with_suffix(".pdf")
        try:
            fig.savefig(p, dpi=100, bbox_inches="tight", pad_inches=0.15)
            fig.savefig(q, bbox_inches="tight", pad_inches=0.15, metadata={"CreationDate": None})
        except BaseException:
            p.unlink(missing_ok=True)  # our own half-written files (the names were free)
            q.unlink(missing_ok=True)
            raise
        finally:
            plt.close(fig)
        self.files.append(p)
        self.vector.append(q)
        return p


def _img(path: Path, alt: str) -> str:
    """A figure inlined as base64 PNG, its caption linking the PDF of the same figure when there is one."""
    data = base64.b64encode(path.read_bytes()).decode()
    cap = html.escape(alt)
    img = f'<img alt="{cap}" src="data:image/png;base64,{data}"/>'
    pdf = path.with_suffix(".pdf")
    link = f" (<a href='{html.escape('figures/' + pdf.name)}'>PDF</a>)" if _regular(pdf) else ""
    return f"<figure>{img}<figcaption>{cap}{link}</figcaption></figure>"


def _num(v: float) -> str:
    """A number for a table cell: integers as integers, otherwise 4 significant-ish digits."""
    if not math.isfinite(v):
        return "&ndash;"
    if float(v).is_integer() and abs(v) < 1e12:
        return str(int(v))
    if abs(v) >= 1000 or abs(v) < 1e-3:
        return f"{v:.3g}"
    return f"{v:.4f}"


def _spread(s: float) -> str:
    """A standard deviation as printed after ``&plusmn;``."""
    return f"{s:.2g}" if abs(s) < 1e-3 or abs(s) >= 1000 else f"{s:.3f}"


def _fmt(m: float, s: float, n: int, show_n: bool = True) -> str:
    """``mean &plusmn; std (n=...)``; no spread shown for a single value or a constant column, no
    ``n`` when ``show_n`` is false (a table whose cells all have the same n says it once)."""
    text = _num(m)
    if n > 1 and s > 0:
        text += f" <small>&plusmn; {_spread(s)}</small>"
    if n > 1 and show_n:
        text += f" <small>(n={n})</small>"
    return text


def _no_value(v: Any) -> bool:
    """A metric the row names but holds no value of: null (NaN and infinities are stored as null)."""
    return v is None or (isinstance(v, float) and not math.isfinite(v))


#: metrics a kind of method cannot produce whatever its rows hold, ``(family, column)``: shown as n/a
_CANNOT = {("sparse_matchers", "matched_fraction")}
#: why a kind of method has no value of a column: ``(family, part of the column name) -> reason``
_WHY_NO_VALUE = {
    ("sparse_matchers", "matched_fraction"): (
        "a sparse matcher matches only its keypoints, so the share of the ground-truth points it matches "
        "measures the keypoint sampling, not the method"),
    ("sparse_matchers", "geodesic_error"): (
        "no matched keypoint is among the ground-truth points evaluated (the truth_sample option)"),
}


#: why a column has no value whatever the method: ``part of the column name -> reason``
_WHY_NO_DATA = {
    "_sym": "the dataset has no symmetric ground truth (corres/B.sym.vts)",
    "flipped": "the dataset has no symmetric ground truth (corres/B.sym.vts) to tell a mirrored map by",
}


def _why_no_value(family: str, column: str) -> str:
    for part, why in _WHY_NO_DATA.items():
        if part in column:
            return why
    for (fam, part), why in _WHY_NO_VALUE.items():
        if family == fam and part in column:
            return why
    return "the metric gave no value for its rows (null in results.jsonl)"


def _cell_key(r: dict) -> tuple[str, str, str]:
    return (str(r.get("dataset", "-")), method_id(r), str(r.get("corruption", "none")))


def _gaps(rows: list[dict]) -> dict[str, dict[tuple[str, str, str], dict[str, list]]]:
    """``{task: {(dataset, method_id, corruption): {column: [rows without a value, ok rows, why]}}}``
    over ok rows: the metrics a row names but has no value of (null, or one its kind of method
    cannot produce), shown as n/a with a note, never as a number."""
    out: dict = defaultdict(lambda: defaultdict(dict))
    n_ok: dict = defaultdict(int)
    for r in rows:
        if r.get("status") != "ok":
            continue
        key = _cell_key(r)
        n_ok[(r["task_name"], key)] += 1
        for k, v in r["metrics"].items():
            if _no_value(v):
                out[r["task_name"]][key].setdefault(k, [0, 0, _why_no_value(str(r.get("family", "")), k)])[0] += 1
    for task, cells in out.items():
        for key, cols in cells.items():
            for g in cols.values():
                g[1] = n_ok[(task, key)]
    return out


def _ranks(cells: dict, column: str) -> dict[tuple[str, str, str], str]:
    """``{cell key: "best" or "tie"}`` for ``column``, per dataset and corruption: the one best mean,
    or the means sharing the best within the printed precision (memory: within 1 MB), named a tie; no
    best memory below 1 MB.
    Nothing where only one method has a value, or where they all share the best (a constant column:
    nothing to choose). The reference rows (:data:`REFERENCE_METHODS`: the humans, the ground truth) are never
    ranked."""
    d = metric_direction(column)
    if d is None:
        return {}
    groups: dict = defaultdict(list)
    for key, cols in cells.items():
        if key[1] in REFERENCE_METHODS:
            continue
        if column in cols and math.isfinite(cols[column][0]):
            groups[(key[0], key[2])].append((cols[column][0], key))
    out: dict = {}
    for items in groups.values():
        if len(items) < 2:
            continue  # one method: nothing to compare
        target = max(v for v, _ in items) if d == "higher" else min(v for v, _ in items)
        if "memory" in column:
            if target < _MEMORY_TOLERANCE_MB:
                continue  # a best below 1 MB is measurement noise, not a method's merit
            tied = {k for v, k in items if abs(v - target) < _MEMORY_TOLERANCE_MB}
        else:
            tied = {k for v, k in items if _num(v) == _num(target)}
        if len(tied) == len(items):
            continue  # constant within what is printed (memory: within 1 MB)
        out.update(dict.fromkeys(tied, "best" if len(tied) == 1 else "tie"))
    return out


_NA = "n/a"
#: method names of reference rows, shown beside the methods but never ranked (the human-consistency row,
#: the ground-truth map of ``truth_reference``)
REFERENCE_METHODS = frozenset({"human", "ground truth"})


class _Grid:
    """One table of the report kept as data (key columns as text; metric cells as ``(mean, std, n,
    mark)``, ``_NA`` or None for no such column), so that its HTML, CSV and LaTeX show the same
    numbers; ``notes`` (plain text) go under it."""

    def __init__(self, title: str, keys: list[str], metrics: list[str], *, stats: bool, css: str = ""):
        self.title = title
        self.keys = keys
        self.metrics = metrics
        self.stats = stats  # cells are mean and std over n rows (else one value each)
        self.css = css
        self.rows: list[tuple[list[str], list[Any]]] = []
        self.notes: list[str] = []


def _html_cell(c: Any, stats: bool, show_n: bool = True) -> str:
    if c is None:
        return "<td>&ndash;</td>"
    if c is _NA:
        return "<td class='na' title='no value: see the note under the table'>n/a</td>"
    m, s, n, mark = c
    text = _fmt(m, s, n, show_n) if stats else _num(m)
    if mark == "published":
        return f"<td class='published' title='{_PUBLISHED_TIP}'>{text}</td>"
    if mark == "best":
        return f"<td class='best'>{text}</td>"
    if mark == "tie":
        return f"<td class='best' title='tied best within the printed precision'>{text} <small>tie</small></td>"
    return f"<td>{text}</td>"


def _same_n(g: _Grid) -> int | None:
    """The one row count every cell of a mean table has (None: they differ, or no cell)."""
    ns = {c[2] for _, cells in g.rows for c in cells if isinstance(c, tuple)}
    return next(iter(ns)) if g.stats and len(ns) == 1 else None


#: the widest a table of the page may be (px); tables are split by columns to stay below it
TABLE_MAX_PX = 1400
#: width estimate of 13 px sans-serif text (px per character, generous) and of a cell's padding and border
_CHAR_PX, _PAD_PX = 7.6, 14.0


def _text_px(text: str, scale: float = 1.0) -> float:
    return len(text) * _CHAR_PX * scale


def _cell_px(c: Any, stats: bool, show_n: bool) -> float:
    """Estimated width of a metric cell on one line (the ``&plusmn;``, ``n`` and ``tie`` in small type)."""
    if c is None:
        return _text_px("-") + _PAD_PX
    if c is _NA:
        return _text_px(_NA) + _PAD_PX
    m, s, n, mark = c
    w = _text_px(_num(m)) * (1.1 if mark else 1.0)  # best: bold
    if stats and n > 1 and s > 0:
        w += _text_px(f" \u00b1 {_spread(s)}", 0.85)
    if stats and n > 1 and show_n:
        w += _text_px(f" (n={n})", 0.85)
    if mark == "tie":
        w += _text_px(" tie", 0.85)
    return w + _PAD_PX


def _header_px(text: str) -> float:
    """A header cell breaks at spaces and after underscores, and is at least 4em wide."""
    pieces = [p for part in text.split() for p in re.split(r"(?<=_)", part) if p]
    return max([52.0] + [_text_px(p, 1.1) for p in pieces]) + _PAD_PX


def _column_widths(g: _Grid) -> tuple[list[float], list[float]]:
    """Estimated widths (px) of the key columns and of the metric columns of ``g``'s HTML table."""
    n = _same_n(g)
    keys = [max([_header_px(k)] + [_text_px(r[0][i]) + _PAD_PX for r in g.rows]) for i, k in enumerate(g.keys)]
    mets = [max([_header_px(_header_text(c))] + [_cell_px(r[1][j], g.stats, n is None) for r in g.rows])
            for j, c in enumerate(g.metrics)]
    return keys, mets


def _column_parts(g: _Grid, budget: float = TABLE_MAX_PX - 80) -> list[list[int]]:
    """The metric columns of ``g`` cut into consecutive groups that, after the key columns, fit
    ``budget`` px (estimated); one group when the whole table fits."""
    keys, mets = _column_widths(g)
    parts: list[list[int]] = [[]]
    used = sum(keys)
    for j, w in enumerate(mets):
        if parts[-1] and used + w > budget:
            parts.append([])
            used = sum(keys)
        parts[-1].append(j)
        used += w
    return parts


def _html_table(g: _Grid) -> str:
    """The table as HTML: numbers never wrap (see the CSS); a table wider than :data:`TABLE_MAX_PX`
    is cut into parts by columns, each repeating the key columns (``data-part='i/n'``,
    ``data-keys``); each part sits in a box that scrolls sideways should it still be wider. A mean
    table whose cells share one n says it once."""
    n = _same_n(g)
    parts = _column_parts(g) if g.metrics else [[]]
    css = f" class='{g.css}'" if g.css else ""
    out = []
    for i, cols in enumerate(parts, 1):
        head = "".join(f"<th>{html.escape(k)}</th>" for k in g.keys) + "".join(_header(g.metrics[j]) for j in cols)
        body = "".join(
            "<tr>" + "".join(f"<td>{html.escape(k)}</td>" for k in keys)
            + "".join(_html_cell(cells[j], g.stats, n is None) for j in cols) + "</tr>"
            for keys, cells in g.rows
        )
        attrs = css
        cap = ""
        if len(parts) > 1:
            attrs += f" data-part='{i}/{len(parts)}' data-keys='{len(g.keys)}'"
            cap = (f"<caption>part {i} of {len(parts)}: columns {cols[0] + 1}-{cols[-1] + 1} of the "
                   f"{len(g.metrics)} values (the same rows)</caption>")
        out.append(f"<div class='tw'><table{attrs}>{cap}<tr>{head}</tr>{body}</table></div>")
    notes = [f"Mean \u00b1 standard deviation over n = {n} row{'s' if n != 1 else ''} per cell."] if n else []
    notes = "".join(f"<p class='note'>{html.escape(x)}</p>" for x in notes + g.notes)
    return "".join(out) + notes


def _csv_text(g: _Grid) -> str:
    """The table as CSV: full-precision values (a mean table: ``COLUMN``, ``COLUMN_std`` and
    ``COLUMN_n`` per metric), ``n/a`` where a method gives no value, empty where it has no such column."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    width = 3 if g.stats else 1
    head = [_printable(k) for k in g.keys]
    for c in g.metrics:
        head += [_printable(c), _printable(f"{c}_std"), _printable(f"{c}_n")] if g.stats else [_printable(c)]
    w.writerow(head)
    for keys, cells in g.rows:
        out = [_printable(k) for k in keys]
        for c in cells:
            if c is None:
                out += [""] * width
            elif c is _NA:
                out += ([_NA, "", "0"] if g.stats else [_NA])
            else:
                out += [repr(float(c[0])), repr(float(c[1])), str(int(c[2]))] if g.stats else [repr(float(c[0]))]
        w.writerow(out)
    return buf.getvalue()


_TEX_ESCAPES = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
                "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}",
                "<": r"\textless{}", ">": r"\textgreater{}", "|": r"\textbar{}", "\u00b1": r"$\pm$",
                "\u2020": r"\dag{}"}


def latex_escape(text: Any) -> str:
    """``text`` as literal LaTeX text (``& % $ # _ { } ~ ^ \\ < > |`` escaped, control characters as ``?``)."""
    s = _printable(str(text).replace("\n", " ").replace("\r", " "))
    return "".join(_TEX_ESCAPES.get(c, c) for c in s)


def _tex_header(name: str) -> str:
    unit = _unit(name)
    text = latex_escape(name) + (f" ({latex_escape(unit)})" if unit else "")
    text += {"higher": r" $\uparrow$", "lower": r" $\downarrow$"}.get(metric_direction(name) or "", "")
    return text + (r"\textsuperscript{\dag}" if rewards_under_segmentation(name) else "")


def _tex_cell(c: Any, stats: bool, show_n: bool) -> str:
    if c is None:
        return "--"
    if c is _NA:
        return _NA
    m, s, n, mark = c
    text = _num(m) if math.isfinite(m) else "--"
    if stats and n > 1 and s > 0:
        text += rf" $\pm$ {_spread(s)}"
    if stats and show_n:
        text += rf" {{\scriptsize (n={n})}}"
    if mark == "published":
        return rf"\textit{{{text}}}"
    if mark == "best":
        return rf"\textbf{{{text}}}"
    if mark == "tie":
        return rf"\textbf{{{text}}}\textsuperscript{{tie}}"
    return text


def _tex_text(g: _Grid) -> str:
    """The table as a booktabs ``tabular`` (``\\usepackage{booktabs}``): the numbers as printed in
    the HTML, best in bold, shared bests marked ``tie``; its notes as a paragraph under it."""
    ns = {c[2] for _, cells in g.rows for c in cells if isinstance(c, tuple)}
    show_n = g.stats and len(ns) > 1
    lines = [f"% {latex_escape(g.title)}", "% written by shape-toolkit bench report; needs \\usepackage{booktabs}",
             f"\\begin{{tabular}}{{{'l' * len(g.keys)}{'r' * len(g.metrics)}}}", r"\toprule",
             " & ".join([latex_escape(k) for k in g.keys] + [_tex_header(c) for c in g.metrics]) + r" \\",
             r"\midrule"]
    for keys, cells in g.rows:
        lines.append(" & ".join([latex_escape(k) for k in keys] + [_tex_cell(c, g.stats, show_n) for c in cells])
                     + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    notes = list(g.notes)
    if g.stats and len(ns) == 1:
        n = next(iter(ns))
        notes.insert(0, f"Mean \u00b1 standard deviation over {n} row{'s' if n != 1 else ''} per cell.")
    marks = {c[3] for _, cells in g.rows for c in cells if isinstance(c, tuple)} - {"", "published"}
    if marks:
        notes.insert(0, "Best in bold" + ("; tie: a best shared within the printed precision." if "tie" in marks
                                          else "."))
    if notes:
        lines += [r"\par\smallskip", r"{\footnotesize " + r" \par ".join(latex_escape(n) for n in notes) + r"\par}"]
    return "\n".join(lines) + "\n"


def _md_escape(text: Any) -> str:
    return _printable(str(text).replace("\n", " ").replace("\r", " ")).replace("|", "\\|")


def markdown_table(columns: list[str], rows: list[list[Any]], *, escape: bool = True) -> list[str]:
    """A GitHub markdown table as lines: the header, the rule and one line per row (each cell ``str()``-ed;
    with ``escape`` the header and cells on one printable line with ``|`` escaped, for text from files,
    errors and user input; without, for cells already formatted as markdown)."""
    fix = _md_escape if escape else str
    return ["| " + " | ".join(fix(c) for c in columns) + " |", "|" + "---|" * len(columns),
            *("| " + " | ".join(fix(c) for c in row) + " |" for row in rows)]


def _md_text(g: _Grid) -> str:
    """The table as GitHub markdown: the numbers as printed in the HTML (mean, std and n of a mean
    table), best in bold, shared bests marked *tie*, published numbers in italics, n/a where a method gives no
    value; its notes under it."""
    def cell(c: Any) -> str:
        if c is None:
            return "-"
        if c is _NA:
            return _NA
        m, sd, n, mark = c
        text = _num(m) if math.isfinite(m) else "-"
        if g.stats and n > 1 and sd > 0:
            text += f" \u00b1 {_spread(sd)}"
        if g.stats and n > 1:
            text += f" (n={n})"
        if mark == "published":  # printed in the thesis, not measured: italic, never best
            return f"*{text}*"
        return f"**{text}**" + (" *tie*" if mark == "tie" else "") if mark in ("best", "tie") else text

    def head(c: str) -> str:
        unit = _unit(c)
        arrow = {"higher": " \u2191", "lower": " \u2193"}.get(metric_direction(c) or "", "")
        dagger = " \u2020" if rewards_under_segmentation(c) else ""
        return _md_escape(c) + (f" ({unit})" if unit else "") + arrow + dagger

    cols = [_md_escape(k) for k in g.keys] + [head(c) for c in g.metrics]
    lines = markdown_table(cols, [[_md_escape(k) for k in keys] + [cell(c) for c in cells] for keys, cells in g.rows],
                           escape=False)
    lines += [""] + [_md_escape(n) + "\n" for n in g.notes]
    return "\n".join(lines) + "\n"


class _Tables:
    """The tables of one report, each written as CSV and LaTeX under fresh names in ``folder`` (a
    name held by a file the report did not write is never reused), each file recorded in ``files``."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.files: list[Path] = []
        self.count = 0
        self.grids: list[_Grid] = []  # in the page's order, for the Markdown summary

    def write(self, g: _Grid, name: str) -> str:
        """Write ``g`` as ``NN-NAME.csv`` and ``.tex``; returns the HTML links to both."""
        self.grids.append(g)
        stem = f"{self.count:02d}-{safe_name(name)}"
        cand, n = stem, 2
        while any(os.path.lexists(self.folder / f"{cand}.{ext}") for ext in ("csv", "tex")):
            cand, n = f"{stem}-{n}", n + 1
        self.count += 1
        links = []
        for ext, text, what in (("csv", _csv_text(g), "CSV"), ("tex", _tex_text(g), "LaTeX (booktabs)")):
            p = self.folder / f"{cand}.{ext}"
            with open(p, "x", encoding="utf-8", newline="") as fh:  # "x": never through a link planted since
                try:
                    fh.write(text)
                except BaseException:
                    p.unlink(missing_ok=True)  # our own half-written file
                    raise
            self.files.append(p)
            links.append(f"<a href='{html.escape('tables/' + p.name)}'>{what}</a>")
        return f"<p class='dl'>This table as {' and '.join(links)}.</p>"


#: the metric a per-category table shows, the first of these a task has
_CATEGORY_METRICS = ("rand_index_error", "mean_geodesic_error", "label_recall", "soft_label_recall",
                     "repeatability@0.05")


def _category_grid(task: str, rows: list[dict]) -> _Grid | None:
    """Mean of the task's main metric per item category (PSB category, animal, subject) and method,
    and the mean over categories (every category weighs the same, as PSB's averages); None when the
    rows have no category or no such metric."""
    ok = [r for r in rows if r.get("status") == "ok" and isinstance(r.get("category"), str)]
    have = {k for r in ok for k, v in r["metrics"].items() if _is_num(v)}
    metric = next((m for m in _CATEGORY_METRICS if m in have), None)
    if metric is None:
        return None
    cats = sorted({r["category"] for r in ok})
    acc: dict = defaultdict(lambda: defaultdict(list))
    for r in ok:
        v = r["metrics"].get(metric)
        if _is_num(v):
            acc[(str(r.get("dataset", "-")), method_id(r), str(r.get("corruption", "none")))][r["category"]].append(v)
    g = _Grid(f"Task {task}: {metric} per category (mean over the category's items)",
              ["dataset", "method", "corruption"], [*cats, "mean of categories"], stats=True)
    for key in sorted(acc):
        per = acc[key]
        cells: list[Any] = [(float(np.mean(per[c])), float(np.std(per[c])), len(per[c]), "") if per.get(c) else None
                            for c in cats]
        means = [float(np.mean(v)) for v in per.values() if v]
        cells.append((float(np.mean(means)), float(np.std(means)), len(means), ""))
        g.rows.append((list(key), cells))
    g.notes.append(f"{metric}: {metric_direction(metric) or 'no direction'} is better; 'mean of categories' "
                   "averages the per-category means, so every category weighs the same.")
    return g


#: the metrics :func:`_pooled_grid` pools (means over scored points: a weighted mean of the rows' is the pooled one)
_POOLED_METRICS = ("within_0.05", "mean_geodesic_error", "mean_geodesic_error_sym")


def _pooled_grid(task: str, rows: list[dict]) -> _Grid | None:
    """Per method and corruption, the task's scored points pooled over every item of every dataset: each of
    :data:`_POOLED_METRICS` as the mean of the rows' values weighted by their ``n_scored`` (a sparse
    matcher's seeds at truth points: ``within_0.05`` becomes correct seeds / seeds), and the total count;
    None when no ok row has ``n_scored``."""
    acc: dict = defaultdict(lambda: defaultdict(lambda: [0.0, 0.0]))
    datasets: set[str] = set()
    for r in rows:
        m = r.get("metrics") or {}
        if r.get("status") != "ok" or not _is_num(m.get("n_scored")):
            continue
        datasets.add(str(r.get("dataset", "-")))
        n, cell = float(m["n_scored"]), acc[(method_id(r), str(r.get("corruption", "none")))]
        cell["n_scored"][0] += n
        for c in _POOLED_METRICS:
            if n > 0 and _is_num(m.get(c)):
                cell[c][0] += n * float(m[c])
                cell[c][1] += n
    if not acc:
        return None
    cols = [c for c in _POOLED_METRICS if any(c in v for v in acc.values())] + ["n_scored"]
    g = _Grid(f"Task {task}: pooled over every item and dataset (each scored point weighs the same)",
              ["dataset", "method", "corruption"], cols, stats=False)
    pooled = next(iter(datasets)) if len(datasets) == 1 else f"all {len(datasets)}"
    for key in sorted(acc):
        cell = acc[key]
        g.rows.append(([pooled, *key], [None if c not in cell else (cell[c][0], 0.0, 1, "") if c == "n_scored"
                                   else (cell[c][0] / cell[c][1], 0.0, 1, "") if cell[c][1] > 0 else _NA
                                   for c in cols]))
    g.notes.append("Pooled: each metric is the mean over all scored points of the method's rows, whatever their item "
                   "or dataset (within_0.05: correct seeds / scored seeds; dataset 'all N': N datasets pooled); "
                   "n_scored is their total. The tables above weigh every item the same instead.")
    return g


def _split_note(run: Path, rows: list[dict]) -> str | None:
    """The one line saying which half of which split the run shows (``RUN/split.json``) and how many of
    its items have rows, or None without a split."""
    from shape_toolkit.bench.config import split_line

    try:
        line = split_line(json.loads((run / SPLIT).read_text(encoding="utf-8")))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    n = len({(r.get("dataset"), r.get("item")) for r in rows})
    return f"{line} Items with rows in this run: {n}." if line else None


def _description(run: Path) -> str | None:
    """The config's ``[run] description`` (``RUN/config.json``), or None."""
    try:
        d = json.loads((run / "config.json").read_text(encoding="utf-8")).get("run", {}).get("description")
    except (OSError, ValueError, AttributeError):
        return None
    return d if isinstance(d, str) and d.strip() else None


def markdown_summary(name: str, tables: list[_Grid], *, command: str | None = None, split: str | None = None,
                     n_rows: int = 0, n_failed: int = 0, description: str | None = None,
                     blas: str | None = None) -> str:
    """The report's tables as one Markdown document: the command that regenerates it first, the config's
    description, the BLAS threads of the rows (``blas``, :func:`blas_summary`), the split line, then every
    table with its notes."""
    lines = [f"# Benchmark report: {_printable(name)}", ""]
    if command:
        lines += ["Regenerate with:", "", f"    {_printable(command)}", ""]
    if description:
        lines += [_printable(description.strip(), keep="\n"), ""]
    from shape_toolkit.bench.worker import code_revision, machine_info, revision_label

    mach = machine_info()
    lines.append(f"{n_rows} rows, {n_failed} failed. Means over items (standard deviation and count where more "
                 "than one); each table is also written as CSV and LaTeX in the report folder. Code when the "
                 f"report was written: {revision_label(code_revision())}. Machine: {mach['cpu']}, {mach['cores']} "
                 f"cores, BLAS {', '.join(mach['blas'])}. Seconds and CPU seconds are the method's own call (a "
                 "published map's: reading its file); spectra come from the run's cache, timed separately, except "
                 "in a spectrum task, where the spectrum is the method.")
    if blas:
        lines.append(f"BLAS threads while the methods ran: {blas}.")
    if split:
        lines += ["", split]
    for g in tables:
        lines += ["", f"## {_printable(g.title)}", "", _md_text(g)]
    return "\n".join(lines).rstrip() + "\n"


def blas_summary(rows: list[dict]) -> str | None:
    """The BLAS threads the rows' methods ran with (``blas_threads`` per row) and how often each ran
    (``repeats``): ``"1 in every row"``, ``"1 (40 rows), 2 (40 rows)"``, with ``"; best of 3 runs"``; None when
    no row recorded it (rows of an older runner)."""
    ok = [r for r in rows if r.get("status") == "ok"]
    counts = Counter(r.get("blas_threads") for r in ok if r.get("blas_threads") is not None)
    if not counts:
        return None
    text = (f"{next(iter(counts))} in every row" if len(counts) == 1 and sum(counts.values()) == len(ok) else
            ", ".join(f"{k} ({v} rows)" for k, v in sorted(counts.items())))
    reps = sorted({int(r.get("repeats") or 1) for r in ok})
    if reps != [1]:
        text += "; timings are the fastest of " + " / ".join(map(str, reps)) + " runs of each row"
    return text


def _mean_grid(task: str, cells: dict, gaps: dict) -> _Grid:
    """Mean and std per (dataset, method, corruption); the best of each column marked (see
    :func:`_ranks`); metrics without a value as n/a, and why, in notes under the table."""
    valued = sorted({c for v in cells.values() for c in v} - set(_ALL_COSTS))
    columns = valued + [c for c in _ALL_COSTS if any(c in v for v in cells.values())]
    g = _Grid(f"Task {task}: mean and standard deviation per method", ["dataset", "method", "corruption"],
              columns, stats=True)
    ranks = {c: _ranks(cells, c) for c in columns}
    notes: dict = defaultdict(set)
    for key in sorted(set(cells) | set(gaps)):
        cols, gap = cells.get(key, {}), gaps.get(key, {})
        row = []
        for c in columns:
            row.append((*cols[c], ranks[c].get(key, "")) if c in cols else _NA if c in gap else None)
        g.rows.append((list(key), row))
        for c, (missing, n, why) in gap.items():
            if c not in valued:
                notes[(c, "absent", why)].add(key[1])
            elif missing == n:
                notes[(c, "na", why)].add(key[1])
            else:
                notes[(c, "partial", why)].add(f"{key[1]} ({missing} of {n} rows)")
    for (c, kind, why), who in sorted(notes.items()):
        who = ", ".join(sorted(who))
        g.notes.append({"absent": f"{c}: not computed for {who} because {why}; no method has a value, so the "
                                  "column is left out.",
                        "na": f"{c}: n/a for {who} because {why}.",
                        "partial": f"{c}: no value for {who} because {why}; the mean is over the other rows."}[kind])
    under = [c for c in columns if rewards_under_segmentation(c)]
    if under:
        g.notes.append(f"\u2020 {', '.join(under)}: {_UNDER_NOTE}.")
    return g


#: a row field that, when rows carry it, splits the long per-item tables into one table per value
SPLIT_FIELD = "category"


def _item_grids(task: str, rows: list[dict], columns: list[str]) -> list[tuple[str | None, _Grid]]:
    """The per-item tables: ``[(None, grid)]``, or one ``(value, grid)`` per value of
    :data:`SPLIT_FIELD` (sorted) when the task's ok rows carry that field (rows without it: ``-``)."""
    ok = [r for r in rows if r.get("status") == "ok"]
    values = sorted({str(r[SPLIT_FIELD]) for r in ok if r.get(SPLIT_FIELD) not in (None, "")})
    if not values:
        g = _item_grid(task, ok, columns)
        return [] if g is None else [(None, g)]
    out = []
    for v in values + (["-"] if any(r.get(SPLIT_FIELD) in (None, "") for r in ok) else []):
        sel = [r for r in ok if (str(r.get(SPLIT_FIELD)) if r.get(SPLIT_FIELD) not in (None, "") else "-") == v]
        g = _item_grid(task, sel, columns)
        if g is not None:
            g.title += f", {SPLIT_FIELD} {v}"
            out.append((v, g))
    return out


_PUBLISHED_TIP = "published in the thesis, on its own shapes: not measured here, never best"


def _add_published(g: _Grid, tables: tuple[str, ...]) -> None:
    """The thesis's printed numbers of ``tables`` (:mod:`shape_toolkit.bench.published`) as rows under the
    measured ones: marked ``published`` (never best; no aggregate reads the grid), columns only the
    thesis prints added before the cost columns, and a note saying what the rows are."""
    from shape_toolkit.bench.published import PUBLISHED_LABEL, published_tables, reference_rows

    refs = [r for t in tables for r in reference_rows(t)]
    if not refs:
        return
    extra = [c for r in refs for c in r.cells if c not in g.metrics]
    extra = list(dict.fromkeys(extra))
    if extra:
        at = g.metrics.index("seconds") if "seconds" in g.metrics else len(g.metrics)
        g.metrics[at:at] = extra
        g.rows = [(keys, cells[:at] + [None] * len(extra) + cells[at:]) for keys, cells in g.rows]
    for r in refs:
        g.rows.append(([r.dataset, r.method, r.corruption],
                       [(*r.cells[c], "published") if c in r.cells else None for c in g.metrics]))
    info = published_tables()
    for t in tables:
        tab = info[t]
        g.notes.append(f"Rows '{PUBLISHED_LABEL}: ...' are the numbers printed in the thesis's {t} (section "
                       f"{tab.section}, line {tab.line} of its text), measured on {tab.data}: not measured here, "
                       "never marked best, left out of every summary; mean (and standard deviation) over the "
                       "thesis's shapes.")
    if extra:
        g.notes.append(f"{', '.join(extra)}: printed by the thesis only; no measured method has this column.")


def _item_grid(task: str, rows: list[dict], columns: list[str]) -> _Grid | None:
    """Per-item values of every scalar metric (None when the task has no ok row)."""
    ok = [r for r in rows if r.get("status") == "ok"]
    if not ok:
        return None
    g = _Grid(f"Task {task}: per-item values", ["dataset", "item", "method", "corruption"], columns, stats=False)
    for r in sorted(ok, key=lambda r: (str(r.get("dataset")), str(r.get("item")), method_id(r),
                                        str(r.get("corruption")))):
        m = r["metrics"]
        cells = []
        for c in columns:
            v = r.get(c) if c in _ALL_COSTS else m.get(c)
            cells.append((float(v), 0.0, 1, "") if _is_num(v) else _NA if c in m and _no_value(v) else None)
        g.rows.append(([str(r.get("dataset", "-")), str(r.get("item")), method_id(r),
                        str(r.get("corruption", "none"))], cells))
    if any(rewards_under_segmentation(c) for c in columns):
        g.notes.append(f"\u2020 {', '.join(c for c in columns if rewards_under_segmentation(c))}: {_UNDER_NOTE}.")
    return g


def _failed_grid(failed: list[dict]) -> _Grid:
    g = _Grid("Failed rows", ["task", "method", "item", "corruption", "error"], [], stats=False, css="failed")
    for r in failed:
        g.rows.append(([str(r.get("task_name")), method_id(r), str(r.get("item")), str(r.get("corruption")),
                        str(r.get("error"))], []))
    return g


def _summary_section(summ: dict, tasks: list[str], rows: list[dict], gaps: dict | None = None) -> str:
    """The first section: per task and dataset, each directed metric's best method (uncorrupted
    rows when there are any), with its value; ties named, no best where all methods agree, and the
    metrics no method has a value of named (``gaps``: see :func:`_gaps`)."""
    out = []
    for task in tasks:
        cells = summ.get(task, {})
        task_gaps = (gaps or {}).get(task, {})
        kind = next((r.get("task_kind", "") for r in rows if r["task_name"] == task), "")
        for ds in sorted({k[0] for k in cells}):
            sub = {k: v for k, v in cells.items() if k[0] == ds}
            corr = "none" if any(k[2] == "none" for k in sub) else sorted({k[2] for k in sub})[0]
            sub = {k: v for k, v in sub.items() if k[2] == corr}
            none_have = defaultdict(set)  # metrics named by rows of this group that no method has a value of
            for k, cols in task_gaps.items():
                if k[0] == ds and k[2] == corr:
                    for c in cols:
                        if not any(c in v for v in sub.values()):
                            none_have[c].add(k[1])
            methods = sorted({k[1] for k in sub})
            cols = sorted({c for v in sub.values() for c in v if metric_direction(c)} - set(_ALL_COSTS))
            items = []
            for c in cols:
                under = "; rewards under-segmentation" if rewards_under_segmentation(c) else ""
                head = f"<li><b>{html.escape(c)}</b> ({metric_direction(c)} is better{under}): "
                have = sorted((k[1], v[c][0]) for k, v in sub.items() if c in v)
                ranks = _ranks(sub, c)
                if len(methods) == 1 or len(have) == 1:  # nothing to rank: the value, with its direction
                    who = "" if len(methods) == 1 else f"only {html.escape(have[0][0])} has a value: "
                    items.append(f"{head}{who}{_num(have[0][1])}</li>")
                elif not ranks:
                    items.append(f"{head}no best: all {len(have)} methods give {_num(have[0][1])}</li>")
                else:
                    names = ", ".join(sorted({k[1] for k in ranks}))
                    tie = "tie: " if len(ranks) > 1 else ""
                    val = _num(sub[next(iter(ranks))][c][0])
                    items.append(f"{head}<span class='best'>{tie}{html.escape(names)}</span> {val}</li>")
            for c, who in sorted(none_have.items()):
                items.append(f"<li><b>{html.escape(c)}</b>: n/a for {html.escape(', '.join(sorted(who)))} "
                             "(no value; see the note under the table)</li>")
            what = f"{len(methods)} method{'s' if len(methods) != 1 else ''}: {', '.join(methods)}"
            body = (f"<ul>{''.join(items)}</ul>" if items
                    else "<p>no metric with a better direction here; see the table below.</p>")
            out.append(f"<h3>{html.escape(task)} ({html.escape(kind)}) on {html.escape(ds)}, "
                       f"corruption {html.escape(corr)}</h3><p>{html.escape(what)}</p>{body}")
    return ("<h2>Summary</h2><p>Best method per metric (&uarr; higher is better, &darr; lower is better; "
            "best values are <span class='best'>highlighted</span> in every table). A best shared within the "
            "printed precision is marked &ldquo;tie&rdquo;; a column where all methods agree (memory: within 1 MB) "
            "has no best; n/a: the method gives no value of that metric (see the notes under the tables). "
            "Every table is also written as CSV and LaTeX (booktabs), every figure also as PDF.</p>"
            + "".join(out))


#: row fields the report shows as text (the reader accepts a string, or null where noted in the store)
_TEXT_FIELDS = {"run_name": None, "task_name": "", "task_kind": "", "dataset": "-", "item": "", "plugin": "",
                "family": "", "method_label": "", "corruption": "none", "corruption_kind": "none",
                "corruption_group": "none", "error": "", "key": "", SPLIT_FIELD: None}


def _normalized(row: dict) -> dict:
    """``row`` with every text field the report shows as a string (a missing or null field as its
    default), so no figure or table meets a number, a list or null where it expects text."""
    r = dict(row)
    for k, default in _TEXT_FIELDS.items():
        v = r.get(k)
        if v is None:
            if default is None:
                r.pop(k, None)
            else:
                r[k] = default
        elif not isinstance(v, str):
            r[k] = json.dumps(v, sort_keys=True, default=str)
    if not isinstance(r.get("metrics"), dict):
        r["metrics"] = {}
    fam = r.get("family")
    if any((fam, k) in _CANNOT for k in r["metrics"]):  # whatever the row holds: no value (n/a), never a score
        r["metrics"] = {k: None if (fam, k) in _CANNOT else v for k, v in r["metrics"].items()}
    return r


def _printable(text: Any, keep: str = "") -> str:
    """``text`` with unencodable characters (lone surrogates) and control characters (but those in
    ``keep``) replaced by ``?``: safe for a terminal, a font and UTF-8."""
    s = str(text).encode("utf-8", "replace").decode("utf-8")
    return "".join(c if c.isprintable() or c in keep else "?" for c in s)


def _t(text: Any) -> str:
    """``text`` for a figure, shown literally: ``$`` escaped (no mathtext, so a label like
    ``$\\frac{a$`` cannot break the layout), see also :func:`_printable` (newlines kept)."""
    return _printable(text, "\n").replace("$", r"\$")


def _legend(text: Any) -> str:
    """:func:`_t` for a legend entry (matplotlib hides empty labels and those that start with ``_``)."""
    s = _t(text)
    if not s.strip():
        return "(empty)"
    return " " + s if s.startswith("_") else s


@contextmanager
def _literal_figure_text() -> Iterator[None]:
    """Figure text is plain text: no LaTeX (whatever the user's matplotlibrc says) and no warnings
    about glyphs the font lacks (a user's label may hold any character) or about overflow (a row
    may hold any finite number; such values show as infinite or off the axes)."""
    import matplotlib

    with matplotlib.rc_context({"text.usetex": False}), warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.filterwarnings("ignore", message=r"Glyph .* missing from", category=UserWarning)
        yield


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False) if matplotlib.get_backend().lower() != "agg" else None
    import matplotlib.pyplot as plt

    return plt


_AXES = {  # curve metric -> (x label, y label, log x)
    "geodesic_error_curve": ("geodesic error (units of sqrt(area))", "fraction of correspondences within", False),
    "repeatability_curve": ("radius r (units of sqrt(area))", "repeatability (fraction of keypoints)", False),
    "chance_curve": ("radius r (units of sqrt(area))", "chance repeatability (fraction)", False),
    "alpha_vs_t": ("diffusion time t", "alpha(K, t)", True),
    "alpha_vs_K": ("K (% of computed eigenpairs)", "alpha(K, t)", False),
    "eigenvalues": ("eigenvalue index", "eigenvalue (1 / length^2)", False),
    "r_smoothness_curve": ("neighbourhood size r (% of the vertices)", "r-smooth source vertices (%)", False),
    "drift_curve": ("frame", "mean drift (units of sqrt(area))", False),
    "within_curve": ("frame", "fraction of trajectories within the radius", False),
}


def _axes_for(metric: str) -> tuple[str, str, bool]:
    for key, lab in _AXES.items():
        if key in metric:
            return lab
    return ("x", metric.replace("_", " "), False)


def _style(ax, values: list[float] | np.ndarray) -> None:
    """Readable axes: no offset notation, at most 6 ticks, and a constant series drawn on an honest
    axis (its value in the middle of a range that includes zero) instead of a fake +-4% zoom."""
    from matplotlib.ticker import MaxNLocator, ScalarFormatter

    fmt = ScalarFormatter(useOffset=False)
    fmt.set_scientific(True)
    fmt.set_powerlimits((-3, 4))
    ax.yaxis.set_major_formatter(fmt)
    ax.xaxis.set_major_locator(MaxNLocator(nbins=6))
    ax.yaxis.set_major_locator(MaxNLocator(nbins=6))
    ax.tick_params(labelsize=10)
    ax.grid(alpha=0.3)
    v = np.asarray([x for x in np.ravel(values) if np.isfinite(x)], dtype=float)
    if v.size and np.ptp(v) <= 1e-12 * max(1.0, abs(float(v[0]))):
        c = float(v[0])
        lo, hi = (min(0.0, 2 * c), max(0.0, 2 * c)) if c != 0 else (-1.0, 1.0)
        ax.set_ylim(lo, hi)
        ax.text(0.02, 0.95, f"constant: {_num(c)}", transform=ax.transAxes, va="top", fontsize=10)


def _grid(plt, n: int, width: float = 12.0, height: float = 4.2, max_cols: int = 3):
    ncol = min(max_cols, max(n, 1))
    nrow = math.ceil(n / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(width, height * nrow), squeeze=False, layout="constrained")
    for ax in axes.ravel()[n:]:
        ax.set_axis_off()
    return fig, axes


def _title(text: str, width_in: float = 12.0, fontsize: float = 12) -> str:
    import textwrap

    return "\n".join(textwrap.wrap(text, max(20, int(width_in * 72 / (0.55 * fontsize)))))


_DASHES = ("-", "--", ":", "-.")


def _curve_figs(task: str, rows: list[dict], figs: _Figs, dataset: str | None = None,
                colors: dict | None = None) -> list[str]:
    """Curve metrics per method (mean over items, band min..max): one panel per corruption group,
    every compared method (and peer) on the same axes, in its colour of the report (``colors``:
    method id -> RGB) and one line style per corruption; one figure per metric and dataset."""
    colors = colors if colors is not None else {}
    plt = _plt()
    parts = []
    curves: dict = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    for r in rows:
        if r.get("status") != "ok" or r["task_name"] != task:
            continue
        if dataset is not None and str(r.get("dataset", "-")) != dataset:
            continue
        g = str(r.get("corruption_group") or "none")
        for k, v in (r.get("metrics") or {}).items():
            if _is_curve(v):
                curves[k][g][(method_id(r), r.get("corruption", "none"))].append(np.asarray(v, dtype=float))
    for metric, by_group in sorted(curves.items()):
        groups = sorted(by_group, key=lambda g: (g != "none", g))
        fig, axes = _grid(plt, len(groups))
        xl, yl, logx = _axes_for(metric)
        for ax, g in zip(axes.ravel(), groups):
            ys = []
            styles = {c: _DASHES[i % len(_DASHES)] for i, c in enumerate(sorted({c for _, c in by_group[g]}))}
            for (mid, corr), cs in sorted(by_group[g].items()):
                L = min(len(c) for c in cs)
                arr = np.stack([c[:L] for c in cs])
                x, y = arr[0, :, 0], arr[:, :, 1].mean(axis=0)
                ys.extend(arr[:, :, 1].ravel())
                label = mid if corr == "none" else f"{mid} {corr[len(g):]}".strip()
                marker = "o" if len(x) <= 12 else None  # few points: marked
                ax.plot(x, y, linestyle=styles[corr], marker=marker, ms=4, lw=1.8, color=colors.get(mid),
                        label=_legend(label[:48]))
                if len(cs) > 1:
                    ax.fill_between(x, arr[:, :, 1].min(axis=0), arr[:, :, 1].max(axis=0), alpha=0.12,
                                    color=colors.get(mid))
            ax.set_title("uncorrupted" if g == "none" else _t(f"corruption: {g}"), fontsize=11)
            if logx:
                ax.set_xscale("log")
            ax.set_xlabel(_t(xl), fontsize=10)
            ax.set_ylabel(_t(yl), fontsize=10)
            _style(ax, ys)
            ax.legend(fontsize=9, loc="best")
        where = f" on {dataset}" if dataset else ""
        fig.suptitle(_t(_title(f"{task}{where}: {metric} (mean over items; band = min..max)")), fontsize=12)
        name = f"{task}-{dataset}-{metric}" if dataset else f"{task}-{metric}"
        parts.append(_img(figs.save(fig, name), f"{task}{where}: {metric}"))
    return parts


def _strength_figs(task: str, rows: list[dict], figs: _Figs, dataset: str | None = None,
                   colors: dict | None = None) -> list[str]:
    """One figure per corruption group: a panel per scalar metric, metric vs strength per method
    (each in its colour of the report, ``colors``: method id -> RGB)."""
    plt = _plt()
    colors = colors if colors is not None else {}
    parts = []
    ok = [r for r in rows if r.get("status") == "ok" and r["task_name"] == task
          and (dataset is None or str(r.get("dataset", "-")) == dataset)]
    groups = sorted({r.get("corruption_group") for r in ok} - {"none", None})
    metrics = sorted({k for r in ok for k, v in (r.get("metrics") or {}).items() if _is_num(v)})
    for g in groups:
        sel = [r for r in ok if r.get("corruption_group") in (g, "none") and _is_num(r.get("strength"))]
        if len({r["strength"] for r in sel}) < 2 or not metrics:
            continue
        fig, axes = _grid(plt, len(metrics), height=3.4, max_cols=4)
        for ax, metric in zip(axes.ravel(), metrics):
            by: dict = defaultdict(lambda: defaultdict(list))
            for r in sel:
                v = (r.get("metrics") or {}).get(metric)
                if _is_num(v):
                    by[method_id(r)][r["strength"]].append(v)
            ys = []
            for mid, pts in sorted(by.items()):
                xs = sorted(pts)
                ys.extend(v for x in xs for v in pts[x])
                ax.errorbar(xs, [np.mean(pts[x]) for x in xs], yerr=[np.std(pts[x]) for x in xs],
                            marker="o", ms=4, capsize=3, color=colors.get(mid), label=_legend(mid))
            d = metric_direction(metric)
            under = ", rewards under-segmentation" if rewards_under_segmentation(metric) else ""
            ax.set_title(_t(f"{metric}" + (f" ({d} is better{under})" if d else "")), fontsize=10)
            ax.set_xlabel(_t(f"{g} strength (0 = uncorrupted)"), fontsize=9)
            _style(ax, ys)
        handles, labels = axes.ravel()[0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="outside lower center", ncol=min(4, max(1, len(labels))), fontsize=10)
        where = f" on {dataset}" if dataset else ""
        fig.suptitle(_t(_title(f"{task}{where}: metrics versus {g} strength (mean and std over items)")), fontsize=12)
        fname = f"{task}-{dataset}-vs-{g}" if dataset else f"{task}-vs-{g}"
        parts.append(_img(figs.save(fig, fname), f"{task}{where}: metrics versus {g} strength"))
    return parts


def _cost_fig(task: str, cells: dict, figs: _Figs, colors: dict | None = None) -> list[str]:
    """Mean run time and peak memory per method, one bar per method in its colour of the report."""
    plt = _plt()
    colors = colors if colors is not None else {}
    by: dict = defaultdict(lambda: {"seconds": [], "peak_memory_mb": []})
    for (_ds, mid, _corr), cols in cells.items():
        for c in ("seconds", "peak_memory_mb"):
            if c in cols:
                by[mid][c].append(cols[c][0])
    if not by:
        return []
    names = sorted(by)
    fig, axes = plt.subplots(1, 2, figsize=(12, 1.2 + 0.45 * len(names)), layout="constrained", sharey=True)
    for ax, c, unit in zip(axes, ("seconds", "peak_memory_mb"), ("s", "MB")):
        vals = [float(np.mean(by[n][c])) if by[n][c] else 0.0 for n in names]
        ax.barh(range(len(names)), vals, color=[colors.get(n, "tab:blue") for n in names])
        ax.set_yticks(range(len(names)), [_t(n[:40]) for n in names], fontsize=10)
        what = "run time" if c == "seconds" else "peak memory growth"
        ax.set_xlabel(f"mean {what} per row ({unit}), lower is better", fontsize=10)
        ax.tick_params(labelsize=10)
        ax.grid(alpha=0.3, axis="x")
    fig.suptitle(_t(f"{task}: runtime and peak memory per method"), fontsize=12)
    return [_img(figs.save(fig, f"{task}-cost"), f"{task}: runtime and memory per method")]


def _render_rows(run: Path, task_rows: list[dict], figs: _Figs, n: int, up: str = "auto") -> list[str]:
    """Up to ``n`` rendered results (one per method), each shape upright by the ``up`` rule of
    :func:`shape_toolkit.viz.upright_frame` and cropped tight."""
    from shape_toolkit.viz import align_labels, pullback_colors, render_shapes

    parts = []
    done_methods: set[str] = set()
    for r in task_rows:
        if len(done_methods) >= n:
            break
        if r.get("status") != "ok" or not r.get("output") or method_id(r) in done_methods:
            continue
        if not isinstance(r.get("prepare_key"), str):
            continue
        ppath = prepared_path(run, r["prepare_key"])
        if not ppath.exists():
            continue
        try:
            prep = load_prepared(ppath, key=r["prepare_key"])  # npz, validated; never pickle
            out = load_output(run, r["output"], key=r.get("key"))
            title = f"{r['task_name']}: {method_id(r)} on {r['item']} ({r.get('corruption', 'none')})"
            kind = r.get("task_kind")
            if kind == "segmentation" and "labels" in out:
                labels = np.asarray(out["labels"])
                if prep.target_labels:  # the result in the ground truth's palette (Hungarian method)
                    truth = np.asarray(prep.target_labels[0])
                    shown = align_labels(labels, truth, prep.target.vertex_areas if prep.target.is_mesh else None)
                    panels = [{"shape": prep.target, "labels": truth, "title": "ground truth"},
                              {"shape": prep.target, "labels": shown,
                               "title": f"result ({len(np.unique(labels))} segments, colours matched to the truth)"}]
                else:
                    panels = [{"shape": prep.target, "labels": labels, "title": "result"}]
            elif kind == "keypoints" and "keypoints" in out:
                panels = [
                    {"shape": prep.source, "points": out["source_keypoints"], "title": "source"},
                    {"shape": prep.target, "points": out["keypoints"], "title": "target"},
                ]
            elif kind == "matching" and "target_of" in out:
                cs, ct = pullback_colors(prep.source, prep.target, out["target_of"])
                panels = [
                    {"shape": prep.target, "colors": ct, "title": "target: colour = position"},
                    {"shape": prep.source, "colors": cs, "title": "source: target colours pulled back through the map"},
                ]
            else:
                continue
            figs.say(f"figure {len(figs.files) + 1}: render of {method_id(r)} on {r['item']}")
            p = figs.fresh(f"render-{r['key']}")
            for path in (p, p.with_suffix(".pdf")):  # the same matplotlib figure, as PNG and as PDF
                render_shapes(panels, path, panel_size=4.0, max_width=12.0, dpi=100, title=_t(title), up=up)
            figs.files.append(p)
            figs.vector.append(p.with_suffix(".pdf"))
            parts.append(_img(p, title))
            done_methods.add(method_id(r))
        except Exception as exc:  # a broken output must not break the report
            parts.append(
                f"<p class='err'>could not render {html.escape(r['key'])}: {html.escape(str(exc))}</p>"
            )
    return parts


def report_colors(rows: list[dict]) -> dict[str, tuple[float, float, float]]:
    """The colour of each method of a report (method id -> RGB in [0, 1]), used by every figure of
    it: :func:`shape_toolkit.viz.method_colors` of all the ok rows' method ids."""
    from shape_toolkit.viz import method_colors

    return method_colors(method_id(r) for r in rows if r.get("status") == "ok")


def _spectra_list(rows: list[dict]) -> str:
    """The spectra each method received (as its rows record them)."""
    seen: dict[str, list[str]] = {}
    for r in rows:
        specs = r.get("spectra") if isinstance(r.get("spectra"), list) else []
        text = "; ".join(
            ", ".join(f"{k}={v}" for k, v in s.items()) for s in specs if isinstance(s, dict)
        ) or "none"
        seen.setdefault(method_id(r), [])
        if text not in seen[method_id(r)]:
            seen[method_id(r)].append(text)
    items = "".join(
        f"<li>{html.escape(m)}: {html.escape(' | '.join(t))}</li>" for m, t in sorted(seen.items())
    )
    return f"<p>Spectra the methods received:</p><ul>{items}</ul>"


def _prepare_section(run: Path, rows: list[dict]) -> str:
    preps = read_prepare_log(run)
    if not preps:
        return ""
    comp = [
        s for p in preps for s in p.get("spectra", [])
        if isinstance(s, dict) and _is_num(s.get("seconds")) and not s.get("cache_hit")
    ]
    spec_total = sum(s["seconds"] for s in comp)
    geo_total = sum(p["geodesic_seconds"] for p in preps if _is_num(p.get("geodesic_seconds")))
    cor_total = sum(p["corruption_seconds"] for p in preps if _is_num(p.get("corruption_seconds")))
    looked = [r for r in rows if _is_num(r.get("spectrum_seconds")) and r.get("task_kind") != "spectrum"]
    hits = sum(bool(r.get("spectrum_cache_hit")) for r in looked)
    look_total = sum(r["spectrum_seconds"] for r in looked)
    avg = spec_total / len(comp) if comp else 0.0
    saved = (f"; computing them per row would have cost about {avg * len(looked):.1f} s" if comp else "")
    return (
        "<h2>Shared precomputation (once per item and corruption)</h2>"
        f"<p>{len(preps)} prepare jobs computed {len(comp)} spectra in {spec_total:.2f} s "
        f"(mean {avg:.3f} s each), geodesic rows for evaluation in {geo_total:.2f} s and corruptions in "
        f"{cor_total:.2f} s. The {len(looked)} method rows then obtained their spectra from the cache "
        f"({hits} hits) in {look_total:.2f} s in total{saved}.</p>"
    )


_CSS = (
    "body{font-family:sans-serif;margin:1.5em auto;max-width:1400px;padding:0 1em;line-height:1.4}"
    "div.tw{max-width:min(100%,1400px);overflow-x:auto;margin:.5em 0 1.5em}div.tw+div.tw{margin-top:-.8em}"
    "caption{caption-side:top;text-align:left;font-size:12px;color:#555;padding:2px 0}"
    "table{border-collapse:collapse;font-size:13px}"
    "td,th{border:1px solid #ccc;padding:3px 6px;text-align:right;white-space:nowrap}"
    "th{white-space:normal;min-width:4em;vertical-align:bottom}"
    "h3.cat{font-size:14px;margin:.8em 0 .2em}"
    "td:nth-child(-n+3){text-align:left}th{background:#eee}"
    "td.best,span.best{background:#d8f5d0;font-weight:bold}"
    "td.published{font-style:italic;color:#555;background:#f4f4f4}"
    "figure{display:block;margin:.8em 0}figure img{max-width:100%;height:auto}"
    "figcaption{font-size:12px;color:#555}.err{color:#a00}small{color:#777}"
    "details{margin:.3em 0 1.5em}summary{cursor:pointer;color:#225}"
    "td.na{color:#777;font-style:italic}table.failed td{text-align:left;white-space:normal}"
    "p.note{font-size:12px;color:#444;margin:-1em 0 .4em;max-width:1200px}p.note+p.note{margin-top:0}"
    "p.dl{font-size:12px;margin:-.8em 0 1.5em}p.note+p.dl{margin-top:.3em}"
)


#: the report folder's record of the files ``write_report`` wrote there (the only files it ever
#: replaces or deletes), with their SHA-256: ``{"generator": ..., "files": {relative path: digest}}``
MANIFEST = ".bench-report.json"
_GENERATOR = "shape-toolkit bench report"
_OWNABLE = re.compile(r"index\.html|figures/[A-Za-z0-9._-]+\.(?:png|pdf)|tables/[A-Za-z0-9._-]+\.(?:csv|tex)")


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _regular(path: Path) -> bool:
    return path.is_file() and not path.is_symlink()


def _legacy_page(path: Path) -> bool:
    """An ``index.html`` written by a report of before the manifest (recognised by its first bytes)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096)
    except OSError:
        return False
    return head.startswith(b"<!DOCTYPE html><html><head><meta charset='utf-8'><title>") and (
        b"<h1>Benchmark report: " in head
    )


def _owned_files(out: Path) -> dict[str, str]:
    """The files of ``out`` a previous report wrote and nobody changed since: ``{relative path:
    digest}`` from the manifest, each still a regular file with its recorded digest.
    :class:`ParameterError` when a manifest is there but is not one."""
    path = out / MANIFEST
    if not os.path.lexists(path):
        return {}
    try:
        if not _regular(path):
            raise ValueError("not a regular file")
        data = json.loads(path.read_text(encoding="utf-8"))
        if not isinstance(data, dict) or data.get("generator") != _GENERATOR or not isinstance(data.get("files"), dict):
            raise ValueError("not a report manifest")
    except (OSError, ValueError) as exc:
        raise ParameterError(
            f"{path} exists and was not written by bench report ({exc}); choose another report folder"
        ) from None
    owned = {}
    for rel, digest in data["files"].items():
        if not (isinstance(rel, str) and isinstance(digest, str) and _OWNABLE.fullmatch(rel)):
            continue
        f = out / rel
        try:
            if _regular(f) and _digest(f) == digest:
                owned[rel] = digest
        except OSError:
            continue
    return owned


def check_report_output(out: str | os.PathLike) -> dict[str, str]:
    """Check, before any work and without writing, that a report may be written into the folder
    ``out``: absent or a folder whose ``index.html`` and manifest, when present, were written by a
    report (:class:`ParameterError` otherwise). Returns the files it owns there (relative path ->
    digest); nothing else in ``out`` is ever replaced or deleted."""
    out = Path(out)
    if os.path.lexists(out) and not out.is_dir():
        raise ParameterError(f"report folder {out} exists and is not a folder; choose another -o")
    page = out / "index.html"
    owned = _owned_files(out)
    if os.path.lexists(page) and "index.html" not in owned and not (_regular(page) and _legacy_page(page)):
        raise ParameterError(
            f"{page} exists and was not written by bench report; choose another report folder "
            "(the report never replaces a file it did not write)"
        )
    for sub in ("figures", "tables"):
        folder = out / sub
        if os.path.lexists(folder) and not folder.is_dir():
            raise ParameterError(f"{folder} exists and is not a folder; choose another report folder")
    return owned


def _write_manifest(out: Path, files: list[Path]) -> None:
    """Record ``files`` (inside ``out``) as the report's own, atomically."""
    rec = {}
    for f in files:
        if _regular(f):
            rec[f.relative_to(out).as_posix()] = _digest(f)
    tmp = out / f".{MANIFEST}.tmp"
    tmp.write_text(json.dumps({"generator": _GENERATOR, "files": rec}, indent=1), encoding="utf-8")
    os.replace(tmp, out / MANIFEST)



def write_report(
    run_dir: str | os.PathLike,
    *,
    output: str | os.PathLike | None = None,
    renders: int = 3,
    progress: Callable[[str], None] | None = None,
    markdown: str | os.PathLike | None = None,
    command: str | None = None,
    up: str = "auto",
) -> dict:
    """Write ``index.html`` (self-contained) with its figures (PNG, and PDF) and tables (CSV and
    LaTeX) for a run folder; ``progress`` receives one line per step (task, figure group); ``up``:
    the rule that stands rendered shapes upright (:func:`shape_toolkit.viz.upright_frame`). Returns
    ``{"html": path, "figures": [PNG paths], "vector_figures": [PDF paths], "tables": [CSV and TeX paths]}``.

    The report replaces or deletes only files it wrote itself (listed with their digests in
    ``OUTPUT/.bench-report.json``); a file it did not write is never touched: an ``index.html`` of
    someone else is a :class:`ParameterError` before any work, other names are avoided. With ``markdown``,
    the tables are also written there as one Markdown file (:func:`markdown_summary`), headed by
    ``command`` (the command line that regenerates it)."""
    def say(msg: str) -> None:  # names from the rows: no control characters on a terminal
        if progress is not None:
            progress(_printable(msg))

    from shape_toolkit.viz import UP_RULES

    if up not in UP_RULES:
        raise ParameterError(f"up must be one of {', '.join(UP_RULES)}, got {up!r}")
    if isinstance(renders, bool) or not isinstance(renders, int) or renders < 0:
        raise ParameterError(f"renders must be an integer >= 0 (shapes rendered per task; 0: none), got {renders!r}")
    run = Path(run_dir)
    if not (run / RESULTS).exists():
        raise ParameterError(f"{run} is not a run folder: {RESULTS} not found (run 'bench run' first)")
    out = Path(output) if output else run / "report"
    owned = check_report_output(out)  # before any work
    every = read_rows(run)  # read once: the rows an earlier config left are counted, not shown
    if not every:  # an empty folder, or every line invalid (skipped with a warning): no empty page
        raise ParameterError(f"{run / RESULTS} holds no valid row: nothing to report (run 'bench run' first)")
    say(f"read {len(every)} rows of {run / RESULTS}")
    (out / "figures").mkdir(parents=True, exist_ok=True)
    (out / "tables").mkdir(exist_ok=True)
    rows = [_normalized(r) for r in only_planned(every, run)]
    stale = len(every) - len(rows)
    if stale:
        say(f"{stale} rows of an earlier config of this folder are not shown (planned.json)")
    for rel in owned:  # the previous report's figures and tables (still as it wrote them)
        if rel.startswith(("figures/", "tables/")):
            (out / rel).unlink(missing_ok=True)
    figs = _Figs(out / "figures", say)
    tables = _Tables(out / "tables")
    path = out / "index.html"
    written: list[Path] = [path] if "index.html" in owned else []
    try:
        with _literal_figure_text():
            page = _page(run, out, rows, figs, tables, renders, say, up, stale)
        tmp = out / ".index.html.tmp"
        tmp.write_text(page, encoding="utf-8", errors="replace")
        os.replace(tmp, path)
        written = [path]
    finally:
        _write_manifest(out, written + figs.files + figs.vector + tables.files)
    if markdown is not None:
        text = markdown_summary(rows[0].get("run_name", run.name) if rows else run.name, tables.grids,
                                command=command, split=_split_note(run, rows), n_rows=len(rows),
                                n_failed=sum(r.get("status") != "ok" for r in rows), description=_description(run),
                                blas=blas_summary(rows))
        with atomic_output(markdown, "Markdown report") as tmp:
            tmp.write_text(text, encoding="utf-8")
        say(f"wrote {markdown}")
    say(f"wrote {path} ({len(figs.files)} figures, {len(tables.files) // 2} tables as CSV and LaTeX)")
    return {"html": path, "figures": list(figs.files), "vector_figures": list(figs.vector),
            "tables": list(tables.files), "markdown": markdown}


def _published_of(run: Path) -> dict[str, tuple[str, ...]]:
    """``{task name: published table ids}`` from the run's ``config.json`` (none when unreadable)."""
    from shape_toolkit.bench.published import task_references

    try:
        raw = json.loads((run / "config.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return task_references(raw)


def _page(run: Path, out: Path, rows: list[dict], figs: _Figs, tables: _Tables, renders: int,
          say: Callable[[str], None], up: str = "auto", stale: int = 0) -> str:
    """The HTML page of the report (its figures saved through ``figs``, its tables through ``tables``)."""
    summ = summarize(rows)
    gaps = _gaps(rows)
    n_ok = sum(r.get("status") == "ok" for r in rows)
    failed = [r for r in rows if r.get("status") != "ok"]
    name = rows[0].get("run_name", run.name) if rows else run.name
    versions = next((r.get("versions") for r in rows if r.get("versions")), {})
    tasks = list(dict.fromkeys(r["task_name"] for r in rows))
    colors = report_colors(rows)
    published = _published_of(run)
    say(f"{len(rows)} rows, {len(tasks)} tasks -> {out / 'index.html'}")
    parts = [
        f"<h1>Benchmark report: {html.escape(str(name))}</h1>",
        f"<p>{len(rows)} rows: {n_ok} ok, {len(failed)} failed. "
        f"Run folder: <code>{html.escape(str(run.resolve()))}</code>.</p>",
        *([f"<p class='split'>{html.escape(split)}</p>"] if (split := _split_note(run, rows)) else []),
        *([f"<p class='note'>{stale} rows in this folder come from an earlier config (keys its last config does not "
           "plan) and are not shown.</p>"] if stale else []),
        _summary_section(summ, tasks, rows, gaps),
        "<p>Seconds are the method's own call (spectra come from the shared cache, timed separately); "
        "peak memory is the resident-set growth during that call (MB). Each dataset is reported on its "
        "own rows; values are mean &plusmn; standard deviation over items. Every method has one colour in all "
        "the figures. Rendered shapes are upright: from their area-weighted principal axes, up is the "
        + {"longest": "longest axis, the heavier end up", "middle": "middle axis (the longest is horizontal), the "
           "heavier end up"}.get(up, "longest axis, or the middle one when the shape stands on legs across the "
                                     "longest (its end slabs differ by two or more separate pieces: four legs "
                                     "against one torso), the end with more pieces down (else the heavier end up)")
        + ", seen along the thinnest axis.</p>",
    ]
    for i, task in enumerate(tasks, 1):
        trows = [r for r in rows if r["task_name"] == task]
        say(f"task {i}/{len(tasks)}: {task} ({len(trows)} rows)")
        parts.append(f"<h2>Task {html.escape(task)} ({html.escape(str(trows[0].get('task_kind', '')))})</h2>")
        cells, task_gaps = summ.get(task, {}), gaps.get(task, {})
        if cells or task_gaps:
            grid = _mean_grid(task, cells, task_gaps)
            measured = grid.metrics[:-1]  # seconds, not memory, per item
            _add_published(grid, published.get(task, ()))
            parts.append(_html_table(grid) + tables.write(grid, task))
            cat = _category_grid(task, trows)
            if cat is not None:
                parts.append(_html_table(cat) + tables.write(cat, f"{task}-categories"))
            pooled = _pooled_grid(task, trows)
            if pooled is not None:
                parts.append(_html_table(pooled) + tables.write(pooled, f"{task}-pooled"))
            groups = _item_grids(task, trows, measured)
            if groups:
                n_items = sum(len(g.rows) for _, g in groups)
                split = f", one table per {SPLIT_FIELD}" if groups[0][0] is not None else ""
                body = "".join(
                    (f"<h3 class='cat'>{html.escape(SPLIT_FIELD)} {html.escape(v)} ({len(g.rows)} rows)</h3>"
                     if v is not None else "")
                    + _html_table(g) + tables.write(g, f"{task}-items" + (f"-{v}" if v is not None else ""))
                    for v, g in groups)
                parts.append(f"<details><summary>per-item values ({n_items} rows{split})</summary>{body}</details>")
        parts.append(_spectra_list(trows))
        datasets = sorted({str(r.get("dataset", "-")) for r in trows})
        for ds in datasets:
            parts += _curve_figs(task, rows, figs, ds if len(datasets) > 1 else None, colors)
            parts += _strength_figs(task, rows, figs, ds if len(datasets) > 1 else None, colors)
        parts += _cost_fig(task, cells, figs, colors)
        if renders > 0:
            say(f"task {i}/{len(tasks)}: rendering up to {renders} shapes")
            parts += _render_rows(run, trows, figs, renders, up)
    parts.append(_prepare_section(run, rows))
    if failed:
        grid = _failed_grid(failed)
        parts.append("<h2>Failed rows</h2>" + _html_table(grid) + tables.write(grid, "failed"))
    parts.append(f"<p><small>Versions: {html.escape(json.dumps(versions))}</small></p>")
    page = (
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(str(name))}</title>"
        f"<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<style>{_CSS}</style></head><body>{''.join(parts)}</body></html>"
    )
    return page
