"""Bad input from the Python API gets a typed one-line error before any large allocation or hang, never a silently
wrong result: build_graph's memory guard (shared with ``shape-toolkit spectrum``), joint_alignment_candidates'
n_samples, check_seeds' conflicting seeds, EM's stopping test at tol = 0, a bench config's generated counts and its
corruption parameters."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import raw_config, run_cli

from shape_toolkit.core import graph as core_graph
from shape_toolkit.core.shape import Shape
from shape_toolkit.data.generate import icosphere
from shape_toolkit.errors import ParameterError
from shape_toolkit.io.mesh import save_shape
from shape_toolkit.spectra import build_graph


# -- 1. build_graph's memory guard ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def sphere() -> Shape:
    return icosphere(3)  # 642 vertices: 205,761 pairs


@pytest.mark.parametrize("graph", [dict(connectivity="epsilon", radius=1e9), dict(connectivity="knn", n_neighbors=641)])
def test_build_graph_refuses_a_graph_above_the_memory_limit(sphere, graph, monkeypatch):
    """From Python an epsilon radius (or kNN size) linking every pair was built whatever the memory: n^2 / 2 edges."""
    built = []
    monkeypatch.setattr(core_graph, "epsilon_edges", lambda *a: built.append(a))
    monkeypatch.setattr(core_graph, "knn_edges", lambda *a: built.append(a))
    with pytest.raises(ParameterError) as ei:
        build_graph(sphere, "gaussian", memory_limit=1e7, **graph)
    msg = str(ei.value)
    assert "\n" not in msg and "205,761 pairs of the 642 points" in msg and "memory_limit" in msg
    assert ("radius=1e+09" in msg) if "radius" in graph else ("n_neighbors=641" in msg)
    assert not built  # refused before any pair was listed


def test_build_graph_default_limit_is_the_machines_memory(sphere, monkeypatch):
    monkeypatch.setattr(core_graph, "machine_memory", lambda: 1e7)
    with pytest.raises(ParameterError, match=r"\(memory_limit, this machine's memory\)"):
        build_graph(sphere, "gaussian", connectivity="epsilon", radius=1e9)
    monkeypatch.setattr(core_graph, "machine_memory", lambda: None)  # unknown: nothing refused for it
    assert build_graph(sphere, "gaussian", connectivity="epsilon", radius=0.2).n_edges > 0


def test_build_graph_within_the_limit_and_an_infinite_limit_build(sphere):
    g = build_graph(sphere, "gaussian", connectivity="epsilon", radius=1e9, memory_limit=0.1e9)
    assert g.n_edges == 642 * 641 // 2
    assert build_graph(sphere, "gaussian", connectivity="knn", n_neighbors=641, memory_limit=math.inf).n_edges > 0


@pytest.mark.parametrize("kw", [dict(radius="1"), dict(radius=float("nan")), dict(radius=-1.0), dict(radius=True),
                                dict(memory_limit=0), dict(memory_limit="1e9"), dict(memory_limit=float("nan"))])
def test_build_graph_bad_radius_or_limit_is_a_parameter_error(sphere, kw):
    with pytest.raises(ParameterError, match=next(iter(kw))):
        build_graph(sphere, "gaussian", connectivity="epsilon", **{"radius": 0.2, **kw})


def test_cli_spectrum_uses_the_core_check(capsys, tmp_path, monkeypatch):
    """One check, in core: the CLI's refusal comes from core.graph.check_graph_memory (with its option names)."""
    path = tmp_path / "s.off"
    save_shape(icosphere(3), path)
    calls = []
    real = core_graph.check_graph_memory

    def spy(*a, **k):
        calls.append(k)
        return real(*a, **k)

    import shape_toolkit.cli.commands.spectrum as cmd

    monkeypatch.setattr(cmd, "check_graph_memory", spy)
    code, _, err = run_cli(capsys, "spectrum", path, "-q", "-k", "5", "--weighting", "gaussian", "--connectivity",
                           "epsilon", "--radius", "1e9", "--memory-limit", "0.1")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "--radius 1e+09 links about 205,761 pairs" in err and "raise --memory-limit" in err
    assert calls and calls[0]["names"]["radius"] == "--radius"


