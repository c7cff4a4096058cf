"""Speed and memory of the heat-kernel numerics and of the geodesic solvers (a benchmark, not a test).

    python benchmarks/bench_heat.py [--quick] [--output benchmarks/results/heat.md]

1. HKS at 16 scales with K = 100 on a ~200k-vertex torus, against the time of computing its
   101-eigenpair spectrum; peak extra memory (tracemalloc) at two sizes shows it is linear in n.
2. The heat-distance descriptor of all vertices to M = 20 keypoints at 5 scales on a ~50k-vertex
   torus, against its spectrum time.
3. Geodesic distances from 1,000 sources on the ~50k-vertex torus with fast marching
   (potpourri3d), the heat method (potpourri3d) and Dijkstra, side by side with libigl's exact
   geodesics (timed on a subset of sources, which also gives the mean relative error of the others).

A tool, not a config (issue 28): the runner's tasks (spectrum, keypoints, segmentation, matching) have no
descriptor or geodesic task, and these measurements (tracemalloc's peak of one call, extrapolated exact
geodesics) are not rows of one.
"""

from __future__ import annotations

import argparse
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from shape_toolkit.core.eigen import smallest_eigenpairs  # noqa: E402
from shape_toolkit.core.shape import Shape  # noqa: E402
from shape_toolkit.core.spectrum import Spectrum, compute_spectrum, laplacian_matrix  # noqa: E402
from shape_toolkit.errors import SolverError  # noqa: E402
from shape_toolkit.features import geodesics  # noqa: E402
from shape_toolkit.features.heat import heat_distances, heat_kernel_signature  # noqa: E402
from shape_toolkit.features.scales import multiscale_times  # noqa: E402
from shape_toolkit.spectra import build_graph  # noqa: E402


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def torus(n_target: int, R: float = 1.0, r: float = 0.4) -> Shape:
    """A regular-grid torus with about ``n_target`` vertices (an irrational-ish aspect ratio)."""
    nu = int(round(np.sqrt(n_target * 2.5)))
    nv = max(3, int(round(n_target / nu)))
    u, v = np.meshgrid(np.arange(nu) * 2 * np.pi / nu, np.arange(nv) * 2 * np.pi / nv, indexing="ij")
    # a slight bump breaks the symmetry so that eigenvalues are not all degenerate
    rr = r * (1 + 0.15 * np.cos(u) * np.sin(2 * v))
    X = np.stack([(R + rr * np.cos(v)) * np.cos(u), (R + rr * np.cos(v)) * np.sin(u), rr * np.sin(v)], -1)
    idx = np.arange(nu * nv).reshape(nu, nv)
    a, b = idx, np.roll(idx, -1, 0)
    c, d = np.roll(idx, -1, 1), np.roll(np.roll(idx, -1, 0), -1, 1)
    F = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    return Shape(X.reshape(-1, 3), F, f"torus{nu * nv}")


NOTES: list[str] = []


def spectrum_of(shape: Shape, k: int):
    """The Gaussian-weighted combinatorial spectrum and its wall time (toolkit solver; ARPACK
    shift-invert if it fails)."""
    graph = build_graph(shape, "gaussian")
    tic = time.perf_counter()
    try:
        spec = compute_spectrum(graph, k, cache=False)
    except SolverError as exc:
        NOTES.append(f"{shape.name}: compute_spectrum failed ({exc}); timed eigsh shift-invert instead")
        log(NOTES[-1])
        tic = time.perf_counter()
        vals, vecs = smallest_eigenpairs(laplacian_matrix(graph.W), k, method="arpack")
        spec = Spectrum(np.maximum(vals, 0), vecs, "combinatorial", "gaussian", None, graph.degrees)
    return spec, time.perf_counter() - tic


