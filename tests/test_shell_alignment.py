"""shell-alignment (the ``shells`` pipeline, issue 25): invariances, seeds, clouds, bad parameters, and the
gorilla-to-person pairs of the shared data."""

from __future__ import annotations

import numpy as np
import pytest

from shape_toolkit.api.registry import create_plugin
from shape_toolkit.core.shape import Shape
from shape_toolkit.data.synthetic import articulated_shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.features.geodesics import paired_geodesic_distances
from shape_toolkit.pipeline import run_pipeline


@pytest.fixture(scope="module")
def poses():
    return tuple(articulated_shape(subdivisions=3, random_state=r).shape for r in (1, 2))


def _error(target: Shape, target_of: np.ndarray) -> float:
    """Mean geodesic error / sqrt(area) against the identity (the generated poses share vertex order)."""
    ids = np.arange(target.n_vertices)
    return float(paired_geodesic_distances(target, ids, target_of, method="dijkstra").mean() / np.sqrt(target.area))


def test_a_moved_and_scaled_copy_maps_onto_itself(poses):
    a, _ = poses
    copy = Shape(np.asarray(a.vertices) * 3.0 + [5.0, 1.0, 2.0], a.faces)
    c = create_plugin("dense_matchers", "shell-alignment").match(a, copy)
    np.testing.assert_array_equal(c.target_of, np.arange(a.n_vertices))
    assert c.info["frame"] == "given" and c.info["residual"] == pytest.approx(0.0, abs=1e-12)


def test_two_poses_without_seeds_and_vertex_order(poses):
    a, b = poses
    c = run_pipeline("shells", a, b)
    assert _error(b, c.target_of) < 0.03  # unseeded zoomout is at 0.56 on this symmetric pair
    # the source's vertex order does not matter
    perm = np.random.default_rng(0).permutation(a.n_vertices)
    pa = Shape(np.asarray(a.vertices)[perm], np.argsort(perm)[np.asarray(a.faces)])
    cp = create_plugin("dense_matchers", "shell-alignment").match(pa, b)
    assert np.mean(cp.target_of == c.target_of[perm]) > 0.95


def test_seeds_are_kept_and_clouds_are_matched(poses):
    a, b = poses
    seeds = np.array([[0, 5], [10, 20]])
    c = create_plugin("dense_matchers", "shell-alignment").match(a, b, seeds=seeds)
    np.testing.assert_array_equal(c.target_of[seeds[:, 0]], seeds[:, 1])
    cloud = Shape(np.asarray(b.vertices))
    cc = create_plugin("dense_matchers", "shell-alignment").match(a, cloud)
    assert cc.n_matched == a.n_vertices and _error(b, cc.target_of) < 0.1


def test_alignment_on_samples_agrees_with_every_vertex_keeps_seeds_and_vertex_order(poses):
    """The alignment on 200 of the 642 vertices (farthest points weighted by their Voronoi cells): as
    accurate as on every vertex, the seeds kept although few are samples, and the same map, ties aside,
    whatever the source's vertex order (the first sample does not depend on it)."""
    a, b = poses
    full = create_plugin("dense_matchers", "shell-alignment", samples=None).match(a, b)
    sampled = create_plugin("dense_matchers", "shell-alignment", samples=200).match(a, b)
    assert _error(b, sampled.target_of) < max(0.03, 1.5 * _error(b, full.target_of))
    assert np.mean(sampled.target_of == full.target_of) < 1.0  # the samples do change the run
    seeds = np.array([[1, 7], [333, 400]])
    c = create_plugin("dense_matchers", "shell-alignment", samples=200).match(a, b, seeds=seeds)
    np.testing.assert_array_equal(c.target_of[seeds[:, 0]], seeds[:, 1])
    perm = np.random.default_rng(3).permutation(a.n_vertices)
    pa = Shape(np.asarray(a.vertices)[perm], np.argsort(perm)[np.asarray(a.faces)])
    cp = create_plugin("dense_matchers", "shell-alignment", samples=200).match(pa, b)
    assert np.mean(cp.target_of == sampled.target_of[perm]) > 0.95
    # a cloud (no normals) goes through the same sampled alternation
    cc = create_plugin("dense_matchers", "shell-alignment", samples=200).match(a, Shape(np.asarray(b.vertices)))
    assert cc.n_matched == a.n_vertices and _error(b, cc.target_of) < 0.03


