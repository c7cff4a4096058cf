"""``bench report``: a self-contained HTML page (PNG figures inlined as base64) plus the PNG files.

Sections: a summary first (per task and dataset, the best method of each metric highlighted and
every metric's direction marked, lower or higher is better); then per task and dataset a table of
mean and standard deviation per method and corruption (never averaging different datasets), with
an expandable per-item table; curve metrics (cumulative geodesic error, eigenvalues, scree alpha)
per method side by side; metric versus corruption strength; runtime and memory per method; the
shared precomputation; failed rows; rendered shapes (segmentations in the ground truth's palette,
matched by the Hungarian method; keypoints; maps by pull-back colour transfer). Figures are made
for a full-width page (about 1200 px), with labelled axes and units.
"""

from __future__ import annotations

import base64
import hashlib
import html
import json
import math
import os
import re
import warnings
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from shape_toolkit.bench.store import (
    RESULTS,
    load_output,
    load_prepared,
    prepared_path,
    read_prepare_log,
    read_rows,
    safe_name,
)
from shape_toolkit.errors import ParameterError

__all__ = ["write_report", "check_report_output", "summarize", "method_id", "metric_direction", "MANIFEST"]

#: metrics where a larger value is better (everything else with a direction: lower is better)
_HIGHER = ("recall", "precision", "repeatability", "coverage", "within", "matched_fraction", "accuracy", "auc",
           "smooth")
