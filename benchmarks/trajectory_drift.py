"""Trajectory drift on generated pose sequences (thesis 7.5.3): how far dense trajectories, chained
from the maps of consecutive frames, wander from the truth, with and without merged (glued) frames.

    python benchmarks/trajectory_drift.py [--frames 7] [--subdivisions 4] [--remesh 1500] [--seeds 10,11]
                                          [--methods zoomout,topo-robust,topo-robust-photometric,sharma2012]
                                          [--merge-frames 2,5] [--sample 500]
    python benchmarks/trajectory_drift.py --report-only   # the markdown from the saved rows

Protocol:

- Sequences: ``data.synthetic.pose_sequence(frames, subdivisions, remesh=N, permute=True,
  random_state=seed)``: one articulated body (limbs of distinct lengths) moving smoothly, every
  frame independently remeshed to about N vertices (pymeshlab isotropic remeshing, as
  independently reconstructed frames are; each vertex stands for its nearest material point of
  the clean mesh) and its vertex order shuffled. ``clean``: no merge; ``merged``: the feet are glued together in
  ``--merge-frames`` (``data.corruptions.glue``; the knees bend to the pose of closest approach
  around those frames). The generator's contact geometry was developed on seeds 0-3; the
  reported seeds (10, 11) were not looked at before this run, and no pipeline parameter was
  tuned on these sequences (the presets run as shipped). Every frame carries its procedural
  texture as ``Shape.colors``; only ``topo-robust-photometric`` (colour-feature seeds, thesis
  7.2.2) looks at it. The texture moves exactly with the surface (no lighting change between
  frames), so photometric consistency holds perfectly here: that favours the photometric preset
  compared with real visual hulls.
- ``chain``: frame t -> t+1 matched by the pipeline, maps chained
  (``results.trajectories.chain_maps``; what ``shape-toolkit track`` does). ``direct``: frame 0
  matched to every frame t directly (no accumulation, but larger deformations and, for the merged
  sequence, the merge itself in one step).
- Drift (``PoseSequence.drift`` -> ``results.trajectories.trajectory_drift``): per frame, the
  Dijkstra (mesh-edge) geodesic distance on the clean frame between the tracked and the true
  material point, / sqrt(area), for ``--sample`` trajectories evenly spaced over frame 0's
  vertices; points welded away in a merged frame have no truth there and are left out.
  ``within``: fraction within 0.05 sqrt(area). ``floor``: the drift of the ground truth itself
  (remeshed vertices stand for their nearest material point, so even the truth is off by about
  half an edge). ``flip``: the drift measured against the
  front/back mirror image of the truth (z -> -z of the rest pose, nearest vertex); a frame is
  counted as flipped when drift > 2 x flip + 0.02.
- One process, one BLAS thread per pair (``track.match_pairs``, as on a Dask worker); CPU and wall
  seconds per frame pair measured around the pipeline only. The machine is shared (2 cores, other
  jobs running): wall time is inflated, CPU time is the comparable figure.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from shape_toolkit.cli.commands.track import match_pairs, pullback_sequence_colors  # noqa: E402
from shape_toolkit.data.synthetic import (  # noqa: E402
    SEQUENCE_LIMB_LENGTHS,
    PoseSequence,
    articulated_shape,
    pose_sequence,
)
from shape_toolkit.results.trajectories import Trajectories, chain_maps, trajectory_drift  # noqa: E402
from shape_toolkit.validation import dumps_json  # noqa: E402

RESULTS = REPO / "benchmarks" / "results"
RAW = RESULTS / "trajectory_drift.json"
REPORT = RESULTS / "trajectory_drift.md"
RADIUS = 0.05


def figure_path(method: str) -> Path:
    return RESULTS / f"trajectory_drift_{method}.png"


def mirror_truth(seq: PoseSequence, subdivisions: int) -> np.ndarray:
    """``(n_0, T)`` material points of the front/back mirror image (z -> -z) of each true point."""
    from scipy.spatial import cKDTree

    rest = articulated_shape(np.zeros(5), subdivisions=subdivisions, limb_length=SEQUENCE_LIMB_LENGTHS).shape
    v = rest.vertices * np.array([1.0, 1.0, -1.0])
    mirror = cKDTree(rest.vertices).query(v)[1]
    m0 = seq.material[0]
    return np.stack([np.where(np.isin(m0, m), mirror[m0], -1) for m in seq.material], axis=1)


def wrong_part(seq: PoseSequence, ids: np.ndarray) -> list[float]:
    """Per frame, the fraction of the trajectories (alive, with a truth) on another body part
    (body, each limb) than their true material point: limb swaps, whole-body rotations."""
    true_part = seq.labels[seq.material[0]]
    out = []
    for t in range(seq.n_frames):
        ok = (ids[:, t] >= 0) & ~np.isin(seq.material[0], seq.welded[t])
        part = seq.labels[seq.material[t][ids[ok, t]]]
        out.append(float(np.mean(part != true_part[ok])) if ok.any() else None)
    return out


def drift_both(seq: PoseSequence, ids: np.ndarray, mirror: np.ndarray, sample: int) -> dict:
    d = seq.drift(ids, radius=RADIUS, sample=sample)
    # the mirror truth may name welded points: those are present only as the vertex they went onto
    mt = mirror.copy()
    for t, m in enumerate(seq.material):
        mt[~np.isin(mt[:, t], m), t] = -1
    f = trajectory_drift(ids, seq.clean, mt, vertex_maps=seq.material, radius=RADIUS, sample=sample)
    return {"mean": d["mean"], "median": d["median"], "max": d["max"], "within": d["within"],
            "lost": d["lost"], "flip_mean": f["mean"], "wrong_part": wrong_part(seq, ids)}


def run_one(kind: str, seed: int, method: str, args: argparse.Namespace) -> dict:
    merges = tuple(args.merge_frames) if kind == "merged" else ()
    seq = pose_sequence(args.frames, subdivisions=args.subdivisions, merge_frames=merges, permute=True,
                        remesh=args.remesh or None, random_state=seed)
    mirror = mirror_truth(seq, args.subdivisions)
    T = seq.n_frames
    chain_pairs = [(t, t + 1) for t in range(T - 1)]
    direct_pairs = [(0, t) for t in range(2, T)]  # 0 -> 1 is the first chain pair
    t0 = time.perf_counter()
    res = match_pairs(seq.frames, chain_pairs + direct_pairs, method)
    maps = [c for c, _ in res]
    sizes = [f.n_vertices for f in seq.frames]
    chain = chain_maps(maps[: T - 1], n_vertices=sizes)
    direct = np.empty_like(chain.ids)
    direct[:, 0] = np.arange(sizes[0])
    direct[:, 1] = maps[0].target_of
    for k, (_, t) in enumerate(direct_pairs):
        direct[:, t] = maps[T - 1 + k].target_of
    direct = Trajectories(direct, tuple(sizes)).ids  # validates
    stats = [s for _, s in res]
    row = {
        "kind": kind, "seed": seed, "method": method, "frames": T, "n_vertices": sizes,
        "clean_vertices": seq.clean[0].n_vertices,
        "contacts": list(seq.contacts), "merge_frames": list(merges),
        "chain": drift_both(seq, chain.ids, mirror, args.sample),
        "direct": drift_both(seq, direct, mirror, args.sample),
        "floor": seq.drift(seq.truth(), radius=RADIUS, sample=args.sample)["mean"],
        "pair_cpu": [s["cpu"] for s in stats], "pair_wall": [s["wall"] for s in stats],
        "n_chain_pairs": T - 1, "seconds": time.perf_counter() - t0,
    }
    if kind == "merged" and seed == args.seeds[0] and method in args.figure_methods:
        from shape_toolkit.viz import render_trajectories

        colors = pullback_sequence_colors(seq.frames, maps[: T - 1])
        render_trajectories(list(seq.frames), chain.ids, figure_path(method), colors=colors, n_tracks=150, tail=5,
                            panel_size=2.6,
                            title=f"{method}, merged sequence (feet glued in frames "
                                  f"{', '.join(map(str, merges))}), seed {seed}: 150 of {sizes[0]} "
                                  "trajectories, last 5 frames, blue (old) to green (now)")
    return row


def dask_check(args: argparse.Namespace, method: str = "zoomout") -> dict:
    """The chain pairs of the first clean sequence, sequentially and on a local Dask cluster of 2
    worker processes (``bench.executors.dask_client``, what ``track --dask local`` uses): wall
    times and whether the trajectories are identical."""
    from shape_toolkit.bench.executors import dask_client
    from shape_toolkit.cli.commands.track import track_frames
    from shape_toolkit.core.spectrum import clear_cache

    seq = pose_sequence(args.frames, subdivisions=args.subdivisions, permute=True, remesh=args.remesh or None,
                        random_state=args.seeds[0])
    clear_cache()  # the rows above left these frames' spectra in memory; the workers start cold
    t0 = time.perf_counter()
    a, _ = track_frames(seq.frames, method)
    seq_wall = time.perf_counter() - t0
    with dask_client(2) as client:
        client.run(_warm_up, method)  # imports and plugin loading count as start-up, as for this process
        t0 = time.perf_counter()
        b, _ = track_frames(seq.frames, method, client=client)
        dask_wall = time.perf_counter() - t0
    return {"method": method, "pairs": seq.n_frames - 1, "sequential_wall": seq_wall, "dask_wall": dask_wall,
            "sequential_cpu_per_pair": float(np.mean([p["cpu"] for p in a.info["pairs"]])),
            "dask_cpu_per_pair": float(np.mean([p["cpu"] for p in b.info["pairs"]])),
            "identical": bool(np.array_equal(a.ids, b.ids))}


def _warm_up(method: str) -> None:
    from shape_toolkit.pipeline import load_pipeline

    load_pipeline(method).plugins()


def code_state() -> dict:
    """The commit the toolkit was at and whether tracked package files had uncommitted edits (other
    work in progress in a shared tree changes results): ``bench.worker.code_revision``."""
    from shape_toolkit.bench.worker import code_revision

    return code_revision(REPO, paths=["shape_toolkit"])


def machine() -> dict:
    """CPU, cores, Python and BLAS libraries (``bench.worker.machine_info``)."""
    from shape_toolkit.bench.worker import machine_info

    return machine_info()


def _f(x, nd: int = 4) -> str:
    return "-" if x is None else f"{x:.{nd}f}"


def report(rows: list[dict], meta: dict) -> str:
    from shape_toolkit.bench.worker import revision_label

    methods = list(dict.fromkeys(r["method"] for r in rows))
    kinds = [k for k in ("clean", "merged") if any(r["kind"] == k for r in rows)]
    seeds = sorted({r["seed"] for r in rows})
    T = rows[0]["frames"]
    resampled = f"each remeshed independently to about {meta['remesh']} vertices and " if meta["remesh"] else ""
    out = [
        "# Trajectory drift on generated pose sequences (thesis 7.5.3)",
        "",
        f"Regenerate: `{meta['command']}` (then `python benchmarks/trajectory_drift.py --report-only`).",
        "",
        "Protocol: see the docstring of `benchmarks/trajectory_drift.py`. Sequences of "
        f"{T} frames of {meta['clean_vertices']} vertices per clean frame, "
        f"{resampled}"
        "vertex order shuffled per frame, "
        f"seeds {', '.join(map(str, seeds))} (held out: the generator was developed on seeds 0-3, nothing was "
        f"tuned on these); merged sequences glue the feet in frames {', '.join(map(str, meta['merge_frames']))}. "
        f"Drift = Dijkstra geodesic on the clean frame between tracked and true point / sqrt(area), "
        f"{meta['sample']} trajectories evenly spaced; `within` = fraction within {RADIUS}.",
        "",
        f"Machine: {meta['machine']['cpu']}, {meta['machine']['cores']} cores shared with other jobs "
        f"(wall times inflated), BLAS threads {', '.join(meta['machine']['blas'])}, one pair at a time, "
        f"one BLAS thread per pair. Sum of the runs: {meta['seconds']:.0f} s wall.",
        "",
        f"Code: commit {revision_label(meta.get('code'))} (recorded after the last row).",
        "",
        "## Summary (means over seeds; `last` = the last frame)",
        "",
        "| pipeline | sequence | mode | mean drift (all frames) | mean drift, last | within, last | "
        "on a wrong part (all frames) | front/back flipped frames | CPU s / pair | wall s / pair |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    summary = {}
    for m in methods:
        for k in kinds:
            rs = [r for r in rows if r["method"] == m and r["kind"] == k]
            cpu = np.mean([c for r in rs for c in r["pair_cpu"][: r["n_chain_pairs"]]])
            wall = np.mean([c for r in rs for c in r["pair_wall"][: r["n_chain_pairs"]]])
            cpu_d = np.mean([c for r in rs for c in r["pair_cpu"][r["n_chain_pairs"]:]] or [np.nan])
            wall_d = np.mean([c for r in rs for c in r["pair_wall"][r["n_chain_pairs"]:]] or [np.nan])
            for mode in ("chain", "direct"):
                per = np.array([[np.nan if v is None else v for v in r[mode]["mean"]] for r in rs])
                within = np.array([r[mode]["within"][-1] for r in rs])
                flips = sum(
                    int(a is not None and b is not None and a > 2 * b + 0.02)
                    for r in rs for a, b in zip(r[mode]["mean"][1:], r[mode]["flip_mean"][1:])
                )
                wp = np.array([[np.nan if v is None else v for v in r[mode]["wrong_part"][1:]] for r in rs])
                allf = float(np.nanmean(per[:, 1:]))
                last = float(np.nanmean(per[:, -1]))
                summary[(m, k, mode)] = (allf, last)
                c, w = (cpu, wall) if mode == "chain" else (cpu_d, wall_d)
                out.append(f"| {m} | {k} | {mode} | {_f(allf)} | {_f(last)} | {_f(float(within.mean()), 3)} | "
                           f"{_f(float(np.nanmean(wp)), 3)} | {flips} / {len(rs) * (T - 1)} | {_f(float(c), 2)} | "
                           f"{_f(float(w), 2)} |")
    out += ["", "CPU/wall per pair: chain rows average the consecutive pairs, direct rows the pairs 0 -> t "
            "(t >= 2; 0 -> 1 is shared with the chain).", ""]
    out += ["## Mean drift per frame (means over seeds)", ""]
    out.append("| pipeline | sequence | mode | " + " | ".join(f"f{t}" for t in range(T)) + " |")
    out.append("|---|---|---|" + "---|" * T)
    for m in methods:
        for k in kinds:
            rs = [r for r in rows if r["method"] == m and r["kind"] == k]
            for mode in ("chain", "direct"):
                per = np.array([[np.nan if v is None else v for v in r[mode]["mean"]] for r in rs])
                cells = " | ".join(_f(float(x)) for x in np.nanmean(per, axis=0))
                out.append(f"| {m} | {k} | {mode} | {cells} |")
    for k in kinds:
        rs = [r for r in rows if r["kind"] == k and r["method"] == methods[0]]
        per = np.array([[np.nan if v is None else v for v in r["floor"]] for r in rs])
        cells = " | ".join(_f(float(x)) for x in np.nanmean(per, axis=0))
        out.append(f"| ground truth (floor) | {k} | - | {cells} |")
    out += ["", "## Fraction within 0.05 per frame (means over seeds)", ""]
    out.append("| pipeline | sequence | mode | " + " | ".join(f"f{t}" for t in range(T)) + " |")
    out.append("|---|---|---|" + "---|" * T)
    for m in methods:
        for k in kinds:
            rs = [r for r in rows if r["method"] == m and r["kind"] == k]
            for mode in ("chain", "direct"):
                per = np.array([r[mode]["within"] for r in rs], dtype=float)
                out.append(f"| {m} | {k} | {mode} | " + " | ".join(_f(float(x), 3) for x in per.mean(axis=0)) + " |")
    out += ["", "## Fraction of trajectories on a wrong body part per frame (means over seeds)", ""]
    out.append("| pipeline | sequence | mode | " + " | ".join(f"f{t}" for t in range(T)) + " |")
    out.append("|---|---|---|" + "---|" * T)
    for m in methods:
        for k in kinds:
            rs = [r for r in rows if r["method"] == m and r["kind"] == k]
            for mode in ("chain", "direct"):
                per = np.array([[np.nan if v is None else v for v in r[mode]["wrong_part"]] for r in rs])
                cells = " | ".join(_f(float(x), 3) for x in np.nanmean(per, axis=0))
                out.append(f"| {m} | {k} | {mode} | {cells} |")
    out += ["", "## Ratios", ""]
    out.append("| comparison | sequence | mode | mean drift ratio (all frames) | last frame |")
    out.append("|---|---|---|---|---|")
    peer = "zoomout"
    for m in methods:
        if m == peer or peer not in methods:
            continue
        for k in kinds:
            for mode in ("chain", "direct"):
                a, b = summary[(m, k, mode)], summary[(peer, k, mode)]
                out.append(f"| {m} / {peer} | {k} | {mode} | {_ratio(a[0], b[0])} | {_ratio(a[1], b[1])} |")
    for m in methods:
        for k in kinds:
            a, b = summary[(m, k, "chain")], summary[(m, k, "direct")]
            out.append(f"| chain / direct ({m}) | {k} | - | {_ratio(a[0], b[0])} | {_ratio(a[1], b[1])} |")
    out += ["", "## Per run (drift per frame, chain)", ""]
    out.append("| pipeline | sequence | seed | contacts per frame | " + " | ".join(f"f{t}" for t in range(T)) + " |")
    out.append("|---|---|---|---|" + "---|" * T)
    for r in rows:
        out.append(f"| {r['method']} | {r['kind']} | {r['seed']} | {r['contacts']} | "
                   + " | ".join(_f(x) for x in r["chain"]["mean"]) + " |")
    if meta.get("dask"):
        dk = meta["dask"]
        speed = dk["sequential_wall"] / dk["dask_wall"]
        out += ["", "## Dask", "",
                f"The {dk['pairs']} chain pairs of the first clean sequence with `{dk['method']}`: sequential "
                f"{dk['sequential_wall']:.1f} s wall, local Dask cluster of 2 worker processes "
                f"{dk['dask_wall']:.1f} s wall ({speed:.2f}x; both with cold spectrum caches, cluster start-up and "
                f"imports excluded; "
                f"a 2-core machine shared with other jobs); CPU per pair {dk['sequential_cpu_per_pair']:.2f} s "
                f"in this process, {dk['dask_cpu_per_pair']:.2f} s on a worker (process CPU time, which there includes "
                "Dask's own threads: event loop, heartbeats, sampling profiler). Trajectories identical: "
                f"{'yes' if dk['identical'] else 'NO'}. No speed-up is measured here: under this load the two "
                "workers share the CPU the one process had, and each pair costs more CPU on a worker; the "
                "parallel path is there for machines with free cores or a cluster (`--dask tcp://...`)."]
    for m in meta["figure_methods"]:
        if figure_path(m).exists():
            out += ["", f"![{m} trajectories]({figure_path(m).name})", "",
                    f"Figure: `{m}`, chained, on the first merged sequence, drawn by `viz.render_trajectories` "
                    "(what `shape-toolkit track --png` writes); each frame coloured by pull-back of the last "
                    "frame's position colours, so a correct tracking looks the same in every frame."]
    out += ["", "## Findings", "", *meta.get("findings", ["(see the tables)"]), ""]
    return "\n".join(out)


def _ratio(a: float, b: float) -> str:
    if not (np.isfinite(a) and np.isfinite(b)):
        return "-"
    if b == 0:
        return "inf" if a > 0 else "1 (both 0)"
    return f"{a / b:.2f}x"


def findings(rows: list[dict]) -> list[str]:
    """Plain statements computed from the rows (wins and misses alike)."""
    out = []
    methods = list(dict.fromkeys(r["method"] for r in rows))
    for k in ("clean", "merged"):
        last = {m: float(np.mean([r["chain"]["mean"][-1] for r in rows if r["method"] == m and r["kind"] == k]))
                for m in methods if any(r["method"] == m and r["kind"] == k for r in rows)}
        if last:
            order = sorted(last, key=last.get)
            out.append(f"- {k} sequences, chained, drift at the last frame: "
                       + ", ".join(f"{m} {last[m]:.4f}" for m in order) + ".")
    for m in methods:
        for k in ("clean", "merged"):
            rs = [r for r in rows if r["method"] == m and r["kind"] == k]
            if not rs:
                continue
            ch = float(np.nanmean([[np.nan if v is None else v for v in r["chain"]["mean"][1:]] for r in rs]))
            di = float(np.nanmean([[np.nan if v is None else v for v in r["direct"]["mean"][1:]] for r in rs]))
            last_w = float(np.mean([r["chain"]["within"][-1] for r in rs]))
            better = "lower" if ch < di else ("equal" if ch == di else "higher")
            out.append(f"- {m}, {k}: chained drift {ch:.4f} (mean over frames 1..T-1) is {better} than matching "
                       f"each frame to frame 0 ({di:.4f}); {100 * last_w:.1f}% of the trajectories are within "
                       f"{RADIUS} in the last frame.")
            if k == "merged":
                mf = rs[0]["merge_frames"]
                wp = float(np.mean([r["direct"]["wrong_part"][t] for r in rs for t in mf]))
                out.append(f"  In the glued frames ({', '.join(map(str, mf))}), matched directly from frame 0, "
                           f"{100 * wp:.1f}% of the trajectories land on a wrong body part.")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=7)
    ap.add_argument("--subdivisions", type=int, default=4)
    ap.add_argument("--remesh", type=int, default=1500, help="vertices per remeshed frame (0: no remeshing)")
    ap.add_argument("--seeds", default="10,11")
    ap.add_argument("--methods", default="zoomout,topo-robust,topo-robust-photometric,sharma2012")
    ap.add_argument("--merge-frames", default="2,5")
    ap.add_argument("--sample", type=int, default=500)
    ap.add_argument("--figure-methods", default="zoomout,topo-robust,topo-robust-photometric")
    ap.add_argument("--no-dask", action="store_true", help="skip the sequential-vs-Dask check")
    ap.add_argument("--report-only", action="store_true")
    args = ap.parse_args()
    args.seeds = [int(s) for s in args.seeds.split(",")]
    args.merge_frames = [int(s) for s in args.merge_frames.split(",")]
    args.figure_methods = args.figure_methods.split(",")
    RESULTS.mkdir(parents=True, exist_ok=True)
    if args.report_only:
        saved = json.loads(RAW.read_text())
        saved["meta"]["findings"] = findings(saved["rows"])
        REPORT.write_text(report(saved["rows"], saved["meta"]))
        print(f"wrote {REPORT}")
        return
    command = " ".join(["python benchmarks/trajectory_drift.py", *sys.argv[1:]])
    saved = json.loads(RAW.read_text()) if RAW.exists() else {"rows": []}
    done = {(r["kind"], r["seed"], r["method"]) for r in saved["rows"]
            if r["frames"] == args.frames and saved.get("meta", {}).get("command") == command}
    rows = [r for r in saved["rows"] if (r["kind"], r["seed"], r["method"]) in done]
    meta = saved.get("meta", {})
    for kind in ("clean", "merged"):
        for seed in args.seeds:
            for method in args.methods.split(","):
                if (kind, seed, method) in done:
                    continue
                row = run_one(kind, seed, method, args)
                rows.append(row)
                print(f"{kind} seed {seed} {method}: chain last {row['chain']['mean'][-1]:.4f}, direct last "
                      f"{row['direct']['mean'][-1]:.4f}, {row['seconds']:.0f} s", flush=True)
                meta = {"command": command, "machine": machine(), "code": code_state(), "sample": args.sample,
                        "remesh": args.remesh, "clean_vertices": row["clean_vertices"],
                        "merge_frames": args.merge_frames, "figure_methods": args.figure_methods,
                        "seconds": float(sum(r["seconds"] for r in rows))}
                RAW.write_text(dumps_json({"meta": meta, "rows": rows}, indent=1))
    if "dask" not in meta and not args.no_dask:
        meta["dask"] = dask_check(args)
        RAW.write_text(dumps_json({"meta": meta, "rows": rows}, indent=1))
    meta["findings"] = findings(rows)
    REPORT.write_text(report(rows, meta))
    print(f"wrote {REPORT}")


if __name__ == "__main__":
    main()
