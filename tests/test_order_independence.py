"""Vertex-order independence of every matcher (issue 11) and every segmenter (issue 13): renumbering
the vertices of the shapes gives the renumbered result. (tests/test_segmentation.py checks the
vertex-based segmenters again on the articulated shape.)

The shapes are asymmetric (four protrusions of different heights), so every spectrum is simple and
the result is defined without ties; answers are compared as 3D points (a renumbered vertex is the
same point), allowing a few vertices to move to a neighbour where a score ties numerically.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers import BUMP_DIRS, bumpy_sphere

import shape_toolkit as st
from shape_toolkit.core.shape import Shape


def _bumpy(seed: int, subdivisions: int = 3) -> Shape:
    return bumpy_sphere(subdivisions, seed, power=8, noise=0.003, name=f"bumpy{seed}")[0]


def _permuted(shape: Shape, seed: int) -> tuple[Shape, np.ndarray, np.ndarray]:
    """A renumbered copy: ``perm[new] = old``, ``inv[old] = new``."""
    perm = np.random.default_rng(seed).permutation(shape.n_vertices)
    inv = np.argsort(perm)
    return Shape(shape.vertices[perm], inv[shape.faces], shape.name + "-perm"), perm, inv


def _pair(subdivisions: int):
    a, b = _bumpy(0, subdivisions), _bumpy(1, subdivisions)
    pa, perm_a, inv_a = _permuted(a, 5)
    pb, perm_b, inv_b = _permuted(b, 6)
    # both shapes are the same icosphere (noise apart), so vertex i matches vertex i: seeds on a sample
    ids = np.arange(0, a.n_vertices, 25)
    seeds = np.column_stack([ids, ids]).astype(np.int64)
    return a, b, pa, pb, perm_a, inv_a, perm_b, inv_b, seeds


@pytest.fixture(scope="module")
def pair():
    """The two bumpy shapes (642 vertices), renumbered copies, seeds."""
    return _pair(3)


@pytest.fixture(scope="module")
def small_pair():
    """The same with 162 vertices: for eigvec-alignment, whose search (21 EM registrations of each
    pose) is about 5 s a match at 642 vertices."""
    return _pair(2)


def _close(p: np.ndarray, q: np.ndarray, scale: float, frac: float = 0.97) -> float:
    """Fraction of rows of ``p`` within ``0.05 * scale`` of the same row of ``q``."""
    ok = np.linalg.norm(p - q, axis=1) <= 0.05 * scale
    assert ok.mean() >= frac, f"only {ok.mean():.3f} of the answers agree after renumbering"
    return float(ok.mean())


def _dense_names():
    return st.available_plugins()["dense_matchers"]


def _sparse_names():
    return st.available_plugins()["sparse_matchers"]


# best-of runs every other dense matcher, each checked on its own: slow
@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n == "best-of" else n
                                  for n in _dense_names()])
def test_dense_matchers_are_vertex_order_independent(pair, small_pair, name):
    a, b, pa, pb, perm_a, inv_a, perm_b, inv_b, seeds = small_pair if name == "eigvec-alignment" else pair
    plugin = st.create_plugin("dense_matchers", name)
    kwargs = {}
    if name not in ("fmap-zoomout", "eigvec-alignment"):
        kwargs["seeds"] = seeds
    if name == "photometric":  # pragma: no cover - a sparse-stage plugin under another family
        pytest.skip("needs colours")
    out = plugin.match(a, b, **kwargs)
    pkw = dict(kwargs)
    if "seeds" in pkw:
        pkw["seeds"] = np.column_stack([inv_a[seeds[:, 0]], inv_b[seeds[:, 1]]])
    out_p = st.create_plugin("dense_matchers", name).match(pa, pb, **pkw)
    # source vertex i of a is vertex inv_a[i] of pa; its image in pb is a point of b
    t, tp = out.target_of, out_p.target_of[inv_a]
    both = (t >= 0) & (tp >= 0)
    assert np.mean((t >= 0) == (tp >= 0)) >= 0.97
    diag = float(np.linalg.norm(np.ptp(b.vertices, axis=0)))
    _close(b.vertices[t[both]], pb.vertices[tp[both]], diag)


@pytest.mark.parametrize("name", _sparse_names())
def test_sparse_matchers_are_vertex_order_independent(pair, name):
    a, b, pa, pb, perm_a, inv_a, perm_b, inv_b, _ = pair
    # small absolute t: many maxima on 642 vertices
    det = st.create_plugin("keypoints", "adf-maxima", t=2.0, K=30, time_scale="absolute")
    kp_a, kp_b = det.detect(a), det.detect(b)
    assert len(kp_a) >= 6 and len(kp_b) >= 6
    m = st.create_plugin("sparse_matchers", name).match(a, b, kp_a, kp_b)
    mp = st.create_plugin("sparse_matchers", name).match(pa, pb, inv_a[kp_a], inv_b[kp_b])
    got = {(int(s), int(t)) for s, t in m}
    back = {(int(perm_a[s]), int(perm_b[t])) for s, t in mp}
    assert len(got) > 0
    agree = len(got & back) / max(len(got), len(back))
    assert agree >= 0.9, (sorted(got), sorted(back))


def _segmenter_names():
    from tests.test_segmentation_parts import ensure_registered

    ensure_registered()
    return st.available_plugins()["segmenters"]


def _tip_constraints(shape: Shape):
    """Clicks a user would give on the bumpy shape: a must-link along each protrusion (its two most
    extreme vertices), one on the body (opposite the first protrusion), a cannot-link between the
    first protrusion and the body."""
    from shape_toolkit.results.labels import Constraints

    v = shape.vertices
    d = BUMP_DIRS / np.linalg.norm(BUMP_DIRS, axis=1, keepdims=True)
    must = [np.argsort(-(v @ di))[[0, 3]] for di in d]
    body = np.argsort(v @ (d[0] + d[1] + d[2] + d[3]))[[0, 3]]
    must.append(body)
    return Constraints(np.array(must), np.array([[must[0][0], body[0]]]))


@pytest.mark.parametrize("name, extra", [(n, {}) for n in _segmenter_names()] + [("csc", {"graph": "dual"})])
def test_segmenters_are_vertex_order_independent(pair, name, extra):
    """Same labels up to renaming (per face when the segmenter has face labels, else per vertex)."""
    from sklearn.metrics import adjusted_rand_score

    from shape_toolkit.results.labels import Constraints

    a, _, pa, _, perm_a, inv_a, _, _, _ = pair
    cons = _tip_constraints(a)
    cons_p = Constraints(inv_a[cons.must_link], inv_a[cons.cannot_link])

    def run(shape, c):
        params = {"n_segments": 5} if "n_segments" in st.create_plugin("segmenters", name).get_params() else {}
        seg = st.create_plugin("segmenters", name, **params, **extra)
        res = seg.segment(shape, constraints=c if seg.accepts_constraints() else None)  # unsupervised: refused
        return res.labels, res.face_labels if res.info["per"] == "face" else None

    lab, fl = run(a, cons)
    lab_p, fl_p = run(pa, cons_p)
    assert len(np.unique(lab)) >= 2
    # vertex i of a is vertex inv_a[i] of pa
    assert adjusted_rand_score(lab, lab_p[inv_a]) > 0.99, name
    if fl is not None:  # faces keep their order when the vertices are renumbered
        assert adjusted_rand_score(fl, fl_p) > 0.99, name
