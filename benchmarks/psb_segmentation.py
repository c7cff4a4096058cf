"""Princeton Segmentation Benchmark on the shared meshes: every segmenter, every PSB metric.

    python benchmarks/psb_segmentation.py [--data DIR] [--meshes 1,2] [--methods a,b] [--no-tune] [--output FILE]

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
- Split: within each PSB category the meshes are ordered by the SHA-1 of their file name and the
  first half (rounded down, at least one when the category has two or more) is the *tuning* split,
  the rest *held out* (:func:`split_of`). The free parameters of ``sdf`` (``n_clusters``,
  ``smoothing_lambda``) and of ``smoothed`` (``smoothing_lambda``) are chosen on the tuning split only
  (mean Rand index error), first, in the same process; every table reports tuning and held-out
  meshes separately, per category.
- ``csc-1ml`` is CSC with *one* must-link per segment (2 clicks per segment of >= 1% of the
  vertices, both well inside it) plus the same 3 cannot-links per neighbouring pair (2 clicks each,
  8 edges either side of the cut).
- Time and peak memory (``tracemalloc``: numpy and Python allocations; native buffers of Open3D,
  PyMaxflow and ARPACK are not seen) per method, also per 10k faces. Spectra are computed once per
  mesh for all methods (``spectrum_specs()`` merged) and not counted in a method's time.
- Predicted labels are per face when the segmenter provides ``face_labels_`` (``sdf``, ``smoothed``);
  otherwise predicted vertex labels become face labels by majority (ties to the smallest label). All metrics
  are area-weighted over faces, as in PSB; cut discrepancy uses Dijkstra distances over mesh edges
  (see ``shape_toolkit.metrics.segmentation``).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from shape_toolkit.api.registry import create_plugin  # noqa: E402
from shape_toolkit.core.spectrum import merge_specs  # noqa: E402
from shape_toolkit.data.datasets import read_face_labels  # noqa: E402
from shape_toolkit.io.mesh import load_shape  # noqa: E402
from shape_toolkit.metrics.segmentation import (  # noqa: E402
    SEGMENTATION_METRICS,
    rand_index_error,
    segmentation_scores,
)
from shape_toolkit.results.labels import draw_constraints, face_to_vertex_labels, vertex_to_face_labels  # noqa: E402

#: (row name, plugin name, extra params, constraints: None / "default" / "one-must-link")
#: a ``smoothed`` row names its base as ``base`` (plugin name) and the base's parameters as ``base_params``
METHODS = [
    ("eigvec-gmm", "eigvec-gmm", {}, None),
    ("eigvec-gmm+smooth", "smoothed", {"base": "eigvec-gmm"}, None),
    ("eigvec-gmm-norm", "eigvec-gmm", {"laplacian": "normalized"}, None),
    ("eigvec-gmm-bic", "eigvec-gmm", {"n_segments": None}, None),
    ("spectral-clustering", "spectral-clustering", {"variant": "ng"}, None),
    ("spectral-clustering+smooth", "smoothed", {"base": "spectral-clustering", "base_params": {"variant": "ng"}},
     None),
    ("sc-commute-time", "spectral-clustering", {"variant": "commute-time"}, None),
    ("sdf", "sdf", {}, None),
    ("sdf-no-cut", "sdf", {"smoothing_lambda": 0.0}, None),
    ("csc", "csc", {}, "default"),
    ("csc+smooth", "smoothed", {"base": "csc"}, "default"),
    ("csc-1ml", "csc", {}, "one-must-link"),
    ("csc-volume", "csc", {"cannot_mode": "volume", "epsilon": 0.05}, "default"),
    ("spectral-learning", "spectral-learning", {}, "default"),
    ("ccskl", "ccskl", {}, "default"),
]

#: tuning grids (tuning split only); the winners are passed to every ``sdf`` / ``smoothed`` row
SDF_GRID = [{"n_clusters": c, "smoothing_lambda": lam} for c in (5, None) for lam in (0.26, 1.0)]
SMOOTH_GRID = [0.25, 0.5, 1.0, 2.0]
#: the base segmenter of the ``smoothed`` tuning (fast; its lambda is then used for every base)
SMOOTH_TUNE_BASE = ("spectral-clustering", {"variant": "ng"})

CATEGORIES = ["human", "cup", "glasses", "airplane", "ant", "chair", "octopus", "table", "teddy", "hand",
              "plier", "fish", "bird", "(spring)", "armadillo", "bust", "mech", "bearing", "vase",
              "fourleg"]

PUBLISHED = "human 0.103, RandCuts 0.152, NormCuts 0.172, ShapeDiam 0.175, KMeans about 0.25"


def data_dir(arg: str | None) -> Path:
    """The shared data directory (``--data``, ``$TOOLKIT_DATA``, or ``../shared/data``)."""
    if arg:
        return Path(arg)
    if os.environ.get("TOOLKIT_DATA"):
        return Path(os.environ["TOOLKIT_DATA"])
    return REPO.parent / "shared" / "data"


def category_of(mesh_id: str) -> str:
    """PSB category of a mesh id (20 models per category, ids 1..400)."""
    return CATEGORIES[(int(mesh_id) - 1) // 20]


def split_of(ids: list[str]) -> dict[str, str]:
    """``{id: "tuning" | "held-out"}``: per category, ids ordered by SHA-1 of ``ID.off``; the first
    ``len // 2`` are for tuning."""
    out: dict[str, str] = {}
    by_cat: dict[str, list[str]] = {}
    for i in ids:
        by_cat.setdefault(category_of(i), []).append(i)
    for members in by_cat.values():
        members = sorted(members, key=lambda i: hashlib.sha1(f"{i}.off".encode()).hexdigest())
        n_tune = len(members) // 2
        for j, i in enumerate(members):
            out[i] = "tuning" if j < n_tune else "held-out"
    return out