_LOWER = ("error", "discrepancy", "gce", "lce", "hamming", "seconds", "memory", "chance")
#: units of known columns, shown in the headers
_UNITS = {"seconds": "s", "peak_memory_mb": "MB", "mean_geodesic_error": "sqrt(area)",
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


def _header(name: str) -> str:
    unit = _UNITS.get(name) or ("%" if name.startswith("r_smooth@") else None)
    unit = f" ({unit})" if unit else ""
    d = metric_direction(name)
    tip = {"higher": "higher is better", "lower": "lower is better"}.get(d, "no better direction")
    return f"<th title='{tip}'>{html.escape(name)}{unit}{_arrow(name)}</th>"


def method_id(row: dict) -> str:
    """Display name of a row's method: its ``method_label`` plus its (short) parameters."""
    p = row.get("params") if isinstance(row.get("params"), dict) else {}
    label = str(row.get("method_label"))
    shown = {k: v for k, v in sorted(p.items()) if not isinstance(v, dict) and len(repr(v)) <= 24}
    if row.get("family") == "pipelines" or not shown:
        return label
    return f"{label}({', '.join(f'{k}={v}' for k, v in shown.items())})"


def _is_num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _is_curve(v: Any) -> bool:
    """A curve metric: a non-empty list of ``[x, y]`` pairs of finite numbers."""
    return isinstance(v, list) and len(v) > 0 and all(
        isinstance(x, list) and len(x) == 2 and _is_num(x[0]) and _is_num(x[1]) for x in v
    )


def summarize(rows: list[dict]) -> dict[str, dict[tuple[str, str, str], dict[str, tuple[float, float, int]]]]:
    """``{task_name: {(dataset, method_id, corruption): {column: (mean, std, count)}}}`` over ok
    rows, for every scalar metric plus ``seconds`` and ``peak_memory_mb``; different datasets are
    never averaged together."""
    acc: dict = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    for r in rows:
        if r.get("status") != "ok":
            continue
        cell = acc[r["task_name"]][(str(r.get("dataset", "-")), method_id(r), str(r.get("corruption", "none")))]
        for k, v in (r.get("metrics") or {}).items():
            if _is_num(v):
                cell[k].append(float(v))
        for k in ("seconds", "peak_memory_mb"):
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
        self.files: list[Path] = []
        self.say = say or (lambda _msg: None)

    def fresh(self, name: str) -> Path:
        """A path ``NN-NAME.png`` in the folder that no file (or link) occupies."""
        stem = f"{len(self.files):02d}-{safe_name(name)}"
        p = self.folder / f"{stem}.png"
        n = 2
        while os.path.lexists(p):  # someone else's file: leave it, take another name
            p = self.folder / f"{stem}-{n}.png"
            n += 1
        return p

    def save(self, fig, name: str) -> Path:
        import matplotlib.pyplot as plt

        self.say(f"figure {len(self.files) + 1}: {name}")  # the layout and PNG encoding take the time
        p = self.fresh(name)
        try:
            fig.savefig(p, dpi=100, bbox_inches="tight", pad_inches=0.15)
        except BaseException:
            p.unlink(missing_ok=True)  # our own half-written file (the name was free)
            raise
        finally:
            plt.close(fig)
        self.files.append(p)
        return p


def _img(path: Path, alt: str) -> str:
    data = base64.b64encode(path.read_bytes()).decode()
    cap = html.escape(alt)
    img = f'<img alt="{cap}" src="data:image/png;base64,{data}"/>'
    return f"<figure>{img}<figcaption>{cap}</figcaption></figure>"


def _num(v: float) -> str:
    """A number for a table cell: integers as integers, otherwise 4 significant-ish digits."""
    if not math.isfinite(v):
        return "&ndash;"
    if float(v).is_integer() and abs(v) < 1e12:
        return str(int(v))
    if abs(v) >= 1000 or abs(v) < 1e-3:
        return f"{v:.3g}"
    return f"{v:.4f}"


def _fmt(m: float, s: float, n: int) -> str:
    """``mean &plusmn; std (n=...)``; no spread shown for a single value or a constant column."""
    text = _num(m)
    if n > 1 and s > 0:
        spread = f"{s:.2g}" if abs(s) < 1e-3 or abs(s) >= 1000 else f"{s:.3f}"
        text += f" &plusmn; {spread}"
    if n > 1:
        text += f" <small>(n={n})</small>"
    return text


def _best(cells: dict, column: str) -> set:
    """Keys of the cells holding the best mean of ``column`` (per dataset and corruption)."""
    d = metric_direction(column)
    if d is None:
        return set()
    groups: dict = defaultdict(list)
    for key, cols in cells.items():
        if column in cols and math.isfinite(cols[column][0]):
            groups[(key[0], key[2])].append((cols[column][0], key))
    best = set()
    for items in groups.values():
        if len({k[1] for _, k in items}) < 2:
            continue  # one method: nothing to compare
        target = max(v for v, _ in items) if d == "higher" else min(v for v, _ in items)
        best |= {k for v, k in items if math.isclose(v, target, rel_tol=1e-12, abs_tol=1e-15)}
    return best


def _table(cells: dict, columns: list[str]) -> str:
    """Mean and std per (dataset, method, corruption); the best of each column in bold."""
    head = "<th>dataset</th><th>method</th><th>corruption</th>" + "".join(_header(c) for c in columns)
    best = {c: _best(cells, c) for c in columns}
    body = []
    for key, cols in sorted(cells.items()):
        ds, mid, corr = key
        tds = []
        for c in columns:
            if c not in cols:
                tds.append("<td>&ndash;</td>")
            elif key in best[c]:
                tds.append(f"<td class='best'>{_fmt(*cols[c])}</td>")
            else:
                tds.append(f"<td>{_fmt(*cols[c])}</td>")
        body.append(f"<tr><td>{html.escape(ds)}</td><td>{html.escape(mid)}</td>"
                    f"<td>{html.escape(corr)}</td>{''.join(tds)}</tr>")
    return f"<table><tr>{head}</tr>{''.join(body)}</table>"


def _item_table(rows: list[dict], columns: list[str]) -> str:
    """Per-item values of every scalar metric, inside an expandable ``<details>``."""
    ok = [r for r in rows if r.get("status") == "ok"]
    if not ok:
        return ""
    head = "<th>dataset</th><th>item</th><th>method</th><th>corruption</th>" + "".join(_header(c) for c in columns)
    body = []
    for r in sorted(ok, key=lambda r: (str(r.get("dataset")), str(r.get("item")), method_id(r),
                                        str(r.get("corruption")))):
        m = r.get("metrics") or {}
        vals = []
        for c in columns:
            v = r.get(c) if c in ("seconds", "peak_memory_mb") else m.get(c)
            vals.append(f"<td>{_num(float(v))}</td>" if _is_num(v) else "<td>&ndash;</td>")
        body.append(
            f"<tr><td>{html.escape(str(r.get('dataset', '-')))}</td><td>{html.escape(str(r.get('item')))}</td>"
            f"<td>{html.escape(method_id(r))}</td><td>{html.escape(str(r.get('corruption', 'none')))}</td>"
            f"{''.join(vals)}</tr>"
        )
    return (f"<details><summary>per-item values ({len(ok)} rows)</summary>"
            f"<table><tr>{head}</tr>{''.join(body)}</table></details>")


def _summary_section(summ: dict, tasks: list[str], rows: list[dict]) -> str:
    """The first section: per task and dataset, each directed metric's best method (uncorrupted
    rows when there are any), with its value."""
    out = []
    for task in tasks:
        cells = summ.get(task, {})
        kind = next((r.get("task_kind", "") for r in rows if r["task_name"] == task), "")
        for ds in sorted({k[0] for k in cells}):
            sub = {k: v for k, v in cells.items() if k[0] == ds}
            corr = "none" if any(k[2] == "none" for k in sub) else sorted({k[2] for k in sub})[0]
            sub = {k: v for k, v in sub.items() if k[2] == corr}
            methods = sorted({k[1] for k in sub})
            cols = sorted({c for v in sub.values() for c in v if metric_direction(c)} - {"seconds", "peak_memory_mb"})
            items = []
            for c in cols:
                if len(methods) == 1:  # nothing to rank: the value, with its direction
                    only = [v[c][0] for v in sub.values() if c in v]
                    if only:
                        items.append(f"<li><b>{html.escape(c)}</b> ({metric_direction(c)} is better): "
                                     f"{_num(only[0])}</li>")
                    continue
                best = _best(sub, c)
                if not best:
                    continue
                names = ", ".join(sorted({k[1] for k in best}))
                val = _num(sub[next(iter(best))][c][0])
                items.append(f"<li><b>{html.escape(c)}</b> ({metric_direction(c)} is better): "
                             f"<span class='best'>{html.escape(names)}</span> {val}</li>")
            what = f"{len(methods)} method{'s' if len(methods) != 1 else ''}: {', '.join(methods)}"
            body = (f"<ul>{''.join(items)}</ul>" if items
                    else "<p>no metric with a better direction here; see the table below.</p>")
            out.append(f"<h3>{html.escape(task)} ({html.escape(kind)}) on {html.escape(ds)}, "
                       f"corruption {html.escape(corr)}</h3><p>{html.escape(what)}</p>{body}")
    return ("<h2>Summary</h2><p>Best method per metric (&uarr; higher is better, &darr; lower is better; "
            "best values are <span class='best'>highlighted</span> in every table).</p>" + "".join(out))


#: row fields the report shows as text (the reader accepts a string, or null where noted in the store)
_TEXT_FIELDS = {"run_name": None, "task_name": "", "task_kind": "", "dataset": "-", "item": "", "plugin": "",
                "family": "", "method_label": "", "corruption": "none", "corruption_kind": "none",
                "corruption_group": "none", "error": "", "key": ""}


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


def _curve_figs(task: str, rows: list[dict], figs: _Figs, dataset: str | None = None) -> list[str]:
    """Curve metrics per method (mean over items, band min..max): one panel per corruption group,
    every compared method (and peer) on the same axes; one figure per metric and dataset."""
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
            for (mid, corr), cs in sorted(by_group[g].items()):
                L = min(len(c) for c in cs)
                arr = np.stack([c[:L] for c in cs])
                x, y = arr[0, :, 0], arr[:, :, 1].mean(axis=0)
                ys.extend(arr[:, :, 1].ravel())
                label = mid if corr == "none" else f"{mid} {corr[len(g):]}".strip()
                marker = "-o" if len(x) <= 12 else "-"  # few points: marked
                ax.plot(x, y, marker, ms=4, lw=1.8, label=_legend(label[:48]))
                if len(cs) > 1:
                    ax.fill_between(x, arr[:, :, 1].min(axis=0), arr[:, :, 1].max(axis=0), alpha=0.12)
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


def _strength_figs(task: str, rows: list[dict], figs: _Figs, dataset: str | None = None) -> list[str]:
    """One figure per corruption group: a panel per scalar metric, metric vs strength per method."""
    plt = _plt()
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
                            marker="o", ms=4, capsize=3, label=_legend(mid))
            d = metric_direction(metric)
            ax.set_title(_t(f"{metric}" + (f" ({d} is better)" if d else "")), fontsize=10)
            ax.set_xlabel(_t(f"{g} strength (0 = uncorrupted)"), fontsize=9)
            _style(ax, ys)
        handles, labels = axes.ravel()[0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="outside lower center", ncol=min(4, max(1, len(labels))), fontsize=10)
        where = f" on {dataset}" if dataset else ""
        fig.suptitle(_t(_title(f"{task}{where}: metrics versus {g} strength (mean and std over items)")), fontsize=12)
        fname = f"{task}-{dataset}-vs-{g}" if dataset else f"{task}-vs-{g}"
        parts.append(_img(figs.save(fig, fname), f"{task}{where}: metrics versus {g} strength"))
    return parts


