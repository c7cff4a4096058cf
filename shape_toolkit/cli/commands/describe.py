"""``shape-toolkit describe MESH --descriptor hks|wks|heat-diffusion|heat-distance [-o OUT.npz]``:
per-vertex descriptors (the spectrum the descriptor declares is computed once and passed in).
Default output: ``SHAPE_STEM.DESCRIPTOR.npz`` in the current directory."""

from __future__ import annotations

import argparse
import time

import numpy as np

from shape_toolkit.api.registry import create_plugin
from shape_toolkit.cli.commands._common import (
    add_memory_limit,
    add_quiet,
    check_distinct,
    check_memory,
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
from shape_toolkit.results.labels import read_vertex_ids, vertex_ids_within
from shape_toolkit.validation import dumps_json

#: bytes per descriptor value held while describing: the computed matrix and the copy written to the .npz
DESCRIPTOR_BYTES = 16


def describe_memory(n: int, k: int, width: int | None) -> float:
    """Estimated peak bytes of ``shape-toolkit describe`` on a shape of ``n`` vertices: computing the declared spectrum
    of ``k`` eigenpairs (:func:`~shape_toolkit.core.spectrum.spectrum_memory`), or afterwards its eigenvectors held
    beside ``width`` descriptor columns (:data:`DESCRIPTOR_BYTES` a value; None: unknown, not counted), whichever is
    more. An estimate for refusing a shape before reading it (``--memory-limit``), not a bound."""
    from shape_toolkit.core.spectrum import spectrum_memory

    return max(spectrum_memory(n, k), spectrum_memory(n, 0) + n * (8 * k + DESCRIPTOR_BYTES * (width or 0)))


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
    add_memory_limit(p)
    add_quiet(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    out = default_output(args.output, args.shape, f"{args.descriptor}.npz")
    check_output_path(out, suffixes=(".npz",))
    check_distinct(out, args.shape, args.keypoints)
    params = parse_params(args.param, plugin_class("descriptors", args.descriptor))
    desc = create_plugin("descriptors", args.descriptor, preset=args.preset, **params)
    from shape_toolkit.spectra import declared_specs

    if args.keypoints and not desc.uses_keypoints:  # before reading anything: they would be ignored
        raise ParameterError(f"--keypoints: the {args.descriptor!r} descriptor takes no keypoints and would ignore "
                             "them; heat-diffusion and heat-distance measure from keypoints")
    kp = read_vertex_ids(args.keypoints, one_based=False) if args.keypoints else None
    k = sum(spec.k for spec in declared_specs(desc))
    width = desc.output_width(None if kp is None else kp.size)
    check_memory(args, [args.shape], lambda n: describe_memory(n, k, width),
                 f"the {args.descriptor} descriptor (a spectrum of {k} eigenpairs"
                 + (f", {width} columns)" if width else ")"), "memory_models.md",
                 "fewer eigenpairs (--param K=...)")
    shape = load_shape(args.shape)
    if kp is not None:  # the ids read above, against the shape
        kp = vertex_ids_within(kp, args.keypoints, shape.n_vertices, one_based=False)
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