def human_k(truths: list[np.ndarray]) -> int:
    """Median number of segments over the human segmentations, rounded half up, >= 2."""
    counts = [len(np.unique(t)) for t in truths]
    return max(2, int(np.floor(np.median(counts) + 0.5)))


def _natural(p: Path) -> tuple:
    import re

    return tuple(int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.name))


def _load(psb: Path, mesh_id: str):
    shape = load_shape(psb / "off" / f"{mesh_id}.off")
    files = sorted((psb / "seg" / mesh_id).glob("*.seg"), key=_natural)
    truths = [read_face_labels(f, shape.n_faces) for f in files]
    return shape, truths


def _make(plugin: str, params: dict, k: int, seed: int, tuned: dict):
    """The plugin of a METHODS row with ``k`` segments, ``random_state`` and the tuned parameters."""
    params = dict(params)
    if plugin == "smoothed":
        base_name = params.pop("base")
        base_params = {"n_segments": k, **params.pop("base_params", {}), "random_state": seed}
        base = create_plugin("segmenters", base_name, **base_params)
        return create_plugin("segmenters", "smoothed", base=base, **{**tuned.get("smoothed", {}), **params})
    if plugin == "sdf":
        params = {**tuned.get("sdf", {}), **params}
    return create_plugin("segmenters", plugin, **{"n_segments": k, **params, "random_state": seed})


def _face_prediction(seg, shape, labels) -> np.ndarray:
    fl = getattr(seg, "face_labels_", None)
    if fl is not None and len(fl) == shape.n_faces:
        return np.asarray(fl)
    return vertex_to_face_labels(shape.faces, labels)