# -- 4. joint_alignment_candidates' n_samples ------------------------------------------------------------------
@pytest.mark.parametrize("n_samples", [0, -5, 2.5, float("nan"), True, "100", None])
def test_joint_alignment_candidates_refuses_bad_n_samples(n_samples):
    """0 fitted empty point sets (a crash in the k-d tree), -5 a ValueError, 2.5 a TypeError."""
    from shape_toolkit.plugins.matching.dense.eigvec_alignment import joint_alignment_candidates

    X = np.random.default_rng(0).standard_normal((50, 4))
    with pytest.raises(ParameterError, match="n_samples must be a positive int"):
        joint_alignment_candidates(X, X, n_samples=n_samples)


def test_joint_alignment_candidates_huge_n_samples_is_every_point():
    from shape_toolkit.plugins.matching.dense.eigvec_alignment import joint_alignment_candidates

    X = np.random.default_rng(0).standard_normal((50, 4))
    every = joint_alignment_candidates(X, X, beam=6, n_samples=50)
    for n in (10**30, np.int64(2**63 - 1)):
        huge = joint_alignment_candidates(X, X, beam=6, n_samples=n)
        assert len(huge) == len(every) == 6 and all(np.array_equal(a, b) for a, b in zip(huge, every))


# -- 5. check_seeds: one target per source vertex --------------------------------------------------------------
def test_check_seeds_refuses_one_source_vertex_with_two_targets():
    from shape_toolkit.validation import check_seeds

    with pytest.raises(ParameterError) as ei:
        check_seeds([[0, 1], [2, 3], [4, 5], [2, 7]], 10, 10)
    msg = str(ei.value)
    assert "\n" not in msg and "source vertex 2" in msg and "3 and 7" in msg


def test_check_seeds_counts_a_repeated_pair_once():
    from shape_toolkit.validation import check_seeds

    s = check_seeds(np.array([[0, 1], [2, 3], [0, 1], [4, 3], [2, 3]]), 10, 10)
    assert s.dtype == np.int64 and s.tolist() == [[0, 1], [2, 3], [4, 3]]  # order kept, one target shared is fine


def test_a_dense_matcher_refuses_conflicting_seeds():
    from shape_toolkit.api.registry import create_plugin

    s = icosphere(1)
    with pytest.raises(ParameterError, match="source vertex 3 is given two targets, 3 and 9"):
        create_plugin("dense_matchers", "seed-growing").match(s, s, seeds=np.array([[3, 3], [5, 5], [3, 9]]))


def test_proxy_seeds_give_a_proxy_vertex_one_target():
    """Two seeds whose sources are nearest one proxy vertex became one proxy source with two targets, which the
    proxies' pipeline now refuses: the first seed's pair is kept."""
    from shape_toolkit.plugins.matching.multires import proxy_seeds
    from shape_toolkit.validation import check_seeds

    s = icosphere(2)
    ids = np.array([0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11])  # the icosahedron's corners
    far = np.linalg.norm(s.vertices[:12] - s.vertices[12], axis=1).argsort()[:1]  # vertex 12 is near corner far[0]
    seeds = np.array([[int(far[0]), 0], [12, 5], [1, 1]])
    p = proxy_seeds(seeds, s, s, ids, ids)
    assert p[:, 0].tolist() == [int(far[0]), 1] and p.tolist() == check_seeds(p, 12, 12).tolist()


def test_label_transfer_reversed_seeds_stay_one_to_one(monkeypatch):
    """Seeds sharing a target (allowed) became, reversed for a matcher without posteriors, one source vertex with two
    targets: the first is kept."""
    import shape_toolkit.results.label_transfer as lt

    s = icosphere(1)
    seen = []

    class Matcher:
        def match(self, a, b, seeds=None):
            from shape_toolkit.results.correspondence import Correspondence
            from shape_toolkit.validation import check_seeds

            seen.append(None if seeds is None else check_seeds(seeds, a.n_vertices, b.n_vertices).tolist())
            return Correspondence(np.arange(a.n_vertices), b.n_vertices)

    monkeypatch.setattr("shape_toolkit.api.registry.create_plugin", lambda *a, **k: Matcher())
    lt.probabilistic_label_transfer(s, np.zeros(s.n_vertices, dtype=np.int64), s, seeds=np.array([[0, 5], [1, 5]]))
    assert seen == [[[0, 5], [1, 5]], [[5, 0]]]


def test_sparse_matchers_emit_one_target_per_source_vertex():
    """The pipeline passes the sparse stage's seeds through check_seeds: every sparse matcher is one-to-one."""
    from shape_toolkit.plugins.matching.association import greedy_discretize

    nodes = np.array([[0, 0], [0, 1], [1, 1], [2, 0], [2, 2]])
    chosen = greedy_discretize(nodes, np.array([0.5, 0.9, 0.8, 0.7, 0.6]))
    pairs = nodes[chosen]
    assert len(np.unique(pairs[:, 0])) == len(pairs) and pairs.tolist() == [[0, 1], [2, 0]]  # highest scores kept


