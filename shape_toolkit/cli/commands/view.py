"""``shape-toolkit view MESH [--labels F [--faces] | --map SRC MAP | --scalar F]``: an interactive 3D
viewer (polyscope, optional ``viz`` extra). ``--map SRC MAP`` shows SRC coloured by the pull-back
of MESH's colours through MAP (one 0-based MESH vertex per SRC vertex, as ``match`` writes)."""

from __future__ import annotations

import argparse
import importlib
from pathlib import Path
from typing import Any

import numpy as np

from shape_toolkit.cli.commands._common import missing_extra, read_labels_arg
from shape_toolkit.errors import ParameterError, ShapeFileError
from shape_toolkit.io.mesh import load_shape


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("view", help="interactive 3D viewer (needs the 'viz' extra: polyscope)")
    p.add_argument("shape", help="mesh or point-cloud file")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--labels", metavar="FILE", help="labels, one per vertex (per face with --faces)")
    g.add_argument("--map", nargs=2, metavar=("SRC", "MAP"),
                   help="a source shape and its map onto SHAPE: both shown, the source by pull-back colours")
    g.add_argument("--scalar", metavar="FILE",
                   help="per-vertex values: text (one per line), .npy, or .npz (first array; --column)")
    p.add_argument("--faces", action="store_true", help="--labels holds one label per face (PSB .seg)")
    p.add_argument("--column", type=int, default=0, help="column of a 2D --scalar array (default 0)")
    p.add_argument("--points", metavar="FILE", help="vertex ids (0-based, one per line) to mark, e.g. keypoints")
    p.set_defaults(func=run)


def read_scalar(path: str, n: int, column: int = 0) -> np.ndarray:
    """Per-vertex values ``(n,)`` float64 from text, ``.npy`` or ``.npz`` (first array, or the row /
    column ``column`` of a 2D one whose other side has ``n`` entries)."""
    p = Path(path)
    try:
        if p.suffix == ".npy":
            x = np.load(p, allow_pickle=False)
        elif p.suffix == ".npz":
            with np.load(p, allow_pickle=False) as z:
                arrays = [z[k] for k in z.files if z[k].ndim in (1, 2) and n in z[k].shape]
            if not arrays:
                raise ShapeFileError(path, f"holds no array with {n} entries per vertex")
            x = arrays[0]
        else:
            x = np.loadtxt(p, dtype=np.float64, ndmin=1)
    except (OSError, ValueError) as exc:
        raise ShapeFileError(path, f"cannot read per-vertex values ({' '.join(str(exc).split())[:80]})") from None
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 2:
        x = x if x.shape[0] == n else x.T
        if not 0 <= column < x.shape[1]:
            raise ParameterError(f"--column {column}: the array has {x.shape[1]} columns")
        x = x[:, column]
    if x.shape != (n,):
        raise ShapeFileError(path, f"has {x.size} values, expected one per vertex ({n})")
    return x


def view_items(args: argparse.Namespace) -> list[dict[str, Any]]:
    """What the viewer shows, computed without any GUI: ``[{"name", "shape", "colors" (n, 3) in
    [0, 1], "points"}]``; every input problem raises a typed one-line error."""
    from shape_toolkit.io.viz import label_colors, pullback_colors, scalar_colors

    shape = load_shape(args.shape)
    points = None
    if args.points:
        from shape_toolkit.results.labels import read_vertex_ids

        points = read_vertex_ids(args.points, one_based=False, n_vertices=shape.n_vertices)
    if args.faces and not args.labels:
        raise ParameterError("--faces applies to --labels")
    name = Path(args.shape).stem
    if args.labels:
        return [{"name": name, "shape": shape, "points": points,
                 "colors": label_colors(read_labels_arg(args.labels, shape, args.faces, "--labels"))}]
    if args.scalar:
        return [{"name": name, "shape": shape, "points": points,
                 "colors": scalar_colors(read_scalar(args.scalar, shape.n_vertices, args.column))}]
    if args.map:
        from shape_toolkit.results.correspondence import load_map

        source = load_shape(args.map[0])
        corr = load_map(args.map[1], source.n_vertices, shape.n_vertices)
        cs, ct = pullback_colors(source, shape, corr.target_of)
        return [{"name": f"{name} (target)", "shape": shape, "colors": ct, "points": points},
                {"name": f"{Path(args.map[0]).stem} (source, pull-back)", "shape": source, "colors": cs,
                 "points": None}]
    return [{"name": name, "shape": shape, "colors": None, "points": points}]


def _polyscope() -> Any:
    try:
        return importlib.import_module("polyscope")
    except ImportError:
        raise missing_extra("view", "polyscope") from None


def run(args: argparse.Namespace) -> int:
    ps = _polyscope()  # before any work: a missing extra is the first thing said
    items = view_items(args)
    ps.init()
    offset = 0.0
    for it in items:
        s = it["shape"]
        v = np.asarray(s.vertices, dtype=np.float64).copy()
        v[:, 0] += offset - v[:, 0].min()
        offset = v[:, 0].max() + 0.2 * (v[:, 0].max() - v[:, 0].min())
        if s.is_mesh:
            m = ps.register_surface_mesh(it["name"], v, s.faces)
        else:
            m = ps.register_point_cloud(it["name"], v)
        if it["colors"] is not None:
            m.add_color_quantity("colour", it["colors"], enabled=True)
        if it["points"] is not None and len(it["points"]):
            ps.register_point_cloud(f"{it['name']} points", v[it["points"]], color=(0.9, 0.1, 0.1))
    ps.show()
    return 0
