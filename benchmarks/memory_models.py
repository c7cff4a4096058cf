"""Peak memory of the commands whose ``--memory-limit`` uses a model fitted here, measured as a user runs them, and
each model's estimate beside each measurement.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/memory_models.py --workdir DIR \\
        [--output benchmarks/results/memory_models.md]

TOSCA cat0 and cat1 (``$TOOLKIT_DATA/tosca5k``, or ``../shared/data``) with every triangle split s x s
(``subdivide``), written to ``DIR`` as binary PLY. Each row runs one command in a fresh child process, one after the
other; CPU seconds (user + system) and peak RSS come from ``wait4``:

- ``shape-toolkit spectrum cat0 -k K -o OUT.npz`` (cotangent weighting), s = 4, 7, 10 (79,970 to 499,802
  vertices), k = 20, 100, 200: ``core.spectrum.SPECTRUM_MEMORY``, ``a + n (b + c k)``;
- ``shape-toolkit match cat0 cat1 --proxy 0`` (pipeline ``auto`` at full resolution), s = 2, 3, 4 (2 x 19,994 to
  2 x 79,970 vertices): ``plugins.matching.multires.MATCH_FULL_MEMORY``, ``a + b n`` for the two shapes' n;
- ``shape-toolkit segment cat0 --proxy 0`` (``ncut``, 6 segments, full resolution), s = 4, 7, 10:
  ``plugins.segmenters.multires.SEGMENT_FULL_MEMORY``, ``a + b n``;
- ``shape-toolkit geodesics cat0 --sources ... --method M``, one source and 20: s = 4, 7, 10 for ``dijkstra``,
  ``fmm`` and ``heat``, s = 2, 3, 4 for ``exact`` (one source): ``features.geodesics.GEODESIC_MEMORY``, ``a + b n``
  per method on the one-source rows, and ``GEODESIC_ROW_BYTES`` per vertex and source (not fitted: the arrays the
  code holds per source);
- ``shape-toolkit transfer-labels cat0 LABELS cat1``: at full resolution (``--proxy 0``), s = 1, 2, and through
  proxies, s = 4, 7, 10: ``plugins.matching.multires.LABEL_TRANSFER_FULL_MEMORY`` and ``LABEL_TRANSFER_MEMORY``,
  ``a + b n`` for the two shapes' n;
- ``shape-toolkit track cat0 cat1 cat2`` (``zoomout``, through proxies), s = 4, 7: ``cli.commands.track.track_memory``,
  every frame held (``FRAME_BYTES`` a vertex) and ``match``'s model for one pair (not fitted);
- ``shape-toolkit describe cat0 --descriptor D`` (``hks``, ``wks``, ``heat-distance`` from 20 keypoints), s = 4, 7, 10:
  ``cli.commands.describe.describe_memory``, the spectrum's model or the eigenvectors held beside the descriptor
  (``DESCRIPTOR_BYTES`` a value; not fitted);
- ``shape-toolkit evaluate-map cat0 cat0 IDENTITY`` with 100 truth points (``heat``, ``dijkstra``, ``fmm``) or
  ``--r-smoothness --r-sample 200``, s = 4, 7, 10: ``cli.commands.evaluate_map.evaluate_map_memory``, the geodesic
  model of the rows solved at once, or r-smoothness's Dijkstra rows and neighbourhood blocks (not fitted).

Each model is also fitted to its rows by least squares (printed beside the shipped constants). The proxy path's
models of ``match`` and ``segment`` (``MATCH_MEMORY``, ``SEGMENT_MEMORY``) come from ``scale_1m.py``. Each row's
measurement is kept in ``DIR/rows.json`` and reused when the script runs again (``--fresh``: measure all again).
About 25 minutes.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

DATA = Path(os.environ.get("TOOLKIT_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))


def run_cli(args: list[str]) -> dict:
    """CPU s, wall s and peak RSS (MB, 10^6 bytes) of ``shape-toolkit ARGS -q`` in a fresh process."""
    t0 = time.perf_counter()
    p = subprocess.Popen([sys.executable, "-m", "shape_toolkit", *args, "-q"], stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE)
    err = p.stderr.read()
    _, status, ru = os.wait4(p.pid, 0)
    rc = os.waitstatus_to_exitcode(status)
    if rc != 0:
        raise SystemExit(f"{' '.join(args)}: exit {rc}: {err.decode()[-500:]}")
    return {"cpu": ru.ru_utime + ru.ru_stime, "wall": time.perf_counter() - t0, "peak": ru.ru_maxrss * 1024 / 1e6}


def mesh(work: Path, name: str, s: int) -> tuple[Path, int]:
    """TOSCA ``name`` split ``s`` x ``s``, written once to ``work``; its path and vertex count."""
    from shape_toolkit.data.corruptions import subdivide
    from shape_toolkit.io.mesh import declared_vertices, load_shape, save_shape

    p = work / f"{name}_s{s}.ply"
    if not p.exists():
        save_shape(subdivide(load_shape(DATA / "tosca5k" / f"{name}.off"), splits=s)[0], p, binary=True)
    return p, int(declared_vertices(p))


class Rows:
    """Measurements of ``run_cli`` kept in ``DIR/rows.json`` by command line, reused on the next run."""

    def __init__(self, path: Path, fresh: bool) -> None:
        self.path = path
        self.rows = {} if fresh or not path.exists() else json.loads(path.read_text())

    def run(self, args: list[str]) -> dict:
        key = " ".join(args)
        if key not in self.rows:
            self.rows[key] = run_cli(args)
            self.path.write_text(json.dumps(self.rows, indent=1))
        return dict(self.rows[key])


def labels_file(work: Path, shape_file: Path, n: int) -> Path:
    """Four labels (the quadrants of the first two coordinates) for the ``n`` vertices of ``shape_file``."""
    from shape_toolkit.io.mesh import load_shape

    p = work / f"{shape_file.stem}.labels.txt"
    if not p.exists():
        V = np.asarray(load_shape(shape_file).vertices)
        lab = (V[:, 0] > np.median(V[:, 0])).astype(int) + 2 * (V[:, 1] > np.median(V[:, 1])).astype(int)
        assert lab.size == n
        np.savetxt(p, lab, fmt="%d")
    return p


def ids_file(work: Path, name: str, n: int, count: int, one_based: bool) -> Path:
    """``count`` vertex ids spread evenly over ``n`` vertices, one per line, written once to ``work``."""
    p = work / name
    if not p.exists():
        np.savetxt(p, np.arange(0, n, n // count)[:count] + int(one_based), fmt="%d")
    return p


def fit(X: list[list[float]], peaks: list[float]) -> np.ndarray:
    """Least-squares coefficients of bytes = X @ coef."""
    return np.linalg.lstsq(np.asarray(X, float), np.asarray(peaks) * 1e6, rcond=None)[0]


def table(rows: list[dict], head: str) -> list[str]:
    cols = head.count("|") + 6
    out = [f"| {head} | CPU s | wall s | peak MB | model MB | model / peak |", "|" + "---|" * cols]
    for r in rows:
        out.append(f"| {r['label']} | {r['cpu']:.1f} | {r['wall']:.1f} | {r['peak']:.0f} | {r['model'] / 1e6:.0f} | "
                   f"{r['model'] / 1e6 / r['peak']:.2f} |")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--workdir", type=Path, required=True)
    ap.add_argument("--fresh", action="store_true", help="measure every row again (default: reuse DIR/rows.json)")
    ap.add_argument("--output", type=Path, default=Path(__file__).resolve().parent / "results" / "memory_models.md")
    a = ap.parse_args()
    from shape_toolkit.cli.commands.describe import DESCRIPTOR_BYTES, describe_memory
    from shape_toolkit.cli.commands.evaluate_map import evaluate_map_memory
    from shape_toolkit.cli.commands.track import FRAME_BYTES, track_memory
    from shape_toolkit.core.spectrum import SPECTRUM_MEMORY, spectrum_memory
    from shape_toolkit.features.geodesics import GEODESIC_MEMORY, GEODESIC_ROW_BYTES, geodesic_memory
    from shape_toolkit.metrics.correspondence import R_SMOOTH_RS
    from shape_toolkit.plugins.matching.multires import (
        LABEL_TRANSFER_FULL_MEMORY,
        LABEL_TRANSFER_MEMORY,
        MATCH_FULL_MEMORY,
        PROXY_VERTICES,
        label_transfer_memory,
        match_memory,
    )
    from shape_toolkit.plugins.segmenters.multires import SEGMENT_FULL_MEMORY, segment_memory

    a.workdir.mkdir(parents=True, exist_ok=True)
    out = a.workdir / "out"
    measure = Rows(a.workdir / "rows.json", a.fresh).run
    spec, match, seg, geo, tl, trk, desc, ev = [], [], [], [], [], [], [], []
    for s in (4, 7, 10):
        p, n = mesh(a.workdir, "cat0", s)
        for k in (20, 100, 200):
            r = measure(["spectrum", str(p), "-k", str(k), "-o", f"{out}.npz"])
            spec.append({**r, "n": n, "k": k, "label": f"{n:,} | {k}", "model": spectrum_memory(n, k)})
            print(f"spectrum n={n} k={k}: {r['cpu']:.1f} s CPU, {r['peak']:.0f} MB", flush=True)
    for s in (2, 3, 4):
        (p, n), (q, m) = mesh(a.workdir, "cat0", s), mesh(a.workdir, "cat1", s)
        r = measure(["match", str(p), str(q), "--proxy", "0", "-o", f"{out}.map.txt"])
        match.append({**r, "n": n + m, "label": f"{n:,} + {m:,}", "model": match_memory(n + m, 0)})
        print(f"match --proxy 0 n={n}+{m}: {r['cpu']:.1f} s CPU, {r['peak']:.0f} MB", flush=True)
    for s in (4, 7, 10):
        p, n = mesh(a.workdir, "cat0", s)
        r = measure(["segment", str(p), "-k", "6", "--proxy", "0", "-o", f"{out}.labels.txt"])
        seg.append({**r, "n": n, "label": f"{n:,}", "model": segment_memory(n, 0)})
        print(f"segment --proxy 0 n={n}: {r['cpu']:.1f} s CPU, {r['peak']:.0f} MB", flush=True)
    many = ",".join(str(i) for i in range(20))
    for method, sizes in (("dijkstra", (4, 7, 10)), ("fmm", (4, 7, 10)), ("heat", (4, 7, 10)), ("exact", (2, 3, 4))):
        for s in sizes:
            p, n = mesh(a.workdir, "cat0", s)
            for src in ("0",) if method == "exact" else ("0", many):
                k = src.count(",") + 1
                r = measure(["geodesics", str(p), "--sources", src, "--method", method, "--time-limit", "600", "-o",
                             f"{out}.npz"])
                geo.append({**r, "n": n, "k": k, "method": method, "label": f"{method} | {n:,} | {k}",
                            "model": geodesic_memory(n, k, method)})
                print(f"geodesics {method} n={n} sources={k}: {r['cpu']:.1f} s CPU, {r['peak']:.0f} MB", flush=True)
    for s, proxy in ((1, 0), (2, 0), (4, 5000), (7, 5000), (10, 5000)):
        (p, n), (q, m) = mesh(a.workdir, "cat0", s), mesh(a.workdir, "cat1", s)
        r = measure(["transfer-labels", str(p), str(labels_file(a.workdir, p, n)), str(q), "--proxy", str(proxy),
                     "-o", f"{out}.labels.txt"])
        tl.append({**r, "n": n + m, "proxy": proxy, "label": f"{'--proxy 0' if proxy == 0 else proxy} | {n:,} + {m:,}",
                   "model": label_transfer_memory(n + m, proxy)})
        print(f"transfer-labels --proxy {proxy} n={n}+{m}: {r['cpu']:.1f} s CPU, {r['peak']:.0f} MB", flush=True)
    for s in (4, 7):
        frames = [mesh(a.workdir, f"cat{i}", s) for i in range(3)]
        r = measure(["track", *(str(p) for p, _ in frames), "-o", f"{out}.traj.npz"])
        n = sum(m for _, m in frames)
        trk.append({**r, "n": n, "label": " + ".join(f"{m:,}" for _, m in frames),
                    "model": track_memory(n, len(frames), PROXY_VERTICES)})
        print(f"track n={n}: {r['cpu']:.1f} s CPU, {r['peak']:.0f} MB", flush=True)
    widths = {"hks": 16, "wks": 100, "heat-distance": 100}  # the defaults; 20 keypoints x 5 times
    for s in (4, 7, 10):
        p, n = mesh(a.workdir, "cat0", s)
        kp = ids_file(a.workdir, f"kp20_s{s}.txt", n, 20, False)
        truth = ids_file(a.workdir, f"truth100_s{s}.vts", n, 100, True)
        ident = ids_file(a.workdir, f"id_s{s}.txt", n, n, False)  # the identity map
        for d, extra in (("hks", []), ("wks", []), ("heat-distance", ["--keypoints", str(kp)])):
            r = measure(["describe", str(p), "--descriptor", d, *extra, "-o", f"{out}.npz"])
            k = 51 if d == "heat-distance" else 101
            desc.append({**r, "n": n, "label": f"{d} | {n:,}", "model": describe_memory(n, k, widths[d])})
            print(f"describe {d} n={n}: {r['cpu']:.1f} s CPU, {r['peak']:.0f} MB", flush=True)
        for g in ("heat", "dijkstra", "fmm"):
            r = measure(["evaluate-map", str(p), str(p), str(ident), "--truth-src", str(truth), "--truth-dst",
                         str(truth), "--geodesics", g, "--time-limit", "900"])
            ev.append({**r, "n": n, "label": f"{g} from 100 truth points | {n:,}",
                       "model": evaluate_map_memory(n, n, g, 100, False)})
            print(f"evaluate-map {g} n={n}: {r['cpu']:.1f} s CPU, {r['peak']:.0f} MB", flush=True)
        r = measure(["evaluate-map", str(p), str(p), str(ident), "--r-smoothness", "--r-sample", "200", "--time-limit",
                     "900"])
        ev.append({**r, "n": n, "label": f"--r-smoothness --r-sample 200 | {n:,}",
                   "model": evaluate_map_memory(n, n, "heat", 0, R_SMOOTH_RS, 200)})
        print(f"evaluate-map r-smoothness n={n}: {r['cpu']:.1f} s CPU, {r['peak']:.0f} MB", flush=True)
    fgeo = {m: fit([[1, r["n"]] for r in geo if r["method"] == m and r["k"] == 1],
                   [r["peak"] for r in geo if r["method"] == m and r["k"] == 1]) for m in GEODESIC_MEMORY}
    ftf = fit([[1, r["n"]] for r in tl if r["proxy"] == 0], [r["peak"] for r in tl if r["proxy"] == 0])
    ftp = fit([[1, r["n"]] for r in tl if r["proxy"]], [r["peak"] for r in tl if r["proxy"]])
    fs = fit([[1, r["n"], r["n"] * r["k"]] for r in spec], [r["peak"] for r in spec])
    fm = fit([[1, r["n"]] for r in match], [r["peak"] for r in match])
    fg = fit([[1, r["n"]] for r in seg], [r["peak"] for r in seg])
    lines = [
        "# Peak memory of `spectrum`, `match --proxy 0`, `segment --proxy 0`, `geodesics`, `transfer-labels`, `track`, "
        "`describe` and `evaluate-map` (the models of `--memory-limit`)",
        "",
        "Regenerate with:", "",
        "    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/memory_models.py --workdir /tmp/memory_models",
        "",
        "TOSCA cat0 (and cat1) with every triangle split s x s, each command in a fresh process per row, one BLAS "
        "thread; CPU and peak RSS from `wait4`. `model` is the estimate `--memory-limit` compares with the limit "
        "before reading the files (the proxy path's models are fitted in `scale_1m.md`).", "",
        "## `shape-toolkit spectrum MESH -k K` (cotangent weighting)", "",
        f"`core.spectrum.SPECTRUM_MEMORY`: bytes = a + n (b + c k), shipped a = {SPECTRUM_MEMORY[0] / 1e6:.0f} MB, "
        f"b = {SPECTRUM_MEMORY[1]:.0f}, c = {SPECTRUM_MEMORY[2]:.1f}; least squares on these rows: a = "
        f"{fs[0] / 1e6:.0f} MB, b = {fs[1]:.0f}, c = {fs[2]:.1f}.", "",
        *table(spec, "n | k"), "",
        "## `shape-toolkit match A B --proxy 0` (`auto` at full resolution)", "",
        f"`plugins.matching.multires.MATCH_FULL_MEMORY`: bytes = a + b n (n: both shapes' vertices), shipped a = "
        f"{MATCH_FULL_MEMORY[0] / 1e6:.0f} MB, b = {MATCH_FULL_MEMORY[1]:.0f}; least squares: a = {fm[0] / 1e6:.0f} "
        f"MB, b = {fm[1]:.0f}.", "",
        *table(match, "n (source + target)"), "",
        "## `shape-toolkit segment MESH --proxy 0` (`ncut`, 6 segments, full resolution)", "",
        f"`plugins.segmenters.multires.SEGMENT_FULL_MEMORY`: bytes = a + b n, shipped a = "
        f"{SEGMENT_FULL_MEMORY[0] / 1e6:.0f} MB, b = {SEGMENT_FULL_MEMORY[1]:.0f}; least squares: a = "
        f"{fg[0] / 1e6:.0f} MB, b = {fg[1]:.0f}.", "",
        *table(seg, "n"), "",
        "## `shape-toolkit geodesics MESH --sources IDS --method M`", "",
        "`features.geodesics.GEODESIC_MEMORY`: bytes = a + n (b + c s) for s sources, c = "
        f"`GEODESIC_ROW_BYTES` = {GEODESIC_ROW_BYTES:.0f} (the float64 arrays the code holds per source: not fitted); "
        "shipped a and b per method, and least squares on the one-source rows:", "",
        "| method | shipped a MB | shipped b | fitted a MB | fitted b |", "|---|---|---|---|---|",
        *[f"| {m} | {GEODESIC_MEMORY[m][0] / 1e6:.0f} | {GEODESIC_MEMORY[m][1]:.0f} | {fgeo[m][0] / 1e6:.0f} | "
          f"{fgeo[m][1]:.0f} |" for m in GEODESIC_MEMORY], "",
        *table(geo, "method | n | sources"), "",
        "## `shape-toolkit transfer-labels TRAIN LABELS TEST` (`eigvec-alignment`)", "",
        "`plugins.matching.multires.LABEL_TRANSFER_FULL_MEMORY` (`--proxy 0`): bytes = a + b n (n: both shapes' "
        f"vertices), "
        f"shipped a = {LABEL_TRANSFER_FULL_MEMORY[0] / 1e6:.0f} MB, b = {LABEL_TRANSFER_FULL_MEMORY[1]:.0f}; least "
        f"squares: a = {ftf[0] / 1e6:.0f} MB, b = {ftf[1]:.0f}. `LABEL_TRANSFER_MEMORY` (through proxies of 5,000 "
        f"vertices, the default): shipped a = {LABEL_TRANSFER_MEMORY[0] / 1e6:.0f} MB, b = "
        f"{LABEL_TRANSFER_MEMORY[1]:.0f}; least squares: a = {ftp[0] / 1e6:.0f} MB, b = {ftp[1]:.0f}.", "",
        *table(tl, "proxy | n (train + test)"), "",
        "## `shape-toolkit track F0 F1 F2` (`zoomout`, through proxies of 5,000 vertices)", "",
        f"`cli.commands.track.track_memory`: bytes = `FRAME_BYTES` n + `match_memory`(2 n / frames), `FRAME_BYTES` = "
        f"{FRAME_BYTES:.0f} (n: every frame's vertices; not fitted).", "",
        *table(trk, "frames' vertices"), "",
        "## `shape-toolkit describe MESH --descriptor D` (its declared spectrum: Gaussian weights, combinatorial)", "",
        "`cli.commands.describe.describe_memory`: the larger of the spectrum's model for the declared k (101 for `hks` "
        "and `wks`, 51 for `heat-distance`) and, once it is solved, its eigenvectors (8 k bytes a vertex) held beside "
        f"the descriptor's columns (`DESCRIPTOR_BYTES` = {DESCRIPTOR_BYTES} a value: the matrix and the copy written; "
        "16, 100 and 100 columns here, `heat-distance` from 20 keypoints); not fitted.", "",
        *table(desc, "descriptor | n"), "",
        "## `shape-toolkit evaluate-map SRC DST MAP` (the identity map of a shape onto itself)", "",
        "`cli.commands.evaluate_map.evaluate_map_memory`: the geodesic error's rows on the target, min(128, truth "
        "points) solved at once (`geodesic_memory`), or r-smoothness's: both shapes' Dijkstra graphs "
        "(`GEODESIC_MEMORY`), 64 float64 rows and their mask on the larger shape, and two blocks of neighbourhoods "
        "(200 vertices here); not fitted.", "",
        *table(ev, "what | n"),
    ]
    a.output.write_text("\n".join(lines) + "\n")
    print(f"wrote {a.output}")


if __name__ == "__main__":
    main()
