"""The `zoomout` presets against pyFM's README pipeline on every tosca5k and faust5k pair, in one run:
mean geodesic error and CPU time per 5k pair, tuning and held-out splits reported apart.

    python benchmarks/zoomout_vs_pyfm.py [--data DIR] [--datasets tosca5k,faust5k]
                                         [--split all|tuning|held-out] [--every N]
                                         [--methods zoomout,zoomout-fast,pyfm] [--truth-step S]
                                         [--fresh]
    python benchmarks/zoomout_vs_pyfm.py --report-only   # the markdown from the saved rows

Regenerates ``benchmarks/results/zoomout_vs_pyfm.md`` from the raw rows in ``zoomout_vs_pyfm.jsonl``
(one row per pair and method, appended as they come; a pair already in the file is skipped unless
``--fresh``).

Protocol:

- Pairs (A, B) of ``pairs.txt`` (24 tosca5k, 97 faust5k). Split: a pair is a *tuning* pair when
  ``int(sha256("A-B").hexdigest(), 16) % 3 == 0`` (8 tosca, 30 faust), else *held-out* (16 tosca, 67
  faust). The presets' parameters were chosen looking at tuning pairs only; held-out numbers are the
  result. ``--every N`` keeps every N-th pair of each dataset and split (file order), a deterministic
  subset for a short run.
- Map A -> B. Error of ground-truth point i: Dijkstra geodesic distance on B (mesh edges) between the
  image of ``A.vts[i]`` and ``B.vts[i]``, divided by sqrt(area(B)); mean over every ``S``-th of the
  5,000 ground-truth points (``--truth-step``, default 5: 1,000 points, to keep the geodesic rows
  affordable on the shared machine).
  Symmetric-aware: the smaller of the errors to ``B.vts[i]`` and ``B.sym.vts[i]``. A pair is
  *flipped* when its mean error exceeds twice its symmetric-aware error plus 0.02.
- Time: from two loaded meshes to the vertex map, spectra included (the toolkit's spectrum cache is
  cleared before every call, and pyFM computes its own 200 eigenpairs). CPU time is
  ``time.process_time`` around the call and is what the ratios use: it is robust to the other work
  on the shared 2-core machine; wall time is reported too. One process per dataset runs every
  method on a pair back to back, then scores all their maps with one pass of geodesic rows. The
  BLAS library and its thread count are read with threadpoolctl and written in the report.
- pyFM: ``pyfmaps`` 1.3.1 README quick start, ``benchmarks/tosca_matching.run_pyfm`` (WKS,
  ``subsample_step=2``, K=30, w_descr=1, w_lap=0.1, w_dcomm=1, w_orient=1, ZoomOut nit=16 step=5,
  ``get_p2p``).
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))
RESULTS = REPO / "benchmarks" / "results"
RAW = RESULTS / "zoomout_vs_pyfm.jsonl"
METHODS = ["zoomout", "zoomout-fast", "pyfm"]
DATASETS = ["tosca5k", "faust5k"]


def _data(arg: str | None) -> Path:
    if arg:
        return Path(arg)
    return Path(os.environ.get("TOOLKIT_DATA", REPO.parent / "shared" / "data"))


def split_of(a: str, b: str) -> str:
    """``"tuning"`` or ``"held-out"``: a fixed hash of the pair name, a third of the pairs tune."""
    return "tuning" if int(hashlib.sha256(f"{a}-{b}".encode()).hexdigest(), 16) % 3 == 0 else "held-out"


def read_pairs(data: Path, dataset: str) -> list[tuple[str, str]]:
    """The (A, B) names of ``pairs.txt``, in file order."""
    out = []
    for line in (data / dataset / "pairs.txt").read_text().splitlines():
        if line.strip():
            a, b = line.split()
            out.append((a, b))
    return out


def select_pairs(data: Path, dataset: str, split: str, every: int) -> list[tuple[str, str]]:
    """The pairs of ``dataset`` in ``split`` (``all``, ``tuning``, ``held-out``), every ``every``-th
    of each split in file order."""
    out = []
    for s in ("tuning", "held-out"):
        if split in ("all", s):
            out += [p for p in read_pairs(data, dataset) if split_of(*p) == s][:: max(1, every)]
    return out


def _blas() -> list[dict]:
    from threadpoolctl import threadpool_info

    return [{"api": i.get("internal_api"), "threads": i.get("num_threads")} for i in threadpool_info()]


def run_dataset(data: Path, dataset: str, pairs: list[tuple[str, str]], methods: list[str],
                truth_step: int = 5) -> None:
    """Run ``methods`` on ``pairs`` of ``dataset`` and append one row per (pair, method) to RAW."""
    warnings.filterwarnings("ignore")
    import pyFM.functional  # noqa: F401  (imports outside the timed calls)
    from tosca_matching import run_pyfm

    from shape_toolkit.core.spectrum import clear_cache
    from shape_toolkit.data.datasets import read_vts
    from shape_toolkit.io.mesh import load_shape
    from shape_toolkit.metrics.correspondence import paired_geodesic_distances
    from shape_toolkit.pipeline import load_pipeline

    pipes = {m: load_pipeline(m) for m in methods if m != "pyfm"}
    blas = _blas()
    d = data / dataset
    for a, b in pairs:
        A, B = load_shape(d / f"{a}.off"), load_shape(d / f"{b}.off")
        maps, times = {}, {}
        for m in methods:
            clear_cache()
            c0, w0 = time.process_time(), time.perf_counter()
            t = run_pyfm(A, B) if m == "pyfm" else pipes[m].run(A, B).target_of
            times[m] = (time.process_time() - c0, time.perf_counter() - w0)
            maps[m] = np.asarray(t, dtype=np.int64)
        step = max(1, truth_step)
        ta = read_vts(d / "corres" / f"{a}.vts", A.n_vertices)[::step]
        tb = read_vts(d / "corres" / f"{b}.vts", B.n_vertices)[::step]
        tbs = read_vts(d / "corres" / f"{b}.sym.vts", B.n_vertices)[::step]
        preds = np.column_stack([maps[m][ta] for m in methods])
        dist = paired_geodesic_distances(B, np.concatenate([tb, tbs]), np.vstack([preds, preds]), method="dijkstra")
        scale = np.sqrt(B.area)
        e, es = dist[: len(tb)] / scale, dist[len(tb):] / scale
        es = np.minimum(e, es)
        with RAW.open("a") as fh:
            for c, m in enumerate(methods):
                row = {"dataset": dataset, "pair": f"{a}-{b}", "split": split_of(a, b), "method": m,
                       "cpu_seconds": times[m][0], "wall_seconds": times[m][1],
                       "mean_error": float(e[:, c].mean()), "mean_error_symmetric": float(es[:, c].mean()),
                       "n_vertices": [A.n_vertices, B.n_vertices], "truth_points": int(len(tb)), "blas": blas}
                fh.write(json.dumps(row) + "\n")
        print(f"  {dataset} {a}-{b}: " + ", ".join(
            f"{m} {e[:, c].mean():.4f} ({times[m][0]:.2f} s CPU)" for c, m in enumerate(methods)),
            file=sys.stderr, flush=True)


#: what the stage-swapping runs showed (a scratch harness that swapped single stages between the
#: two pipelines, pyFM's own maps as reference) and the first run of this benchmark
NOTES = [
    "## Why FAUST was worse, and what changed",
    "",
    "- The old default ran ZoomOut on 2000 farthest-point samples of *both* shapes, so every iteration fitted"
    " C by least squares on the samples. On FAUST tuning pairs where both methods are right this cost 5-15%"
    " (tr_reg_000-006: 0.0259 against pyFM's 0.0221; tr_reg_018-019: 0.0246 against 0.0232). ZoomOut"
    " without sampling, as pyFM's README runs it, gives pyFM's per-pair errors to within 3% on 19 of the 23"
    " FAUST tuning pairs (0.0225, 0.0230 on those two).",
    "- An intermediate version let every source vertex query but matched it to 2000 sampled target vertices."
    " In a first run of this benchmark (16 tosca and 14 faust held-out pairs, same protocol) it was 1.007x"
    " pyFM's error on tosca and 1.28x on faust (4 flipped pairs against pyFM's 2), at 0.22x pyFM's CPU time;"
    " `zoomout-fast` with 1000 target samples was 1.12x and 1.39x at 0.16x. The defaults now sample nothing."
    " That choice was made after seeing those held-out numbers (the unsampled variant had been measured on"
    " tuning pairs only), so for it the held-out split below is not a clean hold-out.",
    "- Not the cause (each swapped in alone on FAUST tuning pairs, < 2% change): pyFM's resolvent Laplacian"
    " mask, its canonical term normalisation, its fixed constant column, its L-BFGS-B instead of the exact"
    " solve, its own eigenbasis (lumped mass, 200 eigenpairs) and its 128-eigenpair WKS.",
    "- Left-right swaps: on a few FAUST pairs *both* pipelines return a swapped map (mean error 0.1-0.37 with"
    " a symmetric-aware error of 0.02-0.09; which of the two is worse varies). The extrinsic triple-product"
    " cue (`matching.orientation.orientation_score`, 500 samples) scores our swapped maps on tr_reg_007-008,"
    " 010-020 and 031-041 at +0.65 to +0.91, i.e. as orientation *preserving*, like the correct ones (+0.76"
    " to +0.97): a fallback on that cue cannot catch them, and a larger orientation weight (3, 10) did not"
    " remove them on the first 8 tuning pairs (3 created a new swap). Not fixed.",
    "- `zoomout-fast`: the same final basis (110) in 8 ZoomOut steps of 10 (default: 16 steps of 5), no"
    " sampling; on 8 FAUST tuning pairs the same mean error as 16 steps of 5 (0.0442 against 0.0441).",
]


def _rows() -> list[dict]:
    if not RAW.exists():
        return []
    return [json.loads(x) for x in RAW.read_text().splitlines() if x.strip()]


def _flipped(r: dict) -> bool:
    return r["mean_error"] > 2 * r["mean_error_symmetric"] + 0.02


def write_report(command: str, output: Path) -> None:
    """The markdown tables from the raw rows (only pairs that every method finished)."""
    rows = _rows()
    methods = [m for m in METHODS if any(r["method"] == m for r in rows)]
    methods += sorted({r["method"] for r in rows} - set(methods))
    by_pair: dict[tuple[str, str], dict[str, dict]] = {}
    for r in rows:
        by_pair.setdefault((r["dataset"], r["pair"]), {})[r["method"]] = r  # last row wins
    complete = {k: v for k, v in by_pair.items() if all(m in v for m in methods)}
    blas = next((r["blas"] for r in rows if r.get("blas")), [])
    lines = [
        "# `zoomout` presets against pyFM's README pipeline (tosca5k, faust5k)",
        "",
        f"Regenerate: `{command}` (then `python benchmarks/zoomout_vs_pyfm.py --report-only`). Protocol: the "
        "docstring of `benchmarks/zoomout_vs_pyfm.py` (A -> B maps, Dijkstra geodesic error on B / sqrt(area B), "
        "spectra included in the times, toolkit cache cleared before every call).",
        "BLAS: " + (", ".join(f"{b['api']} {b['threads']} thread(s)" for b in blas) or "unknown")
        + ". CPU time (`process_time`) is what the ratios use; the machine is a 2-core box shared with other "
        "work, so wall times are inflated by its load.",
        "Tuning split: `sha256(\"A-B\") % 3 == 0`; presets were chosen on tuning pairs, except the decision to "
        "sample nothing in ZoomOut (see the notes). **Held-out is the result.**",
        "",
        "| dataset | split | method | pairs | mean error | vs pyFM | sym-aware error | flipped | CPU s/pair "
        "(mean) | CPU s/pair (median) | CPU vs pyFM | wall s/pair |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    summary = []
    for ds in DATASETS + ["all"]:
        for split in ("held-out", "tuning", "all"):
            keys = [k for k in complete if (ds == "all" or k[0] == ds)
                    and (split == "all" or complete[k][methods[0]]["split"] == split)]
            if not keys:
                continue
            ref = None
            for m in methods:
                rs = [complete[k][m] for k in keys]
                s = {
                    "dataset": ds, "split": split, "method": m, "pairs": len(rs),
                    "mean_error": float(np.mean([r["mean_error"] for r in rs])),
                    "mean_error_symmetric": float(np.mean([r["mean_error_symmetric"] for r in rs])),
                    "flipped": int(sum(_flipped(r) for r in rs)),
                    "cpu_mean": float(np.mean([r["cpu_seconds"] for r in rs])),
                    "cpu_median": float(np.median([r["cpu_seconds"] for r in rs])),
                    "wall_mean": float(np.mean([r["wall_seconds"] for r in rs])),
                }
                if m == "pyfm":
                    ref = s
                summary.append(s)
            for s in summary[-len(methods):]:
                er = s["mean_error"] / ref["mean_error"] if ref else float("nan")
                cr = s["cpu_mean"] / ref["cpu_mean"] if ref else float("nan")
                s["error_vs_pyfm"], s["cpu_vs_pyfm"] = er, cr
                lines.append(
                    f"| {ds} | {split} | {s['method']} | {s['pairs']} | {s['mean_error']:.4f} | {er:.3f}x "
                    f"| {s['mean_error_symmetric']:.4f} | {s['flipped']} | {s['cpu_mean']:.2f} "
                    f"| {s['cpu_median']:.2f} | {cr:.2f}x | {s['wall_mean']:.2f} |")
    lines += [""] + NOTES
    lines += ["", "## Per pair (mean error / CPU s)", "",
              "| dataset | pair | split | " + " | ".join(methods) + " |",
              "|---|---|---|" + "---|" * len(methods)]
    for (ds, p), v in sorted(complete.items()):
        cells = [f"{v[m]['mean_error']:.4f}{' (flipped)' if _flipped(v[m]) else ''} / {v[m]['cpu_seconds']:.2f}"
                 for m in methods]
        lines.append(f"| {ds} | {p} | {v[methods[0]]['split']} | " + " | ".join(cells) + " |")
    output.write_text("\n".join(lines) + "\n")
    output.with_suffix(".json").write_text(json.dumps(summary, indent=1))
    print("\n".join(lines[: 9 + len(summary)]))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", help="shared data directory (default $TOOLKIT_DATA or ../shared/data)")
    ap.add_argument("--datasets", default=",".join(DATASETS))
    ap.add_argument("--split", default="all", choices=["all", "tuning", "held-out"])
    ap.add_argument("--every", type=int, default=1, help="keep every N-th pair of each split")
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--truth-step", type=int, default=5, help="score every S-th ground-truth point")
    ap.add_argument("--fresh", action="store_true", help="rerun pairs already in the raw rows")
    ap.add_argument("--report-only", action="store_true")
    ap.add_argument("--command", help="text of the report's Regenerate line (default: this command)")
    ap.add_argument("--output", default=str(RESULTS / "zoomout_vs_pyfm.md"))
    args = ap.parse_args(argv)
    command = "python benchmarks/zoomout_vs_pyfm.py " + " ".join(
        a for a in (argv if argv is not None else sys.argv[1:]) if a not in ("--report-only", "--fresh"))
    if args.command:
        command = args.command
    if args.report_only:
        write_report(command.strip(), Path(args.output))
        return 0
    data = _data(args.data)
    datasets = [x.strip() for x in args.datasets.split(",") if x.strip()]
    if not all((data / ds / "pairs.txt").exists() for ds in datasets):
        print(f"data not found under {data}: pass --data or set TOOLKIT_DATA", file=sys.stderr)
        return 2
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    done = set() if args.fresh else {(r["dataset"], r["pair"], r["method"]) for r in _rows()}
    for ds in datasets:
        todo = [p for p in select_pairs(data, ds, args.split, args.every)
                if not all((ds, f"{p[0]}-{p[1]}", m) in done for m in methods)]
        print(f"[{ds}] {len(todo)} pairs to run", file=sys.stderr, flush=True)
        run_dataset(data, ds, todo, methods, args.truth_step)
    write_report(command.strip(), Path(args.output))
    return 0


if __name__ == "__main__":
    sys.exit(main())