# -- 6. EM stops at an exact fixed point with tol = 0 ----------------------------------------------------------
def test_em_register_stops_on_an_exact_fixed_point_at_tol_zero(monkeypatch):
    """With tol = 0 the test ``change < tol`` never fired: a converged fit ran all max_iter iterations."""
    from shape_toolkit.plugins.matching import em

    X = np.random.default_rng(0).standard_normal((60, 3))
    calls = []
    real = em._e_step

    def counted(*a):
        calls.append(1)
        return real(*a)

    monkeypatch.setattr(em, "_e_step", counted)
    Q, sigma, _ = em.em_register(X, X, np.eye(3), outlier_weight=0.0, n_neighbors=1, max_iter=50, tol=0.0,
                                 posteriors=False)
    assert len(calls) <= 5 and np.allclose(Q, np.eye(3))


# -- 2. a generated dataset's counts are bounded without max_rows ---------------------------------------------
_bench = raw_config


@pytest.mark.parametrize("kind,params,key,bound", [
    ("synthetic", {"n_poses": 10**9}, "n_poses", "[1, 1000]"),
    ("sequence", {"frames": 10**9}, "frames", "[2, 1000]"),
])
def test_generated_counts_are_bounded_without_max_rows(kind, params, key, bound, monkeypatch):
    """With max_rows=None a billion poses were listed (a billion item refs), a billion frames generated per row."""
    from shape_toolkit.bench.config import ConfigError, parse_config
    from shape_toolkit.data import datasets

    def never(*a, **k):
        raise AssertionError("the dataset was listed")

    monkeypatch.setitem(datasets.DATASET_KINDS, kind, never)
    raw = _bench()
    raw["datasets"][0] = {"name": "d", "kind": kind, "params": params}
    if kind == "sequence":
        raw["tasks"] = [{"task": "sequence", "methods": [{"pipeline": "zoomout"}]}]
    with pytest.raises(ConfigError) as ei:
        parse_config(raw, max_rows=None)
    assert ei.value.key == f"datasets[0].params.{key}" and bound in str(ei.value) and "\n" not in str(ei.value)


def test_the_generators_check_their_own_count_bounds():
    from shape_toolkit.data.datasets import sequence_refs, synthetic_refs
    from shape_toolkit.data.synthetic import MAX_FRAMES, MAX_POSES, pose_sequence, synthetic_dataset

    for call in (lambda: synthetic_dataset(MAX_POSES + 1, subdivisions=0), lambda: synthetic_refs(10**9),
                 lambda: pose_sequence(MAX_FRAMES + 1, subdivisions=0), lambda: sequence_refs([0], frames=10**9)):
        with pytest.raises(ParameterError, match="1000"):
            call()
    assert len(synthetic_refs(MAX_POSES)) == MAX_POSES  # the bound itself is listed


# -- 3. corruption parameters are checked when the config is read ---------------------------------------------
@pytest.mark.parametrize("entry,key,words", [
    ({"kind": "holes", "params": {"strength": 5000}}, "corruptions[0].params.strength", ["'holes'", "[0, 1000]"]),
    ({"kind": "gaussian-noise", "params": {"strength": [0.1, -1]}}, "corruptions[0].params.strength",
     ["'gaussian-noise'", "got -1"]),
    ({"kind": "crop", "params": {"attempts": 10**6}}, "corruptions[0].params.attempts", ["'crop'", "attempts"]),
    ({"kind": "subdivide", "params": {"splits": 0}}, "corruptions[0].params.splits", ["'subdivide'", "[1, 64]"]),
    ({"steps": [{"kind": "gaussian-noise"}, {"kind": "glue", "params": {"radius": -0.1}}]},
     "corruptions[0].steps[1].params.radius", ["'glue'", "radius"]),
])
def test_bad_corruption_parameters_are_refused_when_the_config_is_read(entry, key, words):
    """They were checked only when each row applied the corruption: every row failed, the config was accepted."""
    from shape_toolkit.bench.config import ConfigError, parse_config

    raw = _bench()
    raw["corruptions"] = [{"name": "c", **entry}]
    raw["tasks"][0]["corruptions"] = ["c"]
    with pytest.raises(ConfigError) as ei:
        parse_config(raw)
    assert ei.value.key == key, str(ei.value)
    assert all(w in str(ei.value) for w in words) and "\n" not in str(ei.value)