def tune(psb: Path, ids: list[str], seed: int, log) -> dict:
    """Grid search of the ``sdf`` and ``smoothed`` parameters on ``ids`` (the tuning split), by mean
    Rand index error against every human segmentation."""
    from shape_toolkit.features.smoothing import smooth_labels

    sdf_err = {i: [] for i in range(len(SDF_GRID))}
    sm_err = {lam: [] for lam in SMOOTH_GRID}
    base_err = []
    for mesh_id in ids:
        shape, truths = _load(psb, mesh_id)
        k = human_k(truths)
        areas = shape.face_areas

        def err(fl, truths=truths, areas=areas):
            return float(np.mean([rand_index_error(fl, t, areas) for t in truths]))

        for i, params in enumerate(SDF_GRID):
            seg = create_plugin("segmenters", "sdf", n_segments=k, random_state=seed, **params)
            seg.segment(shape)
            sdf_err[i].append(err(seg.face_labels_))
        base = create_plugin("segmenters", SMOOTH_TUNE_BASE[0], n_segments=k, random_state=seed,
                             **SMOOTH_TUNE_BASE[1])
        try:
            fl0 = vertex_to_face_labels(shape.faces, base.segment(shape))
        except Exception as exc:  # reported by the main run
            log(f"  tune {mesh_id}: {SMOOTH_TUNE_BASE[0]} failed ({type(exc).__name__}: {exc})")
            continue
        base_err.append(err(fl0))
        for lam in SMOOTH_GRID:
            sm_err[lam].append(err(smooth_labels(shape, fl0, None, lam, on="faces")))
        log(f"  tune {mesh_id}: sdf {[round(v[-1], 3) for v in sdf_err.values()]} "
            f"smooth {[round(v[-1], 3) for v in sm_err.values()]} (base {base_err[-1]:.3f})")
    sdf_mean = {i: float(np.mean(v)) for i, v in sdf_err.items()}
    sm_mean = {lam: float(np.mean(v)) for lam, v in sm_err.items()}
    best_sdf = SDF_GRID[min(sdf_mean, key=sdf_mean.get)]
    best_lam = min(sm_mean, key=sm_mean.get)
    return {
        "ids": ids,
        "sdf_grid": [{**p, "rand_index_error": sdf_mean[i]} for i, p in enumerate(SDF_GRID)],
        "smooth_grid": [{"smoothing_lambda": lam, "rand_index_error": sm_mean[lam]} for lam in SMOOTH_GRID],
        "smooth_base_error": float(np.mean(base_err)) if base_err else float("nan"),
        "sdf": dict(best_sdf),
        "smoothed": {"smoothing_lambda": best_lam},
    }


