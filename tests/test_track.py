"""Sequences and dense trajectories (thesis 7.5.3): the pose-sequence generator's ground truth,
chaining maps, the .npz format, drift against the truth, the ``track`` command (sequential and
on Dask) and its drawings."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest
from helpers import panel_empty_fractions, run_cli

from shape_toolkit.core.shape import Shape
from shape_toolkit.data.synthetic import SEQUENCE_LIMB_LENGTHS, articulated_shape, pose_sequence
from shape_toolkit.errors import ParameterError, ShapeFileError
from shape_toolkit.results.correspondence import Correspondence
from shape_toolkit.results.trajectories import Trajectories, chain_maps, compose_maps, trajectory_drift
from shape_toolkit.viz import save_colored_ply


@pytest.fixture(scope="module")
def seq():
    """4 frames, 642 vertices, feet glued in frame 2, vertex order shuffled in every frame."""
    return pose_sequence(4, subdivisions=3, merge_frames=(2,), permute=True, random_state=3)


@pytest.fixture(scope="module")
def seq_files(seq, tmp_path_factory) -> list[Path]:
    d = tmp_path_factory.mktemp("seq")
    paths = []
    for t, (f, c) in enumerate(zip(seq.frames, seq.colors)):
        paths.append(save_colored_ply(f, d / f"f{t}.ply", c))
    return paths


# ------------------------------------------------------------------------------------------
# the generator's ground truth
# ------------------------------------------------------------------------------------------
def test_sequence_ground_truth_is_exact(seq):
    assert seq.n_frames == 4 and seq.contacts[2] >= 1 and seq.contacts[0] == seq.contacts[1] == 0
    texture = articulated_shape(np.zeros(5), subdivisions=3, limb_length=SEQUENCE_LIMB_LENGTHS).colors
    for t in range(4):
        f, m, clean = seq.frames[t], seq.material[t], seq.clean[t]
        # each vertex of a frame sits exactly at its material point on the clean frame
        np.testing.assert_array_equal(f.vertices, clean.vertices[m])
        np.testing.assert_array_equal(seq.colors[t], texture[m])
        np.testing.assert_array_equal(f.colors, texture[m])  # the frame carries its texture
        assert not np.array_equal(m, np.arange(m.size))  # shuffled: the identity is not the answer
    assert seq.frames[2].n_vertices < seq.clean[2].n_vertices  # welded vertices are gone
    # the weld changes the topology (Euler characteristic of the closed sphere, 2, drops) and joins
    # the two legs (labels 3 and 4): each welded point went onto the other leg
    def euler(shape: Shape) -> int:
        return shape.n_vertices - len(shape.edges) + shape.n_faces

    assert euler(seq.clean[2]) == 2 and euler(seq.frames[2]) < 2
    gone = np.setdiff1d(np.arange(seq.clean[2].n_vertices), seq.material[2])
    kept = seq.material[2]
    d = np.linalg.norm(seq.clean[2].vertices[gone][:, None] - seq.clean[2].vertices[kept][None], axis=2)
    onto = kept[np.argmin(d, axis=1)]
    assert set(seq.labels[gone]) | set(seq.labels[onto]) == {3, 4}
    assert np.all(seq.labels[gone] != seq.labels[onto])


def test_sequence_is_smooth_reproducible_and_checked():
    a = pose_sequence(6, random_state=5)
    b = pose_sequence(6, random_state=5)
    c = pose_sequence(6, random_state=6)
    np.testing.assert_array_equal(a.angles, b.angles)
    assert not np.array_equal(a.angles, c.angles)
    step = np.abs(np.diff(a.angles, axis=0)).max()
    assert step < 0.8 * 2 * 0.8  # no jump across the whole range between two frames
    np.testing.assert_array_equal(a.truth(), np.repeat(np.arange(642)[:, None], 6, axis=1))
    for bad in ({"n_frames": 1}, {"merge_frames": (9,)}, {"max_angle": 3.0}, {"limb_lengths": [1.0, 2.0]},
                {"random_state": "x"}):
        with pytest.raises(ParameterError):
            pose_sequence(**{"n_frames": 4, **bad})


def test_remeshed_sequence_truth_is_within_the_rounding():
    seq = pose_sequence(3, subdivisions=3, remesh=300, merge_frames=(1,), random_state=4)
    assert seq.welded[0].size == 0 and seq.welded[1].size > 0
    for t in range(3):
        f, m = seq.frames[t], seq.material[t]
        assert abs(f.n_vertices - 300) < 60 and f.n_vertices != seq.clean[t].n_vertices
        # each new vertex stands for its nearest material point: within about an edge of it
        gap = np.linalg.norm(f.vertices - seq.clean[t].vertices[m], axis=1)
        assert np.median(gap) < 0.5 * f.mean_edge_length and gap.max() < 2 * f.mean_edge_length
        assert not np.isin(m, seq.welded[t]).any()
    d = seq.drift(seq.truth())
    assert d["mean"][0] == 0.0 and 0 < max(d["mean"]) < 0.02 and min(d["within"]) > 0.97
    with pytest.raises(ParameterError):
        pose_sequence(3, remesh=5)


def test_default_articulated_shape_unchanged_by_per_limb_options():
    a = articulated_shape(random_state=1, subdivisions=3)
    b = articulated_shape(random_state=1, subdivisions=3, limb_length=[1.4] * 5)
    np.testing.assert_array_equal(a.shape.vertices, b.shape.vertices)
    with pytest.raises(ParameterError):
        articulated_shape(subdivisions=3, bend_axes=np.tile([1.0, 0.25, 0.0], (5, 1)))  # along limb 0


# ------------------------------------------------------------------------------------------
# chaining
# ------------------------------------------------------------------------------------------
def test_chaining_identity_maps_gives_identity_trajectories():
    n = 50
    tr = chain_maps([np.arange(n)] * 4, n_vertices=[n] * 5)
    np.testing.assert_array_equal(tr.ids, np.repeat(np.arange(n)[:, None], 5, axis=1))
    assert tr.n_frames == 5 and tr.n_tracks == n and tr.alive.all()


def test_chaining_permutations_composes_them_and_loses_unmatched():
    rng = np.random.default_rng(0)
    sizes = [30, 30, 30, 30]
    perms = [rng.permutation(30) for _ in range(3)]
    tr = chain_maps([Correspondence(p, 30) for p in perms])
    expected = np.arange(30)
    for t, p in enumerate(perms):
        expected = p[expected]
        np.testing.assert_array_equal(tr.ids[:, t + 1], expected)
    np.testing.assert_array_equal(compose_maps(perms, n_vertices=sizes), perms[2][perms[1][perms[0]]])
    # an unmatched vertex loses its trajectory from then on; maps between frames of other sizes
    m0 = np.array([2, -1, 0, 1])
    m1 = np.array([4, 0, 1])
    tr = chain_maps([m0, m1], n_vertices=[4, 3, 5])
    np.testing.assert_array_equal(tr.ids, [[0, 2, 1], [1, -1, -1], [2, 0, 4], [3, 1, 0]])
    with pytest.raises(ParameterError):
        chain_maps([m0, np.arange(4)], n_vertices=[4, 3, 5])  # map 1 has 4 entries for 3 vertices
    with pytest.raises(ParameterError):
        chain_maps([np.array([0, 5])], n_vertices=[2, 3])  # id past the next frame
    with pytest.raises(ParameterError):
        chain_maps([])


def test_npz_round_trip_and_hostile_files(tmp_path):
    tr = chain_maps([np.array([2, -1, 0, 1]), np.array([4, 0, 1])], n_vertices=[4, 3, 5],
                    info={"pipeline": "zoomout", "x": float("nan")})
    p = tr.save(tmp_path / "t.npz")
    back = Trajectories.load(p)
    np.testing.assert_array_equal(back.ids, tr.ids)
    assert back.n_vertices == (4, 3, 5) and back.info == {"pipeline": "zoomout", "x": None}
    # an object array would need pickle: refused, as is anything that is not our format
    np.savez(tmp_path / "obj.npz", ids=np.array([object()], dtype=object), n_vertices=np.array([1]),
             info=np.array("{}"), format=np.array("shape-toolkit-trajectories/1"))
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    (tmp_path / "pickled.npz").write_bytes(pickle.dumps({"ids": [1]}))
    np.savez(tmp_path / "other.npz", a=np.arange(3))
    np.savez(tmp_path / "bad.npz", ids=np.array([[0, 7]]), n_vertices=np.array([1, 2]), info=np.array("{}"),
             format=np.array("shape-toolkit-trajectories/1"))
    for name in ("obj", "junk", "pickled", "other", "bad", "missing"):
        with pytest.raises(ShapeFileError):
            Trajectories.load(tmp_path / f"{name}.npz")


# ------------------------------------------------------------------------------------------
# drift
# ------------------------------------------------------------------------------------------
def test_drift_zero_for_truth_and_grows_for_a_perturbed_map(seq):
    truth = seq.truth()
    d = seq.drift(truth)
    assert d["mean"] == [0.0] * 4 and d["max"] == [0.0] * 4 and d["within"] == [1.0] * 4
    assert d["n_measured"][2] < d["n_measured"][0] == 642  # welded points have no truth in frame 2
    # the true frame maps, chained, give back the truth up to frame 2 (after it, a trajectory that
    # went through a welded point follows the vertex it was welded onto)
    maps = []
    for t in range(3):
        inv = np.full(seq.frames[t].n_vertices, -1)
        inv[truth[:, t]] = truth[:, t + 1]
        maps.append(inv)
    chained = chain_maps(maps, n_vertices=[f.n_vertices for f in seq.frames])
    assert seq.drift(chained)["mean"][:3] == [0.0, 0.0, 0.0]
    # perturb the map 1 -> 2: each vertex goes to the vertex of the next material point
    bad = list(maps)
    bad[1] = np.roll(maps[1], 7)
    dd = seq.drift(chain_maps(bad, n_vertices=[f.n_vertices for f in seq.frames]))
    assert dd["mean"][1] == 0.0 and dd["mean"][2] > 0.05 and dd["within"][2] < 0.5
    assert dd["max"][2] >= dd["median"][2] > 0
    # Euclidean drift is a lower bound of the geodesic one
    de = seq.drift(chain_maps(bad, n_vertices=[f.n_vertices for f in seq.frames]), method="euclidean")
    assert de["mean"][2] <= dd["mean"][2] + 1e-12
    ds = seq.drift(truth, sample=50)
    assert ds["n_measured"][0] == 50


def test_drift_checks_its_inputs():
    s = Shape(np.eye(3), np.array([[0, 1, 2]]))
    ids = np.zeros((3, 1), dtype=np.int64)
    ids[:, 0] = [0, 1, 2]
    for kwargs in ({"method": "manhattan"}, {"radius": -1.0}, {"sample": 0}):
        with pytest.raises(ParameterError):
            trajectory_drift(ids, [s], ids, **kwargs)
    with pytest.raises(ParameterError):
        trajectory_drift(ids, [s, s], ids)
    with pytest.raises(ParameterError):
        trajectory_drift(ids, [s], ids + 5)


# ------------------------------------------------------------------------------------------
# the track command
# ------------------------------------------------------------------------------------------
def test_track_cli_end_to_end(seq, seq_files, tmp_path, capsys):
    out = tmp_path / "t.npz"
    code, stdout, err = run_cli(capsys, "track", *seq_files, "--pipeline", "zoomout", "-o", out,
                             "--png", tmp_path / "t.png", "--gif", tmp_path / "t.gif", "--json")
    assert code == 0, err
    assert err == ""  # silent under --json
    res = json.loads(stdout)
    assert res["n_frames"] == 4 and res["n_tracks"] == 642 and len(res["pairs"]) == 3
    tr = Trajectories.load(out)
    assert tr.info["pipeline"] == "zoomout" and len(tr.info["files"]) == 4
    d = seq.drift(tr)
    assert max(d["mean"]) < 0.05 and min(d["within"]) > 0.9  # the tracking follows the truth
    from PIL import Image

    assert Image.open(tmp_path / "t.png").size[0] > 4 * 200
    gif = Image.open(tmp_path / "t.gif")
    assert gif.n_frames == 4
    # upright and cropped tight as every render (issue 28): each frame panel at most 15% empty; the PDF beside it
    empty = panel_empty_fractions(tmp_path / "t.png")
    assert len(empty) == 4 and max(empty) <= 0.15, empty
    assert (tmp_path / "t.pdf").read_bytes()[:5] == b"%PDF-" and res["outputs"]["pdf"] == str(tmp_path / "t.pdf")


def test_track_through_proxies(seq, seq_files, tmp_path, capsys):
    """``--proxy N``: frames above 1.5 N vertices are matched through proxies of N vertices (``Pipeline.run``'s, as
    ``match`` does), and the maps lifted to every vertex; the default leaves these 642-vertex frames alone."""
    from shape_toolkit.cli.commands.track import track_frames
    from shape_toolkit.io.mesh import load_shape

    out = tmp_path / "p.npz"
    code, _, err = run_cli(capsys, "track", *seq_files[:3], "--pipeline", "zoomout", "--proxy", "400", "-o", out, "-q")
    assert code == 0, err
    tr = Trajectories.load(out)
    frames = [load_shape(p) for p in seq_files[:3]]
    through, _ = track_frames(frames, "zoomout", proxy=400)
    direct, _ = track_frames(frames, "zoomout", proxy=0)
    default, _ = track_frames(frames, "zoomout")
    np.testing.assert_array_equal(tr.ids, through.ids)
    np.testing.assert_array_equal(default.ids, direct.ids)
    assert tr.ids.shape == direct.ids.shape and not np.array_equal(through.ids, direct.ids)
    assert tr.alive[:, -1].mean() > 0.95  # every vertex of the first frame followed to the last
    code, _, err = run_cli(capsys, "track", *seq_files[:2], "--proxy", "50")
    assert code == 2 and err.count("\n") == 1 and "--proxy" in err


def test_track_ply_dir_pullback_colours(seq, seq_files, tmp_path, capsys):
    code, stdout, err = run_cli(capsys, "track", *seq_files[:3], "--pipeline", "zoomout", "-o", tmp_path / "t.npz",
                             "--ply-dir", tmp_path / "plys", "--quiet")
    assert code == 0, err
    files = sorted((tmp_path / "plys").glob("frame_*.ply"))
    assert len(files) == 3
    from shape_toolkit.cli.commands.track import pullback_sequence_colors

    # with the true maps, the pulled-back colour of a vertex is the last frame's colour of the
    # vertex that is the same material point
    truth = seq.truth()[:, :3]
    maps = []
    for t in range(2):
        inv = np.full(seq.frames[t].n_vertices, -1)
        inv[truth[:, t]] = truth[:, t + 1]
        maps.append(Correspondence(inv, seq.frames[t + 1].n_vertices))
    ref = np.random.default_rng(0).uniform(size=(seq.frames[2].n_vertices, 3))
    cols = pullback_sequence_colors(seq.frames[:3], maps, ref)
    np.testing.assert_allclose(cols[0][truth[:, 0]], ref[truth[:, 2]])
    np.testing.assert_allclose(cols[2], ref)


def test_track_bad_input_is_one_line_exit_2(seq_files, tmp_path, capsys):
    pc = tmp_path / "cloud.ply"
    save_colored_ply(Shape(np.random.default_rng(0).normal(size=(642, 3))), pc, np.zeros((642, 3)))
    junk = tmp_path / "junk.ply"
    junk.write_text("not a mesh\n")
    cases = [
        [seq_files[0]],
        [seq_files[0], tmp_path / "missing.ply"],
        [seq_files[0], junk],
        [seq_files[0], pc],
        [*seq_files[:2], "--pipeline", "no-such-pipeline"],
        [*seq_files[:2], "-o", tmp_path / "t.txt"],
        [*seq_files[:2], "--seeds", tmp_path / "a.txt", tmp_path / "b.txt"],
        [*seq_files[:2], "--dask", "nonsense"],
        [*seq_files[:2], "--gif", tmp_path / "a.gif", "--ply-dir", tmp_path / "p"],
    ]
    for args in cases:
        extra = [] if "-o" in args else ["-o", tmp_path / "x.npz"]
        code, out, err = run_cli(capsys, "track", *args, *extra)
        assert code == 2, (args, err)
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err


def test_track_on_dask_gives_the_sequential_trajectories(seq, seq_files, tmp_path, capsys):
    pytest.importorskip("distributed")
    a, b = tmp_path / "seq.npz", tmp_path / "dask.npz"
    assert run_cli(capsys, "track", *seq_files, "--pipeline", "zoomout", "-o", a, "--quiet")[0] == 0
    code, _, err = run_cli(capsys, "track", *seq_files, "--pipeline", "zoomout", "-o", b, "--quiet",
                        "--dask", "local", "--workers", "2")
    assert code == 0, err
    np.testing.assert_array_equal(Trajectories.load(a).ids, Trajectories.load(b).ids)


def test_ply_dir_never_overwrites_the_frames(seq_files, tmp_path, capsys):
    """``--ply-dir`` writes frame_000.ply, ...: frames of those names in that folder are refused, kept (issue 27)."""
    import shutil

    frames = [tmp_path / f"frame_{t:03d}.ply" for t in range(2)]
    for src, dst in zip(seq_files, frames):
        shutil.copy(src, dst)
    before = [f.read_bytes() for f in frames]
    code, _, err = run_cli(capsys, "track", *frames, "--ply-dir", tmp_path, "-o", tmp_path / "t.npz", "--quiet")
    assert code == 2 and "must differ from the input" in err and [f.read_bytes() for f in frames] == before
