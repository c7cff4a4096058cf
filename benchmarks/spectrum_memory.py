"""Peak memory of ``shape-toolkit spectrum`` against vertices and eigenpairs, measured, and the model that
``--memory-limit`` uses (``core.spectrum.SPECTRUM_MEMORY``) fitted to it.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/spectrum_memory.py --workdir DIR \\
        [--splits 4 7 10] [--k 20 100 200] [--output benchmarks/results/spectrum_memory.md]

TOSCA cat0 (``$TOOLKIT_DATA/tosca5k``, or ``../shared/data``) with every triangle split s x s (``subdivide``;
s = 4, 7, 10: 79,970, 244,904 and 499,802 vertices), written to ``DIR`` as binary PLY; each size and ``k`` runs
``shape-toolkit spectrum MESH -k K -o OUT.npz`` (the default cotangent weighting) in a fresh child process, one
after the other. CPU seconds (user + system) and peak RSS come from ``wait4``. The model ``bytes = a + n (b + c
k)`` is the least-squares fit of every row; the table gives each row's estimate over its measurement.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

DATA = Path(os.environ.get("TOOLKIT_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))


def run_spectrum(mesh: Path, k: int, out: Path) -> dict:
    """CPU s, wall s and peak RSS (MB, 10^6 bytes) of ``shape-toolkit spectrum mesh -k k -o out``."""
    t0 = time.perf_counter()
    p = subprocess.Popen([sys.executable, "-m", "shape_toolkit", "spectrum", str(mesh), "-k", str(k), "-o", str(out),
                          "-q"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    err = p.stderr.read()
    _, status, ru = os.wait4(p.pid, 0)
    rc = os.waitstatus_to_exitcode(status)
    if rc != 0:
        raise SystemExit(f"spectrum {mesh} -k {k}: exit {rc}: {err.decode()[-500:]}")
    return {"cpu": ru.ru_utime + ru.ru_stime, "wall": time.perf_counter() - t0, "peak": ru.ru_maxrss * 1024 / 1e6}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--workdir", type=Path, required=True)
    ap.add_argument("--splits", type=int, nargs="+", default=[4, 7, 10])
    ap.add_argument("--k", type=int, nargs="+", default=[20, 100, 200])
    ap.add_argument("--output", type=Path, default=Path(__file__).resolve().parent / "results" / "spectrum_memory.md")
    a = ap.parse_args()
    from shape_toolkit.core.spectrum import SPECTRUM_MEMORY
    from shape_toolkit.data.corruptions import subdivide
    from shape_toolkit.io.mesh import load_shape, save_shape

    a.workdir.mkdir(parents=True, exist_ok=True)
    cat0 = load_shape(DATA / "tosca5k" / "cat0.off")
    rows = []
    for s in a.splits:
        mesh = a.workdir / f"cat0_s{s}.ply"
        shape = subdivide(cat0, splits=s)[0]
        save_shape(shape, mesh, binary=True)
        for k in a.k:
            r = run_spectrum(mesh, k, a.workdir / "out.npz")
            rows.append({"n": shape.n_vertices, "k": k, **r})
            print(f"n={shape.n_vertices} k={k}: {r['cpu']:.1f} s CPU, {r['peak']:.0f} MB", flush=True)
    A = np.array([[1.0, r["n"], r["n"] * r["k"]] for r in rows])
    fit = np.linalg.lstsq(A, np.array([r["peak"] * 1e6 for r in rows]), rcond=None)[0]
    lines = [
        "# Peak memory of `shape-toolkit spectrum` (the model of `--memory-limit`)", "",
        "Regenerate with:", "",
        "    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/spectrum_memory.py --workdir /tmp/specmem", "",
        "TOSCA cat0 with every triangle split s x s, `shape-toolkit spectrum MESH -k K -o OUT.npz` (cotangent "
        "weighting) in a fresh process per row, one BLAS thread; CPU and peak RSS from `wait4`. `model` is "
        "`core.spectrum.SPECTRUM_MEMORY` (bytes = a + n (b + c k)), the estimate `--memory-limit` compares with the "
        "limit before reading the file.", "",
        f"Least-squares fit of these rows: a = {fit[0] / 1e6:.0f} MB, b = {fit[1]:.0f} bytes a vertex, c = "
        f"{fit[2]:.1f} bytes a vertex and eigenpair. Shipped: a = {SPECTRUM_MEMORY[0] / 1e6:.0f} MB, b = "
        f"{SPECTRUM_MEMORY[1]:.0f}, c = {SPECTRUM_MEMORY[2]:.1f}.", "",
        "| n | k | CPU s | wall s | peak MB | model MB | model / peak |", "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        est = (SPECTRUM_MEMORY[0] + r["n"] * (SPECTRUM_MEMORY[1] + SPECTRUM_MEMORY[2] * r["k"])) / 1e6
        lines.append(f"| {r['n']:,} | {r['k']} | {r['cpu']:.1f} | {r['wall']:.1f} | {r['peak']:.0f} | {est:.0f} | "
                     f"{est / r['peak']:.2f} |")
    a.output.write_text("\n".join(lines) + "\n")
    print(f"wrote {a.output}")


if __name__ == "__main__":
    main()
