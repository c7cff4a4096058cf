"""``bench report``: a self-contained HTML page (PNG figures inlined as base64) plus the PNG files.

Sections: run summary; per task a table of mean and standard deviation per method (and
corruption) of every scalar metric, seconds and peak memory; curve metrics (cumulative geodesic
error, eigenvalues, scree alpha) averaged per method; metric versus corruption strength;
runtime and memory per method; the shared precomputation (prepare stage: corruption, spectra,
geodesics, done once per item) against the per-row spectrum look-ups it saves; failed rows;
rendered shapes (segmentations by label, keypoints, matches by colour transfer).
"""

from __future__ import annotations

import base64
import html
import json
import math
import os
from collections import defaultdict
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

__all__ = ["write_report", "summarize", "method_id"]


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
    return isinstance(v, list) and len(v) > 0 and all(isinstance(x, list) and len(x) == 2 for x in v)


def summarize(rows: list[dict]) -> dict[str, dict[tuple[str, str], dict[str, tuple[float, float, int]]]]:
    """``{task_name: {(method_id, corruption): {column: (mean, std, count)}}}`` over ok rows, for
    every scalar metric plus ``seconds`` and ``peak_memory_mb``."""
    acc: dict = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    for r in rows:
        if r.get("status") != "ok":
            continue
        cell = acc[r["task_name"]][(method_id(r), str(r.get("corruption", "none")))]
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
    def __init__(self, folder: Path):
        self.folder = folder
        self.files: list[Path] = []

    def save(self, fig, name: str) -> Path:
        import matplotlib.pyplot as plt

        p = self.folder / f"{len(self.files):02d}-{safe_name(name)}.png"
        fig.savefig(p, dpi=90, bbox_inches="tight")
        plt.close(fig)
        self.files.append(p)
        return p


def _img(path: Path, alt: str) -> str:
    data = base64.b64encode(path.read_bytes()).decode()
    cap = html.escape(alt)
    img = f'<img alt="{cap}" src="data:image/png;base64,{data}"/>'
    return f"<figure>{img}<figcaption>{cap}</figcaption></figure>"


def _fmt(m: float, s: float, n: int) -> str:
    if abs(m) >= 1000 or (0 < abs(m) < 1e-3):
        return f"{m:.3g} &plusmn; {s:.2g}"
    return f"{m:.4f} &plusmn; {s:.3f}" + (f" <small>(n={n})</small>" if n > 1 else "")


def _table(cells: dict, columns: list[str]) -> str:
    head = "".join(f"<th>{html.escape(c)}</th>" for c in ["method", "corruption"] + columns)
    body = []
    for (mid, corr), cols in sorted(cells.items()):
        tds = "".join(f"<td>{_fmt(*cols[c]) if c in cols else '&ndash;'}</td>" for c in columns)
        body.append(f"<tr><td>{html.escape(mid)}</td><td>{html.escape(corr)}</td>{tds}</tr>")
    return f"<table><tr>{head}</tr>{''.join(body)}</table>"


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False) if matplotlib.get_backend().lower() != "agg" else None
    import matplotlib.pyplot as plt

    return plt


def _curve_figs(task: str, rows: list[dict], figs: _Figs) -> list[str]:
    """Curve metrics averaged per method: one panel per corruption group (lines: method and
    strength), so uncorrupted and corrupted results sit side by side."""
    plt = _plt()
    parts = []
    curves: dict = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    for r in rows:
        if r.get("status") != "ok" or r["task_name"] != task:
            continue
        g = str(r.get("corruption_group") or "none")
        for k, v in (r.get("metrics") or {}).items():
            if _is_curve(v):
                curves[k][g][(method_id(r), r.get("corruption", "none"))].append(np.asarray(v, dtype=float))
    for metric, by_group in sorted(curves.items()):
        groups = sorted(by_group, key=lambda g: (g != "none", g))
        ncol = min(3, len(groups))
        nrow = math.ceil(len(groups) / ncol)
        fig, axes = plt.subplots(nrow, ncol, figsize=(4.6 * ncol, 3.4 * nrow), squeeze=False)
        for ax, g in zip(axes.ravel(), groups):
            for (mid, corr), cs in sorted(by_group[g].items()):
                L = min(len(c) for c in cs)
                arr = np.stack([c[:L] for c in cs])
                x, y = arr[0, :, 0], arr[:, :, 1].mean(axis=0)
                label = mid if corr == "none" else f"{mid} {corr[len(g) :]}".strip()
                ax.plot(x, y, "-", lw=1.4, label=label[:48])
                if len(cs) > 1:
                    ax.fill_between(x, arr[:, :, 1].min(axis=0), arr[:, :, 1].max(axis=0), alpha=0.12)
            ax.set_title("uncorrupted" if g == "none" else g, fontsize=8)
            if "geodesic_error_curve" in metric:
                ax.set_xlabel("geodesic error / sqrt(area)", fontsize=7)
                ax.set_ylabel("fraction of correspondences", fontsize=7)
            elif "alpha_vs_t" in metric:
                ax.set_xscale("log")
                ax.set_xlabel("t", fontsize=7)
                ax.set_ylabel("alpha(K, t)", fontsize=7)
            elif "alpha_vs_K" in metric:
                ax.set_xlabel("K (% of computed eigenpairs)", fontsize=7)
                ax.set_ylabel("alpha(K, t)", fontsize=7)
            elif metric == "eigenvalues":
                ax.set_xlabel("index", fontsize=7)
                ax.set_ylabel("eigenvalue", fontsize=7)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=6, loc="best")
        for ax in axes.ravel()[len(groups) :]:
            ax.set_axis_off()
        fig.suptitle(f"{task}: {metric} (mean over items; band = min..max)", fontsize=9)
        fig.tight_layout()
        parts.append(_img(figs.save(fig, f"{task}-{metric}"), f"{task}: {metric}"))
    return parts


