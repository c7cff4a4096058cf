"""``shape-toolkit demo``: the toolkit on generated articulated shapes, offline.

Writes into ``-o`` (default ``./shape-toolkit-demo``): the shape, its spectrum, ``spectrum.png``
(eigenvalues), ``eigenvectors.png`` (eigenvectors on the shape, with colour bars), ``match.png``
(the ``zoomout`` pipeline between two poses shown by pull-back colour transfer, with its error
against the exact ground truth) and coloured PLY files; then a small benchmark with its HTML report.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from shape_toolkit.cli.commands._common import (
    add_quiet,
    check_applies,
    int_arg,
    local_workers_arg,
    random_state_arg,
    status,
)
from shape_toolkit.core.spectrum import compute_spectrum
from shape_toolkit.data.synthetic import articulated_shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.features.embedding import choose_dimension
from shape_toolkit.io.mesh import save_shape
from shape_toolkit.spectra import build_graph

#: the fewest eigenpairs: ``eigenvectors.png`` draws eigenvectors 1, 2 and 3 (fewer raised an IndexError)
MIN_K = 4


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the toolkit on a generated articulated shape")
    p.add_argument("-o", "--output", default="shape-toolkit-demo", help="output folder")
    p.add_argument("-k", type=int_arg(f"an integer >= {MIN_K}", MIN_K), default=30,
                   help=f"number of eigenpairs (default 30; at least {MIN_K}: eigenvectors 1-3 are drawn)")
    p.add_argument("--random-state", type=random_state_arg, default=0, help="seed of the generated pose")
    p.add_argument("--workers", type=local_workers_arg, default=None,
                   help="parallel workers of the showcase benchmark (default 1; at most 4 per core, 8 always)")
    p.add_argument(
        "--no-bench",
        action="store_true",
        help="skip the end-to-end benchmark showcase (spectrum and matching figures only)",
    )
    add_quiet(p)
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
                "corruptions": ["none", "holes"],
                "metrics": ["geodesic_error", "label_transfer", "coverage"],
                "options": {"geodesic_method": "dijkstra", "truth_sample": 300},
                "methods": [{"pipeline": "zoomout"}],
            },
        ],
    }


def _showcase(out: Path, random_state: int, workers: int, quiet: bool) -> dict:
    from shape_toolkit.bench.config import parse_config
    from shape_toolkit.bench.report import write_report
    from shape_toolkit.bench.runner import run_benchmark

    cfg = parse_config(showcase_config(random_state), base=out)
    summary = run_benchmark(cfg, out / "bench", workers=workers, progress=not quiet)
    say = None if quiet else (lambda msg: print(f"report: {msg}", file=sys.stderr, flush=True))
    report = write_report(out / "bench", renders=2, progress=say)
    return {
        "rows": summary.rows,
        "failed": summary.failed,
        "reused": summary.reused,
        "report": str(report["html"]),
        "results": str(out / "bench" / "results.jsonl"),
    }


def _spectrum_figures(shape, spec, out: Path) -> list[str]:
    """``spectrum.png`` (eigenvalues against their index) and ``eigenvectors.png`` (eigenvectors 2-4
    on the shape, diverging colours symmetric about 0, with colour bars), each also as PDF."""
    from shape_toolkit.viz import _mpl, render_shapes

    _, plt = _mpl()
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(np.arange(spec.k), spec.eigenvalues, "o-", ms=4)
    ax.set_xlabel("eigenvalue index i (0 = constant eigenvector)", fontsize=11)
    ax.set_ylabel("eigenvalue lambda_i (1 / length^2)", fontsize=11)
    ax.set_title(f"{spec.weighting} Laplacian spectrum of the generated shape ({shape.n_vertices} vertices)",
                 fontsize=11)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "spectrum.png", dpi=120)
    fig.savefig(out / "spectrum.pdf", metadata={"CreationDate": None})
    plt.close(fig)
    panels = []
    for j in (1, 2, 3):
        u = spec.eigenvectors[:, j]
        lim = float(np.abs(u).max())
        title = f"eigenvector {j}, lambda = {spec.eigenvalues[j]:.3g}"
        panels.append({"shape": shape, "scalars": u, "cmap": "coolwarm", "vmin": -lim, "vmax": lim,
                       "colorbar": f"eigenvector {j} value", "title": title})
    render_shapes(panels, out / "eigenvectors.png", panel_size=4.0, dpi=110, pdf=True,
                  title="Laplacian eigenvectors on the shape (blue < 0 < red)")
    return ["spectrum.png", "spectrum.pdf", "eigenvectors.png", "eigenvectors.pdf"]


def _match_demo(out: Path, random_state: int, args: argparse.Namespace) -> dict:
    """The strongest pipeline (``zoomout``) between two generated poses, with the pull-back colour
    render ``match.png``, coloured PLY files and its error against the exact ground truth."""
    from shape_toolkit.pipeline import load_pipeline
    from shape_toolkit.viz import pullback_colors, render_shapes, save_colored_ply

    a = articulated_shape(subdivisions=3, random_state=random_state + 1)
    b = articulated_shape(subdivisions=3, random_state=random_state + 2)
    # The five limbs are intrinsically alike, so an intrinsic map may permute them: one seed match
    # per limb tip (known here: every pose keeps the vertex order) fixes which limb is which.
    v = a.shape.vertices
    centre = v[a.labels == 0].mean(axis=0)
    tips = [int(ids[np.argmax(np.linalg.norm(v[ids] - centre, axis=1))])
            for ids in (np.flatnonzero(a.labels == lab) for lab in np.unique(a.labels) if lab > 0)]
    seeds = np.column_stack([tips, tips]).astype(np.int64)
    pipe = load_pipeline("zoomout")
    t0 = time.perf_counter()
    with status(args, "zoomout: matching two poses") as st:
        corr = pipe.run(a.shape, b.shape, seeds, progress=st.update)
        seconds = time.perf_counter() - t0
        # same mesh connectivity in every pose: the true map is the identity
        truth = np.arange(a.shape.n_vertices)
        ok = corr.target_of >= 0
        d = np.linalg.norm(b.shape.vertices[corr.target_of[ok]] - b.shape.vertices[truth[ok]], axis=1)
        err = float(d.mean() / np.sqrt(b.shape.area))
        st.update("demo: drawing match.png")
        cs, ct = pullback_colors(a.shape, b.shape, corr.target_of)
        render_shapes(
            [{"shape": b.shape, "colors": ct, "title": "target: colour = position"},
             {"shape": a.shape, "colors": cs, "title": "source: target colours pulled back through the map"}],
            out / "match.png", panel_size=4.5, dpi=110, pdf=True,
            title=f"zoomout pipeline with {len(tips)} limb-tip seeds, pull-back colour transfer "
                  f"(mean error {err:.3f} sqrt(area), lower is better)",
        )
        save_colored_ply(a.shape, out / "match.source.ply", cs)
        save_colored_ply(b.shape, out / "match.target.ply", ct)
    return {"pipeline": "zoomout", "n_seeds": len(tips), "mean_error_euclidean_sqrt_area": round(err, 4),
            "seconds": round(seconds, 2),
            "figure": "match.png", "figure_pdf": "match.pdf", "ply": ["match.source.ply", "match.target.ply"]}


def run(args: argparse.Namespace) -> int:
    check_applies("--workers", args.workers is not None, "the benchmark showcase", not args.no_bench,
                  ", which --no-bench skips")
    out = Path(args.output).resolve()
    if out.exists() and not out.is_dir():
        raise ParameterError(f"--output {args.output!r} is a file; the demo writes a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ParameterError(f"--output: cannot create the folder {args.output!r}: {exc.strerror or exc}") from None
    t0 = time.perf_counter()
    with status(args, "demo: generating an articulated shape") as st:
        gen = articulated_shape(random_state=args.random_state)
        shape = gen.shape.with_colors(gen.colors)  # its procedural texture: shape.off is written as COFF
        save_shape(shape, out / "shape.off")
        st.update(f"demo: spectrum, {args.k} eigenpairs of {shape.n_vertices} vertices")
        graph = build_graph(shape, "cotangent")
        spec = compute_spectrum(graph, args.k, sign_fix=True)
        spec.save(out / "spectrum.npz")
        st.update("demo: drawing spectrum.png and eigenvectors.png")
        figures = _spectrum_figures(shape, spec, out)
    print(f"shape: {shape!r}")
    print(f"first eigenvalues: {np.array2string(spec.eigenvalues[:6], precision=4)}")
    match = _match_demo(out, args.random_state, args)
    figures += [match["figure"], match["figure_pdf"]]
    print(f"zoomout matching of two poses: mean error {match['mean_error_euclidean_sqrt_area']:.4f} "
          f"(sqrt-area units, lower is better) in {match['seconds']:.1f} s -> {out / 'match.png'}, "
          f"{out / 'match.source.ply'}")
    summary = {
        "shape": {"n_vertices": shape.n_vertices, "n_faces": shape.n_faces, "generator": "articulated"},
        "weighting": "cotangent",
        "eigenvalues": spec.eigenvalues.tolist(),
        "embedding_dimension_theta_0.95": _safe_dim(spec),
        "figures": figures,
        "match": match,
    }
    if not args.no_bench:
        print("benchmark showcase: spectra, keypoints, segmentation, matching on generated poses ...")
        summary["benchmark"] = _showcase(out, args.random_state, args.workers or 1, args.quiet)
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
