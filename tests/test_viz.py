"""Headless rendering writes real images; coloured PLY files open in Open3D."""

from __future__ import annotations

import numpy as np
import pytest

from shape_toolkit.core.shape import Shape
from shape_toolkit.data.synthetic import articulated_shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.viz import label_colors, match_colors, render_shape, render_shapes, save_colored_ply


@pytest.fixture(scope="module")
def body():
    a = articulated_shape(subdivisions=2, random_state=1)
    return a.shape, a.labels


def _pixels(path):
    import matplotlib.image as mpimg

    return mpimg.imread(path)


def test_render_labels_and_points(body, tmp_path):
    s, labels = body
    p = render_shape(s, tmp_path / "a.png", labels=labels, points=[0, 10], title="parts")
    img = _pixels(p)
    assert p.stat().st_size > 1000
    assert img.ndim == 3 and img[..., :3].std() > 0.05
    # several distinct colours appear (one per part, plus background and shading)
    assert len(np.unique((img[..., :3] * 15).round().reshape(-1, 3), axis=0)) > 6


def test_render_scalars_point_cloud_and_panels(body, tmp_path):
    s, _ = body
    cloud = Shape(s.vertices)
    p = render_shape(cloud, tmp_path / "c.png", scalars=s.vertices[:, 0])
    assert _pixels(p)[..., :3].std() > 0.02
    q = render_shapes([{"shape": s, "scalars": s.vertices[:, 1]}, {"shape": s}], tmp_path / "d.png")
    assert _pixels(q).shape[1] > _pixels(p).shape[1]


def test_render_rejects_bad_input(body, tmp_path):
    s, labels = body
    with pytest.raises(ParameterError):
        render_shape(s, tmp_path / "x.png", labels=labels[:-1])
    with pytest.raises(ParameterError):
        render_shape(s, tmp_path / "x.png", labels=labels, scalars=labels)
    with pytest.raises(ParameterError):
        render_shape(s, tmp_path / "x.png", points=[s.n_vertices])


def test_colored_ply_roundtrip_open3d(body, tmp_path):
    o3d = pytest.importorskip("open3d")
    s, labels = body
    cols = label_colors(labels)
    p = save_colored_ply(s, tmp_path / "s.ply", cols)
    m = o3d.io.read_triangle_mesh(str(p))
    assert len(m.vertices) == s.n_vertices and len(m.triangles) == s.n_faces
    np.testing.assert_allclose(np.asarray(m.vertex_colors), np.round(cols * 255) / 255, atol=1e-6)
    np.testing.assert_allclose(np.asarray(m.vertices), s.vertices)


def test_colored_ply_is_the_mesh_writer(body, tmp_path):
    """save_colored_ply writes exactly what save_shape writes for the shape with those colours (one
    PLY writer), reads back through load_shape to 8-bit colours, takes 0..255 input alike, and
    refuses out-of-range or NaN colours instead of clipping them."""
    from shape_toolkit.io.mesh import load_shape, save_shape

    s, labels = body
    cols = label_colors(labels)
    p = save_colored_ply(s, tmp_path / "v.ply", cols)
    save_shape(s.with_colors(cols), tmp_path / "m.ply")
    assert p.read_bytes() == (tmp_path / "m.ply").read_bytes()
    back = load_shape(p)
    np.testing.assert_array_equal(back.faces, s.faces)
    np.testing.assert_allclose(back.colors, np.round(cols * 255) / 255, atol=1e-12)
    q = save_colored_ply(s, tmp_path / "b.ply", np.round(cols * 255))
    assert q.read_bytes() == p.read_bytes()
    assert not list(tmp_path.glob(".*.tmp"))
    bad = cols.copy()
    bad[3, 0] = -0.5
    with pytest.raises(ParameterError):
        save_colored_ply(s, tmp_path / "x.ply", bad)
    bad[3, 0] = np.nan
    with pytest.raises(ParameterError):
        save_colored_ply(s, tmp_path / "x.ply", bad)
    with pytest.raises(ParameterError):
        save_colored_ply(s, tmp_path / "x.ply", cols * 300)
    assert not (tmp_path / "x.ply").exists()


def test_match_colors_identity_transfers_exactly(body):
    s, _ = body
    cs, ct = match_colors(s, s, np.arange(s.n_vertices))
    np.testing.assert_allclose(cs, ct)
    t = np.full(s.n_vertices, -1)
    _, ct2 = match_colors(s, s, t)
    assert np.allclose(ct2, ct2[0])  # all unmatched: uniform grey
    with pytest.raises(ParameterError):
        match_colors(s, s, np.arange(3))


