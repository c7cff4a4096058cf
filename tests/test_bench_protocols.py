"""Matching protocols of the benchmark runner: published maps as a peer (``peer = "maps"``), the
symmetry-aware error and flips, and corruptions scored on the clean shape through the back-map."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from shape_toolkit.bench.config import ConfigError, parse_config
from shape_toolkit.bench.peers import read_map_file
from shape_toolkit.bench.runner import read_rows, run_benchmark
from shape_toolkit.core.shape import Shape
from shape_toolkit.data.generate import icosphere
from shape_toolkit.errors import ShapeFileError
from shape_toolkit.io.mesh import save_shape


def _edge_distances(shape: Shape, sources: np.ndarray) -> np.ndarray:
    """Dijkstra distances along the mesh edges from ``sources``: ``(len(sources), n)``."""
    e, n = shape.edges, shape.n_vertices
    G = sp.coo_matrix((shape.edge_lengths, (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    return dijkstra(G, directed=False, indices=sources)


def _mirror(shape: Shape) -> np.ndarray:
    """The vertex of ``shape`` at each vertex's mirror image through the plane x = 0."""
    v = np.asarray(shape.vertices)
    d, j = cKDTree(v).query(v * np.array([-1.0, 1.0, 1.0]))
    assert d.max() < 1e-9  # the icosphere is symmetric under x -> -x
    return j.astype(np.int64)


def _pair_folder(root: Path, shape: Shape, maps: dict[str, np.ndarray], sym: np.ndarray | None = None) -> Path:
    """A TOSCA-style folder with the pair (A, B) of ``shape`` to itself, the identity as ground truth,
    ``sym`` as B's symmetric ground truth and each of ``maps`` as ``maps/NAME/A_B.map`` (0-based ids,
    written 1-based; -1 written as 0, no vertex)."""
    (root / "corres").mkdir(parents=True)
    for name in ("A", "B"):
        save_shape(shape, root / f"{name}.off")
    ids = np.arange(1, shape.n_vertices + 1)
    for name in ("A", "B"):
        np.savetxt(root / "corres" / f"{name}.vts", ids, fmt="%d")
    if sym is not None:
        np.savetxt(root / "corres" / "B.sym.vts", sym + 1, fmt="%d")
    (root / "pairs.txt").write_text("A\tB\n")
    for name, t in maps.items():
        (root / "maps" / name).mkdir(parents=True)
        np.savetxt(root / "maps" / name / "A_B.map", np.where(t >= 0, t + 1, 0), fmt="%d")
    return root


def _config(folder: Path, methods: str, options: str = 'geodesic_method = "dijkstra", truth_sample = 100000',
            corruptions: str = "", task_corruptions: str = "") -> dict:
    import tomllib

    text = f"""
[[datasets]]
name = "pair"
kind = "tosca"
path = "{folder}"
{corruptions}
[[tasks]]
task = "matching"
metrics = ["geodesic_error"]
options = {{ {options} }}
{task_corruptions}
{methods}
"""
    return tomllib.loads(text)


def _maps(*names: str) -> str:
    return "".join(f'[[tasks.methods]]\npeer = "maps"\npath = "maps/{n}"\nlabel = "{n}"\n' for n in names)


def _rows(cfg: dict, run: Path) -> dict[str, dict]:
    run_benchmark(parse_config(cfg), run, progress=False)
    rows = {r["method_label"]: r for r in read_rows(run)}
    for r in rows.values():
        assert r["status"] == "ok", r.get("error")
    return rows


def test_maps_peer_reproduces_a_hand_computation(tmp_path):
    shape = icosphere(2)
    n = shape.n_vertices
    rng = np.random.default_rng(0)
    t = rng.permutation(n)
    t[7] = -1  # a published map's 0: no vertex for source vertex 7
    folder = _pair_folder(tmp_path / "pair", shape, {"perm": t})
    row = _rows(_config(folder, _maps("perm")), tmp_path / "run")["perm"]
    # by hand: identity ground truth, Dijkstra along the edges of B, over sqrt(area(B))
    ok = np.flatnonzero(t >= 0)
    d = _edge_distances(shape, ok)[np.arange(ok.size), t[ok]] / np.sqrt(shape.area)
    m = row["metrics"]
    assert m["mean_geodesic_error"] == pytest.approx(d.mean(), rel=1e-5)
    assert m["matched_fraction"] == pytest.approx((n - 1) / n)
    assert m["mean_geodesic_error_sym"] is None and m["flipped"] is None  # no symmetric file: n/a, not 0
    assert row["method_label"] == "perm" and row["family"] == "peers"
    assert row["seconds"] is None and row["cpu_seconds"] is None  # a published method's cost is not known here


