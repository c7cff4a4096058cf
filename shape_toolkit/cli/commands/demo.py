"""``shape-toolkit demo``: the toolkit on a generated articulated shape, offline."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from shape_toolkit.cli.commands._common import positive_int_arg, random_state_arg
from shape_toolkit.core.graph import build_graph
from shape_toolkit.core.spectrum import compute_spectrum
from shape_toolkit.data.synthetic import articulated_shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.features.embedding import choose_dimension, commute_time_embedding
from shape_toolkit.io.mesh import save_shape


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the toolkit on a generated articulated shape")
    p.add_argument("-o", "--output", default="shape-toolkit-demo", help="output folder")
    p.add_argument("-k", type=positive_int_arg, default=30, help="number of eigenpairs (default 30)")
    p.add_argument("--random-state", type=random_state_arg, default=0, help="seed of the generated pose")
    p.add_argument("--workers", type=positive_int_arg, default=1, help="parallel workers of the showcase benchmark")
    p.add_argument(
        "--no-bench",
        action="store_true",
        help="skip the end-to-end benchmark showcase (spectrum figures only)",
    )
    p.set_defaults(func=run)


def showcase_config(random_state: int = 0) -> dict:
    """The demo benchmark: generated poses; spectra, keypoints, segmentation and matching
    (label transfer under corruptions), compared across plugins (a parsed-TOML dict)."""
    return {
        "run": {"name": "shape-toolkit-demo", "random_state": random_state},
        "datasets": [
            {
                "name": "articulated",
                "kind": "synthetic",
                "params": {"n_poses": 3, "subdivisions": 3, "random_state": random_state},
            }
        ],
        "corruptions": [
            {"name": "noise", "kind": "gaussian-noise", "params": {"strength": [0.15, 0.4]}},
            {"name": "holes", "kind": "holes", "params": {"strength": [3]}},
        ],
        "tasks": [
            {
                "task": "spectrum",
                "spectrum": {"k": 30},
                "metrics": ["eigenvalues", "lambda2"],
                "methods": [{"plugin": "gaussian"}, {"plugin": "cotangent"}],
            },
            {
                "task": "keypoints",
                "metrics": ["n_keypoints", "repeatability"],
                "methods": [{"plugin": "adf-maxima", "preset": "sparse"}],
            },
            {
                "task": "segmentation",
                "corruptions": ["none", "noise"],
                "metrics": ["n_segments", "segmentation"],
                "methods": [
                    {"plugin": "eigvec-gmm", "params": {"n_segments": 6}},
                    {
                        "plugin": "spectral-clustering",
                        "preset": "luxburg-unnormalized",
                        "params": {"n_segments": 6},
                    },
                ],
            },
            {
                "task": "matching",
                "corruptions": ["none", "noise", "holes"],
                "metrics": ["geodesic_error", "label_transfer", "coverage"],
                "options": {"geodesic_method": "dijkstra", "truth_sample": 300},
                "methods": [{"plugin": "eigvec-alignment"}],
            },
        ],
    }


def _showcase(out: Path, random_state: int, workers: int) -> dict:
    from shape_toolkit.bench.config import parse_config
    from shape_toolkit.bench.report import write_report
    from shape_toolkit.bench.runner import run_benchmark

    cfg = parse_config(showcase_config(random_state), base=out)
    summary = run_benchmark(cfg, out / "bench", workers=workers)
    report = write_report(out / "bench")
    return {
        "rows": summary.rows,
        "failed": summary.failed,
        "reused": summary.reused,
        "report": str(report["html"]),
        "results": str(out / "bench" / "results.jsonl"),
    }


def _plot(shape, spec, emb, out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    fig = plt.figure(figsize=(12, 4))
    v = shape.vertices
    for i, j in enumerate((1, 2)):
        ax = fig.add_subplot(1, 3, i + 1, projection="3d")
        u = spec.eigenvectors[:, j]
        lim = np.abs(u).max()
        ax.scatter(v[:, 0], v[:, 1], v[:, 2], c=u, cmap="coolwarm", vmin=-lim, vmax=lim, s=2)
        ax.set_title(f"eigenvector {j + 1} (lambda = {spec.eigenvalues[j]:.3g})")
        ax.set_axis_off()
        ax.view_init(elev=15, azim=-70)
    ax = fig.add_subplot(1, 3, 3, projection="3d")
    ax.scatter(emb[:, 0], emb[:, 1], emb[:, 2], c=v[:, 1], cmap="viridis", s=2)
    ax.set_title("commute-time embedding (first 3 dims)")
    fig.tight_layout()
    fig.savefig(out / "embedding.png", dpi=110)
    plt.close(fig)
    written.append("embedding.png")

    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.plot(np.arange(1, spec.k + 1), spec.eigenvalues, "o-", ms=3)
    ax.set_xlabel("index")
    ax.set_ylabel("eigenvalue")
    ax.set_title(f"{spec.weighting} Laplacian spectrum")
    fig.tight_layout()
    fig.savefig(out / "spectrum.png", dpi=110)
    plt.close(fig)
    written.append("spectrum.png")
    return written


def run(args: argparse.Namespace) -> int:
    out = Path(args.output).resolve()
    if out.exists() and not out.is_dir():
        raise ParameterError(f"--output {args.output!r} is a file; the demo writes a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ParameterError(f"--output: cannot create the folder {args.output!r}: {exc.strerror or exc}") from None
    t0 = time.perf_counter()
    gen = articulated_shape(random_state=args.random_state)
    shape = gen.shape
    save_shape(shape, out / "shape.off")
    graph = build_graph(shape, "cotangent")
    spec = compute_spectrum(graph, args.k, sign_fix=True)
    spec.save(out / "spectrum.npz")
    emb = commute_time_embedding(spec, 3)
    figures = _plot(shape, spec, emb, out)
    summary = {
        "shape": {"n_vertices": shape.n_vertices, "n_faces": shape.n_faces, "generator": "articulated"},
        "weighting": "cotangent",
        "eigenvalues": spec.eigenvalues.tolist(),
        "embedding_dimension_theta_0.95": _safe_dim(spec),
        "figures": figures,
    }
    print(f"shape: {shape!r}")
    print(f"first eigenvalues: {np.array2string(spec.eigenvalues[:6], precision=4)}")
    if not args.no_bench:
        print("benchmark showcase: spectra, keypoints, segmentation, matching on generated poses ...")
        summary["benchmark"] = _showcase(out, args.random_state, args.workers)
        b = summary["benchmark"]
        print(f"{b['rows'] + b['reused']} result rows ({b['failed']} failed): {b['results']}")
        print(f"report: {b['report']}")
    summary["seconds"] = round(time.perf_counter() - t0, 2)
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(f"results written to {out}")
    return 0


def _safe_dim(spec) -> int | None:
    try:
        return choose_dimension(spec)
    except ParameterError:
        return None
