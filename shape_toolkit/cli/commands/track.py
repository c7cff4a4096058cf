"""``shape-toolkit track FRAME_0 FRAME_1 ... --pipeline NAME -o traj.npz``: dense trajectories
through a sequence of shapes (thesis 7.5.3, Figs. 7.17-7.18).

Consecutive frames are matched with any pipeline (sequentially, or in parallel on Dask with
``--dask local|tcp://...``), the maps are chained into dense trajectories
(:class:`~shape_toolkit.results.trajectories.Trajectories`, an ``.npz``), and optionally drawn: a
PNG with the frames side by side and trajectory tails (``--png``), an animated GIF (``--gif``) or a
PLY sequence with pull-back colours (``--ply-dir``). Default output: ``FRAME_0_STEM.traj.npz``.

:func:`match_pairs` and :func:`track_frames` are the Python entry points (the benchmark uses them).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from shape_toolkit.cli.commands._common import (
    add_memory_limit,
    add_quiet,
    check_applies,
    check_distinct,
    check_memory,
    check_output_path,
    dask_target,
    default_output,
    local_workers_arg,
    positive_int_arg,
    print_json,
    proxy_arg,
    status,
)
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.plugins.matching.multires import PROXY_VERTICES, match_memory
from shape_toolkit.results.correspondence import Correspondence
from shape_toolkit.results.trajectories import Trajectories, chain_maps, compose_maps

__all__ = ["match_pairs", "track_frames", "pullback_sequence_colors", "track_memory", "FRAME_BYTES", "register", "run"]

#: ``--tracks``, ``--tail`` and ``--workers`` when not given
DEFAULT_TRACKS, DEFAULT_TAIL, DEFAULT_WORKERS = 150, 5, 2

#: bytes a frame holds per vertex while the others are matched (the loaded shape, its cached areas and normals, its
#: trajectory entries; one 244,904-vertex mesh loaded: 150 B, with its areas 250 B, 2026-12-06)
FRAME_BYTES = 300.0


def track_memory(n: int, n_frames: int, proxy: int | None, parallel: int = 1) -> float:
    """Estimated peak bytes of ``shape-toolkit track`` on ``n_frames`` frames of ``n`` vertices in all: every frame held
    (:data:`FRAME_BYTES` a vertex) and ``parallel`` frame pairs (Dask workers) matched at once, each estimated by
    ``match``'s model for a pair of average frames. An estimate for refusing frames before reading them
    (``--memory-limit``; ``benchmarks/results/memory_models.md``), not a bound."""
    pair = 2 * n / max(n_frames, 1)
    return FRAME_BYTES * n + max(int(parallel), 1) * match_memory(int(pair), proxy)


def _match_pair(spec: dict[str, Any], source: Shape, target: Shape, seeds: np.ndarray | None,
                proxy: int | None = PROXY_VERTICES) -> dict[str, Any]:
    """One frame pair (runs in the caller or on a Dask worker): the pipeline with one BLAS thread,
    so that the result does not depend on where it runs; the map, wall and CPU seconds."""
    from shape_toolkit.pipeline import run_pair_timed

    corr, secs = run_pair_timed(spec, source, target, seeds, proxy)
    return {"target_of": np.asarray(corr.target_of), "n_target": corr.n_target, **secs, "n_matched": corr.n_matched}


def match_pairs(
    frames: Sequence[Shape],
    pairs: Sequence[tuple[int, int]],
    pipeline: Any,
    *,
    seeds: Sequence[np.ndarray | None] | None = None,
    client: Any = None,
    progress: Callable[[int, int], None] | None = None,
    proxy: int | None = PROXY_VERTICES,
) -> list[tuple[Correspondence, dict[str, float]]]:
    """Match ``frames[i] -> frames[j]`` for every ``(i, j)`` in ``pairs`` with ``pipeline`` (a
    preset name, TOML path, dict or :class:`~shape_toolkit.pipeline.Pipeline`); ``seeds``: one
    ``(q, 2)`` array or None per pair. With a ``distributed.Client`` the pairs run in parallel on
    its workers, else one after the other; either way each runs with one BLAS thread, so both
    give the same maps. Frames above 1.5 ``proxy`` vertices are matched through proxies (:meth:`Pipeline.run
    <shape_toolkit.pipeline.Pipeline.run>`; None or 0: never). ``progress(done, total)`` after each pair. Returns,
    per pair, the
    :class:`Correspondence` and ``{"wall": s, "cpu": s}`` measured where it ran."""
    from shape_toolkit.pipeline import load_pipeline

    spec = load_pipeline(pipeline).to_dict()
    n = len(frames)
    pairs = [(int(i), int(j)) for i, j in pairs]
    if any(not (0 <= i < n and 0 <= j < n) for i, j in pairs):
        raise ParameterError(f"frame pairs must index the {n} frames")
    seeds = [None] * len(pairs) if seeds is None else list(seeds)
    if len(seeds) != len(pairs):
        raise ParameterError(f"{len(seeds)} seed arrays for {len(pairs)} frame pairs")
    say = progress or (lambda _d, _t: None)
    results: list[dict[str, Any] | None] = [None] * len(pairs)
    if client is None:
        for k, (i, j) in enumerate(pairs):
            results[k] = _match_pair(spec, frames[i], frames[j], seeds[k], proxy)
            say(k + 1, len(pairs))
    else:
        from distributed import as_completed

        futs = {client.submit(_match_pair, spec, frames[i], frames[j], seeds[k], proxy, pure=False): k
                for k, (i, j) in enumerate(pairs)}
        for done, fut in enumerate(as_completed(list(futs)), 1):
            results[futs[fut]] = fut.result()
            say(done, len(pairs))
    out = []
    for r in results:
        assert r is not None
        out.append((Correspondence(r["target_of"], r["n_target"]),
                    {"wall": float(r["wall"]), "cpu": float(r["cpu"]), "n_matched": int(r["n_matched"])}))
    return out


def track_frames(
    frames: Sequence[Shape],
    pipeline: Any,
    *,
    seeds: Sequence[np.ndarray | None] | None = None,
    client: Any = None,
    progress: Callable[[int, int], None] | None = None,
    proxy: int | None = PROXY_VERTICES,
) -> tuple[Trajectories, list[Correspondence]]:
    """Dense trajectories through ``frames`` (at least 2): match each frame to the next
    (:func:`match_pairs`, through proxies above 1.5 ``proxy`` vertices) and chain the maps
    (:func:`~shape_toolkit.results.trajectories.chain_maps`). Returns the trajectories (``info``: pipeline, per-pair
    wall/CPU seconds and matched counts) and the ``T - 1`` frame maps."""
    from shape_toolkit.pipeline import load_pipeline

    if len(frames) < 2:
        raise ParameterError(f"tracking needs at least 2 frames, got {len(frames)}")
    pipe = load_pipeline(pipeline)
    res = match_pairs(frames, [(t, t + 1) for t in range(len(frames) - 1)], pipe, seeds=seeds,
                      client=client, progress=progress, proxy=proxy)
    maps = [c for c, _ in res]
    info = {"pipeline": pipe.name, "pairs": [dict(s) for _, s in res],
            "frames": [f.name for f in frames]}
    return chain_maps(maps, n_vertices=[f.n_vertices for f in frames], info=info), maps


def pullback_sequence_colors(
    frames: Sequence[Shape], maps: Sequence[Correspondence], reference_colors: np.ndarray | None = None
) -> list[np.ndarray]:
    """Per-frame RGB ``(n_t, 3)``: the last frame is coloured by ``reference_colors`` (default its
    positions in its bounding box) and every frame ``t`` takes, vertex by vertex, the colour of
    the last-frame vertex its chained maps ``t -> ... -> T-1`` reach (grey where lost), so a good
    tracking makes all frames look alike (pull-back, as ``match --ply``)."""
    from shape_toolkit.viz import pullback_colors

    last = frames[-1]
    out = []
    for t in range(len(frames)):
        target_of = np.arange(last.n_vertices) if t == len(frames) - 1 else compose_maps(
            maps[t:], n_vertices=[f.n_vertices for f in frames[t:]])
        cs, _ = pullback_colors(frames[t], last, target_of, reference_colors)
        out.append(cs)
    return out


# --------------------------------------------------------------------------------------------
# command line
# --------------------------------------------------------------------------------------------
def register(sub: argparse._SubParsersAction) -> None:
    from shape_toolkit.pipeline import PRESETS

    p = sub.add_parser("track", help="dense trajectories through a sequence of shapes (thesis 7.5.3)",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("frames", nargs="+", metavar="FRAME", help="the frames, in order (at least 2)")
    p.add_argument("--pipeline", default="zoomout",
                   help=f"preset ({', '.join(sorted(PRESETS))}) or a .toml spec (default zoomout)")
    p.add_argument("--seeds", nargs="+", metavar="FILE",
                   help="seed matches per frame pair: T-1 files of 'source target' 0-based ids per line")
    p.add_argument("-o", "--output", help="trajectory file (.npz; default FRAME_0_STEM.traj.npz)")
    p.add_argument("--png", metavar="FIG.png",
                   help="draw the frames side by side with trajectory tails (and the same figure as FIG.pdf)")
    vis = p.add_mutually_exclusive_group()
    vis.add_argument("--gif", metavar="ANIM.gif", help="animated GIF of the frames with trajectory tails")
    vis.add_argument("--ply-dir", metavar="DIR",
                     help="write DIR/frame_NNN.ply, each frame with pull-back colours of the last frame")
    p.add_argument("--tracks", type=positive_int_arg, default=None,
                   help=f"trajectories drawn by --png / --gif (default {DEFAULT_TRACKS})")
    p.add_argument("--tail", type=positive_int_arg, default=None,
                   help=f"frames of trajectory drawn by --png / --gif (default {DEFAULT_TAIL})")
    p.add_argument("--dask", metavar="SCHEDULER", type=dask_target,
                   help="match frame pairs in parallel on Dask: 'local' (a local cluster) or tcp://host:port")
    p.add_argument("--workers", type=local_workers_arg, default=None,
                   help=f"local Dask workers of --dask local (default {DEFAULT_WORKERS}; at most 4 per core, 8 always)")
    p.add_argument("--proxy", type=proxy_arg, default=PROXY_VERTICES, metavar="N",
                   help=f"frames above 1.5 N vertices are matched through proxies of N vertices and the maps lifted to "
                        f"full resolution, as match's (N >= 100; default {PROXY_VERTICES}; 0: always at full "
                        "resolution)")
    p.add_argument("--json", action="store_true", help="print JSON")
    add_memory_limit(p)
    add_quiet(p)
    p.set_defaults(func=run)


def _check_inputs(args: argparse.Namespace) -> tuple[Path, Path | None, Path | None, Path | None]:
    if len(args.frames) < 2:
        raise ParameterError(f"tracking needs at least 2 frames, got {len(args.frames)}")
    out = default_output(args.output, args.frames[0], "traj.npz")
    check_output_path(out, "--output", suffixes=(".npz",))
    check_distinct(out, *args.frames)
    png = check_output_path(args.png, "--png", suffixes=(".png",))
    gif = check_output_path(args.gif, "--gif", suffixes=(".gif",))
    if png is not None:  # the same figure as a PDF beside it (a vector copy for a paper)
        check_output_path(png.with_suffix(".pdf"), "--png (its PDF copy)", suffixes=(".pdf",))
    for extra in (png, png.with_suffix(".pdf") if png is not None else None, gif):
        if extra is not None:
            check_distinct(extra, *args.frames, outputs=(out,))
    ply_dir = None
    if args.ply_dir is not None:
        ply_dir = Path(args.ply_dir)
        if ply_dir.exists() and not ply_dir.is_dir():
            raise ParameterError(f"--ply-dir {args.ply_dir!r} exists and is not a folder")
        if not ply_dir.exists() and not (ply_dir.parent if str(ply_dir.parent) else Path(".")).is_dir():
            raise ParameterError(f"--ply-dir: the parent folder of {args.ply_dir!r} does not exist")
        for t in range(len(args.frames)):  # the files it will write (frame_000.ply, ...) must not be inputs
            check_distinct(ply_dir / f"frame_{t:03d}.ply", *args.frames, *(args.seeds or []), outputs=(out,))
    # options of a step not asked for would be ignored
    check_applies("--workers", args.workers is not None, "--dask local", args.dask == "local",
                  " (a local cluster of that many workers)")
    for option, value in (("--tracks", args.tracks), ("--tail", args.tail)):
        check_applies(option, value is not None, "the drawings", png is not None or gif is not None,
                      "; give --png FIG.png or --gif ANIM.gif")
    args.workers = args.workers or DEFAULT_WORKERS
    args.tracks = args.tracks or DEFAULT_TRACKS
    args.tail = args.tail or DEFAULT_TAIL
    if args.seeds is not None and len(args.seeds) != len(args.frames) - 1:
        raise ParameterError(f"--seeds needs one file per frame pair ({len(args.frames) - 1}), got {len(args.seeds)}")
    return out, png, gif, ply_dir


def run(args: argparse.Namespace) -> int:
    from shape_toolkit.io.mesh import load_shape
    from shape_toolkit.pipeline import load_pipeline
    from shape_toolkit.results.correspondence import read_seeds

    out, png, gif, ply_dir = _check_inputs(args)
    pipe = load_pipeline(args.pipeline)
    parallel = min(args.workers, len(args.frames) - 1) if args.dask == "local" else 1
    check_memory(args, list(args.frames), lambda n: track_memory(n, len(args.frames), args.proxy, parallel),
                 f"tracking through {len(args.frames)} frames"
                 + ("" if args.proxy else " at full resolution (--proxy 0)"), "memory_models.md")
    frames = [load_shape(f) for f in args.frames]
    kinds = {("mesh" if f.is_mesh else "point cloud") for f in frames}
    if len(kinds) > 1:
        bad = next(i for i, f in enumerate(frames) if f.is_mesh != frames[0].is_mesh)
        raise ParameterError(
            f"frames must all be meshes or all point clouds: {args.frames[0]} is a "
            f"{'mesh' if frames[0].is_mesh else 'point cloud'}, {args.frames[bad]} is not"
        )
    seeds = None
    if args.seeds:
        seeds = [read_seeds(s, frames[t].n_vertices, frames[t + 1].n_vertices) for t, s in enumerate(args.seeds)]
    n_pairs = len(frames) - 1
    t0 = time.perf_counter()
    with status(args, f"track ({pipe.name}): 0/{n_pairs} frame pairs") as st:
        def progress(done: int, total: int) -> None:
            st.update(f"track ({pipe.name}): {done}/{total} frame pairs")

        if args.dask is not None:
            from shape_toolkit.bench.executors import dask_client

            st.update(f"track ({pipe.name}): starting Dask")
            with dask_client(args.workers, None if args.dask == "local" else args.dask) as client:
                st.update(f"track ({pipe.name}): 0/{n_pairs} frame pairs on Dask")
                traj, maps = track_frames(frames, pipe, seeds=seeds, client=client, progress=progress,
                                          proxy=args.proxy)
        else:
            traj, maps = track_frames(frames, pipe, seeds=seeds, progress=progress, proxy=args.proxy)
        traj.info["files"] = [str(f) for f in args.frames]
        traj.save(out)
        written: dict[str, Any] = {"npz": str(out)}
        if png or gif or ply_dir:
            st.update("track: drawing")
            colors = pullback_sequence_colors(frames, maps)
            title = f"{pipe.name}: {traj.n_tracks} trajectories through {traj.n_frames} frames"
            if png:
                from shape_toolkit.viz import render_trajectories

                render_trajectories(frames, traj.ids, png, colors=colors, n_tracks=args.tracks,
                                    tail=args.tail, title=title, pdf=True)
                written["png"], written["pdf"] = str(png), str(png.with_suffix(".pdf"))
            if gif:
                from shape_toolkit.viz import render_trajectories

                render_trajectories(frames, traj.ids, gif, colors=colors, n_tracks=args.tracks,
                                    tail=args.tail, title=title)
                written["gif"] = str(gif)
            if ply_dir:
                from shape_toolkit.viz import save_colored_ply

                ply_dir.mkdir(exist_ok=True)
                written["ply"] = [str(save_colored_ply(f, ply_dir / f"frame_{t:03d}.ply", c))
                                  for t, (f, c) in enumerate(zip(frames, colors))]
    seconds = time.perf_counter() - t0
    alive = traj.alive[:, -1].mean()
    result = {
        "pipeline": pipe.name,
        "n_frames": traj.n_frames,
        "n_tracks": traj.n_tracks,
        "alive_last_frame": float(alive),
        "dask": args.dask,
        "seconds": round(seconds, 3),
        "pairs": [{k: (round(v, 3) if isinstance(v, float) else v) for k, v in p.items()} for p in traj.info["pairs"]],
        "outputs": written,
    }
    if args.json:
        print_json(result)
    else:
        print(f"{pipe.name}: {traj.n_tracks} trajectories through {traj.n_frames} frames "
              f"({100 * alive:.1f}% reach the last) in {seconds:.1f} s -> {out}")
        for k in ("png", "pdf", "gif"):
            if k in written:
                print(f"{k}: {written[k]}")
        if "ply" in written:
            print(f"ply: {len(written['ply'])} files in {ply_dir}")
    return 0
