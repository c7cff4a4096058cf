"""``shape-toolkit evaluate-map SRC DST MAP``: quality of a correspondence map.

* ``--truth-src A.vts --truth-dst B.vts``: normalized geodesic error against ground truth (Kim et al.
  2011 protocol), its cumulative curve, and with ``--truth-dst-sym`` the symmetric-aware error.
* ``--r-smoothness [R ...]``: thesis Table 7.2, the percent of r-smooth source vertices (eq. 7.4-7.5)
  for neighbourhoods of R percent of the vertices (default the thesis's 0.1 ... 0.8), no ground
  truth needed.
* ``--labels SRC_LABELS TGT_LABELS``: thesis Table 7.3, mean recall and precision of the source's
  segmentation carried through the map onto the target's (per face with ``--faces``).

Geodesic computations show their progress on a terminal and stop, with one line and exit 2, past
``--time-limit`` seconds (exact geodesics take about a second per ground-truth point on 5k meshes).
"""

from __future__ import annotations

import argparse

import numpy as np

from shape_toolkit.cli.commands._common import (
    add_memory_limit,
    add_quiet,
    add_time_limit,
    check_applies,
    check_memory,
    number_arg,
    positive_int_arg,
    print_json,
    random_state_arg,
    read_labels_arg,
    status,
    time_limit_hint,
)
from shape_toolkit.errors import ParameterError, ShapeFileError, TimeLimitError
from shape_toolkit.io.mesh import load_shape
from shape_toolkit.metrics.correspondence import (
    R_SMOOTH_RS,
    correspondence_report,
    error_normalization,
    geodesic_errors,
    map_label_scores,
    paired_geodesic_distances,
    r_smoothness_table,
    target_coverage,
)
from shape_toolkit.results.correspondence import load_map
from shape_toolkit.results.labels import read_vertex_ids, vertex_ids_within

#: geodesics of the r-neighbourhoods: Dijkstra along edges ranks the nearest vertices like the
#: surface distance does, and explores only a small disc around each vertex
R_SMOOTH_GEODESICS = "dijkstra"


def evaluate_map_memory(n_source: int, n_target: int, method: str, n_truth: int,
                        r_smoothness: tuple[float, ...] | None = None, r_sample: int | None = None) -> float:
    """Estimated peak bytes of ``shape-toolkit evaluate-map`` on shapes of ``n_source`` and ``n_target`` vertices: the
    geodesic error's rows on the target from ``n_truth`` points by ``method`` (none when 0;
    :func:`~shape_toolkit.features.geodesics.geodesic_memory`), or r-smoothness for the neighbourhood sizes
    ``r_smoothness`` (percent; None: not asked) on ``r_sample`` source vertices (None: all), whichever is more. An
    estimate for refusing shapes before reading them (``--memory-limit``), not a bound."""
    from shape_toolkit.features.geodesics import (
        GEODESIC_MEMORY,
        NEAREST_CHUNK,
        PAIRED_CHUNK,
        geodesic_memory,
        relative_neighbourhood_size,
    )
    from shape_toolkit.metrics.correspondence import R_SMOOTH_BLOCK_VALUES

    need = [0.0]
    if n_truth:
        need.append(geodesic_memory(n_target, min(PAIRED_CHUNK, n_truth), method))
    if r_smoothness:  # both shapes' Dijkstra graphs, float64 rows and a mask on the larger, two neighbourhood blocks
        a, b = GEODESIC_MEMORY["dijkstra"]
        n = max(n_source, n_target)
        count = relative_neighbourhood_size(max(r_smoothness), max(n, 1))
        block = min(R_SMOOTH_BLOCK_VALUES, min(r_sample or n_source, n_source) * count)
        need.append(a + b * (n_source + n_target) + 2 * 8 * NEAREST_CHUNK * n + 2 * 8 * block)
    return max(need)


#: ``--geodesics`` and ``--r-theta`` when not given
DEFAULT_GEODESICS = "heat"
DEFAULT_R_THETA = 0.9

