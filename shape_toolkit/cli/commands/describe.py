"""``shape-toolkit describe MESH --descriptor hks|wks|heat-diffusion|heat-distance [-o OUT.npz]``:
per-vertex descriptors (the spectrum the descriptor declares is computed once and passed in).
Default output: ``SHAPE_STEM.DESCRIPTOR.npz`` in the current directory."""

from __future__ import annotations

import argparse
import time

import numpy as np

from shape_toolkit.api.registry import create_plugin
from shape_toolkit.cli.commands._common import (
    add_quiet,
    check_distinct,
    check_output_path,
    declared_spectra,
    default_output,
    emit,
    parse_params,
    plugin_class,
    status,
)
from shape_toolkit.errors import ParameterError
from shape_toolkit.io.mesh import load_shape
from shape_toolkit.results.labels import read_vertex_ids
from shape_toolkit.validation import dumps_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("describe", help="per-vertex descriptors (HKS, WKS, heat diffusion / distance) to an .npz")
    p.add_argument("shape", help="mesh or point-cloud file")
    p.add_argument("--descriptor", default="hks",
                   help="descriptor plugin: hks, wks, heat-diffusion, heat-distance (default hks)")
    p.add_argument("--preset", default=None, help="named parameter preset of the descriptor")
    p.add_argument("--param", action="append", metavar="KEY=VALUE", help="descriptor parameter (repeatable)")
    p.add_argument("--keypoints", metavar="FILE",
                   help="0-based vertex ids, one per line (heat-distance / heat-diffusion measure from them)")
    p.add_argument("-o", "--output", help="output .npz (default SHAPE_STEM.DESCRIPTOR.npz): 'descriptor' "
                   "(n_vertices, d) float64, 'params' (JSON text), 'spectra' (JSON text)")
    p.add_argument("--json", action="store_true", help="print JSON")
    add_quiet(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    out = default_output(args.output, args.shape, f"{args.descriptor}.npz")
    check_output_path(out, suffixes=(".npz",))
    check_distinct(out, args.shape, args.keypoints)
    params = parse_params(args.param, plugin_class("descriptors", args.descriptor))
    desc = create_plugin("descriptors", args.descriptor, preset=args.preset, **params)
    shape = load_shape(args.shape)
    kp = read_vertex_ids(args.keypoints, one_based=False, n_vertices=shape.n_vertices) if args.keypoints else None
    t0 = time.perf_counter()
    with status(args, f"describe: {args.descriptor} on {shape.n_vertices} vertices"):
        spectra, used = declared_spectra(desc, shape)
        spectrum = spectra[0] if spectra and len(spectra) == 1 else spectra
        D = np.asarray(desc.compute(shape, spectrum=spectrum, keypoints=kp), dtype=np.float64)
    seconds = time.perf_counter() - t0
    if D.ndim != 2 or D.shape[0] != shape.n_vertices:
        raise ParameterError(f"descriptor {args.descriptor!r} returned shape {D.shape}, expected (n, d)")
    np.savez_compressed(out, descriptor=D, params=dumps_json(desc.get_params(deep=False)),
                        spectra=dumps_json(used))
    result = {
        "output": str(out),
        "descriptor": args.descriptor,
        "shape": list(D.shape),
        "params": desc.get_params(deep=False),
        "spectra": used,
        "finite": bool(np.isfinite(D).all()),
        "seconds": round(seconds, 3),
    }
    return emit(args, result, f"{shape!r}: {args.descriptor} descriptor {D.shape[0]} x {D.shape[1]} in "
                f"{seconds:.2f} s -> {out}")