def test_pullback_colours_every_source_vertex(body):
    from shape_toolkit.viz import pullback_colors

    s, _ = body
    rng = np.random.default_rng(0)
    t = rng.integers(0, s.n_vertices, s.n_vertices)
    cs, ct = pullback_colors(s, s, t)
    np.testing.assert_allclose(cs, ct[t])  # every source vertex takes its image's colour
    t[:5] = -1
    cs, _ = pullback_colors(s, s, t)
    assert np.allclose(cs[:5], cs[0]) and not np.allclose(cs[5:], cs[0])
    with pytest.raises(ParameterError):
        pullback_colors(s, s, np.full(s.n_vertices, s.n_vertices))


def test_align_labels_hungarian_gives_the_truth_palette(body):
    from shape_toolkit.viz import align_labels

    _, labels = body
    perm = np.array([3, 5, 0, 1, 2, 4])
    pred = perm[labels]
    aligned = align_labels(pred, labels)
    np.testing.assert_array_equal(aligned, labels)
    np.testing.assert_allclose(label_colors(aligned), label_colors(labels))
    extra = pred.copy()
    extra[:10] = 9  # a label without a partner gets a fresh value, not a truth colour
    out = align_labels(extra, labels)
    assert out[0] not in set(labels.tolist()) and set(out[10:].tolist()) <= set(labels.tolist())


def test_label_colour_depends_on_value_only():
    a = label_colors(np.array([0, 1, 2, -1]))
    b = label_colors(np.array([2, 2, 0, 1]))
    np.testing.assert_allclose(a[2], b[0])
    np.testing.assert_allclose(a[0], b[2])
    assert np.allclose(a[3], 0.75)


def test_plotly_show_figure(body):
    pytest.importorskip("plotly")
    from shape_toolkit.viz import show

    s, labels = body
    fig = show(s, labels=labels, points=[0, 1], title="parts")
    assert fig.data[0].type == "mesh3d" and len(fig.data[0].vertexcolor) == s.n_vertices
    assert fig.data[1].type == "scatter3d"
    for bad in ([-1], [s.n_vertices], [0.5]):  # a negative id would wrap silently
        with pytest.raises(ParameterError, match="vertex ids"):
            show(s, points=bad)


def test_colorbar_panel_and_long_title(body, tmp_path):
    s, _ = body
    u = s.vertices[:, 0] - s.vertices[:, 0].mean()
    p = render_shapes(
        [{"shape": s, "scalars": u, "cmap": "coolwarm", "vmin": -1, "vmax": 1, "colorbar": "value", "title": "x"}],
        tmp_path / "cb.png", title="a very long title " * 8,
    )
    assert _pixels(p).shape[0] > 300


def test_label_colors_cost_grows_with_distinct_labels_not_their_values():
    from shape_toolkit.viz import label_colors

    lab = np.array([0, 2**62, -1, 2**62, 3])  # a palette sized by the largest value would need exabytes
    c = label_colors(lab)
    assert c.shape == (5, 3) and np.allclose(c[1], c[3]) and not np.allclose(c[0], c[1])
    assert np.allclose(label_colors(np.array([3]))[0], c[4])  # a label's colour depends on its value only


def test_both_renderers_share_one_lambert_shading(body, tmp_path, monkeypatch):
    """_shaded_faces: a face turned to the light keeps its colour, one edge-on to it keeps the
    ambient share, a flipped face shades like the front; render_shape and render_trajectories
    both draw meshes through it."""
    from shape_toolkit import viz

    light = viz._LIGHT
    e1 = np.cross(light, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(light, e1)  # (e1, e2, light) right-handed: the face (0, e1, e2) has normal +light
    v = np.array([np.zeros(3), e1, e2, light])  # face (0, 1, 3) contains the light: edge-on
    faces = np.array([[0, 1, 2], [0, 2, 1], [0, 1, 3]])
    cols = np.array([[0.8, 0.4, 0.2]] * 4)
    tri, fc = viz._shaded_faces(v, faces, cols)
    assert tri.shape == (3, 3, 3)
    np.testing.assert_allclose(fc[0], [0.8, 0.4, 0.2], atol=1e-12)
    np.testing.assert_allclose(fc[1], fc[0], atol=1e-12)
    np.testing.assert_allclose(fc[2], viz._AMBIENT * np.array([0.8, 0.4, 0.2]), atol=1e-12)
    calls = []
    real = viz._shaded_faces
    monkeypatch.setattr(viz, "_shaded_faces", lambda *a: calls.append(1) or real(*a))
    s, _ = body
    render_shape(s, tmp_path / "a.png")
    viz.render_trajectories([s, s], np.column_stack([np.arange(s.n_vertices)] * 2), tmp_path / "t.png",
                            n_tracks=5)
    assert len(calls) == 3  # one panel, two frames


def test_a_shape_of_no_extent_renders(tmp_path):
    """A box of zero extent (a single point; a cloud of one repeated point, the bad-input corpus's
    all_same_point.xyz, is now refused when loaded): the panel's aspect ratio was NaN."""
    s = Shape(np.ones((1, 3)))
    assert render_shape(s, tmp_path / "same.png", title="one point").stat().st_size > 0
