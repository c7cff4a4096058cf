"""Input-handling defects of issue 27 (the bad-input corpus, items 7-8): each is a typed error in the
API and one line with exit 2 from the CLI, or a correct result; never an internal error or a null."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import run_cli

from shape_toolkit.core.shape import Shape
from shape_toolkit.data.generate import icosphere
from shape_toolkit.errors import InvalidShapeError, ParameterError
from shape_toolkit.io.mesh import save_shape


def _one_line_rejection(code: int, out: str, err: str, needle: str) -> None:
    assert code == 2, (code, err)
    assert len(err.strip().splitlines()) == 1, err
    assert needle in err, err


def _ints(path: Path, values) -> Path:
    path.write_text("".join(f"{int(v)}\n" for v in values))
    return path


# ------------------------------------------------------------------------------------------------
# evaluate-map on degenerate targets: no null error
# ------------------------------------------------------------------------------------------------
DEGENERATE = {
    "zero_area": ([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]]),
    "repeated_index": ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 1, 2]]),
    "collinear_fan": ([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], [[0, 1, 2], [0, 2, 3]]),
}


@pytest.mark.parametrize("name", sorted(DEGENERATE))
def test_geodesic_errors_refuse_a_target_of_zero_area(name):
    from shape_toolkit.metrics.correspondence import error_normalization, geodesic_errors

    v, f = DEGENERATE[name]
    s = Shape(np.asarray(v, dtype=float), np.asarray(f))
    ids = np.arange(s.n_vertices)
    with pytest.raises(InvalidShapeError, match="zero surface area.*undefined"):
        geodesic_errors(s, ids, ids, ids, method="dijkstra")
    with pytest.raises(InvalidShapeError, match="zero surface area"):
        error_normalization(s)
    # unnormalized distances are defined
    assert np.isfinite(geodesic_errors(s, ids, ids, ids, method="dijkstra", normalize=False)).all()


@pytest.mark.parametrize("name", sorted(DEGENERATE))
@pytest.mark.parametrize("sym", [False, True])
def test_evaluate_map_on_a_degenerate_mesh_is_a_one_line_rejection(tmp_path, capsys, name, sym):
    v, f = DEGENERATE[name]
    p = tmp_path / "m.off"
    save_shape(Shape(np.asarray(v, dtype=float), np.asarray(f)), p)
    n = len(v)
    m, t = _ints(tmp_path / "id.map", range(n)), _ints(tmp_path / "t.vts", range(1, n + 1))
    extra = ["--truth-dst-sym", t] if sym else []
    code, out, err = run_cli(capsys, "evaluate-map", p, p, m, "--truth-src", t, "--truth-dst", t,
                          "--geodesics", "dijkstra", "--json", *extra)
    _one_line_rejection(code, out, err, "zero surface area")
    assert out == ""


def test_evaluate_map_on_a_mesh_of_one_point_is_a_one_line_rejection(tmp_path, capsys):
    """Every vertex at one place: refused when the shape is read (no extent), before any metric."""
    p = tmp_path / "m.off"
    p.write_text("OFF\n3 1 0\n1 1 1\n1 1 1\n1 1 1\n3 0 1 2\n")
    m, t = _ints(tmp_path / "id.map", range(3)), _ints(tmp_path / "t.vts", range(1, 4))
    code, out, err = run_cli(capsys, "evaluate-map", p, p, m, "--truth-src", t, "--truth-dst", t,
                             "--geodesics", "dijkstra", "--json")
    _one_line_rejection(code, out, err, "all 3 vertices are at one point")
    assert out == ""


def test_evaluate_map_refuses_when_no_truth_pair_is_matched(tmp_path, capsys):
    s = icosphere(2)
    p = tmp_path / "s.off"
    save_shape(s, p)
    tmap = np.arange(s.n_vertices)
    tmap[:10] = -1  # the truth points only
    m = _ints(tmp_path / "m.map", tmap)
    t = _ints(tmp_path / "t.vts", range(1, 11))
    code, out, err = run_cli(capsys, "evaluate-map", p, p, m, "--truth-src", t, "--truth-dst", t,
                          "--geodesics", "dijkstra", "--json")
    _one_line_rejection(code, out, err, "mean geodesic error is undefined")


def test_evaluate_map_on_a_mesh_with_repeated_vertices_gives_numbers(tmp_path, capsys):
    p = tmp_path / "rep.off"
    save_shape(Shape(np.array([[0, 0, 0], [1, 0, 0], [1, 0, 0], [0, 1, 0.0]]), np.array([[0, 1, 3], [1, 2, 3]])), p)
    m, t = _ints(tmp_path / "id.map", range(4)), _ints(tmp_path / "t.vts", range(1, 5))
    code, out, err = run_cli(capsys, "evaluate-map", p, p, m, "--truth-src", t, "--truth-dst", t,
                          "--geodesics", "dijkstra", "--json")
    assert code == 0, err
    res = json.loads(out)
    assert res["mean_geodesic_error"] == 0.0 and res["matched_fraction"] == 1.0


# ------------------------------------------------------------------------------------------------
# transfer-labels / eigenvector matchers on tiny or odd meshes: one embedding size for both shapes
# ------------------------------------------------------------------------------------------------
def _fan(n: int = 6) -> Shape:
    t = 2 * np.pi * np.arange(n) / n
    v = np.r_[[[0.0, 0.0, 0.0]], np.c_[np.cos(t), np.sin(t), np.zeros(n)]]
    return Shape(v, np.array([[0, 1 + i, 1 + (i + 1) % n] for i in range(n)]))


TINY = {
    "triangle": Shape(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]]), np.array([[0, 1, 2]])),
    "quad": Shape(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]]), np.array([[0, 1, 2], [1, 3, 2]])),
    "fan": _fan(),
    "non_manifold_fan": Shape(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1.0]]),
                              np.array([[0, 1, 2], [0, 1, 3], [0, 1, 4]])),
}
PAIRS = [(a, b) for a in TINY for b in TINY if a != b] + [("sphere", "triangle"), ("triangle", "sphere")]


def _tiny(name: str) -> Shape:
    return icosphere(1) if name == "sphere" else TINY[name]


@pytest.mark.parametrize(("a", "b"), PAIRS)
def test_eigvec_alignment_between_meshes_of_different_tiny_sizes(a, b):
    """Issue 27: a 3-vertex mesh has 2 non-constant eigenvectors, a 5-vertex one 4: the histogram
    alignment built a (2, 2) matrix and indexed it with the target's 4 (IndexError), or EM refused
    'X, Y and Q0 must share the embedding dimension'. Both shapes now embed in the size they share."""
    from shape_toolkit.api.registry import create_plugin
    from shape_toolkit.results.label_transfer import probabilistic_label_transfer

    src, dst = _tiny(a), _tiny(b)
    corr = create_plugin("dense_matchers", "eigvec-alignment").match(src, dst)
    assert corr.target_of.shape == (src.n_vertices,) and (corr.target_of >= 0).all()
    assert corr.info["embedding_dim"] == min(8, src.n_vertices - 1, dst.n_vertices - 1)
    labels, _ = probabilistic_label_transfer(src, np.arange(src.n_vertices) % 2, dst)
    assert labels.shape == (dst.n_vertices,) and set(labels.tolist()) <= {0, 1}


def test_histogram_alignment_refuses_embeddings_of_different_sizes():
    from shape_toolkit.plugins.matching.dense.eigvec_alignment import histogram_alignment

    with pytest.raises(ParameterError, match="one k"):
        histogram_alignment(np.ones((3, 2)), np.ones((5, 4)), np.ones(3), np.ones(5))


def test_shared_dimension_needs_a_non_constant_eigenvector():
    from shape_toolkit.features.basis import Basis
    from shape_toolkit.plugins.matching.dense.em_registration import EMRegistrationMatcher

    one = Basis(np.zeros(1), np.ones((1, 1)), np.ones(1))
    three = Basis(np.zeros(3), np.ones((3, 3)), np.ones(3) / 3)
    assert EMRegistrationMatcher._shared_dimension(8, three, three) == 2
    with pytest.raises(InvalidShapeError, match="only the constant one"):
        EMRegistrationMatcher._shared_dimension(8, one, three)


@pytest.mark.parametrize(("a", "b"), PAIRS)
def test_transfer_labels_cli_on_tiny_meshes(tmp_path, capsys, a, b):
    src, dst = _tiny(a), _tiny(b)
    save_shape(src, tmp_path / "a.off")
    save_shape(dst, tmp_path / "b.off")
    lab = _ints(tmp_path / "a.labels", np.arange(src.n_vertices) % 2)
    code, out, err = run_cli(capsys, "transfer-labels", tmp_path / "a.off", lab, tmp_path / "b.off",
                          "-o", tmp_path / "out.txt", "--json")
    assert code == 0, err
    assert json.loads(out)["n_vertices"] == dst.n_vertices


# ------------------------------------------------------------------------------------------------
# constraints given to a segmenter that takes none: refused, never ignored
# ------------------------------------------------------------------------------------------------
TAKES_CONSTRAINTS = {"ccskl", "csc", "seeded-walk", "spectral-learning"}


def test_every_segmenter_says_whether_it_takes_constraints():
    from shape_toolkit.api.registry import available_plugins, create_plugin, plugins_taking_constraints

    assert set(plugins_taking_constraints()) == TAKES_CONSTRAINTS
    for name in available_plugins()["segmenters"]:
        seg = create_plugin("segmenters", name)
        assert seg.accepts_constraints() == (name in TAKES_CONSTRAINTS), name
    assert create_plugin("segmenters", "smoothed", base="csc").accepts_constraints()
    assert not create_plugin("segmenters", "smoothed", base="eigvec-gmm").accepts_constraints()


@pytest.mark.parametrize("name", ["eigvec-gmm", "spectral-clustering", "ncut", "sdf", "smoothed"])
def test_unsupervised_segmenters_refuse_constraints(name):
    """Issue 27: eigvec-gmm silently ignored --constraints (so did every unsupervised segmenter)."""
    from shape_toolkit.api.registry import create_plugin
    from shape_toolkit.results.labels import Constraints

    s = icosphere(2)
    seg = create_plugin("segmenters", name)
    with pytest.raises(ParameterError, match="takes no constraints.*semi-supervised"):
        seg.segment(s, constraints=Constraints([[0, 1]], []))
    with pytest.raises(ParameterError, match="takes no constraints"):
        seg.segment(s, constraints={"must_link": [[0, 1]]})


@pytest.mark.parametrize("name", ["eigvec-gmm", "spectral-clustering", "ncut", "sdf", "smoothed"])
def test_segment_cli_refuses_constraints_for_unsupervised_methods(tmp_path, capsys, name):
    s = icosphere(2)
    save_shape(s, tmp_path / "s.off")
    cons = tmp_path / "c.json"
    cons.write_text(json.dumps({"must_link": [[0, 1]], "cannot_link": [[0, 100]]}))
    code, out, err = run_cli(capsys, "segment", tmp_path / "s.off", "--method", name, "-k", "3", "--constraints", cons,
                          "-o", tmp_path / "s.txt", "--json")
    _one_line_rejection(code, out, err, "takes no constraints")
    assert "ccskl, csc, seeded-walk, spectral-learning" in err
    assert not (tmp_path / "s.txt").exists()


def test_segment_cli_still_passes_constraints_to_csc(tmp_path, capsys):
    s = icosphere(2)
    save_shape(s, tmp_path / "s.off")
    cons = tmp_path / "c.json"
    cons.write_text(json.dumps({"must_link": [[0, 1]], "cannot_link": [[0, 100]]}))
    code, out, err = run_cli(capsys, "segment", tmp_path / "s.off", "--method", "csc", "-k", "3", "--constraints", cons,
                          "-o", tmp_path / "s.txt", "--json")
    assert code == 0, err
    assert json.loads(out)["n_constraints"] == {"must_link": 1, "cannot_link": 1}


# ------------------------------------------------------------------------------------------------
# view without a display: one line, exit 2, naming --png
# ------------------------------------------------------------------------------------------------
def test_display_problem_rule():
    from shape_toolkit.cli.commands.view import display_problem

    assert "DISPLAY" in display_problem({}, "linux")
    assert display_problem({"DISPLAY": " "}, "linux") is not None
    assert display_problem({"DISPLAY": ":0"}, "linux") is None
    assert display_problem({"WAYLAND_DISPLAY": "wayland-0"}, "linux") is None
    assert display_problem({}, "darwin") is None and display_problem({}, "win32") is None


class _FakePolyscope:
    def __init__(self, fail: bool):
        self.fail, self.inits = fail, 0

    def init(self):
        self.inits += 1
        if self.fail:
            raise RuntimeError("[polyscope]  [EXCEPTION] Automatic initialization: no Polyscope backends could be "
                               "initialized successfully.Polyscope was compiled with support for EGL")


@pytest.fixture
def mesh_file(tmp_path):
    p = tmp_path / "s.off"
    save_shape(icosphere(1), p)
    return p


def test_view_without_display_is_one_line(monkeypatch, capsys, mesh_file):
    """Issue 27: without a display (viz extra installed) view printed polyscope's lines and a multi-line
    internal error, exit 1."""
    from shape_toolkit.cli.commands import view

    fake = _FakePolyscope(fail=True)
    monkeypatch.setattr(view, "_polyscope", lambda: fake)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(view.sys, "platform", "linux")
    code, out, err = run_cli(capsys, "view", mesh_file)
    _one_line_rejection(code, out, err, "no display")
    assert "--png" in err and fake.inits == 0 and out == ""


def test_view_with_a_display_that_cannot_open_is_one_line(monkeypatch, capsys, mesh_file):
    from shape_toolkit.cli.commands import view

    registered = []
    monkeypatch.setattr(view.atexit, "register", registered.append)
    monkeypatch.setattr(view, "_polyscope", lambda: _FakePolyscope(fail=True))
    monkeypatch.setenv("DISPLAY", ":99")
    code, out, err = run_cli(capsys, "view", mesh_file)
    _one_line_rejection(code, out, err, "cannot open the viewer window (Automatic initialization")
    assert "--png" in err and registered == [view._quiet_exit]


def test_view_png_needs_no_display(monkeypatch, capsys, tmp_path, mesh_file):
    from shape_toolkit.cli.commands import view

    monkeypatch.setattr(view, "_polyscope", lambda: pytest.fail("--png must not start polyscope"))
    monkeypatch.delenv("DISPLAY", raising=False)
    odd = tmp_path / "$\\frac{a}{b}$ <script>.off"  # a name matplotlib must not parse as a formula
    odd.write_bytes(mesh_file.read_bytes())
    labels = _ints(tmp_path / "l.txt", np.arange(icosphere(1).n_vertices) % 3)
    code, out, err = run_cli(capsys, "view", odd, "--labels", labels, "--png", tmp_path / "v.png", "--json")
    assert code == 0, err
    assert json.loads(out)["panels"] == [odd.stem]
    assert (tmp_path / "v.png").read_bytes()[:4] == b"\x89PNG"
    code, out, err = run_cli(capsys, "view", mesh_file, "--png", mesh_file)
    _one_line_rejection(code, out, err, "--png must end with .png")
    code, out, err = run_cli(capsys, "view", mesh_file, "--json")
    _one_line_rejection(code, out, err, "--json applies to --png")


# ------------------------------------------------------------------------------------------------
# --param with a JSON table or list where a name is expected: one line naming the parameter
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("value", ['{"a":1}', "[1,2]"])
@pytest.mark.parametrize("command", ["spectrum", "keypoints", "segment", "describe"])
def test_param_table_is_a_one_line_rejection_naming_the_parameter(tmp_path, capsys, mesh_file, command, value):
    """Issue 27: --param 'weighting={"a":1}' gave internal errors (build_graph got the keyword twice on
    spectrum; an unhashable dict reached the registry on keypoints and segment)."""
    extra = {"segment": ["--method", "eigvec-gmm", "-o", tmp_path / "s.txt"],
             "describe": ["-o", tmp_path / "d.npz"]}.get(command, [])
    code, out, err = run_cli(capsys, command, mesh_file, *extra, "--param", f"weighting={value}", "--json")
    _one_line_rejection(code, out, err, "weighting")
    assert "internal error" not in err


def test_build_graph_and_registry_refuse_names_that_are_not_strings():
    from shape_toolkit.api.registry import get_plugin
    from shape_toolkit.errors import PluginError
    from shape_toolkit.spectra import build_graph

    with pytest.raises(ParameterError, match="weighting must be the name of a weighting plugin, got dict"):
        build_graph(icosphere(1), {"a": 1})
    with pytest.raises(PluginError, match="named by a string, got list"):
        get_plugin("weightings", [1, 2])


def test_spectral_clustering_variant_table_is_a_typed_error():
    from shape_toolkit.api.registry import create_plugin

    with pytest.raises(ParameterError, match="variant must be one of 'ng', 'unnormalized', 'random-walk', 'commute"):
        create_plugin("segmenters", "spectral-clustering", n_segments=3, variant={"a": 1}).segment(icosphere(1))


def test_param_names_are_checked_before_any_work(capsys, mesh_file):
    code, out, err = run_cli(capsys, "spectrum", mesh_file, "--param", "connectivity=knn", "--json")
    _one_line_rejection(code, out, err, "CotangentWeighting has no parameter 'connectivity'")


@pytest.mark.parametrize(("family", "name", "params", "needle"), [
    ("dense_matchers", "fmap-zoomout", {"descriptor_params": [1, 2]}, "descriptor_params must be None or a table"),
    ("dense_matchers", "fmap-zoomout", {"descriptor_params": {"a": 1}}, "take n_energies and variance"),
    ("dense_matchers", "fmap-zoomout", {"zoomout_samples": {"a": 1}}, "zoomout_samples must be None or a positive"),
    ("dense_matchers", "greedy-descriptor", {"descriptor_params": "zzz"}, "descriptor_params must be None or a table"),
    ("descriptors", "hks", {"times": {"a": 1}}, "times must be None, a non-negative float or a list"),
    ("descriptors", "hks", {"times": "zzz"}, "times must be None, a non-negative float or a list"),
])
def test_plugin_parameters_of_the_wrong_kind_are_typed_errors(family, name, params, needle):
    """The same kind of --param value on transfer-labels (matchers) and describe: internal errors before."""
    from shape_toolkit.api.registry import create_plugin

    s = icosphere(1)
    p = create_plugin(family, name, **params)
    with pytest.raises(ParameterError, match=needle):
        p.compute(s) if family == "descriptors" else p.match(s, s)


# ------------------------------------------------------------------------------------------------
# what the wider corpus found: explained nulls, tiny point clouds drawn, control characters kept on one line
# ------------------------------------------------------------------------------------------------
def test_info_explains_every_null(tmp_path, capsys):
    bowtie = tmp_path / "bowtie.off"
    save_shape(Shape(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [-1, 0, 0], [-1, -1, 0.0]]),
                     np.array([[0, 1, 2], [0, 3, 4]])), bowtie)
    code, out, err = run_cli(capsys, "info", bowtie, "--json")
    info = json.loads(out)
    assert code == 0 and info["genus"] is None and "closed, connected, manifold" in info["undefined"]["genus"]
    cloud = tmp_path / "c.xyz"
    cloud.write_text("0 0 0\n1 0 0\n0 1 0\n")
    info = json.loads(run_cli(capsys, "info", cloud, "--json")[1])
    assert all(info["undefined"][k] == "a point cloud has no faces" for k, v in info.items() if v is None)
    sphere = tmp_path / "s.off"
    save_shape(icosphere(1), sphere)
    assert "undefined" not in json.loads(run_cli(capsys, "info", sphere, "--json")[1])


def test_evaluate_segmentation_explains_an_undefined_cut_discrepancy(tmp_path, capsys):
    s = icosphere(1)
    save_shape(s, tmp_path / "s.off")
    one = _ints(tmp_path / "one.txt", np.zeros(s.n_vertices))  # one segment: no cut
    two = _ints(tmp_path / "two.seg", np.arange(s.n_faces) % 2)
    code, out, err = run_cli(capsys, "evaluate-segmentation", tmp_path / "s.off", one, "--truth", two, "--json")
    res = json.loads(out)
    assert code == 0 and res["cut_discrepancy"] is None and "needs both" in res["undefined"]["cut_discrepancy"]
    code, out, err = run_cli(capsys, "evaluate-segmentation", tmp_path / "s.off", one, "--truth", one, "--json")
    assert json.loads(out)["cut_discrepancy"] == 0.0 and "undefined" not in json.loads(out)


@pytest.mark.parametrize("n", [1, 2])
def test_render_draws_clouds_of_one_or_two_points(tmp_path, n):
    """view --png on a 1- or 2-point cloud: the view frame's SVD had fewer axes than 3 (IndexError)."""
    from shape_toolkit.viz import render_shapes

    out = render_shapes([{"shape": Shape(np.arange(3 * n, dtype=float).reshape(n, 3))}], tmp_path / "c.png")
    assert out.read_bytes()[:4] == b"\x89PNG"