def test_the_config_check_is_the_corruptions_own():
    """One declaration (CORRUPTION_PARAMS): what the config refuses, the corruption refuses with the same words."""
    from shape_toolkit.data.corruptions import CORRUPTION_PARAMS, apply_corruption, check_corruption_params

    s = icosphere(1)
    for kind, declared in CORRUPTION_PARAMS.items():
        for name in declared:
            with pytest.raises(ParameterError) as at_parse:
                check_corruption_params(kind, {name: "x"})
            with pytest.raises(ParameterError) as at_run:
                apply_corruption(s, kind, **{name: "x"})
            assert str(at_parse.value) == str(at_run.value), kind
    check_corruption_params("holes", {"strength": 3, "radius": 0.05})  # valid values pass


def test_every_built_in_corruption_declares_its_bounded_parameters():
    """Each corruption of the package has its declarations (a new one without them would go unchecked at parse time),
    and a corruption added to CORRUPTIONS from outside, with none, still passes the config check (it checks its own)."""
    import inspect

    from shape_toolkit.data import corruptions

    assert set(corruptions.CORRUPTION_PARAMS) == set(corruptions.CORRUPTIONS)
    for kind, fn in corruptions.CORRUPTIONS.items():
        if "strength" in inspect.signature(fn).parameters:
            assert "strength" in corruptions.CORRUPTION_PARAMS[kind], kind

    def added(shape, *, strength: float = 0.1, random_state: int = 0):
        return shape, np.arange(shape.n_vertices)

    corruptions.CORRUPTIONS["added-s40"] = added
    try:
        corruptions.check_corruption_params("added-s40", {"strength": 5.0})
        with pytest.raises(ParameterError, match="no parameter"):
            corruptions.check_corruption_params("added-s40", {"sigma": 1.0})
    finally:
        del corruptions.CORRUPTIONS["added-s40"]


# -- 8. every numeric corruption parameter declared and bounded (remesh, glue, point-cloud, subdivide) ------------
def test_every_corruption_parameter_is_declared():
    """remesh's iterations and glue's candidates reached pymeshlab / numpy unchecked: no declaration."""
    import inspect

    from shape_toolkit.data.corruptions import CORRUPTION_PARAMS, CORRUPTIONS

    for kind, fn in CORRUPTIONS.items():
        params = set(inspect.signature(fn).parameters) - {"shape", "random_state"}
        assert params == set(CORRUPTION_PARAMS[kind]), kind


@pytest.mark.parametrize("kind,params,words", [
    ("remesh", {"n_vertices": 10**10}, ["n_vertices", "[20, 2000000]", "10000000000"]),
    ("remesh", {"iterations": 10**9}, ["iterations", "[1, 100]", "1000000000"]),
    ("remesh", {"iterations": 0}, ["iterations", "[1, 100]"]),
    ("glue", {"candidates": 0}, ["candidates", "[1, 50000000]"]),
    ("glue", {"candidates": -5}, ["candidates", "-5"]),
    ("point-cloud", {"points": 10**12}, ["points", "[2, 50000000]"]),
])
def test_unbounded_corruption_counts_are_refused(kind, params, words, monkeypatch):
    """Refused when a config is read and when the corruption runs, before pymeshlab is asked (a remesh to 1e10
    vertices, 1e9 passes) or numpy allocates (1e12 points)."""
    import sys

    from shape_toolkit.data.corruptions import apply_corruption, check_corruption_params

    with pytest.raises(ParameterError) as at_parse:
        check_corruption_params(kind, params)
    assert all(w in str(at_parse.value) for w in words) and "\n" not in str(at_parse.value)
    monkeypatch.setitem(sys.modules, "pymeshlab", None)  # importing it raises: the check comes first
    with pytest.raises(ParameterError) as at_run:
        apply_corruption(icosphere(1), kind, **params)
    assert str(at_run.value) == str(at_parse.value)


def test_remesh_strength_target_within_the_remeshing_budget(monkeypatch):
    """strength * n_vertices (up to 20 times the shape) is held to the same budget as n_vertices."""
    import sys

    from shape_toolkit.data import corruptions

    monkeypatch.setattr(corruptions, "MAX_REMESH_VERTICES", 100)
    monkeypatch.setitem(sys.modules, "pymeshlab", None)
    with pytest.raises(ParameterError) as ei:
        corruptions.remesh(icosphere(2), strength=1.0)  # 162 vertices
    msg = str(ei.value)
    assert "162" in msg and "MAX_REMESH_VERTICES" in msg and "smaller strength" in msg and "\n" not in msg


