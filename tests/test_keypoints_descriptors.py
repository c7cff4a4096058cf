"""Keypoint detectors (adf-maxima, harris3d), heat descriptors (hks, wks, heat-diffusion,
heat-distance), the keypoints CLI and the repeatability metric."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import BUMP_DIRS, bumpy_sphere

from shape_toolkit.api.registry import available_plugins, create_plugin, get_plugin
from shape_toolkit.cli import main as cli_main
from shape_toolkit.core.eigen import smallest_eigenpairs
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum, laplacian_matrix
from shape_toolkit.errors import InvalidShapeError, ParameterError, PluginError, SpectrumMismatchError
from shape_toolkit.features import heat, scales
from shape_toolkit.features.descriptor_score import descriptor_matching_score
from shape_toolkit.features.geodesics import k_ring
from shape_toolkit.io.mesh import save_shape
from shape_toolkit.metrics.keypoints import (
    ground_truth_map,
    keypoint_coverage,
    keypoint_repeatability,
    repeatability_report,
)
from shape_toolkit.spectra import build_graph


def gaussian_spectrum(shape: Shape, k: int) -> Spectrum:
    """The detectors' default spectrum (Gaussian weights, combinatorial), solved with ARPACK."""
    g = build_graph(shape, "gaussian")
    vals, vecs = smallest_eigenpairs(laplacian_matrix(g.W), k, method="arpack-splu")
    return Spectrum(np.maximum(vals, 0.0), vecs, "combinatorial", "gaussian", None, g.degrees)


def rigid(shape: Shape, seed: int = 1) -> Shape:
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    return Shape(shape.vertices @ q.T + [3.0, -2.0, 0.5], shape.faces, "moved")


def permuted(shape: Shape, seed: int = 2) -> tuple[Shape, np.ndarray]:
    """Copy with new vertex order; ``perm[new] = old`` and ``inv[old] = new``."""
    perm = np.random.default_rng(seed).permutation(shape.n_vertices)
    inv = np.argsort(perm)
    return Shape(shape.vertices[perm], inv[shape.faces], "permuted"), inv


@pytest.fixture(scope="module")
def bump():
    shape, tips = bumpy_sphere(3)
    return shape, tips, gaussian_spectrum(shape, 31)


# -- registry and presets ---------------------------------------------------------------------
def test_plugins_registered_with_table_6_1_presets():
    fams = available_plugins()
    assert {"adf-maxima", "harris3d"} <= set(fams["keypoints"])
    assert {"hks", "wks", "heat-diffusion", "heat-distance"} <= set(fams["descriptors"])
    adf = get_plugin("keypoints", "adf-maxima")
    # the thesis's Table 6.1, literally (absolute times), beside the scale-free defaults
    assert adf.presets["thesis-sparse"] == {"t": 500.0, "K": 10, "ring": 2, "time_scale": "absolute"}
    assert adf.presets["thesis-dense"] == {"t": 50.0, "K": 50, "ring": 2, "time_scale": "absolute"}
    assert adf.presets["sparse"]["time_scale"] == "first" and adf.presets["dense"]["time_scale"] == "last"
    assert create_plugin("keypoints", "adf-maxima").get_params() == create_plugin(
        "keypoints", "adf-maxima", preset="sparse").get_params()
    h = create_plugin("keypoints", "harris3d", preset="dense")
    assert (h.neighbourhood, h.neighbourhood_param, h.k, h.ring) == ("adaptive", 0.01, 0.04, 2)
    assert (h.selection, h.selection_param) == ("clustering", 0.001)
    assert create_plugin("keypoints", "harris3d", preset="sparse").selection == "fraction"
    with pytest.raises(ParameterError):
        create_plugin("keypoints", "adf-maxima", preset="medium")


