"""Matching large shapes through proxies (issue 29, item 1): proxies made of input vertices, the
proxy map lifted to full resolution by a local spectral search."""

from __future__ import annotations

import numpy as np
import pytest

from shape_toolkit.core.inspect import connected_components
from shape_toolkit.core.shape import Shape
from shape_toolkit.data.corruptions import subdivide
from shape_toolkit.data.synthetic import articulated_shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.pipeline import load_pipeline
from shape_toolkit.plugins.matching.multires import CLUSTER_FIRST, lift_map, make_proxy

LENGTHS = np.array([1.0, 1.3, 1.6, 1.9, 2.2])  # limbs told apart


@pytest.fixture(scope="module")
def poses():
    a = articulated_shape(subdivisions=5, random_state=1, limb_length=LENGTHS).shape
    b = articulated_shape(subdivisions=5, random_state=2, limb_length=LENGTHS).shape
    return a, b  # same vertex order: the truth is the identity


def _error(b: Shape, t: np.ndarray) -> float:
    return float(np.linalg.norm(b.vertices[t] - b.vertices, axis=1).mean() / np.sqrt(b.area))


def test_a_proxy_is_made_of_input_vertices(poses):
    a, _ = poses
    proxy, ids = make_proxy(a, 1500)
    assert proxy.is_mesh and 1000 <= proxy.n_vertices <= 2000
    np.testing.assert_array_equal(proxy.vertices, a.vertices[ids])
    assert len(np.unique(ids)) == len(ids)
    cloud, cids = make_proxy(Shape(a.vertices, None, "cloud"), 1500)
    assert not cloud.is_mesh and cloud.n_vertices == 1500
    np.testing.assert_array_equal(cloud.vertices, a.vertices[cids])
    with pytest.raises(ParameterError):
        make_proxy(a, 10)


def test_a_clustered_proxy_reaches_its_size():
    # far above the proxy size, vertex clustering runs first; the edge collapse after it once stopped at
    # ~4x the size (around the non-manifold edges clustering leaves: 780 vertices for 200 here, 22k for 5k
    # at 10^6 vertices)
    big, _ = subdivide(articulated_shape(random_state=1).shape, splits=3)
    assert big.n_vertices > 4 * CLUSTER_FIRST * 200
    proxy, ids = make_proxy(big, 200)
    assert proxy.is_mesh and 150 <= proxy.n_vertices <= 300
    np.testing.assert_array_equal(proxy.vertices, big.vertices[ids])
    # in one piece, as the input: the repairs' debris (loose triangles here, 46 pieces at 10^6) is dropped
    assert connected_components(proxy)[0] == 1


def test_a_clustered_proxy_is_reproducible():
    """pymeshlab's clustering returns the same mesh in an order that changes from call to call, and the
    repairs and the collapse after it depend on the order (10^6 vertices: 5,551-5,580 proxy vertices over
    four calls); the clustered mesh is put in a canonical order first, so every call gives the same proxy."""
    big, _ = subdivide(articulated_shape(random_state=1).shape, splits=3)
    first = make_proxy(big, 200)[1]
    for _ in range(4):
        np.testing.assert_array_equal(make_proxy(big, 200)[1], first)


def test_the_canonical_order_of_a_mesh_does_not_depend_on_its_order():
    from shape_toolkit.plugins.matching.multires import _canonical

    a = articulated_shape(random_state=1).shape
    V, F = np.asarray(a.vertices), np.asarray(a.faces)
    rng = np.random.default_rng(0)
    perm = rng.permutation(len(V))
    inv = np.argsort(perm)
    G = inv[F][rng.permutation(len(F))]
    G = np.roll(G, 1, axis=1)  # each face starts elsewhere, same orientation
    for x, y in zip(_canonical(V, F), _canonical(V[perm], G)):
        np.testing.assert_array_equal(x, y)


