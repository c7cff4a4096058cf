"""``shape-toolkit evaluate-segmentation MESH PRED --truth FILE_OR_DIR``: PSB metrics and the
thesis' matched recall / precision, averaged over every ground-truth segmentation given."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from shape_toolkit.cli.commands._common import print_json, read_labels_as_given, read_labels_file
from shape_toolkit.errors import ParameterError, ShapeFileError
from shape_toolkit.io.mesh import load_shape
from shape_toolkit.metrics.segmentation import SEGMENTATION_METRICS, segmentation_scores
from shape_toolkit.results.labels import vertex_to_face_labels


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("evaluate-segmentation", help="score a segmentation against ground truth")
    p.add_argument("shape", help="mesh file")
    p.add_argument("prediction", help="labels file: one per vertex (default) or per face (--faces)")
    p.add_argument("--truth", required=True,
                   help="ground-truth labels file, or a directory of them (PSB: .seg, one per face; "
                        "files with one label per vertex are converted)")
    p.add_argument("--faces", action="store_true", help="the prediction has one label per face")
    p.add_argument("--per-truth", action="store_true", help="also list the scores against each truth")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def _truth_files(path: Path) -> list[Path]:
    if not path.exists():
        raise ShapeFileError(path, "no such ground-truth file or directory")
    if path.is_dir():
        files = sorted((f for f in path.iterdir() if f.is_file() and not f.name.startswith(".")
                        and f.suffix in (".seg", ".txt", ".labels")), key=_natural)
        if not files:
            raise ShapeFileError(path, "contains no .seg / .txt / .labels ground-truth files")
        return files
    return [path]


def _natural(p: Path) -> tuple:
    import re

    return tuple(int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.name))


def _face_labels(path: Path, shape, what: str) -> np.ndarray:
    labels = read_labels_file(path)
    if len(labels) == shape.n_faces:
        return labels
    if len(labels) == shape.n_vertices:
        return vertex_to_face_labels(shape.faces, labels)
    raise ShapeFileError(
        path, f"{what} has {len(labels)} labels but the mesh has {shape.n_faces} faces "
              f"and {shape.n_vertices} vertices"
    )


def run(args: argparse.Namespace) -> int:
    if not args.truth:  # Path("") is the current folder: an empty argument must not mean it
        raise ParameterError("--truth: give a ground-truth file or folder, got an empty name")
    files = _truth_files(Path(args.truth))
    pred_path = Path(args.prediction).resolve()
    if Path(args.truth).is_dir() and any(f.resolve() == pred_path for f in files):
        # one of the truths would be the prediction itself, silently averaged in as a perfect score
        raise ParameterError(f"--truth folder {args.truth} holds the prediction {args.prediction} itself; keep the "
                             "prediction out of the ground-truth folder")
    shape = load_shape(args.shape)
    shape.require_faces("evaluate-segmentation")
    pred = read_labels_as_given(args.prediction, shape, args.faces, "PRED")
    pred_faces = pred if args.faces else vertex_to_face_labels(shape.faces, pred)
    truths = [_face_labels(f, shape, "ground truth") for f in files]
    scores = segmentation_scores(pred_faces, truths, mesh=shape)
    result = {name: (None if math.isnan(scores[name]) else scores[name]) for name in SEGMENTATION_METRICS}
    if result.get("cut_discrepancy", 0.0) is None:  # the one metric that can be undefined: say why
        result["undefined"] = {"cut_discrepancy": "only one of the prediction and the ground truth has a cut "
                               "(a boundary between segments), and the distance between cuts needs both"}
    result["n_truths"] = len(truths)
    result["truth_files"] = [str(f) for f in files]
    result["n_segments_pred"] = int(len(np.unique(pred)))
    if args.per_truth:
        result["per_truth"] = scores["per_truth"]
    if args.json:
        print_json(result)
    else:
        print(f"{shape!r} vs {len(truths)} ground truth(s):")
        for name in SEGMENTATION_METRICS:
            v = result[name]
            better = "higher is better" if name in ("recall", "precision") else "lower is better"
            print(f"  {name:18s} {'n/a' if v is None else f'{v:.4f}'}   ({better})")
    return 0
