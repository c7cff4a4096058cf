"""Headless rendering of shapes to PNG (matplotlib Agg) and coloured PLY export.

:func:`render_shape` draws a mesh (``Poly3DCollection``, Lambert-shaded face colours) or a point
cloud with optional per-vertex ``scalars`` (colour map), ``labels`` (one colour per label) or
explicit ``colors``, and highlights ``points`` (vertex ids, e.g. keypoints). Shapes are shown in
their principal-axes frame (largest extent horizontal, smallest along the view direction), so no
camera needs to be chosen. :func:`match_colors` shows a correspondence by colour transfer;
:func:`save_colored_ply` writes vertex colours that MeshLab and Open3D display.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError

__all__ = [
    "label_colors",
    "scalar_colors",
    "coordinate_colors",
    "match_colors",
    "render_shape",
    "render_shapes",
    "save_colored_ply",
]

_NEUTRAL = np.array([0.75, 0.75, 0.75])


def _mpl():
    import matplotlib

    matplotlib.use("Agg", force=False) if matplotlib.get_backend().lower() != "agg" else None
    import matplotlib.pyplot as plt

    return matplotlib, plt


def label_colors(labels: np.ndarray) -> np.ndarray:
    """RGB ``(n, 3)`` in [0, 1]: one distinct colour per label (tab20 cycle), grey for negatives."""
    matplotlib, _ = _mpl()
    lab = np.asarray(labels, dtype=np.int64).ravel()
    uniq = np.unique(lab[lab >= 0])
    idx = np.searchsorted(uniq, lab)
    cmap = matplotlib.colormaps["tab20"]
    pal = np.array([cmap((2 * i) % 20 + (i // 10) % 2)[:3] for i in range(max(len(uniq), 1))])
    out = np.tile(_NEUTRAL, (len(lab), 1))
    ok = lab >= 0
    out[ok] = pal[idx[ok] % len(pal)]
    return out


def scalar_colors(
    values: np.ndarray, cmap: str = "viridis", vmin: float | None = None, vmax: float | None = None
) -> np.ndarray:
    """RGB ``(n, 3)`` of per-vertex scalars through a matplotlib colour map (NaN: grey)."""
    matplotlib, _ = _mpl()
    x = np.asarray(values, dtype=np.float64).ravel()
    fin = np.isfinite(x)
    lo = np.nanmin(x[fin]) if vmin is None and fin.any() else (vmin or 0.0)
    hi = np.nanmax(x[fin]) if vmax is None and fin.any() else (vmax if vmax is not None else 1.0)
    t = (x - lo) / (hi - lo) if hi > lo else np.zeros_like(x)
    out = np.asarray(matplotlib.colormaps[cmap](np.clip(np.nan_to_num(t), 0, 1)))[:, :3]
    out[~fin] = _NEUTRAL
    return out


def coordinate_colors(shape: Shape) -> np.ndarray:
    """RGB ``(n, 3)``: the vertex position in the bounding box as a colour (smooth, unique-ish)."""
    b = shape.bounding_box
    return np.clip((shape.vertices - b[0]) / np.maximum(b[1] - b[0], 1e-300), 0, 1)


def match_colors(source: Shape, target: Shape, target_of: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Colour transfer of a map ``target_of`` ``(n_source,)`` (-1 unmatched): source colours
    from positions; each target vertex takes the mean colour of the source vertices mapped to
    it (grey when none). Returns ``(source_rgb (n_s, 3), target_rgb (n_t, 3))``."""
    t = np.asarray(target_of, dtype=np.int64).ravel()
    if t.size != source.n_vertices:
        raise ParameterError(f"the map has {t.size} entries for {source.n_vertices} source vertices")
    if t.size and t.max() >= target.n_vertices:
        raise ParameterError("the map points past the target's vertices")
    cs = coordinate_colors(source)
    ok = t >= 0
    acc = np.zeros((target.n_vertices, 3))
    cnt = np.zeros(target.n_vertices)
    np.add.at(acc, t[ok], cs[ok])
    np.add.at(cnt, t[ok], 1)
    ct = np.tile(_NEUTRAL, (target.n_vertices, 1))
    hit = cnt > 0
    ct[hit] = acc[hit] / cnt[hit, None]
    return cs, ct


