"""Scale of the dense matchers (issue 15 item 3): EM registration and seed growing on 20k-245k-vertex
pairs, each stage's wall and CPU time and peak resident memory, in one run.

    python benchmarks/bench_scale.py                       # sizes s = 2 3 5 7, then the 5k accuracy check
    python benchmarks/bench_scale.py --splits 2 3 --accuracy 0
    python benchmarks/bench_scale.py --baseline-dir DIR    # also time the matcher files found in DIR

Regenerates ``benchmarks/results/scale.md`` and ``scale.json``.

**Pairs.** TOSCA ``cat0 -> cat1`` (``tosca5k``, 5,000 vertices each, ``../shared/data`` or
``$TOOLKIT_DATA``) with every triangle split into ``s x s`` congruent triangles on a flat barycentric
grid (``bench_eigensolver.subdivide``): s = 2, 3, 4, 5, 6, 7 give 19,994, 44,984, 79,970, 124,952,
179,930 and 244,904 vertices. The surface itself does not change, only its sampling. The original
vertices keep their ids ``0 .. 4999`` (the new ones follow), so the ground truth ``A.vts[i] <-> B.vts[i]``
holds unchanged. Seeds: 30 ground-truth pairs, farthest-point samples of the source's ground-truth
points (the same on every size). Error: each predicted target vertex is replaced by the original vertex
of B nearest to it in space (at most about half an original edge away: the new vertices lie on the
original triangles), and the geodesic error is measured on the original 5k mesh of B (Dijkstra on its
edges, divided by ``sqrt(area)``): the same ruler on every size.

**Stages.** Each stage runs in a fresh child process (``--child``), one at a time:

- ``spectrum``: the spectra both matchers declare (``spectrum_specs()``: cotangent Laplace-Beltrami
  with mass, 31 eigenpairs, for EM and its orientation check; the Gaussian graph Laplacian with 26 for
  the heat-distance descriptor of seed growing), both shapes, written to a disk cache the other stages
  read;
- ``em``: ``em-registration`` (defaults) from the seeds: EM, hard map, orientation check (which computes
  the source's symmetry map with ``fmap-zoomout`` on the same spectrum);
- ``seed``: ``seed-growing`` (defaults): heat-distance descriptors on the seeds as keypoints, then
  Algorithm 6;
- ``em-core``: ``em-registration`` without the orientation check (EM, hard map, filling);
- ``em-thesis`` (opt-in): the topo-robust refinement (graph spectrum, k_final = 40).

Times are the stage call's wall clock and process CPU time (``process_time``). Memory: the child's peak
resident set (``VmHWM``, native allocations included) over the stage, reset after loading the meshes and
spectra (``/proc/self/clear_refs``), so ``peak MB`` is the highest resident size during the stage
(meshes and spectra included), and ``over load`` the part above the resident size before it. BLAS: the
thread count threadpoolctl reports in the child (the process default; the eigensolver caps itself to 1).

**Whole pipelines** (issue 14): a stage ``preset:NAME`` runs ``load_pipeline(NAME).run(A, B)`` (no seeds
given: the preset finds its own, e.g. keypoints and replicator matching) in a fresh child with no disk
spectrum cache, so its time includes every spectrum it declares. Same columns and error as above, plus
the pipeline's own stage timings (``info["timings"]``, wall) and, timed by wrapping
``em_registration``'s functions in the child only (the package is not changed), the wall and CPU time
of the polish (``_polish``, the ``polish_k`` refinement), of every coarse-to-fine refinement
(``_refine``, the polish's included), of their nearest-neighbour searches (``_nearest``), of EM itself
(``em_register``) and of the orientation check (``OrientationRepair.side_check``). Runs with preset stages write
``benchmarks/results/scale_presets.md`` (+ ``.json``)::

    python benchmarks/bench_scale.py --splits 1 2 3 --accuracy-pairs '' \\
        --stages preset:zoomout,preset:sharma2012,preset:topo-robust
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

RESULTS = REPO / "benchmarks" / "results" / "scale.md"
PRESET_RESULTS = REPO / "benchmarks" / "results" / "scale_presets.md"
#: prefix of a whole-pipeline stage: ``preset:NAME`` runs the pipeline preset ``NAME``
PRESET_PREFIX = "preset:"
N_SEEDS = 30
MEMORY_BUDGET_MB = 4096.0
#: seconds after which a child is stopped
CHILD_TIMEOUT = 10800


def data_dir(arg: str | None = None) -> Path:
    """The shared data directory: ``arg``, ``$TOOLKIT_DATA`` or ``../shared/data``."""
    if arg:
        return Path(arg)
    env = os.environ.get("TOOLKIT_DATA")
    return Path(env) if env else REPO.parent / "shared" / "data"


def subdivide_keep_ids(V: np.ndarray, F: np.ndarray, s: int) -> tuple[np.ndarray, np.ndarray]:
    """Every triangle of ``(V, F)`` split ``s x s`` on a flat barycentric grid, the original vertices
    first with their ids kept: vertices ``(n', 3)``, triangles ``(s^2 |F|, 3)``."""
    from bench_eigensolver import subdivide
    from scipy.spatial import cKDTree

    V = np.asarray(V, dtype=np.float64)
    if s == 1:
        return V.copy(), np.asarray(F, dtype=np.int64).copy()
    W, G = subdivide(V, np.asarray(F, dtype=np.int64), int(s))
    d, where = cKDTree(W).query(V, k=1)
    if d.max() > 1e-12 * max(1.0, float(np.abs(V).max())) or np.unique(where).size != len(V):
        raise RuntimeError("subdivision lost an original vertex")
    order = np.concatenate([where, np.setdiff1d(np.arange(len(W)), where)])
    new_id = np.empty(len(W), dtype=np.int64)
    new_id[order] = np.arange(len(W))
    return W[order], new_id[G]


def farthest_points(P: np.ndarray, q: int) -> np.ndarray:
    """``q`` farthest-point samples (row indices) of points ``P`` ``(n, 3)``, from row 0."""
    chosen = [0]
    d = np.linalg.norm(P - P[0], axis=1)
    for _ in range(q - 1):
        chosen.append(int(np.argmax(d)))
        d = np.minimum(d, np.linalg.norm(P - P[chosen[-1]], axis=1))
    return np.asarray(chosen, dtype=np.int64)


def load_pair(data: Path, a: str, b: str, s: int):
    """Shapes ``a``, ``b`` of tosca5k split ``s x s``, their ground truth (0-based vertex ids valid
    on every ``s``) and the original (5k) shapes."""
    from shape_toolkit.core.shape import Shape
    from shape_toolkit.data.datasets import read_vts
    from shape_toolkit.io.mesh import load_shape

    tosca = data / "tosca5k"
    A0, B0 = load_shape(tosca / f"{a}.off"), load_shape(tosca / f"{b}.off")
    ta = read_vts(tosca / "corres" / f"{a}.vts", A0.n_vertices)
    tb = read_vts(tosca / "corres" / f"{b}.vts", B0.n_vertices)
    out = []
    for S in (A0, B0):
        V, F = subdivide_keep_ids(np.asarray(S.vertices), np.asarray(S.faces), s)
        out.append(Shape(V, F, name=f"{S.name}x{s * s}" if s > 1 else S.name))
    return out[0], out[1], ta, tb, A0, B0


def seeds_of(A0_vertices: np.ndarray, ta: np.ndarray, tb: np.ndarray, q: int = N_SEEDS) -> np.ndarray:
    """``q`` ground-truth seed pairs ``(q, 2)``: farthest-point samples of the source's truth points."""
    _, first = np.unique(ta, return_index=True)
    first = np.sort(first)
    rows = first[farthest_points(np.asarray(A0_vertices)[ta[first]], q)]
    return np.column_stack([ta[rows], tb[rows]]).astype(np.int64)


def map_error(B0, target_of: np.ndarray, B_vertices: np.ndarray, ta: np.ndarray, tb: np.ndarray) -> dict:
    """Mean geodesic error (Dijkstra on the original ``B0``, / sqrt(area)) of a map on the split pair;
    unmatched points are left out of the mean and counted."""
    from scipy.spatial import cKDTree

    from shape_toolkit.metrics.correspondence import paired_geodesic_distances

    pred = np.asarray(target_of, dtype=np.int64)[ta]
    ok = pred >= 0
    near = cKDTree(np.asarray(B0.vertices)).query(np.asarray(B_vertices)[pred[ok]], k=1)[1]
    d = paired_geodesic_distances(B0, tb[ok], near, method="dijkstra") / np.sqrt(B0.area)
    return {"mean_error": float(d.mean()) if d.size else float("nan"), "matched": float(ok.mean())}


# -- the child ------------------------------------------------------------------------------------
def peak_rss_mb() -> float:
    """Peak resident memory of this process since start or the last :func:`reset_peak` (VmHWM), MB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024.0
    raise RuntimeError("no VmHWM in /proc/self/status")


def rss_mb() -> float:
    """Current resident memory (VmRSS), MB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise RuntimeError("no VmRSS in /proc/self/status")


def reset_peak() -> None:
    """Reset this process's VmHWM to its current resident size."""
    Path("/proc/self/clear_refs").write_text("5")


def blas_threads() -> int | None:
    """BLAS thread count of this process (threadpoolctl), None when unknown."""
    try:
        from threadpoolctl import threadpool_info
    except ImportError:  # pragma: no cover
        return None
    blas = [i for i in threadpool_info() if i.get("user_api") == "blas"]
    return int(blas[0]["num_threads"]) if blas else None


def _load_module(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def matchers(baseline_dir: str | None):
    """``(em, seed)`` matcher classes: the package's, or those of the files in ``baseline_dir``
    (``em_registration.py``, ``seed_growing.py``, ``descriptor_score.py`` of another version)."""
    if not baseline_dir:
        from shape_toolkit.plugins.matching.dense.em_registration import EMRegistrationMatcher
        from shape_toolkit.plugins.matching.dense.seed_growing import SeedGrowingMatcher

        return EMRegistrationMatcher, SeedGrowingMatcher
    d = Path(baseline_dir)
    em = _load_module(d / "em_registration.py", "baseline_em_registration")
    sg = _load_module(d / "seed_growing.py", "baseline_seed_growing")
    if (d / "descriptor_score.py").exists():
        ds = _load_module(d / "descriptor_score.py", "baseline_descriptor_score")
        sg.descriptor_matching_score = ds.descriptor_matching_score
    return em.EMRegistrationMatcher, sg.SeedGrowingMatcher


#: matcher stages: name -> (class index in ``matchers()``, parameters)
MATCHERS = {
    "em": (0, {}),
    # the refinement stage of the topo-robust pipeline preset (thesis embedding, coarse-to-fine to 40)
    "em-thesis": (0, {"spectrum": "graph", "scaling": "commute-time", "dimension": "scree", "k": 10,
                      "k_final": 40}),
    "seed": (1, {}),
    # EM, hard map and filling alone: the defaults without the orientation check (whose nested
    # functional-map matchers are timed with it in ``em``)
    "em-core": (0, {"orientation": "none"}),
}


def _matcher(stage: str, baseline_dir: str | None):
    which, params = MATCHERS[stage]
    return matchers(baseline_dir)[which](**params)


def preset_name(stage: str) -> str | None:
    """The pipeline preset a ``preset:NAME`` stage runs, None for the other stages."""
    return stage[len(PRESET_PREFIX):] if stage.startswith(PRESET_PREFIX) else None


def parse_stages(text: str) -> list[str]:
    """The comma-separated ``--stages`` list, checked: ``spectrum``, a :data:`MATCHERS` name or
    ``preset:NAME`` with ``NAME`` a pipeline preset (``shape_toolkit.pipeline.PRESETS``). Raises
    ``ParameterError`` naming the stage and what is known."""
    from shape_toolkit.errors import ParameterError
    from shape_toolkit.pipeline import PRESETS

    stages = [t.strip() for t in str(text).split(",") if t.strip()]
    if not stages:
        raise ParameterError("--stages: no stage given")
    for stage in stages:
        name = preset_name(stage)
        if name is not None:
            if name not in PRESETS:
                raise ParameterError(f"--stages: unknown pipeline preset {name!r} in {stage!r} "
                                     f"(known: {', '.join(sorted(PRESETS))})")
        elif stage != "spectrum" and stage not in MATCHERS:
            raise ParameterError(f"--stages: unknown stage {stage!r} (known: spectrum, {', '.join(MATCHERS)}, "
                                 f"{PRESET_PREFIX}NAME)")
    if len(set(stages)) != len(stages):
        raise ParameterError(f"--stages: a stage is repeated in {text!r}")
    return stages


#: ``em_registration`` functions timed inside a preset stage: report key -> (attribute owner, name)
TIMED = {"polish": ("EMRegistrationMatcher", "_polish"), "refine_steps": ("EMRegistrationMatcher", "_refine"),
         "nearest": (None, "_nearest"), "em_register": (None, "em_register"),
         "orientation_check": ("OrientationRepair", "side_check")}


def instrument_em(clock: dict) -> None:
    """Wrap the :data:`TIMED` functions of ``em_registration`` in this process so that each call adds
    its wall and CPU seconds and a count to ``clock[key] = {"wall", "cpu", "calls"}`` (inclusive:
    the polish's refinement is also in ``refine_steps``; the package's files are not changed)."""
    import functools

    from shape_toolkit.plugins.matching.dense import em_registration as E

    for key, (owner_name, attr) in TIMED.items():
        owner = getattr(E, owner_name) if owner_name else E
        fn = getattr(owner, attr)

        def timed(*a, _fn=fn, _key=key, **kw):
            t0, c0 = time.perf_counter(), time.process_time()
            try:
                return _fn(*a, **kw)
            finally:
                c = clock.setdefault(_key, {"wall": 0.0, "cpu": 0.0, "calls": 0})
                c["wall"] += time.perf_counter() - t0
                c["cpu"] += time.process_time() - c0
                c["calls"] += 1

        setattr(owner, attr, functools.wraps(fn)(timed))


def run_preset(name: str, A, B) -> tuple[object, dict]:
    """``load_pipeline(name).run(A, B)`` with :func:`instrument_em`: the map and
    ``{"timings": the pipeline's stage wall times, "em": the wrapped functions' times, ...}``."""
    from shape_toolkit.pipeline import load_pipeline

    clock: dict = {}
    instrument_em(clock)
    corr = load_pipeline(name).run(A, B)
    info = corr.info
    extra = {"timings": {k: float(v) for k, v in info.get("timings", {}).items()}, "em": clock,
             "n_seeds": info.get("n_seeds"), "seed_source": info.get("seed_source"),
             "n_keypoints": info.get("n_keypoints"), "polish_k": info.get("polish_k"),
             "k_final": info.get("k_final"), "embedding_dim": info.get("embedding_dim"),
             "orientation": {k: v for k, v in info.items() if k.startswith("orientation")
                             and isinstance(v, (bool, int, float, str))},
             "spectra": info.get("spectra")}
    return corr, extra


def child(stages: list[str], data: Path, a: str, b: str, s: int, baseline_dir: str | None) -> list[dict]:
    """Run ``stages`` (``spectrum`` or a :data:`MATCHERS` name) in this process on the pair split
    ``s x s``; returns one row each: times, peak memory, and the map error for matchers."""
    import warnings

    warnings.filterwarnings("ignore")
    from shape_toolkit.spectra import SpectrumSpec

    A, B, ta, tb, A0, B0 = load_pair(data, a, b, s)
    seeds = seeds_of(np.asarray(A0.vertices), ta, tb)
    rows = []
    for stage in stages:
        name = preset_name(stage)
        if name is not None:  # the whole pipeline, its spectra included (no disk cache: run_child)
            from shape_toolkit.bench.worker import code_revision

            out = {"stage": stage, "pair": f"{a}-{b}", "n_source": A.n_vertices, "n_target": B.n_vertices,
                   "split": s, "blas_threads": blas_threads(),
                   "code": code_revision(REPO, paths=["shape_toolkit"])}
            reset_peak()
            before = rss_mb()
            t0, c0 = time.perf_counter(), time.process_time()
            corr, extra = run_preset(name, A, B)
            out.update({"seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0,
                        "peak_mb": peak_rss_mb(), "before_mb": before, **extra})
            out.update(map_error(B0, corr.target_of, np.asarray(B.vertices), ta, tb))
            out["n_matched"] = int(corr.n_matched)
            del corr
            rows.append(out)
            continue
        if stage == "spectrum":
            specs = SpectrumSpec.merge_all(
                [sp for name in MATCHERS for sp in _matcher(name, None).spectrum_specs()])
        else:
            m = _matcher(stage, baseline_dir)
            # each declared spectrum served by the spectrum stage's merged one of its kind (more
            # eigenpairs; the matcher uses the first k): no eigensolve of another size in the child
            merged = SpectrumSpec.merge_all([sp for name in MATCHERS for sp in _matcher(name, None).spectrum_specs()])
            specs = [next((a for a in merged if a.kind == sp.kind and a.k >= sp.k), sp) for sp in m.spectrum_specs()]
        out: dict = {"stage": stage, "pair": f"{a}-{b}", "n_source": A.n_vertices, "n_target": B.n_vertices,
                     "split": s, "blas_threads": blas_threads(), "specs": [sp.to_dict() for sp in specs]}
        if stage == "spectrum":
            reset_peak()
            before = rss_mb()
            t0, c0 = time.perf_counter(), time.process_time()
            for shape in (A, B):
                for sp in specs:
                    sp.compute(shape)
        else:
            spectra_a = [sp.compute(A) for sp in specs]  # from the disk cache the spectrum stage filled
            spectra_b = [sp.compute(B) for sp in specs]
            reset_peak()
            before = rss_mb()
            t0, c0 = time.perf_counter(), time.process_time()
            corr = m.match(A, B, seeds=seeds, source_spectrum=spectra_a, target_spectrum=spectra_b)
        out.update({"seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0,
                    "peak_mb": peak_rss_mb(), "before_mb": before})
        if stage != "spectrum":
            out.update(map_error(B0, corr.target_of, np.asarray(B.vertices), ta, tb))
            out["n_matched"] = int(corr.n_matched)
            out["orientation"] = {k: v for k, v in corr.info.items() if k.startswith("orientation")}
            del corr, spectra_a, spectra_b
        rows.append(out)
    return rows


def run_child(stages: list[str], data: Path, a: str, b: str, s: int, cache: Path,
              baseline_dir: str | None, timeout: float = CHILD_TIMEOUT) -> list[dict]:
    """``child`` in a fresh process with the spectrum cache in ``cache`` (none for preset stages),
    stopped after ``timeout`` seconds (its rows then carry the error)."""
    env = {**os.environ, "TOOLKIT_CACHE_DIR": str(cache)}
    if any(preset_name(st) for st in stages):  # a preset computes (and is timed on) its own spectra
        env.pop("TOOLKIT_CACHE_DIR")
    cmd = [sys.executable, __file__, "--child", ",".join(stages), "--pair", a, b, "--split", str(s),
           "--data", str(data)]
    if baseline_dir:
        cmd += ["--baseline-dir", baseline_dir]
    try:
        r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return [{"stage": st, "pair": f"{a}-{b}", "split": s, "error": f"stopped after {timeout:.0f} s"}
                for st in stages]
    if r.returncode != 0:
        err = (r.stderr.strip().splitlines() or ["?"])[-1]
        return [{"stage": st, "pair": f"{a}-{b}", "split": s, "error": err} for st in stages]
    return json.loads(r.stdout.strip().splitlines()[-1])


#: held-out accuracy pairs (cat0-cat1, the scale pair, chose the sample sizes)
ACCURACY_PAIRS = ["cat0-cat3", "cat1-cat2", "cat2-cat4", "cat3-cat5", "dog0-dog2", "dog1-dog3", "wolf0-wolf2"]
#: largest split the baseline runs at, per stage (its EM refinements were quadratic in time)
BASELINE_MAX_SPLIT = {"em": 3, "em-thesis": 2, "seed": 2}
#: the files a baseline version is made of (``--baseline-commit``)
BASELINE_FILES = ["shape_toolkit/plugins/matching/dense/em_registration.py",
                  "shape_toolkit/plugins/matching/dense/seed_growing.py",
                  "shape_toolkit/features/descriptor_score.py"]


def baseline_from_commit(rev: str, into: Path) -> Path:
    """The matcher files of commit ``rev`` (``git show``, read only) written to ``into``."""
    for f in BASELINE_FILES:
        text = subprocess.run(["git", "-C", str(REPO), "show", f"{rev}:{f}"], capture_output=True, text=True,
                              check=True).stdout
        (into / Path(f).name).write_text(text)
    return into


def _fmt(x, nd=1):
    return "" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f"{x:.{nd}f}"


def write_report(res: dict, out: Path) -> None:
    """``scale.md`` (and ``scale.json`` next to it) from the rows of a run; the whole-pipeline
    report (:func:`write_presets_report`) when the rows hold ``preset:NAME`` stages."""
    out.with_suffix(".json").write_text(json.dumps(res, indent=1))
    rows = res["rows"]
    if any(preset_name(r["stage"]) for r in rows):
        write_presets_report(res, out)
        return
    order = {name: i for i, name in enumerate(["spectrum", *MATCHERS])}
    cur = sorted((r for r in rows if r.get("kind") == "scale" and r["impl"] == "current" and "error" not in r),
                 key=lambda r: (r["split"], order.get(r["stage"], 99)))
    lines = [
        "# Scale: EM registration and seed growing on 20k-245k-vertex pairs",
        "",
        f"Command: `{res['command']}` ({res['date']}, {res['machine']}; 2 shared cores, "
        f"1-min load {res['load'][0]:.1f} at start, {res['load'][1]:.1f} at the end; other helpers' jobs ran "
        "at the same time, so wall times are inflated: CPU times are the better measure).",
        "",
        "Pair: TOSCA cat0 -> cat1 with every triangle split s x s (flat, original vertices keep their ids: the "
        "ground truth is unchanged); 30 ground-truth seeds (farthest-point samples). Each stage is a fresh child "
        "process; `peak MB` is its peak resident set during the stage (meshes and spectra loaded before it "
        "included), `+MB` the part above the resident size when the stage started. Error: mean geodesic error "
        "of the 5,000 ground-truth points, the predicted vertex snapped to the nearest original vertex of B, "
        "Dijkstra on the original 5k mesh / sqrt(area). BLAS: threads of the child's BLAS (threadpoolctl; "
        "the eigensolver caps itself to 1 inside). Budget: 4096 MB peak for EM and seed growing.",
        "",
        "| s | vertices | stage | wall s | CPU s | peak MB | +MB | BLAS | error | within 4 GB |",
        "|---:|---:|---|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in cur:
        ok = "" if r["stage"] == "spectrum" else ("yes" if r["peak_mb"] <= MEMORY_BUDGET_MB else "**no**")
        lines.append(f"| {r['split']} | {r['n_source']:,} | {r['stage']} | {_fmt(r['seconds'])} | "
                     f"{_fmt(r['cpu_seconds'])} | {_fmt(r['peak_mb'], 0)} | {_fmt(r['peak_mb'] - r['before_mb'], 0)} | "
                     f"{r['blas_threads']} | {_fmt(r.get('mean_error'), 4)} | {ok} |")
    failed = [r for r in rows if "error" in r]
    if failed:
        lines += ["", "Failed children: " + "; ".join(f"{r['stage']} s={r['split']} ({r['impl']}): {r['error']}"
                                                     for r in failed)]
    # growth: CPU exponent between successive sizes
    lines += ["", "## Growth (CPU time exponent between successive sizes, `t ~ n^e`)", "",
              "| stage | sizes | exponent |", "|---|---|---:|"]
    for stage in dict.fromkeys(r["stage"] for r in cur):
        rs = sorted((r for r in cur if r["stage"] == stage), key=lambda r: r["n_source"])
        for a, b in zip(rs, rs[1:]):
            e = np.log(b["cpu_seconds"] / a["cpu_seconds"]) / np.log(b["n_source"] / a["n_source"])
            lines.append(f"| {stage} | {a['n_source']:,} -> {b['n_source']:,} | {e:.2f} |")
    base = [r for r in rows if r.get("kind") == "scale" and r["impl"] == "baseline" and "error" not in r]
    if base:
        lines += ["", f"## Against the previous version ({res.get('baseline', 'baseline')})", "",
                  "Same pair, seeds, spectra and machine; speed-up = baseline CPU / current CPU.", "",
                  "| s | vertices | stage | baseline CPU s | current CPU s | speed-up | baseline peak MB | "
                  "current peak MB | baseline error | current error |",
                  "|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|"]
        for b in base:
            c = next((r for r in cur if r["stage"] == b["stage"] and r["split"] == b["split"]), None)
            if c is None:
                continue
            lines.append(f"| {b['split']} | {b['n_source']:,} | {b['stage']} | {_fmt(b['cpu_seconds'])} | "
                         f"{_fmt(c['cpu_seconds'])} | {b['cpu_seconds'] / c['cpu_seconds']:.2f}x | "
                         f"{_fmt(b['peak_mb'], 0)} | {_fmt(c['peak_mb'], 0)} | {_fmt(b.get('mean_error'), 4)} | "
                         f"{_fmt(c.get('mean_error'), 4)} |")
    acc = [r for r in rows if r.get("kind") == "accuracy" and "error" not in r]
    if acc:
        lines += ["", "## Accuracy on held-out tosca5k pairs (5k vertices, before / after)", "",
                  "Same 30 ground-truth seeds and spectra for both versions. cat0-cat1 (the scale pair) chose the "
                  "sample sizes; these pairs were not looked at for that. Mean geodesic error (Dijkstra / sqrt(area)).",
                  "", "| pair | stage | baseline error | current error | baseline CPU s | current CPU s |",
                  "|---|---|---:|---:|---:|---:|"]
        means: dict[str, list] = {}
        for c in (r for r in acc if r["impl"] == "current"):
            b = next((r for r in acc if r["impl"] == "baseline" and r["stage"] == c["stage"]
                      and r["pair"] == c["pair"]), None)
            if b is None:
                continue
            means.setdefault(c["stage"], []).append((b["mean_error"], c["mean_error"]))
            lines.append(f"| {c['pair']} | {c['stage']} | {b['mean_error']:.4f} | {c['mean_error']:.4f} | "
                         f"{_fmt(b['cpu_seconds'], 2)} | {_fmt(c['cpu_seconds'], 2)} |")
        for stage, v in means.items():
            v = np.asarray(v)
            lines.append(f"| **mean** ({len(v)} pairs) | {stage} | **{v[:, 0].mean():.4f}** | **{v[:, 1].mean():.4f}** "
                         "| | |")
    lines += ["", res.get("notes", ""), ""]
    out.write_text("\n".join(lines))


#: the peer the thesis presets are compared with in the presets report
PEER = "zoomout"


def _exponent(a: float, b: float, na: int, nb: int) -> str:
    return f"{np.log(b / a) / np.log(nb / na):.2f}" if a > 0 and b > 0 and nb != na else ""


def write_presets_report(res: dict, out: Path) -> None:
    """The whole-pipeline report (``scale_presets.md``) from the rows of runs with ``preset:NAME``
    stages: times, memory and error per size and preset, where the time goes, the ratios to the
    :data:`PEER` preset and the growth exponents (the ``.json`` is written by :func:`write_report`)."""
    rows = [r for r in res["rows"] if r.get("kind", "scale") == "scale"]
    ok = sorted((r for r in rows if "error" not in r), key=lambda r: (r["split"], r["stage"]))
    presets = list(dict.fromkeys(preset_name(r["stage"]) or r["stage"] for r in ok))
    cmds = res["command"].split("; ")
    load = res.get("load", [float("nan")] * 2)
    blas = sorted({r["blas_threads"] for r in ok if r.get("blas_threads") is not None})
    from shape_toolkit.bench.worker import revision_label

    codes = sorted({revision_label(r.get("code")) for r in ok})
    lines = [
        "# Scale: whole matching pipelines (thesis presets vs zoomout) on 5k-45k-vertex pairs",
        "",
        "Regenerate the tables from the saved rows: `python benchmarks/bench_scale.py --report-only "
        f"--output benchmarks/results/{out.name}`. Rows produced by:",
        "",
        *[f"- `{c.replace(' (merged)', '')}`" for c in cmds],
        "",
        f"Date: {res['date']}. Machine: {res.get('cpu', 'CPU not recorded')}, {res['machine']}; 2 cores shared with "
        "other jobs (what else ran: the notes below); 1-min load "
        f"{load[0]:.1f} at the start, {load[1]:.1f} at the end: wall times are inflated by the other jobs, "
        f"CPU times are the better measure. BLAS threads in the children: {', '.join(map(str, blas)) or '?'} "
        "(threadpoolctl; the eigensolver caps itself to 1). Package code (`shape_toolkit/`): "
        f"{'; '.join(codes)}.",
        "",
        "Pair: TOSCA cat0 -> cat1 (`tosca5k`), every triangle split s x s (flat: same surface, original vertex "
        "ids kept, so the ground truth holds on every size). Each cell is one fresh child process running "
        "`load_pipeline(NAME).run(A, B)` with no seeds given (the preset finds its own) and no disk spectrum "
        "cache, so the times include every spectrum the preset declares. `peak MB`: the child's peak resident "
        "set during the run (meshes loaded before it included); `+MB` the part above the resident size at the "
        "start. Error: mean geodesic error of the 5,000 ground-truth points, the predicted vertex snapped to "
        "the nearest original vertex of B, Dijkstra on the original 5k mesh / sqrt(area) (the same ruler on "
        "every size). One pair, one run per cell: no tuning was done here, nothing was chosen on these numbers.",
        "",
        "| s | vertices | preset | wall s | CPU s | peak MB | +MB | BLAS | error | seeds |",
        "|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in ok:
        lines.append(f"| {r['split']} | {r['n_source']:,} | {preset_name(r['stage']) or r['stage']} | "
                     f"{_fmt(r['seconds'])} | {_fmt(r['cpu_seconds'])} | {_fmt(r['peak_mb'], 0)} | "
                     f"{_fmt(r['peak_mb'] - r['before_mb'], 0)} | {r.get('blas_threads')} | "
                     f"{_fmt(r.get('mean_error'), 4)} | {r.get('n_seeds', '')} |")
    failed = [r for r in rows if "error" in r]
    if failed:
        lines += ["", "Not measured / failed: " + "; ".join(
            f"{r['stage']} s={r['split']}: {r['error']}" for r in failed)]
    stage_keys = ["spectra", "keypoints", "sparse", "descriptors", "dense", "refine"]
    lines += ["", "## Where the time goes", "",
              "Wall seconds of the pipeline's stages (`info[\"timings\"]`), then wall / CPU seconds of "
              "em-registration's parts inside `refine` (wrapped in the child; inclusive: `refine steps` counts "
              "every coarse-to-fine refinement call, the polish's included, `NN` every nearest-neighbour search "
              "in them; `orient` is the left/right check, EM-again and its side reference included).", "",
              "| s | preset | " + " | ".join(stage_keys) + " | EM (em_register) | orient | polish | refine steps "
              "| NN searches |", "|---:|---|" + "---:|" * (len(stage_keys) + 5)]
    for r in ok:
        t, em = r.get("timings", {}), r.get("em", {})

        def part(key, em=em):
            c = em.get(key)
            return f"{c['wall']:.1f} / {c['cpu']:.1f} ({c['calls']})" if c else ""

        lines.append(f"| {r['split']} | {preset_name(r['stage']) or r['stage']} | "
                     + " | ".join(_fmt(t.get(k)) for k in stage_keys)
                     + f" | {part('em_register')} | {part('orientation_check')} | {part('polish')} | "
                     f"{part('refine_steps')} | {part('nearest')} |")
    lines += ["", "(`wall / CPU (calls)`; an empty cell: the stage or part is not in that preset.)"]
    by = {(r["split"], preset_name(r["stage"])): r for r in ok}
    others = [p for p in presets if p != PEER]
    if any((s_, PEER) in by for s_, _ in by):
        lines += ["", f"## Ratios to {PEER} (same size; > 1: slower / more memory than {PEER})", "",
                  "| s | vertices | preset | CPU ratio | wall ratio | peak MB ratio | error | " + PEER + " error |",
                  "|---:|---:|---|---:|---:|---:|---:|---:|"]
        for split in sorted({k[0] for k in by}):
            z = by.get((split, PEER))
            for name in others:
                r = by.get((split, name))
                if z is None or r is None:
                    continue
                lines.append(f"| {split} | {r['n_source']:,} | {name} | {r['cpu_seconds'] / z['cpu_seconds']:.2f}x | "
                             f"{r['seconds'] / z['seconds']:.2f}x | {r['peak_mb'] / z['peak_mb']:.2f}x | "
                             f"{_fmt(r.get('mean_error'), 4)} | {_fmt(z.get('mean_error'), 4)} |")
    lines += ["", "## Growth (exponent e of `t ~ n^e` between successive sizes)", "",
              "| preset | sizes | CPU | wall | polish CPU | spectra wall |", "|---|---|---:|---:|---:|---:|"]
    for name in presets:
        rs = sorted((r for r in ok if (preset_name(r["stage"]) or r["stage"]) == name), key=lambda r: r["n_source"])
        for a, b in zip(rs, rs[1:]):
            pa, pb = a.get("em", {}).get("polish"), b.get("em", {}).get("polish")
            sa, sb = a.get("timings", {}).get("spectra"), b.get("timings", {}).get("spectra")
            lines.append(f"| {name} | {a['n_source']:,} -> {b['n_source']:,} | "
                         f"{_exponent(a['cpu_seconds'], b['cpu_seconds'], a['n_source'], b['n_source'])} | "
                         f"{_exponent(a['seconds'], b['seconds'], a['n_source'], b['n_source'])} | "
                         f"{_exponent(pa['cpu'], pb['cpu'], a['n_source'], b['n_source']) if pa and pb else ''} | "
                         f"{_exponent(sa, sb, a['n_source'], b['n_source']) if sa and sb else ''} |")
    lines += ["", res.get("notes", ""), ""]
    out.write_text("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", help="shared data directory (default $TOOLKIT_DATA or ../shared/data)")
    ap.add_argument("--pair", nargs=2, default=["cat0", "cat1"])
    ap.add_argument("--splits", nargs="+", type=int, default=[2, 3, 5, 7])
    ap.add_argument("--stages", default="spectrum,seed,em-core,em",
                    help="stages to run (also: em-thesis, whose final refinement is quadratic in time, and "
                    "preset:NAME, the whole pipeline preset NAME, e.g. preset:topo-robust)")
    ap.add_argument("--baseline-commit", help="also run the matcher files of this commit (git show, read only)")
    ap.add_argument("--baseline-dir", help="... or those found in this directory")
    ap.add_argument("--baseline-max-split", type=int,
                    help="run the baseline only up to this split (default: 3 for em, 2 for the others; "
                    "the old EM was quadratic in time)")
    ap.add_argument("--accuracy-pairs", default=",".join(ACCURACY_PAIRS),
                    help="held-out tosca5k pairs for the before/after accuracy check ('' to skip)")
    ap.add_argument("--output", type=Path,
                    help=f"report (default {RESULTS.name}; {PRESET_RESULTS.name} when --stages has preset:NAME)")
    ap.add_argument("--child-timeout", type=float, default=CHILD_TIMEOUT,
                    help="seconds after which a stage's child is stopped (its row records that)")
    ap.add_argument("--report-only", action="store_true", help="rewrite the .md from the .json")
    ap.add_argument("--merge", nargs="+", type=Path, metavar="JSON",
                    help="write the report of the rows of these earlier runs' .json files together "
                    "(e.g. runs with different --stages and --splits)")
    ap.add_argument("--notes", default="", help="text added at the end of the report")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--split", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    from shape_toolkit.errors import ParameterError

    try:
        stages = parse_stages(args.stages)
    except ParameterError as exc:
        print(f"bench_scale: {exc}", file=sys.stderr)
        return 2
    if args.output is None:
        args.output = PRESET_RESULTS if any(preset_name(st) for st in stages) else RESULTS
    data = data_dir(args.data)
    if args.child:
        print(json.dumps(child(args.child.split(","), data, *args.pair, args.split, args.baseline_dir)))
        return 0
    if args.merge:
        parts = [json.loads(p.read_text()) for p in args.merge]
        res = {**parts[0], "rows": [r for p in parts for r in p["rows"]],
               "command": "; ".join(p["command"] for p in parts) + " (merged)",
               "date": ", ".join(dict.fromkeys(p["date"] for p in parts)),
               "load": [min(p["load"][0] for p in parts), max(p["load"][1] for p in parts)],
               "notes": args.notes or parts[0].get("notes", "")}
        write_report(res, args.output)
        print(args.output.read_text())
        return 0
    if args.report_only:
        write_report(json.loads(args.output.with_suffix(".json").read_text()), args.output)
        print(args.output.read_text())
        return 0
    if not (data / "tosca5k" / f"{args.pair[0]}.off").exists():
        print(f"tosca5k not found under {data}: pass --data or set TOOLKIT_DATA", file=sys.stderr)
        return 2
    rows: list[dict] = []
    from shape_toolkit.bench.worker import cpu_model

    res = {"command": "python benchmarks/bench_scale.py " + " ".join(argv if argv is not None else sys.argv[1:]),
           "date": time.strftime("%Y-%m-%d %H:%M"), "machine": platform.platform(), "cpu": cpu_model(),
           "load": [os.getloadavg()[0], 0.0], "rows": rows, "notes": args.notes}
    with tempfile.TemporaryDirectory() as tmp:
        base = args.baseline_dir
        if args.baseline_commit:
            d = Path(tmp) / "baseline"
            d.mkdir()
            base = str(baseline_from_commit(args.baseline_commit, d))
            res["baseline"] = f"commit {args.baseline_commit}"
        elif base:
            res["baseline"] = base
        cache = Path(tmp) / "cache"

        def run(kind, stages_, a, b, s, impl):
            for r in run_child(stages_, data, a, b, s, cache, impl, args.child_timeout):
                r.update(kind=kind, impl="baseline" if impl else "current")
                rows.append(r)
                print(json.dumps({k: v for k, v in r.items() if k != "specs"}), file=sys.stderr, flush=True)

        for s in args.splits:
            for stage in stages:
                run("scale", [stage], *args.pair, s, None)
                top = args.baseline_max_split or BASELINE_MAX_SPLIT.get(stage, 0)
                if base and stage != "spectrum" and not preset_name(stage) and s <= top:
                    run("scale", [stage], *args.pair, s, base)
        for pair in filter(None, args.accuracy_pairs.split(",")):
            a, b = pair.split("-")
            run("accuracy", ["spectrum"] + [st for st in stages if st != "spectrum"], a, b, 1, None)
            if base:
                run("accuracy", [st for st in stages if st != "spectrum"], a, b, 1, base)
    res["load"][1] = os.getloadavg()[0]
    write_report(res, args.output)
    print(args.output.read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