def test_markdown_report_names_the_command_and_says_na(tmp_path):
    from shape_toolkit.bench.report import write_report

    shape = icosphere(1)
    folder = _pair_folder(tmp_path / "pair", shape, {"ident": np.arange(shape.n_vertices)})
    _rows(_config(folder, _maps("ident")), tmp_path / "run")
    md = tmp_path / "x.md"
    res = write_report(tmp_path / "run", renders=0, markdown=md, command="shape-toolkit bench run c.toml --report")
    text = md.read_text()
    assert res["markdown"] == md and text.splitlines()[2:5] == [
        "Regenerate with:", "", "    shape-toolkit bench run c.toml --report"]
    assert "| pair | ident | none |" in text and "no symmetric ground truth" in text


def test_items_select_dataset_items_by_name(tmp_path):
    folder = _pair_folder(tmp_path / "pair", icosphere(1), {})
    cfg = _config(folder, '[[tasks.methods]]\npipeline = "zoomout"\n')
    cfg["datasets"][0]["items"] = ["A-B"]
    assert [r.name for r in parse_config(cfg).datasets["pair"].refs] == ["A-B"]
    cfg["datasets"][0]["items"] = ["A-B", "B-A"]
    with pytest.raises(ConfigError) as e:
        parse_config(cfg)
    assert e.value.key == "datasets[0].items[1]" and "no item 'B-A'" in str(e.value)


def test_flips_are_counted_on_a_mirrored_map(tmp_path):
    shape = icosphere(2)
    mirror = _mirror(shape)
    ident = np.arange(shape.n_vertices)
    folder = _pair_folder(tmp_path / "pair", shape, {"mirror": mirror, "ident": ident}, sym=mirror)
    rows = _rows(_config(folder, _maps("mirror", "ident")), tmp_path / "run")
    flipped, right = rows["mirror"]["metrics"], rows["ident"]["metrics"]
    assert flipped["flipped"] == 1 and right["flipped"] == 0
    assert flipped["mean_geodesic_error_sym"] == 0.0 and flipped["mean_geodesic_error"] > 0.2
    assert right["mean_geodesic_error"] == right["mean_geodesic_error_sym"] == 0.0


@pytest.mark.parametrize("text, problem", [
    ("1\n2\n", "has 2 vertex ids, expected one per source vertex"),
    ("x", "must be integers"),
    ("1.5", "must be integers"),
    ("-1", "outside 1.."),
    ("99999", "outside 1.."),
])
def test_a_bad_map_file_is_refused_naming_it(tmp_path, text, problem):
    path = tmp_path / "A_B.map"
    lines = text if "\n" in text else "\n".join(["1"] * 9 + [text]) + "\n"
    path.write_text(lines)
    with pytest.raises(ShapeFileError) as e:
        read_map_file(path, 10, 10)
    assert problem in str(e.value) and "A_B.map" in str(e.value)


def test_a_bad_map_file_fails_its_row_naming_it_and_a_missing_one_the_config(tmp_path):
    shape = icosphere(1)
    folder = _pair_folder(tmp_path / "pair", shape, {"short": np.arange(5)})
    run_benchmark(parse_config(_config(folder, _maps("short"))), tmp_path / "run", progress=False)
    (row,) = read_rows(tmp_path / "run")
    assert row["status"] == "failed" and "A_B.map" in row["error"] and "expected one per source vertex" in row["error"]
    with pytest.raises(ConfigError) as e:
        parse_config(_config(folder, _maps("nothing")))
    assert e.value.key == "tasks[0].methods[0].path" and "A_B.map" in str(e.value)
    for bad, key in (('peer = "maps"\n', "path"), ('peer = "maps"\npath = "../x"\n', "path"),
                     ('peer = "pyfm"\npath = "maps/short"\n', "path")):
        with pytest.raises(ConfigError) as e:
            parse_config(_config(folder, "[[tasks.methods]]\n" + bad))
        assert e.value.key == f"tasks[0].methods[0].{key}"
    corr = '[[corruptions]]\nname = "noise"\nkind = "gaussian-noise"\n'
    with pytest.raises(ConfigError, match="clean pairs"):
        parse_config(_config(folder, _maps("short"), corruptions=corr, task_corruptions='corruptions = ["noise"]'))


