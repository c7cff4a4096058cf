"""Speed and memory of the dense matchers (issue 6), each case in its own child process.

    python benchmarks/bench_matching.py [--data DIR] [--subdivide S] [--output FILE]

Regenerates ``benchmarks/results/bench_matching.md``. Cases:

- ``em-registration`` and ``seed-growing`` on TOSCA cat0 -> cat1 with every triangle split into
  ``S x S`` (S = 4: 79,968 and 79,968 vertices; ``--subdivide 3`` gives about 45k); 30 seeds from
  the ground truth (original vertices keep their positions, so the ``.vts`` ids are located by
  position). Error = mean normalized Dijkstra geodesic error at every 10th of the 5,000
  ground-truth points (all 5,000 on the 5k pair).
- The full ``sharma2012`` pipeline and ``zoomout`` against pyFM's README pipeline on the 5k-vertex
  pair cat0 -> cat1 (the protocol of ``configs/tosca_matching.toml``).

Time: wall clock and CPU time of the matching call from loaded meshes (spectra included). Peak
memory: ``VmHWM`` of the child minus that of a child that only loads the meshes. One BLAS thread.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

RESULTS = REPO / "benchmarks" / "results"


def _data(arg: str | None) -> Path:
    if arg:
        return Path(arg)
    return Path(os.environ.get("TOOLKIT_DATA", REPO.parent / "shared" / "data"))


def load_pair(tosca: Path, s: int):
    """cat0, cat1 (subdivided ``s x s`` when ``s > 1``) and their ground truth (0-based)."""
    from scipy.spatial import cKDTree

    from shape_toolkit.core.shape import Shape
    from shape_toolkit.data.datasets import read_vts
    from shape_toolkit.io.mesh import load_shape

    out = []
    for name in ("cat0", "cat1"):
        sh = load_shape(tosca / f"{name}.off")
        truth = read_vts(tosca / "corres" / f"{name}.vts", sh.n_vertices)
        if s > 1:
            from bench_eigensolver import subdivide

            v, f = subdivide(np.asarray(sh.vertices), np.asarray(sh.faces), s)
            where = cKDTree(v).query(np.asarray(sh.vertices))[1]
            sh = Shape(v, f, f"{name}x{s}")
            truth = where[truth]
        out.append((sh, truth))
    return out


def peak_rss_mb() -> float:
    """Peak resident memory of this process in MB: ``VmHWM`` (``ru_maxrss`` of a fork+exec child
    would also count the parent's memory at the fork)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def child(case: str, tosca: Path, s: int, out: Path) -> None:
    """Run one case and write its measurements as JSON to ``out``."""
    import warnings

    warnings.filterwarnings("ignore")
    (A, ta), (B, tb) = load_pair(tosca, s)
    res: dict = {"case": case, "n_source": A.n_vertices, "n_target": B.n_vertices}
    if case != "none":
        from shape_toolkit.metrics import geodesic_errors

        seeds = np.column_stack([ta, tb])[np.linspace(0, len(ta) - 1, 30).astype(int)]
        t0, c0 = time.perf_counter(), time.process_time()
        if case == "pyfm":
            from shape_toolkit.bench.peers import pyfm_map

            t = pyfm_map(A, B)
        elif case in ("em-registration", "seed-growing"):
            from shape_toolkit.api.registry import create_plugin

            t = create_plugin("dense_matchers", case).match(A, B, seeds=seeds).target_of
        else:
            from shape_toolkit.pipeline import run_pipeline

            t = run_pipeline(case, A, B).target_of
        res["seconds"] = time.perf_counter() - t0
        res["cpu_seconds"] = time.process_time() - c0
        sub = slice(None, None, 10 if s > 1 else 1)  # 500 truth points on the big meshes
        e = geodesic_errors(B, t, ta[sub], tb[sub], method="dijkstra")
        res["mean_error"] = float(e[np.isfinite(e)].mean())
        res["matched"] = float(np.isfinite(e).mean())
    res["maxrss_mb"] = peak_rss_mb()
    out.write_text(json.dumps(res))


def run_child(case: str, data: Path, s: int) -> dict:
    out = Path(f"/tmp/bench_matching_{os.getpid()}_{case}_{s}.json")
    cmd = [sys.executable, __file__, "--child", case, "--subdivide", str(s), "--data", str(data),
           "--out", str(out)]
    print(f"[{case}, subdivide {s}]", file=sys.stderr, flush=True)
    r = subprocess.run(cmd)
    if r.returncode != 0:
        return {"case": case, "error": f"exit code {r.returncode}"}
    res = json.loads(out.read_text())
    out.unlink()
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data")
    ap.add_argument("--subdivide", type=int, default=4)
    ap.add_argument("--output", default=str(RESULTS / "bench_matching.md"))
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    data = _data(args.data)
    tosca = data / "tosca5k"
    if args.child:
        child(args.child, tosca, args.subdivide, Path(args.out))
        return 0
    if not (tosca / "cat0.off").exists():
        print(f"TOSCA data not found at {tosca}", file=sys.stderr)
        return 2
    t0 = time.time()
    rows = []
    big = args.subdivide
    base_big = run_child("none", data, big)
    for case in ("em-registration", "seed-growing"):
        r = run_child(case, data, big)
        r["peak_mb"] = r.get("maxrss_mb", 0) - base_big["maxrss_mb"]
        rows.append(r)
    base = run_child("none", data, 1)
    for case in ("sharma2012", "zoomout", "pyfm"):
        r = run_child(case, data, 1)
        r["peak_mb"] = r.get("maxrss_mb", 0) - base["maxrss_mb"]
        rows.append(r)
    lines = [
        "# Matching speed and memory",
        "",
        f"Regenerate: `python benchmarks/bench_matching.py --subdivide {big}` "
        f"({(time.time() - t0) / 60:.1f} min on a shared 2-core machine, one BLAS thread). "
        "Protocol in the script's docstring.",
        "",
        "| case | source / target vertices | wall s | CPU s | peak MB | mean error | matched |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['case']} | - | failed: {r['error']} | - | - | - | - |")
            continue
        lines.append(
            f"| {r['case']} | {r['n_source']:,} / {r['n_target']:,} | {r['seconds']:.2f} | "
            f"{r['cpu_seconds']:.2f} | "
            f"{r['peak_mb']:.0f} | {r['mean_error']:.4f} | {100 * r['matched']:.1f}% |"
        )
    sh = next((r for r in rows if r["case"] == "sharma2012" and "seconds" in r), None)
    py = next((r for r in rows if r["case"] == "pyfm" and "seconds" in r), None)
    if sh and py:
        lines += ["", f"sharma2012 / pyFM on the 5k pair: wall {sh['seconds'] / py['seconds']:.2f}x, "
                  f"CPU {sh['cpu_seconds'] / py['cpu_seconds']:.2f}x (CPU time is what a loaded shared "
                  "machine distorts least)."]
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    Path(args.output).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
