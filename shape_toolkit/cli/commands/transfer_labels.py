"""``shape-toolkit transfer-labels TRAIN TRAIN_LABELS TEST [-o labels.txt]``: probabilistic label
transfer (Algorithm 5) from a segmented shape to another. Labels are per vertex, or per face with
``--faces`` (PSB ``.seg``: read, converted, and written per face). Default output:
``TEST_STEM.labels.txt`` (``TEST_STEM.seg`` with ``--faces``) in the current directory. Shapes above 1.5
``--proxy`` vertices are labelled through proxies
(:func:`~shape_toolkit.plugins.matching.multires.transfer_labels_through_proxies`)."""

from __future__ import annotations

import argparse
import time

import numpy as np

from shape_toolkit.cli.commands._common import (
    add_memory_limit,
    add_ply,
    add_quiet,
    check_distinct,
    check_memory,
    check_output_path,
    check_ply,
    default_output,
    parse_params,
    plugin_class,
    print_json,
    proxy_arg,
    read_labels_arg,
    status,
    write_ply,
)
from shape_toolkit.data.datasets import write_labels
from shape_toolkit.io.mesh import load_shape
from shape_toolkit.plugins.matching.multires import (
    PROXY_VERTICES,
    label_transfer_memory,
    transfer_labels_through_proxies,
)
from shape_toolkit.results.correspondence import read_seeds
from shape_toolkit.results.label_transfer import probabilistic_label_transfer
from shape_toolkit.results.labels import vertex_to_face_labels


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("transfer-labels", help="transfer vertex labels of a segmented shape to another")
    p.add_argument("train", help="segmented (training) shape")
    p.add_argument("train_labels", help="one integer label per train vertex (per face with --faces)")
    p.add_argument("test", help="shape to label")
    p.add_argument("-o", "--output", help="write one label per test vertex (face with --faces) here "
                   "(default TEST_STEM.labels.txt, or TEST_STEM.seg with --faces)")
    p.add_argument("--faces", action="store_true",
                   help="label files hold one label per face (PSB .seg): TRAIN_LABELS, --truth and the output")
    p.add_argument("--matcher", default="eigvec-alignment",
                   help="dense matcher (default eigvec-alignment: eigenvector alignment + EM; its preset "
                   "thesis is Algorithm 5 as written)")
    p.add_argument("--preset", default=None, help="preset of the matcher")
    p.add_argument("--param", action="append", metavar="KEY=VALUE", help="matcher parameter")
    p.add_argument("--seeds", help="seed matches 'train test' (0-based) per line, e.g. for em-registration")
    p.add_argument("--truth", help="ground-truth test labels: report recall and precision")
    p.add_argument("--proxy", type=proxy_arg, default=PROXY_VERTICES, metavar="N",
                   help=f"shapes above 1.5 N vertices are labelled through proxies of N vertices, each test vertex "
                        f"taking its nearest proxy vertex's label (N >= 100; default {PROXY_VERTICES}; 0: always at "
                        "full resolution)")
    add_ply(p, "the transferred labels")
    p.add_argument("--json", action="store_true", help="print JSON")
    add_memory_limit(p)
    add_quiet(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    output = default_output(args.output, args.test, "seg" if args.faces else "labels.txt")
    check_output_path(output)
    check_distinct(output, args.train, args.train_labels, args.test, args.truth, args.seeds)
    check_ply(args.ply, args.train, args.train_labels, args.test, args.truth, args.seeds, output=str(output))
    params = parse_params(args.param, plugin_class("dense_matchers", args.matcher))
    check_memory(args, [args.train, args.test], lambda n: label_transfer_memory(n, args.proxy),
                 "transferring the labels" if args.proxy else "transferring the labels at full resolution (--proxy 0)",
                 "memory_models.md")
    train = load_shape(args.train)
    test = load_shape(args.test)
    if args.faces:
        test.require_faces("--faces")
    labels = read_labels_arg(args.train_labels, train, args.faces, "TRAIN_LABELS")
    truth = read_labels_arg(args.truth, test, args.faces, "--truth") if args.truth else None
    seeds = read_seeds(args.seeds, train.n_vertices, test.n_vertices) if args.seeds else None
    t0 = time.perf_counter()
    with status(args, f"transfer-labels: {args.matcher} {train.n_vertices} -> {test.n_vertices} vertices"):
        how = {"matcher": args.matcher, "matcher_params": params, "preset": args.preset, "seeds": seeds}
        if args.proxy and max(train.n_vertices, test.n_vertices) > 1.5 * args.proxy:
            out, corr = transfer_labels_through_proxies(train, labels, test, args.proxy, **how)
        else:
            out, corr = probabilistic_label_transfer(train, labels, test, **how)
    seconds = time.perf_counter() - t0
    write_labels(output, vertex_to_face_labels(test.faces, out) if args.faces else out)
    from shape_toolkit.viz import label_colors

    ply = write_ply(args.ply, test, label_colors(out))
    values, counts = np.unique(out, return_counts=True)
    result = {
        "labels_file": str(output),
        "per": "face" if args.faces else "vertex",
        "ply": ply,
        "n_vertices": test.n_vertices,
        "n_unlabelled": int(np.sum(out < 0)),
        "label_counts": {str(int(v)): int(c) for v, c in zip(values, counts)},
        "matcher": args.matcher,
        "soft": corr.posteriors is not None,
        "proxy": ({k: v for k, v in corr.info["proxy"].items() if not k.endswith("_ids")}
                  | {"proxy_vertices": [len(corr.info["proxy"]["train_ids"]), len(corr.info["proxy"]["test_ids"])]}
                  if "proxy" in corr.info else None),
        "seconds": round(seconds, 3),
    }
    if truth is not None:
        from shape_toolkit.metrics.correspondence import label_transfer_scores

        s = label_transfer_scores(out, truth)
        result.update(recall=s["recall"], precision=s["precision"])
    if args.json:
        print_json(result)
    else:
        n = test.n_faces if args.faces else test.n_vertices
        print(f"wrote {n} {'face' if args.faces else 'vertex'} labels to {output} ({args.matcher}, {seconds:.2f} s)")
        if truth is not None:
            print(f"recall {result['recall']:.4f}  precision {result['precision']:.4f}")
    return 0
