"""Where the CPU time of a 5k-vertex match goes: the `zoomout` preset and pyFM's README pipeline,
stage by stage.

    python benchmarks/profile_matching.py [--data DIR] [--pairs faust5k:tr_reg_000:tr_reg_001,...]
                                          [--repeat R] [--output FILE]

Regenerates ``benchmarks/results/matching_profile.md`` and ``.json``.

Protocol: each (method, pair) runs in a fresh child process (empty spectrum cache, one BLAS thread
unless ``OPENBLAS_NUM_THREADS`` is set), under ``cProfile`` with ``time.process_time`` as its
clock, so the stage times are CPU seconds and robust to other load on the machine; a stage is the
cumulative time of the functions listed in ``STAGES`` (a function called inside another stage
counts in both only where said). The ZoomOut final point map (every source vertex against every
target vertex, the last call) is timed apart by a wrapper around ``features.basis._point_map``.
The best of ``--repeat`` runs (by total) is kept.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import cProfile  # noqa: E402
import json  # noqa: E402
import multiprocessing  # noqa: E402
import pstats  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
RESULTS = REPO / "benchmarks" / "results"
DEFAULT_PAIRS = "faust5k:tr_reg_000:tr_reg_001,tosca5k:cat0:cat1"

#: stage -> (module path fragment, function name) whose cumulative CPU time is the stage's
STAGES = {
    "zoomout": [
        ("spectra (both shapes)", "core/spectrum.py", "compute_spectrum"),
        ("WKS descriptors (both)", "plugins/descriptors/wks.py", "wave_kernel_signature"),
        ("descriptor compression", "features/basis.py", "compress_descriptors"),
        ("orientation operators (both)", "features/basis.py", "orientation_operators"),
        ("functional map fit (incl. multiplication operators)", "features/basis.py", "fit_functional_map"),
        ("farthest point samples (both)", "core/geometry.py", "farthest_point_sampling"),
        ("ZoomOut: point maps (nearest neighbours)", "features/basis.py", "_point_map"),
        ("ZoomOut: functional maps from point maps", "features/basis.py", "fmap_from_p2p"),
        ("ZoomOut total (incl. final point map)", "features/basis.py", "zoomout"),
    ],
    "pyfm": [
        ("spectra (both shapes, 200 eigenpairs)", "mesh/trimesh.py", "process"),
        ("WKS descriptors (both)", "pyFM/functional.py", "compute_spectral_descriptors"),
        ("descriptor multiplication operators", "pyFM/functional.py", "_compute_descr_op"),
        ("orientation operators", "pyFM/functional.py", "_compute_orientation_op"),
        ("functional map fit (L-BFGS-B, incl. operators)", "pyFM/functional.py", "fit"),
        ("ZoomOut iterations", "pyFM/functional.py", "zoomout_refine"),
        ("final point map", "pyFM/functional.py", "get_p2p"),
    ],
}


def _cumulative(stats: pstats.Stats, fragment: str, name: str) -> tuple[float, int]:
    """Cumulative CPU seconds and primitive call count of the functions ``name`` whose file path
    contains ``fragment`` (outermost calls only: recursion is not double counted by cProfile)."""
    tot, calls = 0.0, 0
    for (fname, _line, func), (cc, _nc, _tt, ct, _callers) in stats.stats.items():  # type: ignore[attr-defined]
        if func == name and fragment in fname.replace("\\", "/"):
            tot += ct
            calls += cc
    return tot, calls


def child(method: str, data: Path, ds: str, a: str, b: str) -> dict:
    """Profile one match in this (fresh) process; returns the stage table."""
    import warnings

    warnings.filterwarnings("ignore")
    from threadpoolctl import threadpool_info

    from shape_toolkit.io.mesh import load_shape

    A, B = load_shape(data / ds / f"{a}.off"), load_shape(data / ds / f"{b}.off")
    final = {"cpu": 0.0}  # CPU of the last point map (the final one: every source vertex)
    if method == "zoomout":
        from shape_toolkit.features import basis as fz  # ZoomOut looks its point map up there
        from shape_toolkit.pipeline import load_pipeline

        inner = fz._point_map

        def timed_point_map(C, emb_s, emb_t):
            c0 = time.process_time()
            out = inner(C, emb_s, emb_t)
            final["cpu"] = time.process_time() - c0
            return out

        fz._point_map = timed_point_map
        pipe = load_pipeline("zoomout")

        def run():
            return pipe.run(A, B).target_of
    else:
        from shape_toolkit.bench.peers import pyfm_map

        def run():
            return pyfm_map(A, B)

    prof = cProfile.Profile(time.process_time)
    c0, w0 = time.process_time(), time.perf_counter()
    prof.enable()
    run()
    prof.disable()
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    stats = pstats.Stats(prof)
    rows = []
    for label, frag, name in STAGES[method]:
        t, calls = _cumulative(stats, frag, name)
        rows.append({"stage": label, "function": name, "calls": calls, "cpu_seconds": t})
    if method == "zoomout":
        rows.append({"stage": "ZoomOut: final point map (all vertices, in the two rows above)",
                     "function": "_point_map", "calls": 1, "cpu_seconds": final["cpu"]})
    blas = [{"api": i.get("internal_api"), "threads": i.get("num_threads")} for i in threadpool_info()]
    return {"method": method, "pair": f"{a}-{b}", "dataset": ds, "n": [A.n_vertices, B.n_vertices],
            "cpu_seconds": cpu, "wall_seconds": wall, "stages": rows, "blas": blas}


def _in_child(fn, *args) -> dict:
    """``fn(*args)`` in a fresh (spawned) process, or ``{"error": ...}`` when it fails."""
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        try:
            return pool.submit(fn, *args).result()
        except Exception as exc:  # noqa: BLE001 - a failed run is reported, the others go on
            return {"error": f"{type(exc).__name__}: {exc}"}


def write_results(profiles: list[dict], output: Path) -> None:
    """The markdown report at ``output`` and its data beside it (``.json``)."""
    from shape_toolkit.bench.report import markdown_table

    output.parent.mkdir(parents=True, exist_ok=True)
    output.with_suffix(".json").write_text(json.dumps({"profiles": profiles}, indent=1))
    blas = next((p["blas"] for p in profiles if "blas" in p), [])
    lines = [
        "# Where a 5k-vertex match spends its CPU time (`zoomout` preset and pyFM's README pipeline)",
        "",
        "Regenerate: `python benchmarks/profile_matching.py` (protocol in its docstring: fresh process per "
        "run, empty spectrum cache, cProfile with a CPU clock, best of the repeats).",
        "BLAS: " + (", ".join(f"{b['api']} {b['threads']} thread(s)" for b in blas) or "unknown") + ". "
        "CPU seconds (process time); wall seconds depend on the load of the shared 2-core machine.",
        "",
    ]
    for p in profiles:
        if "error" in p:
            lines += [f"- {p.get('method')} {p.get('pair')}: failed ({p['error']})", ""]
            continue
        lines += [
            f"## {p['method']}: {p['dataset']} {p['pair']} ({p['n'][0]} -> {p['n'][1]} vertices)",
            "",
            f"Total: **{p['cpu_seconds']:.2f} s CPU** ({p['wall_seconds']:.2f} s wall).",
            "",
        ]
        total = p["cpu_seconds"] if p["cpu_seconds"] > 0 else float("nan")
        lines += markdown_table(["stage", "function", "calls", "CPU s", "share"], [
            [r["stage"], f"`{r['function']}`", r["calls"], f"{r['cpu_seconds']:.3f}",
             f"{100 * r['cpu_seconds'] / total:.0f}%"] for r in p["stages"]], escape=False) + [""]
    output.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=os.environ.get("TOOLKIT_DATA", str(REPO.parent / "shared" / "data")),
                    help="shared data directory (default $TOOLKIT_DATA or ../shared/data)")
    ap.add_argument("--pairs", default=DEFAULT_PAIRS, help="comma-separated dataset:A:B")
    ap.add_argument("--methods", default="zoomout,pyfm")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--output", default=str(RESULTS / "matching_profile.md"))
    args = ap.parse_args(argv)
    data = Path(args.data)
    pairs = [tuple(p.split(":")) for p in args.pairs.split(",") if p.strip()]
    if not all((data / ds / f"{a}.off").exists() for ds, a, _ in pairs):
        print(f"data not found under {data}: pass --data or set TOOLKIT_DATA", file=sys.stderr)
        return 2
    profiles = []
    for ds, a, b in pairs:
        for method in [m.strip() for m in args.methods.split(",") if m.strip()]:
            runs = [_in_child(child, method, data, ds, a, b) for _ in range(max(1, args.repeat))]
            ok = [r for r in runs if "error" not in r]
            best = min(ok, key=lambda r: r["cpu_seconds"]) if ok else {**runs[0], "method": method, "pair": f"{a}-{b}"}
            profiles.append(best)
            print(f"[{method} {a}-{b}] {best.get('cpu_seconds', float('nan')):.2f} s CPU", file=sys.stderr, flush=True)
    write_results(profiles, Path(args.output))
    return 0


if __name__ == "__main__":
    sys.exit(main())