# -- adf-maxima -------------------------------------------------------------------------------
def test_adf_maxima_find_the_protrusions(bump):
    shape, tips, spec = bump
    t = 0.5  # in units of 1 / lambda_1 (the default time_scale)
    kp = create_plugin("keypoints", "adf-maxima", t=t, K=10).detect(shape, spectrum=spec)
    absolute = create_plugin("keypoints", "adf-maxima", t=t / spec.eigenvalues[1], K=10, time_scale="absolute")
    np.testing.assert_array_equal(absolute.detect(shape, spectrum=spec), kp)
    assert kp.dtype == np.int64
    assert set(kp[:3].tolist()) == set(tips[:3])  # the three largest protrusions, strongest first
    adf = create_plugin("keypoints", "adf-maxima", t=t, K=10).adf(shape, spectrum=spec)
    for p in kp:  # each keypoint is the maximum of its 2-ring
        assert adf[p] >= adf[k_ring(shape, int(p), 2)].max()
    # larger t: fewer, more global maxima (section 6.6.2)
    few = create_plugin("keypoints", "adf-maxima", t=20 * t, K=10).detect(shape, spectrum=spec)
    many = create_plugin("keypoints", "adf-maxima", t=t / 10, K=30).detect(shape, spectrum=spec)
    assert len(few) < len(kp) < len(many)
    top = create_plugin("keypoints", "adf-maxima", t=t, K=10, max_keypoints=2).detect(shape, spectrum=spec)
    np.testing.assert_array_equal(top, kp[:2])


def test_adf_maxima_deterministic_and_invariant(bump):
    shape, _, spec = bump
    det = create_plugin("keypoints", "adf-maxima", t=0.5, K=10)
    kp = det.detect(shape, spectrum=spec)
    np.testing.assert_array_equal(det.detect(shape, spectrum=spec), kp)
    moved = rigid(shape)
    np.testing.assert_array_equal(det.detect(moved, spectrum=gaussian_spectrum(moved, 11)), kp)
    perm, inv = permuted(shape)
    np.testing.assert_array_equal(det.detect(perm, spectrum=gaussian_spectrum(perm, 11)), inv[kp])
    # eigenvector signs do not matter
    flipped = Spectrum(spec.eigenvalues, -spec.eigenvectors, spec.laplacian, spec.weighting, None, spec.degrees)
    np.testing.assert_array_equal(det.detect(shape, spectrum=flipped), kp)


def test_adf_maxima_default_spectrum_small_shape():
    shape, tips = bumpy_sphere(2)
    kp = create_plugin("keypoints", "adf-maxima", t=10.0, K=10, time_scale="absolute").detect(shape)
    assert len(kp) >= 1 and kp.min() >= 0 and kp.max() < shape.n_vertices
    assert kp[0] == tips[0]


def test_adf_maxima_errors(bump):
    shape, _, spec = bump
    with pytest.raises(SpectrumMismatchError, match="31 eigenpairs, fewer than 32"):
        create_plugin("keypoints", "adf-maxima", K=31).detect(shape, spectrum=spec)  # 30 non-null
    for bad in (0.0, -5.0, float("nan")):
        with pytest.raises(ParameterError, match="positive"):
            create_plugin("keypoints", "adf-maxima", t=bad).detect(shape, spectrum=spec)
    with pytest.raises(ParameterError):
        create_plugin("keypoints", "adf-maxima", ring=0).detect(shape, spectrum=spec)
    with pytest.raises(ParameterError, match="time_scale"):
        create_plugin("keypoints", "adf-maxima", time_scale="seconds").detect(shape, spectrum=spec)
    with pytest.raises(ParameterError):
        create_plugin("keypoints", "adf-maxima", K=10).detect(bumpy_sphere(2)[0], spectrum=spec)  # wrong n


# -- harris3d ---------------------------------------------------------------------------------
def test_harris3d_finds_protrusions_and_is_invariant(bump):
    shape, tips, _ = bump
    det = create_plugin("keypoints", "harris3d", selection_param=0.01)  # fraction: 6 points
    kp = det.detect(shape)
    assert len(kp) == round(0.01 * shape.n_vertices)
    assert set(tips[:3]) <= set(kp.tolist())
    np.testing.assert_array_equal(det.detect(shape), kp)
    np.testing.assert_array_equal(det.detect(rigid(shape)), kp)
    perm, inv = permuted(shape)
    np.testing.assert_array_equal(det.detect(perm), inv[kp])
    dense = create_plugin("keypoints", "harris3d", preset="dense").detect(shape)
    assert len(dense) > len(kp)
    spaced = create_plugin("keypoints", "harris3d", selection="clustering", selection_param=0.3).detect(shape)
    d = np.linalg.norm(shape.vertices[spaced][:, None] - shape.vertices[spaced][None], axis=2)
    assert np.all(d[np.triu_indices(len(spaced), 1)] > 0.3 * shape.diagonal)