def test_control_characters_in_names_keep_errors_on_one_line(tmp_path, capsys, mesh_file):
    from shape_toolkit.errors import ShapeFileError, printable

    assert printable("a\nb\tc") == "a\\nb\\tc" and printable("café <b>") == "café <b>"
    assert "\n" not in str(ShapeFileError("x\ny.off", "no such file"))
    cases = [
        (["info", tmp_path / "a\nb.off"], "a\\nb.off: no such file"),
        (["keypoints", mesh_file, "--param", "a\nb=1"], "a parameter name as KEY"),
        (["keypoints", mesh_file, "--param", "t=a\nb"], 't="a\\nb": t expects a number'),
        (["keypoints", mesh_file, "--param", "<script>=1"], "a parameter name as KEY"),
    ]
    for args, needle in cases:
        code, out, err = run_cli(capsys, *args, "--json")
        _one_line_rejection(code, out, err, needle)


def test_cotangent_weights_of_a_mesh_with_only_flat_faces_are_refused_within_bounded_memory():
    """Every face flat (collinear vertices, repeated indices): the weighting left them all out and handed
    libigl no face, whose mass matrix asked for gigabytes (11 GB peak; std::bad_alloc, or the OOM killer).
    Run in a child limited to 2 GB of address space, so a regression cannot take the machine down."""
    import resource
    import subprocess
    import sys

    code = (
        "import numpy as np\n"
        "from shape_toolkit.core.shape import Shape\n"
        "from shape_toolkit.spectra import build_graph\n"
        "from shape_toolkit.errors import InvalidShapeError\n"
        "for v, f in (([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]]),\n"
        "             ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 1, 2]])):\n"
        "    try:\n"
        "        build_graph(Shape(np.array(v, float), np.array(f)), 'cotangent')\n"
        "    except InvalidShapeError as e:\n"
        "        assert 'numerically flat' in str(e), e\n"
        "    else:\n"
        "        raise SystemExit('accepted')\n"
        "print('ok')\n"
    )

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (2 * 1024**3, 2 * 1024**3))

    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, preexec_fn=limit,
                       env={"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr[-500:]


# ------------------------------------------------------------------------------------------------
# clouds on lines: the cloud Laplacian has no triangle to build on
# ------------------------------------------------------------------------------------------------
def _lines(n: int, rows: int) -> np.ndarray:
    """``rows`` parallel lines of ``n`` points each, 1 apart (spacing 1/n along them): collinear neighbourhoods."""
    line = np.column_stack([np.linspace(0, 1, n), np.zeros(n), np.zeros(n)])
    return np.vstack([line + [0, r, 0] for r in range(rows)])


@pytest.mark.parametrize("rows", [1, 2])
@pytest.mark.parametrize("mode", ["sheet", "all"])
def test_the_cloud_laplacian_of_points_on_lines_is_a_typed_error(rows, mode):
    """geometry-central aborted with a RuntimeError ('unreferenced vertex 0'): an internal error, exit 1."""
    from shape_toolkit.plugins.weightings.intrinsic_delaunay import IntrinsicDelaunayWeighting

    with pytest.raises(InvalidShapeError, match="curve, not a surface"):
        IntrinsicDelaunayWeighting(cloud_neighbors=mode).weigh(Shape(_lines(200, rows), None), np.zeros((0, 2), int))


def test_match_cli_refuses_a_collinear_cloud_in_one_line(tmp_path, capsys, mesh_file):
    np.savetxt(tmp_path / "line.xyz", _lines(200, 1))
    code, out, err = run_cli(capsys, "match", tmp_path / "line.xyz", mesh_file, "--pipeline", "zoomout",
                             "-o", tmp_path / "m.txt", "--quiet")
    _one_line_rejection(code, out, err, "curve, not a surface")


@pytest.mark.parametrize("n, needle", [(2, "at least 5 points"), (4, "at least 5 points"),
                                       (20, r"n_neighbors \(30\) must be below its number of points")])
def test_the_cloud_laplacian_of_a_tiny_cloud_names_the_cloud_and_what_it_needs(n, needle):
    """It said 'n_neighbors must be in [3, 1], got 30' (an empty range, for a parameter the user never set)."""
    from shape_toolkit.plugins.weightings.intrinsic_delaunay import IntrinsicDelaunayWeighting

    cloud = Shape(np.random.default_rng(0).random((n, 3)), None, name="tiny")
    with pytest.raises(ParameterError, match=rf"'tiny'.*{needle}"):
        IntrinsicDelaunayWeighting().weigh(cloud, np.zeros((0, 2), int))
