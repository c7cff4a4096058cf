"""Headless rendering of shapes to PNG (matplotlib Agg) and coloured PLY export.

:func:`render_shape` draws a mesh (``Poly3DCollection``, Lambert-shaded face colours) or a point
cloud with optional per-vertex ``scalars`` (colour map), ``labels`` (one colour per label) or
explicit ``colors``, and highlights ``points`` (vertex ids, e.g. keypoints). Shapes are shown in
their principal-axes frame (largest extent horizontal, smallest along the view direction), so no
camera needs to be chosen. :func:`pullback_colors` shows a correspondence by pull-back colour
transfer (the source takes the colours of the target vertices it maps to, so every matched source
vertex is coloured); :func:`match_colors` is the older push-forward. :func:`align_labels` renames a
segmentation's labels to the ground truth's (Hungarian method) so both are drawn in one palette.
:func:`save_colored_ply` writes vertex colours that MeshLab and Open3D display; :func:`show` returns
an interactive plotly figure for notebooks (optional ``viz`` extra).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import InvalidShapeError, ParameterError
from shape_toolkit.io.mesh import save_shape

__all__ = [
    "label_colors",
    "scalar_colors",
    "coordinate_colors",
    "match_colors",
    "pullback_colors",
    "align_labels",
    "eigenvector_colors",
    "show",
    "render_shape",
    "render_shapes",
    "save_colored_ply",
    "render_trajectories",
]

_NEUTRAL = np.array([0.75, 0.75, 0.75])


def _mpl():
    import matplotlib

    matplotlib.use("Agg", force=False) if matplotlib.get_backend().lower() != "agg" else None
    import matplotlib.pyplot as plt

    return matplotlib, plt


def _label_color(value: int) -> tuple[float, float, float]:
    """The colour of label ``value`` (>= 0): tab10, then the light halves of tab20, then a golden-ratio
    hue cycle (computed from the value, so huge label values cost nothing)."""
    matplotlib, _ = _mpl()
    if value < 10:
        return tuple(matplotlib.colormaps["tab10"](value)[:3])
    if value < 20:
        return tuple(matplotlib.colormaps["tab20"](2 * (value - 10) + 1)[:3])
    import colorsys

    return colorsys.hsv_to_rgb((0.618034 * ((value - 20) % 10**9)) % 1.0, 0.65, 0.9)


def label_colors(labels: np.ndarray) -> np.ndarray:
    """RGB ``(n, 3)`` in [0, 1] for integer labels ``(n,)``: the colour depends on the label VALUE
    (label ``j`` always gets the same colour), so two segmentations with aligned labels (see
    :func:`align_labels`) share colours; grey for negative (unlabelled) entries. Memory and time grow
    with the number of distinct labels, never with their values."""
    lab = np.asarray(labels, dtype=np.int64).ravel()
    ok = lab >= 0
    out = np.tile(_NEUTRAL, (len(lab), 1))
    if ok.any():
        values, inv = np.unique(lab[ok], return_inverse=True)
        out[ok] = np.asarray([_label_color(int(v)) for v in values], dtype=np.float64)[inv]
    return out


def align_labels(labels: np.ndarray, reference: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """``labels`` ``(n,)`` renamed to best agree with ``reference`` ``(n,)`` (Hungarian method,
    :func:`scipy.optimize.linear_sum_assignment` on the overlap, weighted by ``weights`` ``(n,)``
    such as face areas): each label takes the reference label it overlaps most under a one-to-one
    assignment; labels left over get fresh values after the reference's. Negative labels stay."""
    from scipy.optimize import linear_sum_assignment

    a = np.asarray(labels, dtype=np.int64).ravel()
    b = np.asarray(reference, dtype=np.int64).ravel()
    if a.shape != b.shape:
        raise ParameterError(f"labels {a.shape} and reference {b.shape} must have the same shape")
    w = np.ones(a.size) if weights is None else np.asarray(weights, dtype=np.float64).ravel()
    ua = np.unique(a[a >= 0])
    ub = np.unique(b[b >= 0])
    out = a.copy()
    if ua.size == 0:
        return out
    ok = (a >= 0) & (b >= 0)
    overlap = np.zeros((ua.size, max(ub.size, 1)))
    if ub.size:
        np.add.at(overlap, (np.searchsorted(ua, a[ok]), np.searchsorted(ub, b[ok])), w[ok])
    rows, cols = linear_sum_assignment(-overlap)
    new = {}
    for r, c in zip(rows, cols):
        if ub.size and overlap[r, c] > 0:
            new[int(ua[r])] = int(ub[c])
    nxt = int(max(ub.max() if ub.size else -1, -1)) + 1
    for lab in ua:
        if int(lab) not in new:
            new[int(lab)] = nxt
            nxt += 1
    lut = np.array([new[int(x)] for x in ua])
    out[a >= 0] = lut[np.searchsorted(ua, a[a >= 0])]
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