def test_harris3d_response_of_a_plane_and_a_saddle():
    # flat patch: zero response; the quadratic fit recovers the exact patch of z = x^2 - y^2
    g = np.linspace(-1, 1, 11)
    x, y = np.meshgrid(g, g)
    ids = np.arange(121).reshape(11, 11)
    f = np.concatenate([
        np.stack([ids[:-1, :-1].ravel(), ids[1:, :-1].ravel(), ids[1:, 1:].ravel()], 1),
        np.stack([ids[:-1, :-1].ravel(), ids[1:, 1:].ravel(), ids[:-1, 1:].ravel()], 1),
    ])
    det = create_plugin("keypoints", "harris3d", neighbourhood="rings", neighbourhood_param=2)
    flat = Shape(np.stack([x.ravel(), y.ravel(), 0 * x.ravel()], 1), f)
    np.testing.assert_allclose(det.response(flat), 0.0, atol=1e-20)
    saddle = Shape(np.stack([x.ravel(), y.ravel(), 0.1 * (x**2 - y**2).ravel()], 1), f)
    r = det.response(saddle)
    c = 60  # centre vertex: p1 = 0.2, p3 = -0.2, others 0 -> A = B = 0.08, C = 0
    assert r[c] == pytest.approx(0.08 * 0.08 - 0.04 * 0.16**2, rel=1e-6)


def test_harris3d_errors(bump):
    shape, _, _ = bump
    with pytest.raises(InvalidShapeError):
        create_plugin("keypoints", "harris3d").detect(Shape(shape.vertices))
    with pytest.raises(ParameterError):
        create_plugin("keypoints", "harris3d", selection="best").detect(shape)
    with pytest.raises(ParameterError):
        create_plugin("keypoints", "harris3d", neighbourhood_param=-1).detect(shape)
    with pytest.raises(ParameterError):
        create_plugin("keypoints", "harris3d", wrong=1)


# -- descriptors ------------------------------------------------------------------------------
def test_hks_plugin(bump):
    shape, _, spec = bump
    d = create_plugin("descriptors", "hks", n_times=8, K=30).compute(shape, spectrum=spec)
    np.testing.assert_allclose(d, heat.heat_kernel_signature(spec, scales.default_times(spec, 8)))
    assert d.shape == (shape.n_vertices, 8)
    moved = rigid(shape)
    d2 = create_plugin("descriptors", "hks", n_times=8, K=30).compute(moved, spectrum=gaussian_spectrum(moved, 31))
    np.testing.assert_allclose(d2, d, rtol=1e-6, atol=1e-12)
    perm, inv = permuted(shape)
    d3 = create_plugin("descriptors", "hks", n_times=8, K=30).compute(perm, spectrum=gaussian_spectrum(perm, 31))
    np.testing.assert_allclose(d3[inv], d, rtol=1e-6, atol=1e-12)
    lg = create_plugin("descriptors", "hks", K=30, times=[1.0, 10.0], log=True, scale="trace").compute(
        shape, spectrum=spec
    )
    assert lg.shape == (shape.n_vertices, 2) and np.all(np.isfinite(lg))
    with pytest.raises(ParameterError):
        create_plugin("descriptors", "hks", K=30, times=[1.0, -1.0]).compute(shape, spectrum=spec)
    with pytest.raises(SpectrumMismatchError, match="fewer than 101"):  # too short: never recomputed
        create_plugin("descriptors", "hks", K=100).compute(shape, spectrum=spec)


def test_wks_plugin(bump):
    shape, _, spec = bump
    d = create_plugin("descriptors", "wks", n_energies=20, K=30).compute(shape, spectrum=spec)
    assert d.shape == (shape.n_vertices, 20) and np.all(d >= 0)
    flipped = Spectrum(spec.eigenvalues, spec.eigenvectors * -1, spec.laplacian, spec.weighting, None, spec.degrees)
    np.testing.assert_allclose(create_plugin("descriptors", "wks", n_energies=20, K=30).compute(
        shape, spectrum=flipped), d)
    # each energy band is a weighted mean of u_k^2, whose vertex sum is 1
    np.testing.assert_allclose(d.sum(axis=0), 1.0, rtol=1e-10)