def _shuffle_and_drop(shape: Shape, *, strength: float = 0.1, random_state: int = 0):
    """A test corruption: drop a fraction ``strength`` of the vertices (and their faces), then
    permute the rest; the back-map names each new vertex's original id."""
    rng = np.random.default_rng(random_state)
    keep = np.sort(rng.choice(shape.n_vertices, int(round((1 - strength) * shape.n_vertices)), replace=False))
    sub, ids = shape.submesh(keep)
    perm = rng.permutation(sub.n_vertices)
    inv = np.empty_like(perm)
    inv[perm] = np.arange(perm.size)
    return Shape(sub.vertices[perm], inv[sub.faces], shape.name), np.asarray(ids)[perm].astype(np.int64)


def test_clean_scoring_goes_through_the_back_map(tmp_path, monkeypatch):
    from shape_toolkit.bench import peers
    from shape_toolkit.data import corruptions

    def by_position(source, target):  # the true map onto the corrupted target: -1 where a vertex is gone
        d, j = cKDTree(target.vertices).query(source.vertices)
        return np.where(d < 1e-12, j, -1)

    monkeypatch.setitem(corruptions.CORRUPTIONS, "shuffle", _shuffle_and_drop)
    monkeypatch.setitem(peers.PEERS, "exact", (by_position, "numpy", "numpy"))
    shape = icosphere(2)
    folder = _pair_folder(tmp_path / "pair", shape, {})
    corr = '[[corruptions]]\nname = "shuffle"\nkind = "shuffle"\nparams = { strength = [0.1, 0.3] }\n'
    cfg = _config(folder, '[[tasks.methods]]\npeer = "exact"\n',
                  options='geodesic_method = "dijkstra", truth_sample = 100000, score_on = "clean"',
                  corruptions=corr, task_corruptions='corruptions = ["shuffle"]')
    run_benchmark(parse_config(cfg), tmp_path / "run", progress=False)
    rows = read_rows(tmp_path / "run")
    assert len(rows) == 2
    for r in rows:
        m = r["metrics"]
        assert r["status"] == "ok", r.get("error")
        assert m["mean_geodesic_error"] == 0.0  # every surviving vertex lands on its clean partner
        assert m["matched_fraction"] == pytest.approx(1 - r["strength"], abs=0.01)  # scored on every clean vertex
        assert r["n_vertices"] < shape.n_vertices  # the corrupted target was matched


def test_clean_scoring_and_self_targets_are_validated(tmp_path):
    folder = _pair_folder(tmp_path / "pair", icosphere(1), {})
    for opt in ('score_on = "nowhere"', 'target = "other"'):
        with pytest.raises(ConfigError) as e:
            parse_config(_config(folder, '[[tasks.methods]]\npipeline = "zoomout"\n', options=opt))
        assert e.value.key == f"tasks[0].options.{opt.split()[0]}"


@pytest.mark.slow  # about 5-10 s: 900 Dijkstra rows twice on a 5,000-vertex mesh
def test_maps_peer_on_a_real_noniso_pair(shared_data, tmp_path):
    from shape_toolkit.data.datasets import read_vts
    from shape_toolkit.io.mesh import load_shape

    root = shared_data / "tosca_noniso"
    if not (root / "maps" / "BCICP").is_dir():
        pytest.skip("tosca_noniso with its published maps is not in the shared data")
    cfg = _config(root, _maps("BCICP"))
    cfg["datasets"][0]["limit"] = 1
    row = _rows(cfg, tmp_path / "run")["BCICP"]
    a, b = "8_gorilla_04", "8_man_05"  # the first pair of pairs.txt
    assert row["item"] == f"{a}-{b}"
    B = load_shape(root / f"{b}.off")
    ta, tb = read_vts(root / "corres" / f"{a}.vts"), read_vts(root / "corres" / f"{b}.vts")
    t = np.loadtxt(root / "maps" / "BCICP" / f"{a}_{b}.map", dtype=np.int64) - 1
    d = _edge_distances(B, tb)[np.arange(tb.size), t[ta]] / np.sqrt(B.area)
    assert row["metrics"]["mean_geodesic_error"] == pytest.approx(d.mean(), rel=1e-5)
    assert row["metrics"]["mean_geodesic_error"] == pytest.approx(0.1018, abs=1e-4)  # matching_field.py's row (former)
    assert row["metrics"]["flipped"] is None