def test_a_large_pair_is_matched_through_proxies_and_lifted(poses):
    a, b = poses
    assert a.n_vertices > 1.5 * 2000
    corr = load_pipeline("zoomout").run(a, b, proxy=2000)
    assert corr.info["proxy"]["proxy_vertices"][0] < a.n_vertices
    assert corr.n_source == a.n_vertices and corr.n_matched == a.n_vertices
    assert _error(b, np.asarray(corr.target_of)) < 0.02
    assert corr.info["orientation"]["verdict"] == "preserving"
    # wall and CPU seconds of every stage, the lift's own split (full shapes' spectra, descent) included
    cpu = corr.info["cpu_timings"]
    assert set(cpu) == set(corr.info["timings"]) >= {"proxies", "proxy spectra", "proxy dense", "lift"}
    assert all(v >= 0 for v in cpu.values())
    assert corr.info["proxy"]["lift"] == "interpolated: barycentric on the proxy's triangles"
    assert set(corr.info["proxy"]["cpu_seconds"]) == {"interpolation"}
    assert sum(corr.info["proxy"]["cpu_seconds"].values()) <= cpu["lift"] + 1e-3
    # the functional map is between the proxies' eigenbases: it is filed with the proxy, not read as the shapes'
    assert "C" not in corr.info and np.asarray(corr.info["proxy"]["C"]).ndim == 2


def test_two_large_clouds_report_the_proxies_orientation(poses):
    """Through proxies, two clouds are judged on the proxies (a full cloud's outward normals cost minutes at
    10^6 points), and the verdict says so."""
    a, b = (Shape(s.vertices, None, "cloud") for s in poses)
    corr = load_pipeline("zoomout").run(a, b, proxy=2000)
    assert corr.info["orientation"]["on"] == "proxies"
    assert corr.info["orientation"]["verdict"] == corr.info["proxy"]["proxy_orientation"]["verdict"] == "preserving"