@pytest.mark.parametrize("bad", [{"k_schedule": []}, {"k_schedule": [10, 6]}, {"k_schedule": [1, 6]},
                                 {"alpha": -1}, {"beta": float("nan")}, {"mu": "big"}, {"iters": 0},
                                 {"samples": 0}, {"samples": 2.5}])
def test_bad_parameters_are_refused(poses, bad):
    a, b = poses
    with pytest.raises(ParameterError):
        create_plugin("dense_matchers", "shell-alignment", **bad).match(a, b)


@pytest.mark.slow
def test_gorilla_to_a_man_below_the_spectral_pipelines(shared_data):
    """8_gorilla_05 -> 8_man_05, a tuning pair of the field benchmark's split by subject: zoomout and pyFM are at
    0.54 and 0.63 there (the fit of WKS descriptors fails between a gorilla and a man); BCICP's published
    map 0.052."""
    from shape_toolkit.data.datasets import read_vts
    from shape_toolkit.io.mesh import load_shape

    root = shared_data / "tosca_noniso"
    A, B = load_shape(root / "8_gorilla_05.off"), load_shape(root / "8_man_05.off")
    ta = read_vts(root / "corres" / "8_gorilla_05.vts", A.n_vertices)
    tb = read_vts(root / "corres" / "8_man_05.vts", B.n_vertices)
    t = run_pipeline("shells", A, B).target_of
    err = float(paired_geodesic_distances(B, tb, t[ta], method="dijkstra").mean() / np.sqrt(B.area))
    assert err < 0.2, err


def test_a_crop_is_placed_on_the_other_pose_by_the_part_alone():
    """A generated shape with 30% of its area cut away (one geodesic ball, the ``crop`` corruption) matched to
    another pose of it: with ``partial`` only the part pulls, from its place on the whole (the partial
    functional map's support), and the map is close to the crop's back-map; the bijective shells, pulled by the
    whole's every point, and the partial functional map it starts from are not."""
    from shape_toolkit.data.corruptions import crop
    from shape_toolkit.plugins.matching.dense.fmap_zoomout import FmapZoomOutMatcher

    a, b = (articulated_shape(subdivisions=3, random_state=r).shape for r in (1, 2))
    part, back = crop(a, strength=0.3, random_state=1, attempts=20)

    def error(target_of: np.ndarray) -> float:
        return float(paired_geodesic_distances(b, back, target_of, method="dijkstra").mean() / np.sqrt(b.area))

    c = create_plugin("dense_matchers", "shell-alignment", partial=True).match(part, b)
    assert c.info["partial"]["area_ratio"] == pytest.approx(part.area / b.area, rel=1e-3)  # the areas' ratio
    bijective = create_plugin("dense_matchers", "shell-alignment").match(part, b)
    start = FmapZoomOutMatcher(partial=True).match(part, b)
    assert error(c.target_of) < 0.03  # measured 0.014
    assert error(bijective.target_of) > 3 * error(c.target_of)  # measured 0.098
    assert error(start.target_of) > 3 * error(c.target_of)  # measured 0.40


def test_partial_shell_parameters_are_refused_in_one_line(poses):
    a, b = poses
    with pytest.raises(ParameterError, match="area_ratio.*needs partial"):
        create_plugin("dense_matchers", "shell-alignment", area_ratio=0.5).match(a, b)
    m = create_plugin("dense_matchers", "shell-alignment", partial=True)
    start = np.zeros(a.n_vertices, dtype=np.int64)
    for bad in (0.0, 1.5):
        with pytest.raises(ParameterError, match="area_ratio"):
            m.match_part(a, b, start, bad)
    for bad_start in (start[:-1], start - 1, start + b.n_vertices):
        with pytest.raises(ParameterError, match="start"):
            m.match_part(a, b, bad_start, 0.7)