def test_self_target_matches_each_shape_to_a_copy_of_itself(tmp_path, monkeypatch):
    from shape_toolkit.bench import peers

    def by_position(source, target):
        d, j = cKDTree(target.vertices).query(source.vertices)
        return np.where(d < 1e-12, j, -1)

    monkeypatch.setitem(peers.PEERS, "exact", (by_position, "numpy", "numpy"))
    shape = icosphere(2)
    folder = _pair_folder(tmp_path / "pair", shape, {})
    save_shape(shape.with_vertices(2.0 * np.asarray(shape.vertices)), folder / "B.off")  # B is not A
    rows = {}
    for target in ("pair", "self"):
        cfg = _config(folder, '[[tasks.methods]]\npeer = "exact"\n',
                      options=f'geodesic_method = "dijkstra", truth_sample = 100000, target = "{target}"')
        run_benchmark(parse_config(cfg), tmp_path / f"run-{target}", progress=False)
        (rows[target],) = read_rows(tmp_path / f"run-{target}")
    assert rows["self"]["metrics"]["mean_geodesic_error"] == 0.0
    assert rows["self"]["metrics"]["matched_fraction"] == 1.0
    assert rows["pair"]["metrics"]["matched_fraction"] < 0.1  # the scaled B: no vertex where A's are


def test_even_truth_points_are_evenly_spaced_in_the_ground_truth():
    from shape_toolkit.bench.tasks import prepare
    from shape_toolkit.data.datasets import DatasetItem

    shape = icosphere(1)
    n = shape.n_vertices
    ident = np.stack([np.arange(n), np.arange(n)], axis=1)
    item = DatasetItem("A-B", shape, target=shape, correspondence=ident)
    kw = dict(pairwise=True, random_state=0, truth_sample=5, geodesic_method="dijkstra")
    even = prepare(item, "none", {}, truth_points="even", **kw)
    assert even.truth_eval[:, 0].tolist() == np.linspace(0, n - 1, 5).round().astype(int).tolist()
    assert len(prepare(item, "none", {}, **kw).truth_eval) == 5  # a seeded random draw by default
    step = n // 5  # the fixed stride of a script that took every step-th point from the first
    stride = prepare(item, "none", {}, truth_points="stride", **kw)
    assert stride.truth_eval[:, 0].tolist() == [0, step, 2 * step, 3 * step, 4 * step]
    assert stride.truth_eval[:, 0].tolist() != even.truth_eval[:, 0].tolist()


def test_corrupt_both_subdivides_source_and_target_and_keeps_the_truth(tmp_path):
    """``corrupt = "both"``: a size grid of pairs. Both shapes are split 2 x 2 (original ids kept), the
    ground truth still holds (original vertices keep their ids), and the default changes the
    target only; ``target = "self"`` with it is refused, naming the key."""
    from shape_toolkit.bench.tasks import prepare
    from shape_toolkit.data.datasets import load_item, open_dataset

    shape = icosphere(1)
    folder = _pair_folder(tmp_path / "pair", shape, {})
    (ref,) = list(open_dataset("tosca", folder))
    item = load_item(ref)
    both = prepare(item, "subdivide", {"splits": 2}, pairwise=True, random_state=0, corrupt="both",
                   geodesic_method="dijkstra", truth_sample=100000)
    one = prepare(item, "subdivide", {"splits": 2}, pairwise=True, random_state=0)
    n2 = both.target.n_vertices
    assert n2 > shape.n_vertices and both.source.n_vertices == n2
    assert one.source.n_vertices == shape.n_vertices and one.target.n_vertices == n2
    np.testing.assert_array_equal(both.truth, np.stack([np.arange(shape.n_vertices)] * 2, axis=1))
    methods = '[[tasks.methods]]\npipeline = "zoomout"\n'
    cfg = _config(folder, methods, options='geodesic_method = "dijkstra", corrupt = "both"',
                  corruptions='[[corruptions]]\nname = "split"\nkind = "subdivide"\nparams = { splits = 2 }\n',
                  task_corruptions='corruptions = ["split"]')
    cfg["tasks"][0]["options"]["target"] = "self"
    with pytest.raises(ConfigError) as e:
        parse_config(cfg)
    assert e.value.key.startswith("tasks[0].options") and "corrupt" in str(e.value)


