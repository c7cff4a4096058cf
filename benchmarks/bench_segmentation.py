"""Speed and memory of every segmenter end to end, against the cost of the spectrum alone.

    python benchmarks/bench_segmentation.py [--subdivisions 5 6] [--output FILE]

Shapes: ``shape_toolkit.data.synthetic.articulated_shape(subdivisions=s)`` (5: 10,242 vertices; 6: 40,962).
Each stage runs in a fresh subprocess (no spectrum cache shared between stages):

- ``spectrum-combinatorial``: Gaussian shape graph + the 11 smallest eigenpairs of ``L = D - W``
  (what both segmenters need with their defaults, p = 10);
- ``eigvec-gmm``: the whole segmentation with k = 6, spectrum included;
- ``csc``: the whole segmentation with its defaults (on a mesh: the concavity-weighted dual graph,
  k-means seeded by the must-link groups), k = 6 and constraints drawn from the limb labels, both
  eigensolves (the L-embedding and the modified Laplacian) included;
- ``csc-vertex``: the same on the vertex graph (``graph="vertex"``, thesis 5.2), spectrum included;
- ``ncut``: recursive normalized cuts on the dual graph, k = 6;
- ``sdf``: shape diameter function (Open3D ray casting), GMM, graph cut, k = 6;
- ``seeded-walk``: random walks from the same constraints' must-link groups.

Reported: wall time and process CPU time (all threads of the child; with one BLAS thread the two agree
unless the machine is busy), both per 10,000 faces, the wall-time ratio to the spectrum stage, and peak
resident memory added by the stage
(``ru_maxrss`` after minus before; imports and plugin loading happen before; native buffers of
Open3D, PyMaxflow and SuperLU included), per 1,000 vertices and per 10,000 faces: a constant across
sizes means memory linear in ``n`` (a dense ``n x n`` matrix would be 13 GB at 41k vertices).
Writes ``benchmarks/results/bench_segmentation.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

CHILD = r"""
import json, resource, sys, time
sys.path.insert(0, {repo!r})
from shape_toolkit.data.synthetic import articulated_shape
from shape_toolkit.results.labels import draw_constraints
from shape_toolkit.api.registry import create_plugin
from shape_toolkit.spectra import build_graph
from shape_toolkit.core.spectrum import compute_spectrum
from threadpoolctl import threadpool_limits
art = articulated_shape(subdivisions={sub})
shape = art.shape
cons = draw_constraints(art.labels, shape.edges, random_state=0)
_ = shape.edges, shape.face_areas
from shape_toolkit.api.registry import available_plugins
available_plugins()  # load every plugin module (sklearn, igl imports) before timing
import shape_toolkit.plugins.segmenters.csc, shape_toolkit.plugins.segmenters.eigvec_gmm  # noqa: E401
import shape_toolkit.plugins.segmenters.sdf, shape_toolkit.plugins.segmenters.ncut  # noqa: E401
import shape_toolkit.plugins.segmenters.seeded_walk, open3d, maxflow  # noqa: E401
import sklearn.cluster, sklearn.mixture  # noqa: E401
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t, c = time.perf_counter(), time.process_time()
with threadpool_limits({threads}):
    if {stage!r} == "spectrum-combinatorial":
        compute_spectrum(build_graph(shape, "gaussian"), 11, use_mass=False, cache=False)
    elif {stage!r} == "spectrum-normalized":
        compute_spectrum(build_graph(shape, "gaussian"), 11, laplacian="normalized", cache=False)
    elif {stage!r} == "eigvec-gmm":
        create_plugin("segmenters", "eigvec-gmm", n_segments=6).segment(shape)
    elif {stage!r} == "csc":
        create_plugin("segmenters", "csc", n_segments=6).segment(shape, constraints=cons)
    elif {stage!r} == "csc-vertex":
        create_plugin("segmenters", "csc", n_segments=6, graph="vertex").segment(shape, constraints=cons)
    elif {stage!r} == "seeded-walk":
        create_plugin("segmenters", "seeded-walk").segment(shape, constraints=cons)
    else:
        create_plugin("segmenters", {stage!r}, n_segments=6).segment(shape)
