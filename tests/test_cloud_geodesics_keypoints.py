"""Point clouds: their kNN graphs joined where the surface joins them (keypoints, descriptors, Dijkstra), and the
heat method on the point-cloud Laplacian's surface (issue 29, item 4: "ADF keypoints and geodesics on clouds")."""

from __future__ import annotations

import numpy as np
import pytest

from shape_toolkit.core.geometry import edge_components
from shape_toolkit.core.graph import cloud_knn_edges, knn_edges
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import DisconnectedGraphError, InvalidShapeError
from shape_toolkit.features import geodesics as g
from shape_toolkit.plugins.keypoints.adf_maxima import ADFMaxima


def _rings(gap: float = 1.5, per: int = 20, a: float = 10.0) -> np.ndarray:
    """An ellipsoid of semi-axes (1, 1, ``a``) sampled as rings of ``per`` points, ``gap`` apart along its axis: every
    point's 10 nearest lie on its own ring (0.31 apart), as on the tail of TOSCA's cat0 remeshed."""
    pts = []
    for z in np.arange(-a + gap / 2, a, gap):
        r = np.sqrt(max(1.0 - (z / a) ** 2, 0.0))
        t = np.arange(per) * 2 * np.pi / per + 0.1 * z
        pts.append(np.c_[r * np.cos(t), r * np.sin(t), np.full(per, z)])
    return np.vstack(pts)


def _fibonacci_sphere(n: int, centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    i = np.arange(n) + 0.5
    phi, theta = np.arccos(1 - 2 * i / n), np.pi * (1 + 5**0.5) * i
    return np.c_[np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)] + np.asarray(centre)


def test_rings_of_one_surface_are_joined_and_keep_their_knn_edges():
    P = _rings()
    assert edge_components(len(P), knn_edges(P, 10))[0] > 5  # the plain kNN graph falls apart ring by ring
    e = cloud_knn_edges(Shape(P), 10)
    assert edge_components(len(P), e)[0] == 1
    plain = {tuple(x) for x in knn_edges(P, 10)}
    assert plain <= {tuple(x) for x in e}  # only edges added, none taken away
    added = np.array([x for x in e if tuple(x) not in plain])
    z = P[added, 2]
    assert np.all(np.abs(z[:, 0] - z[:, 1]) < 3.1)  # to the next ring or the one after, never across the shape


