"""``shape-toolkit spectrum MESH -k K``: Laplacian eigenvalues (and vectors to an .npz)."""

from __future__ import annotations

import argparse
import math

import numpy as np

from shape_toolkit.cli.commands._common import (
    add_memory_limit,
    add_ply,
    add_quiet,
    check_memory,
    check_output_path,
    check_ply,
    parse_params,
    plugin_class,
    positive_float_arg,
    positive_int_arg,
    print_json,
    status,
    write_ply,
)
from shape_toolkit.core.graph import KNN_NEIGHBORS, check_graph_memory
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import LAPLACIANS, compute_spectrum, spectrum_memory
from shape_toolkit.errors import ParameterError
from shape_toolkit.io.mesh import load_shape
from shape_toolkit.spectra import build_graph, point_cloud_weighting

#: weighting parameters that are also build_graph's keywords (intrinsic-delaunay's n_neighbors), and their options
_GRAPH_OPTIONS = {"n_neighbors": "--neighbors"}
#: how check_graph_memory's messages name build_graph's arguments here: the options
_CLI_NAMES = {"radius": "--radius", "n_neighbors": "--neighbors", "memory_limit": "--memory-limit"}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("spectrum", help="smallest Laplacian eigenpairs of a shape")
    p.add_argument("shape", help="mesh or point-cloud file")
    p.add_argument("-k", type=int, default=20, help="number of eigenpairs (default 20)")
    p.add_argument("--weighting", default="cotangent", help="weighting plugin (default cotangent)")
    p.add_argument("--laplacian", default="combinatorial", choices=LAPLACIANS)
    p.add_argument("--no-mass", action="store_true", help="ignore the weighting's mass matrix")
    p.add_argument("--connectivity", default="auto", choices=["auto", "mesh", "knn", "epsilon"])
    p.add_argument("--neighbors", type=positive_int_arg, default=None,
                   help=f"k of the kNN graph (point clouds; default {KNN_NEIGHBORS}, or the weighting's own where it "
                   "triangulates the cloud: intrinsic-delaunay's 30)")
    p.add_argument("--radius", type=positive_float_arg, default=None, help="radius of the epsilon graph")
    p.add_argument("--param", action="append", metavar="KEY=VALUE", help="weighting parameter")
    p.add_argument("--largest-component", action="store_true",
                   help="analyse the largest connected component instead of refusing")
    p.add_argument("--sign-fix", action="store_true", help="deterministic eigenvector signs")
    p.add_argument("-o", "--output", help="write eigenvalues and eigenvectors to this .npz")
    add_ply(p, "one eigenvector (blue negative, white zero, red positive)")
    p.add_argument("--eigenvector", type=int, default=1, metavar="I",
                   help="0-based index of the eigenvector written by --ply (default 1: the Fiedler vector)")
    p.add_argument("--json", action="store_true", help="print JSON")
    add_memory_limit(p)
    add_quiet(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    check_output_path(args.output, suffixes=(".npz",))
    check_ply(args.ply, args.shape, output=args.output)
    if args.ply and not 0 <= args.eigenvector < args.k:
        raise ParameterError(f"--eigenvector {args.eigenvector}: must be in [0, {args.k - 1}] (-k {args.k})")
    params = parse_params(args.param, plugin_class("weightings", args.weighting))
    for key, option in _GRAPH_OPTIONS.items():
        if key in params:  # build_graph's own keyword: passed on it would collide (a TypeError)
            raise ParameterError(f"--param {key}: give it as {option} N (the graph's kNN size, which also sets the "
                                 f"{args.weighting} weighting's {key} where it triangulates a point cloud)")
    check_memory(args, [args.shape], lambda n: spectrum_memory(n, args.k), f"computing {args.k} eigenpairs (-k)",
                 "memory_models.md")
    shape = load_shape(args.shape)
    # a weighting that needs faces takes its point-cloud counterpart on a cloud, as match's spectra do
    weighting = args.weighting if shape.is_mesh else point_cloud_weighting(args.weighting)
    if weighting != args.weighting and params:
        raise ParameterError(f"--param applies to {args.weighting}, which needs faces; on this point cloud the "
                             f"weighting is {weighting}: give --weighting {weighting} with its parameters")
    _check_graph_memory(args, shape, weighting)
    with status(args, f"spectrum: {args.k} eigenpairs of {shape.n_vertices} vertices"):
        graph = build_graph(
            shape, weighting, connectivity=args.connectivity, n_neighbors=args.neighbors,
            radius=args.radius, memory_limit=math.inf, **params,  # checked above, with the spectrum's memory
        )
        spec = compute_spectrum(
            graph, args.k, laplacian=args.laplacian, use_mass=False if args.no_mass else None,
            sign_fix=args.sign_fix or bool(args.ply),
            components="largest" if args.largest_component else "raise",
        )
    ply = None
    if args.ply:
        from shape_toolkit.viz import eigenvector_colors

        # with --largest-component the other vertices hold zeros (white)
        ply = write_ply(args.ply, shape, eigenvector_colors(spec.eigenvectors[:, args.eigenvector]))
    if args.output:
        spec.save(args.output)
    result = {
        "eigenvalues": spec.eigenvalues.tolist(),
        "n_vertices": shape.n_vertices,
        "k": spec.k,
        "weighting": weighting,
        "laplacian": args.laplacian,
        "generalized": spec.generalized,
        "graph": {"edges": graph.n_edges, **graph.info},
        "output": args.output,
        "ply": ply,
        "eigenvector": args.eigenvector if ply else None,
    }
    if args.json:
        print_json(result)
    else:
        print(f"{shape!r}: {spec.k} smallest eigenvalues ({args.laplacian}, {weighting}):")
        print(np.array2string(spec.eigenvalues, precision=6, max_line_width=100))
    return 0


def _check_graph_memory(args: argparse.Namespace, shape: Shape, weighting: str) -> None:
    """Refuse a ``--radius`` or ``--neighbors`` whose graph, with the spectrum's memory, would need more than the
    memory limit (:func:`~shape_toolkit.core.graph.check_graph_memory`, the check ``build_graph`` makes from Python,
    here with the options' names, ``--memory-limit`` and the eigenpairs' memory)."""
    cls = plugin_class("weightings", weighting)
    if not getattr(cls, "uses_edges", not getattr(cls, "needs_faces", False)):
        return  # the weighting makes its own edges (and refuses an epsilon graph itself)
    check_graph_memory(shape, connectivity=args.connectivity, n_neighbors=args.neighbors, radius=args.radius,
                       memory_limit=args.memory_limit, reserve=spectrum_memory(shape.n_vertices, args.k),
                       names=_CLI_NAMES)  # memory_limit None: this machine's memory