_percent_arg = number_arg("a percent of the vertices in (0, 100]", 0.0, 100.0, open_low=True)
_theta_arg = number_arg("a fraction in (0, 1]", 0.0, 1.0, open_low=True)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "evaluate-map",
        help="geodesic error, r-smoothness and label transfer of a correspondence map",
        description="Evaluate a map (one 0-based target vertex per source vertex, -1 unmatched) by its "
        "geodesic error against ground truth, its r-smoothness (thesis Table 7.2) and the recall and "
        "precision of a segmentation carried through it (Table 7.3). Give at least one of them.",
    )
    p.add_argument("source", help="source shape")
    p.add_argument("target", help="target shape")
    p.add_argument("map", help="map file: one 0-based target vertex per source vertex, -1 unmatched")
    p.add_argument("--truth-src", help="ground-truth source vertex ids (TOSCA .vts)")
    p.add_argument("--truth-dst", help="ground-truth target vertex ids, same length")
    p.add_argument("--truth-dst-sym", help="symmetric ground truth on the target (.sym.vts)")
    p.add_argument("--zero-based", action="store_true", help="truth files count from 0 (default: 1, .vts)")
    p.add_argument("--geodesics", default=None, choices=["exact", "heat", "fmm", "dijkstra"],
                   help=f"geodesic distance method of the error against the truth (default {DEFAULT_GEODESICS})")
    add_time_limit(p, "; exact geodesics take about 1 s per ground-truth point on a 5,000-vertex mesh")
    p.add_argument("--r-smoothness", nargs="*", type=_percent_arg, metavar="R",
                   help="percent of r-smooth source vertices (thesis eq. 7.4-7.5, Table 7.2) for "
                   "neighbourhoods of R percent of the vertices (no R: "
                   f"{' '.join(f'{r:g}' for r in R_SMOOTH_RS)}, the thesis's)")
    p.add_argument("--r-theta", type=_theta_arg, default=None,
                   help=f"with --r-smoothness: fraction of a neighbourhood that must land in the image's neighbourhood "
                   f"(default {DEFAULT_R_THETA:g})")
    p.add_argument("--r-sample", type=positive_int_arg, default=None, metavar="N",
                   help="evaluate r-smoothness on N random source vertices (default: all of them)")
    p.add_argument("--random-state", type=random_state_arg, default=None, help="seed of --r-sample (default 0)")
    p.add_argument("--labels", nargs=2, metavar=("SRC_LABELS", "TGT_LABELS"),
                   help="segmentations of both shapes (same label = same part): mean recall and precision "
                   "of the source's labels carried onto the target through the map (Table 7.3)")
    p.add_argument("--faces", action="store_true", help="--labels files hold one label per face (PSB .seg)")
    p.add_argument("--json", action="store_true", help="print JSON")
    add_memory_limit(p)
    add_quiet(p)
    p.set_defaults(func=run)


def _truth(path: str, one_based: bool) -> np.ndarray:
    try:
        return read_vertex_ids(path, one_based=one_based)
    except ShapeFileError as exc:
        hint = " (use --zero-based for 0-based files)" if one_based and "1-based" in str(exc) else ""
        raise ShapeFileError(path, exc.problem + hint) from None


def _check_args(args: argparse.Namespace) -> None:
    if (args.truth_src is None) != (args.truth_dst is None):
        raise ParameterError("--truth-src and --truth-dst go together")
    check_applies("--truth-dst-sym", args.truth_dst_sym, "--truth-src and --truth-dst", args.truth_src is not None,
                  ", not given here: it would be ignored")
    check_applies("--faces", args.faces, "--labels files", args.labels, "; give --labels SRC_LABELS TGT_LABELS")
    if args.truth_src is None and args.r_smoothness is None and not args.labels:
        raise ParameterError(
            "nothing to evaluate: give --truth-src/--truth-dst (geodesic error), --r-smoothness or --labels"
        )
    truth, smooth = args.truth_src is not None, args.r_smoothness is not None
    for given, option, needs, has in (  # an option of an evaluation not asked for would be ignored
        (args.zero_based, "--zero-based", "--truth-src and --truth-dst", truth),
        (args.geodesics is not None, "--geodesics", "--truth-src and --truth-dst", truth),
        (args.r_theta is not None, "--r-theta", "--r-smoothness", smooth),
        (args.r_sample is not None, "--r-sample", "--r-smoothness", smooth),
        (args.random_state is not None, "--random-state", "--r-sample", args.r_sample is not None),
    ):
        check_applies(option, given, needs, has, ", not given here: it would be ignored")


