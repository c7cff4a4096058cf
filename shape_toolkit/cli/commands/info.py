"""``shape-toolkit info MESH [--json]``: topology and defect report of a shape file."""

from __future__ import annotations

import argparse

from shape_toolkit.cli.commands._common import emit
from shape_toolkit.core.inspect import mesh_info
from shape_toolkit.io.mesh import load_shape


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("info", help="counts, topology and defects of a mesh or point cloud")
    p.add_argument("shape", help="mesh or point-cloud file (OFF, PLY, OBJ, STL, XYZ, PCD)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def format_info(info: dict) -> str:
    """The :func:`mesh_info` dict as an aligned two-column text table."""
    rows = []
    for key, value in info.items():
        if key == "undefined":
            continue  # the '-' of each null says it
        if key == "bounding_box":
            lo = ", ".join(f"{x:.6g}" for x in value["min"])
            hi = ", ".join(f"{x:.6g}" for x in value["max"])
            value = f"[{lo}] .. [{hi}]"
        elif isinstance(value, float) and value != value:
            value = "-"
        elif isinstance(value, float):
            value = f"{value:.6g}"
        elif value is None:
            value = "-"
        rows.append((key.replace("_", " "), str(value)))
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def undefined_reasons(info: dict) -> dict[str, str]:
    """Why each null of a :func:`mesh_info` dict is null: a property a point cloud does not have, or a
    genus that only a closed, connected, manifold mesh has. Every null of the JSON output is named here."""
    out = {}
    for key, value in info.items():
        if value is None:
            if not info.get("is_mesh", True):
                out[key] = "a point cloud has no faces"
            elif key == "genus":
                out[key] = "defined for a closed, connected, manifold mesh only"
            else:
                out[key] = "not defined for this shape"
    return out


def run(args: argparse.Namespace) -> int:
    info = mesh_info(load_shape(args.shape, duplicate_faces="keep"))  # info reports them
    info["path"] = str(args.shape)
    if undefined := undefined_reasons(info):
        info["undefined"] = undefined
    return emit(args, info, format_info(info))