def test_heat_diffusion_descriptor(bump):
    shape, tips, spec = bump
    times = [2.0, 8.0, 32.0]
    d = create_plugin("descriptors", "heat-diffusion", times=times, K=15).compute(
        shape, spectrum=spec, keypoints=tips
    )
    M, tau = len(tips), len(times)
    assert d.shape == (shape.n_vertices, (M + 1) * tau)
    cube = d.reshape(shape.n_vertices, M + 1, tau)
    H = heat.heat_kernel(spec, times, cols=tips, K=15)  # (tau, n, M)
    np.testing.assert_allclose(cube[:, :M, :], H.transpose(1, 2, 0))
    np.testing.assert_allclose(cube[:, M, :], heat.heat_kernel_signature(spec, times, K=15))
    with pytest.raises(ParameterError, match="keypoints"):
        create_plugin("descriptors", "heat-diffusion", K=15).compute(shape, spectrum=spec)
    with pytest.raises(ParameterError):
        create_plugin("descriptors", "heat-diffusion", K=15).compute(
            shape, spectrum=spec, keypoints=[shape.n_vertices]
        )


@pytest.mark.parametrize("name, params", [("hks", {}), ("hks", {"times": [0.1, 1.0, 10.0]}), ("wks", {"n_energies": 7}),
                                          ("heat-diffusion", {}), ("heat-distance", {"n_times": 3})])
def test_output_width_is_the_width_compute_returns(bump, name, params):
    """``output_width`` (what ``describe --memory-limit`` counts before reading a shape) is the number of columns
    ``compute`` returns, for the keypoints given; keypoint descriptors without keypoints do not know it."""
    shape = bump[0]
    desc = create_plugin("descriptors", name, **params)
    kp = np.array([0, 5, 40, 90])
    assert desc.output_width(kp.size) == desc.compute(shape, keypoints=kp).shape[1]
    if name.startswith("heat-"):
        assert desc.output_width(None) is None


def test_heat_distance_descriptor_and_matching_score(bump):
    shape, tips, spec = bump
    times = [2.0, 8.0, 32.0]
    plug = create_plugin("descriptors", "heat-distance", times=times, K=15)
    d = plug.compute(shape, spectrum=spec, keypoints=tips)
    M, tau = len(tips), len(times)
    assert d.shape == (shape.n_vertices, M * tau)
    cube = d.reshape(shape.n_vertices, M, tau)
    for ti, t in enumerate(times):
        np.testing.assert_allclose(
            cube[:, :, ti], heat.heat_distance(spec, t, tips, normalization="unit-sphere", K=15).T
        )
    np.testing.assert_allclose(cube[tips, np.arange(M), :], 0.0, atol=1e-6)
    # the same shape with another vertex order: eq. 6.66 scores find the right vertex
    perm, inv = permuted(shape)
    d2 = plug.compute(perm, spectrum=gaussian_spectrum(perm, 31), keypoints=inv[tips])
    q = np.arange(0, shape.n_vertices, 7)
    own = descriptor_matching_score(d, d2, q, inv[q], n_times=tau)
    assert np.all(own < 1e-4)
    P = descriptor_matching_score(d, d2, q, None, n_times=tau, pairwise=True)
    assert np.mean(np.argmin(P, axis=1) == inv[q]) > 0.95
    with pytest.raises(ParameterError, match="keypoints"):
        plug.compute(shape, spectrum=spec)
    with pytest.raises(ParameterError):
        plug.compute(shape, spectrum=spec, keypoints=[-3])
    with pytest.raises(ParameterError):
        create_plugin("descriptors", "heat-distance", normalization="cosine").compute(
            shape, spectrum=spec, keypoints=tips
        )


def test_keypoint_descriptors_default_spectrum_and_times():
    shape, tips = bumpy_sphere(2)
    d = create_plugin("descriptors", "heat-distance").compute(shape, keypoints=tips)
    assert d.shape == (shape.n_vertices, len(tips) * 5) and np.all(np.isfinite(d))
    d = create_plugin("descriptors", "heat-diffusion", n_times=3).compute(shape, keypoints=tips[:2])
    assert d.shape == (shape.n_vertices, 3 * 3)


