"""``shape-toolkit constraints MESH LABELS [--faces] [-o cons.json]``: the must-link and cannot-link
clicks a person would give for a known segmentation, drawn with the PSB benchmark's protocol
(:func:`shape_toolkit.results.labels.clicks_from_segmentation`), written as the JSON that
``segment --constraints`` reads. Default output: ``MESH_STEM.constraints.json`` in the current
directory."""

from __future__ import annotations

import argparse

import numpy as np

from shape_toolkit.cli.commands._common import (
    check_distinct,
    check_output_path,
    count_arg,
    default_output,
    emit,
    number_arg,
    positive_int_arg,
    random_state_arg,
    read_labels_as_given,
)
from shape_toolkit.errors import ParameterError
from shape_toolkit.io.mesh import load_shape
from shape_toolkit.results.labels import clicks_from_segmentation, save_constraints
from shape_toolkit.validation import shown_value

#: cannot-links drawn across each boundary between two segments when ``--cannot-per-boundary`` is not given
DEFAULT_CANNOT_PER_BOUNDARY = 3


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("constraints", help="draw must-link / cannot-link clicks from a known segmentation "
                                           "(the PSB benchmark's protocol)")
    p.add_argument("shape", help="mesh file")
    p.add_argument("labels", help="one integer label per vertex, or per face with --faces (PSB .seg)")
    p.add_argument("--faces", action="store_true", help="the labels are per face")
    p.add_argument("-o", "--output", help="constraints JSON (default MESH_STEM.constraints.json)")
    p.add_argument("--must-per-segment", type=positive_int_arg, default=1,
                   help="must-links per segment, chained between random vertices inside it (default 1)")
    p.add_argument("--cannot-per-boundary", type=count_arg, default=None,
                   help=f"cannot-links across each boundary between two segments (default {DEFAULT_CANNOT_PER_BOUNDARY}"
                   ", or the mesh's edge count when it has fewer; 0: none; at most the mesh's edge count)")
    p.add_argument("--cannot-offset", type=count_arg, default=8,
                   help="edges each cannot-link end lies inside its segment (default 8)")
    p.add_argument("--min-segment-fraction", type=number_arg("a fraction in [0, 1]", 0.0, 1.0), default=0.01,
                   help="segments with fewer vertices than this fraction get no click (default 0.01)")
    p.add_argument("--random-state", type=random_state_arg, default=0, help="seed of the draw (default 0)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    out = default_output(args.output, args.shape, "constraints.json")
    check_output_path(out, suffixes=(".json",))
    check_distinct(out, args.shape, args.labels)
    shape = load_shape(args.shape)
    shape.require_faces("constraints")
    labels = read_labels_as_given(args.labels, shape, args.faces, "LABELS")
    n_edges = len(shape.edges)
    if args.cannot_per_boundary is None:  # the default, on a mesh of fewer edges: as many as there are
        args.cannot_per_boundary = min(DEFAULT_CANNOT_PER_BOUNDARY, n_edges)
    if args.cannot_per_boundary > n_edges:  # a boundary has fewer cut edges: they would repeat (1e9 ran for hours)
        raise ParameterError(f"--cannot-per-boundary {shown_value(args.cannot_per_boundary)}: more than the mesh's "
                             f"{n_edges} edges, so the links across a boundary would repeat; give at most {n_edges}")
    try:
        cons = clicks_from_segmentation(
            shape, labels, n_must_per_segment=args.must_per_segment, n_cannot_per_boundary=args.cannot_per_boundary,
            cannot_offset=args.cannot_offset, min_segment_fraction=args.min_segment_fraction, faces=args.faces,
            random_state=args.random_state)
    except ParameterError as exc:
        raise ParameterError(f"{args.labels}: {exc}") from None
    save_constraints(out, cons)
    n_segments = int(len(np.unique(labels)))
    result = {"constraints_file": str(out), "must_link": cons.n_must, "cannot_link": cons.n_cannot,
              "n_segments_in_labels": n_segments, "per": "face" if args.faces else "vertex",
              "random_state": args.random_state}
    return emit(args, result, f"{shape!r}: {cons.n_must} must-links, {cons.n_cannot} cannot-links from "
                f"{n_segments} segments -> {out}")
