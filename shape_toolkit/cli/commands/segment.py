"""``shape-toolkit segment MESH [--method NAME]``: one label per vertex (or per face, PSB ``.seg``)."""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from shape_toolkit.api.registry import create_seeded
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
    positive_int_arg,
    proxy_arg,
    random_state_arg,
    status,
    write_ply,
)
from shape_toolkit.data.datasets import write_labels
from shape_toolkit.errors import (
    DisconnectedGraphError,
    MeshRequiredError,
    NumericallyDisconnectedGraphError,
    ParameterError,
)
from shape_toolkit.io.mesh import load_shape
from shape_toolkit.plugins.matching.multires import PROXY_VERTICES
from shape_toolkit.results.labels import load_constraints

#: the segmenter of ``segment`` without ``--method``: the least Rand index error of the unsupervised methods
#: on the held-out PSB categories (README, benchmarks/results/psb_segmentation.md)
DEFAULT_METHOD = "ncut"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("segment", help="segment a shape with a segmenter plugin")
    p.add_argument("shape", help="mesh or point-cloud file")
    p.add_argument("--method", default=DEFAULT_METHOD,
                   help=f"segmenter plugin (default {DEFAULT_METHOD}, the best unsupervised one on PSB; it needs -k; "
                   "eigvec-gmm, csc, ...)")
    p.add_argument("-k", "--n-segments", type=positive_int_arg, default=None,
                   help="number of segments (default: the method chooses, where it can)")
    p.add_argument("--constraints", help='JSON file {"must_link": [[i, j], ...], "cannot_link": [...]}')
    p.add_argument("--random-state", type=random_state_arg, default=None, help="seed of k-means / GMM (default 0)")
    p.add_argument("--preset", default=None, help="named parameter preset of the method")
    p.add_argument("--param", action="append", metavar="KEY=VALUE", help="method parameter")
    p.add_argument("--proxy", type=proxy_arg, default=PROXY_VERTICES, metavar="N",
                   help=f"shapes (meshes and point clouds) above 1.5 N vertices are segmented through a proxy of N "
                        f"vertices and the labels carried to every vertex (N >= 100; default {PROXY_VERTICES}, as "
                        "match; 0: always at full resolution)")
    p.add_argument("-o", "--output", help="labels file (default: SHAPE_STEM.METHOD.labels.txt, "
                   "or .seg with --faces)")
    p.add_argument("--faces", action="store_true",
                   help="write one label per face (the method's own face labels where it segments faces, "
                   "else the majority of the face's vertices), PSB .seg format")
    add_ply(p, "the segments (one colour per label)")
    p.add_argument("--json", action="store_true", help="print JSON")
    add_memory_limit(p)
    add_quiet(p)
    p.set_defaults(func=run)


def _diagnostics(seg: Any) -> dict[str, Any]:
    out = {}
    for name, value in vars(seg).items():
        if name.endswith("_") and not name.startswith("_"):
            out[name] = value.tolist() if isinstance(value, np.ndarray) else value
    return out


#: segmenters of points (no faces needed), named when a segmenter of faces is given a point cloud
CLOUD_METHODS = ("spectral-clustering", "eigvec-gmm")


@contextmanager
def _cloud_hint(shape: Any, method: str) -> Iterator[None]:
    """A point cloud refused by a segmenter that needs faces: the error names the cloud the user gave (not the
    proxy it was segmented through) and the methods that take points."""
    try:
        yield
    except MeshRequiredError as exc:
        if shape.is_mesh:
            raise
        raise MeshRequiredError(f"{method!r} needs a triangle mesh, but {shape!r} has no faces; segment a point cloud "
                                f"with --method {' or '.join(CLOUD_METHODS)}") from exc


