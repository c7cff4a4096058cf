"""Issue 30 item 1: the literal ``thesis`` presets and chains beside the improved defaults.

Each preset must exist, validate, run on a small generated shape or pair and declare the spectrum the text
says (Gaussian graph of eq. 3.7, combinatorial ``D - W`` without mass); the defaults must stay what they were;
``t = 0`` is a valid diffusion time; ``plugins show`` prints what a preset changes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from shape_toolkit.api.registry import create_plugin, get_registry
from shape_toolkit.cli import main
from shape_toolkit.data.synthetic import articulated_shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.features import heat
from shape_toolkit.features.scales import check_times
from shape_toolkit.pipeline import PRESETS, load_pipeline
from shape_toolkit.results.labels import Constraints

#: (family, plugin) -> what the thesis preset must set (the text's values)
THESIS = {
    ("dense_matchers", "em-registration"): {"spectrum": "graph", "weighting": "gaussian", "scaling": "none",
                                            "threshold": 0.5, "fill_unmatched": False, "orientation": "none"},
    ("dense_matchers", "eigvec-alignment"): {"spectrum": "graph", "weighting": "gaussian", "scaling": "commute-time",
                                             "alignment": "histogram", "holes": "keep", "side": "none"},
    ("dense_matchers", "seed-growing"): {"ring": 2, "descriptor": {"plugin": "heat-diffusion", "preset": "thesis"}},
    ("sparse_matchers", "replicator"): {"spectrum": "graph", "orientation": "none"},
    ("sparse_matchers", "spectral"): {"spectrum": "graph", "orientation": "none"},
    ("sparse_matchers", "rrwm"): {"spectrum": "graph", "orientation": "none"},
    ("sparse_matchers", "umeyama"): {"spectrum": "graph"},
    ("descriptors", "heat-diffusion"): {"times": [0.0, 20.0, 40.0, 80.0, 100.0], "K": 25},
    ("descriptors", "heat-distance"): {"K": 25, "n_times": 5, "normalization": "unit-sphere"},
    ("segmenters", "csc"): {"graph": "vertex", "weighting": "gaussian", "output_dim": "k", "cannot_mode": "volume",
                            "reweight": "set", "kmeans_init": "k-means++", "k_mismatch": "kmeans"},
    ("segmenters", "eigvec-gmm"): {"n_eigenvectors": 10, "laplacian": "combinatorial", "weighting": "gaussian",
                                   "min_component_fraction": 1.0, "k_rule": "bic-minimum"},
}


@pytest.fixture(scope="module")
def pair():
    return articulated_shape(random_state=1, subdivisions=3), articulated_shape(random_state=2, subdivisions=3)


def _is_gaussian_d_minus_w(spec) -> bool:
    return spec.weighting == "gaussian" and spec.laplacian == "combinatorial" and spec.use_mass is not True


@pytest.mark.parametrize("key", sorted(THESIS))
def test_thesis_preset_exists_validates_and_sets_the_texts_values(key):
    family, name = key
    plugin = create_plugin(family, name, "thesis")
    plugin._validate_params()
    params = plugin.get_params(deep=False)
    for p, v in THESIS[key].items():
        assert params[p] == v, (name, p)
    assert get_registry().get(family, name).presets["thesis"] != {}


@pytest.mark.parametrize("key", sorted(THESIS))
def test_thesis_preset_declares_the_gaussian_graph_without_mass(key, pair):
    family, name = key
    plugin = create_plugin(family, name, "thesis", **({"n_segments": 6} if family == "segmenters" else {}))
    specs = plugin.spectrum_specs()  # its own and its nested plugins' (seed growing: the descriptor's)
    assert specs and all(_is_gaussian_d_minus_w(s) for s in specs), (name, specs)
    assert not any(s.compute(pair[0].shape).generalized for s in specs)  # no mass matrix in the operator


def test_defaults_are_unchanged():
    em = create_plugin("dense_matchers", "em-registration")
    assert (em.spectrum, em.scaling, em.orientation, em.fill_unmatched) == ("lbo", "none", "preserving", True)
    assert em.spectrum_spec().weighting == "cotangent" and em.spectrum_spec().use_mass is True
    for name in ("replicator", "spectral", "rrwm", "umeyama"):
        spec = create_plugin("sparse_matchers", name).spectrum_spec()
        assert spec.weighting == "cotangent" and spec.use_mass is True, name
    csc = create_plugin("segmenters", "csc", n_segments=6)
    assert (csc.graph, csc.reweight, csc.output_dim, csc.kmeans_init) == ("auto", "monotone", None, "constraints")
    assert create_plugin("segmenters", "eigvec-gmm").k_rule == "knee"
    # the improved chains keep their extensions; topo-robust keeps the commute-time embedding under its new name
    assert "orient" in PRESETS["sharma2012"] and PRESETS["sharma2012"]["refine"]["params"] == {"polish_k": 100}
    refine = PRESETS["topo-robust"]["refine"]
    assert refine["preset"] == "topo-robust"
    topo = create_plugin("dense_matchers", "em-registration", "topo-robust")
    assert (topo.spectrum, topo.scaling, topo.dimension, topo.k) == ("graph", "commute-time", "scree", 10)
    assert PRESETS["ovsjanikov2010"]["dense"]["plugin"] == "greedy-descriptor"


def test_em_thesis_is_algorithm_7_on_the_plain_eigenvectors(pair):
    A, B = pair[0].shape, pair[1].shape
    em = create_plugin("dense_matchers", "em-registration", "thesis")
    spec = em.spectrum_spec()
    assert spec.k == 11 and spec.use_mass is False  # k + 1, no orientation repair's 30 dimensions
    bs, bt = em._bases(A, B, None, None)
    np.testing.assert_allclose(em._embed(bs, 4), bs.evecs[:, 1:5])  # eq. 6.24 at t = 0: no scaling
    seeds = np.column_stack([np.arange(0, A.n_vertices, 7)] * 2)  # same connectivity: identity seeds
    c = em.match(A, B, seeds=seeds)
    assert 3 <= c.info["embedding_dim"] <= 10
    matched = c.target_of >= 0
    assert 0 < matched.sum() < A.n_vertices or np.all(c.confidence[matched] > 0.5)
    np.testing.assert_array_equal(matched, c.confidence > 0.5)  # Algorithm 7, step 4: only posterior > 0.5


def test_sparse_thesis_presets_match_keypoints_on_the_gaussian_graph(pair):
    A, B = pair[0].shape, pair[1].shape
    det = create_plugin("keypoints", "adf-maxima", "thesis-dense")
    ka, kb = det.detect(A), det.detect(B)
    for name in ("replicator", "spectral", "rrwm", "umeyama"):
        m = create_plugin("sparse_matchers", name, "thesis")
        pairs = m.match(A, B, ka, kb)
        assert pairs.ndim == 2 and pairs.shape[1] == 2 and len(pairs) >= 1, name
        assert np.isin(pairs[:, 0], ka).all() and np.isin(pairs[:, 1], kb).all()


def test_heat_and_seed_growing_thesis_presets_use_t_zero(pair):
    A, B = pair[0].shape, pair[1].shape
    kp = np.array([0, 50, 100, 200])
    d = create_plugin("descriptors", "heat-diffusion", "thesis")
    D = d.compute(A, keypoints=kp)
    assert D.shape == (A.n_vertices, (len(kp) + 1) * 5) and np.all(np.isfinite(D))
    assert list(d.descriptor_times(A)) == [0.0, 20.0, 40.0, 80.0, 100.0]
    sg = create_plugin("dense_matchers", "seed-growing", "thesis")
    c = sg.match(A, B, seeds=np.column_stack([kp, kp]))
    assert c.info["n_times"] == 5 and np.all(c.target_of[kp] == kp)


@pytest.mark.filterwarnings("ignore:.*must-links:UserWarning")  # the literal CSC does not enforce clicks
def test_csc_thesis_is_algorithm_4_on_the_vertex_graph(pair):
    art = pair[0]
    shape, labels = art.shape, art.labels
    must = [[int(np.flatnonzero(labels == s)[0]), int(np.flatnonzero(labels == s)[-1])] for s in range(6)]
    cannot = [[must[0][0], must[s][0]] for s in range(1, 6)]
    csc = create_plugin("segmenters", "csc", "thesis", n_segments=6)
    seg = csc.segment(shape, constraints=Constraints(np.array(must), np.array(cannot)))
    assert csc.component_graph(shape) == "vertex" and seg.info.get("per") != "face"
    assert len(csc.modified_eigenvalues_) == 6  # the k first non-null eigenpairs of L_hat (step 3)
    assert csc.n_seed_groups_ == 6 and seg.labels.max() + 1 == 6
    # reweight "set": every edge of a cannot-link volume is epsilon, even one lighter than epsilon before
    W_hat = csc.modified_weights(shape, Constraints(np.zeros((0, 2), int), np.array(cannot[:1])))
    mono = create_plugin("segmenters", "csc", "thesis", n_segments=6, reweight="monotone", epsilon=10.0)
    W_mono = mono.modified_weights(shape, Constraints(np.zeros((0, 2), int), np.array(cannot[:1])))
    setw = create_plugin("segmenters", "csc", "thesis", n_segments=6, epsilon=10.0)
    W_set = setw.modified_weights(shape, Constraints(np.zeros((0, 2), int), np.array(cannot[:1])))
    assert W_hat.nnz == W_set.nnz and np.isclose(W_set.max(), 10.0) and W_mono.max() <= 1.0


def test_eigvec_gmm_thesis_keeps_the_bic_minimum(pair):
    seg = create_plugin("segmenters", "eigvec-gmm", "thesis", max_segments=8)
    seg.segment(pair[0].shape)
    best = min(seg.bic_curve_, key=seg.bic_curve_.get)
    assert seg.n_segments_rule_ == "bic-minimum" and seg.n_segments_ <= best


@pytest.mark.parametrize("name", ["sharma2012-thesis", "ovsjanikov2010-thesis"])
def test_literal_chains_run_with_the_thesis_stages(name, pair):
    spec = PRESETS[name]
    assert "orient" not in spec
    assert all(st.get("preset", "").startswith("thesis") for k, st in spec.items() if k != "description")
    assert spec["dense"]["plugin"] == "seed-growing" and spec["descriptors"]["plugin"] == "heat-diffusion"
    if name == "sharma2012-thesis":
        assert spec["refine"] == {"plugin": "em-registration", "preset": "thesis"}  # no k_final, no polish_k
    else:
        assert "refine" not in spec
    pipe = load_pipeline(name)
    for s in pipe.spectrum_specs():
        assert s.weighting == "gaussian" and s.use_mass is not True  # no cotangent spectrum anywhere
    c = pipe.run(pair[0].shape, pair[1].shape)
    assert c.target_of.shape == (pair[0].shape.n_vertices,) and c.n_matched > 0
    assert c.info["n_seeds"] >= 3


def test_mateus2008_thesis_runs_em_on_the_plain_graph_eigenvectors(pair):
    pipe = load_pipeline("mateus2008-thesis")
    m = pipe.plugins()["dense"]
    assert (m.spectrum, m.weighting, m.scaling, m.fill_unmatched) == ("graph", "gaussian", "none", False)
    assert (m.alignment, m.holes, m.side) == ("histogram", "keep", "none")  # Mateus 2008's alignment, not the search
    assert all(_is_gaussian_d_minus_w(s) for s in pipe.spectrum_specs())
    improved = load_pipeline("mateus2008").plugins()["dense"]
    assert (improved.alignment, improved.holes, improved.side) == ("histogram", "keep", "none")
    c = pipe.run(pair[0].shape, pair[1].shape)
    np.testing.assert_array_equal(c.target_of >= 0, c.confidence > 0.5)


# -- t = 0 -------------------------------------------------------------------------------------
def test_t_zero_is_accepted_and_is_the_identity_kernel(pair):
    assert check_times(0.0).tolist() == [0.0] and check_times([0, 20]).tolist() == [0.0, 20.0]
    for bad in (-1.0, [0.0, -1e-3], np.nan):
        with pytest.raises(ParameterError):
            check_times(bad)
    shape = articulated_shape(subdivisions=1).shape  # small: the full spectrum
    n = shape.n_vertices
    spec = create_plugin("descriptors", "heat-diffusion", "thesis").spectrum_spec()
    S = type(spec)(n, spec.weighting, spec.laplacian, spec.use_mass).compute(shape)
    H0 = heat.heat_kernel(S, 0.0, dense_ok=True, deflate=False)[0]
    np.testing.assert_allclose(H0, np.eye(n), atol=1e-8)  # exp(-0 L) = I: a delta at every vertex
    H0d = heat.heat_kernel(S, 0.0, dense_ok=True)[0]
    np.testing.assert_allclose(H0d, np.eye(n) - 1.0 / n, atol=1e-8)  # deflated (eq. 6.20): minus u_1 u_1^T
    with np.errstate(all="raise"):  # nothing divides by t
        for norm in heat.NORMALIZATIONS:
            assert np.all(np.isfinite(heat.heat_distances(S, [0.0, 1.0], [0, 1], normalization=norm)))
        assert np.all(np.isfinite(heat.heat_kernel_signature(S, 0.0, scale="trace")))
        heat.unit_sphere_embedding(S, 0.0)
        heat.trace_scaled_embedding(S, 0.0)
    create_plugin("descriptors", "hks", times=[0.0, 1.0])._validate_params()


# -- plugins show ----------------------------------------------------------------------------------
def test_plugins_show_prints_the_differences(capsys):
    assert main(["plugins", "show", "em-registration"]) == 0
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if x.strip().startswith("default -> thesis:"))
    assert "spectrum 'lbo' -> 'graph'" in line and "fill_unmatched True -> False" in line
    assert "orientation 'preserving' -> 'none'" in line and "threshold" not in line  # 0.5 is the default
    assert main(["plugins", "show", "csc"]) == 0
    assert "graph 'auto' -> 'vertex'" in capsys.readouterr().out
    assert main(["plugins", "show", "sharma2012-thesis"]) == 0
    out = capsys.readouterr().out
    assert "stage refine: {'plugin': 'em-registration', 'preset': 'thesis'}" in out
    assert "sharma2012 -> sharma2012-thesis:" in out
    assert "stage orient: {'plugin': 'orientation-repair'} -> (none)" in out
    assert main(["plugins", "show", "ovsjanikov2010-thesis", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["compared_with"] == "ovsjanikov2010"
    assert info["stage_differences"]["dense"][0] == {"plugin": "greedy-descriptor"}
