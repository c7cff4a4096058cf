"""Princeton Segmentation Benchmark on the shared meshes: every segmenter, every PSB metric.

    python benchmarks/psb_segmentation.py [--data DIR] [--meshes 1,2] [--output FILE]

Data: ``--data``, else ``$TOOLKIT_DATA``, else ``../shared/data`` next to the repository; the meshes
are ``psb/off/ID.off`` with human segmentations ``psb/seg/ID/ID_K.seg`` (one label per face).
Regenerates ``benchmarks/results/psb_segmentation.md`` (and ``.json``).

Protocol (stated again in the results file):

- ``k`` per mesh = the median number of segments over the mesh's human segmentations (rounded half
  up, at least 2); every method gets the same ``k`` (``eigvec-gmm-bic`` chooses its own by BIC).
- Unsupervised methods are scored against every human segmentation of the mesh, averaged.
- Constrained methods (csc, spectral-learning, ccskl) get constraints drawn automatically from the
  *first* human segmentation (``ID_0.seg``, converted to vertex labels by area-weighted majority):
  2 must-links chained inside each segment of at least 1% of the vertices, 3 cannot-links across
  every pair of neighbouring such segments (each end 8 edges from the cut),
  ``random_state`` fixed. They are scored against the *other* human segmentations.
- ``human`` is each human segmentation scored against the others (leave one out), averaged: the
  consistency ceiling the published PSB numbers call "Human".
- Predicted vertex labels become face labels by majority (ties to the smallest label). All metrics
  are area-weighted over faces, as in PSB; cut discrepancy uses Dijkstra distances over mesh edges
  (see ``shape_toolkit.metrics.segmentation``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from shape_toolkit.api.registry import create_plugin  # noqa: E402
from shape_toolkit.data.datasets import read_face_labels  # noqa: E402
from shape_toolkit.io.mesh import load_shape  # noqa: E402
from shape_toolkit.metrics.segmentation import SEGMENTATION_METRICS, segmentation_scores  # noqa: E402
from shape_toolkit.plugins.segmenters._common import graph_spectrum, shape_graph  # noqa: E402
from shape_toolkit.results.labels import draw_constraints, face_to_vertex_labels, vertex_to_face_labels  # noqa: E402

#: (row name, plugin name, extra params, constrained?, which spectrum to pass)
METHODS = [
    ("eigvec-gmm", "eigvec-gmm", {}, False, "combinatorial"),
    ("eigvec-gmm-norm", "eigvec-gmm", {"laplacian": "normalized"}, False, "normalized"),
    ("eigvec-gmm-bic", "eigvec-gmm", {"n_segments": None}, False, "combinatorial"),
    ("spectral-clustering", "spectral-clustering", {"variant": "ng"}, False, "normalized"),
    ("sc-commute-time", "spectral-clustering", {"variant": "commute-time"}, False, "combinatorial"),
    ("csc", "csc", {}, True, "combinatorial"),
    ("csc-volume", "csc", {"cannot_mode": "volume", "epsilon": 0.05}, True, "combinatorial"),
    ("spectral-learning", "spectral-learning", {}, True, None),
    ("ccskl", "ccskl", {}, True, "normalized"),
]

PUBLISHED = "human 0.103, RandCuts 0.152, NormCuts 0.172, ShapeDiam 0.175, KMeans about 0.25"


def data_dir(arg: str | None) -> Path:
    """The shared data directory (``--data``, ``$TOOLKIT_DATA``, or ``../shared/data``)."""
    if arg:
        return Path(arg)
    if os.environ.get("TOOLKIT_DATA"):
        return Path(os.environ["TOOLKIT_DATA"])
    return REPO.parent / "shared" / "data"


def human_k(truths: list[np.ndarray]) -> int:
    """Median number of segments over the human segmentations, rounded half up, >= 2."""
    counts = [len(np.unique(t)) for t in truths]
    return max(2, int(np.floor(np.median(counts) + 0.5)))


def _natural(p: Path) -> tuple:
    import re

    return tuple(int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.name))


def run_mesh(psb: Path, mesh_id: str, seed: int, log) -> dict:
    """Scores of every method on one mesh."""
    shape = load_shape(psb / "off" / f"{mesh_id}.off")
    files = sorted((psb / "seg" / mesh_id).glob("*.seg"), key=_natural)
    truths = [read_face_labels(f, shape.n_faces) for f in files]
    k = human_k(truths)
    areas = shape.face_areas
    rows = {}
    # human consistency: each segmentation against the others
    per = [segmentation_scores(truths[i], truths[:i] + truths[i + 1:], areas, mesh=shape)
           for i in range(len(truths))]
    rows["human"] = {m: float(np.nanmean([p[m] for p in per])) for m in SEGMENTATION_METRICS}
    rows["human"]["seconds"] = 0.0
    t0 = time.perf_counter()
    graph = shape_graph(shape, "gaussian")
    spectra = {
        kind: graph_spectrum(shape, max(k, 20) + 2, weighting="gaussian", laplacian=kind, graph=graph)
        for kind in ("combinatorial", "normalized")
    }
    t_spec = time.perf_counter() - t0
    vtruth0 = face_to_vertex_labels(shape.faces, truths[0], shape.n_vertices, areas)
    cons = draw_constraints(vtruth0, shape.edges, n_must_per_segment=2, n_cannot_per_boundary=3,
                            cannot_offset=8, min_segment_size=max(2, shape.n_vertices // 100),
                            random_state=seed)
    for name, plugin, params, constrained, kind in METHODS:
        params = {"n_segments": k, **params, "random_state": seed}
        seg = create_plugin("segmenters", plugin, **params)
        t = time.perf_counter()
        labels = seg.segment(shape, spectrum=spectra[kind] if kind else None,
                             constraints=cons if constrained else None)
        dt = time.perf_counter() - t
        pred = vertex_to_face_labels(shape.faces, labels)
        ref = truths[1:] if constrained and len(truths) > 1 else truths
        sc = segmentation_scores(pred, ref, areas, mesh=shape)
        rows[name] = {m: sc[m] for m in SEGMENTATION_METRICS}
        rows[name]["seconds"] = dt
        rows[name]["k"] = int(len(np.unique(labels)))
        if hasattr(seg, "selected_eigenvectors_"):
            rows[name]["selected"] = list(seg.selected_eigenvectors_)
        if getattr(seg, "bic_monotone_", None) is not None:
            rows[name]["bic_monotone"] = bool(seg.bic_monotone_)
        log(f"  {mesh_id:>4s} {name:20s} k={rows[name]['k']:2d} RI err={sc['rand_index_error']:.3f} "
            f"recall={sc['recall']:.3f} ({dt:.1f} s)")
    return {"mesh": mesh_id, "n_vertices": shape.n_vertices, "n_faces": shape.n_faces, "k": k,
            "n_truths": len(truths), "n_must": cons.n_must, "n_cannot": cons.n_cannot,
            "spectrum_seconds": t_spec, "rows": rows}


def _fmt(v: float) -> str:
    return "n/a" if v is None or not np.isfinite(v) else f"{v:.3f}"


def write_report(results: list[dict], out: Path, seed: int, elapsed: float) -> None:
    """Markdown tables: the mean over meshes per method, then every mesh."""
    names = ["human"] + [m[0] for m in METHODS]
    cols = list(SEGMENTATION_METRICS)
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True,
                                text=True, check=False).stdout.strip()
    except OSError:
        commit = "?"
    lines = [
        "# Princeton Segmentation Benchmark on the shared meshes",
        "",
        "Regenerate with `python benchmarks/psb_segmentation.py` (data: `--data`, `$TOOLKIT_DATA` or "
        "`../shared/data`).",
        f"Commit {commit}, random_state {seed}, {len(results)} meshes, {elapsed:.0f} s in total.",
        "",
        "Protocol: `k` per mesh = median number of segments of its human segmentations (rounded half up); "
        "unsupervised methods are scored against every human segmentation; constrained methods (csc, "
        "spectral-learning, ccskl) get constraints drawn from the first human segmentation (2 must-links "
        "chained inside each segment with >= 1% of the vertices, 3 cannot-links across each pair of "
        "neighbouring such segments, 8 edges from the cut on each side) and are scored against the others. "
        "`csc-volume` is CSC with the literal cannot-link rule (every edge of the volume set to "
        "epsilon = 0.05) instead of the default bisector cut. "
        "`human` = each human segmentation against the others. `eigvec-gmm-bic` chooses `k` by BIC "
        "(knee of the curve when BIC has no minimum up to 15); `eigvec-gmm-norm` uses the normalized "
        "Laplacian (thesis Fig. 4.1) instead of the default combinatorial one (4.2). "
        "`sc-commute-time` is the SC column of thesis Table 5.1 (k-means on the commute-time "
        "embedding); `spectral-clustering` is Ng et al. 2001. "
        "Metrics are area-weighted over faces; rand_index_error = 1 - Rand index; cut discrepancy uses "
        "Dijkstra distances along mesh edges normalised by the mean distance to the centroid; lower is "
        "better except recall and precision (thesis 5.5, optimal one-to-one matching).",
        "",
        f"Published PSB averages (Rand index error, all categories, for reference): {PUBLISHED}.",
        "",
        "## Mean over meshes",
        "",
        "| method | " + " | ".join(cols) + " | seconds |",
        "|---" * (len(cols) + 2) + "|",
    ]
    for name in names:
        vals = [np.nanmean([r["rows"][name][c] for r in results]) for c in cols]
        sec = np.mean([r["rows"][name]["seconds"] for r in results])
        lines.append(f"| {name} | " + " | ".join(_fmt(v) for v in vals) + f" | {sec:.1f} |")
    spec = np.mean([r["spectrum_seconds"] for r in results])
    lines += ["", f"Mean time of the two spectra per mesh (shared by the methods): {spec:.1f} s.", ""]
    lines += ["## Per mesh", ""]
    for r in results:
        lines += [
            f"### mesh {r['mesh']} ({r['n_vertices']} vertices, {r['n_faces']} faces, {r['n_truths']} human "
            f"segmentations, k = {r['k']}, constraints: {r['n_must']} must-link, "
            f"{r['n_cannot']} cannot-link)",
            "",
            "| method | k | " + " | ".join(cols) + " | seconds |",
            "|---" * (len(cols) + 3) + "|",
        ]
        for name in names:
            row = r["rows"][name]
            kk = row.get("k", "")
            extra = ""
            if "selected" in row:
                note = ", BIC without minimum" if row.get("bic_monotone") else ""
                extra = f" (eigenvectors {row['selected']}{note})"
            lines.append(f"| {name}{extra} | {kk} | " + " | ".join(_fmt(row[c]) for c in cols)
                         + f" | {row['seconds']:.1f} |")
        lines.append("")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines))
    out.with_suffix(".json").write_text(json.dumps(results, indent=1, default=float))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", help="shared data directory (contains psb/)")
    ap.add_argument("--meshes", help="comma-separated mesh ids (default: all)")
    ap.add_argument("--random-state", type=int, default=0)
    ap.add_argument("--output", default=str(REPO / "benchmarks" / "results" / "psb_segmentation.md"))
    args = ap.parse_args(argv)
    psb = data_dir(args.data) / "psb"
    if not (psb / "off").is_dir():
        print(f"psb_segmentation: no PSB meshes under {psb}: pass --data or set TOOLKIT_DATA",
              file=sys.stderr)
        return 2
    ids = sorted((p.stem for p in (psb / "off").glob("*.off")), key=lambda s: (len(s), s))
    if args.meshes:
        wanted = args.meshes.split(",")
        missing = sorted(set(wanted) - set(ids))
        if missing:
            print(f"psb_segmentation: unknown mesh ids {missing}; available {ids}", file=sys.stderr)
            return 2
        ids = [i for i in ids if i in wanted]
    t0 = time.perf_counter()
    results = []
    for mesh_id in ids:
        print(f"mesh {mesh_id} ...", file=sys.stderr, flush=True)
        results.append(run_mesh(psb, mesh_id, args.random_state,
                                lambda s: print(s, file=sys.stderr, flush=True)))
    write_report(results, Path(args.output), args.random_state, time.perf_counter() - t0)
    print(f"wrote {args.output}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
