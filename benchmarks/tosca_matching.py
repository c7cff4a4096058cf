"""Dense correspondence on TOSCA (24 pairs of ``tosca5k/pairs.txt``): every toolkit pipeline side
by side with pyFM (``pyfmaps`` 1.3.1, its README quick-start pipeline) in one run.

    python benchmarks/tosca_matching.py [--limit N] [--methods zoomout,pyfm,...] [--data DIR]
                                        [--geodesics dijkstra|heat] [--output FILE]

Regenerates ``benchmarks/results/tosca_matching.md``, ``.json`` and ``.png`` (error curves).

Protocol (repeated in the results file):

- Map direction A -> B for each pair (A, B); ground truth ``A.vts[i] <-> B.vts[i]`` (1-based files).
- Error of pair ``i``: geodesic distance on B between the image of ``A.vts[i]`` and ``B.vts[i]``,
  divided by ``sqrt(area(B))`` (Kim et al. 2011). Mean over all ground-truth points, cumulative
  curve on [0, 0.25]. Symmetric-aware error: the smaller of the errors to ``B.vts[i]`` and
  ``B.sym.vts[i]``. Unmatched points (-1) count as failures in the curve and are left out of the
  mean (the ``matched`` column says how many there were).
- Geodesics: the same method for every row (default Dijkstra on mesh edges, which overestimates
  surface geodesics by a few percent on these meshes; ``--geodesics heat`` is closer to exact).
- Each method runs in its own child process over all pairs (no cache shared between methods); the
  time per pair is the wall clock from two loaded meshes to the vertex map (Laplacian spectra,
  descriptors, keypoints, matching, refinement all included); its CPU time (``process_time``,
  one BLAS thread everywhere) is reported too and the speed ratio uses it, because the methods run
  one after the other on a shared 2-core machine whose load changes during the run and distorts
  wall times. Peak memory is the child's ``VmHWM`` minus that of a child that only imports and
  loads the meshes (native allocations included).
- pyFM: ``TriMesh(..., area_normalize=True, center=True)``, ``preprocess(descr_type="WKS",
  subsample_step=2)``, ``fit(K=30, w_descr=1, w_lap=0.1, w_dcomm=1, w_orient=1)``,
  ``zoomout_refine(nit=16, step=5)``, ``get_p2p`` (the README quick start; its mesh1 is our B so
  that its ``p2p_21`` is our A -> B map).
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
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from shape_toolkit.data.datasets import read_vts  # noqa: E402
from shape_toolkit.io.mesh import load_shape  # noqa: E402
from shape_toolkit.metrics.correspondence import (  # noqa: E402
    DEFAULT_THRESHOLDS,
    error_curve,
    is_flipped,
    paired_geodesic_distances,
)

#: toolkit pipelines compared (every dense pipeline preset) plus the peer
METHODS = ["zoomout", "zoomout-fast", "sharma2012", "topo-robust", "seed-growing", "mateus2008", "ovsjanikov2010",
           "pyfm"]
RESULTS = REPO / "benchmarks" / "results"


def _data_dir(arg: str | None) -> Path:
    if arg:
        return Path(arg)
    if os.environ.get("TOOLKIT_DATA"):
        return Path(os.environ["TOOLKIT_DATA"])
    return REPO.parent / "shared" / "data"


def read_pairs(tosca: Path) -> list[tuple[str, str]]:
    """The (A, B) name pairs of ``pairs.txt``."""
    pairs = []
    for line in (tosca / "pairs.txt").read_text().splitlines():
        if line.strip():
            a, b = line.split()
            pairs.append((a, b))
    return pairs


def run_pyfm(A, B) -> np.ndarray:
    """pyFM's README quick start, returning the A -> B vertex map (the package's one copy of it,
    :func:`shape_toolkit.bench.peers.pyfm_map`, also run by ``peer = "pyfm"`` in bench configs)."""
    from shape_toolkit.bench.peers import pyfm_map

    return pyfm_map(A, B)


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


def child(method: str, tosca: Path, pairs: list[tuple[str, str]], out_dir: Path) -> None:
    """Run one method over all pairs in this process; write maps and timings to ``out_dir``."""
    import warnings

    warnings.filterwarnings("ignore")
    from shape_toolkit.pipeline import load_pipeline

    pipe = None if method in ("pyfm", "none") else load_pipeline(method)
    rows = []
    for a, b in pairs:
        A, B = load_shape(tosca / f"{a}.off"), load_shape(tosca / f"{b}.off")
        if method == "none":
            continue
        t0, c0 = time.perf_counter(), time.process_time()
        if method == "pyfm":
            t = run_pyfm(A, B)
        else:
            t = pipe.run(A, B).target_of
        dt, cpu = time.perf_counter() - t0, time.process_time() - c0
        np.save(out_dir / f"{method}__{a}__{b}.npy", t)
        rows.append({"pair": f"{a}-{b}", "seconds": dt, "cpu_seconds": cpu})
        print(f"  {method} {a}-{b}: {dt:.2f} s (CPU {cpu:.2f} s)", file=sys.stderr, flush=True)
    rss = peak_rss_mb()
    (out_dir / f"{method}.json").write_text(json.dumps({"rows": rows, "maxrss_mb": rss}))


def evaluate(tosca: Path, pairs, methods, out_dir: Path, geodesics: str) -> dict:
    """Per-pair errors of every method's maps (one pass of distance rows per pair)."""
    per = {m: {"err": [], "sym": [], "pairs": []} for m in methods}
    for a, b in pairs:
        A, B = load_shape(tosca / f"{a}.off"), load_shape(tosca / f"{b}.off")
        ta = read_vts(tosca / "corres" / f"{a}.vts", A.n_vertices)
        tb = read_vts(tosca / "corres" / f"{b}.vts", B.n_vertices)
        tbs = read_vts(tosca / "corres" / f"{b}.sym.vts", B.n_vertices)
        avail = [m for m in methods if (out_dir / f"{m}__{a}__{b}.npy").exists()]
        if not avail:
            continue
        preds = np.column_stack([np.load(out_dir / f"{m}__{a}__{b}.npy")[ta] for m in avail])
        bad = preds < 0
        safe = np.where(bad, tb[:, None], preds)
        # rows from the true points and from their symmetric twins serve every method at once
        d = paired_geodesic_distances(B, np.concatenate([tb, tbs]), np.vstack([safe, safe]),
                                      method=geodesics)
        scale = np.sqrt(B.area)
        e, es = d[: len(tb)] / scale, d[len(tb):] / scale
        e[bad] = np.inf
        es = np.minimum(e, np.where(bad, np.inf, es))
        for c, m in enumerate(avail):
            per[m]["err"].append(e[:, c])
            per[m]["sym"].append(es[:, c])
            per[m]["pairs"].append(f"{a}-{b}")
        print(f"  evaluated {a}-{b}", file=sys.stderr, flush=True)
    return per


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", help="shared data directory (default $TOOLKIT_DATA or ../shared/data)")
    ap.add_argument("--limit", type=int, help="only the first N pairs")
    ap.add_argument("--methods", default=",".join(METHODS), help="comma-separated methods")
    ap.add_argument("--geodesics", default="dijkstra", choices=["dijkstra", "heat", "fmm", "exact"])
    ap.add_argument("--output", default=str(RESULTS / "tosca_matching.md"))
    ap.add_argument("--note", default="", help="a paragraph written under the summary table")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--pairs-json", help=argparse.SUPPRESS)
    ap.add_argument("--out-dir", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    tosca = _data_dir(args.data) / "tosca5k"
    if args.child:
        child(args.child, tosca, [tuple(p) for p in json.loads(args.pairs_json)], Path(args.out_dir))
        return 0
    if not (tosca / "pairs.txt").exists():
        print(f"TOSCA data not found at {tosca}: pass --data or set TOOLKIT_DATA", file=sys.stderr)
        return 2
    pairs = read_pairs(tosca)[: args.limit] if args.limit else read_pairs(tosca)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    t_start = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        out_dir = Path(tmp)
        info: dict[str, dict] = {}
        for m in ["none"] + methods:
            print(f"[{m}] {len(pairs)} pairs", file=sys.stderr, flush=True)
            cmd = [sys.executable, __file__, "--child", m, "--pairs-json", json.dumps(pairs),
                   "--out-dir", tmp, "--data", str(tosca.parent)]
            r = subprocess.run(cmd)
            if r.returncode != 0:
                print(f"[{m}] failed with exit code {r.returncode}", file=sys.stderr)
                continue
            info[m] = json.loads((out_dir / f"{m}.json").read_text())
        per = evaluate(tosca, pairs, methods, out_dir, args.geodesics)
    base = info.get("none", {}).get("maxrss_mb", 0.0)
    summary = []
    for m in methods:
        if m not in info or not per[m]["err"]:
            continue
        e = np.concatenate(per[m]["err"])
        es = np.concatenate(per[m]["sym"])
        secs = [r["seconds"] for r in info[m]["rows"]]
        cpus = [r["cpu_seconds"] for r in info[m]["rows"]]
        th, frac = error_curve(e)
        _, frac_s = error_curve(es)
        fin = e[np.isfinite(e)]
        summary.append({
            "method": m,
            "pairs": len(per[m]["pairs"]),
            "mean_error": float(fin.mean()),
            "mean_error_symmetric": float(es[np.isfinite(es)].mean()),
            "within_0.05": float(np.mean(e <= 0.05)),
            "within_0.05_symmetric": float(np.mean(es <= 0.05)),
            "matched": float(np.isfinite(e).mean()),
            "seconds_mean": float(np.mean(secs)),
            "seconds_median": float(np.median(secs)),
            "cpu_seconds_mean": float(np.mean(cpus)),
            "peak_mb": float(info[m]["maxrss_mb"] - base),
            "flipped_pairs": int(sum(
                is_flipped(np.mean(x[np.isfinite(x)]), np.mean(y[np.isfinite(y)]))
                for x, y in zip(per[m]["err"], per[m]["sym"])
            )),
            "curve": [[float(a), float(b)] for a, b in zip(th, frac)],
            "curve_symmetric": [[float(a), float(b)] for a, b in zip(th, frac_s)],
            "per_pair": [
                {"pair": p, "mean_error": float(x[np.isfinite(x)].mean()), "seconds": s}
                for p, x, s in zip(per[m]["pairs"], per[m]["err"], secs)
            ],
        })
    shown = [a for a in (argv if argv is not None else sys.argv[1:])]
    if "--note" in shown:  # the note is printed below the table, not in the command line
        i = shown.index("--note")
        del shown[i : i + 2]
    command = " ".join(["python benchmarks/tosca_matching.py", *shown])
    write_results(summary, Path(args.output), len(pairs), args.geodesics, time.time() - t_start,
                  command, args.note)
    return 0


def write_results(summary: list[dict], output: Path, n_pairs: int, geodesics: str, wall: float,
                  command: str = "python benchmarks/tosca_matching.py", note: str = "") -> None:
    """Markdown table + JSON + PNG curves."""
    output.parent.mkdir(parents=True, exist_ok=True)
    output.with_suffix(".json").write_text(json.dumps(summary, indent=1))
    png = output.with_suffix(".png")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    for s in summary:
        c = np.array(s["curve"])
        cs = np.array(s["curve_symmetric"])
        style = "--" if s["method"] == "pyfm" else "-"
        axes[0].plot(c[:, 0], c[:, 1], style, label=s["method"])
        axes[1].plot(cs[:, 0], cs[:, 1], style, label=s["method"])
    for ax, title in zip(axes, ["geodesic error", "symmetric-aware geodesic error"]):
        ax.set_xlim(0, float(DEFAULT_THRESHOLDS[-1]))
        ax.set_ylim(0, 1)
        ax.set_xlabel("error threshold (geodesic / sqrt(area))")
        ax.set_title(f"TOSCA {n_pairs} pairs: {title}")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("fraction of correspondences")
    axes[1].legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)
    peer = next((s for s in summary if s["method"] == "pyfm"), None)
    lines = [
        "# Dense correspondence on TOSCA (tosca5k, pairs.txt)",
        "",
        f"Regenerate: `{command}` ({n_pairs} pairs, geodesics: {geodesics}, "
        f"whole run {wall / 60:.1f} min on a shared 2-core machine, one BLAS thread; speed ratios use "
        "CPU time, wall times depend on the machine's load while each method ran).",
        "Protocol: see the docstring of `benchmarks/tosca_matching.py` (A -> B maps, error on B divided by "
        "sqrt(area(B)), unmatched points count as failures in the curve and are left out of the mean).",
        "",
        "| method | pairs | mean error | within 0.05 | mean error (sym-aware) | within 0.05 (sym) "
        "| flipped pairs | matched | wall s/pair | CPU s/pair | CPU time vs pyFM | peak MB |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in summary:
        ratio = f"{s['cpu_seconds_mean'] / peer['cpu_seconds_mean']:.2f}x" if peer else "-"  # no pyFM row: a dash
        lines.append(
            f"| {s['method']} | {s['pairs']} | {s['mean_error']:.4f} | {100 * s['within_0.05']:.1f}% "
            f"| {s['mean_error_symmetric']:.4f} | {100 * s['within_0.05_symmetric']:.1f}% "
            f"| {s['flipped_pairs']} | {100 * s['matched']:.1f}% | {s['seconds_mean']:.2f} "
            f"| {s['cpu_seconds_mean']:.2f} | {ratio} | {s['peak_mb']:.0f} |"
        )
    lines += [
        "",
        f"![error curves]({png.name})",
        "",
        *([note, ""] if note else []),
        "`flipped pairs`: pairs whose mean error is more than twice (+0.02) the symmetric-aware one, i.e. "
        "maps that swap left and right. Left-right disambiguation: `zoomout` and `zoomout-fast` use the "
        "orientation-preserving term of Ren et al. 2018 in the functional map fit (outward normals); "
        "`sharma2012`, `topo-robust`, `seed-growing` and `ovsjanikov2010` decide the side of each keypoint "
        "match against a coarse functional map with that term (`matching.orientation.side_reference`): a match "
        "(a, b) or its mirror image (S(a), b), S the source's intrinsic symmetry where S passes the "
        "involution check (`symmetry_validity`), whichever agrees better, and drops matches far from it; "
        "`em-registration` decides per region of its dense map between T(x) and T(S(x)) the same way, and "
        "where neither agrees and T piles two parts onto one it takes the reference's own map; "
        "`mateus2008` is the published baseline and matches up to symmetry (thesis 7.2.1).",
        "",
        "## Per pair (mean error / seconds)",
        "",
        "| pair | " + " | ".join(s["method"] for s in summary) + " |",
        "|---|" + "---|" * len(summary),
    ]
    pair_names = [p["pair"] for p in summary[0]["per_pair"]] if summary else []
    for i, p in enumerate(pair_names):
        cells = []
        for s in summary:
            row = s["per_pair"][i] if i < len(s["per_pair"]) else None
            cells.append(f"{row['mean_error']:.3f} / {row['seconds']:.1f}" if row else "-")
        lines.append(f"| {p} | " + " | ".join(cells) + " |")
    output.write_text("\n".join(lines) + "\n")
    print("\n".join(lines[:8 + len(summary)]))


if __name__ == "__main__":
    sys.exit(main())