def run_mesh(psb: Path, mesh_id: str, seed: int, log, methods=None, tuned: dict | None = None,
             trace_memory: bool = False) -> dict:
    """Scores of every method on one mesh."""
    tuned = tuned or {}
    methods = methods or METHODS
    shape, truths = _load(psb, mesh_id)
    k = human_k(truths)
    areas = shape.face_areas
    rows = {}
    # human consistency: each segmentation against the others
    per = [segmentation_scores(truths[i], truths[:i] + truths[i + 1:], areas, mesh=shape)
           for i in range(len(truths))]
    rows["human"] = {m: float(np.nanmean([p[m] for p in per])) for m in SEGMENTATION_METRICS}
    rows["human"]["seconds"] = 0.0
    vtruth0 = face_to_vertex_labels(shape.faces, truths[0], shape.n_vertices, areas)
    common = dict(n_cannot_per_boundary=3, cannot_offset=8, min_segment_size=max(2, shape.n_vertices // 100),
                  random_state=seed)
    cons = {"default": draw_constraints(vtruth0, shape.edges, n_must_per_segment=2, **common),
            "one-must-link": draw_constraints(vtruth0, shape.edges, n_must_per_segment=1, **common)}
    plugins = {name: _make(plugin, params, k, seed, tuned) for name, plugin, params, _ in methods}
    t0 = time.perf_counter()
    specs = merge_specs(s for p in plugins.values() for s in p.spectrum_specs())
    spectra, spec_errors = [], []
    for spec in specs:
        try:
            spectra.append(spec.compute(shape))
        except Exception as exc:
            spec_errors.append(f"{spec.to_dict()}: {type(exc).__name__}: {exc}")
    t_spec = time.perf_counter() - t0
    for name, _plugin, _params, cmode in methods:
        seg = plugins[name]
        kwargs = {"spectrum": spectra if seg.spectrum_specs() else None,
                  "constraints": cons[cmode] if cmode else None}
        t = time.perf_counter()
        try:
            labels = seg.segment(shape, **kwargs)
            error = None
        except Exception as exc:
            labels, error = None, f"{type(exc).__name__}: {exc}"
        dt = time.perf_counter() - t
        peak = float("nan")
        if trace_memory and error is None:  # a second run, traced (tracemalloc slows Python code down)
            from shape_toolkit.plugins.segmenters import sdf as _sdf

            _sdf._SDF_CACHE.clear()
            again = _make(*[m for m in methods if m[0] == name][0][1:3], k, seed, tuned)
            tracemalloc.start()
            tracemalloc.reset_peak()
            again.segment(shape, **kwargs)
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
        if error is not None:
            rows[name] = {"error": error, "seconds": dt}
            log(f"  {mesh_id:>4s} {name:26s} FAILED: {error}")
            continue
        pred = _face_prediction(seg, shape, labels)
        ref = truths[1:] if cmode and len(truths) > 1 else truths
        sc = segmentation_scores(pred, ref, areas, mesh=shape)
        rows[name] = {m: sc[m] for m in SEGMENTATION_METRICS}
        rows[name]["seconds"] = dt
        if np.isfinite(peak):
            rows[name]["peak_mb"] = peak / 2**20
        rows[name]["k"] = int(len(np.unique(pred)))
        if hasattr(seg, "selected_eigenvectors_"):
            rows[name]["selected"] = list(seg.selected_eigenvectors_)
        if getattr(seg, "bic_monotone_", None) is not None:
            rows[name]["bic_monotone"] = bool(seg.bic_monotone_)
        log(f"  {mesh_id:>4s} {name:26s} k={rows[name]['k']:2d} RI err={sc['rand_index_error']:.3f} "
            f"({dt:.1f} s, {peak / 2**20:.0f} MB)")
    return {"mesh": mesh_id, "category": category_of(mesh_id), "n_vertices": shape.n_vertices,
            "n_faces": shape.n_faces, "k": k, "n_truths": len(truths),
            "n_must": cons["default"].n_must, "n_cannot": cons["default"].n_cannot,
            "n_must_1ml": cons["one-must-link"].n_must, "spectrum_seconds": t_spec,
            "spectrum_errors": spec_errors, "rows": rows}


def _fmt(v: float) -> str:
    return "n/a" if v is None or not np.isfinite(v) else f"{v:.3f}"


def _mean(results: list[dict], name: str, col: str) -> float:
    vals = [r["rows"][name][col] for r in results if name in r["rows"] and col in r["rows"][name]]
    vals = [v for v in vals if v is not None and np.isfinite(v)]
    return float(np.mean(vals)) if vals else float("nan")


def _category_mean(results: list[dict], name: str, col: str) -> float:
    """Mean over categories of the per-category mean (every category weighs the same)."""
    cats = sorted({r["category"] for r in results})
    vals = [_mean([r for r in results if r["category"] == c], name, col) for c in cats]
    vals = [v for v in vals if np.isfinite(v)]
    return float(np.mean(vals)) if vals else float("nan")


def _summary_table(results: list[dict], names: list[str], cols: list[str]) -> list[str]:
    lines = ["| method | " + " | ".join(cols) + " | RI err, mean of categories | failures |",
             "|---" * (len(cols) + 3) + "|"]
    for name in names:
        fails = sum(1 for r in results if "error" in r["rows"].get(name, {}))
        lines.append(f"| {name} | " + " | ".join(_fmt(_mean(results, name, c)) for c in cols)
                     + f" | {_fmt(_category_mean(results, name, 'rand_index_error'))} | {fails} |")
    return lines


def write_report(results: list[dict], out: Path, seed: int, elapsed: float, tuned: dict | None = None,
                 names: list[str] | None = None, command: str = "") -> None:
    """Markdown: tuning, summary per split, per category (Rand index error), time and memory, every mesh."""
    names = ["human"] + (names or [m[0] for m in METHODS])
    cols = list(SEGMENTATION_METRICS)
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True,
                                text=True, check=False).stdout.strip()
    except OSError:
        commit = "?"
    split = {r["mesh"]: r["split"] for r in results}
    tune_res = [r for r in results if split[r["mesh"]] == "tuning"]
    held = [r for r in results if split[r["mesh"]] == "held-out"]
    lines = [
        "# Princeton Segmentation Benchmark on the shared meshes",
        "",
        f"Regenerate with `{command or 'python benchmarks/psb_segmentation.py'}` (data: `--data`, "
        "`$TOOLKIT_DATA` or `../shared/data`).",
        f"Commit {commit} (plus the working tree), random_state {seed}, {len(results)} meshes "
        f"({len(tune_res)} tuning, {len(held)} held out), {elapsed:.0f} s in total.",
        "",
        "Protocol: `k` per mesh = median number of segments of its human segmentations (rounded half up); "
        "unsupervised methods are scored against every human segmentation; constrained methods (csc, "
        "spectral-learning, ccskl) get constraints drawn from the first human segmentation (2 must-links "
        "chained inside each segment with >= 1% of the vertices, i.e. 3 clicks per segment, 3 cannot-links "
        "across each pair of neighbouring such segments, 8 edges from the cut on each side, 2 clicks each) "
        "and are scored against the others. `csc-1ml`: the same with ONE must-link per segment (2 clicks "
        "per segment, both at least 3 rings inside it). `csc-volume` is CSC with the literal cannot-link "
        "rule (every edge of the volume set to epsilon = 0.05) instead of the default bisector cut. "
        "`human` = each human segmentation against the others. `eigvec-gmm-bic` chooses `k` by BIC; "
        "`eigvec-gmm-norm` uses the normalized Laplacian. `sc-commute-time` is k-means on the commute-time "
        "embedding; `spectral-clustering` is Ng et al. 2001. `sdf`: Shape Diameter Function, 1-D GMM, "
        "alpha-expansion graph cut with the concavity-aware dihedral cost, then connected components merged "
        "down to `k` (CGAL's method); `sdf-no-cut`: the same without the graph cut. `X+smooth`: the "
        "`smoothed` plugin, the same graph cut applied to X's labels. "
        "Metrics are area-weighted over faces; rand_index_error = 1 - Rand index; lower is better except "
        "recall and precision. Method time excludes the spectra (computed once per mesh for all methods).",
        "",
        "Split: per category, mesh ids ordered by SHA-1 of `ID.off`, first half (rounded down) = tuning. "
        "Parameters chosen on the tuning split only; the held-out numbers are the honest ones.",
        "",
        f"Published PSB averages (Rand index error, all categories, for reference): {PUBLISHED}.",
        "",
    ]
    if tuned:
        lines += ["## Tuning (tuning split only, mean Rand index error)", "",
                  f"Tuning meshes: {', '.join(tuned['ids'])}.", "",
                  "| sdf n_clusters | sdf smoothing_lambda | RI err |", "|---|---|---|"]
        for row in tuned["sdf_grid"]:
            nc = "k" if row["n_clusters"] is None else row["n_clusters"]
            lines.append(f"| {nc} | {row['smoothing_lambda']} | {_fmt(row['rand_index_error'])} |")
        lines += ["", f"`smoothed` on {SMOOTH_TUNE_BASE[0]} (unsmoothed: {_fmt(tuned['smooth_base_error'])}):", "",
                  "| smoothing_lambda | RI err |", "|---|---|"]
        for row in tuned["smooth_grid"]:
            lines.append(f"| {row['smoothing_lambda']} | {_fmt(row['rand_index_error'])} |")
        lines += ["", f"Chosen: sdf {tuned['sdf']}, smoothed {tuned['smoothed']}.", ""]
    # targets
    unsup = [n for n in names if n != "human" and not any(m[0] == n and m[3] for m in METHODS)]
    if held and unsup:
        best = min(unsup, key=lambda n: _category_mean(held, n, "rand_index_error"))
        vb = _category_mean(held, best, "rand_index_error")
        lines += ["## Targets (held-out split, mean over categories of the Rand index error)", "",
                  f"- best unsupervised: {best} {_fmt(vb)} (target <= 0.13: {'met' if vb <= 0.13 else 'NOT met'}); "
                  f"all meshes: {_fmt(_category_mean(results, best, 'rand_index_error'))}"]
        if "csc-1ml" in names:
            vc = _category_mean(held, "csc-1ml", "rand_index_error")
            lines.append(f"- csc with one must-link per segment (csc-1ml): {_fmt(vc)} (target <= 0.10: "
                         f"{'met' if vc <= 0.10 else 'NOT met'}); all meshes: "
                         f"{_fmt(_category_mean(results, 'csc-1ml', 'rand_index_error'))}")
        if "eigvec-gmm" in names and "spectral-clustering" in names:
            cats = sorted({r["category"] for r in results})
            wins = sum(1 for c in cats
                       if _mean([r for r in results if r["category"] == c], "eigvec-gmm", "rand_index_error")
                       < _mean([r for r in results if r["category"] == c], "spectral-clustering", "rand_index_error"))
            lines.append(f"- eigvec-gmm beats spectral-clustering (Ng) in {wins} of {len(cats)} categories "
                         "(all meshes, Rand index error; table below)")
        lines.append("")
    for label, subset in (("held-out split", held), ("tuning split", tune_res), ("all meshes", results)):
        if subset:
            lines += [f"## Mean over meshes: {label} ({len(subset)} meshes)", ""]
            lines += _summary_table(subset, names, cols) + [""]
    # per category, Rand index error, tuning / held-out
    cats = [c for c in CATEGORIES if any(r["category"] == c for r in results)]
    lines += ["## Rand index error per category (tuning / held-out; '-' = no mesh of that split)", "",
              "| method | " + " | ".join(cats) + " |", "|---" * (len(cats) + 1) + "|"]
    for name in names:
        cells = []
        for c in cats:
            parts = []
            for sub in (tune_res, held):
                rs = [r for r in sub if r["category"] == c]
                parts.append(_fmt(_mean(rs, name, "rand_index_error")) if rs else "-")
            cells.append(" / ".join(parts))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines.append("")
    # time and memory
    lines += ["## Time and peak memory (all meshes)", "",
              "Per 10k faces = the method's seconds (or tracemalloc peak MB) divided by faces / 10 000, averaged "
              "over meshes. Seconds: untraced run, every mesh (sdf includes its ray casting; methods after the "
              "first sdf row reuse its cached SDF). Peak MB: a second, traced run on every 10th mesh only "
              "(tracemalloc slows Python code several-fold); it sees numpy and Python allocations, not Open3D / "
              "PyMaxflow / ARPACK native buffers.", "",
              "| method | seconds per mesh | seconds per 10k faces | peak MB per mesh | peak MB per 10k faces |",
              "|---|---|---|---|---|"]
    for name in names[1:]:
        rs = [r for r in results if "k" in r["rows"].get(name, {})]
        rm = [r for r in rs if "peak_mb" in r["rows"][name]]
        if not rs:
            continue
        sec = np.mean([r["rows"][name]["seconds"] for r in rs])
        sec10 = np.mean([r["rows"][name]["seconds"] / (r["n_faces"] / 1e4) for r in rs])
        mb = np.mean([r["rows"][name]["peak_mb"] for r in rm]) if rm else float("nan")
        mb10 = np.mean([r["rows"][name]["peak_mb"] / (r["n_faces"] / 1e4) for r in rm]) if rm else float("nan")
        lines.append(f"| {name} | {sec:.2f} | {sec10:.2f} | {mb:.0f} | {mb10:.0f} |")
    spec = np.mean([r["spectrum_seconds"] for r in results])
    lines += ["", f"Mean time of the spectra per mesh (shared by the methods): {spec:.1f} s.", ""]
    fails = [(r["mesh"], n, r["rows"][n]["error"]) for r in results for n in names if "error" in r["rows"].get(n, {})]
    fails += [(r["mesh"], "spectrum", e) for r in results for e in r.get("spectrum_errors", [])]
    lines += ["## Failures", ""] + ([f"- mesh {m}, {n}: {e}" for m, n, e in fails] or ["None."]) + [""]
    lines += ["## Per mesh", ""]
    for r in results:
        lines += [
            f"### mesh {r['mesh']} ({r['category']}, {r['split']}; {r['n_vertices']} vertices, {r['n_faces']} "
            f"faces, {r['n_truths']} human segmentations, k = {r['k']}, constraints: {r['n_must']} must-link "
            f"({r['n_must_1ml']} for csc-1ml), {r['n_cannot']} cannot-link)",
            "",
            "| method | k | " + " | ".join(cols) + " | seconds |",
            "|---" * (len(cols) + 3) + "|",
        ]
        for name in names:
            row = r["rows"].get(name)
            if row is None:
                continue
            if "error" in row:
                lines.append(f"| {name} | failed: {row['error'][:120]} |" + " |" * (len(cols) + 1))
                continue
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
    out.with_suffix(".json").write_text(json.dumps({"tuned": tuned, "results": results}, indent=1, default=float))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", help="shared data directory (contains psb/)")
    ap.add_argument("--meshes", help="comma-separated mesh ids (default: all)")
    ap.add_argument("--methods", help="comma-separated METHODS row names (default: all)")
    ap.add_argument("--no-tune", action="store_true", help="skip the tuning sweep (plugin defaults)")
    ap.add_argument("--random-state", type=int, default=0)
    ap.add_argument("--output", default=str(REPO / "benchmarks" / "results" / "psb_segmentation.md"))
    args = ap.parse_args(argv)
    psb = data_dir(args.data) / "psb"
    if not (psb / "off").is_dir():
        print(f"psb_segmentation: no PSB meshes under {psb}: pass --data or set TOOLKIT_DATA",
              file=sys.stderr)
        return 2
    all_ids = sorted((p.stem for p in (psb / "off").glob("*.off")), key=lambda s: (len(s), s))
    split = split_of(all_ids)
    ids = all_ids
    if args.meshes:
        wanted = args.meshes.split(",")
        missing = sorted(set(wanted) - set(ids))
        if missing:
            print(f"psb_segmentation: unknown mesh ids {missing}; available {ids}", file=sys.stderr)
            return 2
        ids = [i for i in ids if i in wanted]
    methods = METHODS
    if args.methods:
        wanted_m = args.methods.split(",")
        unknown = sorted(set(wanted_m) - {m[0] for m in METHODS})
        if unknown:
            print(f"psb_segmentation: unknown methods {unknown}", file=sys.stderr)
            return 2
        methods = [m for m in METHODS if m[0] in wanted_m]

    def log(s):
        print(s, file=sys.stderr, flush=True)

    t0 = time.perf_counter()
    tuned = None
    if not args.no_tune:
        tune_ids = [i for i in ids if split[i] == "tuning"]
        log(f"tuning on {len(tune_ids)} meshes: {tune_ids}")
        tuned = tune(psb, tune_ids, args.random_state, log)
        log(f"tuned: sdf {tuned['sdf']}, smoothed {tuned['smoothed']}")
    results = []
    for mesh_id in ids:
        log(f"mesh {mesh_id} ({category_of(mesh_id)}, {split[mesh_id]}) ...")
        r = run_mesh(psb, mesh_id, args.random_state, log, methods, tuned,
                     trace_memory=ids.index(mesh_id) % 10 == 0)
        r["split"] = split[mesh_id]
        results.append(r)
    command = "python " + " ".join(["benchmarks/psb_segmentation.py"] + (argv if argv is not None else sys.argv[1:]))
    write_report(results, Path(args.output), args.random_state, time.perf_counter() - t0, tuned,
                 [m[0] for m in methods], command)
    log(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