def test_remesh_bounds_are_the_clean_commands():
    """One constant for the remeshing passes: the CLI's --remesh-iterations and the corruption's iterations."""
    from shape_toolkit.cli.commands import clean
    from shape_toolkit.core import cleanup
    from shape_toolkit.data.corruptions import CORRUPTION_PARAMS

    assert clean.MAX_REMESH_ITERATIONS is cleanup.MAX_REMESH_ITERATIONS
    assert CORRUPTION_PARAMS["remesh"]["iterations"].constraints[0].high == cleanup.MAX_REMESH_ITERATIONS
    assert CORRUPTION_PARAMS["remesh"]["n_vertices"].constraints[1].high == cleanup.MAX_REMESH_VERTICES


def test_subdivide_refuses_more_vertices_than_any_shape_before_splitting(monkeypatch):
    """splits up to 64 multiply the vertices by ~2000: the count (split_triangles' formula) is checked first."""
    from shape_toolkit.data import corruptions

    s = icosphere(1)  # 42 vertices, 120 edges, 80 triangles: 4 x 4 splits make 42 + 3 * 120 + 3 * 80 = 642
    monkeypatch.setattr(corruptions, "MAX_VERTICES", 642)
    out, _ = corruptions.subdivide(s, splits=4)
    assert out.n_vertices == 642  # the formula is the count split_triangles makes
    monkeypatch.setattr(corruptions, "MAX_VERTICES", 641)
    monkeypatch.setattr(corruptions, "split_triangles", lambda *a: pytest.fail("split before the check"))
    with pytest.raises(ParameterError) as ei:
        corruptions.subdivide(s, splits=4)
    msg = str(ei.value)
    assert "splits=4" in msg and "642" in msg and "MAX_VERTICES" in msg and "fewer splits" in msg and "\n" not in msg


def test_sequence_remesh_bound_is_the_remeshing_budget(monkeypatch):
    """At subdivisions 7, 20 times a frame's vertices (3,276,840) passed the config, above the remesh corruption's
    budget: every row would have failed."""
    from shape_toolkit.bench.config import ConfigError, parse_config
    from shape_toolkit.core.cleanup import MAX_REMESH_VERTICES
    from shape_toolkit.data import datasets

    monkeypatch.setitem(datasets.DATASET_KINDS, "sequence", lambda *a, **k: pytest.fail("the dataset was listed"))
    raw = _bench()
    raw["datasets"][0] = {"name": "d", "kind": "sequence", "params": {"remesh": 3_000_000, "subdivisions": 7}}
    raw["tasks"] = [{"task": "sequence", "methods": [{"pipeline": "zoomout"}]}]
    with pytest.raises(ConfigError) as ei:
        parse_config(raw, max_rows=None)
    assert ei.value.key == "datasets[0].params.remesh" and f"{MAX_REMESH_VERTICES:,}" in str(ei.value)
    assert "MAX_REMESH_VERTICES" in str(ei.value) and "\n" not in str(ei.value)


# -- 9. edge_length_graph's kNN graph of a point cloud: the memory check of build_graph --------------------------
def test_edge_length_graph_refuses_a_cloud_graph_above_the_memory_limit(sphere, monkeypatch):
    """The neighbours were capped below n, but n * k pairs were queried whatever the memory."""
    cloud = Shape(sphere.vertices)
    monkeypatch.setattr(core_graph, "knn_edges", lambda *a: pytest.fail("neighbours queried"))
    with pytest.raises(ParameterError) as ei:
        core_graph.edge_length_graph(cloud, 10**6, memory_limit=1e6)
    msg = str(ei.value)
    assert "n_neighbors=641" in msg and "642 points" in msg and "memory_limit" in msg and "\n" not in msg
    monkeypatch.setattr(core_graph, "machine_memory", lambda: 1e4)
    with pytest.raises(ParameterError, match=r"n_neighbors=8 .*\(memory_limit, this machine's memory\)"):
        core_graph.edge_length_graph(cloud)