def _read_truths(args: argparse.Namespace) -> tuple[np.ndarray, ...] | None:
    """The truth files' ids (0-based), read before the shapes (the memory estimate counts them): source, target and,
    with ``--truth-dst-sym``, the symmetric target; None without ``--truth-src``."""
    if args.truth_src is None:
        return None
    one = not args.zero_based
    return tuple(_truth(p, one) for p in (args.truth_src, args.truth_dst, args.truth_dst_sym) if p)


def _geodesic_error(args, source, target, corr, st, truths: tuple[np.ndarray, ...]) -> dict:
    one = not args.zero_based
    ts = vertex_ids_within(truths[0], args.truth_src, source.n_vertices, one_based=one)
    td = vertex_ids_within(truths[1], args.truth_dst, target.n_vertices, one_based=one)
    if ts.size != td.size:
        raise ShapeFileError(
            args.truth_dst,
            f"has {td.size} ids but {args.truth_src} has {ts.size}: the truth files must pair up",
        )
    sym = None
    if args.truth_dst_sym:
        sym = vertex_ids_within(truths[2], args.truth_dst_sym, target.n_vertices, one_based=one)
        if sym.size != td.size:
            raise ShapeFileError(args.truth_dst_sym, f"has {sym.size} ids, expected {td.size}")
    st.update(f"evaluate-map: {args.geodesics} geodesics from the predicted images")
    try:
        if sym is None:
            err = geodesic_errors(target, corr, ts, td, method=args.geodesics, time_limit=args.time_limit,
                                  progress=st.count)
            result = correspondence_report(err)
        else:  # one pass of distance rows from the predicted vertices serves both truths
            pred = corr.target_of[ts]
            ok = pred >= 0
            both = np.full((ts.size, 2), np.inf)
            unit = error_normalization(target)
            both[ok] = paired_geodesic_distances(
                target, pred[ok], np.column_stack([td[ok], sym[ok]]), method=args.geodesics,
                time_limit=args.time_limit, progress=st.count,
            ) / unit
            result = correspondence_report(both[:, 0])
            rs = correspondence_report(both.min(axis=1))
            result["symmetric"] = {"mean_geodesic_error": rs["mean_geodesic_error"], "curve": rs["curve"]}
    except TimeLimitError as exc:
        raise time_limit_hint(exc, args) from None
    if result["matched_fraction"] == 0:  # the library's NaN mean (a benchmark row's "no value"): refuse
        raise ParameterError(
            f"no ground-truth pair has an error: the map leaves all {ts.size} truth source vertices unmatched "
            "(-1) or sends them where the true target vertex cannot be reached (another connected component), "
            "so the mean geodesic error is undefined"
        )
    result["geodesics"] = args.geodesics
    return result