# -- CLI --------------------------------------------------------------------------------------
def test_cli_keypoints_json(tmp_path, capsys):
    shape, tips = bumpy_sphere(2)
    path = tmp_path / "bumpy.off"
    save_shape(shape, path)
    rc = cli_main(["keypoints", str(path), "--detector", "adf-maxima", "--param", "t=10",
                   "--param", "K=10", "--param", "time_scale=absolute", "--json"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["detector"] == "adf-maxima" and out["params"]["t"] == 10 and out["params"]["K"] == 10
    assert out["keypoints"][0] == tips[0]
    rc = cli_main(["keypoints", str(path), "--detector", "harris3d", "--preset", "dense", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["params"]["selection"] == "clustering" and len(out["keypoints"]) > 0


@pytest.mark.parametrize("args, msg", [
    (["--detector", "nope"], "unknown keypoints plugin"),
    (["--detector", "adf-maxima", "--preset", "huge"], "no preset"),
    (["--detector", "adf-maxima", "--param", "t=-1"], "positive"),
    (["--detector", "adf-maxima", "--param", "bogus=1"], "no parameter"),
    (["--detector", "adf-maxima", "--param", "K=500"], "K = 500"),
])
def test_cli_keypoints_errors(tmp_path, capsys, args, msg):
    shape, _ = bumpy_sphere(2)
    path = tmp_path / "bumpy.off"
    save_shape(shape, path)
    rc = cli_main(["keypoints", str(path), *args])
    err = capsys.readouterr().err
    assert rc == 2 and msg in err and err.count("\n") == 1


def test_cli_harris_on_point_cloud(tmp_path, capsys):
    path = tmp_path / "cloud.xyz"
    save_shape(Shape(bumpy_sphere(2)[0].vertices), path)
    assert cli_main(["keypoints", str(path), "--detector", "harris3d"]) == 2
    err = capsys.readouterr().err
    assert "harris3d" in err and err.count("\n") == 1


# -- repeatability ----------------------------------------------------------------------------
def test_repeatability_metric(bump):
    shape, tips, _ = bump
    n = shape.n_vertices
    ident = np.arange(n)
    rep = keypoint_repeatability(shape, tips, tips, ident, [0.0, 0.05])
    np.testing.assert_allclose(rep, [1.0, 1.0])
    far = [int(np.argmin(shape.vertices @ BUMP_DIRS[0]))]  # the opposite pole of the largest bump
    rep = keypoint_repeatability(shape, [tips[0]], far, ident, [0.05, 10.0])
    np.testing.assert_allclose(rep, [0.0, 1.0])
    # half of A's keypoints repeat
    rep = keypoint_repeatability(shape, tips[:2], [tips[0]], ident, 0.05)
    np.testing.assert_allclose(rep, [0.5])
    # a permuted copy with its ground-truth map: repeatability 1
    perm, inv = permuted(shape)
    gt = ground_truth_map(shape, ident, inv, n)
    np.testing.assert_array_equal(gt, inv)
    rep = repeatability_report(shape, perm, tips, inv[tips], gt, np.argsort(inv), [0.01, 0.05])
    assert rep["a_to_b"] == [1.0, 1.0] and rep["b_to_a"] == [1.0, 1.0]
    assert 0 < rep["chance"][0] < rep["chance"][1] < 1
    cov = keypoint_coverage(shape, tips, [0.0, 0.05, 100.0])
    assert cov[0] < cov[1] and cov[2] == pytest.approx(1.0)
    assert np.isnan(keypoint_repeatability(shape, [], tips, ident, 0.05)[0])
    with pytest.raises(ParameterError):
        keypoint_repeatability(shape, [n], tips, ident, 0.05)
    with pytest.raises(ParameterError):
        keypoint_repeatability(shape, tips, tips, ident, -0.1)


def test_ground_truth_map_fills_unlisted_vertices(bump):
    shape, _, _ = bump
    listed = np.arange(0, shape.n_vertices, 2)
    m = ground_truth_map(shape, listed, listed + 1, shape.n_vertices + 1)
    np.testing.assert_array_equal(m[listed], listed + 1)
    assert m.shape == (shape.n_vertices,) and set(np.unique(m)) <= set((listed + 1).tolist())
    with pytest.raises(ParameterError):
        ground_truth_map(shape, listed, listed[:-1], shape.n_vertices)


def test_unknown_family_member():
    with pytest.raises(PluginError):
        create_plugin("descriptors", "shot")


# -- issue 10: declared spectra, sklearn contract -------------------------------------------------
SPECTRAL = [
    ("keypoints", "adf-maxima", {"t": 10.0, "K": 10}),
    ("descriptors", "hks", {"n_times": 4, "K": 20}),
    ("descriptors", "wks", {"n_energies": 8, "K": 20}),
    ("descriptors", "heat-diffusion", {"K": 8, "n_times": 3}),
    ("descriptors", "heat-distance", {"K": 8, "n_times": 3}),
]


def _run(plugin, shape, spectrum=None, tips=None):
    if plugin.family == "keypoints":
        return plugin.detect(shape, spectrum=spectrum)
    return plugin.compute(shape, spectrum=spectrum, keypoints=tips)


@pytest.mark.parametrize("family, name, params", SPECTRAL)
def test_plugins_declare_and_check_their_spectrum(family, name, params):
    from sklearn.base import clone

    from shape_toolkit.spectra import default_spec

    shape, tips = bumpy_sphere(2)
    plug = create_plugin(family, name, **params)
    assert "random_state" not in plug.get_params()  # deterministic
    spec = plug.spectrum_spec()
    assert (spec.weighting, spec.laplacian, spec.use_mass) == ("gaussian", "combinatorial", None)
    out = _run(plug, shape, None, tips)
    np.testing.assert_allclose(_run(plug, shape, spec.compute(shape), tips), out)
    np.testing.assert_allclose(_run(clone(plug), shape, None, tips), out)
    # a longer spectrum of the same kind gives the same output (the plugin uses what it declared)
    longer = default_spec(spec.k + 10, "graph").compute(shape)
    np.testing.assert_allclose(_run(plug, shape, longer, tips), out, rtol=1e-6, atol=1e-7)
    with pytest.raises(SpectrumMismatchError, match="fewer than"):
        _run(plug, shape, longer.truncated(spec.k - 1), tips)
    with pytest.raises(SpectrumMismatchError, match="Laplacian"):
        _run(plug, shape, default_spec(spec.k, "graph", laplacian="normalized").compute(shape), tips)


def test_harris3d_declares_no_spectrum_and_clones():
    from sklearn.base import clone

    shape, _ = bumpy_sphere(2)
    h = create_plugin("keypoints", "harris3d", preset="sparse")
    assert h.spectrum_spec() is None and "random_state" not in h.get_params()
    np.testing.assert_array_equal(clone(h).detect(shape), h.detect(shape))


@pytest.mark.parametrize("name", ["heat-diffusion", "heat-distance"])
def test_descriptor_times_are_the_times_compute_uses(name):
    shape, tips = bumpy_sphere(2)
    plug = create_plugin("descriptors", name, K=8, n_times=3)
    times = plug.descriptor_times(shape)
    fixed = create_plugin("descriptors", name, K=8, times=times.tolist())
    np.testing.assert_allclose(fixed.compute(shape, keypoints=tips), plug.compute(shape, keypoints=tips))


# -- scale-free defaults (issue 30) ------------------------------------------------------------
@pytest.mark.parametrize("subdivisions", [3, 4])
def test_default_keypoints_survive_a_4x_refinement(subdivisions):
    """The same keypoints, within tolerance, on a mesh and on its 4x refinement (midpoint
    subdivision: the same surface, 4x the faces, eigenvalues 4x smaller)."""
    import igl

    from shape_toolkit.data.synthetic import articulated_shape

    gen = articulated_shape(subdivisions=subdivisions, random_state=0)
    coarse = gen.shape
    V, F = igl.upsample(coarse.vertices, coarse.faces)
    fine = Shape(V, F, "refined")  # the first n vertices are the coarse ones
    a = create_plugin("keypoints", "adf-maxima").detect(coarse)
    b = create_plugin("keypoints", "adf-maxima").detect(fine)
    assert abs(len(a) - len(b)) <= 0.2 * max(len(a), len(b))
    # each coarse keypoint has a fine one nearby (within 3 coarse edge lengths)
    edge = np.linalg.norm(coarse.vertices[coarse.faces[:, 0]] - coarse.vertices[coarse.faces[:, 1]], axis=1).mean()
    d = np.linalg.norm(coarse.vertices[a][:, None] - fine.vertices[b][None], axis=2).min(axis=1)
    assert (d <= 3 * edge).mean() >= 0.8
    # the literal thesis time is not scale-free: on the five-limbed shape the counts differ
    lit = [len(create_plugin("keypoints", "adf-maxima", preset="thesis-sparse").detect(s)) for s in (coarse, fine)]
    assert lit[0] != lit[1]


def test_default_keypoints_are_the_limb_tips_of_the_demo_shape():
    """The demo's five-limbed shape: the five strongest default keypoints lie one on each limb
    (the thesis's absolute t = 500 gave 2 keypoints, at the body's poles)."""
    from shape_toolkit.data.synthetic import articulated_shape

    gen = articulated_shape(random_state=0)
    kp = create_plugin("keypoints", "adf-maxima").detect(gen.shape)
    assert sorted(gen.labels[kp[:5]].tolist()) == [1, 2, 3, 4, 5]
