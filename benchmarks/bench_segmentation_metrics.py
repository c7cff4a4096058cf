"""Peak memory and time of the segmentation metrics (what ``evaluate-segmentation`` runs) against the
face count: they must grow linearly (issue 11: a 9k-face PSB mesh used to peak at 2.9 GB).

Each size runs in a fresh child process on a subdivided icosphere with a 12-part prediction and three
"human" segmentations of 6-10 parts (contiguous patches around random centres, like PSB). Peak memory is
the child's VmHWM minus its high-water mark just before the metrics (so the mesh itself is not counted).

Regenerate: ``python benchmarks/bench_segmentation_metrics.py`` (writes
``benchmarks/results/segmentation_metrics.md``).

A tool, not a config (issue 28): the runner times a row's metrics (``metric_seconds``) but measures no memory
of them, and its memory probe (a rise in one long-lived process) would under-count what this checks: the
metrics' own peak against the face count, in a fresh child per size.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results" / "segmentation_metrics.md"
SUBDIVISIONS = (4, 5, 6, 7)  # 5k, 20k, 82k, 328k faces


def _status_mb(field: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def _reset_peak() -> float:
    """Reset the high-water mark to the current RSS (Linux ``clear_refs`` 5); the RSS in MB."""
    import gc

    gc.collect()
    Path("/proc/self/clear_refs").write_text("5")
    return _status_mb("VmRSS")


def child(subdivisions: int) -> dict:
    """Measure one size in this process (run in a fresh child)."""
    import numpy as np

    from shape_toolkit.data.generate import icosphere
    from shape_toolkit.metrics.segmentation import segmentation_scores

    shape = icosphere(subdivisions)
    rng = np.random.default_rng(0)
    centroids = shape.vertices[shape.faces].mean(axis=1)

    def patches(k: int) -> np.ndarray:
        centres = centroids[rng.choice(len(centroids), k, replace=False)]
        d = ((centroids[:, None, :] - centres[None]) ** 2).sum(axis=2)
        return np.argmin(d, axis=1).astype(np.int64)

    pred = patches(12)
    truths = [patches(k) for k in (6, 8, 10)]
    import tracemalloc

    base = _reset_peak()
    tracemalloc.start()
    t0, c0 = time.perf_counter(), time.process_time()
    scores = segmentation_scores(pred, truths, mesh=shape)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    traced = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    return {
        "faces": int(shape.n_faces), "peak_mb": traced, "rss_rise_mb": max(_status_mb("VmHWM") - base, 0.0),
        "wall_s": wall, "cpu_s": cpu,
        "rand_index_error": float(scores["rand_index_error"]) if "rand_index_error" in scores else None,
    }


def main() -> None:
    if len(sys.argv) == 3 and sys.argv[1] == "--child":
        print(json.dumps(child(int(sys.argv[2]))))
        return
    rows = []
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    for s in SUBDIVISIONS:
        out = subprocess.run([sys.executable, __file__, "--child", str(s)], capture_output=True, text=True,
                             env=env, check=True)
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
        print(rows[-1], flush=True)
    load = os.getloadavg()[0]
    lines = [
        "# Segmentation metrics: peak memory and time against the face count",
        "",
        "Regenerate: `python benchmarks/bench_segmentation_metrics.py` (one fresh child process per size, one BLAS",
        f"thread; load average {load:.1f} on 2 cores while it ran). Metrics: Rand index, cut discrepancy, Hamming,",
        "GCE/LCE of a 12-part prediction against three 6-10-part segmentations (`segmentation_scores`, what",
        "`shape-toolkit evaluate-segmentation` computes). Peak = tracemalloc's peak of the numpy/Python allocations",
        "during the metrics (the RSS rise, reusing memory freed earlier, under-counts; last column).",
        "",
        "| faces | peak MB | MB per 10k faces | wall s | CPU s | RSS rise MB |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(f"| {r['faces']:,} | {r['peak_mb']:.1f} | {10_000 * r['peak_mb'] / r['faces']:.2f} | "
                     f"{r['wall_s']:.2f} | {r['cpu_s']:.2f} | {r['rss_rise_mb']:.1f} |")
    per = [10_000 * r["peak_mb"] / r["faces"] for r in rows[1:]]
    lines += ["", f"Memory per 10k faces stays between {min(per):.2f} and {max(per):.2f} MB from "
              f"{rows[1]['faces']:,} to {rows[-1]['faces']:,} faces: linear in the face count (the old code "
              "peaked at 2.9 GB on a 9k-face PSB mesh)."]
    RESULTS.write_text("\n".join(lines) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