def _strength_figs(task: str, rows: list[dict], figs: _Figs) -> list[str]:
    """One figure per corruption group: a panel per scalar metric, metric vs strength per method."""
    plt = _plt()
    parts = []
    ok = [r for r in rows if r.get("status") == "ok" and r["task_name"] == task]
    groups = sorted({r.get("corruption_group") for r in ok} - {"none", None})
    metrics = sorted({k for r in ok for k, v in (r.get("metrics") or {}).items() if _is_num(v)})
    for g in groups:
        sel = [r for r in ok if r.get("corruption_group") in (g, "none") and _is_num(r.get("strength"))]
        if len({r["strength"] for r in sel}) < 2 or not metrics:
            continue
        ncol = min(4, len(metrics))
        nrow = math.ceil(len(metrics) / ncol)
        fig, axes = plt.subplots(nrow, ncol, figsize=(3.3 * ncol, 2.6 * nrow + 0.6), squeeze=False)
        for ax, metric in zip(axes.ravel(), metrics):
            by: dict = defaultdict(lambda: defaultdict(list))
            for r in sel:
                v = (r.get("metrics") or {}).get(metric)
                if _is_num(v):
                    by[method_id(r)][r["strength"]].append(v)
            for mid, pts in sorted(by.items()):
                xs = sorted(pts)
                ax.errorbar(
                    xs,
                    [np.mean(pts[x]) for x in xs],
                    yerr=[np.std(pts[x]) for x in xs],
                    marker="o",
                    ms=3,
                    capsize=2,
                    label=mid,
                )
            ax.set_title(metric, fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
        for ax in axes.ravel()[len(metrics) :]:
            ax.set_axis_off()
        handles, labels = axes.ravel()[0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="lower center", ncol=min(4, max(1, len(labels))), fontsize=7)
        fig.suptitle(
            f"{task}: metrics versus {g} strength (0 = uncorrupted; mean and std over items)", fontsize=9
        )
        fig.tight_layout(rect=(0, 0.08, 1, 0.95))
        parts.append(_img(figs.save(fig, f"{task}-vs-{g}"), f"{task}: metrics versus {g} strength"))
    return parts


def _cost_fig(task: str, cells: dict, figs: _Figs) -> list[str]:
    plt = _plt()
    by: dict = defaultdict(lambda: {"seconds": [], "peak_memory_mb": []})
    for (mid, _corr), cols in cells.items():
        for c in ("seconds", "peak_memory_mb"):
            if c in cols:
                by[mid][c].append(cols[c][0])
    if not by:
        return []
    names = sorted(by)
    fig, axes = plt.subplots(1, 2, figsize=(9, 0.5 + 0.35 * len(names) + 1))
    for ax, c, unit in zip(axes, ("seconds", "peak_memory_mb"), ("s", "MB")):
        vals = [float(np.mean(by[n][c])) if by[n][c] else 0.0 for n in names]
        ax.barh(range(len(names)), vals, color="tab:blue" if c == "seconds" else "tab:orange")
        ax.set_yticks(range(len(names)))
        ax.set_yticklabels(names if ax is axes[0] else [""] * len(names), fontsize=7)
        ax.set_xlabel(f"mean {c} ({unit})")
        ax.grid(alpha=0.3, axis="x")
    fig.suptitle(f"{task}: runtime and peak memory per method", fontsize=9)
    return [_img(figs.save(fig, f"{task}-cost"), f"{task}: runtime and memory per method")]


def _render_rows(run: Path, task_rows: list[dict], figs: _Figs, n: int) -> list[str]:
    from shape_toolkit.io.viz import match_colors, render_shapes

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
            prep = load_prepared(ppath)  # npz, validated; never pickle
            out = load_output(run, r["output"])
            title = f"{r['task_name']}: {method_id(r)} on {r['item']} ({r.get('corruption', 'none')})"
            kind = r.get("task_kind")
            if kind == "segmentation" and "labels" in out:
                panels = [{"shape": prep.target, "labels": out["labels"], "title": "result"}]
                if prep.target_labels:
                    panels.append(
                        {"shape": prep.target, "labels": prep.target_labels[0], "title": "ground truth"}
                    )
            elif kind == "keypoints" and "keypoints" in out:
                panels = [
                    {"shape": prep.source, "points": out["source_keypoints"], "title": "source"},
                    {"shape": prep.target, "points": out["keypoints"], "title": "target"},
                ]
            elif kind == "matching" and "target_of" in out:
                cs, ct = match_colors(prep.source, prep.target, out["target_of"])
                panels = [
                    {"shape": prep.source, "colors": cs, "title": "source"},
                    {"shape": prep.target, "colors": ct, "title": "target (colour transfer)"},
                ]
            else:
                continue
            p = render_shapes(
                panels,
                figs.folder / f"{len(figs.files):02d}-render-{safe_name(r['key'])}.png",
                panel_size=3.0,
                dpi=80,
                title=title,
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
    avg = spec_total / len(comp) if comp else float("nan")
    return (
        "<h2>Shared precomputation (once per item and corruption)</h2>"
        f"<p>{len(preps)} prepare jobs computed {len(comp)} spectra in {spec_total:.2f} s "
        f"(mean {avg:.3f} s each), geodesic rows for evaluation in {geo_total:.2f} s and corruptions in "
        f"{cor_total:.2f} s. The {len(looked)} method rows then obtained their spectra from the cache "
        f"({hits} hits) in {look_total:.2f} s in total; computing them per row would have cost about "
        f"{(avg * len(looked)) if comp else float('nan'):.1f} s.</p>"
    )


_CSS = (
    "body{font-family:sans-serif;margin:1.5em;max-width:1300px}"
    "table{border-collapse:collapse;margin:.5em 0 1.5em;font-size:12px}"
    "td,th{border:1px solid #ccc;padding:3px 6px;text-align:right}"
    "td:first-child,td:nth-child(2){text-align:left}th{background:#eee}"
    "figure{display:inline-block;margin:.3em;vertical-align:top}figure img{max-width:620px}"
    "figcaption{font-size:11px;color:#555}.err{color:#a00}small{color:#777}"
)


def write_report(
    run_dir: str | os.PathLike, *, output: str | os.PathLike | None = None, renders: int = 3
) -> dict:
    """Write ``index.html`` (self-contained) and PNG figures for a run folder; returns
    ``{"html": path, "figures": [paths]}``."""
    run = Path(run_dir)
    if not (run / RESULTS).exists():
        raise ParameterError(f"{run} is not a run folder: {RESULTS} not found (run 'bench run' first)")
    rows = read_rows(run)
    out = Path(output) if output else run / "report"
    (out / "figures").mkdir(parents=True, exist_ok=True)
    for old in (out / "figures").glob("*.png"):
        old.unlink()
    figs = _Figs(out / "figures")
    summ = summarize(rows)
    n_ok = sum(r.get("status") == "ok" for r in rows)
    failed = [r for r in rows if r.get("status") != "ok"]
    name = rows[0].get("run_name", run.name) if rows else run.name
    versions = next((r.get("versions") for r in rows if r.get("versions")), {})
    parts = [
        f"<h1>Benchmark report: {html.escape(str(name))}</h1>",
        f"<p>{len(rows)} rows: {n_ok} ok, {len(failed)} failed. "
        f"Run folder: <code>{html.escape(str(run.resolve()))}</code>."
        f" Versions: {html.escape(json.dumps(versions))}.</p>",
        "<p>Seconds are the method's own call (spectra come from the shared cache, timed separately); "
        "peak memory is the resident-set growth during that call (MB).</p>",
    ]
    tasks = list(dict.fromkeys(r["task_name"] for r in rows))
    for task in tasks:
        trows = [r for r in rows if r["task_name"] == task]
        parts.append(f"<h2>Task {html.escape(task)} ({trows[0].get('task_kind', '')})</h2>")
        cells = summ.get(task, {})
        cols = sorted({c for v in cells.values() for c in v} - {"seconds", "peak_memory_mb"})
        if cells:
            parts.append(_table(cells, cols + ["seconds", "peak_memory_mb"]))
        parts.append(_spectra_list(trows))
        parts += _curve_figs(task, rows, figs)
        parts += _strength_figs(task, rows, figs)
        parts += _cost_fig(task, cells, figs)
        if renders > 0:
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
    page = (
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(str(name))}</title>"
        f"<style>{_CSS}</style></head><body>{''.join(parts)}</body></html>"
    )
    path = out / "index.html"
    tmp = out / ".index.html.tmp"
    tmp.write_text(page, encoding="utf-8")
    os.replace(tmp, path)
    return {"html": path, "figures": list(figs.files)}