def test_corrupt_source_crops_the_source_only_and_carries_the_truth(tmp_path):
    """``corrupt = "source"`` (partial matching): the source is cropped with the seed ``corrupt = "both"`` gives
    it, the target stays whole; the ground truth keeps the crop's points, each paired with its original vertex
    (the crop's back-map); ``target = "self"`` with it is refused, naming the key."""
    from shape_toolkit.bench.tasks import prepare
    from shape_toolkit.data.corruptions import crop
    from shape_toolkit.data.datasets import load_item, open_dataset

    shape = icosphere(2)
    folder = _pair_folder(tmp_path / "pair", shape, {})
    item = load_item(next(iter(open_dataset("tosca", folder))))
    p = prepare(item, "crop", {"strength": 0.3, "attempts": 20}, pairwise=True, random_state=0, corrupt="source",
                score_on="clean", geodesic_method="dijkstra", truth_sample=100000)
    part, back = crop(shape, strength=0.3, random_state=1, attempts=20)
    assert p.target is item.target and p.source.n_vertices == part.n_vertices < shape.n_vertices
    np.testing.assert_array_equal(p.vertex_map, np.arange(shape.n_vertices))
    np.testing.assert_array_equal(p.truth, np.stack([np.arange(part.n_vertices), back], axis=1))
    assert p.geodesic_rows.shape == (part.n_vertices, shape.n_vertices)
    methods = '[[tasks.methods]]\npipeline = "partial"\n'
    cfg = _config(folder, methods, options='geodesic_method = "dijkstra", corrupt = "source"',
                  corruptions='[[corruptions]]\nname = "cut"\nkind = "crop"\nparams = { strength = 0.3 }\n',
                  task_corruptions='corruptions = ["cut"]')
    parse_config(cfg)
    cfg["tasks"][0]["options"]["target"] = "self"
    with pytest.raises(ConfigError) as e:
        parse_config(cfg)
    assert e.value.key.startswith("tasks[0].options") and "corrupt" in str(e.value)


def test_truth_seeds_reach_a_seeded_matcher_and_are_refused_elsewhere(tmp_path):
    """``truth_seeds = N``: seed-growing (which refuses to run without seeds) gets N ground-truth pairs, spread
    over the source by farthest-point sampling; a pipeline (it finds its own) in such a task is refused."""
    from shape_toolkit.bench.tasks import prepare, truth_seeds
    from shape_toolkit.data.datasets import load_item, open_dataset

    shape = icosphere(2)
    folder = _pair_folder(tmp_path / "pair", shape, {})
    item = load_item(next(iter(open_dataset("tosca", folder))))
    seeds = truth_seeds(prepare(item, "none", {}, pairwise=True, random_state=0), 12)
    assert seeds.shape == (12, 2) and np.array_equal(seeds[:, 0], seeds[:, 1]) and seeds[0, 0] == 0
    d = np.linalg.norm(shape.vertices[seeds[:, 0], None] - shape.vertices[None, seeds[:, 0]], axis=2)
    assert d[~np.eye(12, dtype=bool)].min() > 0.3  # spread out, not 12 neighbours
    opts = 'geodesic_method = "dijkstra", truth_sample = 100000, truth_seeds = 12'
    row = _rows(_config(folder, '[[tasks.methods]]\nplugin = "seed-growing"\n', options=opts), tmp_path / "r")
    assert row["seed-growing"]["metrics"]["mean_geodesic_error"] < 0.05  # the identity pair, seeded with truth
    with pytest.raises(ConfigError) as e:
        parse_config(_config(folder, '[[tasks.methods]]\npipeline = "zoomout"\n', options=opts))
    assert e.value.key == "tasks[0].methods[0]" and "truth_seeds" in str(e.value)
    # scored on the clean target, the seeds still name vertices of the corrupted target the method matches: the
    # truth carried through the corruption's vertex map (holes remove and renumber target vertices)
    p = prepare(item, "holes", {"strength": 2}, pairwise=True, random_state=0, score_on="clean")
    assert p.target.n_vertices < p.clean_target.n_vertices
    seeds = truth_seeds(p, 12)
    assert seeds.shape == (12, 2) and seeds[:, 1].max() < p.target.n_vertices
    np.testing.assert_array_equal(np.asarray(p.vertex_map)[seeds[:, 1]], seeds[:, 0])  # the identity pair's truth


def _self_config(folder: Path, methods: str, *, seed: str = "seed = 0\n", score_on: str = "target") -> dict:
    """Algorithm 5's protocol (the former ``plt_alignment.py``): each shape of ``folder`` matched to a copy of
    itself with 2 holes, 6 geodesic Voronoi cells carried by the corruption's vertex map."""
    import tomllib

    return tomllib.loads(f"""
[[datasets]]
name = "shapes"
kind = "folder"
path = "{folder}"
[[corruptions]]
name = "holes"
kind = "holes"
params = {{ strength = 2 }}
{seed}
[[tasks]]
task = "matching"
corruptions = ["holes"]
metrics = ["soft_label_transfer", "label_transfer"]
options = {{ target = "self", label_segments = 6, truth_sample = 1, score_on = "{score_on}" }}
{methods}
""")


