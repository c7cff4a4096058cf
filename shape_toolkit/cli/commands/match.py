"""``shape-toolkit match SRC DST --pipeline NAME_OR_FILE -o map.txt``: dense correspondence
by a named or TOML-described pipeline; the map file holds one 0-based target vertex per source
vertex (-1 when unmatched)."""

from __future__ import annotations

import argparse
import sys
import time

from shape_toolkit.cli.commands._common import check_distinct, check_output_path, print_json, read_seeds_file
from shape_toolkit.errors import ParameterError
from shape_toolkit.io.mesh import load_shape
from shape_toolkit.pipeline import PRESETS, load_pipeline
from shape_toolkit.results.correspondence import save_map


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("match", help="dense correspondence between two shapes")
    p.add_argument("source", help="source shape")
    p.add_argument("target", help="target shape")
    p.add_argument("--pipeline", default="zoomout",
                   help=f"preset ({', '.join(sorted(PRESETS))}) or a .toml spec (default zoomout)")
    p.add_argument("--seeds", help="seed matches: 'source target' 0-based ids per line")
    p.add_argument("-o", "--output", required=True, help="map file to write")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    check_output_path(args.output)
    check_distinct(args.output, args.source, args.target, args.seeds)
    pipe = load_pipeline(args.pipeline)
    source = load_shape(args.source)
    target = load_shape(args.target)
    seeds = read_seeds_file(args.seeds, source.n_vertices, target.n_vertices) if args.seeds else None
    say = None if args.quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))
    t0 = time.perf_counter()
    corr = pipe.run(source, target, seeds, progress=say)
    seconds = time.perf_counter() - t0
    if corr.n_matched == 0:
        raise ParameterError(f"pipeline {pipe.name!r} matched no vertex; nothing written")
    save_map(args.output, corr)
    result = {
        "map_file": args.output,
        "n_matched": corr.n_matched,
        "n_source": corr.n_source,
        "n_target": corr.n_target,
        "pipeline": pipe.name,
        "seconds": round(seconds, 3),
        "stages": {k: round(v, 3) for k, v in corr.info.get("timings", {}).items()},
        "n_seeds": corr.info.get("n_seeds", 0),
    }
    if args.json:
        print_json(result)
    else:
        print(f"{pipe.name}: matched {corr.n_matched}/{corr.n_source} vertices in {seconds:.2f} s "
              f"-> {args.output}")
    return 0
