"""Headless rendering of shapes to PNG (matplotlib Agg) and coloured PLY export.

:func:`render_shape` draws a mesh (2D polygons in painter's order, Lambert-shaded face colours) or a point
cloud with optional per-vertex ``scalars`` (colour map), ``labels`` (one colour per label) or
explicit ``colors``, and highlights ``points`` (vertex ids, e.g. keypoints). Shapes are shown
upright (:func:`upright_frame`: principal axes, the up direction by a stated rule, the same for any
rigid motion of the input) and cropped tight (each panel as wide as the shape's projection), so no
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

from shape_toolkit.core.shape import Shape, coordinate_scale
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
    "upright_frame",
    "method_colors",
    "UP_RULES",
    "PANELS_KEY",
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


def method_colors(methods) -> dict[str, tuple[float, float, float]]:
    """One RGB colour (in [0, 1]) per method name, the same in every figure that is given the same
    names: the distinct names are sorted and take the label colours 0, 1, 2, ... in that order
    (tab10 first), so a report that passes all its methods once colours each alike everywhere."""
    names = sorted({str(m) for m in methods})
    return {m: _label_color(i) for i, m in enumerate(names)}


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


#: the rules :func:`upright_frame` knows for the up direction
UP_RULES = ("auto", "longest", "middle")
#: the automatic rule cuts this fraction of an axis's extent at each of its two ends
_END_SLAB = 1.0 / 3.0
#: a piece of an end slab counts when it holds at least this share of the slab's area (not a stray triangle)
_MIN_PIECE = 0.02
#: the middle axis is up when its two ends differ by at least this many more pieces than the longest axis's:
#: one piece of difference is a head or a tail, two or more are legs
_LEGS = 2


def _vertex_weights(vertices: np.ndarray, faces: np.ndarray | None) -> np.ndarray:
    """Each vertex's share ``(n,)`` of the surface area (a third of its faces' areas), summing to 1; a point
    cloud or a mesh of zero area: every point alike."""
    v = np.asarray(vertices, dtype=np.float64)
    w = np.ones(len(v))
    if faces is not None and len(faces):
        f = np.asarray(faces, dtype=np.int64)
        area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
        if area.sum() > 0:
            w = np.bincount(f.ravel(), np.repeat(area / 3.0, 3), minlength=len(v))
    return w / w.sum()


def _moments(vertices: np.ndarray, faces: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Area-weighted centroid ``(3,)`` and covariance ``(3, 3)`` of a surface (each vertex weighs a
    third of the area of its faces; a point cloud or a mesh of zero area: every point alike)."""
    v = np.asarray(vertices, dtype=np.float64)
    w = _vertex_weights(v, faces)
    centre = w @ v
    c = v - centre
    return centre, (c * w[:, None]).T @ c


def _end_pieces(h: np.ndarray, faces: np.ndarray, w: np.ndarray) -> int:
    """How many more separate pieces the surface falls into at the low end of the heights ``h`` ``(n,)`` than
    at the high end (negative: fewer): each end slab (:data:`_END_SLAB` of the extent) cut out of the mesh,
    its connected pieces of at least :data:`_MIN_PIECE` of its area counted (a standing animal's four legs
    against its torso)."""
    from shape_toolkit.core.geometry import edge_components

    t = (h - h.min()) / max(float(np.ptp(h)), 1e-300)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    counts = []
    for inside in (t <= _END_SLAB, t >= 1.0 - _END_SLAB):
        _, label = edge_components(len(h), edges[inside[edges[:, 0]] & inside[edges[:, 1]]])
        area = np.bincount(label[inside], w[inside])
        counts.append(int((area >= _MIN_PIECE * area.sum()).sum()))
    return counts[0] - counts[1]


def _heavier_end(axis: np.ndarray, c: np.ndarray) -> np.ndarray:
    """``axis`` ``(3,)`` signed so that the centroid (the origin of the centred vertices ``c``) lies
    on its positive half of the extent: the heavier end first (legs, stems and tails are thinner
    than what they carry). An exact tie keeps the sign of the largest component."""
    h = c @ axis
    mid = 0.5 * (h.max() + h.min())
    if mid > 0 or (mid == 0 and axis[np.argmax(np.abs(axis))] < 0):
        return -axis
    return axis