def eigenvector_colors(vector: np.ndarray) -> np.ndarray:
    """RGB ``(n, 3)`` of a signed per-vertex function ``(n,)`` (an eigenvector): diverging map
    symmetric about zero (blue negative, white zero, red positive)."""
    x = np.asarray(vector, dtype=np.float64).ravel()
    lim = float(np.nanmax(np.abs(x))) if x.size and np.isfinite(x).any() else 1.0
    return scalar_colors(x, "coolwarm", -lim, lim if lim > 0 else 1.0)


def _check_map(source: Shape, target: Shape, target_of: np.ndarray) -> np.ndarray:
    t = np.asarray(target_of, dtype=np.int64).ravel()
    if t.size != source.n_vertices:
        raise ParameterError(f"the map has {t.size} entries for {source.n_vertices} source vertices")
    if t.size and (t.max() >= target.n_vertices or t.min() < -1):
        raise ParameterError(f"the map must hold target vertex ids in [0, {target.n_vertices - 1}] or -1")
    return t


def pullback_colors(
    source: Shape, target: Shape, target_of: np.ndarray, target_colors: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Pull-back colour transfer of a map ``target_of`` ``(n_source,)`` (-1 unmatched): the target
    is coloured smoothly (``target_colors`` ``(n_t, 3)`` in [0, 1], default its positions in its
    bounding box) and each source vertex takes the colour of the target vertex it maps to, so every
    matched source vertex is coloured and a correct map makes the two look alike (unmatched: grey).
    Returns ``(source_rgb (n_s, 3), target_rgb (n_t, 3))``."""
    t = _check_map(source, target, target_of)
    ct = coordinate_colors(target) if target_colors is None else np.asarray(target_colors, dtype=np.float64)
    if ct.shape != (target.n_vertices, 3):
        raise ParameterError(f"target_colors must have shape ({target.n_vertices}, 3), got {ct.shape}")
    cs = np.tile(_NEUTRAL, (source.n_vertices, 1))
    ok = t >= 0
    cs[ok] = ct[t[ok]]
    return cs, ct


def match_colors(source: Shape, target: Shape, target_of: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Push-forward colour transfer of a map ``target_of`` ``(n_source,)`` (-1 unmatched): source
    colours from positions; each target vertex takes the mean colour of the source vertices mapped
    to it (grey when none; prefer :func:`pullback_colors`, which leaves no hole).
    Returns ``(source_rgb (n_s, 3), target_rgb (n_t, 3))``."""
    t = _check_map(source, target, target_of)
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
    rows = c[:: max(1, len(c) // 5000)]
    # full_matrices for fewer than 3 points: three axes all the same (a reduced SVD has one per point)
    _, _, vt = np.linalg.svd(rows, full_matrices=len(rows) < 3)
    # keep each principal axis pointing like the input axis it is closest to (keeps "up" up)
    for j in range(3):
        i = int(np.argmax(np.abs(vt[j])))
        if vt[j, i] < 0:
            vt[j] *= -1
    p = c @ vt.T  # columns: largest, middle, smallest extent
    # matplotlib view: x right, z up, y into the screen
    return np.stack([p[:, 0], p[:, 2], p[:, 1]], axis=1)


#: direction of the light of every render (view frame: x right, y into the screen, z up)
_LIGHT = np.array([0.3, -1.0, 0.6]) / np.linalg.norm([0.3, -1.0, 0.6])
#: Lambert shading: ambient share, the rest scales with |cos| of the normal to the light
_AMBIENT = 0.35


def _shaded_faces(v: np.ndarray, faces: np.ndarray, colors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangles ``(m, 3, 3)`` of view-frame vertices ``v`` and their Lambert-shaded face colours
    ``(m, 3)`` in [0, 1]: the mean vertex colour times ``ambient + (1 - ambient) |n . light|``
    (two-sided, so no face goes black when seen from behind)."""
    tri = v[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    shade = _AMBIENT + (1.0 - _AMBIENT) * np.abs(n @ _LIGHT)
    return tri, np.clip(colors[faces].mean(axis=1) * shade[:, None], 0, 1)


def _draw(
    ax, shape: Shape, colors: np.ndarray, points: np.ndarray | None, title: str | None, point_size: float
) -> None:
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    v = _frame(shape.vertices)
    if shape.is_mesh:
        tri, fc = _shaded_faces(v, shape.faces, colors)
        coll = Poly3DCollection(tri, facecolors=fc, edgecolors=fc, linewidths=0.2)
        ax.add_collection3d(coll)
    else:
        ax.scatter(v[:, 0], v[:, 1], v[:, 2], c=colors, s=2, depthshade=False)
    if points is not None and len(points):
        # drawn after the surface, whatever the depth sort says: a keypoint on the far side or in a
        # fold is still shown (the depth sort hid most of them behind the mesh)
        ax.computed_zorder = False
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
        ax.set_title(title, fontsize=10, pad=2)


def _colors_for(shape: Shape, scalars, labels, colors, cmap, vmin=None, vmax=None) -> np.ndarray:
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
        return scalar_colors(x, cmap, vmin, vmax)
    if colors is not None:
        c = np.asarray(colors, dtype=np.float64)
        if c.shape != (n, 3):
            raise ParameterError(f"colors must have shape ({n}, 3), got {c.shape}")
        return c / 255.0 if c.max() > 1.0 else c
    return np.tile(_NEUTRAL, (n, 1))


def _wrap(text: str, width_in: float, fontsize: float) -> str:
    """``text`` wrapped to lines that fit ``width_in`` inches at ``fontsize`` points (no clipping)."""
    import textwrap

    chars = max(12, int(width_in * 72 / (0.55 * fontsize)))
    return "\n".join(textwrap.wrap(text, chars)) or text


def render_shapes(
    panels: list[dict],
    path: str | os.PathLike,
    *,
    panel_size: float = 3.2,
    dpi: int = 100,
    title: str | None = None,
) -> Path:
    """Render several shapes side by side into one PNG (``panel_size`` inches per panel); each panel
    is a dict of :func:`render_shape` arguments (``shape`` plus optional scalars/labels/colors/points/
    title/cmap/vmin/vmax, and ``colorbar``: a label string to draw a colour bar of the scalars)."""
    _, plt = _mpl()
    if not panels:
        raise ParameterError("nothing to render")
    width = panel_size * len(panels)
    fs = 11
    sup = _wrap(title, width, fs) if title else None
    n_sup = sup.count("\n") + 1 if sup else 0
    head = 0.28 * n_sup
    foot = 0.45 if any(pn.get("colorbar") for pn in panels) else 0.0
    fig = plt.figure(figsize=(width, panel_size + head + 0.3 + foot))
    for i, pnl in enumerate(panels):
        pnl = dict(pnl)
        shape = pnl.pop("shape")
        ax = fig.add_subplot(1, len(panels), i + 1, projection="3d")
        cmap = pnl.get("cmap", "viridis")
        cols = _colors_for(
            shape, pnl.get("scalars"), pnl.get("labels"), pnl.get("colors"), cmap, pnl.get("vmin"), pnl.get("vmax")
        )
        sub = _wrap(pnl["title"], panel_size, 10) if pnl.get("title") else None
        _draw(ax, shape, cols, pnl.get("points"), sub, pnl.get("point_size", 30.0))
        if pnl.get("colorbar") and pnl.get("scalars") is not None:
            import matplotlib as mpl

            x = np.asarray(pnl["scalars"], dtype=np.float64)
            fin = x[np.isfinite(x)]
            lo = pnl.get("vmin", fin.min() if fin.size else 0.0)
            hi = pnl.get("vmax", fin.max() if fin.size else 1.0)
            sm = mpl.cm.ScalarMappable(norm=mpl.colors.Normalize(lo, hi if hi > lo else lo + 1), cmap=cmap)
            cb = fig.colorbar(sm, ax=ax, orientation="horizontal", fraction=0.05, pad=0.02, shrink=0.8)
            cb.set_label(str(pnl["colorbar"]), fontsize=9)
            cb.ax.tick_params(labelsize=8)
    total = panel_size + head + 0.3 + foot
    top = 1 - (head + 0.1) / total
    if sup:
        fig.suptitle(sup, fontsize=fs, y=0.995, va="top")
    fig.subplots_adjust(left=0, right=1, bottom=0.02 + foot / total, top=top, wspace=0.02)
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
    0..255 integers) as ``uchar red, green, blue`` properties: the shape with these colours,
    written by :func:`shape_toolkit.io.mesh.save_shape` (the one PLY writer). Colours outside
    those ranges, or not finite, raise :class:`ParameterError`. Returns the path."""
    c = np.asarray(colors, dtype=np.float64)
    if c.shape != (shape.n_vertices, 3):
        raise ParameterError(f"colors must have shape ({shape.n_vertices}, 3), got {c.shape}")
    if not np.isfinite(c).all():
        raise ParameterError("colors must be finite")
    if c.max(initial=0) > 1.0:  # 8-bit values
        c = c / 255.0
    try:
        coloured = shape.with_colors(c)
    except InvalidShapeError as e:
        raise ParameterError(f"colors must lie in [0, 1] or 0..255: {e}") from None
    p = Path(path)
    save_shape(coloured, p)
    return p


def show(
    shape: Shape,
    *,
    scalars: np.ndarray | None = None,
    labels: np.ndarray | None = None,
    colors: np.ndarray | None = None,
    points: np.ndarray | None = None,
    cmap: str = "viridis",
    title: str | None = None,
    height: int = 480,
):
    """An interactive 3D view for notebooks: a plotly ``Figure`` (``Mesh3d`` with per-vertex
    colours, or a point cloud) showing ``scalars`` ``(n,)``, ``labels`` ``(n,)`` or RGB ``colors``
    ``(n, 3)``, with ``points`` (vertex ids) as red markers; ``height`` in pixels. Displayed inline
    when it is the last expression of a cell. Needs plotly (the ``viz`` extra)."""
    try:
        import plotly.graph_objects as go
    except ImportError:
        raise ParameterError(
            "show() needs plotly, part of the optional 'viz' extra: pip install 'shape-toolkit[viz]'"
        ) from None
    cols = _colors_for(shape, scalars, labels, colors, cmap)
    rgb = [f"rgb({r},{g},{b})" for r, g, b in np.clip(np.round(cols * 255), 0, 255).astype(int).tolist()]
    v = shape.vertices
    data = []
    if shape.is_mesh:
        f = shape.faces
        data.append(go.Mesh3d(x=v[:, 0], y=v[:, 1], z=v[:, 2], i=f[:, 0], j=f[:, 1], k=f[:, 2],
                              vertexcolor=rgb, flatshading=False, hoverinfo="skip", name="shape"))
    else:
        data.append(go.Scatter3d(x=v[:, 0], y=v[:, 1], z=v[:, 2], mode="markers",
                                 marker={"size": 2, "color": rgb}, name="shape"))
    if points is not None and len(points):
        p = v[np.asarray(points, dtype=np.int64)]
        data.append(go.Scatter3d(x=p[:, 0], y=p[:, 1], z=p[:, 2], mode="markers",
                                 marker={"size": 5, "color": "red"}, name="points"))
    fig = go.Figure(data=data)
    fig.update_layout(title=title, height=height, margin={"l": 0, "r": 0, "t": 30 if title else 0, "b": 0},
                      scene={"aspectmode": "data", "xaxis": {"visible": False}, "yaxis": {"visible": False},
                             "zaxis": {"visible": False}}, showlegend=False)
    return fig


def render_trajectories(
    shapes: list[Shape],
    trajectories: np.ndarray,
    path: str | os.PathLike,
    *,
    colors: list[np.ndarray | None] | None = None,
    frames: list[int] | None = None,
    n_tracks: int = 150,
    tail: int = 5,
    panel_size: float = 3.0,
    dpi: int = 100,
    fps: float = 3.0,
    title: str | None = None,
) -> Path:
    """Dense trajectories over a sequence, as in thesis Figs. 7.17-7.18: a PNG with the chosen
    ``frames`` side by side (default all, at most 9 evenly spaced), or an animated GIF (``path``
    ending in ``.gif``, one frame per sequence frame, ``fps`` frames per second, Pillow).

    ``shapes``: the ``T`` frames; ``trajectories`` int ``(n_0, T)``: vertex of frame ``t`` reached
    by the trajectory of vertex ``j`` of frame 0 (``-1`` lost). Each frame is drawn with its
    vertex ``colors`` (``(n_t, 3)`` in [0, 1], e.g. pull-back colours; default the shape's own
    colours, else grey) and the tails
    of ``n_tracks`` trajectories (farthest-point sample of frame 0, deterministic) over the last
    ``tail`` frames as polylines, blue (oldest) to green (current) as in the thesis. All frames
    share one view: the principal-axes frame of frame 0, the same rule as :func:`render_shape`."""
    _, plt = _mpl()
    T = len(shapes)
    ids = np.asarray(trajectories)
    if T < 1 or ids.ndim != 2 or ids.shape[1] != T or not np.issubdtype(ids.dtype, np.integer):
        raise ParameterError(f"trajectories must be an integer (n_0, {T}) array, got {ids.dtype} {ids.shape}")
    ids = ids.astype(np.int64)
    if ids.shape[0] != shapes[0].n_vertices:
        raise ParameterError(f"{ids.shape[0]} trajectories for the {shapes[0].n_vertices} vertices of frame 0")
    for t, s in enumerate(shapes):
        if ids[:, t].min() < -1 or ids[:, t].max() >= s.n_vertices:
            raise ParameterError(f"trajectory ids of frame {t} must lie in [-1, {s.n_vertices - 1}]")
    if colors is not None and len(colors) != T:
        raise ParameterError(f"{len(colors)} colour arrays for {T} frames")
    if n_tracks < 0 or tail < 1:
        raise ParameterError("need n_tracks >= 0 and tail >= 1")
    cols = [_colors_for(s, None, None, getattr(s, "colors", None) if colors is None else colors[t], "viridis")
            for t, s in enumerate(shapes)]
    if frames is None:
        frames = sorted({int(round(x)) for x in np.linspace(0, T - 1, min(T, 9))})
    frames = [int(f) for f in frames]
    if not frames or min(frames) < 0 or max(frames) >= T:
        raise ParameterError(f"frames must be a non-empty list of frame indices in [0, {T - 1}]")
    # one view for every frame: the affine map that _frame applies to frame 0
    v0 = shapes[0].vertices
    c0 = v0.mean(axis=0)
    lin = np.linalg.lstsq(v0 - c0, _frame(v0), rcond=None)[0]
    views = [(s.vertices - c0) @ lin for s in shapes]
    lo = np.min([v.min(axis=0) for v in views], axis=0)
    hi = np.max([v.max(axis=0) for v in views], axis=0)
    ext = np.maximum(hi - lo, 1e-3 * max(float((hi - lo).max()), 1e-300))
    tracks = _spread_tracks(views[0], ids, n_tracks)
    blue_green = np.array([[0.1, 0.3, 1.0], [0.1, 0.85, 0.2]])

    def draw(ax, t: int) -> None:
        from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

        ax.computed_zorder = False  # mesh first, trajectories on top
        v, s = views[t], shapes[t]
        if s.is_mesh:
            tri, fc = _shaded_faces(v, s.faces, cols[t])
            ax.add_collection3d(Poly3DCollection(tri, facecolors=fc, edgecolors=fc, linewidths=0.2, zorder=1))
        else:
            ax.scatter(v[:, 0], v[:, 1], v[:, 2], c=cols[t], s=2, depthshade=False, zorder=1)
        segs, segc = [], []
        first = max(0, t - tail)
        for k in range(first, t):
            a, b = ids[tracks, k], ids[tracks, k + 1]
            ok = (a >= 0) & (b >= 0)
            segs.append(np.stack([views[k][a[ok]], views[k + 1][b[ok]]], axis=1))
            w = (k + 1 - first) / max(t - first, 1)
            segc += [blue_green[0] * (1 - w) + blue_green[1] * w] * int(ok.sum())
        if segs and sum(len(x) for x in segs):
            ax.add_collection3d(Line3DCollection(np.concatenate(segs), colors=segc, linewidths=1.2, zorder=5))
        alive = ids[tracks, t]
        p = v[alive[alive >= 0]]
        if len(p):
            ax.scatter(p[:, 0], p[:, 1], p[:, 2], c=[blue_green[1]], s=4, depthshade=False, zorder=6)
        ax.set_xlim(lo[0], lo[0] + ext[0])
        ax.set_ylim(lo[1], lo[1] + ext[1])
        ax.set_zlim(lo[2], lo[2] + ext[2])
        ax.set_box_aspect(tuple(ext / ext.max()), zoom=0.95)
        ax.view_init(elev=12, azim=-90)
        ax.set_axis_off()
        ax.set_title(f"frame {t}", fontsize=10, pad=2)

    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    head = 0.35 if title else 0.0
    if p.suffix.lower() == ".gif":
        from matplotlib.animation import FuncAnimation, PillowWriter

        fig = plt.figure(figsize=(panel_size * 1.3, panel_size * 1.3 + head))
        ax = fig.add_subplot(1, 1, 1, projection="3d")

        def update(t: int) -> list:
            ax.clear()
            draw(ax, t)
            return []

        if title:
            fig.suptitle(_wrap(title, panel_size * 1.3, 10), fontsize=10)
        anim = FuncAnimation(fig, update, frames=range(T), blit=False)
        anim.save(p, writer=PillowWriter(fps=float(fps)), dpi=dpi)
        plt.close(fig)
        return p
    fig = plt.figure(figsize=(panel_size * len(frames), panel_size + 0.3 + head))
    for i, t in enumerate(frames):
        draw(fig.add_subplot(1, len(frames), i + 1, projection="3d"), t)
    if title:
        fig.suptitle(_wrap(title, panel_size * len(frames), 11), fontsize=11, y=0.995, va="top")
    fig.subplots_adjust(left=0, right=1, bottom=0.02, top=1 - (head + 0.1) / (panel_size + 0.3 + head), wspace=0.02)
    fig.savefig(p, dpi=dpi)
    plt.close(fig)
    return p


def _spread_tracks(points: np.ndarray, ids: np.ndarray, n: int) -> np.ndarray:
    """Up to ``n`` trajectory indices spread over frame 0 (farthest-point sampling from the vertex
    nearest the centroid, among trajectories alive in frame 1 or the only frame)."""
    cand = np.flatnonzero(ids[:, min(1, ids.shape[1] - 1)] >= 0)
    if n == 0 or cand.size == 0:
        return np.zeros(0, dtype=np.int64)
    p = points[cand]
    chosen = [int(np.argmin(np.linalg.norm(p - p.mean(axis=0), axis=1)))]
    d = np.linalg.norm(p - p[chosen[0]], axis=1)
    while len(chosen) < min(n, cand.size):
        k = int(np.argmax(d))
        chosen.append(k)
        d = np.minimum(d, np.linalg.norm(p - p[k], axis=1))
    return cand[np.asarray(chosen, dtype=np.int64)]