def _cost_fig(task: str, cells: dict, figs: _Figs) -> list[str]:
    plt = _plt()
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
        ax.barh(range(len(names)), vals, color="tab:blue" if c == "seconds" else "tab:orange")
        ax.set_yticks(range(len(names)), [_t(n[:40]) for n in names], fontsize=10)
        what = "run time" if c == "seconds" else "peak memory growth"
        ax.set_xlabel(f"mean {what} per row ({unit}), lower is better", fontsize=10)
        ax.tick_params(labelsize=10)
        ax.grid(alpha=0.3, axis="x")
    fig.suptitle(_t(f"{task}: runtime and peak memory per method"), fontsize=12)
    return [_img(figs.save(fig, f"{task}-cost"), f"{task}: runtime and memory per method")]


def _render_rows(run: Path, task_rows: list[dict], figs: _Figs, n: int) -> list[str]:
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
            p = render_shapes(
                panels,
                figs.fresh(f"render-{r['key']}"),
                panel_size=min(4.5, 12.0 / len(panels)),
                dpi=100,
                title=_t(title),
            )
            figs.files.append(p)
            parts.append(_img(p, title))
            done_methods.add(method_id(r))
        except Exception as exc:  # a broken output must not break the report
            parts.append(
                f"<p class='err'>could not render {html.escape(r['key'])}: {html.escape(str(exc))}</p>"
            )
    return parts


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
    "body{font-family:sans-serif;margin:1.5em auto;max-width:1240px;padding:0 1em;line-height:1.4}"
    "table{border-collapse:collapse;margin:.5em 0 1.5em;font-size:13px}"
    "td,th{border:1px solid #ccc;padding:3px 6px;text-align:right}"
    "td:nth-child(-n+3){text-align:left}th{background:#eee}"
    "td.best,span.best{background:#d8f5d0;font-weight:bold}"
    "figure{display:block;margin:.8em 0}figure img{width:100%;max-width:1200px;height:auto}"
    "figcaption{font-size:12px;color:#555}.err{color:#a00}small{color:#777}"
    "details{margin:.3em 0 1.5em}summary{cursor:pointer;color:#225}"
)


