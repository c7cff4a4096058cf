"""Matching against the field in one table (issue 25): isometric TOSCA, FAUST across people,
non-isometric gorillas to people, and targets with 6 glued contacts, every toolkit pipeline named
beside pyFM's README pipeline (run here) and the published BIM and BCICP maps (read from the data).

    python benchmarks/matching_field.py [--data DIR] [--sets tosca,faust,noniso,glued]
                                        [--split report|tune|all] [--every tosca=2,faust=4,...]
                                        [--methods zoomout,topo-robust,pyfm,BIM,BCICP] [--fresh]
    python benchmarks/matching_field.py --report-only      # the markdown from the saved rows

Rows go to ``benchmarks/results/matching_field.jsonl`` (one per pair and method, appended as they
come; a row already there is skipped unless ``--fresh``); the report is ``matching_field.md``.

Protocol:

- **Splits by subject and animal, never by pair.** A pair is *tune* when both of its shapes belong to
  the tuning subjects, *report* when both belong to the reporting ones (FAUST pairs across the two
  groups are in neither):

  ======== ================================ =====================================
  set      tune                             report
  ======== ================================ =====================================
  tosca    dogs                             cats, wolves
  faust    people 0 and 1 (000-019)         people 2, 3 and 4 (020-049)
  noniso   gorillas to the 3 men            gorillas to the 5 women
  glued    as tosca and faust               as tosca and faust
  ======== ================================ =====================================

  The data hold two gorillas only, so both ``noniso`` halves map them, to different people.
  The tables reported in the README are the *report* halves.
- Map A -> B. Error of a ground-truth point ``i``: Dijkstra geodesic distance on B (mesh edges)
  between the image of ``A.vts[i]`` and ``B.vts[i]``, over ``sqrt(area(B))``; mean over every
  ``--truth-step``-th point (default 5; the 900 landmarks of ``noniso`` are all used). Symmetric-aware
  error: the smaller of the errors to ``B.vts[i]`` and ``B.sym.vts[i]`` (no symmetric files in
  ``noniso``). A pair is *flipped* when its error exceeds twice its symmetric-aware error plus 0.02
  (``metrics.correspondence.is_flipped``). Ground-truth points a map leaves unmatched (a few BIM
  maps hold a 0, no vertex, on 1-3 of 5,000 vertices) are left out of its mean and counted in the row.
- ``glued``: the target B is ``data.corruptions.glue(B, strength=6, random_state=h)`` with ``h`` a fixed
  hash of the pair's name; the map to the glued mesh is composed with the corruption's vertex map and
  scored on the clean B.
- ``cloud`` / ``cloud-noisy``: both shapes as point clouds of their vertices (no faces), with Gaussian
  noise of 0 / 0.5 % of the bounding-box diagonal (seeded by the pair's name); the vertex map is scored on
  the clean mesh B as above. pyFM's pipeline needs meshes: no peer row; the mesh rows of the same pairs
  (sets ``tosca`` and ``faust``) are the reference ("x mesh" in the report).
- ``large``: both shapes remeshed independently to about 100,000 vertices (pymeshlab isotropic remeshing,
  cached in ``$TOOLKIT_LARGE_CACHE``); ground-truth points move to their nearest remeshed vertex. The
  reference is the same pipeline on the 5k pair ("x 5k" in the report; target <= 1.1x + 0.005).
  ``peak_mb``: resident memory above the start of the call (sampled).
- Time: from two loaded meshes to the vertex map, spectra included (the toolkit's spectrum and side
  caches are cleared before every call; pyFM computes its own). CPU (``time.process_time``) and wall
  time per pair, one BLAS thread (read back with threadpoolctl and written in the report). The
  published maps have no time here (BCICP reported about 350 s a pair).
- pyFM: ``pyfmaps`` 1.3.1 README quick start (``shape_toolkit.bench.peers.pyfm_map``).
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
RESULTS = REPO / "benchmarks" / "results"
RAW = RESULTS / "matching_field.jsonl"
REPORT = RESULTS / "matching_field.md"
SETS = {"tosca": "tosca5k", "faust": "faust5k", "noniso": "tosca_noniso", "glued": "tosca5k+faust5k",
        "cloud": "tosca5k+faust5k", "cloud-noisy": "tosca5k+faust5k", "large": "tosca5k+faust5k"}
#: vertices of each shape of the ``large`` set (independent isotropic remeshing of the 5k shapes)
LARGE_VERTICES = 100_000
LARGE_CACHE = Path(os.environ.get("TOOLKIT_LARGE_CACHE", "/tmp/shape-toolkit-large"))
#: point-cloud sets: both shapes as clouds of their vertices (no faces), with Gaussian noise of this
#: fraction of the bounding-box diagonal; scored on the meshes they came from
CLOUD_NOISE = {"cloud": 0.0, "cloud-noisy": 0.005}
PUBLISHED = ("BIM", "BCICP")
METHODS = ["zoomout", "shells", "auto", "topo-robust", "pyfm", *PUBLISHED]
GLUE_CONTACTS = 6


def split_of(dataset: str, a: str, b: str) -> str | None:
    """``"tune"``, ``"report"`` or None (a FAUST pair across the two groups) for the pair ``(a, b)`` of
    ``dataset`` (``tosca5k``, ``faust5k``, ``tosca_noniso``): by subject and animal, never by pair."""
    if dataset == "faust5k":
        people = {int(a[-3:]) // 10, int(b[-3:]) // 10}
        return "tune" if people <= {0, 1} else "report" if people <= {2, 3, 4} else None
    if dataset == "tosca5k":
        return "tune" if a.startswith("dog") else "report"
    if dataset == "tosca_noniso":
        return "report" if "woman" in b else "tune"
    raise ValueError(f"no split rule for {dataset!r}")


def _data(arg: str | None) -> Path:
    return Path(arg) if arg else Path(os.environ.get("TOOLKIT_DATA", REPO.parent / "shared" / "data"))


def read_pairs(data: Path, dataset: str) -> list[tuple[str, str]]:
    """The (A, B) names of ``dataset/pairs.txt``, in file order."""
    return [tuple(line.split()[:2]) for line in (data / dataset / "pairs.txt").read_text().splitlines()
            if line.strip()]


def jobs_of(data: Path, sets: list[str], split: str, every: dict[str, int]) -> list[tuple[str, str, str, str]]:
    """``(set, dataset, a, b)`` for every selected pair: the ``split`` half, every ``every[set]``-th pair of
    each dataset in file order."""
    out = []
    for s in sets:
        for ds in SETS[s].split("+"):
            pairs = [p for p in read_pairs(data, ds) if split in ("all", split_of(ds, *p))]
            out += [(s, ds, a, b) for a, b in pairs[:: max(1, every.get(s, 1))]]
    return out


def _large(shape, dataset: str):
    """``shape`` remeshed to about :data:`LARGE_VERTICES` vertices (pymeshlab isotropic remeshing, the
    toolkit's ``clean --remesh``), cached in :data:`LARGE_CACHE`."""
    from shape_toolkit.core.cleanup import clean_shape
    from shape_toolkit.io.mesh import load_shape, save_shape

    path = LARGE_CACHE / f"{dataset}_{LARGE_VERTICES}" / f"{shape.name}.ply"
    if path.exists():
        return load_shape(path)
    edge = float(np.sqrt(2 * shape.area / (np.sqrt(3) * LARGE_VERTICES)))
    big, _ = clean_shape(shape, remesh_target_edge=edge, remesh_iterations=3)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_shape(big, path)
    return load_shape(path)


def _blas() -> list[dict]:
    from threadpoolctl import threadpool_info

    return [{"api": i.get("internal_api"), "threads": i.get("num_threads")} for i in threadpool_info()]


def _done() -> set[tuple[str, str, str]]:
    if not RAW.exists():
        return set()
    return {(r["set"], r["pair"], r["method"]) for r in map(json.loads, RAW.read_text().splitlines())}


def run(data: Path, jobs: list[tuple[str, str, str, str]], methods: list[str], truth_step: int,
        command: str = "") -> None:
    """Run ``methods`` on ``jobs`` and append one row per (pair, method) to :data:`RAW` (each row keeps the
    ``command`` that made it)."""
    warnings.filterwarnings("ignore")
    from shape_toolkit.bench.peers import pyfm_map
    from shape_toolkit.bench.worker import MemoryMonitor, code_revision
    from shape_toolkit.core.spectrum import clear_cache
    from shape_toolkit.data.corruptions import glue
    from shape_toolkit.data.datasets import read_vts
    from shape_toolkit.io.mesh import load_shape
    from shape_toolkit.metrics.correspondence import is_flipped, paired_geodesic_distances
    from shape_toolkit.pipeline import load_pipeline

    pipes = {m: load_pipeline(m) for m in methods if m != "pyfm" and m not in PUBLISHED}
    blas, rev = _blas(), code_revision()
    done = _done()
    for s, ds, a, b in jobs:
        todo = [m for m in methods if (s, f"{a}-{b}", m) not in done]
        if s != "noniso":
            todo = [m for m in todo if m not in PUBLISHED]
        if s in CLOUD_NOISE:  # pyFM's pipeline needs meshes
            todo = [m for m in todo if m != "pyfm"]
        if not todo:
            continue
        root = data / ds
        A, B = load_shape(root / f"{a}.off"), load_shape(root / f"{b}.off")
        A5, B5 = A, B  # the shapes the ground truth is given on
        if s == "large":
            A, B = _large(A, ds), _large(B, ds)
        Bm, vmap = B, np.arange(B.n_vertices)
        if s == "glued":
            h = int(hashlib.sha256(f"{a}-{b}".encode()).hexdigest(), 16) % 2**31
            Bm, vmap = glue(B, strength=GLUE_CONTACTS, random_state=h)
            vmap = np.asarray(vmap)
        Ain = A
        if s in CLOUD_NOISE:
            from shape_toolkit.core.shape import Shape

            rng = np.random.default_rng(int(hashlib.sha256(f"{a}-{b}".encode()).hexdigest(), 16) % 2**31)
            # coincident vertices (a few FAUST meshes have some) are one point of the cloud: a cloud
            # Laplacian refuses duplicates; the map is expanded back to every vertex
            _, first_a, inv_a = np.unique(A.vertices, axis=0, return_index=True, return_inverse=True)
            first_b = np.unique(B.vertices, axis=0, return_index=True)[1]
            order_a, order_b = np.sort(first_a), np.sort(first_b)  # cloud point j is vertex order[j]
            Ain, Bm = (Shape(S.vertices[o] + CLOUD_NOISE[s] * float(np.linalg.norm(np.ptp(S.vertices, axis=0)))
                             * rng.standard_normal((len(o), 3)), None, name=f"{S.name}-cloud")
                       for S, o in ((A, order_a), (B, order_b)))
            pos_a = np.empty(len(first_a), np.int64)  # unique row -> its cloud point
            pos_a[np.argsort(first_a)] = np.arange(len(first_a))
            src_of_vertex = pos_a[inv_a.ravel()]  # mesh vertex of A -> its cloud point
            vmap = order_b  # a target cloud point -> its mesh vertex
        maps, times, infos, peaks = {}, {}, {}, {}
        for m in todo:
            if m in PUBLISHED:
                path = root / "maps" / m / f"{a}_{b}.map"
                maps[m] = np.loadtxt(path, dtype=np.int64) - 1
                times[m] = (None, None)
                continue
            clear_cache()
            c0, w0 = time.process_time(), time.perf_counter()
            mon = MemoryMonitor().__enter__()
            if m == "pyfm":
                t = pyfm_map(A, Bm)
            else:
                corr = pipes[m].run(Ain, Bm)
                t = corr.target_of
                if s in CLOUD_NOISE:  # every mesh vertex: the image of its cloud point
                    t = np.asarray(t)[src_of_vertex]
                infos[m] = {k: corr.info[k] for k in ("orientation",) if k in corr.info}
            times[m] = (time.process_time() - c0, time.perf_counter() - w0)
            mon.__exit__(None, None, None)
            peaks[m] = round(mon.peak_mb, 1)
            maps[m] = vmap[np.asarray(t, dtype=np.int64)]
        step = 1 if ds == "tosca_noniso" else max(1, truth_step)
        ta = read_vts(root / "corres" / f"{a}.vts", A5.n_vertices)[::step]
        tb = read_vts(root / "corres" / f"{b}.vts", B5.n_vertices)[::step]
        sym = root / "corres" / f"{b}.sym.vts"
        tbs = read_vts(sym, B5.n_vertices)[::step] if sym.exists() else None
        if s == "large":  # ground-truth points: the nearest vertex of the remeshed shape
            from scipy.spatial import cKDTree

            ta = cKDTree(A.vertices).query(A5.vertices[ta])[1]
            tb, tbs = (None if t is None else cKDTree(B.vertices).query(B5.vertices[t])[1] for t in (tb, tbs))
        preds = np.column_stack([maps[m][ta] for m in todo])
        unmatched = preds < 0  # a published map's 0 (1-based: no match) on a few vertices
        preds = np.where(unmatched, tb[:, None], preds)
        src = tb if tbs is None else np.concatenate([tb, tbs])
        dist = paired_geodesic_distances(B, src, preds if tbs is None else np.vstack([preds, preds]),
                                         method="dijkstra") / np.sqrt(B.area)
        e = dist[: len(tb)]
        es = None if tbs is None else np.minimum(e, dist[len(tb):])
        with RAW.open("a") as fh:
            for c, m in enumerate(todo):
                ok = ~unmatched[:, c]
                mean = float(e[ok, c].mean())
                sym_mean = None if es is None else float(es[ok, c].mean())
                row = {"set": s, "dataset": ds, "pair": f"{a}-{b}", "split": split_of(ds, a, b), "method": m,
                       "mean": mean, "mean_sym": sym_mean, "unmatched": int((~ok).sum()),
                       "flipped": None if sym_mean is None else is_flipped(mean, sym_mean),
                       "cpu_s": times[m][0], "wall_s": times[m][1], "peak_mb": peaks.get(m), "info": infos.get(m, {}),
                       "n_vertices": [A.n_vertices, B.n_vertices],
                       "blas": blas, "code": rev, "date": time.strftime("%Y-%m-%d"), "command": command}
                fh.write(json.dumps(row) + "\n")
                print(f"{s} {a}-{b} {m}: {mean:.4f}" + ("" if sym_mean is None else f" (sym {sym_mean:.4f})")
                      + ("" if times[m][0] is None else f" CPU {times[m][0]:.1f} s"), flush=True)


def _fmt(x: float | None, spec: str = ".4f") -> str:
    return "n/a" if x is None else format(x, spec)


def write_report() -> str:
    """The markdown of :data:`RAW`: the commands that made its rows, then per set and split the means over
    the pairs every method ran on, ratios to pyFM, flips, CPU per pair; then every pair's row."""
    rows = [json.loads(x) for x in RAW.read_text().splitlines()] if RAW.exists() else []
    commands = list(dict.fromkeys(r.get("command", "") for r in rows if r.get("command")))
    out = ["# Matching against the field: isometric, across people, non-isometric, glued contacts", "",
           "Commands (each row keeps its own):", "", *[f"    {c}" for c in commands], "",
           "Protocol: `benchmarks/matching_field.py` (its docstring): splits **by subject and animal**, never by pair "
           "(tosca: dogs tune, cats and wolves report; faust: people 0-1 tune, 2-4 report; noniso: men tune, "
           "women report; glued: 6 contacts welded on the target, same splits). Mean geodesic error / sqrt(area); "
           "flipped: error > 2 x symmetric-aware + 0.02. CPU and wall seconds per pair, spectra included, "
           "one BLAS thread. BIM and BCICP are the published maps (no time measured here).", ""]
    if rows:
        codes = sorted({r["code"].get("commit", "?")[:7] + ("+dirty" if r["code"].get("dirty") else "")
                        for r in rows if isinstance(r.get("code"), dict)})
        blas = rows[-1].get("blas")
        out += [f"Code: {', '.join(codes)}. BLAS: {blas}. Rows measured {min(r['date'] for r in rows)} to "
                f"{max(r['date'] for r in rows)}.", ""]
    for split in ("report", "tune"):
        sub = [r for r in rows if r["split"] == split]
        if not sub:
            continue
        out += [f"## {split} half", "",
                "| set | method | pairs | mean error | x pyFM | flipped | worst pair | CPU s / pair | wall s / pair |",
                "|---|---|---|---|---|---|---|---|---|"]
        for s in SETS:
            cells: dict[str, dict[str, dict]] = {}
            for r in (r for r in sub if r["set"] == s):
                cells.setdefault(r["pair"], {})[r["method"]] = r
            names = METHODS + sorted({m for c in cells.values() for m in c} - set(METHODS))
            methods = [m for m in names if any(m in c for c in cells.values())]
            common = [p for p, c in cells.items() if all(m in c for m in methods)]
            if not common:
                continue
            ref = np.mean([cells[p]["pyfm"]["mean"] for p in common]) if "pyfm" in methods else None
            for m in methods:
                rs = [cells[p][m] for p in common]
                mean = float(np.mean([r["mean"] for r in rs]))
                flips = [r["flipped"] for r in rs if r["flipped"] is not None]
                worst = max(rs, key=lambda r: r["mean"])
                cpu = [r["cpu_s"] for r in rs if r["cpu_s"] is not None]
                wall = [r["wall_s"] for r in rs if r["wall_s"] is not None]
                out.append(
                    f"| {s} | {m} | {len(rs)} | {mean:.4f} | {_fmt(mean / ref if ref else None, '.2f')} | "
                    f"{sum(flips) if flips else 'n/a'} | {worst['pair']} {worst['mean']:.3f} | "
                    f"{_fmt(float(np.mean(cpu)) if cpu else None, '.1f')} | "
                    f"{_fmt(float(np.mean(wall)) if wall else None, '.1f')} |")
        out.append("")
    large = [r for r in rows if r["set"] == "large"]
    if large:
        small = {(r["pair"], r["method"]): r["mean"] for r in rows if r["set"] in ("tosca", "faust")}
        out += ["## About 100,000 vertices against the 5k pair", "",
                "Each shape remeshed independently; the default `match` goes through 5,000-vertex proxies. "
                "Targets: error <= 1.1 x the 5k error + 0.005, <= 60 s CPU, <= 4 GB.", "",
                "| split | pair | method | vertices | error | 5k error | bound | CPU s | wall s | peak MB |",
                "|---|---|---|---|---|---|---|---|---|---|"]
        for r in sorted(large, key=lambda r: (r["split"], r["pair"], r["method"])):
            ref = small.get((r["pair"], r["method"]))
            bound = None if ref is None else 1.1 * ref + 0.005
            met = "" if bound is None else (" met" if r["mean"] <= bound else " NOT met")
            out.append(f"| {r['split']} | {r['pair']} | {r['method']} | {r.get('n_vertices')} | {r['mean']:.4f} | "
                       f"{_fmt(ref)} | {_fmt(bound)}{met} | "
                       f"{_fmt(r['cpu_s'], '.1f')} | {_fmt(r['wall_s'], '.1f')} | {_fmt(r.get('peak_mb'), '.0f')} |")
        out.append("")
    clouds = [r for r in rows if r["set"] in CLOUD_NOISE and r["split"] == "report"]
    if clouds:
        mesh = {(r["pair"], r["method"]): r["mean"] for r in rows if r["set"] in ("tosca", "faust")}
        out += ["## Point clouds against the meshes of the same pairs (report half)", "",
                "Same pairs and method on meshes (sets tosca and faust) as the reference; target: <= 1.3x.", "",
                "| set | method | pairs | mean error (cloud) | mean error (mesh) | x mesh | worst pair |",
                "|---|---|---|---|---|---|---|"]
        for s in CLOUD_NOISE:
            for m in dict.fromkeys(r["method"] for r in clouds if r["set"] == s):
                rs = [r for r in clouds if r["set"] == s and r["method"] == m and (r["pair"], m) in mesh]
                if not rs:
                    continue
                c, ms = float(np.mean([r["mean"] for r in rs])), float(np.mean([mesh[(r["pair"], m)] for r in rs]))
                worst = max(rs, key=lambda r: r["mean"])
                out.append(f"| {s} | {m} | {len(rs)} | {c:.4f} | {ms:.4f} | {c / ms:.2f} | "
                           f"{worst['pair']} {worst['mean']:.3f} |")
        out.append("")
    out += ["## Every pair", "", "| set | split | pair | method | error | sym-aware | flipped | CPU s | wall s |",
            "|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: (list(SETS).index(r["set"]), r["split"], r["pair"], METHODS.index(r["method"])
                                         if r["method"] in METHODS else 99)):
        out.append(f"| {r['set']} | {r['split']} | {r['pair']} | {r['method']} | {r['mean']:.4f} | "
                   f"{_fmt(r['mean_sym'])} | {'yes' if r['flipped'] else '' if r['flipped'] is not None else 'n/a'} | "
                   f"{_fmt(r['cpu_s'], '.1f')} | {_fmt(r['wall_s'], '.1f')} |")
    text = "\n".join(out) + "\n"
    REPORT.write_text(text)
    return text


