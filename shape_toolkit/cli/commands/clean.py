"""``shape-toolkit clean MESH -o OUT``: repair defects, write the result, print what changed."""

from __future__ import annotations

import argparse

from shape_toolkit.cli.commands._common import (
    check_applies,
    check_distinct,
    check_output_path,
    default_output,
    int_arg,
    positive_float_arg,
    print_json,
)
from shape_toolkit.core.cleanup import MAX_REMESH_ITERATIONS, clean_shape
from shape_toolkit.io.mesh import _WRITERS, load_shape, save_shape

#: ``--remesh-iterations`` without a value
DEFAULT_REMESH_ITERATIONS = 3
#: the output formats with a binary variant (``--binary``); the others are always text
BINARY_FORMATS = (".ply", ".stl")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "clean",
        help="merge duplicates, drop degenerate faces, repair non-manifold parts, optionally "
        "keep the largest component and remesh",
    )
    p.add_argument("shape", help="input mesh or point-cloud file")
    p.add_argument("-o", "--output",
                   help="output file (OFF, PLY, OBJ, STL, XYZ; default SHAPE_STEM.clean.EXT in the current directory)")
    p.add_argument("--keep-largest", action="store_true", help="keep only the largest component")
    p.add_argument("--remesh", type=positive_float_arg, metavar="EDGE_LEN", default=None,
                   help="isotropic remeshing to this target edge length (file units)")
    p.add_argument("--remesh-iterations", default=None, metavar="N",
                   type=int_arg(f"an integer in [1, {MAX_REMESH_ITERATIONS}]", 1, MAX_REMESH_ITERATIONS),
                   help=f"remeshing iterations, with --remesh (default {DEFAULT_REMESH_ITERATIONS}, at most "
                        f"{MAX_REMESH_ITERATIONS})")
    p.add_argument("--no-repair", action="store_true", help="do not repair non-manifold parts")
    p.add_argument("--binary", action="store_true", help="write binary PLY/STL (other formats are text only)")
    p.add_argument("--map", metavar="NPY", default=None,
                   help="also save the new->old vertex map (int64, -1 = new vertex) to this .npy")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    ext = Path(args.shape).suffix.lower()
    args.output = str(default_output(args.output, args.shape, f"clean{ext if ext in _WRITERS else '.ply'}"))
    check_output_path(args.output, suffixes=tuple(sorted(_WRITERS)))
    check_applies("--remesh-iterations", args.remesh_iterations is not None, "remeshing", args.remesh is not None,
                  "; give --remesh EDGE_LEN too")
    check_applies("--binary", args.binary, "PLY and STL output", args.output.lower().endswith(BINARY_FORMATS),
                  f"; {args.output!r} is written as text")
    check_output_path(args.map, "--map", suffixes=(".npy",))
    check_distinct(args.output, args.shape)
    if args.map:
        check_distinct(args.map, args.shape, outputs=(args.output,))
    shape = load_shape(args.shape, duplicate_faces="keep")  # removing them is clean's job
    cleaned, report = clean_shape(
        shape,
        repair_non_manifold=not args.no_repair,
        keep_largest_component=args.keep_largest,
        remesh_target_edge=args.remesh,
        remesh_iterations=args.remesh_iterations or DEFAULT_REMESH_ITERATIONS,
    )
    save_shape(cleaned, args.output, binary=args.binary)
    if args.map:
        import numpy as np

        np.save(args.map, report.vertex_map)
    out = {"input": str(args.shape), "output": str(args.output), **report.to_dict()}
    if args.json:
        print_json(out)
    else:
        width = max(len(k) for k in out)
        for k, v in out.items():
            if k == "notes":
                v = "; ".join(v) if v else "-"
            print(f"{k.replace('_', ' '):<{width}}  {v}")
    return 0