def run(args: argparse.Namespace) -> int:
    params = parse_params(args.param, plugin_class("segmenters", args.method))
    out = Path(args.output) if args.output else Path(
        f"{Path(args.shape).stem}.{args.method}.{'seg' if args.faces else 'labels.txt'}"
    )
    check_output_path(out)
    check_distinct(out, args.shape, args.constraints)
    check_ply(args.ply, args.shape, args.constraints, output=str(out))
    if args.n_segments is not None:
        params["n_segments"] = args.n_segments
    if args.random_state is not None:  # the flag wins over --param random_state=...
        params.pop("random_state", None)
    # the seed goes to the segmenters that have randomness (k-means, GMM), not to deterministic ones (ncut)
    seg = create_seeded("segmenters", args.method, args.preset, args.random_state, **params)
    if args.constraints is not None and hasattr(seg, "accepts_constraints") and not seg.accepts_constraints():
        from shape_toolkit.api.registry import plugins_taking_constraints

        raise ParameterError(  # before any work; Segmenter.check_constraints says the same from Python
            f"--constraints: {args.method!r} takes no constraints (it is unsupervised) and would ignore them; "
            f"drop them or use a segmenter that uses them: {', '.join(plugins_taking_constraints())}"
        )
    if seg.lacks_n_segments():  # before reading the file: the method would refuse any shape
        raise ParameterError(f"{args.method!r} needs the number of segments: add -k N (an integer >= 2)")
    from shape_toolkit.plugins.segmenters.multires import segment_memory

    check_memory(args, [args.shape], lambda n: segment_memory(n, args.proxy),
                 f"segmenting it ({args.method}{'' if args.proxy else ', at full resolution: --proxy 0'})",
                 "scale_1m.md and memory_models.md" if args.proxy else "memory_models.md")
    shape = load_shape(args.shape)
    if args.faces:
        shape.require_faces("--faces")
    constraints = None
    if args.constraints:
        constraints = load_constraints(args.constraints, shape.n_vertices)
    t0 = time.perf_counter()
    through_proxy = bool(args.proxy) and shape.n_vertices > 1.5 * args.proxy
    with status(args, f"segment: {args.method} on {shape.n_vertices} vertices") as st, _cloud_hint(shape, args.method):
        if through_proxy:
            from shape_toolkit.plugins.segmenters.multires import segment_through_proxy

            st.update(f"segment: {args.method} through a proxy of {args.proxy} vertices")
            result = segment_through_proxy(seg, shape, proxy=args.proxy, constraints=constraints)
            used = []
        else:
            try:
                spectra, used = declared_spectra(seg, shape)
            except DisconnectedGraphError as exc:
                if isinstance(exc, NumericallyDisconnectedGraphError):  # one piece: splitting would not help
                    raise
                # a shape in several pieces: no spectrum of the whole (it would mix them); the segmenter either
                # segments it piece by piece with their own spectra, or raises this error itself
                spectra, used = None, []
            st.update(f"segment: {args.method}")
            result = seg.segment(shape, spectrum=spectra, constraints=constraints)
    elapsed = time.perf_counter() - t0
    labels = result.labels
    written = result.face_labels if args.faces else labels  # a segmenter of faces: its own face labels
    write_labels(out, written)
    from shape_toolkit.viz import label_colors

    ply = write_ply(args.ply, shape, label_colors(labels))
    result = {
        "labels_file": str(out),
        "ply": ply,
        "n_segments": int(len(np.unique(labels))),
        "method": args.method,
        "params": seg.get_params(deep=False),
        "spectra": used,
        # through a proxy the fitted attributes are the proxy's (cut_labels_, sdf_: one per proxy face): kept with it
        "proxy": {**result.info["proxy"], "diagnostics": _diagnostics(seg)} if through_proxy else None,
        "per": "face" if args.faces else "vertex",
        "n_vertices": shape.n_vertices,
        "n_faces": shape.n_faces,
        "n_constraints": {"must_link": constraints.n_must, "cannot_link": constraints.n_cannot}
        if constraints is not None else None,
        "segment_sizes": np.bincount(labels).tolist(),
        "info": result.info,
        "diagnostics": {} if through_proxy else _diagnostics(seg),
        "seconds": round(elapsed, 3),
    }
    return emit(args, result, f"{shape!r}: {result['n_segments']} segments by {args.method} -> {out} "
                f"({result['per']} labels, {elapsed:.2f} s)")