def _every(arg: str) -> dict[str, int]:
    out = {}
    for part in filter(None, arg.split(",")):
        k, _, v = part.partition("=")
        if k not in SETS or not v.isdigit() or int(v) < 1:
            raise SystemExit(f"--every: expected set=N with a set of {sorted(SETS)} and N >= 1, got {part!r}")
        out[k] = int(v)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", help="shared data directory (default $TOOLKIT_DATA or ../shared/data)")
    ap.add_argument("--sets", default=",".join(SETS))
    ap.add_argument("--split", default="report", choices=["report", "tune", "all"])
    ap.add_argument("--every", default="", help="set=N,...: every N-th pair of that set")
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--truth-step", type=int, default=5)
    ap.add_argument("--fresh", action="store_true", help="start a new rows file")
    ap.add_argument("--report-only", action="store_true")
    args = ap.parse_args(argv)
    if args.report_only:
        write_report()
        return 0
    data = _data(args.data)
    sets = [s for s in args.sets.split(",") if s]
    methods = [m for m in args.methods.split(",") if m]
    bad = [s for s in sets if s not in SETS]
    if bad:
        print(f"unknown sets or methods: {bad}", file=sys.stderr)
        return 2
    if not (data / "tosca5k" / "pairs.txt").exists():
        print(f"shared data not found at {data}: pass --data or set TOOLKIT_DATA", file=sys.stderr)
        return 2
    if args.fresh and RAW.exists():
        RAW.unlink()
    command = "python benchmarks/matching_field.py " + " ".join(a for a in (argv if argv is not None else sys.argv[1:])
                                                                if a != "--fresh")
    run(data, jobs_of(data, sets, args.split, _every(args.every)), methods, args.truth_step, command)
    write_report()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