#: the report folder's record of the files ``write_report`` wrote there (the only files it ever
#: replaces or deletes), with their SHA-256: ``{"generator": ..., "files": {relative path: digest}}``
MANIFEST = ".bench-report.json"
_GENERATOR = "shape-toolkit bench report"
_OWNABLE = re.compile(r"index\.html|figures/[A-Za-z0-9._-]+\.png")


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
    figures = out / "figures"
    if os.path.lexists(figures) and not figures.is_dir():
        raise ParameterError(f"{figures} exists and is not a folder; choose another report folder")
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
) -> dict:
    """Write ``index.html`` (self-contained) and PNG figures for a run folder; ``progress`` receives
    one line per step (task, figure group). Returns ``{"html": path, "figures": [paths]}``.

    The report replaces or deletes only files it wrote itself (listed with their digests in
    ``OUTPUT/.bench-report.json``); a file it did not write is never touched: an ``index.html`` of
    someone else is a :class:`ParameterError` before any work, other names are avoided."""
    def say(msg: str) -> None:  # names from the rows: no control characters on a terminal
        if progress is not None:
            progress(_printable(msg))

    run = Path(run_dir)
    if not (run / RESULTS).exists():
        raise ParameterError(f"{run} is not a run folder: {RESULTS} not found (run 'bench run' first)")
    out = Path(output) if output else run / "report"
    owned = check_report_output(out)  # before any work
    (out / "figures").mkdir(parents=True, exist_ok=True)
    say(f"reading {run / RESULTS}")
    rows = [_normalized(r) for r in read_rows(run)]
    for rel in owned:  # the previous report's figures (still as it wrote them)
        if rel.startswith("figures/"):
            (out / rel).unlink(missing_ok=True)
    figs = _Figs(out / "figures", say)
    path = out / "index.html"
    written: list[Path] = [path] if "index.html" in owned else []
    try:
        with _literal_figure_text():
            page = _page(run, out, rows, figs, renders, say)
        tmp = out / ".index.html.tmp"
        tmp.write_text(page, encoding="utf-8", errors="replace")
        os.replace(tmp, path)
        written = [path]
    finally:
        _write_manifest(out, written + figs.files)
    say(f"wrote {path} ({len(figs.files)} figures)")
    return {"html": path, "figures": list(figs.files)}