def _frame(v: np.ndarray) -> np.ndarray:
    c = v - v.mean(axis=0)
    _, _, vt = np.linalg.svd(c[:: max(1, len(c) // 5000)], full_matrices=False)
    # keep each principal axis pointing like the input axis it is closest to (keeps "up" up)
    for j in range(3):
        i = int(np.argmax(np.abs(vt[j])))
        if vt[j, i] < 0:
            vt[j] *= -1
    p = c @ vt.T  # columns: largest, middle, smallest extent
    # matplotlib view: x right, z up, y into the screen
    return np.stack([p[:, 0], p[:, 2], p[:, 1]], axis=1)


def _draw(
    ax, shape: Shape, colors: np.ndarray, points: np.ndarray | None, title: str | None, point_size: float
) -> None:
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    v = _frame(shape.vertices)
    if shape.is_mesh:
        f = shape.faces
        tri = v[f]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        light = np.array([0.3, -1.0, 0.6])
        light /= np.linalg.norm(light)
        shade = 0.35 + 0.65 * np.abs(n @ light)
        fc = np.clip(colors[f].mean(axis=1) * shade[:, None], 0, 1)
        coll = Poly3DCollection(tri, facecolors=fc, edgecolors=fc, linewidths=0.2)
        ax.add_collection3d(coll)
    else:
        ax.scatter(v[:, 0], v[:, 1], v[:, 2], c=colors, s=2, depthshade=False)
    if points is not None and len(points):
        p = v[np.asarray(points, dtype=np.int64)]
        ax.scatter(
            p[:, 0],
            p[:, 1],
            p[:, 2],
            c="red",
            s=point_size,
            edgecolors="black",
            linewidths=0.5,
            depthshade=False,
            zorder=10,
        )
    lo, hi = v.min(axis=0), v.max(axis=0)
    ext = np.maximum(hi - lo, 1e-3 * max(float((hi - lo).max()), 1e-300))
    ax.set_xlim(lo[0], lo[0] + ext[0])
    ax.set_ylim(lo[1], lo[1] + ext[1])
    ax.set_zlim(lo[2], lo[2] + ext[2])
    ax.set_box_aspect(tuple(ext / ext.max()), zoom=0.95)
    ax.view_init(elev=12, azim=-90)
    ax.set_axis_off()
    if title:
        ax.set_title(title, fontsize=9)


def _colors_for(shape: Shape, scalars, labels, colors, cmap) -> np.ndarray:
    given = [x is not None for x in (scalars, labels, colors)]
    if sum(given) > 1:
        raise ParameterError("give at most one of scalars, labels, colors")
    n = shape.n_vertices
    if labels is not None:
        lab = np.asarray(labels)
        if lab.shape != (n,):
            raise ParameterError(f"labels must have shape ({n},), got {lab.shape}")
        return label_colors(lab)
    if scalars is not None:
        x = np.asarray(scalars)
        if x.shape != (n,):
            raise ParameterError(f"scalars must have shape ({n},), got {x.shape}")
        return scalar_colors(x, cmap)
    if colors is not None:
        c = np.asarray(colors, dtype=np.float64)
        if c.shape != (n, 3):
            raise ParameterError(f"colors must have shape ({n}, 3), got {c.shape}")
        return c / 255.0 if c.max() > 1.0 else c
    return np.tile(_NEUTRAL, (n, 1))


def render_shapes(
    panels: list[dict],
    path: str | os.PathLike,
    *,
    panel_size: float = 3.2,
    dpi: int = 100,
    title: str | None = None,
) -> Path:
    """Render several shapes side by side into one PNG; each panel is a dict of
    :func:`render_shape` arguments (``shape`` plus optional scalars/labels/colors/points/title)."""
    _, plt = _mpl()
    if not panels:
        raise ParameterError("nothing to render")
    fig = plt.figure(figsize=(panel_size * len(panels), panel_size + (0.3 if title else 0)))
    for i, pnl in enumerate(panels):
        pnl = dict(pnl)
        shape = pnl.pop("shape")
        ax = fig.add_subplot(1, len(panels), i + 1, projection="3d")
        cols = _colors_for(
            shape, pnl.get("scalars"), pnl.get("labels"), pnl.get("colors"), pnl.get("cmap", "viridis")
        )
        _draw(ax, shape, cols, pnl.get("points"), pnl.get("title"), pnl.get("point_size", 30.0))
    if title:
        fig.suptitle(title, fontsize=10)
    fig.subplots_adjust(left=0, right=1, bottom=0, top=0.86 if title else 0.95, wspace=0)
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p, dpi=dpi)
    plt.close(fig)
    return p


def render_shape(
    shape: Shape,
    path: str | os.PathLike,
    *,
    scalars: np.ndarray | None = None,
    labels: np.ndarray | None = None,
    colors: np.ndarray | None = None,
    points: np.ndarray | None = None,
    cmap: str = "viridis",
    title: str | None = None,
    size: float = 4.0,
    dpi: int = 100,
) -> Path:
    """Render ``shape`` to a PNG at ``path`` (headless): per-vertex ``scalars`` ``(n,)``,
    ``labels`` ``(n,)`` or RGB ``colors`` ``(n, 3)`` (0..1 or 0..255), and ``points`` (vertex ids)
    drawn as red dots. Returns the path."""
    pts = None if points is None else np.asarray(points, dtype=np.int64).ravel()
    if pts is not None and pts.size and (pts.min() < 0 or pts.max() >= shape.n_vertices):
        raise ParameterError(f"points must be vertex ids in [0, {shape.n_vertices - 1}]")
    panel = {
        "shape": shape,
        "scalars": scalars,
        "labels": labels,
        "colors": colors,
        "points": pts,
        "cmap": cmap,
        "title": title,
    }
    return render_shapes([panel], path, panel_size=size, dpi=dpi)


def save_colored_ply(shape: Shape, path: str | os.PathLike, colors: np.ndarray) -> Path:
    """Write ``shape`` as ASCII PLY with per-vertex RGB ``colors`` ``(n, 3)`` (0..1 floats or
    0..255 integers) as ``uchar red, green, blue`` properties."""
    c = np.asarray(colors, dtype=np.float64)
    if c.shape != (shape.n_vertices, 3):
        raise ParameterError(f"colors must have shape ({shape.n_vertices}, 3), got {c.shape}")
    if c.max(initial=0) <= 1.0:
        c = c * 255.0
    c = np.clip(np.round(c), 0, 255).astype(np.int64)
    p = Path(path)
    head = [
        "ply",
        "format ascii 1.0",
        "comment written by shape-toolkit",
        f"element vertex {shape.n_vertices}",
        "property double x",
        "property double y",
        "property double z",
        "property uchar red",
        "property uchar green",
        "property uchar blue",
    ]
    if shape.is_mesh:
        head += [f"element face {shape.n_faces}", "property list uchar int vertex_indices"]
    head.append("end_header")
    lines = [" ".join(head[:1])] + head[1:]
    vrows = [
        f"{x!r} {y!r} {z!r} {r} {g} {b}" for (x, y, z), (r, g, b) in zip(shape.vertices.tolist(), c.tolist())
    ]
    frows = [f"3 {a} {b} {d}" for a, b, d in shape.faces.tolist()] if shape.is_mesh else []
    tmp = p.with_name(f".{p.name}.tmp")
    tmp.write_text("\n".join(lines + vrows + frows) + "\n")
    os.replace(tmp, p)
    return p
