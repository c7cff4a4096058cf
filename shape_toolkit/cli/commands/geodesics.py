"""``shape-toolkit geodesics MESH --sources IDS [--method exact|heat|fmm|dijkstra] [-o OUT.npz]``:
geodesic distances from a few source vertices to every vertex. Default output:
``SHAPE_STEM.geodesics.npz`` in the current directory. As in ``evaluate-map``, the solve shows
its progress on a terminal and stops, with one line and exit 2, past ``--time-limit`` seconds."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from shape_toolkit.cli.commands._common import (
    add_memory_limit,
    add_ply,
    add_quiet,
    add_time_limit,
    check_distinct,
    check_memory,
    check_output_path,
    check_ply,
    default_output,
    emit,
    status,
    time_limit_hint,
    write_ply,
)
from shape_toolkit.errors import ParameterError, TimeLimitError
from shape_toolkit.features.geodesics import geodesic_distances, geodesic_memory
from shape_toolkit.io.mesh import MAX_VERTICES, load_shape
from shape_toolkit.results.labels import read_vertex_ids, vertex_ids_within
from shape_toolkit.validation import machine_memory, shown_value

METHODS = ("exact", "heat", "fmm", "dijkstra")


def parse_sources(text: str, n_vertices: int | None = None) -> np.ndarray:
    """``--sources``: comma-separated 0-based ids (``0,15,200``) or a file of one id per line;
    int64 ``(s,)``, checked against ``n_vertices`` when given (:func:`sources_within`)."""
    if _is_file(text):
        ids = read_vertex_ids(text, one_based=False)
    else:
        try:
            values = [int(t) for t in text.replace(" ", "").split(",") if t != ""]
        except ValueError:
            raise ParameterError(f"--sources expects comma-separated vertex ids or a file, got {text[:40]!r}") from None
        huge = [v for v in values if v > MAX_VERTICES]  # no shape has more vertices; past int64 numpy had overflowed
        if huge:
            raise ParameterError(f"--sources: vertex id {shown_value(huge[0], 40)} is out of range (no shape has "
                                 f"more than {MAX_VERTICES} vertices)")
        ids = np.array(values, dtype=np.int64)
        if ids.size == 0:
            raise ParameterError("--sources: give at least one vertex id")
        if (ids < 0).any():
            raise ParameterError(f"--sources: vertex id {int(ids[ids < 0][0])} is negative")
    return ids if n_vertices is None else sources_within(ids, text, n_vertices)


def _is_file(text: str) -> bool:
    """Whether ``text`` names a file; a text no file can have (too long a name) is not one."""
    try:
        return Path(text).is_file()
    except (OSError, ValueError):
        return False


def sources_within(ids: np.ndarray, text: str, n_vertices: int) -> np.ndarray:
    """The ids :func:`parse_sources` read from ``text`` (before the mesh, for the memory estimate), checked against a
    mesh of ``n_vertices`` vertices, in the words of the file's or the list's own errors."""
    if _is_file(text):
        return vertex_ids_within(ids, text, n_vertices, one_based=False)
    bad = ids[ids >= n_vertices]
    if bad.size:
        raise ParameterError(f"--sources: vertex id {int(bad[0])} is out of range [0, {n_vertices - 1}]")
    return ids


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("geodesics", help="geodesic distances from source vertices to every vertex")
    p.add_argument("shape", help="mesh file (dijkstra also works on point clouds' kNN graph)")
    p.add_argument("--sources", required=True, metavar="IDS",
                   help="0-based source vertex ids, comma-separated (0,15,200), or a file of one id per line")
    p.add_argument("--method", default="heat", choices=METHODS, help="solver (default heat; exact is slow)")
    p.add_argument("-o", "--output", help="output .npz (default SHAPE_STEM.geodesics.npz): 'distances' "
                   "(n_sources, n_vertices) float64 in the mesh's length units, 'sources' (n_sources,)")
    add_time_limit(p, "; exact geodesics take about 1 s per source on a 5,000-vertex mesh")
    add_ply(p, "the distance to the nearest source")
    p.add_argument("--json", action="store_true", help="print JSON")
    add_memory_limit(p)
    add_quiet(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    out = default_output(args.output, args.shape, "geodesics.npz")
    check_output_path(out, suffixes=(".npz",))
    check_distinct(out, args.shape)
    check_ply(args.ply, args.shape, output=str(out))
    src = parse_sources(args.sources)  # (a bad list is refused before the mesh is read)
    count = src.size
    check_memory(args, [args.shape], lambda n: geodesic_memory(n, count, args.method),
                 f"{args.method} geodesics from {count} source{'s' if count > 1 else ''}", "memory_models.md",
                 "give fewer --sources" if count > 1 else "")
    shape = load_shape(args.shape)
    src = sources_within(src, args.sources, shape.n_vertices)
    limit = args.memory_limit if args.memory_limit is not None else machine_memory()
    need = geodesic_memory(shape.n_vertices, count, args.method, cloud=not shape.is_mesh)
    if not shape.is_mesh and limit is not None and need > limit:  # a file does not say it has no faces: known now
        raise ParameterError(
            f"{args.shape} is a point cloud of {shape.n_vertices:,} points, for which {args.method} geodesics would "
            f"need about {need / 1e9:.1f} GB (its local triangulations; measured growth, "
            f"features.geodesics.GEODESIC_CLOUD_MEMORY), above the memory limit of {limit / 1e9:.1f} GB "
            "(--memory-limit); use --method dijkstra, fewer points, or raise --memory-limit")
    t0 = time.perf_counter()
    with status(args, f"geodesics: {args.method} from {src.size} sources") as st:
        try:
            D = geodesic_distances(shape, src, method=args.method, time_limit=args.time_limit, progress=st.count)
        except TimeLimitError as exc:
            raise time_limit_hint(exc, args) from None
    seconds = time.perf_counter() - t0
    np.savez_compressed(out, distances=D, sources=src, method=np.array(args.method))
    nearest = D.min(axis=0)
    ply = None
    if args.ply:
        from shape_toolkit.viz import scalar_colors

        ply = write_ply(args.ply, shape, scalar_colors(nearest, "magma_r"))
    fin = nearest[np.isfinite(nearest)]
    result = {
        "output": str(out),
        "ply": ply,
        "method": args.method,
        "sources": src.tolist(),
        "shape": list(D.shape),
        "max_distance": float(fin.max()) if fin.size else None,
        "unreachable": int(np.sum(~np.isfinite(nearest))),
        "seconds": round(seconds, 3),
    }
    return emit(args, result, f"{shape!r}: distances from {src.size} source(s) ({args.method}) in "
                f"{seconds:.2f} s -> {out}")
