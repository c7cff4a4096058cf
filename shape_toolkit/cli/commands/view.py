"""``shape-toolkit view MESH [--labels F [--faces] | --map SRC MAP | --scalar F] [--png OUT.png]``: an
interactive 3D viewer (polyscope, optional ``viz`` extra), or with ``--png`` the same view drawn into
a PNG (matplotlib, no display needed). ``--map SRC MAP`` shows SRC coloured by the pull-back of
MESH's colours through MAP (one 0-based MESH vertex per SRC vertex, as ``match`` writes).

The window needs a display: without one (no ``DISPLAY`` or ``WAYLAND_DISPLAY`` on Linux, or a
display polyscope cannot open) the command says so in one line, exit 2, naming ``--png``."""

from __future__ import annotations

import argparse
import atexit
import importlib
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

from shape_toolkit.cli.commands._common import (
    check_applies,
    check_distinct,
    check_output_path,
    count_arg,
    missing_extra,
    print_json,
    read_labels_arg,
)
from shape_toolkit.errors import ParameterError, ShapeFileError, ToolkitError
from shape_toolkit.io.mesh import load_shape


class NoDisplayError(ToolkitError):
    """The interactive viewer cannot open a window: no display, or one that cannot be opened."""


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
    p.add_argument("--column", type=count_arg, default=None,
                   help="column of a 2D --scalar array (default 0)")
    p.add_argument("--points", metavar="FILE", help="vertex ids (0-based, one per line) to mark, e.g. keypoints")
    p.add_argument("--png", metavar="OUT.png", default=None,
                   help="draw the view into this PNG instead of opening a window (matplotlib; no display "
                   "or polyscope needed)")
    p.add_argument("--json", action="store_true", help="with --png: print what was written as JSON")
    p.set_defaults(func=run)


def read_scalar(path: str, n: int, column: int | None = None) -> np.ndarray:
    """Per-vertex values ``(n,)`` float64 from text, ``.npy`` or ``.npz`` (first array, or the row /
    column ``column`` of a 2D one whose other side has ``n`` entries; None: 0). A column past 0 asked of
    a 1D array, which has only that one, is a :class:`ParameterError` (it would be ignored)."""
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
    if column and x.ndim != 2:
        raise ParameterError(f"--column {column}: {path} holds one value per vertex, no columns to choose from")
    if x.ndim == 2:
        column = column or 0
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
    from shape_toolkit.viz import label_colors, pullback_colors, scalar_colors

    # (--column 0, the default column, is no choice to ignore)
    check_applies("--column", args.column, "a 2D --scalar array", args.scalar, "; give --scalar FILE")
    shape = load_shape(args.shape)
    points = None
    if args.points:
        from shape_toolkit.results.labels import read_vertex_ids

        points = read_vertex_ids(args.points, one_based=False, n_vertices=shape.n_vertices)
    check_applies("--faces", args.faces, "--labels", args.labels)
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


#: the one-line advice of every display problem
NO_DISPLAY_HINT = "draw the view into a file instead with --png OUT.png (no display needed), or run under xvfb-run"


def display_problem(environ: dict[str, str] | None = None, platform: str | None = None) -> str | None:
    """Why no window can be opened, or None when a display may be there: on Linux and the BSDs (X11 or
    Wayland), neither ``DISPLAY`` nor ``WAYLAND_DISPLAY`` is set. macOS and Windows always have one."""
    env = os.environ if environ is None else environ
    plat = sys.platform if platform is None else platform
    if plat.startswith(("darwin", "win32", "cygwin")):
        return None
    if env.get("DISPLAY", "").strip() or env.get("WAYLAND_DISPLAY", "").strip():
        return None
    return "no display to open the viewer window in (neither DISPLAY nor WAYLAND_DISPLAY is set)"


def _quiet_exit() -> None:
    """At exit, after a failed polyscope start: silence polyscope's own shutdown callback, which
    complains on stdout and as an ignored exception that it was never initialized."""
    sys.unraisablehook = lambda _: None
    try:
        sys.stdout.flush()
        os.dup2(os.open(os.devnull, os.O_WRONLY), 1)
    except OSError:  # pragma: no cover - no stdout to silence
        pass


def _init(ps: Any) -> None:
    """``ps.init()`` with polyscope's own console lines silenced; a failure is one line (NoDisplayError)."""
    try:
        sys.stdout.flush()
        saved = os.dup(1)
    except (OSError, ValueError):  # no real stdout (a test's capture): nothing to silence
        saved = None
    try:
        if saved is not None:
            os.dup2(os.open(os.devnull, os.O_WRONLY), 1)
        ps.init()
    except RuntimeError as exc:
        atexit.register(_quiet_exit)
        text = " ".join(str(exc).replace("[polyscope]", "").replace("[EXCEPTION]", "").split())
        raise NoDisplayError(f"cannot open the viewer window ({text.split('.')[0][:160]}); {NO_DISPLAY_HINT}") from None
    finally:
        if saved is not None:
            sys.stdout.flush()
            os.dup2(saved, 1)
            os.close(saved)


def _literal(text: str) -> str:
    """``text`` shown literally by matplotlib (``$`` escaped: a file named ``$\\frac{a}{b}$`` is no formula)."""
    return str(text).replace("$", r"\$")


def _png(args: argparse.Namespace) -> int:
    inputs = [args.shape, args.labels, args.scalar, args.points, *(args.map or [])]
    out = check_output_path(args.png, "--png", suffixes=(".png",))
    check_distinct(out, *inputs)
    items = view_items(args)
    from shape_toolkit.viz import render_shapes

    panels = [{"shape": it["shape"], "colors": it["colors"], "points": it["points"], "title": _literal(it["name"])}
              for it in items]
    render_shapes(panels, out)
    if args.json:
        print_json({"png": str(out), "panels": [it["name"] for it in items]})
    else:
        print(f"wrote {out}")
    return 0


def run(args: argparse.Namespace) -> int:
    if args.png:
        return _png(args)
    check_applies("--json", args.json, "--png", args.png, " (the window prints nothing)")
    ps = _polyscope()  # before any work: a missing extra is the first thing said
    problem = display_problem()
    if problem:
        raise NoDisplayError(f"{problem}; {NO_DISPLAY_HINT}")
    items = view_items(args)
    _init(ps)
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