dt, cpu = time.perf_counter() - t, time.process_time() - c
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({{"n": shape.n_vertices, "m": shape.n_faces, "seconds": dt, "cpu_seconds": cpu,
                  "peak_kb": after - before}}))
"""


#: the segmenter stages, each timed against the spectrum stage
STAGES = ("eigvec-gmm", "csc", "csc-vertex", "ncut", "sdf", "seeded-walk")


def run_stage(sub: int, stage: str, threads: int) -> dict:
    """Run one stage in a fresh interpreter; returns ``{"n", "m", "seconds", "cpu_seconds", "peak_kb"}``."""
    code = CHILD.format(repo=str(REPO), sub=sub, stage=stage, threads=threads)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise RuntimeError(f"stage {stage} (subdivisions {sub}) failed:\n{out.stderr}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--subdivisions", type=int, nargs="+", default=[5, 6])
    ap.add_argument("--threads", type=int, default=1, help="BLAS/OpenMP threads (default 1)")
    ap.add_argument("--output", default=str(REPO / "benchmarks" / "results" / "bench_segmentation.md"))
    args = ap.parse_args(argv)
    sys.path.insert(0, str(REPO))
    from shape_toolkit.bench.worker import cpu_model

    rows = []
    for sub in args.subdivisions:
        spec = {}
        for stage, ref in [("spectrum-combinatorial", None)] + [(st, "spectrum-combinatorial") for st in STAGES]:
            print(f"subdivisions {sub}: {stage} ...", file=sys.stderr, flush=True)
            r = run_stage(sub, stage, args.threads)
            if ref is None:
                spec[stage] = r["seconds"]
            r.update(stage=stage, subdivisions=sub, ratio=r["seconds"] / spec[ref or stage])
            rows.append(r)
            print(f"  n={r['n']} {r['seconds']:.2f} s ({r['cpu_seconds']:.2f} s CPU), "
                  f"x{r['ratio']:.2f} of the spectrum, "
                  f"+{r['peak_kb'] / 1024:.0f} MB peak", file=sys.stderr, flush=True)
    load = Path("/proc/loadavg").read_text().split()[:3] if Path("/proc/loadavg").exists() else ["?"]
    lines = [
        "# Segmentation speed and memory of every segmenter vs the spectrum alone",
        "",
        "Regenerate with `python benchmarks/bench_segmentation.py`. "
        "Shapes: `articulated_shape(subdivisions=s)`;",
        f"k = 6; {args.threads} BLAS/OpenMP thread(s); load average at the end {' '.join(load)} "
        "(a shared machine: ratios are more meaningful than absolute times).",
        f"Machine: {cpu_model()}, {os.cpu_count()} cores. CPU = process CPU time of the stage's child.",
        "",
        "| vertices | faces | stage | seconds | seconds per 10k faces | CPU s | CPU s per 10k faces | x spectrum "
        "| peak MB added | MB per 1k vertices | MB per 10k faces |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        mb = r["peak_kb"] / 1024
        m10 = r["m"] / 1e4
        lines.append(f"| {r['n']} | {r['m']} | {r['stage']} | {r['seconds']:.2f} | {r['seconds'] / m10:.2f} | "
                     f"{r['cpu_seconds']:.2f} | {r['cpu_seconds'] / m10:.2f} | {r['ratio']:.2f} | {mb:.0f} | "
                     f"{mb / (r['n'] / 1000):.2f} | {mb / m10:.1f} |")
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    t0 = time.perf_counter()
    code = main()
    print(f"({time.perf_counter() - t0:.0f} s, max RSS of the driver "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024} MB)", file=sys.stderr)
    sys.exit(code)
