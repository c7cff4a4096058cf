"""Defaults sweep (issue 11): every plugin with its defaults on every real shape, failures listed.

    python benchmarks/sweep.py                      # all shapes of tosca5k, faust5k, psb (long)
    python benchmarks/sweep.py --limit 3            # the first 3 shapes of each dataset
    python benchmarks/sweep.py --shapes tosca5k/cat0 psb/27 --no-report

For every shape: each weighting builds a graph and a 30-eigenpair spectrum (the combinatorial
Laplacian, with the mass matrix when the weighting has one), then every keypoint detector,
descriptor and segmenter runs through ``shape_toolkit.create_plugin(family, name)`` with its defaults
and no spectrum (so it computes its declared one). Each shape runs in its own subprocess (a crash or
a hang costs one shape, not the sweep) and each call has a wall-clock timeout. Matching pipelines
(``--pairs N``) run ``run_pipeline(preset, a, b)`` on the first N test pairs of each dataset.

Results are appended as JSON lines to ``--work-dir`` (resumable: shapes already done are skipped,
``--fresh`` starts over); ``benchmarks/results/sweep.md`` is regenerated from them.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
import traceback
from pathlib import Path

_REPO = Path(__file__).resolve().parent.parent
DATASETS = ("tosca5k", "faust5k", "psb")
SPECTRUM_K = 30
#: families whose plugins run on one shape (matchers need two: they run through the pipelines)
SHAPE_FAMILIES = ("keypoints", "descriptors", "segmenters")
#: plugins that cannot run without user input, with the reason (reported, not run)
#: keypoint descriptors get the keypoints of the default detector (as in the thesis pipeline, ch. 7)
KEYPOINT_DESCRIPTORS = ("heat-diffusion", "heat-distance")
#: required parameters without a default, given explicitly (reported in the output)
REQUIRED_PARAMS = {("segmenters", "csc"): {"n_segments": 6}, ("segmenters", "ncut"): {"n_segments": 6}}
NEEDS_INPUT = {
    ("segmenters", "ccskl"): "needs user constraints (must-link/cannot-link pairs)",
    ("segmenters", "spectral-learning"): "needs user constraints (labelled vertices)",
    ("segmenters", "seeded-walk"): "needs user constraints (one must-link group per segment)",
}


def data_root() -> Path:
    env = os.environ.get("TOOLKIT_DATA")
    return Path(env) if env else _REPO.parent / "shared" / "data"


def shape_path(root: Path, name: str) -> Path:
    ds, stem = name.split("/", 1)
    return root / ds / ("off" if ds == "psb" else "") / f"{stem}.off"


def list_shapes(root: Path, limit: int | None = None) -> list[str]:
    """Shape names ``dataset/stem``, interleaved across datasets (a partial run covers all three)."""
    per = []
    for ds in DATASETS:
        d = root / ds / ("off" if ds == "psb" else "")
        stems = sorted((p.stem for p in d.glob("*.off")), key=lambda s: (len(s), s))
        per.append([f"{ds}/{s}" for s in stems[:limit]])
    out = []
    for i in range(max(map(len, per), default=0)):
        out.extend(lst[i] for lst in per if i < len(lst))
    return out


def list_pairs(root: Path, n: int) -> list[tuple[str, str]]:
    out = []
    for ds in ("tosca5k", "faust5k"):
        f = root / ds / "pairs.txt"
        if f.exists():
            rows = [ln.split() for ln in f.read_text().splitlines() if ln.strip()]
            out.extend((f"{ds}/{a}", f"{ds}/{b}") for a, b in rows[:n])
    return out


def plugin_names() -> dict[str, list[str]]:
    from shape_toolkit.api.registry import available_plugins

    return {k: sorted(v) for k, v in available_plugins().items()}


# -- one shape, in a worker process ------------------------------------------------------------
class _Timeout(Exception):
    pass


def _alarm(signum, frame):  # noqa: ARG001
    raise _Timeout()


def _run(task: str, fn, timeout: float) -> dict:
    t0 = time.perf_counter()
    signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout)
    row: dict = {"task": task}
    try:
        row["summary"] = fn()
        row["ok"] = True
    except _Timeout:
        row.update(ok=False, error="Timeout", message=f"no result within {timeout:g} s")
    except Exception as exc:  # noqa: BLE001 - the sweep records every failure
        row.update(ok=False, error=type(exc).__name__, message=str(exc).splitlines()[0][:400] if str(exc) else "",
                   where=traceback.format_exc().strip().splitlines()[-3].strip()[:200])
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
    row["seconds"] = round(time.perf_counter() - t0, 2)
    return row


def worker_shape(name: str, timeout: float, out) -> None:
    import numpy as np

    from shape_toolkit import create_plugin
    from shape_toolkit.core.spectrum import compute_spectrum
    from shape_toolkit.io.mesh import load_shape
    from shape_toolkit.spectra import build_graph

    shape = load_shape(shape_path(data_root(), name))
    names = plugin_names()

    def emit(row):
        row["shape"] = name
        out.write(json.dumps(row) + "\n")
        out.flush()

    def weighting(w):
        def fn():
            g = build_graph(shape, w)
            s = compute_spectrum(g, min(SPECTRUM_K, shape.n_vertices))
            return f"lambda_1..3 = {', '.join(f'{x:.3g}' for x in s.eigenvalues[:3])}"
        return fn

    for w in names.get("weightings", []):
        emit(_run(f"weightings/{w}", weighting(w), timeout))

    def plugin(family, p):
        def fn():
            obj = create_plugin(family, p, **REQUIRED_PARAMS.get((family, p), {}))
            if family == "keypoints":
                r = obj.detect(shape)
                return f"{len(r)} keypoints"
            if family == "descriptors":
                kp = (create_plugin("keypoints", "adf-maxima", "thesis-sparse").detect(shape)  # as in its results
                      if p in KEYPOINT_DESCRIPTORS else None)
                r = obj.compute(shape, keypoints=kp)
                if not np.isfinite(r).all():
                    raise ValueError("non-finite descriptor values")
                return f"shape {tuple(r.shape)}"
            r = obj.segment(shape)
            return f"{r.n_segments} segments"
        return fn

    for family in SHAPE_FAMILIES:
        for p in names.get(family, []):
            if (family, p) in NEEDS_INPUT:
                emit({"task": f"{family}/{p}", "ok": None, "message": NEEDS_INPUT[family, p], "seconds": 0})
                continue
            emit(_run(f"{family}/{p}", plugin(family, p), timeout))


def worker_pair(a: str, b: str, presets: list[str], timeout: float, out) -> None:
    from shape_toolkit.io.mesh import load_shape
    from shape_toolkit.pipeline import run_pipeline

    root = data_root()
    sa, sb = load_shape(shape_path(root, a)), load_shape(shape_path(root, b))
    for preset in presets:
        def fn(preset=preset):
            c = run_pipeline(preset, sa, sb)
            return type(c).__name__
        row = _run(f"pipeline/{preset}", fn, timeout)
        row["shape"] = f"{a} -> {b}"
        out.write(json.dumps(row) + "\n")
        out.flush()


# -- driver ------------------------------------------------------------------------------------
def _done(path: Path) -> set[str]:
    if not path.exists():
        return set()
    return {json.loads(ln)["shape"] for ln in path.read_text().splitlines() if ln.strip()}


def _spawn(args: list[str], log: Path, budget: float) -> str | None:
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    try:
        p = subprocess.run([sys.executable, __file__, *args, "--out", str(log)], stdout=subprocess.DEVNULL,
                           stderr=subprocess.PIPE, env=env, timeout=budget, text=True)
    except subprocess.TimeoutExpired:
        return f"worker killed after {budget:g} s"
    if p.returncode != 0:
        return f"worker exited with {p.returncode}: {(p.stderr or '').strip().splitlines()[-1:]}"
    return None


def drive(args) -> None:
    root = data_root()
    work = Path(args.work_dir)
    work.mkdir(parents=True, exist_ok=True)
    log = work / "rows.jsonl"
    if args.fresh and log.exists():
        log.unlink()
    shapes = args.shapes or list_shapes(root, args.limit)
    done = _done(log)
    n_tasks = 4 + 8 + 8
    for i, name in enumerate(shapes):
        if name in done:
            continue
        t0 = time.perf_counter()
        err = _spawn(["--worker", name, "--timeout", str(args.timeout)], log, args.timeout * n_tasks)
        if err:
            with open(log, "a") as fh:
                fh.write(json.dumps({"shape": name, "task": "worker", "ok": False, "error": "WorkerError",
                                     "message": err, "seconds": round(time.perf_counter() - t0, 1)}) + "\n")
        print(f"[{i + 1}/{len(shapes)}] {name} {time.perf_counter() - t0:.0f}s {err or ''}", flush=True)
    presets = args.presets or sorted(__import__("shape_toolkit.pipeline", fromlist=["PRESETS"]).PRESETS)
    for a, b in list_pairs(root, args.pairs):
        if f"{a} -> {b}" in done:
            continue
        err = _spawn(["--worker-pair", a, b, "--timeout", str(args.timeout), "--presets", *presets], log,
                     args.timeout * len(presets))
        if err:
            with open(log, "a") as fh:
                fh.write(json.dumps({"shape": f"{a} -> {b}", "task": "worker", "ok": False,
                                     "error": "WorkerError", "message": err}) + "\n")
        print(f"pair {a} -> {b} {err or ''}", flush=True)
    if not args.no_report:
        report(log, Path(args.report), " ".join(sys.argv[1:]))


def report(log: Path, out: Path, argv: str) -> None:
    rows = [json.loads(ln) for ln in log.read_text().splitlines() if ln.strip()]
    shapes = sorted({r["shape"] for r in rows if "->" not in r["shape"]})
    pairs = sorted({r["shape"] for r in rows if "->" in r["shape"]})
    fails = [r for r in rows if r.get("ok") is False]
    skipped = sorted({(r["task"], r["message"]) for r in rows if r.get("ok") is None})
    per_ds = {ds: sum(s.startswith(ds + "/") for s in shapes) for ds in DATASETS}
    tasks = sorted({r["task"] for r in rows})
    lines = [
        "# Defaults sweep (issue 11)",
        "",
        "Regenerate: `python benchmarks/sweep.py " + (argv or "") + "`" if argv else
        "Regenerate: `python benchmarks/sweep.py`",
        "(`--work-dir` keeps the raw JSON lines; the run resumes where it stopped.)",
        "",
        f"Shapes: {len(shapes)} ({', '.join(f'{ds} {n}' for ds, n in per_ds.items())}); pairs: {len(pairs)}; "
        f"calls: {sum(r.get('ok') is not None for r in rows)}, failures: {len(fails)}.",
        "",
        "Every weighting builds a graph and a 30-eigenpair spectrum; every keypoint detector, descriptor and "
        "segmenter runs with its defaults and no spectrum (it computes its declared one).",
        "",
        "## Per task",
        "",
        "| task | ok | failed | median s | max s |",
        "|---|---|---|---|---|",
    ]
    for t in tasks:
        rs = [r for r in rows if r["task"] == t and r.get("ok") is not None]
        if not rs:
            continue
        secs = sorted(r.get("seconds", 0) for r in rs)
        lines.append(f"| {t} | {sum(bool(r['ok']) for r in rs)} | {sum(r['ok'] is False for r in rs)} | "
                     f"{secs[len(secs) // 2]:.1f} | {secs[-1]:.1f} |")
    lines += ["", "Keypoint descriptors (" + ", ".join(KEYPOINT_DESCRIPTORS) + ") get the `adf-maxima` keypoints; "
              "required parameters given explicitly: " + "; ".join(f"`{f}/{n}` {kw}" for (f, n), kw in
                                                                   REQUIRED_PARAMS.items()) + "."]
    if skipped:
        lines += ["", "Not run (need user input): " + "; ".join(f"`{t}` ({m})" for t, m in skipped) + "."]
    lines += ["", "## Failures", ""]
    if not fails:
        lines.append("None.")
    else:
        lines += ["| shape | task | error | message |", "|---|---|---|---|"]
        for r in sorted(fails, key=lambda r: (r["task"], r["shape"])):
            msg = (r.get("message") or "").replace("|", "\\|")
            lines.append(f"| {r['shape']} | {r['task']} | {r.get('error')} | {msg} |")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    print(out.read_text())


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shapes", nargs="*", help="dataset/stem names (default: every shape)")
    ap.add_argument("--limit", type=int, default=None, help="first N shapes of each dataset")
    ap.add_argument("--pairs", type=int, default=0, help="matching pipelines on the first N pairs per dataset")
    ap.add_argument("--presets", nargs="*", help="pipeline presets (default: all)")
    ap.add_argument("--timeout", type=float, default=120.0, help="seconds per call")
    ap.add_argument("--work-dir", default=os.path.join(os.environ.get("TMPDIR", "/tmp"), "shape_toolkit_sweep"),
                    help="raw results (JSON lines)")
    ap.add_argument("--report", default=str(_REPO / "benchmarks" / "results" / "sweep.md"))
    ap.add_argument("--fresh", action="store_true", help="forget earlier raw results")
    ap.add_argument("--no-report", action="store_true")
    ap.add_argument("--report-only", action="store_true", help="regenerate the report from the raw results")
    ap.add_argument("--out", help=argparse.SUPPRESS)
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--worker-pair", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        with open(args.out, "a") as out:
            worker_shape(args.worker, args.timeout, out)
    elif args.worker_pair:
        with open(args.out, "a") as out:
            worker_pair(*args.worker_pair, args.presets, args.timeout, out)
    elif args.report_only:
        report(Path(args.work_dir) / "rows.jsonl", Path(args.report), "")
    else:
        drive(args)


if __name__ == "__main__":
    main()