def timed_peak(fn):
    tracemalloc.start()
    tic = time.perf_counter()
    out = fn()
    dt = time.perf_counter() - tic
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return out, dt, peak


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="smaller shapes (smoke run)")
    ap.add_argument("--exact-sources", type=int, default=1,
                    help="sources timed with libigl exact (minutes each at 50k)")
    ap.add_argument("--output", default=str(REPO / "benchmarks" / "results" / "heat.md"))
    args = ap.parse_args(argv)
    big, mid, n_src = (20_000, 5_000, 100) if args.quick else (200_000, 50_000, 1000)
    lines = ["# Heat-kernel and geodesic benchmarks", "",
             "Regenerate: `python benchmarks/bench_heat.py` (add `--quick` for a smoke run). "
             "Machine: 2 shared cores; times are wall-clock seconds of one run, compare ratios.", ""]

    # 1. HKS -------------------------------------------------------------------------------
    lines += ["## 1. HKS, 16 scales, K = 100", "",
              "| n | spectrum (101 pairs) s | HKS s | HKS / spectrum | HKS peak extra memory "
              "| bytes per vertex |",
              "|---|---|---|---|---|---|"]
    for n in (big // 4, big):
        shape = torus(n)
        log(f"HKS: {shape.name}: computing the spectrum ...")
        spec, t_spec = spectrum_of(shape, 101)
        times = np.geomspace(1.0, 1000.0, 16)
        hks, t_hks, peak = timed_peak(
            lambda spec=spec, times=times: heat_kernel_signature(spec, times, K=100)
        )
        assert hks.shape == (shape.n_vertices, 16)
        lines.append(f"| {shape.n_vertices} | {t_spec:.1f} | {t_hks:.3f} | {t_hks / t_spec:.4f} | "
                     f"{peak / 2**20:.1f} MiB | {peak / shape.n_vertices:.0f} |")
        log(lines[-1])
    lines += ["", "Peak extra memory includes the (n, 16) output (128 bytes per vertex) and one row chunk "
              "of U**2 (at most 16384 x 100 floats, 12.5 MiB); the (n, 101) eigenvectors themselves "
              "(808 bytes per vertex) belong to the spectrum. Bytes per vertex do not grow with n: "
              "memory is linear in n (output + a fixed-size chunk), no n x n matrix.", ""]

    # 2. heat-distance descriptor --------------------------------------------------------------
    shape = torus(mid)
    log(f"heat distance: {shape.name}: computing the spectrum ...")
    spec, t_spec = spectrum_of(shape, 51)
    kp = np.linspace(0, shape.n_vertices - 1, 20).astype(np.int64)

    def desc():
        t = multiscale_times(spec, 5, 25)
        return heat_distances(spec, t, kp, normalization="unit-sphere", K=25)

    D, t_desc, peak = timed_peak(desc)
    assert D.shape == (5, 20, shape.n_vertices)
    lines += ["## 2. Heat-distance descriptor, M = 20 keypoints, 5 scales, K = 25 (unit-sphere metric)", "",
              "| n | spectrum (51 pairs) s | descriptor s | descriptor / spectrum | peak extra memory |",
              "|---|---|---|---|---|",
              f"| {shape.n_vertices} | {t_spec:.1f} | {t_desc:.3f} | {t_desc / t_spec:.4f} | "
              f"{peak / 2**20:.1f} MiB ({peak / shape.n_vertices:.0f} B/vertex; output is "
              f"{5 * 20 * 8} B/vertex) |", ""]
    log(lines[-2])

    # 3. geodesics ----------------------------------------------------------------------------
    rng = np.random.default_rng(0)
    sources = np.sort(rng.choice(shape.n_vertices, n_src, replace=False))
    sub = sources[: args.exact_sources]
    geodesics.clear_geodesic_cache()
    log(f"geodesics: exact from {sub.size} sources ...")
    tic = time.perf_counter()
    exact = geodesics.geodesic_distances(shape, sub, method="exact", cache=False)
    t_exact = (time.perf_counter() - tic) / sub.size
    lines += [f"## 3. Geodesics from {n_src} sources on the {shape.n_vertices}-vertex torus", "",
              f"libigl exact was run on {sub.size} of the sources (its per-source time is extrapolated to "
              f"{n_src}); the mean relative error of the other methods is measured against it on those "
              "sources (vertices farther than 1% of the largest distance).", "",
              "| method | s per source | total s for all sources | vs exact (speed-up) | mean rel. error | "
              "max rel. error |",
              "|---|---|---|---|---|---|",
              f"| exact (libigl) | {t_exact:.3f} | {t_exact * n_src:.0f} (extrapolated) | 1 | 0 | 0 |"]
    for method in ("fmm", "heat", "dijkstra"):
        log(f"geodesics: {method} from {n_src} sources ...")
        geodesics.clear_geodesic_cache()
        tic = time.perf_counter()
        for s in range(0, n_src, 100):  # chunks: the (1000, n) float64 result would be 400 MB
            rows = geodesics.geodesic_distances(shape, sources[s : s + 100], method=method, cache=False)
            if s == 0:
                approx = rows[: sub.size].copy()
        total = time.perf_counter() - tic
        mask = exact > 0.01 * exact.max()
        rel = np.abs(approx - exact)[mask] / exact[mask]
        lines.append(f"| {method} | {total / n_src:.4f} | {total:.1f} | {t_exact * n_src / total:.0f}x | "
                     f"{rel.mean():.4f} | {rel.max():.3f} |")
        log(lines[-1])
    lines += ["", "fmm: potpourri3d `MeshFastMarchingDistanceSolver`; heat: potpourri3d "
              "`MeshHeatMethodDistanceSolver` (robust intrinsic-Delaunay Laplacian, factored once, reused "
              "across sources); dijkstra: scipy on mesh edges.", ""]
    if NOTES:
        lines += ["Notes:", ""] + [f"- {x}" for x in NOTES] + [""]
    text = "\n".join(lines)
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    Path(args.output).write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