def test_adf_keypoints_of_the_rings_are_the_two_tips():
    P = _rings()
    kp = ADFMaxima().detect(Shape(P))
    tips = {int(np.argmin(P[:, 2])) // 20, int(np.argmax(P[:, 2])) // 20}  # the end rings
    assert len(kp) >= 2 and {int(k) // 20 for k in kp[:2]} == tips


def test_a_connected_cloud_keeps_its_knn_graph_exactly():
    P = _fibonacci_sphere(500)
    assert np.array_equal(cloud_knn_edges(Shape(P), 10), knn_edges(P, 10))


def test_two_objects_stay_apart():
    P = np.vstack([_fibonacci_sphere(300), _fibonacci_sphere(300, centre=(10.0, 0.0, 0.0))])
    cloud = Shape(P)
    assert edge_components(len(P), cloud_knn_edges(cloud, 10))[0] == 2
    with pytest.raises(DisconnectedGraphError, match="2 connected components"):
        ADFMaxima().detect(cloud)
    d = g.geodesic_distances(cloud, [0], method="dijkstra", cache=False)[0]
    assert np.isinf(d[300:]).all() and np.isfinite(d[:300]).all()


@pytest.mark.parametrize("noise, tol", [(0.0, 0.03), (0.01, 0.05)])
def test_heat_geodesics_on_a_sphere_cloud_are_great_circles(noise, tol):
    P = _fibonacci_sphere(2000)
    noisy = P + noise * np.random.default_rng(0).normal(size=P.shape)
    src = [0, 700, 1500]
    d = g.geodesic_distances(Shape(noisy), src, method="heat", cache=False)
    gt = np.arccos(np.clip(P[src] @ P.T, -1.0, 1.0))
    far = gt > 0.1
    assert np.mean(np.abs(d[far] - gt[far]) / gt[far]) < tol
    if noise == 0.0:  # Dijkstra along the cloud's kNN edges (chords, zigzags) is further off
        dj = g.geodesic_distances(Shape(P), src, method="dijkstra", cache=False)
        assert np.mean(np.abs(d[far] - gt[far])) < np.mean(np.abs(dj[far] - gt[far]))


def test_cloud_geodesics_refuse_exact_and_fmm_naming_heat():
    cloud = Shape(_fibonacci_sphere(200))
    for method in ("exact", "fmm"):
        with pytest.raises(InvalidShapeError, match="'heat'"):
            g.geodesic_distances(cloud, [0], method=method)
    with pytest.raises(InvalidShapeError, match="coincide"):
        g.geodesic_distances(Shape(np.vstack([cloud.vertices, cloud.vertices[:3]])), [0], method="heat")


def test_cli_geodesics_and_keypoints_on_a_cloud(tmp_path, capsys):
    import json

    from shape_toolkit.cli import main
    from shape_toolkit.io.mesh import save_shape

    path = tmp_path / "rings.ply"
    save_shape(Shape(_rings(), name="rings"), path)
    assert main(["keypoints", str(path), "--json", "-q"]) == 0
    assert len(json.loads(capsys.readouterr().out)["keypoints"]) >= 2
    assert main(["geodesics", str(path), "--sources", "0,5", "--json", "-q"]) == 0  # the default: heat
    out = json.loads(capsys.readouterr().out)
    assert out["method"] == "heat" and out["unreachable"] == 0
    assert main(["geodesics", str(path), "--sources", "0", "--method", "fmm", "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'heat'" in err[0]


@pytest.mark.parametrize("name", ["cat0", "dog0"])
def test_tosca_vertex_clouds_keypoints_and_geodesics(shared_data, name):
    """TOSCA cat0 and dog0 as the clouds of their vertices: their 10-NN graphs fall apart (4 pieces each, the
    remeshing's rings on the tail), so keypoints were refused. Now ADF keypoints of the cloud lie where the mesh's
    are, and both cloud methods reach every point and are near libigl's exact geodesics on the mesh."""
    from shape_toolkit.io.mesh import load_shape

    mesh = load_shape(shared_data / "tosca5k" / f"{name}.off")
    cloud = Shape(mesh.vertices)
    assert edge_components(mesh.n_vertices, knn_edges(mesh.vertices, 10))[0] > 1
    scale = np.sqrt(mesh.area)
    km, kc = ADFMaxima().detect(mesh), ADFMaxima().detect(cloud)
    near = np.linalg.norm(mesh.vertices[km][:, None] - mesh.vertices[kc][None], axis=2).min(axis=1) / scale
    assert np.mean(near < 0.05) >= 0.8  # measured: every one of the mesh's 7 within 0.05 (at most 0.029 / 0.049)
    src = [0, 2500]
    ref = g.geodesic_distances(mesh, src, method="exact")
    far = ref > 0.01 * ref.max()
    for method, tol in (("heat", 0.04), ("dijkstra", 0.08)):  # measured 0.020 / 0.032 and 0.048 / 0.053
        d = g.geodesic_distances(cloud, src, method=method, cache=False)
        assert np.isfinite(d).all()
        assert np.mean(np.abs(d[far] - ref[far]) / ref[far]) < tol, method


def test_cli_heat_geodesics_of_a_cloud_too_large_for_the_memory_limit_are_refused_naming_dijkstra(tmp_path, capsys):
    """A file does not say that it has no faces, so the mesh model passes a cloud; once read, the cloud's own model
    (its local triangulations: about 12 kB a point, 2.6x a mesh's) refuses it, naming the cheaper method."""
    from shape_toolkit.cli import main
    from shape_toolkit.features.geodesics import GEODESIC_MEMORY, geodesic_memory
    from shape_toolkit.io.mesh import save_shape

    path = tmp_path / "sphere.ply"
    save_shape(Shape(_fibonacci_sphere(2000), name="sphere"), path)
    mesh_need, cloud_need = geodesic_memory(2000, 1, "heat"), geodesic_memory(2000, 1, "heat", cloud=True)
    assert cloud_need > 2 * mesh_need and geodesic_memory(2000, 1, "dijkstra", cloud=True) == GEODESIC_MEMORY[
        "dijkstra"][0] + 2000 * (GEODESIC_MEMORY["dijkstra"][1] + 32.0)
    limit = f"{(mesh_need + cloud_need) / 2 / 1e9:.6f}"  # between the two: only the cloud's model refuses
    assert main(["geodesics", str(path), "--sources", "0", "--memory-limit", limit, "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "point cloud of 2,000 points" in err[0] and "--method dijkstra" in err[0]
    from shape_toolkit.data.generate import icosphere

    mesh = icosphere(4)  # 2,562 vertices: more than the cloud, but a mesh's heat method needs less
    save_shape(mesh, tmp_path / "mesh.ply")
    assert geodesic_memory(mesh.n_vertices, 1, "heat") < float(limit) * 1e9
    assert main(["geodesics", str(tmp_path / "mesh.ply"), "--sources", "0", "--memory-limit", limit, "-q"]) == 0


def test_a_maps_error_on_a_cloud_target_is_in_units_of_the_clouds_own_area():
    """The normalized geodesic error on a point-cloud target: heat geodesics along its surface over the square root
    of that surface's area (it needed a mesh). A unit sphere sampled: the area is 4 pi to a few percent, and a map
    off by a known rotation has the error of the great circles it moves along."""
    from shape_toolkit.core.surface import cloud_area
    from shape_toolkit.metrics.correspondence import error_normalization, geodesic_errors

    P = _fibonacci_sphere(3000)
    cloud = Shape(P)
    assert cloud_area(cloud) == pytest.approx(4 * np.pi, rel=0.02)
    assert error_normalization(cloud) == pytest.approx(np.sqrt(cloud_area(cloud)))
    c, s = np.cos(0.3), np.sin(0.3)  # a map that turns every point by 0.3 rad about z
    turned = P @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
    from scipy.spatial import cKDTree

    target_of = cKDTree(P).query(turned)[1]
    ids = np.arange(0, 3000, 37)
    err = geodesic_errors(cloud, target_of, ids, ids, method="heat")
    along = np.arccos(np.clip(np.einsum("ij,ij->i", P[ids], P[target_of[ids]]), -1, 1))  # the true arc
    keep = along > 0.1  # away from the poles, where the arc is shorter than the sampling
    np.testing.assert_allclose(err[keep] * np.sqrt(4 * np.pi), along[keep], rtol=0.15, atol=0.02)


def test_a_clouds_area_and_heat_geodesics_share_one_sheet_triangulation(monkeypatch):
    """A cloud's area (the unit of a map's error) and its heat geodesics run on the same sheet triangulation, now
    computed once per cloud (kept in ``SHEET_CACHE``): evaluate-map on a cloud triangulated it twice. The arrays
    returned are copies (changing them changes nothing kept), and the same points with their own normals are another
    cloud (another triangulation)."""
    from shape_toolkit.core import surface
    from shape_toolkit.metrics.correspondence import error_normalization, geodesic_errors

    calls = []
    real = surface.local_delaunay_triangles
    monkeypatch.setattr(surface, "local_delaunay_triangles", lambda *a, **k: calls.append(1) or real(*a, **k))
    surface.SHEET_CACHE.clear()
    P = _fibonacci_sphere(1500)
    cloud = Shape(P)
    unit = error_normalization(cloud)
    geodesic_errors(cloud, np.arange(1500), np.arange(0, 1500, 50), np.arange(0, 1500, 50), method="heat")
    assert len(calls) == 1
    V, F = surface.sheet_triangulation(cloud, 30, "jet")
    V[:] = 0.0
    F[:] = 0
    assert len(calls) == 1 and surface.cloud_area(cloud) == pytest.approx(unit**2)
    surface.sheet_triangulation(Shape(P, normals=P), 30, "jet")
    assert len(calls) == 2
