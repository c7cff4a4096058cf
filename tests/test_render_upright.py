"""Renders a researcher can put in a supplement (issue 28 item 3): shapes upright by a stated rule that
depends on the shape alone (the same view for any rigid motion of the input and any vertex order), and
cropped tight (no panel more than 15% empty, measured on the rendered pixels)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import empty_fraction, read_render
from scipy.spatial.transform import Rotation

from shape_toolkit.core.shape import Shape
from shape_toolkit.data.synthetic import articulated_shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.viz import _frame, method_colors, render_shape, render_shapes, upright_frame

_BOX_FACES = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                       [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]])


def _boxes(boxes: list[tuple[tuple[float, float, float], tuple[float, float, float]]]) -> Shape:
    """A mesh of axis-aligned boxes ``(low corner, high corner)``, each subdivided a little."""
    verts, faces = [], []
    for lo, hi in boxes:
        corners = np.array([[hi[0] if i & 1 else lo[0], hi[1] if i & 2 else lo[1], hi[2] if i & 4 else lo[2]]
                            for i in range(8)])
        faces.append(_BOX_FACES + sum(len(v) for v in verts))
        verts.append(corners)
    return Shape(np.concatenate(verts), np.concatenate(faces))


def _figure() -> Shape:
    """A standing figure, z up: two thin legs, a broad torso, a head and one raised arm (so that no
    symmetry leaves its frame undefined). Tallest along z, broadest along x, thinnest along y."""
    return _boxes([((-0.7, -0.25, 0.0), (-0.2, 0.25, 1.6)),  # legs
                   ((0.2, -0.25, 0.0), (0.7, 0.25, 1.6)),
                   ((-1.0, -0.4, 1.6), (1.0, 0.4, 3.4)),  # torso
                   ((-0.35, -0.3, 3.4), (0.35, 0.3, 4.0)),  # head
                   ((1.0, -0.2, 2.2), (1.9, 0.2, 3.3))])  # one arm, held out


def _rigid(shape: Shape, seed: int) -> tuple[Shape, np.ndarray]:
    """``shape`` moved by a random rotation and translation, its vertices in a random order (and
    the faces renumbered): returns it and the permutation (new vertex i is old vertex perm[i])."""
    rng = np.random.default_rng(seed)
    rot = Rotation.random(random_state=seed).as_matrix()
    perm = rng.permutation(shape.n_vertices)
    inv = np.empty_like(perm)
    inv[perm] = np.arange(len(perm))
    v = shape.vertices[perm] @ rot.T + rng.normal(size=3) * 10
    return Shape(v, inv[shape.faces][rng.permutation(shape.n_faces)]), perm


def _quadruped() -> tuple[Shape, np.ndarray]:
    """A four-legged animal: an elongated torso (a sphere stretched to twice its length) on four legs, with a
    neck and head and a tail; returns it and its part labels (0 torso, 1-4 legs, 5 neck and head, 6 tail)."""
    limbs = np.array([[0.8, -1, 0.6], [0.8, -1, -0.6], [-0.8, -1, 0.6], [-0.8, -1, -0.6], [1, 0.8, 0], [-1, 0.4, 0]])
    a = articulated_shape(subdivisions=4, limbs=limbs, limb_length=[1.6, 1.6, 1.6, 1.6, 1.2, 1.0], limb_radius=0.2,
                          cap_angle=0.3)
    return Shape(a.shape.vertices * np.array([2.0, 1.0, 0.8]), a.shape.faces), a.labels


@pytest.mark.parametrize("up", ["auto", "longest", "middle"])
def test_the_view_depends_on_the_shape_alone(up):
    for shape in (_figure(), articulated_shape(subdivisions=2, random_state=3).shape, _quadruped()[0]):
        view = _frame(shape.vertices, shape.faces, up)
        for seed in range(4):
            moved, perm = _rigid(shape, seed)
            r, _ = upright_frame(moved.vertices, moved.faces, up=up)
            assert np.isclose(np.linalg.det(r), 1.0)  # a rotation: never a mirror image
            np.testing.assert_allclose(_frame(moved.vertices, moved.faces, up), view[perm], atol=1e-8)


def test_a_standing_shape_is_drawn_upright_whatever_its_pose():
    figure = _figure()
    legs = figure.vertices[:, 2] < 1.6 - 1e-9
    head = figure.vertices[:, 2] > 3.4 + 1e-9
    for seed in range(6):
        moved, perm = _rigid(figure, seed)  # lying on its side, upside down, ...
        v = _frame(moved.vertices, moved.faces)
        up, right = v[:, 2], v[:, 0]
        assert np.ptp(up) > np.ptp(right) > np.ptp(v[:, 1])  # tallest up, thinnest along the view
        assert up[head[perm]].min() > up.max() - 0.61 and up[legs[perm]].max() < up.min() + 1.61  # head up, feet down
    # the rule for shapes that are longest lying down: the longest extent horizontal
    v = _frame(figure.vertices, figure.faces, "middle")
    assert np.ptp(v[:, 0]) > np.ptp(v[:, 2])
    with pytest.raises(ParameterError, match="up must be one of"):
        upright_frame(figure.vertices, figure.faces, up="sideways")


def test_a_quadruped_stands_on_its_legs_whatever_its_pose():
    """Longest across (its body), the automatic rule stands it on its four legs, head and tail up; the
    longest-axis rule stood it on its tail."""
    animal, labels = _quadruped()
    legs, body = np.isin(labels, [1, 2, 3, 4]), labels == 0
    for seed in range(6):
        moved, perm = _rigid(animal, seed)
        v = _frame(moved.vertices, moved.faces)
        up = v[:, 2]
        assert np.ptp(v[:, 0]) > np.ptp(up)  # its length across the screen
        assert up[legs[perm]].min() == up.min()  # the feet are the lowest points
        assert up[body[perm]].min() > up.min() + 0.25 * np.ptp(up)  # the torso is carried, not lying
        old = _frame(moved.vertices, moved.faces, "longest")[:, 2]
        assert old[body[perm]].min() < old.min() + 0.25 * np.ptp(old)  # the former default: not on its legs


def test_one_panel_is_cropped_tight(tmp_path):
    shapes = [_rigid(_figure(), 1)[0], articulated_shape(subdivisions=2, random_state=0).shape,
              Shape(articulated_shape(subdivisions=2, random_state=2).shape.vertices)]  # and a point cloud
    for i, s in enumerate(shapes):
        img, _ = read_render(render_shape(s, tmp_path / f"{i}.png", size=3.0))
        assert empty_fraction(img) <= 0.15, (i, empty_fraction(img))


def test_every_panel_of_a_figure_is_cropped_tight(tmp_path):
    a = articulated_shape(subdivisions=2, random_state=0)
    panels = [{"shape": _rigid(_figure(), 2)[0], "title": "a standing figure, moved"},
              {"shape": a.shape, "labels": a.labels, "title": "labels"},
              {"shape": a.shape, "scalars": a.shape.vertices[:, 0], "colorbar": "x", "title": "with a colour bar"}]
    img, boxes = read_render(render_shapes(panels, tmp_path / "p.png", panel_size=3.0, title="three panels"))
    assert boxes is not None and len(boxes) == 3
    for box in boxes:
        assert empty_fraction(img, box) <= 0.15, (box, empty_fraction(img, box))
    img2, boxes2 = read_render(render_shapes(panels, tmp_path / "q.png", panel_size=3.0, max_width=6.0))
    assert img2.shape[1] <= 6.0 * 100 + 1 and all(empty_fraction(img2, b) <= 0.15 for b in boxes2)


def test_method_colours_are_one_per_method_and_stable():
    c = method_colors(["b", "a", "c", "a"])
    assert list(c) == ["a", "b", "c"] and len(set(c.values())) == 3
    assert method_colors(["c", "b", "a"]) == c  # any order of the same names


def test_the_report_takes_the_up_rule_and_refuses_another(tmp_path, capsys):
    from shape_toolkit.bench.report import write_report
    from shape_toolkit.cli import main

    with pytest.raises(ParameterError, match="up must be one of"):
        write_report(tmp_path, up="sideways")  # before any work: not even the run folder is looked at
    assert main(["bench", "report", str(tmp_path), "--up", "sideways"]) == 2  # one line, exit 2
    assert "--up" in capsys.readouterr().err
