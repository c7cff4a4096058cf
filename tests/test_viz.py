"""Headless rendering writes real images; coloured PLY files open in Open3D."""

from __future__ import annotations

import numpy as np
import pytest

from shape_toolkit.core.shape import Shape
from shape_toolkit.data.synthetic import articulated_shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.io.viz import label_colors, match_colors, render_shape, render_shapes, save_colored_ply


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


def test_match_colors_identity_transfers_exactly(body):
    s, _ = body
    cs, ct = match_colors(s, s, np.arange(s.n_vertices))
    np.testing.assert_allclose(cs, ct)
    t = np.full(s.n_vertices, -1)
    _, ct2 = match_colors(s, s, t)
    assert np.allclose(ct2, ct2[0])  # all unmatched: uniform grey
    with pytest.raises(ParameterError):
        match_colors(s, s, np.arange(3))