def test_soft_label_transfer_in_the_runner_equals_algorithm_5_called_directly(tmp_path):
    """A config reproduces the former script's protocol: the copy drawn with the corruption's fixed ``seed``,
    the labels carried by its exact vertex map, the soft transfer of eq. 5.9 from the matcher's posteriors."""
    from shape_toolkit.api.registry import create_plugin
    from shape_toolkit.data.corruptions import apply_corruption
    from shape_toolkit.metrics.correspondence import label_transfer_scores, map_label_scores, truth_segments
    from shape_toolkit.results.correspondence import transfer_labels

    shape = icosphere(3)
    (tmp_path / "shapes").mkdir()
    save_shape(shape, tmp_path / "shapes" / "ball.off")
    rows = _rows(_self_config(tmp_path / "shapes", '[[tasks.methods]]\nplugin = "eigvec-alignment"\n'
                                                    'preset = "thesis"\nlabel = "thesis"\n'), tmp_path / "run")
    row = rows["thesis"]
    assert row["corruption_seed"] == 0
    ident = np.arange(shape.n_vertices)
    labels, _ = truth_segments(shape, shape, ident, ident, 6)
    copy, vmap = apply_corruption(shape, "holes", random_state=0, strength=2)
    corr = create_plugin("dense_matchers", "eigvec-alignment", "thesis").match(shape, copy)
    assert corr.posteriors is not None
    soft = label_transfer_scores(transfer_labels(corr, labels, to="target", soft=True), labels[vmap])
    hard = map_label_scores(corr.target_of, labels, labels[vmap], copy)
    m = row["metrics"]
    assert m["soft_label_recall"] == pytest.approx(soft["recall"], abs=1e-12)
    assert m["soft_label_precision"] == pytest.approx(soft["precision"], abs=1e-12)
    assert m["label_recall"] == pytest.approx(hard["recall"], abs=1e-12)


def test_soft_label_transfer_scored_on_the_clean_shape_sums_posteriors_through_the_back_map():
    """``score_on = "clean"``: the posteriors onto the holed copy are read on the clean shape, so its removed
    vertices get no mass and count against the soft recall exactly; on the copy the exact map scores 1."""
    from shape_toolkit.bench.tasks import TASKS, prepare
    from shape_toolkit.data.corruptions import invert_vertex_map
    from shape_toolkit.data.datasets import DatasetItem
    from shape_toolkit.metrics import label_transfer_scores, truth_segments
    from shape_toolkit.results.correspondence import Correspondence

    shape = icosphere(3)
    task = TASKS["matching"]
    opts = task.check_options({"target": "self", "label_segments": 6})
    scores = {}
    for score_on in ("target", "clean"):
        p = prepare(DatasetItem("ball", shape), "holes", {"strength": 2}, pairwise=True, random_state=0,
                    target="self", score_on=score_on)
        copy = p.target
        t = invert_vertex_map(p.vertex_map, shape)  # the exact map: each kept vertex to its copy
        ok = np.flatnonzero(t >= 0)
        post = sp.csr_matrix((np.ones(ok.size), (ok, t[ok])), shape=(shape.n_vertices, copy.n_vertices))
        out = {"target_of": t, "correspondence": Correspondence(t, copy.n_vertices, posteriors=post)}
        scores[score_on] = task.evaluate(["soft_label_transfer", "label_transfer"], p, out, opts)
        one = np.full_like(t, -1)
        one[ok[0]] = t[ok[0]]  # a hard map of one vertex beside the exact posteriors: soft follows the posteriors
        out = {"target_of": one, "correspondence": Correspondence(one, copy.n_vertices, posteriors=post)}
        scores[score_on, "one"] = task.evaluate(["soft_label_transfer", "label_transfer"], p, out, opts)
        assert scores[score_on, "one"]["soft_label_recall"] == scores[score_on]["soft_label_recall"]
        assert scores[score_on, "one"]["label_recall"] < 0.5  # one label filled everywhere
    assert 0 < ok.size < shape.n_vertices  # the holes removed vertices
    assert scores["target"]["soft_label_recall"] == 1.0 and scores["target"]["label_recall"] == 1.0
    ident = np.arange(shape.n_vertices)
    labels, _ = truth_segments(shape, shape, ident, ident, 6)
    kept = np.zeros(shape.n_vertices, bool)
    kept[ok] = True
    want = label_transfer_scores(np.where(kept, labels, -1), labels)
    assert want["recall"] < 1.0
    assert scores["clean"]["soft_label_recall"] == pytest.approx(want["recall"], abs=1e-12)
    assert scores["clean"]["label_recall"] > scores["clean"]["soft_label_recall"]  # the hard map fills the holes


