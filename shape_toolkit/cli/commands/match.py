"""``shape-toolkit match SRC DST --pipeline NAME_OR_FILE [-o MAP]``: dense correspondence by a named
or TOML-described pipeline; the map file holds one 0-based target vertex per source vertex (-1 when
unmatched). Default output: ``SRC_STEM.to-DST_STEM.map.txt`` in the current directory."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from shape_toolkit.cli.commands._common import (
    add_memory_limit,
    add_quiet,
    check_distinct,
    check_memory,
    check_output_path,
    check_ply,
    default_output,
    print_json,
    proxy_arg,
    status,
    write_ply,
)
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.io.mesh import load_shape
from shape_toolkit.pipeline import PRESETS, load_pipeline
from shape_toolkit.plugins.matching.multires import PROXY_VERTICES, match_memory
from shape_toolkit.results.correspondence import read_seeds, save_map


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("match", help="dense correspondence between two shapes")
    p.add_argument("source", help="source shape")
    p.add_argument("target", help="target shape")
    p.add_argument("--pipeline", default="auto",
                   help=f"preset ({', '.join(sorted(PRESETS))}) or a .toml spec (default auto: zoomout and "
                        "shells, the map of least ZoomOut residual; zoomout alone is 2.5x faster on isometric pairs)")
    p.add_argument("--seeds", help="seed matches: 'source target' 0-based ids per line")
    p.add_argument("--proxy", type=proxy_arg, default=PROXY_VERTICES, metavar="N",
                   help=f"shapes above 1.5 N vertices are matched through proxies of N vertices and the map lifted "
                        f"to full resolution (N >= 100; default {PROXY_VERTICES}; 0: always at full resolution)")
    p.add_argument("-o", "--output", help="map file to write (default SRC_STEM.to-DST_STEM.map.txt)")
    p.add_argument("--ply", metavar="OUT.ply", default=None,
                   help="also write OUT.source.ply and OUT.target.ply: the target coloured by position, "
                        "the source by the colours pulled back through the map (MeshLab, Open3D)")
    p.add_argument("--json", action="store_true", help="print JSON")
    add_memory_limit(p)
    add_quiet(p)
    p.set_defaults(func=run)


def ply_pair(path: str) -> tuple[Path, Path]:
    """``OUT.ply`` -> ``(OUT.source.ply, OUT.target.ply)``."""
    p = Path(path)
    stem = p.name[:-4] if p.name.lower().endswith(".ply") else p.name
    return p.with_name(f"{stem}.source.ply"), p.with_name(f"{stem}.target.ply")


def run(args: argparse.Namespace) -> int:
    out = default_output(args.output, args.source, f"to-{Path(args.target).stem}.map.txt")
    check_output_path(out)
    check_distinct(out, args.source, args.target, args.seeds)
    check_ply(args.ply, args.source, args.target, args.seeds, output=str(out))
    if args.ply:  # the two files --ply writes must not be an input either
        for written in ply_pair(args.ply):
            check_distinct(written, args.source, args.target, args.seeds, outputs=(str(out),))
    pipe = load_pipeline(args.pipeline)
    check_memory(args, [args.source, args.target], lambda n: match_memory(n, args.proxy),
                 "matching them" if args.proxy else "matching them at full resolution (--proxy 0)",
                 "scale_1m.md and memory_models.md" if args.proxy else "memory_models.md")
    source = load_shape(args.source)
    target = load_shape(args.target)
    seeds = read_seeds(args.seeds, source.n_vertices, target.n_vertices) if args.seeds else None
    t0 = time.perf_counter()
    with status(args, f"{pipe.name}: starting") as st:
        corr = pipe.run(source, target, seeds, progress=st.update, proxy=args.proxy or None)
    seconds = time.perf_counter() - t0
    if corr.n_matched == 0:
        raise ParameterError(f"pipeline {pipe.name!r} matched no vertex; nothing written")
    save_map(out, corr)
    plys = None
    if args.ply:
        from shape_toolkit.viz import pullback_colors

        ps, pt = ply_pair(args.ply)
        cs, ct = pullback_colors(source, target, corr.target_of)
        plys = [write_ply(ps, source, cs), write_ply(pt, target, ct)]
    result = {
        "map_file": str(out),
        "ply": plys,
        "n_matched": corr.n_matched,
        "n_source": corr.n_source,
        "n_target": corr.n_target,
        "pipeline": pipe.name,
        "seconds": round(seconds, 3),
        "stages": {k: round(v, 3) for k, v in corr.info.get("timings", {}).items()},
        "stages_cpu": {k: round(v, 3) for k, v in corr.info.get("cpu_timings", {}).items()},
        "n_seeds": corr.info.get("n_seeds", 0),
        "orientation": corr.info.get("orientation"),
        "ambiguity": corr.info.get("ambiguity"),
        "settled": corr.info.get("settled"),
        # the proxies' functional map (a k x k array) is for the API, not the summary
        "proxy": {k: v for k, v in corr.info["proxy"].items() if k != "C"} if corr.info.get("proxy") else None,
        "open_boundary": _open_boundary(source, target),
        "seeds_torn": _seeds_torn(source, target, corr.target_of, seeds),
    }
    if args.json:
        print_json(result)
    else:
        print(f"{pipe.name}: matched {corr.n_matched}/{corr.n_source} vertices in {seconds:.2f} s -> {out}")
        o = corr.info.get("orientation")
        if o and o["verdict"] != "preserving" and o["samples"] > 0:  # clouds have no outward normals to judge
            from shape_toolkit.core.inspect import inconsistent_edges

            mixed = [(f, n) for f, s in ((args.source, source), (args.target, target))
                     if s.is_mesh and (n := len(inconsistent_edges(s.faces)))]
            why = (f"; but the faces of {mixed[0][0]} are not consistently oriented ({mixed[0][1]} edges), which the "
                   "verdict reads from: 'shape-toolkit clean' orients them") if mixed else ""
            print(f"warning: the map's orientation is {o['verdict']} (score {o['score']:+.2f}, z {o['z']:+.1f}): "
                  f"left and right may be swapped; pass seeds (--seeds) to fix it{why}")
        a = corr.info.get("ambiguity")
        if a and a.get("ambiguous"):
            print(f"warning: another map ({a['rival']}) lies {a['disagreement']:.2f} sqrt(area) from this one with a "
                  f"residual only {a['residual_ratio']:.2f} times its own: the pair is ambiguous (a half turn or a "
                  "swapped part may have been kept); pass seeds (--seeds) to decide")
        if result["seeds_torn"]:
            print(f"warning: the map goes elsewhere at {result['seeds_torn']} of the {len(seeds)} seeds (the points "
                  "around each such seed land 0.15 sqrt(area) or more from its target): check those seeds, or add "
                  "more where the shapes differ")
        hint = _partial_hint(result["open_boundary"], args, pipe.name)
        if hint:
            print(hint)
        if plys:
            print(f"coloured meshes: {plys[0]} (pull-back), {plys[1]}")
    return 0


def _seeds_torn(source: Shape, target: Shape, target_of: np.ndarray, seeds: np.ndarray | None) -> int | None:
    """At how many of the user's ``seeds`` ``(q, 2)`` the final map goes elsewhere
    (:func:`~shape_toolkit.plugins.matching.selection.seed_tears`: the points around the seed, since most pipelines
    write the seeds themselves into their maps); None without seeds, or for a target cloud with no surface to measure
    it on. A cloud's area is that of its surface (:func:`~shape_toolkit.core.surface.cloud_area`), measured on at most
    ``PROXY_VERTICES`` of its points (a fixed random draw: the area is the surface's, whatever the sampling, and the
    full triangulation of a million points would take gigabytes)."""
    from shape_toolkit.core.surface import cloud_area
    from shape_toolkit.errors import InvalidShapeError
    from shape_toolkit.plugins.matching.selection import seed_tears

    if seeds is None or not len(seeds):
        return None
    try:
        if target.is_mesh:
            area = target.area
        else:
            n, m = target.n_vertices, PROXY_VERTICES
            pick = np.sort(np.random.default_rng(0).choice(n, m, replace=False)) if n > m else np.arange(n)
            area = cloud_area(Shape(np.asarray(target.vertices)[pick], None, name=target.name))
    except InvalidShapeError:
        return None
    return seed_tears(source, target, target_of, seeds, area)


def _open_boundary(source: Shape, target: Shape) -> dict:
    """Each shape's boundary length in units of the square root of its area (0: closed; None: a point cloud)."""
    from shape_toolkit.core.inspect import boundary_length

    def rel(s: Shape) -> float | None:
        b = boundary_length(s)
        return None if b is None else (round(b / np.sqrt(s.area), 4) if s.area > 0 else None)

    return {"source": rel(source), "target": rel(target)}


def _partial_hint(open_boundary: dict, args: argparse.Namespace, pipeline: str) -> str | None:
    """A note when one mesh is closed and the other is not (a part of a whole?) and the pipeline is not ``partial``."""
    s, t = open_boundary["source"], open_boundary["target"]
    if pipeline == "partial" or s is None or t is None or (s > 0) == (t > 0):
        return None
    part, whole, length = (args.source, args.target, s) if s > 0 else (args.target, args.source, t)
    return (f"note: {part} has an open boundary ({length:.2f} sqrt(area) long) and {whole} is closed: if it is a part "
            f"of the other (a region cut away or unseen), 'shape-toolkit match {part} {whole} --pipeline partial' "
            "matches a part to a whole")