def upright_frame(
    vertices: np.ndarray, faces: np.ndarray | None = None, *, up: str = "auto"
) -> tuple[np.ndarray, np.ndarray]:
    """The view of every render: ``(R, centre)`` with the rows of ``R`` ``(3, 3)`` the screen's
    right, depth (into the screen) and up directions in input coordinates and ``centre`` ``(3,)``
    the area centroid, so ``(vertices - centre) @ R.T`` are view coordinates (x right, y depth,
    z up). Depends on the shape alone: the same for any rigid motion of the input and any vertex order.

    The rule, from the area-weighted principal axes e1, e2, e3 (largest spread first):
    - ``up="auto"`` (the default): the longest axis e1 is up (a standing person, a bottle, a bird at rest),
      unless the shape stands on legs across the longest axis: cut a slab of a third of the extent off each
      end of an axis and count the separate pieces of the surface in each (pieces of at least 2% of the
      slab's area); when the two ends of e2 differ by at least two more pieces than those of e1 (a
      quadruped: four legs below, one torso above; one piece more is a head or a tail), e2 is up. The sign:
      when the two ends of the up axis differ by two or more pieces, the end with more is down (legs);
      otherwise as below. A point cloud (no faces to cut) keeps e1 and the rule below;
    - ``"longest"``: up is e1, right is e2; ``"middle"``: up is e2, right is e1;
    - the view is along e3, the thinnest direction, so the screen shows the broadest silhouette;
    - the sign of up (unless the pieces decided it) and of right: the area centroid lies above the middle
      of the shape's extent, i.e. the heavier end is up (a body stands on its legs); depth completes a
      proper rotation, so a render is never a mirror image.
    Symmetric shapes (equal spreads, or a centroid exactly mid-extent) have no preferred frame; a
    deterministic one is taken."""
    if up not in UP_RULES:
        raise ParameterError(f"up must be one of {', '.join(map(repr, UP_RULES))}, got {up!r}")
    # every step is scale-free: on coordinates divided by a power of two near the largest (exact), so areas and
    # second moments stay finite whatever the units (1e100 coordinates made the covariance NaN)
    scale = coordinate_scale(vertices)
    v = np.asarray(vertices, dtype=np.float64) / scale
    centre, cov = _moments(v, faces)
    _, vec = np.linalg.eigh(cov)
    e1, e2 = vec[:, 2], vec[:, 1]
    c = v - centre
    legs = 0  # pieces more at the low end of the up axis than at its high end (auto; 0: not counted)
    if up == "auto" and faces is not None and len(faces):
        f, w = np.asarray(faces, dtype=np.int64), _vertex_weights(v, faces)
        by_axis = [_end_pieces(c @ e1, f, w), _end_pieces(c @ e2, f, w)]
        up = "middle" if abs(by_axis[1]) >= abs(by_axis[0]) + _LEGS else "longest"
        legs = by_axis[up == "middle"]
    upward, right = (e2, e1) if up == "middle" else (e1, e2)
    upward = -upward if legs <= -_LEGS else upward if legs >= _LEGS else _heavier_end(upward, c)
    right = _heavier_end(right, c)
    depth = np.cross(upward, right)  # (right, depth, up) right-handed: det(R) = +1
    return np.stack([right, depth, upward]), centre * scale


def _frame(v: np.ndarray, faces: np.ndarray | None = None, up: str = "auto") -> np.ndarray:
    """View coordinates ``(n, 3)`` (x right, y into the screen, z up) of :func:`upright_frame`."""
    r, centre = upright_frame(v, faces, up=up)
    return (np.asarray(v, dtype=np.float64) - centre) @ r.T


#: direction of the light of every render (view frame: x right, y into the screen, z up)
_LIGHT = np.array([0.3, -1.0, 0.6]) / np.linalg.norm([0.3, -1.0, 0.6])
#: Lambert shading: ambient share, the rest scales with |cos| of the normal to the light
_AMBIENT = 0.35