def test_a_fixed_corruption_seed_draws_every_item_alike_and_is_validated(tmp_path):
    """``seed = N`` on a corruption: every item's copy with random_state N (the default hashes one per item);
    a bad seed is refused naming its key, before any work."""
    from shape_toolkit.bench.plan import plan

    (tmp_path / "shapes").mkdir()
    for name in ("a", "b"):
        save_shape(icosphere(2), tmp_path / "shapes" / f"{name}.off")
    method = '[[tasks.methods]]\nplugin = "eigvec-alignment"\n'
    _, fixed = plan(parse_config(_self_config(tmp_path / "shapes", method, seed="seed = 7\n")), tmp_path / "r1")
    _, hashed = plan(parse_config(_self_config(tmp_path / "shapes", method, seed="")), tmp_path / "r2")
    assert sorted(p.seed for p in fixed.values()) == [7, 7]
    assert len({p.seed for p in hashed.values()}) == 2 and 7 not in {p.seed for p in hashed.values()}
    for bad in ("seed = -1\n", 'seed = "0"\n', "seed = 2147483647\n"):
        with pytest.raises(ConfigError) as e:
            parse_config(_self_config(tmp_path / "shapes", method, seed=bad))
        assert e.value.key == "corruptions[0].seed"
    with pytest.raises(ConfigError) as e:  # the soft metric is a matching metric
        cfg = _self_config(tmp_path / "shapes", method)
        cfg["tasks"][0].update(task="segmentation", options={})
        cfg["tasks"][0]["methods"] = [{"plugin": "spectral-clustering"}]
        parse_config(cfg)
    assert e.value.key.startswith("tasks[0].metrics") and "soft_label_transfer" in str(e.value)


def test_the_soft_transfer_alone_gets_a_per_category_table():
    """A run scoring only Algorithm 5's soft transfer (soft_label_transfer) still gets its per-category table."""
    from shape_toolkit.bench.report import _category_grid

    rows = [{"status": "ok", "category": c, "dataset": "d", "plugin": "eigvec-alignment", "method_label": "m",
             "corruption": "none", "metrics": {"soft_label_recall": v, "soft_label_precision": 1.0}}
            for c, v in [("cat", 0.5), ("cat", 1.0), ("wolf", 0.25)]]
    g = _category_grid("t", rows)
    assert g is not None and "soft_label_recall" in g.title
    (_, cells), = g.rows
    assert cells[0][0] == 0.75 and cells[1][0] == 0.25 and cells[2][0] == 0.5  # cat, wolf, mean of categories


def test_a_composed_corruption_scored_on_the_clean_target_equals_a_hand_composed_run(tmp_path, monkeypatch):
    """Two steps (drop and shuffle vertices, then move them by Gaussian noise), each with its own seed from the
    corruption's: the runner's error on the clean target equals the one of the same steps applied by hand, the
    nearest-vertex map composed through both back-maps and measured along the clean mesh's edges."""
    from shape_toolkit.bench import peers
    from shape_toolkit.data import corruptions
    from shape_toolkit.data.corruptions import gaussian_noise, step_seeds

    def nearest(source, target):
        return cKDTree(target.vertices).query(source.vertices)[1]

    monkeypatch.setitem(corruptions.CORRUPTIONS, "shuffle", _shuffle_and_drop)
    monkeypatch.setitem(peers.PEERS, "nearest", (nearest, "numpy", "numpy"))
    shape = icosphere(2)
    folder = _pair_folder(tmp_path / "pair", shape, {})
    corr = ('[[corruptions]]\nname = "moved"\nseed = 5\nsteps = [{ kind = "shuffle", params = { strength = 0.2 } }, '
            '{ kind = "gaussian-noise", params = { strength = [0.3, 0.6] } }]\n')
    cfg = _config(folder, '[[tasks.methods]]\npeer = "nearest"\n',
                  options='geodesic_method = "dijkstra", truth_sample = 100000, score_on = "clean"',
                  corruptions=corr, task_corruptions='corruptions = ["moved"]')
    run_benchmark(parse_config(cfg), tmp_path / "run", progress=False)
    rows = sorted(read_rows(tmp_path / "run"), key=lambda r: r["strength"])
    assert [r["corruption"] for r in rows] == ["moved[shuffle:0.2+gaussian-noise:0.3]",
                                               "moved[shuffle:0.2+gaussian-noise:0.6]"]
    s1, s2 = step_seeds(5, 2)
    dropped, m1 = _shuffle_and_drop(shape, strength=0.2, random_state=s1)
    geo = _edge_distances(shape, np.arange(shape.n_vertices))
    for r, sigma in zip(rows, (0.3, 0.6)):
        assert r["status"] == "ok", r.get("error")
        assert r["corruption_kind"] == "shuffle+gaussian-noise" and r["corruption_seed"] == 5
        moved, m2 = gaussian_noise(dropped, strength=sigma, random_state=s2)
        t = m1[m2][nearest(shape, moved)]  # the map onto the clean target, by hand
        want = geo[np.arange(shape.n_vertices), t] / np.sqrt(shape.area)
        assert want.mean() > 0.01  # the noise moved the vertices: the map is not exact
        assert r["metrics"]["mean_geodesic_error"] == pytest.approx(want.mean(), rel=1e-5)
        assert r["metrics"]["matched_fraction"] == 1.0
        assert r["n_vertices"] == dropped.n_vertices < shape.n_vertices


