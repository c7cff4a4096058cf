"""``shape-toolkit keypoints MESH --detector NAME [--preset P] [--param K=V ...] [--json]``."""

from __future__ import annotations

import argparse
import time

import numpy as np

from shape_toolkit.api.registry import create_plugin
from shape_toolkit.cli.commands._common import (
    add_memory_limit,
    add_ply,
    add_quiet,
    check_distinct,
    check_memory,
    check_output_path,
    check_ply,
    declared_spectra,
    emit,
    parse_params,
    plugin_class,
    status,
    write_ply,
)
from shape_toolkit.errors import ParameterError
from shape_toolkit.io.mesh import load_shape


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("keypoints", help="detect keypoints (0-based vertex ids)")
    p.add_argument("shape", help="mesh or point-cloud file")
    p.add_argument("--detector", default="adf-maxima", help="keypoint plugin (default adf-maxima)")
    p.add_argument("--preset", default=None, help="named parameter set, e.g. sparse or dense")
    p.add_argument("--param", action="append", metavar="KEY=VALUE",
                   help="detector parameter (repeatable), overrides the preset")
    p.add_argument("-o", "--output", help="also write the ids, one per line, to this file")
    add_ply(p, "the keypoints (red spots on a grey shape)")
    p.add_argument("--json", action="store_true", help="print JSON")
    add_memory_limit(p)
    add_quiet(p)
    p.set_defaults(func=run)


def keypoint_colors(shape, ids: np.ndarray, radius: float = 0.015) -> np.ndarray:
    """RGB ``(n, 3)``: grey shape, red discs of ``radius`` (fraction of the bounding-box diagonal)
    around the keypoint vertices ``ids``, so they show on a per-vertex coloured mesh."""
    from scipy.spatial import cKDTree

    cols = np.tile([0.78, 0.78, 0.78], (shape.n_vertices, 1))
    if len(ids):
        near = cKDTree(shape.vertices).query_ball_point(shape.vertices[ids], radius * shape.diagonal)
        hit = np.unique(np.concatenate([np.asarray(x, dtype=np.int64) for x in near] + [ids]))
        cols[hit] = [0.85, 0.1, 0.1]
    return cols


def run(args: argparse.Namespace) -> int:
    check_output_path(args.output)
    if args.output:
        check_distinct(args.output, args.shape)
    check_ply(args.ply, args.shape, output=args.output)
    params = parse_params(args.param, plugin_class("keypoints", args.detector))
    detector = create_plugin("keypoints", args.detector, preset=args.preset, **params)
    from shape_toolkit.core.spectrum import spectrum_memory
    from shape_toolkit.spectra import declared_specs

    k = max((spec.k for spec in declared_specs(detector)), default=0)  # the spectrum is most of its memory
    check_memory(args, [args.shape], lambda n: spectrum_memory(n, k),
                 f"detecting keypoints ({args.detector}, a spectrum of {k} eigenpairs)", "memory_models.md")
    shape = load_shape(args.shape)
    start = time.perf_counter()
    with status(args, f"keypoints: {args.detector} on {shape.n_vertices} vertices"):
        spectra, used = declared_spectra(detector, shape)
        ids = np.asarray(detector.detect(shape, spectrum=spectra), dtype=np.int64)
    seconds = time.perf_counter() - start
    if ids.ndim != 1 or (ids.size and (ids.min() < 0 or ids.max() >= shape.n_vertices)):
        raise ParameterError(f"detector {args.detector!r} returned invalid vertex ids")
    if args.output:
        np.savetxt(args.output, ids, fmt="%d")
    ply = write_ply(args.ply, shape, keypoint_colors(shape, ids))
    result = {
        "output": args.output,
        "ply": ply,
        "keypoints": ids.tolist(),
        "detector": args.detector,
        "preset": args.preset,
        "params": detector.get_params(deep=False),
        "spectra": used,
        "n_keypoints": int(ids.size),
        "n_vertices": shape.n_vertices,
        "seconds": round(seconds, 4),
    }
    return emit(args, result, f"{shape!r}: {ids.size} keypoints ({args.detector}"
                f"{', preset ' + args.preset if args.preset else ''})", " ".join(str(i) for i in ids))
