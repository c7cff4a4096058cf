"""Corruptions keep exact track of where every vertex came from."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse.csgraph import shortest_path

from shape_toolkit.core.inspect import connected_components
from shape_toolkit.core.shape import Shape
from shape_toolkit.data.corruptions import (
    CORRUPTIONS,
    apply_corruption,
    carry_correspondence,
    carry_labels,
    compose_vertex_maps,
    crop,
    gaussian_noise,
    holes,
    invert_vertex_map,
    micro_holes,
    partial,
    remesh,
    rigid_motion,
    shortcut,
    shot_noise,
    step_seeds,
)
from shape_toolkit.data.generate import icosphere
from shape_toolkit.data.synthetic import articulated_shape
from shape_toolkit.errors import InvalidShapeError, ParameterError


@pytest.fixture(scope="module")
def body():
    a = articulated_shape(subdivisions=3)
    return a.shape, a.labels


def _pairwise(v):
    return np.linalg.norm(v[:, None] - v[None], axis=-1)


def test_rigid_motion_is_isometry_with_identity_map(body):
    s, _ = body
    c, vm = rigid_motion(s, strength=0.7, scale=2.0, random_state=3)
    assert np.array_equal(vm, np.arange(s.n_vertices))
    assert np.array_equal(c.faces, s.faces)
    idx = np.arange(0, s.n_vertices, 17)
    np.testing.assert_allclose(_pairwise(c.vertices[idx]), 2.0 * _pairwise(s.vertices[idx]), rtol=1e-10)
    assert not np.allclose(c.vertices, s.vertices)


def test_noise_identity_map_and_magnitude(body):
    s, _ = body
    c, vm = gaussian_noise(s, strength=0.2, random_state=1)
    assert np.array_equal(vm, np.arange(s.n_vertices))
    d = c.vertices - s.vertices
    assert abs(d.std() / (0.2 * s.mean_edge_length) - 1) < 0.1
    c2, _ = shot_noise(s, strength=0.05, magnitude=3.0, random_state=1)
    moved = np.linalg.norm(c2.vertices - s.vertices, axis=1) > 1e-12
    assert moved.sum() == round(0.05 * s.n_vertices)
    np.testing.assert_allclose(
        np.linalg.norm(c2.vertices - s.vertices, axis=1)[moved], 3.0 * s.mean_edge_length
    )


def test_seeded_and_deterministic(body):
    s, _ = body
    a, _ = gaussian_noise(s, random_state=5)
    b, _ = gaussian_noise(s, random_state=5)
    c, _ = gaussian_noise(s, random_state=6)
    assert np.array_equal(a.vertices, b.vertices)
    assert not np.array_equal(a.vertices, c.vertices)


def test_remesh_changes_count_and_maps_to_nearby_originals(body):
    s, labels = body
    c, vm = remesh(s, strength=1.6, random_state=0)
    assert c.n_vertices != s.n_vertices
    assert abs(c.n_vertices / (1.6 * s.n_vertices) - 1) < 0.35
    assert vm.min() >= 0 and vm.max() < s.n_vertices
    d = np.linalg.norm(c.vertices - s.vertices[vm], axis=1)
    assert d.max() < 2.0 * s.mean_edge_length
    lab = carry_labels(labels, vm)
    assert lab.shape == (c.n_vertices,) and set(np.unique(lab)) == set(np.unique(labels))


@pytest.mark.parametrize("fn", [holes, micro_holes, partial])
def test_removals_keep_exact_coordinates(body, fn):
    s, _ = body
    c, vm = fn(s, random_state=2)
    assert c.n_vertices < s.n_vertices
    assert np.array_equal(c.vertices, s.vertices[vm])
    assert len(np.unique(vm)) == len(vm)


def test_partial_removes_the_requested_fraction(body):
    s, _ = body
    c, _ = partial(s, strength=0.3, random_state=0)
    assert 0.6 < c.n_vertices / s.n_vertices < 0.72


def test_shortcut_glues_far_apart_vertices(body):
    s, _ = body
    c, vm = shortcut(s, strength=2, random_state=0)
    assert np.array_equal(vm, np.arange(s.n_vertices))
    assert c.n_faces == s.n_faces + 4
    new = c.faces[s.n_faces :]
    import scipy.sparse as sp

    def hops(shape, a, b):
        e = shape.edges
        A = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(shape.n_vertices,) * 2)
        return shortest_path(A, directed=False, unweighted=True, indices=[a])[0, b]

    a, b = new[0, 0], new[0, 1]
    assert hops(c, a, b) == 1
    assert hops(s, a, b) > 2


def test_correspondence_carried_through_holes(body):
    s, _ = body
    c, vm = holes(s, strength=4, radius=0.08, random_state=1)
    ident = np.arange(s.n_vertices)
    pairs = carry_correspondence(np.stack([ident, ident], 1), vm, s)
    assert 0 < len(pairs) == c.n_vertices
    np.testing.assert_array_equal(c.vertices[pairs[:, 1]], s.vertices[pairs[:, 0]])
    inv = invert_vertex_map(vm, s)
    assert np.array_equal(vm[inv[vm]], vm)
    assert (inv < 0).sum() == s.n_vertices - c.n_vertices


def test_apply_corruption_registry_and_errors(body):
    s, _ = body
    for name in CORRUPTIONS:
        if name == "color-noise":  # the one corruption of colours: a shape without any is refused
            with pytest.raises(InvalidShapeError, match="no vertex colours"):
                apply_corruption(s, name, random_state=0)
            continue
        c, vm = apply_corruption(s, name, random_state=0)
        assert len(vm) == c.n_vertices
    same, vm = apply_corruption(s, "none")
    assert same is s
    with pytest.raises(ParameterError, match="unknown corruption"):
        apply_corruption(s, "melt")
    with pytest.raises(ParameterError, match="no parameter"):
        apply_corruption(s, "holes", sigma=1)
    with pytest.raises(ParameterError):
        partial(s, strength=2.0)


def test_remesh_correspondence_keeps_every_point_nearby(body):
    s, _ = body
    c, vm = remesh(s, strength=0.7, random_state=0)
    ident = np.arange(s.n_vertices)
    pairs = carry_correspondence(np.stack([ident, ident], 1), vm, s, resampled=True)
    assert len(pairs) > 0.95 * s.n_vertices
    d = np.linalg.norm(c.vertices[pairs[:, 1]] - s.vertices[pairs[:, 0]], axis=1)
    assert np.median(d) < 1.0 * s.mean_edge_length


@pytest.mark.parametrize("name", sorted(CORRUPTIONS))
def test_every_corruption_carries_colours_with_the_surface(body, name):
    """Called directly (not only through apply_corruption), each corruption gives every new
    vertex the colour of the original vertex its map names: a texture moves with the surface."""
    shape = body[0] if isinstance(body, tuple) else body
    rng = np.random.default_rng(0)
    coloured = shape.with_colors(rng.random((shape.n_vertices, 3)))
    out, vmap = CORRUPTIONS[name](coloured, random_state=1)
    assert out.colors is not None
    if name == "color-noise":  # changes the colours themselves, the geometry not at all
        np.testing.assert_array_equal(out.vertices, coloured.vertices)
        np.testing.assert_array_equal(vmap, np.arange(coloured.n_vertices))
        d = out.colors - 0.9 * coloured.colors
        inside = (out.colors > 0) & (out.colors < 1)
        assert 0.04 < d[inside].std() < 0.06 and abs(d[inside].mean()) < 0.01  # sigma 0.05 around gain 0.9
        assert out.colors.min() >= 0 and out.colors.max() <= 1
        same, _ = CORRUPTIONS[name](coloured, strength=0.0, gain=1.0, random_state=1)
        np.testing.assert_array_equal(same.colors, coloured.colors)
        return
    np.testing.assert_array_equal(out.colors, coloured.colors[vmap])


@pytest.mark.parametrize("strength", [0.1, 0.3, 0.5])
def test_crop_removes_one_connected_region_of_the_requested_area(body, strength):
    """``crop`` (partial shapes): the removed vertices hold the asked fraction of the area (to within a
    vertex ring, plus at most 5% when the cut splits off a piece), form one connected region, and the kept ones
    keep exact coordinates and their back-map."""
    s, labels = body
    c, vm = crop(s, strength=strength, random_state=3)
    removed = np.setdiff1d(np.arange(s.n_vertices), vm)
    frac = s.vertex_areas[removed].sum() / s.area
    assert strength - 0.02 < frac <= strength + 0.05  # + a piece the cut split off (at most 5%)
    assert np.array_equal(c.vertices, s.vertices[vm]) and len(np.unique(vm)) == len(vm)
    sub, _ = s.submesh(removed)
    assert connected_components(sub)[0] == 1
    assert carry_labels(labels, vm).shape == (c.n_vertices,)
    c2, vm2 = crop(s, strength=strength, random_state=3)
    assert np.array_equal(vm, vm2)
    assert not np.array_equal(vm, crop(s, strength=strength, random_state=4)[1])


def test_crop_refuses_a_cut_that_leaves_too_little_in_one_piece():
    """Two separate spheres: cutting 30% around a vertex of one leaves the other as the largest piece, with half
    the area, not 70%: refused, naming random_state (never a silently larger crop)."""
    a = articulated_shape(subdivisions=2, limbs=np.array([[1.0, 0, 0]]), limb_length=0.01).shape
    v = np.vstack([a.vertices, a.vertices + [10.0, 0, 0]])
    f = np.vstack([a.faces, a.faces + a.n_vertices])
    two = type(a)(v, f)
    with pytest.raises(InvalidShapeError, match="random_state"):
        crop(two, strength=0.3, random_state=0)
    # a centre on a piece smaller than the cut: the other piece is never cut into, and the short cut is refused
    small = type(a)(np.vstack([a.vertices, 3 * a.vertices + [10.0, 0, 0]]), f)
    centre_in_small = [rs for rs in range(20) if np.random.default_rng(rs).integers(small.n_vertices) < a.n_vertices]
    with pytest.raises(InvalidShapeError, match="random_state"):
        crop(small, strength=0.3, random_state=centre_in_small[0])
    assert crop(two, strength=0.0)[0] is two


def test_point_cloud_of_the_vertices_keeps_them_and_their_ids(body):
    """``point-cloud`` with ``points = 0``: the distinct vertices, no faces, each point mapped to its own
    vertex; the noise has the asked standard deviation in bounding-box diagonals."""
    s, _ = body
    c, vm = apply_corruption(s, "point-cloud", random_state=2)
    assert not c.is_mesh and c.n_vertices == s.n_vertices
    np.testing.assert_array_equal(c.vertices, s.vertices[vm])
    n, vn = apply_corruption(s, "point-cloud", strength=0.005, random_state=2)
    np.testing.assert_array_equal(vn, vm)
    assert abs((n.vertices - s.vertices[vn]).std() / (0.005 * s.diagonal) - 1) < 0.1


def test_point_cloud_samples_lie_on_the_surface_near_their_vertex(body):
    """``points = N``: N points on the triangles (distance to the surface ~ 0), each mapped to the vertex
    nearest to it, seeded; the ground truth carried onto the cloud keeps every vertex within an edge."""
    import igl

    s, _ = body
    c, vm = apply_corruption(s, "point-cloud", points=3000, random_state=4)
    assert c.n_vertices == 3000 and not c.is_mesh
    d2 = igl.point_mesh_squared_distance(c.vertices, s.vertices, s.faces)[0]
    assert np.sqrt(d2).max() < 1e-9 * s.diagonal
    near = np.linalg.norm(c.vertices[:, None] - s.vertices[None], axis=-1).argmin(axis=1)
    np.testing.assert_array_equal(vm, near)
    again, _ = apply_corruption(s, "point-cloud", points=3000, random_state=4)
    np.testing.assert_array_equal(again.vertices, c.vertices)
    ident = np.arange(s.n_vertices)
    truth = carry_correspondence(np.stack([ident, ident], 1), vm, s, resampled=True)
    assert len(truth) == s.n_vertices
    gap = np.linalg.norm(c.vertices[truth[:, 1]] - s.vertices[truth[:, 0]], axis=1)
    assert gap.max() < 2.5 * s.mean_edge_length


def test_point_cloud_refuses_bad_parameters(body):
    s, _ = body
    for bad in ({"points": 1}, {"points": -5}, {"points": 2.5}, {"strength": -0.1}):
        with pytest.raises(ParameterError):
            apply_corruption(s, "point-cloud", **bad)
    cloud, _ = apply_corruption(s, "point-cloud")
    with pytest.raises(InvalidShapeError):  # sampling needs triangles
        apply_corruption(cloud, "point-cloud", points=100)


@pytest.fixture(scope="module")
def thin_limbs():
    """Five limbs thinner than a hole (limb radius 0.12 body radii; a hole's radius is 0.32)."""
    return articulated_shape(subdivisions=3, limb_radius=0.12).shape


def test_holes_never_cut_a_part_off(thin_limbs):
    """Holes are punched, as SHREC'10's (the thesis's Table 5.2): on a shape whose limbs are thinner than a
    hole, whole balls around random vertices (the former corruption, which kept the largest piece) cut limbs
    off, so removed vertices lie far from any kept one; the holes never do: every removed vertex is within a
    hole's diameter (plus an edge) of a kept one, the number of connected components does not change, and
    every kept vertex is where its map says."""
    from scipy.spatial import cKDTree

    from shape_toolkit.data.corruptions import _keep

    s = thin_limbs
    r = 0.05 * s.diagonal
    tree = cKDTree(s.vertices)

    def farthest_removed(vm):
        removed = np.setdiff1d(np.arange(s.n_vertices), vm)
        return cKDTree(s.vertices[vm]).query(s.vertices[removed])[0].max()

    amputated = 0
    for seed in range(12):
        keep = np.ones(s.n_vertices, dtype=bool)
        for c in np.random.default_rng(seed).choice(s.n_vertices, 4, replace=False):
            keep[tree.query_ball_point(s.vertices[c], r)] = False
        amputated += farthest_removed(_keep(s, keep)[1]) > 2 * r + s.mean_edge_length
        cut, vm = holes(s, strength=4, radius=0.05, random_state=seed)
        assert farthest_removed(vm) <= 2 * r + s.mean_edge_length
        assert connected_components(cut)[0] == connected_components(s)[0] == 1
        assert s.n_vertices - cut.n_vertices >= 4
        np.testing.assert_array_equal(cut.vertices, s.vertices[vm])
    assert amputated >= 6  # the test can tell an amputation from a hole


def test_holes_keep_every_component_and_are_deterministic(thin_limbs):
    """Two disjoint copies stay two components; same seed, same copy; another seed, another copy."""
    from shape_toolkit.core.shape import Shape

    s = thin_limbs
    two = Shape(np.concatenate([s.vertices, s.vertices + [20.0, 0, 0]]),
                np.concatenate([s.faces, s.faces + s.n_vertices]))
    a, va = holes(two, strength=6, random_state=3)
    b, vb = holes(two, strength=6, random_state=3)
    c, vc = holes(two, strength=6, random_state=4)
    assert connected_components(a)[0] == 2
    assert np.array_equal(va, vb) and np.array_equal(a.faces, b.faces)
    assert not np.array_equal(va, vc)
    # more holes of the same seed add to the fewer: the first two of four are the two
    _, v2 = holes(s, strength=2, random_state=5)
    _, v4 = holes(s, strength=4, random_state=5)
    assert set(v4) < set(v2)


def test_holes_that_cannot_fit_raise(thin_limbs):
    """A hole that would remove the whole shape wherever it is put: a typed error after the allowed attempts."""
    with pytest.raises(InvalidShapeError, match="no place for hole 1 of 1"):
        holes(thin_limbs, strength=1, radius=1.0, attempts=5, random_state=0)
    with pytest.raises(ParameterError, match="attempts"):
        holes(thin_limbs, strength=1, attempts=0)
    with pytest.raises(ParameterError, match="radius"):
        holes(thin_limbs, strength=1, radius=0)


def test_crop_of_a_mesh_in_pieces_no_centre_can_crop_says_so():
    """Two equal spheres: a crop keeps one piece, so 70% of the area is out of reach from every centre; the error
    said 'try another random_state' (and more attempts), which could never help. It names the pieces and the way
    out; a mesh whose largest piece can hold the asked share still gets the random_state advice."""
    s = icosphere(2)
    two = Shape(np.vstack([s.vertices, s.vertices + [5.0, 0, 0]]), np.vstack([s.faces, s.faces + s.n_vertices]))
    for rs in range(3):
        with pytest.raises(InvalidShapeError, match=r"in pieces \(the largest holds 50% .*--keep-largest") as err:
            crop(two, strength=0.3, random_state=rs, attempts=5)
        assert "try another" not in str(err.value)
    assert crop(two, strength=0.5, random_state=0, attempts=20)[0].n_vertices == s.n_vertices  # one sphere: 50%


def test_crop_of_a_mesh_too_coarse_to_cut_finely_is_refused():
    """A tetrahedron cropped by 30% lost three faces of four: its kept vertices held 75% of the vertex areas, so
    the crop passed as '70% kept' while 21% of the surface was. Refused now (a coarse mesh cannot be cut finely)."""
    tet = Shape(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]),
                np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    with pytest.raises(InvalidShapeError, match="keeps one piece with 21% of the area"):
        crop(tet, strength=0.3, random_state=0)