def test_a_step_the_shape_refuses_fails_its_rows_with_one_typed_line(tmp_path):
    """Colour noise on a target without colours: every row of that corruption fails with the step's typed
    error, one line naming the step; the run goes on with the other corruptions."""
    folder = _pair_folder(tmp_path / "pair", icosphere(1), {"ident": np.arange(42)})
    corr = ('[[corruptions]]\nname = "noisy"\nsteps = [{ kind = "gaussian-noise" }, '
            '{ kind = "color-noise", params = { strength = 0.1 } }]\n')
    cfg = _config(folder, '[[tasks.methods]]\npipeline = "zoomout"\n', corruptions=corr,
                  task_corruptions='corruptions = ["none", "noisy"]')
    run_benchmark(parse_config(cfg), tmp_path / "run", progress=False)
    rows = {r["corruption"]: r for r in read_rows(tmp_path / "run")}
    assert rows["none"]["status"] == "ok"
    bad = rows["noisy[gaussian-noise:0.1+color-noise:0.1]"]
    assert bad["status"] == "failed" and len(bad["error"].splitlines()) == 1
    assert ("InvalidShapeError: step 2 of 2 of 'gaussian-noise+color-noise' (color-noise):" in bad["error"]
            and "no vertex colours" in bad["error"]), bad["error"]


def test_truth_reference_row_is_the_filled_ground_truth_and_never_best(tmp_path):
    from types import SimpleNamespace

    from shape_toolkit.bench.report import write_report
    from shape_toolkit.bench.tasks import GroundTruthMap

    shape = icosphere(2)
    n = shape.n_vertices
    perm = np.random.default_rng(0).permutation(n)
    folder = _pair_folder(tmp_path / "pair", shape, {"ident": np.arange(n), "perm": perm})
    keep = np.arange(0, n, 3)  # the ground truth pairs every third vertex, as template points do
    for name in ("A", "B"):
        np.savetxt(folder / "corres" / f"{name}.vts", keep + 1, fmt="%d")
    # by hand: every vertex takes the image of the nearest paired vertex along the edges (here itself)
    t = GroundTruthMap.target_of(SimpleNamespace(name="A-B", source=shape, truth=np.c_[keep, keep]))
    d = _edge_distances(shape, keep)
    assert np.array_equal(t[keep], keep)
    assert np.allclose(d[np.searchsorted(keep, t), np.arange(n)], d.min(axis=0))
    cfg = _config(folder, _maps("ident", "perm"), options='geodesic_method = "dijkstra", truth_reference = true')
    rows = _rows(cfg, tmp_path / "run")
    ref = rows["ground truth"]
    assert ref["family"] == "references" and ref["seconds"] is None
    assert ref["metrics"]["mean_geodesic_error"] == 0.0 and ref["metrics"]["matched_fraction"] == 1.0
    md = tmp_path / "x.md"
    write_report(tmp_path / "run", renders=0, markdown=md)
    lines = md.read_text().splitlines()
    line = next(s for s in lines if s.startswith("| pair | ground truth |"))
    assert "**" not in line  # a reference, never ranked, though its error is the least
    assert "*tie*" not in next(s for s in lines if s.startswith("| pair | ident |"))  # ident alone is best
    with pytest.raises(ConfigError, match="score_on"):
        parse_config(_config(folder, _maps("ident"), options='truth_reference = true, score_on = "clean"'))
