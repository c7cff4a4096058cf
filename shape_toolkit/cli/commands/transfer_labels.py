"""``shape-toolkit transfer-labels TRAIN TRAIN_LABELS TEST -o labels.txt``: probabilistic label
transfer (Algorithm 5) from a segmented shape to another."""

from __future__ import annotations

import argparse
import time

import numpy as np

from shape_toolkit.cli.commands._common import (
    check_distinct,
    check_output_path,
    parse_params,
    plugin_class,
    print_json,
    read_labels_file,
    read_seeds_file,
)
from shape_toolkit.data.datasets import write_labels
from shape_toolkit.io.mesh import load_shape
from shape_toolkit.results.label_transfer import probabilistic_label_transfer


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("transfer-labels", help="transfer vertex labels of a segmented shape to another")
    p.add_argument("train", help="segmented (training) shape")
    p.add_argument("train_labels", help="one integer label per train vertex")
    p.add_argument("test", help="shape to label")
    p.add_argument("-o", "--output", required=True, help="write one label per test vertex here")
    p.add_argument("--matcher", default="eigvec-alignment",
                   help="dense matcher (default eigvec-alignment: histogram alignment + EM)")
    p.add_argument("--preset", default=None, help="preset of the matcher")
    p.add_argument("--param", action="append", metavar="KEY=VALUE", help="matcher parameter")
    p.add_argument("--seeds", help="seed matches 'train test' (0-based) per line, e.g. for em-registration")
    p.add_argument("--truth", help="ground-truth test labels: report recall and precision")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    check_output_path(args.output)
    check_distinct(args.output, args.train, args.train_labels, args.test, args.truth, args.seeds)
    params = parse_params(args.param, plugin_class("dense_matchers", args.matcher))
    train = load_shape(args.train)
    test = load_shape(args.test)
    labels = read_labels_file(args.train_labels, train.n_vertices)
    truth = read_labels_file(args.truth, test.n_vertices) if args.truth else None
    seeds = read_seeds_file(args.seeds, train.n_vertices, test.n_vertices) if args.seeds else None
    t0 = time.perf_counter()
    out, corr = probabilistic_label_transfer(
        train, labels, test, matcher=args.matcher, matcher_params=params,
        preset=args.preset, seeds=seeds,
    )
    seconds = time.perf_counter() - t0
    write_labels(args.output, out)
    values, counts = np.unique(out, return_counts=True)
    result = {
        "labels_file": args.output,
        "n_vertices": test.n_vertices,
        "n_unlabelled": int(np.sum(out < 0)),
        "label_counts": {str(int(v)): int(c) for v, c in zip(values, counts)},
        "matcher": args.matcher,
        "soft": corr.posteriors is not None,
        "seconds": round(seconds, 3),
    }
    if truth is not None:
        from shape_toolkit.metrics.correspondence import label_transfer_scores

        s = label_transfer_scores(out, truth)
        result.update(recall=s["recall"], precision=s["precision"])
    if args.json:
        print_json(result)
    else:
        print(f"wrote {test.n_vertices} labels to {args.output} ({args.matcher}, {seconds:.2f} s)")
        if truth is not None:
            print(f"recall {result['recall']:.4f}  precision {result['precision']:.4f}")
    return 0