def _shaded_faces(v: np.ndarray, faces: np.ndarray, colors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangles ``(m, 3, 3)`` of view-frame vertices ``v`` and their Lambert-shaded face colours
    ``(m, 3)`` in [0, 1]: the mean vertex colour times ``ambient + (1 - ambient) |n . light|``
    (two-sided, so no face goes black when seen from behind)."""
    tri = v[faces]
    t = tri / coordinate_scale(tri)  # the normals' directions on exactly rescaled coordinates: no overflow at 1e100
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    shade = _AMBIENT + (1.0 - _AMBIENT) * np.abs(n @ _LIGHT)
    return tri, np.clip(colors[faces].mean(axis=1) * shade[:, None], 0, 1)


#: the camera looks down on the shape by this angle (radians): a little of the top shows
_ELEVATION = np.radians(10.0)
#: PNG text chunk where a render records its panels' boxes (pixels: left, top, width, height)
PANELS_KEY = "shape-toolkit-panels"


def _project(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthographic projection of view coordinates ``v`` ``(n, 3)`` seen from ``_ELEVATION`` above:
    screen positions ``(n, 2)`` (x right, y up) and depths ``(n,)`` (larger: farther)."""
    ce, se = np.cos(_ELEVATION), np.sin(_ELEVATION)
    return np.column_stack([v[:, 0], v[:, 2] * ce + v[:, 1] * se]), v[:, 1] * ce - v[:, 2] * se


class _View:
    """One shape as drawn: view coordinates, screen positions, depths and the screen bounding box."""

    def __init__(self, v: np.ndarray):
        self.v = v
        self.xy, self.depth = _project(v)
        lo, hi = self.xy.min(axis=0), self.xy.max(axis=0)
        # a scale that the coordinates can resolve, even when every point is the same one (span 0)
        span = max(float((hi - lo).max()), 1e-6 * float(np.abs(np.concatenate([lo, hi])).max()), 1e-12)
        pad = np.maximum(hi - lo, 1e-3 * span) * 0.01 + 1e-3 * span
        self.lo, self.hi = lo - pad, hi + pad

    @property
    def aspect(self) -> float:
        """Width over height of the screen bounding box."""
        e = self.hi - self.lo
        return float(e[0] / e[1])


def _draw(ax, shape: Shape, view: _View, colors: np.ndarray, points: np.ndarray | None, point_size: float) -> None:
    """Draw ``shape`` in the 2D axes ``ax``, far to near (painter's order), limits its bounding box."""
    from matplotlib.collections import PolyCollection

    if shape.is_mesh:
        _, fc = _shaded_faces(view.v, shape.faces, colors)
        order = np.argsort(-view.depth[shape.faces].mean(axis=1), kind="stable")
        tri = view.xy[shape.faces[order]]
        ax.add_collection(PolyCollection(tri, facecolors=fc[order], edgecolors=fc[order], linewidths=0.25))
    else:
        order = np.argsort(-view.depth, kind="stable")
        ax.scatter(view.xy[order, 0], view.xy[order, 1], c=colors[order], s=2, linewidths=0)
    if points is not None and len(points):
        # drawn after the surface: a keypoint on the far side or in a fold is still shown
        p = view.xy[np.asarray(points, dtype=np.int64)]
        ax.scatter(p[:, 0], p[:, 1], c="red", s=point_size, edgecolors="black", linewidths=0.5, zorder=10)
    ax.set_xlim(view.lo[0], view.hi[0])
    ax.set_ylim(view.lo[1], view.hi[1])
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_axis_off()


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


def _save_with_panels(fig, path: Path, dpi: int, boxes: list[tuple[float, float, float, float]], height: float,
                      pdf: bool = False) -> None:
    """Save ``fig`` to ``path`` (and with ``pdf`` the same figure to ``path`` with the suffix ``.pdf``); a PNG
    records its panels' boxes (inches from the bottom left, figure ``height`` inches) as pixels from the top left
    in the text chunk :data:`PANELS_KEY`."""
    import json

    for out in (path, path.with_suffix(".pdf")) if pdf and path.suffix.lower() != ".pdf" else (path,):
        meta = None
        if out.suffix.lower() == ".png":
            px = [[round(x * dpi), round((height - y - h) * dpi), round(w * dpi), round(h * dpi)]
                  for x, y, w, h in boxes]
            meta = {PANELS_KEY: json.dumps(px)}
        elif out.suffix.lower() == ".pdf":
            meta = {"CreationDate": None}
        fig.savefig(out, dpi=dpi, metadata=meta)


#: layout of :func:`render_shapes` (inches): outer margin, gap between panels, narrowest panel
_MARGIN, _GAP, _MIN_PANEL = 0.05, 0.15, 1.2


def render_shapes(
    panels: list[dict],
    path: str | os.PathLike,
    *,
    panel_size: float = 3.2,
    dpi: int = 100,
    title: str | None = None,
    up: str = "auto",
    max_width: float | None = None,
    pdf: bool = False,
) -> Path:
    """Render several shapes side by side into one PNG (or PDF, by the suffix of ``path``; ``pdf``: the same
    figure also as ``path`` with the suffix ``.pdf``). Each
    panel is a dict of :func:`render_shape` arguments (``shape`` plus optional scalars/labels/colors/
    points/title/cmap/vmin/vmax/up, and ``colorbar``: a label string to draw a colour bar of the
    scalars). Every shape is upright (:func:`upright_frame` with the panel's ``up`` rule, default
    ``up``) and cropped tight: its panel is ``panel_size`` inches high and as wide as the shape's
    projection (at least 1.2 in), the whole scaled down to ``max_width`` inches when wider. A PNG
    records its panels' pixel boxes in the text chunk :data:`PANELS_KEY`."""
    _, plt = _mpl()
    if not panels:
        raise ParameterError("nothing to render")
    items = []
    for pnl in panels:
        pnl = dict(pnl)
        shape = pnl.pop("shape")
        cols = _colors_for(shape, pnl.get("scalars"), pnl.get("labels"), pnl.get("colors"),
                           pnl.get("cmap", "viridis"), pnl.get("vmin"), pnl.get("vmax"))
        view = _View(_frame(shape.vertices, shape.faces if shape.is_mesh else None, pnl.get("up", up)))
        items.append((shape, pnl, cols, view))
    h = float(panel_size)
    widths = np.array([h * view.aspect for *_, view in items])
    gaps = _GAP * (len(items) - 1) + 2 * _MARGIN
    if max_width is not None and widths.sum() + gaps > max_width:
        scale = max(max_width - gaps, 0.5) / widths.sum()
        h, widths = h * scale, widths * scale
    cells = np.maximum(widths, _MIN_PANEL)  # a panel narrower than its title: centred in a wider cell
    width = float(cells.sum() + gaps)
    fs = 11
    sup = _wrap(title, width, fs) if title else None
    head = 0.22 * (sup.count("\n") + 1) + 0.08 if sup else 0.0
    subs = [_wrap(p["title"], c, 10) if p.get("title") else None for (_, p, _, _), c in zip(items, cells)]
    sub_h = max((0.19 * (t.count("\n") + 1) + 0.06 for t in subs if t), default=0.0)
    foot = 0.6 if any(p.get("colorbar") and p.get("scalars") is not None for _, p, _, _ in items) else 0.0
    height = _MARGIN + head + sub_h + h + foot + _MARGIN
    fig = plt.figure(figsize=(width, height))
    boxes = []
    x = _MARGIN
    for (shape, pnl, cols, view), w, cell, sub in zip(items, widths, cells, subs):
        left, bottom = x + (cell - w) / 2, _MARGIN + foot
        ax = fig.add_axes((left / width, bottom / height, w / width, h / height))
        _draw(ax, shape, view, cols, pnl.get("points"), pnl.get("point_size", 30.0))
        boxes.append((left, bottom, float(w), h))
        if sub:
            fig.text((x + cell / 2) / width, (bottom + h + 0.04) / height, sub, ha="center", va="bottom", fontsize=10)
        if foot:
            if pnl.get("colorbar") and pnl.get("scalars") is not None:
                import matplotlib as mpl

                xs = np.asarray(pnl["scalars"], dtype=np.float64)
                fin = xs[np.isfinite(xs)]
                lo = pnl.get("vmin", fin.min() if fin.size else 0.0)
                hi = pnl.get("vmax", fin.max() if fin.size else 1.0)
                norm = mpl.colors.Normalize(lo, hi if hi > lo else lo + 1)
                sm = mpl.cm.ScalarMappable(norm=norm, cmap=pnl.get("cmap", "viridis"))
                cax = fig.add_axes(((x + 0.1 * cell) / width, (_MARGIN + 0.36) / height, 0.8 * cell / width,
                                    0.12 / height))
                cb = fig.colorbar(sm, cax=cax, orientation="horizontal")
                cb.set_label(str(pnl["colorbar"]), fontsize=9)
                cb.ax.tick_params(labelsize=8)
        x += cell + _GAP
    if sup:
        fig.text(0.5, 1 - _MARGIN / height, sup, ha="center", va="top", fontsize=fs)
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    _save_with_panels(fig, p, dpi, boxes, height, pdf)
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
    up: str = "auto",
) -> Path:
    """Render ``shape`` to a PNG at ``path`` (headless): per-vertex ``scalars`` ``(n,)``,
    ``labels`` ``(n,)`` or RGB ``colors`` ``(n, 3)`` (0..1 or 0..255), and ``points`` (vertex ids)
    drawn as red dots; upright by the ``up`` rule of :func:`upright_frame`, ``size`` inches high and
    cropped to the shape. Returns the path."""
    pts = _point_ids(shape, points)
    panel = {
        "shape": shape,
        "scalars": scalars,
        "labels": labels,
        "colors": colors,
        "points": pts,
        "cmap": cmap,
        "title": title,
    }
    return render_shapes([panel], path, panel_size=size, dpi=dpi, up=up)


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


