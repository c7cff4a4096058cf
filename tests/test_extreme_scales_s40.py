"""Coordinates far from 1: a shape read at 1e150 can be inspected (issue 27), but the computations multiply two
areas (the Laplacian's weights and masses), which leave float64 near 1e76 and 1e-75. Every plugin's work method and
the heat and fast-marching geodesics refuse such a shape in one line naming the fix, instead of an overflow warning
followed by a misleading error ("invalid mass vector", "zero mass: clean the shape") or a result computed through
infinities (the default segmenter exited 0). Exact geodesics are scale-free: libigl's MMP compares lengths with
absolute tolerances and looped forever at 1e-30 coordinates."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import run_cli, time_budget

from shape_toolkit.core.shape import Shape, check_extent
from shape_toolkit.data.generate import icosphere
from shape_toolkit.data.synthetic import articulated_shape
from shape_toolkit.errors import InvalidShapeError
from shape_toolkit.io.mesh import save_shape


@pytest.fixture(autouse=True)
def _in_process(monkeypatch):
    monkeypatch.setenv("SHAPE_TOOLKIT_IN_PROCESS", "1")


@pytest.mark.parametrize("scale, word", [(1e80, "large"), (1e150, "large"), (1e-80, "small"), (1e-120, "small")])
@pytest.mark.parametrize("command, extra", [
    ("spectrum", ["-k", "8", "-o", "{d}/s.npz"]),
    ("segment", ["-k", "3", "-o", "{d}/s.labels.txt"]),
    ("keypoints", ["-o", "{d}/k.txt"]),
    ("match", ["{shape}", "-o", "{d}/m.txt"]),
    ("geodesics", ["--sources", "0", "-o", "{d}/g.npz"]),
])
def test_computations_refuse_coordinates_whose_area_products_leave_float64(tmp_path, capsys, scale, word, command,
                                                                           extra):
    s = icosphere(2)
    p = tmp_path / "far.off"
    save_shape(Shape(s.vertices * scale, s.faces), p)
    args = [a.format(d=tmp_path, shape=p) for a in extra]
    code, out, err = run_cli(capsys, command, p, *args)
    assert code == 2 and out == "", err
    assert len(err.strip().splitlines()) == 1, err  # no overflow warning before it
    assert f"too {word} for the toolkit's computations" in err and "rescale the shape" in err, err


def test_info_still_reads_a_shape_beyond_the_computations_range(tmp_path, capsys):
    s = icosphere(2)
    p = tmp_path / "far.off"
    save_shape(Shape(s.vertices * 1e150, s.faces), p)
    code, out, err = run_cli(capsys, "info", p, "--json")
    assert code == 0, err


@pytest.mark.parametrize("scale", [1e-70, 1e-30, 1e30, 1e70])
def test_within_the_range_the_spectrum_scales_as_the_laplacian_does(scale):
    """lambda(s X) = lambda(X) / s^2: the check refuses nothing the computations can do."""
    from shape_toolkit.core.spectrum import compute_spectrum
    from shape_toolkit.spectra import build_graph

    s = icosphere(2)
    ref = compute_spectrum(build_graph(s, "cotangent"), 8).eigenvalues
    far = compute_spectrum(build_graph(Shape(s.vertices * scale, s.faces), "cotangent"), 8).eigenvalues
    np.testing.assert_allclose(far * scale**2, ref, rtol=1e-6, atol=1e-9)


def test_the_computations_range_of_check_extent():
    s = icosphere(2)
    n = max(s.n_vertices, s.n_faces)
    assert check_extent(s.vertices * 1e70, n, power=4) == pytest.approx(s.diagonal * 1e70)
    for scale, word in ((1e80, "large"), (1e-80, "small")):
        with pytest.raises(InvalidShapeError, match=f"too {word} for the toolkit's computations.*must lie in"):
            check_extent(s.vertices * scale, n, power=4)
        with pytest.raises(InvalidShapeError, match=f"too {word}"):
            Shape(s.vertices * scale, s.faces).check_computable()
    Shape(s.vertices * 1e70, s.faces).check_computable()


@pytest.mark.parametrize("scale", [1e-30, 1e-70, 1e30])
def test_exact_geodesics_are_scale_free(scale):
    """Distances of s X are s times those of X (to rounding), and no tolerance of the solver depends on the units."""
    from shape_toolkit.features.geodesics import clear_geodesic_cache, geodesic_distances

    clear_geodesic_cache()
    s = icosphere(2)
    ref = geodesic_distances(s, [0, 7], method="exact", cache=False)
    with time_budget(60):  # looped forever at 1e-30 before
        far = geodesic_distances(Shape(s.vertices * scale, s.faces), [0, 7], method="exact", cache=False)
    np.testing.assert_allclose(far / scale, ref, rtol=1e-12, atol=1e-12 * ref.max())


@pytest.mark.parametrize("scale", [1e100, 1e-100])
def test_segmentation_metrics_are_scale_free_at_extreme_scales(tmp_path, capsys, scale):
    """Area-weighted metrics square face areas: at 1e100 they overflowed (ten warning lines, values through
    infinities), at 1e-100 they underflowed to zero. The weights are divided by a power of two near the largest."""
    import json

    s = icosphere(2)
    labels, truth = (s.vertices[:, 2] > 0.3).astype(int), (s.vertices[:, 0] > 0).astype(int)
    np.savetxt(tmp_path / "l.txt", labels, fmt="%d")
    np.savetxt(tmp_path / "t.txt", truth, fmt="%d")
    got = {}
    for name, k in (("one", 1.0), ("far", scale)):
        save_shape(Shape(s.vertices * k, s.faces), tmp_path / f"{name}.off")
        code, out, err = run_cli(capsys, "evaluate-segmentation", tmp_path / f"{name}.off", tmp_path / "l.txt",
                                 "--truth", tmp_path / "t.txt", "--json")
        assert code == 0 and err.strip() == "", err
        got[name] = json.loads(out)
    for key in ("rand_index_error", "cut_discrepancy", "hamming", "gce", "lce"):
        assert got["far"][key] == pytest.approx(got["one"][key], rel=1e-9, abs=1e-12), key


@pytest.mark.parametrize("scale", [1e100, 1e-100])
def test_view_png_at_extreme_scales(tmp_path, capsys, scale):
    """The upright frame's second moments and the shading normals are taken on exactly rescaled coordinates: at
    1e100 the frame had failed ('Eigenvalues did not converge', an internal error) and the normals overflowed."""
    from shape_toolkit.viz import upright_frame

    s = icosphere(2)
    p = tmp_path / "far.off"
    save_shape(Shape(s.vertices * scale, s.faces), p)
    code, out, err = run_cli(capsys, "view", p, "--png", tmp_path / "far.png")
    assert code == 0 and err.strip() == "" and (tmp_path / "far.png").stat().st_size > 0, err
    body = articulated_shape(subdivisions=2, random_state=3).shape  # a shape with one upright frame (a sphere has none)
    R1, c1 = upright_frame(body.vertices, body.faces)
    R2, c2 = upright_frame(body.vertices * scale, body.faces)
    np.testing.assert_allclose(R2, R1, atol=1e-9)
    np.testing.assert_allclose(c2 / scale, c1, atol=1e-12)