def test_a_composed_corruption_maps_through_both_steps(body):
    """``holes+micro-holes``: each step with its own seed from the chain's, and the chain's map equals the
    second step's map read through the first's (every kept vertex is at its original's place)."""
    s, _ = body
    seeds = step_seeds(3, 2)
    assert len(set(seeds)) == 2 and 3 not in seeds and step_seeds(3, 2) == seeds  # own streams, deterministic
    out, vm = apply_corruption(s, "holes+micro-holes", random_state=3,
                               steps=[{"strength": 2, "radius": 0.08}, {"strength": 0.05}])
    a, m1 = holes(s, strength=2, radius=0.08, random_state=seeds[0])
    b, m2 = micro_holes(a, strength=0.05, random_state=seeds[1])
    np.testing.assert_array_equal(vm, m1[m2])
    np.testing.assert_array_equal(out.vertices, b.vertices)
    np.testing.assert_array_equal(out.vertices, s.vertices[vm])
    assert out.n_vertices < a.n_vertices < s.n_vertices  # both steps removed vertices
    assert not np.array_equal(vm, m1[: len(vm)])  # not the first map alone
    np.testing.assert_array_equal(compose_vertex_maps(np.array([4, 5, 6]), np.array([2, -1, 0])), [6, -1, 4])
    assert compose_vertex_maps(np.array([4, -1]), np.array([1, 0])).tolist() == [-1, 4]


def test_a_composed_corruption_names_the_step_that_failed(body):
    s, _ = body
    with pytest.raises(InvalidShapeError, match=r"step 2 of 2 of 'gaussian-noise\+color-noise' \(color-noise\): "
                                                r".*no vertex colours"):
        apply_corruption(s, "gaussian-noise+color-noise", steps=[{}, {"strength": 0.1}])
    with pytest.raises(ParameterError, match=r"step 1 of 2 .*strength must be a float in \[0, 100\]"):
        apply_corruption(s, "glue+gaussian-noise", steps=[{"strength": -1}, {}])
    with pytest.raises(ParameterError, match="unknown step 'melt'"):
        apply_corruption(s, "glue+melt", steps=[{}, {}])
    with pytest.raises(ParameterError, match="takes steps = a list of 2 parameter tables"):
        apply_corruption(s, "glue+gaussian-noise", steps=[{}])
    with pytest.raises(ParameterError, match="takes steps"):
        apply_corruption(s, "glue+gaussian-noise", strength=1)