def run(args: argparse.Namespace) -> int:
    _check_args(args)
    args.geodesics = args.geodesics or DEFAULT_GEODESICS
    args.r_theta = DEFAULT_R_THETA if args.r_theta is None else args.r_theta
    args.random_state = 0 if args.random_state is None else args.random_state
    truths = _read_truths(args)
    n_truth = truths[0].size if truths else 0
    rs = None if args.r_smoothness is None else (tuple(args.r_smoothness) or R_SMOOTH_RS)
    work = " and ".join(([f"{args.geodesics} geodesics from {n_truth} truth points"] if n_truth else [])
                        + (["r-smoothness"] if args.r_smoothness is not None else []))
    check_memory(args, [args.source, args.target],
                 lambda c: evaluate_map_memory(c[0], c[1], args.geodesics, n_truth, rs, args.r_sample),
                 f"evaluating the map ({work})" if work else "evaluating the map", "memory_models.md",
                 "fewer truth points" if n_truth else "", by_shape=True)
    source = load_shape(args.source)
    target = load_shape(args.target)
    # Every score is scale-free (errors in units of sqrt(area), neighbourhoods by vertex counts).
    # Evaluate on coordinates divided by a power of two near their magnitude (an exact rescaling),
    # so coordinates near the extremes a Shape takes (1e-150, 1e150) neither underflow nor overflow in
    # the geodesic solvers (1e300 ones did: NaN heat-method matrices; such shapes are now refused on load).
    target = target.with_vertices(target.vertices / target.scale)
    source = source.with_vertices(source.vertices / source.scale)
    corr = load_map(args.map, source.n_vertices, target.n_vertices)
    if corr.n_matched == 0:
        raise ParameterError(f"{args.map}: the map matches no vertex (all -1)")
    labels = None
    if args.labels:
        labels = (read_labels_arg(args.labels[0], source, args.faces, "SRC_LABELS"),
                  read_labels_arg(args.labels[1], target, args.faces, "TGT_LABELS"))
        if not np.any(labels[1] >= 0):
            raise ShapeFileError(args.labels[1], "has no label >= 0 (negative labels mean unlabelled)")
    result: dict = {}
    with status(args, "evaluate-map") as st:
        if args.truth_src is not None:
            result.update(_geodesic_error(args, source, target, corr, st, truths))
        if rs is not None:
            st.update("evaluate-map: r-smoothness (geodesic neighbourhoods on both shapes)")
            try:
                table = r_smoothness_table(
                    source, target, corr, rs, args.r_theta, sample=args.r_sample,
                    method=R_SMOOTH_GEODESICS, random_state=args.random_state,
                    time_limit=args.time_limit, progress=st.count,
                )
            except TimeLimitError as exc:
                raise time_limit_hint(exc, args) from None
            result["r_smoothness"] = {
                "theta": args.r_theta,
                "n_evaluated": min(args.r_sample or source.n_vertices, source.n_vertices),
                "geodesics": R_SMOOTH_GEODESICS,
                "table": [[r, pct] for r, pct in table.items()],
            }
        if labels is not None:
            st.update("evaluate-map: label transfer")
            s = map_label_scores(corr, labels[0], labels[1], target)
            result["labels"] = {
                "recall": s["recall"], "precision": s["precision"], "filled": s["filled"],
                "n_labels": len(s["labels"]), "per": "face" if args.faces else "vertex",
            }
    result["coverage"] = target_coverage(corr)
    result["n_matched"] = corr.n_matched
    if args.json:
        print_json(result)
        return 0
    if "mean_geodesic_error" in result:
        print(f"mean geodesic error {result['mean_geodesic_error']:.4f} (sqrt-area units, lower is better), "
              f"{100 * result['within_0.05']:.1f}% within 0.05, coverage {result['coverage']:.3f}")
        if "symmetric" in result:
            print(f"symmetric-aware mean geodesic error {result['symmetric']['mean_geodesic_error']:.4f} "
                  "(the better of the truth and its mirror, per point)")
    else:
        print(f"coverage {result['coverage']:.3f} ({corr.n_matched}/{corr.n_source} source vertices matched)")
    if "r_smoothness" in result:
        r = result["r_smoothness"]
        cells = "  ".join(f"r={a:g}%: {b:.2f}" for a, b in r["table"])
        print(f"r-smooth vertices in percent (theta {r['theta']:g}, {r['n_evaluated']} source vertices, "
              f"higher is smoother): {cells}")
    if "labels" in result:
        lab = result["labels"]
        print(f"label transfer over {lab['n_labels']} labels: mean recall {lab['recall']:.4f}  "
              f"mean precision {lab['precision']:.4f} (higher is better; {100 * lab['filled']:.1f}% of the "
              "target reached by no source vertex took its nearest neighbour's label)")
    return 0
