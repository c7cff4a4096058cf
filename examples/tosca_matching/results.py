"""Run the TOSCA example's ``dense`` task in parts and regenerate ``results.md`` and the curve PNG.

Thesis Tables 7.2-7.3 and the cumulative error curves (see README.md in this folder). The methods
can be run in separate run folders at different code revisions (e.g. the baselines first, the
thesis presets later); every run records the git commit of each row it adds, and ``report``
combines the folders (for a method and pair, the row of the folder named last wins).

    python examples/tosca_matching/results.py run -o runs/tosca-base --methods zoomout,mateus2008,ovsjanikov2010,pyfm
    python examples/tosca_matching/results.py run -o runs/tosca-thesis --methods topo-robust,sharma2012
    python examples/tosca_matching/results.py report runs/tosca-base runs/tosca-thesis

To run exactly a commit while the working tree has other sessions' uncommitted edits, export it
and run from outside the repository (the commit is then recorded, clean)::

    git archive HEAD shape_toolkit | tar -x -C /tmp/code && git rev-parse --short=12 HEAD > /tmp/code/EXPORTED_COMMIT
    cd /tmp && PYTHONPATH=/tmp/code python /path/to/examples/tosca_matching/results.py run -o /abs/run/folder ...

``run`` uses one worker, in process, with one BLAS thread (the runner's local executor), and the
``dense`` task of ``config.toml`` unchanged but for the method list; ``--limit N`` keeps the first
N pairs. ``report`` writes ``results.md``, ``results.json`` and ``results_curves.png`` next to this
file (``--out`` to write elsewhere).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

HERE = Path(__file__).resolve().parent
CONFIG = HERE / "config.toml"
REVISIONS = "revisions.jsonl"
RUNLOG = "runlog.jsonl"
#: the thesis's Table 7.2 (percent, r-smooth_theta, theta = 90 %): {method: {r: [6 visual-shape pairs]}}
THESIS_72 = {
    "ovsjanikov2010": {0.1: [8.56, 24.63, 30.47, 0.0, 0.0, 7.65], 0.2: [14.09, 38.96, 48.09, 7.60, 7.05, 9.01],
                       0.3: [16.47, 50.40, 59.70, 8.39, 7.28, 10.04], 0.4: [17.22, 52.41, 65.41, 11.65, 8.43, 13.05],
                       0.5: [19.21, 58.99, 68.13, 10.57, 9.52, 12.82], 0.8: [20.43, 64.88, 74.27, 14.45, 12.24, 16.80]},
    "mateus2008": {0.1: [15.93, 16.95, 12.79, 0.0, 0.0, 10.52], 0.2: [20.70, 22.60, 15.65, 11.61, 10.53, 12.87],
                   0.3: [24.64, 27.02, 18.68, 15.54, 13.28, 13.71], 0.4: [26.28, 28.56, 19.75, 17.51, 16.31, 17.66],
                   0.5: [28.25, 30.53, 20.49, 17.79, 17.58, 20.53], 0.8: [30.10, 31.66, 22.87, 20.13, 20.24, 23.81]},
    "proposed": {0.1: [36.33, 38.60, 39.17, 0.0, 0.0, 30.64], 0.2: [44.30, 52.51, 54.70, 24.37, 25.71, 36.01],
                 0.3: [53.25, 64.67, 67.56, 37.00, 38.62, 38.62], 0.4: [55.75, 65.16, 70.82, 47.70, 45.08, 42.44],
                 0.5: [60.14, 71.85, 73.10, 49.26, 51.26, 49.69], 0.8: [65.10, 78.88, 82.83, 55.82, 55.76, 58.06]},
}
#: the thesis's Table 7.3 (mean recall, mean precision) on 5 visual-shape pairs
THESIS_73 = {
    "proposed": ([0.9134, 0.9548, 0.9815, 0.9574, 0.9705], [0.9400, 0.9807, 0.9919, 0.9845, 0.9876]),
    "mateus2008": ([0.2765, 0.2259, 0.4791, 0.1308, 0.3829], [0.2488, 0.1647, 0.4846, 0.1138, 0.4521]),
}
RS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.8)
#: pairs the thesis presets' left/right decision was developed on (benchmarks/results/topological_noise.md)
DEV_PAIRS = ("cat0-cat2", "cat0-cat3", "cat0-cat5")
#: display order: the thesis presets, the thesis's comparison methods, the toolkit's and the peer
ORDER = ("topo-robust", "sharma2012", "mateus2008", "ovsjanikov2010", "zoomout", "pyfm")


def git_revision() -> dict[str, Any]:
    """The code a run used (``bench.worker.code_revision`` of the imported ``shape_toolkit``): HEAD's
    12-character hash, ``dirty`` when tracked files under ``shape_toolkit/`` differ from it (other
    sessions may have uncommitted edits in the tree; ``dirty_files`` names them); from an exported
    tree (``git archive COMMIT shape_toolkit`` with the commit in ``EXPORTED_COMMIT`` beside it, put
    first on ``PYTHONPATH``), that commit, clean."""
    from shape_toolkit.bench.worker import code_revision

    return code_revision(paths=["shape_toolkit"])


def dense_config(methods: list[str] | None) -> dict[str, Any]:
    """``config.toml`` with its ``dense`` task only, keeping the methods named (pipeline or peer
    names; None keeps all)."""
    raw = tomllib.loads(CONFIG.read_text())
    task = next(t for t in raw["tasks"] if t.get("name") == "dense")
    names = [m.get("pipeline") or m.get("peer") or m.get("plugin") for m in task["methods"]]
    if methods is not None:
        unknown = sorted(set(methods) - set(names))
        if unknown:
            raise SystemExit(f"error: unknown method(s) {', '.join(unknown)}; the config has {', '.join(names)}")
        task = dict(task, methods=[m for m, n in zip(task["methods"], names) if n in methods])
    return dict(raw, tasks=[task])


def cmd_run(args: argparse.Namespace) -> int:
    from shape_toolkit.bench.config import parse_config
    from shape_toolkit.bench.executors import run_benchmark
    from shape_toolkit.bench.store import read_rows
    from shape_toolkit.bench.worker import revision_label

    methods = [m.strip() for m in args.methods.split(",")] if args.methods else None
    cfg = parse_config(dense_config(methods), base=HERE, source=str(CONFIG))
    run = Path(args.output)
    rev = git_revision()
    before = {r["key"] for r in read_rows(run)} if (run / "results.jsonl").exists() else set()
    started, load0 = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()), os.getloadavg()
    summary = run_benchmark(cfg, run, workers=1, limit=args.limit, progress=not args.quiet)
    new = [r for r in read_rows(run) if r["key"] not in before]
    entry = {"methods": methods, "limit": args.limit, "started": started,
             "ended": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()), "wall_seconds": summary.seconds,
             "load_start": [round(x, 2) for x in load0], "load_end": [round(x, 2) for x in os.getloadavg()],
             "new_rows": len(new), "cpus": os.cpu_count(), **rev}
    with open(run / RUNLOG, "a", encoding="utf-8") as fh:
        fh.write(json.dumps(entry) + "\n")
    with open(run / REVISIONS, "a", encoding="utf-8") as fh:
        for r in new:
            fh.write(json.dumps({"key": r["key"], **rev}) + "\n")
    print(f"{len(new)} new rows at {revision_label(rev)} in {run} ({summary.failed} failed rows in the folder)")
    return 0 if summary.failed == 0 else 1


# ------------------------------------------------------------------------------------------------
# report
# ------------------------------------------------------------------------------------------------
def _short(row: dict) -> str:
    label = str(row.get("method_label") or row.get("plugin"))
    return label.split(":", 1)[1] if ":" in label else label


def combined_rows(runs: list[Path]) -> list[dict]:
    """The ok and failed ``dense`` rows of the run folders, one per (method, pair): a later folder's
    row replaces an earlier one's; each row gets ``commit`` from its folder's revision log."""
    from shape_toolkit.bench.store import read_rows

    best: dict[tuple[str, str], dict] = {}
    for run in runs:
        revs: dict[str, str] = {}
        if (run / REVISIONS).exists():
            for line in (run / REVISIONS).read_text().splitlines():
                if line.strip():
                    d = json.loads(line)
                    revs[d["key"]] = d["commit"] + ("+dirty" if d.get("dirty") else "")
        for r in read_rows(run):
            if r.get("task_name") != "dense":
                continue
            r = dict(r, commit=revs.get(r["key"], "unrecorded"), run_folder=str(run))
            if r.get("status") == "ok":
                m = r.get("metrics") or {}
                if "mean_geodesic_error_sym" in m:  # rows since the runner reports both errors
                    r["direct_error"], r["metrics"] = m["mean_geodesic_error"], symmetric_view(m)
                else:  # older rows: mean_geodesic_error was the symmetry-aware error
                    r["direct_error"] = direct_error(run, r)
            best[(_short(r), str(r["item"]))] = r
    return list(best.values())


def truth_rows(runs: list[Path], rows: list[dict]) -> list[dict]:
    """Reference rows ``ground truth``: each pair's ground-truth map scored by the runner's own
    metric code with the run's task options. The ground truth pairs template points, so it covers
    part of the source vertices (about 3,600 of 5,000 on tosca5k); every other source vertex takes
    the image of the nearest covered one along the edges, so that the map is total."""
    from shape_toolkit.bench.store import load_prepared, prepared_path
    from shape_toolkit.bench.tasks import TASKS
    from shape_toolkit.features.geodesics import nearest_source

    adapter = TASKS["matching"]
    out, seen = [], set()
    for r in rows:
        if r.get("status") != "ok" or r["item"] in seen:
            continue
        run = Path(r["run_folder"])
        try:
            raw = json.loads((run / "config.json").read_text())
            task = next(t for t in raw["tasks"] if t.get("name") == "dense")
            opts = adapter.check_options(dict(task.get("options") or {}))
            prep = load_prepared(prepared_path(run, r["prepare_key"]))
        except (OSError, ValueError, KeyError, StopIteration):  # no config or prepared item: no reference
            continue
        if prep.truth is None or not len(prep.truth):
            continue
        t = np.full(prep.source.n_vertices, -1, dtype=np.int64)
        t[prep.truth[:, 0]] = prep.truth[:, 1]
        have = np.flatnonzero(t >= 0)  # the truth covers part of the vertices (template points):
        owner = nearest_source(prep.source, have)  # the others take the image of the nearest covered one
        fill = (t < 0) & (owner >= 0)
        t[fill] = t[owner[fill]]
        metrics = symmetric_view(adapter.evaluate(["geodesic_error", "r_smoothness", "label_transfer"], prep,
                                                  {"target_of": t}, opts))
        seen.add(r["item"])
        out.append({"key": f"truth-{r['item']}", "status": "ok", "item": r["item"], "method_label": "ground truth",
                    "metrics": metrics, "commit": "-", "direct_error": None})
    return out


def symmetric_view(metrics: dict) -> dict:
    """A row's metrics with the symmetry-aware error (and its curve) as ``mean_geodesic_error``, the
    column this report shows (the runner's ``mean_geodesic_error`` is against the ground truth alone)."""
    if metrics.get("mean_geodesic_error_sym") is None:
        return metrics
    return {**metrics, "mean_geodesic_error": metrics["mean_geodesic_error_sym"],
            "geodesic_error_curve": metrics.get("geodesic_error_sym_curve", metrics.get("geodesic_error_curve"))}


def direct_error(run: Path, row: dict) -> float | None:
    """Mean geodesic error (units of sqrt(area)) of a row's map against the ground truth alone,
    without the left-right mirror the ``mean_geodesic_error`` column allows, from the run folder's
    prepared item and saved map (None when either is missing)."""
    from shape_toolkit.bench.store import load_output, load_prepared, prepared_path

    try:
        prep = load_prepared(prepared_path(run, row["prepare_key"]))
        t = np.asarray(load_output(run, row["output"])["target_of"], dtype=np.int64)
    except (OSError, KeyError, TypeError, ValueError):
        return None
    if prep.geodesic_rows is None or prep.truth_eval is None:
        return None
    pred = t[prep.truth_eval[:, 0]]
    ok = np.flatnonzero(pred >= 0)
    if ok.size == 0:
        return None
    return float(np.mean(prep.geodesic_rows[ok, pred[ok]]) / np.sqrt(prep.target.area))


def _mean(xs: list[float]) -> float:
    xs = [x for x in xs if isinstance(x, (int, float)) and math.isfinite(x)]
    return float(np.mean(xs)) if xs else float("nan")


def flipped(row: dict) -> bool:
    """A left-right swapped map: the error without the symmetric ground truth is more than twice
    (+0.02) the symmetry-aware one (the rule of benchmarks/configs/tosca_matching.toml)."""
    from shape_toolkit.metrics.correspondence import is_flipped

    a, s = row.get("direct_error"), (row.get("metrics") or {}).get("mean_geodesic_error")
    return isinstance(a, (int, float)) and isinstance(s, (int, float)) and is_flipped(a, s)


def summarize_methods(rows: list[dict]) -> dict[str, dict[str, Any]]:
    """Per method: pair count, failures, means of every Table 7.2/7.3 column, error, flips, CPU."""
    by: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        by[_short(r)].append(r)
    out: dict[str, dict[str, Any]] = {}
    for name, rs in by.items():
        ok = [r for r in rs if r.get("status") == "ok"]
        m = [r.get("metrics") or {} for r in ok]
        d: dict[str, Any] = {
            "pairs": len(ok), "failed": len(rs) - len(ok),
            "commits": sorted({r["commit"] for r in rs}),
            "mean_geodesic_error": _mean([x.get("mean_geodesic_error") for x in m]),
            "within_0.05": _mean([_within(x.get("geodesic_error_curve"), 0.05) for x in m]),
            "flipped": sum(flipped(r) for r in ok) if any(r.get("direct_error") is not None for r in ok) else None,
            "mean_direct_error": _mean([r.get("direct_error") for r in ok]),
            "label_recall": _mean([x.get("label_recall") for x in m]),
            "label_precision": _mean([x.get("label_precision") for x in m]),
            "cpu_s": _mean([r.get("cpu_seconds") for r in ok]),
            "wall_s": _mean([r.get("seconds") for r in ok]),
        }
        for r_ in RS:
            d[f"r_smooth@{r_:g}"] = _mean([x.get(f"r_smooth@{r_:g}") for x in m])
        out[name] = d
    return out


def _within(curve: Any, t: float) -> float:
    if not isinstance(curve, list) or not curve:
        return float("nan")
    c = np.asarray(curve, dtype=float)
    return float(np.interp(t, c[:, 0], c[:, 1]))


def _f(v: Any, fmt: str = "{:.1f}") -> str:
    return "n/a" if v is None or (isinstance(v, float) and not math.isfinite(v)) else fmt.format(v)


def _ratio(a: Any, b: Any) -> str:
    ok = all(isinstance(x, (int, float)) and math.isfinite(x) for x in (a, b)) and b > 0
    return f"{a / b:.2f}x" if ok else "-"


def _ordered(names) -> list[str]:
    return sorted(names, key=lambda n: (ORDER.index(n) if n in ORDER else len(ORDER), n))


def curves_png(rows: list[dict], path: Path) -> None:
    """Two panels: the cumulative geodesic-error curves and the r-smoothness curves, mean over pairs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6), layout="constrained")
    by: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        if r.get("status") == "ok":
            by[_short(r)].append(r.get("metrics") or {})
    for i, name in enumerate(_ordered(by)):
        for ax, key in zip(axes, ("geodesic_error_curve", "r_smoothness_curve")):
            cs = [np.asarray(m[key], dtype=float) for m in by[name] if isinstance(m.get(key), list)]
            if not cs:
                continue
            L = min(len(c) for c in cs)
            arr = np.stack([c[:L] for c in cs])
            ax.plot(arr[0, :, 0], arr[:, :, 1].mean(axis=0), "-o" if key.startswith("r_") else "-",
                    ms=4, lw=1.8, color=f"C{i}", label=f"{name} ({len(cs)} pairs)")
    axes[0].set_xlabel("geodesic error (units of sqrt(area))")
    axes[0].set_ylabel("fraction of correspondences within")
    axes[0].set_xlim(0, 0.25)
    axes[0].set_title("cumulative geodesic error (symmetric ground truth allowed)")
    axes[1].set_xlabel("neighbourhood size r (% of the vertices)")
    axes[1].set_ylabel("r-smooth source vertices (%), theta = 90 %")
    axes[1].set_title("Table 7.2: r-smoothness (eq. 7.4-7.5)")
    for ax in axes:
        ax.grid(alpha=0.3)
    if axes[0].get_legend_handles_labels()[0]:  # one legend: the colours are the same in both panels
        axes[0].legend(fontsize=9, loc="lower right")
    n_items = len({r["item"] for r in rows})
    fig.suptitle(f"TOSCA tosca5k, {n_items} pairs: mean over the pairs each method matched", fontsize=12)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _thesis_mean(method: str, r: float) -> float:
    return float(np.mean(THESIS_72[method][r]))


def write_results(runs: list[Path], out: Path) -> dict[str, Any]:
    """Write ``results.md``, ``results.json`` and ``results_curves.png`` into ``out``."""
    from shape_toolkit.bench.worker import revision_label

    rows = combined_rows(runs)
    if not rows:
        raise SystemExit(f"error: no dense rows in {', '.join(map(str, runs))}")
    truth = truth_rows(runs, rows)
    summ = summarize_methods(rows)
    tsum = summarize_methods(truth).get("ground truth")
    names = _ordered(summ)
    out.mkdir(parents=True, exist_ok=True)
    curves_png(rows, out / "results_curves.png")
    n_items = len({r["item"] for r in rows})
    lines = [
        "# TOSCA matching: thesis Tables 7.2-7.3 and the error curves",
        "",
        "Regenerate: `python examples/tosca_matching/results.py report " + " ".join(str(r) for r in runs) + "`",
        f"(rows from the run folders named; the runs themselves: see the docstring of `results.py`). {n_items} pairs "
        "of `tosca5k/pairs.txt`; one worker, one BLAS thread (the runner's local executor); "
        f"machine: {platform.machine()}, {os.cpu_count()} cores shared with other jobs.",
        "",
        "![error and r-smoothness curves](results_curves.png)",
        "",
        "## Table 7.2: r-smoothness (percent of source vertices, theta = 90 %, 1,000 source vertices per pair)",
        "",
        "| method | pairs | " + " | ".join(f"r = {r:g}" for r in RS) + " |",
        "|---|---|" + "---|" * len(RS),
    ]
    for n in names:
        s = summ[n]
        lines.append(f"| {n} | {s['pairs']} | " + " | ".join(_f(s[f'r_smooth@{r:g}']) for r in RS) + " |")
    if tsum:
        lines.append(f"| *ground-truth map (reference)* | {tsum['pairs']} | "
                     + " | ".join(_f(tsum[f'r_smooth@{r:g}']) for r in RS) + " |")
    for key, label in (("proposed", "thesis: proposed method"), ("mateus2008", "thesis: [Mateus 2008]"),
                       ("ovsjanikov2010", "thesis: [Ovsjanikov 2010] (HKS + seed growing)")):
        lines.append(f"| *{label}* | 6 visual | " + " | ".join(_f(_thesis_mean(key, r)) for r in RS) + " |")
    lines += [
        "",
        "Thesis rows: mean of Table 7.2's six visual-shape pairs (flashkick, samba, lucie; 4,000-12,000 "
        "vertices, topological merges). Not the same data, so only the ordering can be compared. "
        "Ground-truth map: each pair's ground truth (template points; the uncovered source vertices take "
        "the image of the nearest covered one) scored by the same code. The shapes are remeshed "
        "independently, so even the true map is not r-smooth everywhere.",
        "",
        "## Table 7.3: segmentation transfer (mean recall and precision over 8 segments)",
        "",
        "| method | pairs | recall | precision | mean geodesic error | within 0.05 | flipped pairs | CPU s/pair | "
        "CPU vs pyFM | wall s/pair | failed | commit |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for n in names:
        s = summ[n]
        lines.append(
            f"| {n} | {s['pairs']} | {_f(s['label_recall'], '{:.4f}')} | {_f(s['label_precision'], '{:.4f}')} | "
            f"{_f(s['mean_geodesic_error'], '{:.4f}')} | {_f(100 * s['within_0.05'])} % | "
            f"{_f(s['flipped'], '{}')} | {_f(s['cpu_s'])} | {_ratio(s['cpu_s'], summ.get('pyfm', {}).get('cpu_s'))} | "
            f"{_f(s['wall_s'])} | {s['failed']} | "
            f"{', '.join(s['commits'])} |"
        )
    if tsum:
        lines.append(f"| *ground-truth map (reference)* | {tsum['pairs']} | {_f(tsum['label_recall'], '{:.4f}')} | "
                     f"{_f(tsum['label_precision'], '{:.4f}')} | {_f(tsum['mean_geodesic_error'], '{:.4f}')} | "
                     "| | | | | | |")
    for key, label in (("proposed", "thesis: proposed method"), ("mateus2008", "thesis: [Mateus 2008]")):
        rec, prec = THESIS_73[key]
        lines.append(f"| *{label}* | 5 visual | {np.mean(rec):.4f} | {np.mean(prec):.4f} | | | | | | | | |")
    lines += ["", "## Verdict (generated from the numbers above, all pairs)", ""] + verdict(summ, rows)
    lines += ["", "## Runs (one worker, one BLAS thread; the machine's 2 cores were shared with other sessions)", ""]
    for run in runs:
        log = run / RUNLOG
        for line in (log.read_text().splitlines() if log.exists() else []):
            if line.strip():
                e = json.loads(line)
                lines.append(f"- `{run.name}`: {', '.join(e.get('methods') or ['all'])}: {e['new_rows']} rows, "
                             f"{e['started']} to {e['ended']} ({_f(e.get('wall_seconds'), '{:.0f}')} s wall), "
                             f"load average {(e.get('load_start') or ['?'])[0]} at the start, "
                             f"{(e.get('load_end') or ['?'])[0]} at the end; "
                             f"code {revision_label(e)}. {e.get('note', '')}".rstrip())
    held = [r for r in rows if r["item"] not in DEV_PAIRS]
    hs = summarize_methods(held)
    lines += [
        "",
        f"## Without the development pairs ({', '.join(DEV_PAIRS)})",
        "",
        "The thesis presets' left/right decision was developed on these three pairs; the means below leave "
        "them out (earlier sessions also looked at the whole 24-pair set, see benchmarks/results/).",
        "",
        "| method | pairs | " + " | ".join(f"r = {r:g}" for r in RS) + " | recall | precision | mean error | "
        "flipped |",
        "|---|---|" + "---|" * (len(RS) + 4),
    ]
    for n in _ordered(hs):
        s = hs[n]
        lines.append(f"| {n} | {s['pairs']} | " + " | ".join(_f(s[f'r_smooth@{r:g}']) for r in RS)
                     + f" | {_f(s['label_recall'], '{:.4f}')} | {_f(s['label_precision'], '{:.4f}')} | "
                     f"{_f(s['mean_geodesic_error'], '{:.4f}')} | {_f(s['flipped'], '{}')} |")
    lines += ["", "## Per pair: mean geodesic error / r-smooth@0.8 / recall", "",
              "| pair | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    cell = {(_short(r), r["item"]): r for r in rows}
    for item in sorted({r["item"] for r in rows}):
        vals = []
        for n in names:
            r = cell.get((n, item))
            if r is None:
                vals.append("")
            elif r.get("status") != "ok":
                vals.append("failed")
            else:
                m = r.get("metrics") or {}
                vals.append(f"{_f(m.get('mean_geodesic_error'), '{:.3f}')} / {_f(m.get('r_smooth@0.8'))} / "
                            f"{_f(m.get('label_recall'), '{:.2f}')}" + (" (flip)" if flipped(r) else ""))
        lines.append(f"| {item} | " + " | ".join(vals) + " |")
    (out / "results.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    doc = {"methods": summ, "ground_truth_map": tsum, "without_dev_pairs": hs, "runs": [str(r) for r in runs]}
    (out / "results.json").write_text(json.dumps(doc, indent=1, default=str) + "\n", encoding="utf-8")
    return summ


def paired(rows: list[dict], a: str, b: str, col: str) -> tuple[float, float, int]:
    """Mean over the pairs both methods matched of ``a``'s minus ``b``'s ``col``, its standard error
    (std of the per-pair differences / sqrt(pairs)) and the number of pairs."""
    val: dict[tuple[str, str], float] = {}
    for r in rows:
        v = (r.get("metrics") or {}).get(col)
        if r.get("status") == "ok" and isinstance(v, (int, float)) and math.isfinite(v):
            val[(_short(r), r["item"])] = float(v)
    d = np.array([val[(a, i)] - val[(b, i)] for (m, i) in val if m == a and (b, i) in val])
    if d.size == 0:
        return float("nan"), float("nan"), 0
    se = float(d.std(ddof=1) / np.sqrt(d.size)) if d.size > 1 else float("nan")
    return float(d.mean()), se, int(d.size)


def verdict(summ: dict[str, dict[str, Any]], rows: list[dict] | None = None) -> list[str]:
    """Markdown bullets: where each thesis preset beats or misses ``zoomout`` and ``pyfm`` on the
    Table 7.2/7.3 columns (with ``rows``: which of those differences exceed twice their paired
    standard error over the pairs), and whether the thesis's ordering (proposed > [Ovsjanikov
    2010] > [Mateus 2008] on Table 7.2's means, proposed > [Mateus 2008] on Table 7.3) is reproduced."""
    cols = [f"r_smooth@{r:g}" for r in RS] + ["label_recall", "label_precision"]
    peers = [p for p in ("zoomout", "pyfm") if p in summ]
    out = []
    for preset in ("topo-robust", "sharma2012"):
        if preset not in summ:
            out.append(f"- `{preset}`: no rows.")
            continue
        s = summ[preset]
        wins = [c for c in cols if peers and all(s[c] > summ[p][c] for p in peers)]
        losses = [c for c in cols if c not in wins]
        out.append(f"- `{preset}` beats {' and '.join(f'`{p}`' for p in peers)} on {len(wins)} of {len(cols)} "
                   f"columns ({', '.join(wins) or 'none'}); does not on {', '.join(losses) or 'none'}. "
                   f"Mean geodesic error {_f(s['mean_geodesic_error'], '{:.4f}')} vs "
                   + ", ".join(f"{p} {_f(summ[p]['mean_geodesic_error'], '{:.4f}')} "
                               f"({_ratio(s['mean_geodesic_error'], summ[p]['mean_geodesic_error'])})" for p in peers)
                   + f"; flipped pairs {_f(s['flipped'], '{}')}.")
        if rows is not None and peers:
            clear = []
            for c in cols:
                tests = [paired(rows, preset, p, c) for p in peers]
                if all(n > 1 and abs(dm) > 2 * se for dm, se, n in tests):
                    signs = {np.sign(dm) for dm, _, _ in tests}
                    if len(signs) == 1:
                        clear.append(f"{c} {'higher' if signs.pop() > 0 else 'LOWER'} "
                                     f"({', '.join(f'{dm:+.3g} +- {se:.2g}' for dm, se, _ in tests)})")
            out.append(f"  Differences beyond twice their paired standard error against both "
                       f"(per-pair {preset} minus {' / '.join(peers)}): "
                       + ("; ".join(clear) + "; every other column is a tie within that noise." if clear
                          else "none: every column is a tie within that noise."))
    trio = ("topo-robust", "ovsjanikov2010", "mateus2008")
    if all(m in summ for m in trio):
        same = []
        for r in RS:
            ours = sorted(trio, key=lambda m: -summ[m][f"r_smooth@{r:g}"])
            thesis = sorted(("proposed", "ovsjanikov2010", "mateus2008"), key=lambda m: -_thesis_mean(m, r))
            thesis = ["topo-robust" if m == "proposed" else m for m in thesis]
            same.append((r, ours == thesis, " > ".join(ours)))
        n_same = sum(x[1] for x in same)
        n_first = sum(o.startswith("topo-robust") for _, _, o in same)
        out.append(f"- Table 7.2 ordering (thesis: proposed > [Ovsjanikov 2010] > [Mateus 2008] at every r, "
                   f"means of its 6 pairs): reproduced at {n_same} of {len(RS)} r values, topo-robust first of "
                   f"the three at {n_first} of {len(RS)}; here "
                   + "; ".join(f"r = {r:g}: {o}" for r, _, o in same) + ".")
        ratio = [summ["topo-robust"][f"r_smooth@{r:g}"] / _thesis_mean("proposed", r) for r in RS]
        out.append("- Table 7.2 numbers: topo-robust / thesis proposed = "
                   + ", ".join(f"{x:.2f}" for x in ratio) + " at r = " + ", ".join(f"{r:g}" for r in RS) + ".")
    if "topo-robust" in summ and "mateus2008" in summ:
        t, m = summ["topo-robust"], summ["mateus2008"]
        rec, prec = THESIS_73["proposed"]
        ok = t["label_recall"] > m["label_recall"] and t["label_precision"] > m["label_precision"]
        word = "reproduced" if ok else "NOT reproduced"
        out.append(f"- Table 7.3 ordering (thesis: proposed > [Mateus 2008]): {word} "
                   f"(recall {t['label_recall']:.3f} vs {m['label_recall']:.3f}, precision {t['label_precision']:.3f} "
                   f"vs {m['label_precision']:.3f}; thesis {np.mean(rec):.3f}/{np.mean(prec):.3f} vs "
                   f"{np.mean(THESIS_73['mateus2008'][0]):.3f}/{np.mean(THESIS_73['mateus2008'][1]):.3f}).")
    return out


def cmd_report(args: argparse.Namespace) -> int:
    runs = [Path(r) for r in args.runs]
    missing = [str(r) for r in runs if not (r / "results.jsonl").exists()]
    if missing:
        print(f"error: not a run folder: {', '.join(missing)}", file=sys.stderr)
        return 2
    write_results(runs, Path(args.out) if args.out else HERE)
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="run the dense task for some methods into a run folder")
    r.add_argument("-o", "--output", required=True, help="run folder")
    r.add_argument("--methods", help="comma-separated pipeline/peer names (default: all of config.toml)")
    r.add_argument("--limit", type=int, help="first N pairs")
    r.add_argument("-q", "--quiet", action="store_true")
    r.set_defaults(func=cmd_run)
    q = sub.add_parser("report", help="write results.md/.json and results_curves.png from run folders")
    q.add_argument("runs", nargs="+", help="run folders; for a method and pair the last folder's row wins")
    q.add_argument("--out", help="output folder (default: this example's folder)")
    q.set_defaults(func=cmd_report)
    args = p.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
