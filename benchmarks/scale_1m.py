"""Issue 29's 1M-vertex targets, measured: the default ``match`` and ``segment --method ncut`` from 5k to 1M
vertices, CPU and peak memory of the CLI as a user runs it, CPU per stage of the match, growth exponents.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 nice python benchmarks/scale_1m.py --workdir DIR \\
        [--splits 1 2 3 5 7 14] [--output benchmarks/results/scale_1m.md]

The pair: TOSCA cat0 -> cat1 (``$TOOLKIT_DATA/tosca5k``), both split s x s (``subdivide``: the original
vertices keep their ids, so the ground truth holds; s = 14: 979,610 vertices), written to ``DIR`` as binary
PLY, and their vertices alone as point clouds (``*.cloud.ply``). Each size runs fresh child processes, one
after the other: ``shape-toolkit match A B --json`` (no flags: pipeline ``auto``, proxies of 5,000 vertices
above 7,500), whose JSON gives each stage's CPU seconds (``stages_cpu``; the lift: the map interpolated on the
proxies' triangles); ``shape-toolkit segment A --method ncut -k 6`` (through its default proxy of 5,000
vertices above 7,500); reading the pair (``load_shape``, imports excluded: the same process state as a CLI
run, which an in-process timing after the scoring is not); and ``match`` on the two point clouds (proxies of
5,000 farthest points, the map interpolated among each point's three nearest proxy points). CPU seconds
(user + system) and peak RSS of a CLI run come from ``wait4`` (the command and its supervised child).
Error: mean normalised geodesic error of the 5,000 ground-truth points, each predicted vertex mapped to its
nearest original vertex, Dijkstra on the clean 5k cat1 / sqrt(area) (``matching_scale.toml``'s ``score_on =
"clean"``).
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

STAGES = ["read", "proxies", "proxy pipeline", "lift", "total"]
#: the TOSCA meshes of 5,000 vertices and their ground truth (``corres/*.vts``)
TOSCA = Path(os.environ.get("TOOLKIT_DATA", Path(__file__).resolve().parents[2] / "shared" / "data")) / "tosca5k"


def make_meshes(work: Path, s: int) -> None:
    from shape_toolkit.data.corruptions import subdivide
    from shape_toolkit.io.mesh import load_shape, save_shape

    for name in ("cat0", "cat1"):
        out = work / f"{name}_s{s}.ply"
        if not out.exists():
            sub, vmap = subdivide(load_shape(TOSCA / f"{name}.off"), splits=s)
            save_shape(sub, out, binary=True)
            np.save(work / f"{name}_s{s}.vmap.npy", vmap)
        cloud = work / f"{name}_s{s}.cloud.ply"
        if not cloud.exists():  # the same vertices without the faces: a scan's point cloud
            from shape_toolkit.core.shape import Shape

            save_shape(Shape(load_shape(out).vertices, None, name=name), cloud, binary=True)


def read_cpu(paths: list[Path]) -> float:
    """CPU seconds of ``load_shape`` on ``paths`` in a fresh process (as the CLI reads them; imports excluded)."""
    code = ("import sys, time; from shape_toolkit.io.mesh import load_shape; t = time.process_time(); "
            "[load_shape(p) for p in sys.argv[1:]]; print(time.process_time() - t)")
    return float(subprocess.run([sys.executable, "-c", code, *map(str, paths)], check=True, capture_output=True,
                                text=True).stdout)


def run_cli(args: list[str]) -> dict:
    """CPU s (user + system, children included), wall s and peak RSS MB of one CLI run."""
    t0 = time.perf_counter()
    p = subprocess.Popen([sys.executable, "-m", "shape_toolkit", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    out = p.stdout.read()
    err = p.stderr.read()
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    rc = os.waitstatus_to_exitcode(status)
    if rc != 0:
        raise SystemExit(f"{' '.join(args)}: exit {rc}: {err.decode()[-500:]}")
    return {"cpu": ru.ru_utime + ru.ru_stime, "wall": wall, "peak_mb": ru.ru_maxrss / 1024, "json": json.loads(out)}


def score(map_file: Path, vmap_t: Path) -> float:
    from shape_toolkit.data.datasets import read_vts
    from shape_toolkit.io.mesh import load_shape
    from shape_toolkit.metrics.correspondence import geodesic_errors

    b = load_shape(TOSCA / "cat1.off")
    ta, tb = (read_vts(TOSCA / "corres" / f"{name}.vts", b.n_vertices) for name in ("cat0", "cat1"))
    m = np.loadtxt(map_file, dtype=np.int64)[: b.n_vertices]  # the original vertices keep their ids
    vm = np.load(vmap_t)
    pred = np.where(m >= 0, vm[np.maximum(m, 0)], -1)
    e = geodesic_errors(b, pred, ta, tb, method="dijkstra")
    return float(e[np.isfinite(e)].mean())


def stages(match: dict, read: float) -> dict:
    """CPU seconds per stage of one ``match --json`` run (``stages_cpu``) and of reading."""
    cpu = match["stages_cpu"]
    out = {"read": read, "proxies": cpu.get("proxies", 0.0),
           "proxy pipeline": sum(v for k, v in cpu.items() if k.startswith("proxy ")), "lift": cpu.get("lift", 0.0)}
    out["total"] = read + sum(cpu.values())
    return {"proxy": (match.get("proxy") or {}).get("proxy_vertices"), "cpu": out}


def exponent(x0: float, x1: float, n0: int, n1: int) -> float:
    return math.log(x1 / x0) / math.log(n1 / n0) if x0 > 0 and x1 > 0 else float("nan")


def nlogn(n0: int, n1: int) -> float:
    """The exponent n log n shows between n0 and n1."""
    return 1 + math.log(math.log(n1) / math.log(n0)) / math.log(n1 / n0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--workdir", required=True, help="folder for the split meshes and maps (not the repository)")
    ap.add_argument("--splits", type=int, nargs="+", default=[1, 2, 3, 5, 7, 14])
    ap.add_argument("--output", default="benchmarks/results/scale_1m.md")
    args = ap.parse_args()
    work = Path(args.workdir)
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    for s in args.splits:
        make_meshes(work, s)
        a, b, m = work / f"cat0_s{s}.ply", work / f"cat1_s{s}.ply", work / f"match_s{s}.map.txt"
        match = run_cli(["match", str(a), str(b), "-o", str(m), "--json", "-q"])
        err = score(m, work / f"cat1_s{s}.vmap.npy")
        st = stages(match["json"], read_cpu([a, b]))
        ca, cb = (work / f"{x}_s{s}.cloud.ply" for x in ("cat0", "cat1"))
        cm = work / f"cloud_s{s}.map.txt"
        cloud = run_cli(["match", str(ca), str(cb), "-o", str(cm), "--json", "-q"])
        cloud["error"] = score(cm, work / f"cat1_s{s}.vmap.npy")
        seg = run_cli(["segment", str(a), "--method", "ncut", "-k", "6", "-o", str(work / f"seg_s{s}.labels.txt"),
                       "--json", "-q"])
        n = match["json"]["n_source"]
        rows.append({"s": s, "n": n, "match": match, "error": err, "stages": st, "seg": seg, "cloud": cloud})
        print(f"s={s}: n={rows[-1]['n']} match cpu {match['cpu']:.1f} s, {match['peak_mb']:.0f} MB, error {err:.4f}; "
              f"segment cpu {seg['cpu']:.1f} s; clouds cpu {cloud['cpu']:.1f} s, error {cloud['error']:.4f}",
              flush=True)
    write(rows, Path(args.output), args.splits)


def write(rows: list[dict], out: Path, splits: list[int]) -> None:
    base = next((r["error"] for r in rows if r["s"] == 1), None)
    blas = os.environ.get("OPENBLAS_NUM_THREADS")
    cmd = ("OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 nice python benchmarks/scale_1m.py --workdir DIR --splits "
           + " ".join(map(str, splits)) + f" --output {out}")
    L = ["# Issue 29 at 1M vertices: default `match` and `segment --method ncut`, 5k to 1M", "",
         f"Regenerate with: `{cmd}`", "",
         f"Run {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; 2 shared cores (other jobs ran: wall > CPU); "
         f"BLAS threads {blas}. Protocol: the docstring of `benchmarks/scale_1m.py`.", "",
         "## `shape-toolkit match A B` (pipeline auto, default proxy 5,000)", "",
         "| s | n | CPU s | wall s | peak MB | BLAS threads | proxy vertices | error | error / 5k error | "
         "target 1.1 x 5k + 0.005 |", "|---:|---:|---:|---:|---:|---:|---|---:|---:|---|"]
    for r in rows:
        m = r["match"]
        ratio = f"{r['error'] / base:.2f}" if base else "-"
        ok = "-" if base is None or r["s"] == 1 else ("met" if r["error"] <= 1.1 * base + 0.005 else "not met")
        L.append(f"| {r['s']} | {r['n']:,} | {m['cpu']:.1f} | {m['wall']:.1f} | {m['peak_mb']:,.0f} | {blas} | "
                 f"{r['stages']['proxy'] or 'none (direct)'} | {r['error']:.4f} | {ratio} | {ok} |")
    big = [r for r in rows if r["s"] > 1]
    L += ["", "## Match: CPU seconds per stage and growth exponents", "",
          "| stage | " + " | ".join(f"{r['n']:,}" for r in big) + " | exponent first-last | exponent last step | "
          "n log n allows (first-last / last step) |", "|---" * (len(big) + 4) + "|"]
    if len(big) >= 2:
        n0, n1, n2 = big[0]["n"], big[-1]["n"], big[-2]["n"]
        for st in STAGES:
            v = [r["stages"]["cpu"].get(st, 0.0) for r in big]
            L.append(f"| {st} | " + " | ".join(f"{x:.2f}" for x in v) + f" | {exponent(v[0], v[-1], n0, n1):.2f} | "
                     f"{exponent(v[-2], v[-1], n2, n1):.2f} | {nlogn(n0, n1):.2f} / {nlogn(n2, n1):.2f} |")
    L += ["", "## `shape-toolkit segment A --method ncut -k 6` (ncut: the default method; proxy 5,000 above 7,500)", "",
          "| s | n | CPU s | wall s | peak MB | segment sizes (vertices) |", "|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        g = r["seg"]
        L.append(f"| {r['s']} | {r['n']:,} | {g['cpu']:.1f} | {g['wall']:.1f} | {g['peak_mb']:,.0f} | "
                 f"{g['json']['segment_sizes']} |")
    if len(rows) >= 2:
        g0, g1, n0, n1 = rows[-2]["seg"], rows[-1]["seg"], rows[-2]["n"], rows[-1]["n"]
        L += ["", f"Segment CPU exponent over the last step: {exponent(g0['cpu'], g1['cpu'], n0, n1):.2f}"
              f" (n log n: {nlogn(n0, n1):.2f})."]
    L += ["", "## `shape-toolkit match A B` on point clouds: the same vertices without faces "
          "(proxies: 5,000 farthest points above 7,500)", "",
          "| s | n | CPU s | wall s | peak MB | proxies CPU s | lift CPU s | error | error / mesh error at this size |",
          "|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        c = r["cloud"]
        sc = c["json"].get("stages_cpu", {})
        L.append(f"| {r['s']} | {r['n']:,} | {c['cpu']:.1f} | {c['wall']:.1f} | {c['peak_mb']:,.0f} | "
                 f"{sc.get('proxies', 0.0):.2f} | {sc.get('lift', 0.0):.2f} | {c['error']:.4f} | "
                 f"{c['error'] / r['error']:.2f} |")
    out.write_text("\n".join(L) + "\n")
    (out.with_suffix(".json")).write_text(json.dumps(
        [{k: v for k, v in r.items() if k not in ("match", "seg", "cloud")} | {
            "match": {k: v for k, v in r["match"].items() if k != "json"} | {"stages": r["match"]["json"]["stages"]},
            "segment": {k: v for k, v in r["seg"].items() if k != "json"},
            "cloud": {k: v for k, v in r["cloud"].items() if k != "json"} | {"stages": r["cloud"]["json"]["stages"]}}
         for r in rows], indent=1))


if __name__ == "__main__":
    main()