def _point_ids(shape: Shape, points: np.ndarray | None) -> np.ndarray | None:
    """``points`` as int64 vertex ids ``(q,)``, checked to lie in the shape (a negative id would wrap)."""
    if points is None:
        return None
    pts = np.asarray(points, dtype=np.float64).ravel()
    if pts.size and (not np.all(pts == np.round(pts)) or pts.min() < 0 or pts.max() >= shape.n_vertices):
        raise ParameterError(f"points must be vertex ids in [0, {shape.n_vertices - 1}]")
    return pts.astype(np.int64)


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
    up: str = "auto",
):
    """An interactive 3D view for notebooks: a plotly ``Figure`` (``Mesh3d`` with per-vertex
    colours, or a point cloud) showing ``scalars`` ``(n,)``, ``labels`` ``(n,)`` or RGB ``colors``
    ``(n, 3)``, with ``points`` (vertex ids) as red markers; ``height`` in pixels. The camera starts
    as in :func:`render_shape`: the shape upright, seen along its thinnest axis (``up``: see
    :func:`upright_frame`). Displayed inline when it is the last expression of a cell. Needs plotly
    (the ``viz`` extra)."""
    try:
        import plotly.graph_objects as go
    except ImportError:
        raise ParameterError(
            "show() needs plotly, part of the optional 'viz' extra: pip install 'shape-toolkit[viz]'"
        ) from None
    cols = _colors_for(shape, scalars, labels, colors, cmap)
    rgb = [f"rgb({r},{g},{b})" for r, g, b in np.clip(np.round(cols * 255), 0, 255).astype(int).tolist()]
    # upright as in render_shape: view coordinates (x right, y away from the camera, z up)
    v = _frame(shape.vertices, shape.faces if shape.is_mesh else None, up)
    data = []
    if shape.is_mesh:
        f = shape.faces
        data.append(go.Mesh3d(x=v[:, 0], y=v[:, 1], z=v[:, 2], i=f[:, 0], j=f[:, 1], k=f[:, 2],
                              vertexcolor=rgb, flatshading=False, hoverinfo="skip", name="shape"))
    else:
        data.append(go.Scatter3d(x=v[:, 0], y=v[:, 1], z=v[:, 2], mode="markers",
                                 marker={"size": 2, "color": rgb}, name="shape"))
    pts = _point_ids(shape, points)
    if pts is not None and len(pts):
        p = v[pts]
        data.append(go.Scatter3d(x=p[:, 0], y=p[:, 1], z=p[:, 2], mode="markers",
                                 marker={"size": 5, "color": "red"}, name="points"))
    fig = go.Figure(data=data)
    fig.update_layout(title=title, height=height, margin={"l": 0, "r": 0, "t": 30 if title else 0, "b": 0},
                      scene={"aspectmode": "data", "xaxis": {"visible": False}, "yaxis": {"visible": False},
                             "zaxis": {"visible": False},
                             "camera": {"up": {"x": 0, "y": 0, "z": 1}, "eye": {"x": 0, "y": -2.0, "z": 0.35}}},
                      showlegend=False)
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
    up: str = "auto",
    pdf: bool = False,
) -> Path:
    """Dense trajectories over a sequence, as in thesis Figs. 7.17-7.18: a PNG with the chosen
    ``frames`` side by side (default all, at most 9 evenly spaced; ``pdf``: the same figure also as
    ``path`` with the suffix ``.pdf``), or an animated GIF (``path`` ending in ``.gif``, one frame per
    sequence frame, ``fps`` frames per second, Pillow).

    ``shapes``: the ``T`` frames; ``trajectories`` int ``(n_0, T)``: vertex of frame ``t`` reached
    by the trajectory of vertex ``j`` of frame 0 (``-1`` lost). Each frame is drawn with its
    vertex ``colors`` (``(n_t, 3)`` in [0, 1], e.g. pull-back colours; default the shape's own
    colours, else grey) and the tails
    of ``n_tracks`` trajectories (farthest-point sample of frame 0, deterministic) over the last
    ``tail`` frames as polylines, blue (oldest) to green (current) as in the thesis. All frames
    share one view, cropped to the box of all frames: the upright frame of frame 0
    (:func:`upright_frame` with the ``up`` rule), the same rule as :func:`render_shape`."""
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
    # one view for every frame: the upright frame of frame 0 (the rule of render_shape)
    r0, c0 = upright_frame(shapes[0].vertices, shapes[0].faces if shapes[0].is_mesh else None, up=up)
    views = [(s.vertices - c0) @ r0.T for s in shapes]
    drawn = [_View(v) for v in views]
    lo = np.min([d.lo for d in drawn], axis=0)
    hi = np.max([d.hi for d in drawn], axis=0)
    aspect = float((hi - lo)[0] / (hi - lo)[1])
    tracks = _spread_tracks(views[0], ids, n_tracks)
    blue_green = np.array([[0.1, 0.3, 1.0], [0.1, 0.85, 0.2]])

    def draw(ax, t: int) -> None:
        from matplotlib.collections import LineCollection

        s, d = shapes[t], drawn[t]
        _draw(ax, s, d, cols[t], None, 0.0)
        segs, segc = [], []
        first = max(0, t - tail)
        for k in range(first, t):
            a, b = ids[tracks, k], ids[tracks, k + 1]
            ok = (a >= 0) & (b >= 0)
            segs.append(np.stack([drawn[k].xy[a[ok]], drawn[k + 1].xy[b[ok]]], axis=1))
            w = (k + 1 - first) / max(t - first, 1)
            segc += [blue_green[0] * (1 - w) + blue_green[1] * w] * int(ok.sum())
        if segs and sum(len(x) for x in segs):
            ax.add_collection(LineCollection(np.concatenate(segs), colors=segc, linewidths=0.9, alpha=0.85, zorder=5))
        alive = ids[tracks, t]
        q = d.xy[alive[alive >= 0]]
        if len(q):
            ax.scatter(q[:, 0], q[:, 1], c=[blue_green[1]], s=4, zorder=6)
        ax.set_xlim(lo[0], hi[0])  # one box for all frames: the motion shows
        ax.set_ylim(lo[1], hi[1])

    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    w = panel_size * aspect
    cell = max(w, _MIN_PANEL)
    label_h = 0.25
    if p.suffix.lower() == ".gif":
        from matplotlib.animation import FuncAnimation, PillowWriter

        ph = panel_size * 1.3  # one frame at a time: a larger panel
        gw = ph * aspect
        gcell = max(gw, _MIN_PANEL * 1.3)
        sup = _wrap(title, gcell, 10) if title else None
        head = 0.2 * (sup.count("\n") + 1) + 0.08 if sup else 0.0
        width, height = gcell + 2 * _MARGIN, ph + label_h + head + 2 * _MARGIN
        fig = plt.figure(figsize=(width, height))
        ax = fig.add_axes(((_MARGIN + (gcell - gw) / 2) / width, _MARGIN / height, gw / width, ph / height))
        label = fig.text(0.5, (_MARGIN + ph + 0.04) / height, "", ha="center", va="bottom", fontsize=10)

        def update(t: int) -> list:
            ax.clear()
            draw(ax, t)
            label.set_text(f"frame {t}")
            return []

        if sup:
            fig.text(0.5, 1 - _MARGIN / height, sup, ha="center", va="top", fontsize=10)
        anim = FuncAnimation(fig, update, frames=range(T), blit=False)
        anim.save(p, writer=PillowWriter(fps=float(fps)), dpi=dpi)
        plt.close(fig)
        return p
    n = len(frames)
    width = cell * n + _GAP * (n - 1) + 2 * _MARGIN
    sup = _wrap(title, width, 11) if title else None
    head = 0.22 * (sup.count("\n") + 1) + 0.08 if sup else 0.0
    height = panel_size + label_h + head + 2 * _MARGIN
    fig = plt.figure(figsize=(width, height))
    boxes = []
    for i, t in enumerate(frames):
        x = _MARGIN + i * (cell + _GAP)
        left = x + (cell - w) / 2
        ax = fig.add_axes((left / width, _MARGIN / height, w / width, panel_size / height))
        draw(ax, t)
        boxes.append((left, _MARGIN, w, panel_size))
        fig.text((x + cell / 2) / width, (_MARGIN + panel_size + 0.04) / height, f"frame {t}", ha="center",
                 va="bottom", fontsize=10)
    if sup:
        fig.text(0.5, 1 - _MARGIN / height, sup, ha="center", va="top", fontsize=11)
    _save_with_panels(fig, p, dpi, boxes, height, pdf)
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