def test_seeds_are_carried_to_the_proxies(poses):
    a, b = poses
    seeds = np.array([[i, i] for i in range(0, a.n_vertices, a.n_vertices // 6)])
    corr = load_pipeline("zoomout").run(a, b, seeds, proxy=2000)
    assert _error(b, np.asarray(corr.target_of)) < 0.02
    # and the lifted map keeps the user's pairs, as a map of the shapes matched directly does: one sent elsewhere too
    odd = np.vstack([seeds, [[seeds[0, 0] + 1, seeds[1, 1]]]])
    held = load_pipeline("zoomout").run(a, b, odd, proxy=2000)
    np.testing.assert_array_equal(held.target_of[odd[:, 0]], odd[:, 1])


def test_the_interpolated_lift_of_two_clouds_is_finer_than_the_proxy_map(poses):
    # clouds: each point weighted on its three nearest proxy points; between them it must land nearer the truth
    # than the nearest proxy point's image does (measured: 0.0101 against 0.0183)
    from scipy.spatial import cKDTree

    a, b = (Shape(s.vertices, None, "cloud") for s in poses)
    pa, ia = make_proxy(a, 800)
    pb, ib = make_proxy(b, 800)
    pmap = cKDTree(b.vertices[ib]).query(b.vertices[ia])[1]
    out, info = lift_map(a, b, ia, ib, pmap)
    assert info["lift"] == "interpolated: inverse distance among the nearest proxy points"
    nearest = ib[pmap[cKDTree(a.vertices[ia]).query(a.vertices)[1]]]
    assert _error(poses[1], out) < 0.7 * _error(poses[1], nearest)
    own, _ = lift_map(a, a, ia, ia, np.arange(len(ia)))  # a proxy point onto itself is itself
    np.testing.assert_array_equal(own[ia], ia)


def test_the_interpolated_lift_of_a_shape_onto_itself_is_the_identity(poses):
    a, _ = poses
    proxy, ids = make_proxy(a, 1000)
    out, info = lift_map(a, a, ids, ids, np.arange(len(ids)), proxies=(proxy, proxy))
    assert info["lift"] == "interpolated: barycentric on the proxy's triangles"
    assert np.mean(out == np.arange(a.n_vertices)) > 0.95
    assert _error(a, out) < 0.002


def test_the_interpolated_lift_is_finer_than_the_proxy_map(poses):
    # the true proxy map of two poses (same vertex order) sends each source proxy vertex to the target proxy
    # vertex nearest its true image, up to one proxy spacing off; between the proxy vertices the interpolation
    # must land nearer the truth than the nearest proxy vertex's image does
    from scipy.spatial import cKDTree

    a, b = poses
    pa, ia = make_proxy(a, 800)
    pb, ib = make_proxy(b, 800)
    pmap = cKDTree(b.vertices[ib]).query(b.vertices[ia])[1]
    out, _ = lift_map(a, b, ia, ib, pmap, proxies=(pa, pb))
    nearest = ib[pmap[cKDTree(a.vertices[ia]).query(a.vertices)[1]]]
    assert _error(b, out) < 0.6 * _error(b, nearest)
    # unmatched proxy vertices take their nearest matched neighbour's image; every vertex is still mapped
    holes = pmap.copy()
    holes[::7] = -1
    out2, _ = lift_map(a, b, ia, ib, holes, proxies=(pa, pb))
    assert out2.min() >= 0 and _error(b, out2) < 1.5 * _error(b, out)
    with pytest.raises(ParameterError):
        lift_map(a, b, ia[:-1], ib, pmap, proxies=(pa, pb))
    with pytest.raises(ParameterError, match="one target proxy vertex"):
        lift_map(a, b, ia, ib, pmap + pb.n_vertices, proxies=(pa, pb))


def test_the_interpolated_lift_does_not_average_across_a_seam(poses):
    # a proxy map with a seam: the proxy vertices on one side of a plane are sent to the far end of the shape;
    # no vertex may land between the two sides (the corners' images are averaged only where they stay close)
    a, _ = poses
    pa, ia = make_proxy(a, 800)
    P = a.vertices[ia]
    far = P[:, 0] > np.median(P[:, 0])
    pmap = np.arange(len(ia))
    pmap[far] = np.argmax(P[:, 0])  # every far-side proxy vertex onto one extreme vertex
    out, _ = lift_map(a, a, ia, ia, pmap, proxies=(pa, pa))
    X = a.vertices
    # each vertex lands near itself (the near side) or near the extreme vertex, never between them
    d = np.minimum(np.linalg.norm(X[out] - X, axis=1), np.linalg.norm(X[out] - P[pmap[far][0]], axis=1))
    e = pa.edges
    longest = np.linalg.norm(P[e[:, 0]] - P[e[:, 1]], axis=1).max()
    assert d.max() < longest  # without the seam rule: 1.55 against 1.00


def test_the_errors_of_a_proxy_name_the_way_out():
    """A proxy size under 100, a mesh in pieces each too small to keep (a triangle soup: 'decimation left no
    surface') and a proxy map with too few matches said what went wrong, not what to do: each names --proxy 0."""
    from shape_toolkit.errors import InvalidShapeError
    from shape_toolkit.plugins.matching.multires import interpolated_map

    rng = np.random.default_rng(0)
    corners = rng.random((400, 1, 3)) * 5 + rng.random((400, 3, 3)) * 0.1
    soup = Shape(corners.reshape(-1, 3), np.arange(1200).reshape(-1, 3))
    with pytest.raises(InvalidShapeError, match=r"left no surface .*--proxy 0"):
        make_proxy(soup, 100)
    with pytest.raises(ParameterError, match=r">= 100, got 5 .*--proxy 0"):
        make_proxy(soup, 5)
    cloud = Shape(rng.random((50, 3)), None)
    with pytest.raises(ParameterError, match=r"too few to lift .*--proxy 0"):
        interpolated_map(cloud, cloud, cloud, cloud, np.r_[[0, 1], np.full(48, -1)])


@pytest.mark.parametrize("proxy", ["abc", [300], float("nan"), 150.7, True, -5, 50])
def test_pipeline_run_refuses_a_bad_proxy_size_before_any_work(proxy):
    """A string or a list was a TypeError, NaN silently matched at full resolution and 150.7 was cut to 150."""
    s = Shape(np.random.default_rng(0).random((20, 3)), None)
    with pytest.raises(ParameterError, match="proxy size must be an integer >= 100"):
        load_pipeline("zoomout").run(s, s, proxy=proxy)


@pytest.mark.parametrize("proxy", [None, 0, False, np.int64(0)])
def test_pipeline_run_without_a_proxy(proxy, monkeypatch):
    """None, 0 (and False, a numpy 0) turn the proxy off: the stages run on the shapes themselves."""
    from shape_toolkit.pipeline import Pipeline

    seen = []
    monkeypatch.setattr(Pipeline, "_run_stages", lambda self, source, *a: seen.append(source.n_vertices))
    s = Shape(np.random.default_rng(0).random((20, 3)), None)
    load_pipeline("zoomout").run(s, s, proxy=proxy)
    assert seen == [20]


@pytest.mark.parametrize("command", ["match", "segment"])
def test_cli_proxy_under_100_is_refused_by_the_parser(capsys, tmp_path, command):
    """--proxy 1..99 passed the parser; match then refused it only for shapes large enough to need the proxy."""
    from helpers import run_cli

    from shape_toolkit.data.generate import icosphere
    from shape_toolkit.io.mesh import save_shape

    save_shape(icosphere(1), tmp_path / "s.off")  # 42 vertices: no proxy would be made
    files = [tmp_path / "s.off"] * (2 if command == "match" else 1)
    code, out, err = run_cli(capsys, command, *files, "--proxy", "50", "-o", tmp_path / "o.txt")
    assert code == 2 and err.count("\n") == 1 and "0 (no proxy) or an integer in [100, " in err and "got 50" in err, err


def test_lift_map_refuses_ids_and_proxy_maps_that_are_not_vertex_ids():
    """An id past the shape was an IndexError; a negative id indexed from the end, fractional ids and proxy-map
    entries were truncated and a NaN entry cast to a huge negative number ('unmatched'): silently wrong maps."""
    rng = np.random.default_rng(0)
    shape = Shape(rng.random((60, 3)), None)
    ids, pm = np.arange(0, 60, 3), np.arange(20)
    assert lift_map(shape, shape, ids, ids, pm)[0].shape == (60,)
    assert lift_map(shape, shape, ids, ids, pm.astype(float))[0].shape == (60,)  # integral floats are ids
    for bad_ids in (np.r_[ids[:-1], 60], np.r_[ids[:-1], -1], ids + 0.5, ids[:0]):
        with pytest.raises(ParameterError, match="src_ids"):
            lift_map(shape, shape, bad_ids, ids, pm)
    for bad_map in (pm + 0.5, np.r_[pm[:-1], np.nan], np.r_[pm[:-1], -5], pm > 3):
        with pytest.raises(ParameterError, match="proxy map must give"):
            lift_map(shape, shape, ids, ids, bad_map)


def test_a_partial_map_through_proxies_carries_its_support_to_the_whole():
    """info['partial']['support'] (where on the whole the part lies, a mask of the whole's vertices) was the
    target proxy's mask, of its length, next to a map of the full target: carried as the map is, it is the
    whole's, and holds the part's images."""
    from shape_toolkit.data.corruptions import crop
    from shape_toolkit.data.generate import icosphere

    whole = icosphere(3)  # 642 vertices: a proxy of 200
    part, _ = crop(whole, strength=0.5, random_state=0)
    m = {"plugin": "fmap-zoomout", "params": {"partial": True, "area_ratio": 0.5, "k": 10, "zoomout_iters": 2}}
    corr = load_pipeline({"name": "p", "dense": m}).run(part, whole, proxy=200)
    support = corr.info["partial"]["support"]
    assert corr.info["proxy"]["proxy_vertices"][1] < whole.n_vertices
    assert support.shape == (whole.n_vertices,) and support.dtype == bool
    assert support[corr.target_of].mean() > 0.9 and 0.3 < support.mean() < 0.8, (support[corr.target_of].mean(),
                                                                                  support.mean())


def test_cli_match_through_proxies_reports_the_proxy_without_its_functional_map(capsys, tmp_path, poses):
    """``match --json`` through proxies: the summary names the proxies and the lift; the proxies' functional map, a
    k x k array in the proxies' eigenbases, stays in the API's ``info['proxy']``."""
    import json

    from helpers import run_cli

    from shape_toolkit.io.mesh import save_shape

    a, b = poses
    save_shape(a, tmp_path / "a.off")
    save_shape(b, tmp_path / "b.off")
    code, out, err = run_cli(capsys, "match", tmp_path / "a.off", tmp_path / "b.off", "--pipeline", "zoomout",
                             "--proxy", "2000", "-o", tmp_path / "map.txt", "--json")
    assert code == 0, err
    proxy = json.loads(out)["proxy"]
    assert proxy["proxy_vertices"][0] < a.n_vertices and "C" not in proxy
