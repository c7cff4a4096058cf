"""Ground-truth files and dataset layouts (TOSCA-style correspondences, PSB segmentations).

Datasets are listed cheaply as :class:`ItemRef` (small, picklable: a kind, a name and the paths
or parameters needed to build it) and materialised with :func:`load_item` into a
:class:`DatasetItem` (shape, optional matching target and ground truth). Benchmark workers
receive refs and load items themselves.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError, ShapeFileError
from shape_toolkit.results.labels import face_to_vertex_labels, read_int_file, read_vertex_ids
from shape_toolkit.validation import atomic_output, shown_value

__all__ = [
    "read_vertex_ids",
    "read_vts",
    "read_face_labels",
    "read_labels",
    "write_labels",
    "ItemRef",
    "DatasetItem",
    "DATASET_KINDS",
    "GENERATED_KINDS",
    "sequence_refs",
    "tosca_dataset",
    "psb_dataset",
    "folder_dataset",
    "synthetic_refs",
    "open_dataset",
    "find_item",
    "load_item",
    "PSB_CATEGORIES",
    "item_group",
    "truth_segment_counts",
]


def read_vts(path: str | os.PathLike, n_vertices: int | None = None) -> np.ndarray:
    """Read a TOSCA ``.vts`` correspondence file (1-based) as 0-based int64 vertex ids."""
    return read_vertex_ids(path, one_based=True, n_vertices=n_vertices)


def read_labels(path: str | os.PathLike, n_expected: int | None = None) -> np.ndarray:
    """Read one integer label per line (vertex labels, or face labels of a PSB ``.seg`` file)
    as int64 ``(n,)``; a length other than ``n_expected`` raises :class:`ShapeFileError`."""
    labels = read_int_file(path, "labels")
    if n_expected is not None and len(labels) != n_expected:
        raise ShapeFileError(path, f"has {len(labels)} labels, expected {n_expected}")
    return labels


def read_face_labels(path: str | os.PathLike, n_faces: int | None = None) -> np.ndarray:
    """Read a PSB ``.seg`` file: one label per face, in face order, int64 ``(m,)``."""
    return read_labels(path, n_faces)


def write_labels(path: str | os.PathLike, labels: np.ndarray) -> None:
    """Write one integer per line (labels, or 0-based vertex ids with -1 for unmatched)."""
    with atomic_output(path, "labels file") as tmp:
        np.savetxt(tmp, np.asarray(labels, dtype=np.int64), fmt="%d")


# --------------------------------------------------------------------------------------------
# dataset layouts
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ItemRef:
    """A light, picklable reference to one dataset item: ``kind`` (tosca, psb, folder,
    synthetic), its ``name``, and the ``paths``/``params`` :func:`load_item` needs."""

    kind: str
    name: str
    paths: dict[str, Any] = field(default_factory=dict)
    params: dict[str, Any] = field(default_factory=dict)


@dataclass
class DatasetItem:
    """One benchmark item with its ground truth.

    ``shape``: the (source) shape. ``labels``: ground-truth per-vertex segmentations of ``shape``
    (list of int64 ``(n,)``, several when several people segmented it). ``face_labels``: the same
    per face when the dataset gives them. ``target`` and ``correspondence`` (int64 ``(q, 2)``
    pairs ``[source vertex, target vertex]``) for matching; ``symmetric_correspondence`` the
    left-right symmetric ground truth when known. ``target_labels`` segmentations of the target.
    """

    name: str
    shape: Shape
    labels: list[np.ndarray] = field(default_factory=list)
    face_labels: list[np.ndarray] = field(default_factory=list)
    target: Shape | None = None
    correspondence: np.ndarray | None = None
    symmetric_correspondence: np.ndarray | None = None
    target_labels: list[np.ndarray] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)


def _require_dir(root: str | os.PathLike, what: str) -> Path:
    p = Path(root)
    if not p.is_dir():
        raise ShapeFileError(p, f"{what} dataset folder not found")
    return p


def tosca_dataset(
    root: str | os.PathLike, *, pairs: str = "pairs.txt", classes: list[str] | None = None
) -> list[ItemRef]:
    """Pairs of a TOSCA-style folder: ``NAME.off`` meshes, ``corres/NAME.vts`` (1-based, row i of
    every file of a class is the same point) and a tab/space separated ``pairs`` list (A B);
    ``corres/B.sym.vts`` (the left-right symmetric ground truth) when the folder has it (tosca5k,
    faust5k; not tosca_noniso, whose symmetric metrics are then n/a). A loaded item's ``meta``
    names its ``folder`` and ``pair`` ``[A, B]`` (where published maps ``A_B.map`` are looked up). With
    ``classes`` (e.g. ``["dog", "wolf"]``: a split by animal), only pairs whose two shapes' classes (the
    letters before the digits) are listed."""
    root = _require_dir(root, "TOSCA-style")
    plist = root / pairs
    if plist.exists():
        rows = [ln.split() for ln in plist.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
        for r in rows:
            if len(r) != 2:
                raise ShapeFileError(plist, f"each line must name two shapes, got {' '.join(r)!r}")
    else:  # every ordered pair of shapes sharing a class prefix (letters before the digits)
        names = sorted(p.stem for p in root.glob("*.off"))
        cls = {n: n.rstrip("0123456789") for n in names}
        rows = [[a, b] for a in names for b in names if a < b and cls[a] == cls[b]]
    if classes is not None:
        if not isinstance(classes, (list, tuple)) or not all(isinstance(c, str) for c in classes):
            raise ParameterError(f"classes must be a list of class names, got {classes!r}")
        known = {n.rstrip("0123456789") for r in rows for n in r}
        bad = sorted(set(classes) - known)
        if bad:
            raise ParameterError(f"classes: unknown class {bad[0]!r}; known: {', '.join(sorted(known))}")
        rows = [r for r in rows if all(n.rstrip("0123456789") in classes for n in r)]
    refs = []
    for a, b in rows:
        paths = {"source": str(root / f"{a}.off"), "target": str(root / f"{b}.off")}
        for key, nm in (("source_vts", a), ("target_vts", b)):
            paths[key] = str(root / "corres" / f"{nm}.vts")
        sym = root / "corres" / f"{b}.sym.vts"
        if sym.exists():
            paths["target_sym_vts"] = str(sym)
        for key in ("source", "target", "source_vts", "target_vts"):
            if not Path(paths[key]).exists():
                raise ShapeFileError(paths[key], f"listed by {plist.name} but missing")
        refs.append(ItemRef("tosca", f"{a}-{b}", paths))
    return refs


def psb_dataset(root: str | os.PathLike) -> list[ItemRef]:
    """Meshes of the Princeton Segmentation Benchmark layout: ``off/ID.off`` and the human
    segmentations ``seg/ID/ID_K.seg`` (one label per face), sorted by numeric id."""
    root = _require_dir(root, "PSB")
    off = root / "off" if (root / "off").is_dir() else root
    meshes = sorted(off.glob("*.off"), key=lambda p: (int(p.stem) if p.stem.isdigit() else 1 << 60, p.stem))
    refs = []
    for m in meshes:
        segdir = root / "seg" / m.stem
        segs = sorted(segdir.glob("*.seg"), key=lambda p: (len(p.stem), p.stem)) if segdir.is_dir() else []
        if not segs:
            segs = sorted((root / "seg").glob(f"{m.stem}*.seg")) if (root / "seg").is_dir() else []
        refs.append(ItemRef("psb", m.stem, {"shape": str(m), "segs": [str(s) for s in segs]}))
    return refs


def folder_dataset(root: str | os.PathLike, *, pattern: str = "*") -> list[ItemRef]:
    """Every mesh or point-cloud file (OFF, PLY, OBJ, STL, XYZ, PCD) matching ``pattern``; a
    sibling ``NAME.labels`` file (one label per vertex) is read as ground truth."""
    from shape_toolkit.io.mesh import MESH_FORMATS, POINT_FORMATS

    root = _require_dir(root, "shape")
    exts = set(MESH_FORMATS) | set(POINT_FORMATS)
    files = sorted(p for p in root.glob(pattern) if p.is_file() and p.suffix.lower() in exts)
    refs = []
    for f in files:
        paths: dict[str, Any] = {"shape": str(f)}
        lab = f.with_suffix(".labels")
        if lab.exists():
            paths["labels"] = str(lab)
        refs.append(ItemRef("folder", f.stem, paths))
    return refs


def synthetic_refs(
    n_poses: int = 4, *, subdivisions: int = 3, random_state: int = 0, max_angle: float = 1.0,
    limb_lengths: list[float] | None = None,
) -> list[ItemRef]:
    """Refs of :func:`shape_toolkit.data.synthetic.synthetic_dataset`: item ``pose{i}`` is pose i, matched to
    pose i + 1 (cyclically) with the identity as exact ground truth; ``limb_lengths``: one per limb (None:
    alike). Any other pair of poses is the item ``pose{i}-pose{j}`` (:func:`find_item`), named as a TOSCA pair."""
    from shape_toolkit.data.synthetic import MAX_POSES

    if isinstance(n_poses, bool) or not isinstance(n_poses, (int, np.integer)) or not 1 <= n_poses <= MAX_POSES:
        raise ParameterError(f"n_poses must be an integer in [1, {MAX_POSES}] (every pose is made), got "
                             f"{shown_value(n_poses)}")
    params = {
        "n_poses": int(n_poses), "subdivisions": int(subdivisions),
        "random_state": int(random_state), "max_angle": float(max_angle),
    }
    if limb_lengths is not None:
        try:
            lengths = [float(x) for x in limb_lengths]
        except (TypeError, ValueError):
            raise ParameterError(f"limb_lengths must be a list of numbers, got {limb_lengths!r}") from None
        from shape_toolkit.data.synthetic import DEFAULT_LIMBS

        if len(lengths) != len(DEFAULT_LIMBS) or not all(np.isfinite(x) and x > 0 for x in lengths):
            raise ParameterError(f"limb_lengths must hold {len(DEFAULT_LIMBS)} positive lengths, got {limb_lengths!r}")
        params["limb_lengths"] = lengths
    return [ItemRef("synthetic", f"pose{i}", {}, {**params, "index": i}) for i in range(n_poses)]


def sequence_refs(
    seeds: list[int] | tuple[int, ...] = (0,),
    *,
    frames: int = 7,
    subdivisions: int = 3,
    remesh: int | None = None,
    merge_frames: list[int] | tuple[int, ...] = (),
    max_angle: float = 0.8,
    permute: bool = True,
) -> list[ItemRef]:
    """Refs of generated pose sequences (:func:`shape_toolkit.data.synthetic.pose_sequence`, thesis
    7.5.3): one item ``seedS`` per random state in ``seeds``, ``frames`` frames each, feet glued in
    ``merge_frames``, every frame remeshed to about ``remesh`` vertices (None: not) and its vertex
    order shuffled when ``permute``. A loaded item is frame 0; the ``sequence`` task regenerates the
    frames from ``meta["sequence"]``."""
    if isinstance(seeds, (int, np.integer)) and not isinstance(seeds, bool):
        seeds = [int(seeds)]
    if not isinstance(seeds, (list, tuple)) or not seeds or not all(
        isinstance(s, (int, np.integer)) and not isinstance(s, bool) and s >= 0 for s in seeds
    ):
        raise ParameterError(f"seeds must be a non-empty list of non-negative integers, got {seeds!r}")
    from shape_toolkit.data.synthetic import MAX_FRAMES

    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or not 2 <= frames <= MAX_FRAMES:
        raise ParameterError(f"frames must be an integer in [2, {MAX_FRAMES}] (every frame is made and kept), got "
                             f"{shown_value(frames)}")
    if not isinstance(merge_frames, (list, tuple)) or not all(
        isinstance(m, (int, np.integer)) and not isinstance(m, bool) and 0 <= m < frames for m in merge_frames
    ):
        raise ParameterError(f"merge_frames must be frame indices in [0, {frames - 1}], got {merge_frames!r}")
    if remesh is not None and (isinstance(remesh, bool) or not isinstance(remesh, (int, np.integer)) or remesh < 20):
        raise ParameterError(f"remesh must be a vertex count >= 20, got {remesh!r}")
    params = {"n_frames": int(frames), "subdivisions": int(subdivisions),
              "merge_frames": [int(m) for m in merge_frames], "max_angle": float(max_angle),
              "remesh": None if remesh is None else int(remesh),
              "permute": bool(permute)}
    return [ItemRef("sequence", f"seed{int(s)}", {}, {**params, "random_state": int(s)})
            for s in dict.fromkeys(int(s) for s in seeds)]


#: dataset kinds generated from parameters (no folder)
GENERATED_KINDS = ("synthetic", "sequence")

#: dataset kind -> function listing its refs (first argument: the folder, except generated kinds)
DATASET_KINDS = {
    "tosca": tosca_dataset,
    "psb": psb_dataset,
    "folder": folder_dataset,
    "synthetic": synthetic_refs,
    "sequence": sequence_refs,
}


def open_dataset(kind: str, path: str | os.PathLike | None = None, **params: Any) -> list[ItemRef]:
    """The item refs of a dataset of ``kind`` (see :data:`DATASET_KINDS`) at ``path``."""
    if kind not in DATASET_KINDS:
        raise ParameterError(f"unknown dataset kind {kind!r}; known: {', '.join(DATASET_KINDS)}")
    fn = DATASET_KINDS[kind]
    try:
        if kind in GENERATED_KINDS:
            return fn(**params)
        if path is None:
            raise ParameterError(f"a {kind} dataset needs a path")
        return fn(path, **params)
    except TypeError as exc:
        raise ParameterError(f"{kind} dataset: {exc}") from None


def find_item(kind: str, refs: list[ItemRef] | tuple[ItemRef, ...], name: str) -> ItemRef:
    """The item of a dataset of ``kind`` named ``name``: one of its listed ``refs``, or a pair named
    ``"SOURCE-TARGET"`` as TOSCA's pairs are: for a synthetic dataset any two distinct poses,
    ``"pose0-pose2"`` (its listed items pair pose i with pose i + 1, as ``pose{i}``; the identity is the
    ground truth of every pair). :class:`ParameterError` names a few items when there is no such item."""
    for r in refs:
        if r.name == name:
            return r
    if kind == "synthetic" and refs:
        import re

        m = re.fullmatch(r"pose(\d+)-pose(\d+)", name)
        base = {k: v for k, v in refs[0].params.items() if k != "index"}
        n = int(base["n_poses"])
        if m and int(m[1]) != int(m[2]) and max(int(m[1]), int(m[2])) < n:
            return ItemRef("synthetic", name, {}, {**base, "index": int(m[1]), "target_index": int(m[2])})
        pairs = f" or a pair of two of its {n} poses, e.g. pose0-pose{min(2, n - 1)}" if n > 1 else ""
        raise ParameterError(f"no item {name!r} in the dataset: its items are pose0 ... pose{n - 1} (pose i -> "
                             f"i + 1){pairs}")
    raise ParameterError(f"no item {name!r} in the dataset; e.g. {', '.join(r.name for r in list(refs)[:5])}")


#: PSB categories in id order: model ``ID`` (1..400) is of category ``PSB_CATEGORIES[(ID - 1) // 20]``
PSB_CATEGORIES = ("human", "cup", "glasses", "airplane", "ant", "chair", "octopus", "table", "teddy", "hand",
                  "plier", "fish", "bird", "spring", "armadillo", "bust", "mech", "bearing", "vase", "fourleg")


def _shape_group(name: str) -> str:
    """The group of one shape name: a FAUST subject (``tr_reg_NNN``: ``subject-NNN // 10``), else the
    class prefix (the letters before the trailing digits: TOSCA's animal, ``cat0`` -> ``cat``)."""
    stem = Path(name).stem
    if stem.startswith("tr_reg_") and stem[7:].isdigit():
        return f"subject-{int(stem[7:]) // 10}"
    prefix = stem.rstrip("0123456789").rstrip("_-")
    return prefix or stem


def item_group(ref: ItemRef) -> str | None:
    """The group of an item, for per-category tables and splits that never cut a group: a PSB mesh's
    category (from its numeric id), the animal of a TOSCA-style pair (``cat``), the FAUST subject
    (``subject-2``); a pair of shapes of two groups gets both, ``"a+b"`` (in no split half). None
    when the item has no group (folder and synthetic datasets)."""
    if ref.kind == "psb":
        stem = Path(str(ref.paths.get("shape", ref.name))).stem
        if stem.isdigit() and 1 <= int(stem) <= 20 * len(PSB_CATEGORIES):
            return PSB_CATEGORIES[(int(stem) - 1) // 20]
        return None
    if ref.kind == "tosca":
        groups = sorted({_shape_group(ref.paths["source"]), _shape_group(ref.paths["target"])})
        return "+".join(groups)
    return None


def truth_segment_counts(ref: ItemRef) -> list[int]:
    """Segments per ground-truth segmentation of an item, read from its label files without loading
    the shape (PSB ``.seg`` face labels, a folder's ``.labels``; other kinds load the item)."""
    if ref.kind == "psb":
        return [int(np.unique(read_face_labels(s)).size) for s in ref.paths.get("segs", [])]
    if ref.kind == "folder":
        return [int(np.unique(read_labels(ref.paths["labels"])).size)] if "labels" in ref.paths else []
    return [int(np.unique(lab).size) for lab in load_item(ref).labels]


def _pairs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    if len(a) != len(b):
        raise ParameterError(f"correspondence files differ in length ({len(a)} vs {len(b)})")
    return np.stack([a, b], axis=1).astype(np.int64)


def load_item(ref: ItemRef) -> DatasetItem:
    """Materialise a ref: read the shapes and their ground truth (0-based, validated)."""
    from shape_toolkit.io.mesh import load_shape

    p = ref.paths
    if ref.kind == "tosca":
        src, tgt = load_shape(p["source"], kind="mesh"), load_shape(p["target"], kind="mesh")
        a = read_vts(p["source_vts"], src.n_vertices)
        b = read_vts(p["target_vts"], tgt.n_vertices)
        item = DatasetItem(ref.name, src, target=tgt, correspondence=_pairs(a, b), meta={
            "folder": str(Path(p["source"]).parent), "pair": [Path(p["source"]).stem, Path(p["target"]).stem]})
        if "target_sym_vts" in p:
            item.symmetric_correspondence = _pairs(a, read_vts(p["target_sym_vts"], tgt.n_vertices))
        return item
    if ref.kind == "psb":
        shape = load_shape(p["shape"], kind="mesh")
        fls = [read_face_labels(s, shape.n_faces) for s in p["segs"]]
        vls = [face_to_vertex_labels(shape.faces, fl, shape.n_vertices) for fl in fls]
        return DatasetItem(ref.name, shape, labels=vls, face_labels=fls)
    if ref.kind == "folder":
        shape = load_shape(p["shape"])
        labels = [read_labels(p["labels"], shape.n_vertices)] if "labels" in p else []
        return DatasetItem(ref.name, shape, labels=labels)
    if ref.kind == "sequence":
        from shape_toolkit.data.synthetic import cached_pose_sequence

        seq = cached_pose_sequence(ref.params)
        return DatasetItem(ref.name, seq.frames[0], labels=[seq.frame_labels(0)],
                           meta={"sequence": dict(ref.params)})
    if ref.kind == "synthetic":
        from shape_toolkit.data.synthetic import synthetic_dataset

        prm = dict(ref.params)
        i = prm.pop("index")
        j = prm.pop("target_index", None)  # a pair named poseI-poseJ; else pose i -> i + 1
        poses = synthetic_dataset(**prm)
        a, b = poses[i], poses[(i + 1) % len(poses) if j is None else j]
        ident = np.arange(a.shape.n_vertices, dtype=np.int64)
        src, tgt = (x.shape if x.colors is None else x.shape.with_colors(x.colors) for x in (a, b))
        return DatasetItem(
            ref.name, src, labels=[a.labels], target=tgt,
            correspondence=np.stack([ident, ident], axis=1), target_labels=[b.labels],
            meta={"angles": a.angles.tolist(), "target_angles": b.angles.tolist()},
        )
    raise ParameterError(f"unknown dataset kind {ref.kind!r}")