def test_edge_length_graph_within_the_limit_and_on_a_mesh(sphere, monkeypatch):
    monkeypatch.setattr(core_graph, "machine_memory", lambda: 1.0)  # a mesh's own edges are never refused
    assert core_graph.edge_length_graph(sphere).nnz == 2 * len(sphere.edges)
    G = core_graph.edge_length_graph(Shape(sphere.vertices), 8, memory_limit=math.inf)
    assert G.shape == (642, 642) and G.nnz >= 642 * 8
    for bad in (dict(memory_limit=0), dict(memory_limit="1e9"), dict(n_neighbors=2.5)):
        with pytest.raises(ParameterError, match=next(iter(bad))):
            core_graph.edge_length_graph(Shape(sphere.vertices), **{"n_neighbors": 8, **bad})


# -- 10. orient_pairs keeps the preferred pair of a source vertex: the callers pass pairs by decreasing score -------
def test_orient_pairs_keeps_the_earlier_pair_of_a_source_vertex(monkeypatch):
    """The contract: pairs in decreasing preference; a source vertex in two matches keeps the earlier one."""
    from types import SimpleNamespace

    from shape_toolkit.plugins.matching import orientation

    s = icosphere(1)
    ref = SimpleNamespace(sq_distances=lambda a, b: np.zeros(len(a)), target_of=None, basis=None, k_smooth=0)
    monkeypatch.setattr(orientation, "side_reference", lambda *a, **k: ref)
    monkeypatch.setattr(orientation, "symmetry_map", lambda *a, **k: np.arange(s.n_vertices))
    monkeypatch.setattr(orientation, "symmetry_validity", lambda *a, **k: np.zeros(s.n_vertices, dtype=bool))
    assert orientation.orient_pairs(s, s, np.array([[3, 5], [0, 7], [3, 9]])).tolist() == [[3, 5], [0, 7]]
    assert orientation.orient_pairs(s, s, np.array([[3, 9], [0, 7], [3, 5]])).tolist() == [[3, 9], [0, 7]]


def test_association_matchers_pass_pairs_to_orient_pairs_by_decreasing_score(monkeypatch):
    """The one caller honours the contract: scores out of node order reach orient_pairs highest first."""
    from shape_toolkit.api.registry import create_plugin
    from shape_toolkit.plugins.matching import association

    s = icosphere(1)
    nodes = np.array([[0, 0], [1, 1], [2, 2], [3, 3]])
    graph = association.AssociationGraph(nodes, np.ones((4, 4)) - np.eye(4), np.ones(4))
    scores = np.array([0.2, 0.9, 0.5, 0.7])
    seen = []
    monkeypatch.setattr(association, "association_graph", lambda *a, **k: graph)
    monkeypatch.setattr(association, "orient_pairs", lambda s_, t_, pairs, *a: seen.append(pairs) or pairs)
    m = create_plugin("sparse_matchers", "spectral", orientation="preserving")
    monkeypatch.setattr(type(m), "_spectrum", lambda self, shape, spectrum: None)
    monkeypatch.setattr(type(m), "_solve", lambda self, g: scores[: len(g.nodes)])
    kp = np.array([10, 11, 12, 13])
    m.match(s, s, kp, kp)
    assert seen[0][:, 0].tolist() == [11, 13, 12, 10]  # scores 0.9, 0.7, 0.5, 0.2


@pytest.mark.parametrize("iterations", [0, 101, 10**9, 2.5, True, "3"])
def test_clean_shape_bounds_remesh_iterations_as_the_clean_command(iterations):
    """From Python as from `clean --remesh-iterations`: at most MAX_REMESH_ITERATIONS (10**9 had run for hours)."""
    from shape_toolkit.core.cleanup import clean_shape

    with pytest.raises(ParameterError, match="remesh_iterations must be an integer in"):
        clean_shape(icosphere(1), remesh_target_edge=0.1, remesh_iterations=iterations)


def test_shortcut_min_ratio_is_at_least_one():
    """A geodesic is never shorter than the straight line: a min_ratio below 1 only lets a pair of ratio 0 (no pair
    at all) be bridged; refused, in the config as in the corruption, and 1 is accepted."""
    from shape_toolkit.data.corruptions import apply_corruption, check_corruption_params

    for bad in (0.5, 0.0, -1.0):
        with pytest.raises(ParameterError, match="min_ratio"):
            check_corruption_params("shortcut", {"min_ratio": bad})
    shape, vmap = apply_corruption(icosphere(2), "shortcut", strength=1, min_ratio=1.0)
    assert shape.n_faces > icosphere(2).n_faces and len(vmap) == shape.n_vertices
