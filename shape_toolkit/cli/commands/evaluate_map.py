"""``shape-toolkit evaluate-map SRC DST MAP --truth-src A.vts --truth-dst B.vts``: normalized
geodesic error of a map against ground truth (Kim et al. 2011 protocol)."""

from __future__ import annotations

import argparse

import numpy as np

from shape_toolkit.cli.commands._common import print_json
from shape_toolkit.errors import ParameterError, ShapeFileError
from shape_toolkit.io.mesh import load_shape
from shape_toolkit.metrics.correspondence import (
    correspondence_report,
    geodesic_errors,
    paired_geodesic_distances,
    target_coverage,
)
from shape_toolkit.results.correspondence import load_map
from shape_toolkit.results.labels import read_vertex_ids


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("evaluate-map", help="geodesic error of a correspondence map")
    p.add_argument("source", help="source shape")
    p.add_argument("target", help="target shape")
    p.add_argument("map", help="map file: one 0-based target vertex per source vertex, -1 unmatched")
    p.add_argument("--truth-src", required=True, help="ground-truth source vertex ids (TOSCA .vts)")
    p.add_argument("--truth-dst", required=True, help="ground-truth target vertex ids, same length")
    p.add_argument("--truth-dst-sym", help="symmetric ground truth on the target (.sym.vts)")
    p.add_argument("--zero-based", action="store_true", help="truth files count from 0 (default: 1, .vts)")
    p.add_argument("--geodesics", default="heat", choices=["exact", "heat", "fmm", "dijkstra"],
                   help="geodesic distance method (default heat)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def _truth(path: str, n: int, one_based: bool):
    try:
        return read_vertex_ids(path, one_based=one_based, n_vertices=n)
    except ShapeFileError as exc:
        hint = " (use --zero-based for 0-based files)" if one_based and "1-based" in str(exc) else ""
        raise ShapeFileError(path, exc.problem + hint) from None


def run(args: argparse.Namespace) -> int:
    source = load_shape(args.source)
    target = load_shape(args.target)
    # The error is in units of sqrt(area): scale-free. Evaluate on coordinates divided by a power
    # of two near their magnitude (an exact rescaling), so 1e-300 or 1e300 coordinates neither
    # underflow nor overflow in the geodesic solvers (they did: NaN heat-method matrices).
    target = target.with_vertices(target.vertices / target.scale)
    corr = load_map(args.map, source.n_vertices, target.n_vertices)
    if corr.n_matched == 0:
        raise ParameterError(f"{args.map}: the map matches no vertex (all -1)")
    one = not args.zero_based
    ts = _truth(args.truth_src, source.n_vertices, one)
    td = _truth(args.truth_dst, target.n_vertices, one)
    if ts.size != td.size:
        raise ShapeFileError(
            args.truth_dst,
            f"has {td.size} ids but {args.truth_src} has {ts.size}: the truth files must pair up",
        )
    sym = None
    if args.truth_dst_sym:
        sym = _truth(args.truth_dst_sym, target.n_vertices, one)
        if sym.size != td.size:
            raise ShapeFileError(args.truth_dst_sym, f"has {sym.size} ids, expected {td.size}")
    if sym is None:
        err = geodesic_errors(target, corr, ts, td, method=args.geodesics)
        result = correspondence_report(err)
    else:  # one pass of distance rows from the predicted vertices serves both truths
        pred = corr.target_of[ts]
        ok = pred >= 0
        both = np.full((ts.size, 2), np.inf)
        both[ok] = paired_geodesic_distances(
            target, pred[ok], np.column_stack([td[ok], sym[ok]]), method=args.geodesics
        ) / np.sqrt(target.area)
        result = correspondence_report(both[:, 0])
        rs = correspondence_report(both.min(axis=1))
        result["symmetric"] = {"mean_geodesic_error": rs["mean_geodesic_error"], "curve": rs["curve"]}
    result["coverage"] = target_coverage(corr)
    result["n_matched"] = corr.n_matched
    result["geodesics"] = args.geodesics
    if args.json:
        print_json(result)
    else:
        print(f"mean geodesic error {result['mean_geodesic_error']:.4f} (sqrt-area units, lower is better), "
              f"{100 * result['within_0.05']:.1f}% within 0.05, coverage {result['coverage']:.3f}")
        if "symmetric" in result:
            print(f"symmetric-aware mean geodesic error {result['symmetric']['mean_geodesic_error']:.4f} "
                  "(the better of the truth and its mirror, per point)")
    return 0