def _page(run: Path, out: Path, rows: list[dict], figs: _Figs, renders: int, say: Callable[[str], None]) -> str:
    """The HTML page of the report (its figures saved through ``figs``)."""
    summ = summarize(rows)
    n_ok = sum(r.get("status") == "ok" for r in rows)
    failed = [r for r in rows if r.get("status") != "ok"]
    name = rows[0].get("run_name", run.name) if rows else run.name
    versions = next((r.get("versions") for r in rows if r.get("versions")), {})
    tasks = list(dict.fromkeys(r["task_name"] for r in rows))
    say(f"{len(rows)} rows, {len(tasks)} tasks -> {out / 'index.html'}")
    parts = [
        f"<h1>Benchmark report: {html.escape(str(name))}</h1>",
        f"<p>{len(rows)} rows: {n_ok} ok, {len(failed)} failed. "
        f"Run folder: <code>{html.escape(str(run.resolve()))}</code>.</p>",
        _summary_section(summ, tasks, rows),
        "<p>Seconds are the method's own call (spectra come from the shared cache, timed separately); "
        "peak memory is the resident-set growth during that call (MB). Each dataset is reported on its "
        "own rows; values are mean &plusmn; standard deviation over items.</p>",
    ]
    for i, task in enumerate(tasks, 1):
        trows = [r for r in rows if r["task_name"] == task]
        say(f"task {i}/{len(tasks)}: {task} ({len(trows)} rows)")
        parts.append(f"<h2>Task {html.escape(task)} ({html.escape(str(trows[0].get('task_kind', '')))})</h2>")
        cells = summ.get(task, {})
        cols = sorted({c for v in cells.values() for c in v} - {"seconds", "peak_memory_mb"})
        if cells:
            parts.append(_table(cells, cols + ["seconds", "peak_memory_mb"]))
            parts.append(_item_table(trows, cols + ["seconds"]))
        parts.append(_spectra_list(trows))
        datasets = sorted({str(r.get("dataset", "-")) for r in trows})
        for ds in datasets:
            parts += _curve_figs(task, rows, figs, ds if len(datasets) > 1 else None)
            parts += _strength_figs(task, rows, figs, ds if len(datasets) > 1 else None)
        parts += _cost_fig(task, cells, figs)
        if renders > 0:
            say(f"task {i}/{len(tasks)}: rendering up to {renders} shapes")
            parts += _render_rows(run, trows, figs, renders)
    parts.append(_prepare_section(run, rows))
    if failed:
        items = "".join(
            f"<tr><td>{html.escape(str(r.get('task_name')))}</td><td>{html.escape(method_id(r))}</td>"
            f"<td>{html.escape(str(r.get('item')))}</td><td>{html.escape(str(r.get('corruption')))}</td>"
            f"<td style='text-align:left'>{html.escape(str(r.get('error')))}</td></tr>"
            for r in failed
        )
        parts.append(
            "<h2>Failed rows</h2><table><tr><th>task</th><th>method</th><th>item</th><th>corruption</th>"
            f"<th>error</th></tr>{items}</table>"
        )
    parts.append(f"<p><small>Versions: {html.escape(json.dumps(versions))}</small></p>")
    page = (
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(str(name))}</title>"
        f"<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<style>{_CSS}</style></head><body>{''.join(parts)}</body></html>"
    )
    return page
