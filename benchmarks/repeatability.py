"""Keypoint repeatability of adf-maxima and harris3d (Table 6.1 presets) on the tosca5k pairs.

    python benchmarks/repeatability.py [--data DIR] [--limit N] [--output FILE]

Reads ``$TOOLKIT_DATA`` (else ``../shared/data`` next to the repository), detects keypoints on
every shape of the 24 test pairs with both detectors and both presets, and measures, for each
pair, the fraction of A's keypoints whose ground-truth image lies within geodesic radius
``r * sqrt(area_B)`` of a keypoint of B (and the reverse), next to the chance level (area fraction
covered by the keypoints' r-balls). Writes ``benchmarks/results/repeatability.md`` with the
verdict on the thesis's claim (section 6.6.2) that ADF maxima at large scales are the more
repeatable sparse detector.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from shape_toolkit.api.registry import create_plugin  # noqa: E402
from shape_toolkit.data.datasets import read_vts  # noqa: E402
from shape_toolkit.io.mesh import load_shape  # noqa: E402
from shape_toolkit.metrics.keypoints import ground_truth_map, repeatability_report  # noqa: E402
from shape_toolkit.spectra import shape_spectrum  # noqa: E402

RADII = (0.025, 0.05, 0.1)
SETUPS = [
    ("adf-maxima", "sparse"), ("harris3d", "sparse"), ("harris3d", "sparse-count"),
    ("adf-maxima", "dense"), ("harris3d", "dense"),
    ("adf-maxima", "thesis-sparse"), ("adf-maxima", "thesis-dense"),
]
# "sparse-count": Harris3D's strongest ring maxima, as many as sparse ADF found on that shape
# (removes the keypoint-count difference between the two sparse setups)


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=None, help="data directory (default $TOOLKIT_DATA or ../shared/data)")
    ap.add_argument("--limit", type=int, default=None, help="only the first N pairs")
    ap.add_argument("--method", default="fmm", help="geodesic method (default fmm)")
    ap.add_argument("--output", default=str(REPO / "benchmarks" / "results" / "repeatability.md"))
    args = ap.parse_args(argv)
    data = Path(args.data or os.environ.get("TOOLKIT_DATA") or REPO.parent / "shared" / "data")
    root = data / "tosca5k"
    if not (root / "pairs.txt").is_file():
        print(f"repeatability: no tosca5k data under {data} (set TOOLKIT_DATA)", file=sys.stderr)
        return 2
    pairs = [ln.split() for ln in (root / "pairs.txt").read_text().splitlines() if ln.strip()]
    if args.limit:
        pairs = pairs[: args.limit]
    names = sorted({n for p in pairs for n in p})
    t0 = time.perf_counter()
    shapes, vts, keypoints, timing = {}, {}, {}, {s: 0.0 for s in SETUPS}
    for i, name in enumerate(names):
        shape = load_shape(root / f"{name}.off")
        shapes[name] = shape
        vts[name] = read_vts(root / "corres" / f"{name}.vts", shape.n_vertices)
        tic = time.perf_counter()
        spec = shape_spectrum(shape, 51, kind="graph")  # K = 50 non-null covers both ADF presets
        t_spec = time.perf_counter() - tic
        harris = create_plugin("keypoints", "harris3d", preset="sparse")
        tic = time.perf_counter()
        resp = harris.response(shape)
        t_resp = time.perf_counter() - tic
        for det, preset in SETUPS:
            plugin = create_plugin("keypoints", det, preset=preset.replace("-count", ""))
            tic = time.perf_counter()
            if preset == "sparse-count":
                n_adf = len(keypoints[(name, "adf-maxima", "sparse")])
                plugin.set_params(selection_param=n_adf / shape.n_vertices)
                kp = plugin.select(shape, resp)[:n_adf]
                timing[(det, preset)] += time.perf_counter() - tic + t_resp
            elif det == "harris3d":
                kp = plugin.select(shape, resp)
                timing[(det, preset)] += time.perf_counter() - tic + t_resp
            else:
                kp = plugin.detect(shape, spectrum=spec)
                timing[(det, preset)] += time.perf_counter() - tic + t_spec
            keypoints[(name, det, preset)] = kp
        log(f"[{i + 1}/{len(names)}] {name}: {shape.n_vertices} vertices, spectrum {t_spec:.1f}s, "
            + ", ".join(f"{d}/{p}: {len(keypoints[(name, d, p)])}" for d, p in SETUPS))
    rows = {s: [] for s in SETUPS}
    for a, b in pairs:
        sa, sb = shapes[a], shapes[b]
        m_ab = ground_truth_map(sa, vts[a], vts[b], sb.n_vertices)
        m_ba = ground_truth_map(sb, vts[b], vts[a], sa.n_vertices)
        for s in SETUPS:
            rep = repeatability_report(
                sa, sb, keypoints[(a, *s)], keypoints[(b, *s)], m_ab, m_ba, RADII, method=args.method
            )
            rows[s].append((a, b, rep))
    elapsed = time.perf_counter() - t0
    text = render(rows, pairs, names, timing, elapsed, args)
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    Path(args.output).write_text(text)
    log(f"wrote {args.output} in {elapsed:.0f}s")
    print(text)
    return 0


def _mean(rows: list, key: str) -> np.ndarray:
    return np.nanmean(np.array([r[2][key] for r in rows], dtype=np.float64), axis=0)


def render(rows: dict, pairs: list, names: list, timing: dict, elapsed: float, args) -> str:
    ri = RADII.index(0.05)
    out = [
        "# Keypoint repeatability on tosca5k (adf-maxima vs harris3d)",
        "",
        "Regenerate: `python benchmarks/repeatability.py` (data from `$TOOLKIT_DATA` or `../shared/data`).",
        "",
        f"Pairs: {len(pairs)} ({len(names)} shapes, about 5,000 vertices each, independently remeshed). "
        f"Geodesics: `{args.method}`. Spectrum for ADF: 51 eigenpairs of the combinatorial Laplacian of "
        "the Gaussian-weighted mesh graph (bandwidth = mean edge length), as in the thesis.",
        "ADF presets: the scale-free defaults, sparse `t = 1 / lambda_1, K=10, ring=2` and dense "
        "`t = 4 ln 10 / lambda_K, K=50, ring=2` (times in units of the shape's own spectrum), and the thesis's "
        "Table 6.1 literally, `thesis-sparse` `t=500, K=10, ring=2` and `thesis-dense` `t=50, K=50, ring=2` "
        "(absolute times). Harris3D (Table 6.1): adaptive neighbourhood 0.01 x diagonal, k=0.04, ring=2, "
        "sparse = fraction 0.001 of "
        "the vertices, dense = clustering with spacing 0.001 x diagonal; `sparse-count` is Harris3D "
        "keeping as many of its strongest ring maxima as sparse ADF found on the same shape.",
        "",
        "Repeatability at radius r: fraction of A's keypoints whose ground-truth image on B lies within "
        "geodesic distance r x sqrt(area B) of a keypoint of B, averaged over both directions and over the "
        "pairs. *Chance* is the area fraction covered by the r-balls around the keypoints: the score of "
        "randomly placed points. *Excess* = repeatability - chance.",
        "",
        "| detector | preset | keypoints / shape | " + " | ".join(f"rep. r={r}" for r in RADII)
        + " | " + " | ".join(f"chance r={r}" for r in RADII) + " | excess r=0.05 | time / shape (s) |",
        "|---|---|---|" + "---|" * (2 * len(RADII)) + "---|---|",
    ]
    summary = {}
    for s in SETUPS:
        rs = rows[s]
        rep, ch = _mean(rs, "mean"), _mean(rs, "chance")
        nk = np.mean([0.5 * (r[2]["n_keypoints_a"] + r[2]["n_keypoints_b"]) for r in rs])
        summary[s] = (rep, ch, nk)
        out.append(
            f"| {s[0]} | {s[1]} | {nk:.1f} | " + " | ".join(f"{x:.3f}" for x in rep) + " | "
            + " | ".join(f"{x:.3f}" for x in ch) + f" | {rep[ri] - ch[ri]:+.3f} | "
            f"{timing[s] / len(names):.1f} |"
        )
    a_rep, a_ch, a_n = summary[("adf-maxima", "sparse")]
    h_rep, h_ch, h_n = summary[("harris3d", "sparse")]
    wins = sum(
        1 for (ra, rh) in zip(rows[("adf-maxima", "sparse")], rows[("harris3d", "sparse")])
        if ra[2]["mean"][ri] > rh[2]["mean"][ri]
    )
    confirmed = a_rep[ri] > h_rep[ri] and (a_rep[ri] - a_ch[ri]) > (h_rep[ri] - h_ch[ri])
    verdict = "CONFIRMED" if confirmed else "REFUTED"
    out += [
        "",
        f"## Verdict: the thesis's claim is {verdict} on this data",
        "",
        f"Claim (section 6.6.2, Fig. 6.7): ADF maxima at large time scales are a more repeatable sparse "
        f"detector than Harris3D. At r = 0.05, sparse ADF maxima reach {a_rep[ri]:.3f} "
        f"(chance {a_ch[ri]:.3f}, {a_n:.1f} keypoints per shape) against {h_rep[ri]:.3f} for sparse "
        f"Harris3D (chance {h_ch[ri]:.3f}, {h_n:.1f} keypoints); ADF is better on {wins} of "
        f"{len(pairs)} pairs. The claim counts as confirmed only if ADF wins both in raw "
        "repeatability and in excess over chance (more keypoints inflate raw repeatability).",
        "",
        "## Per pair (mean of both directions, r = 0.05)",
        "",
        "| A | B | " + " | ".join(f"{d} {p}" for d, p in SETUPS) + " |",
        "|---|---|" + "---|" * len(SETUPS),
    ]
    for i, (a, b) in enumerate(pairs):
        out.append(f"| {a} | {b} | " + " | ".join(f"{rows[s][i][2]['mean'][ri]:.2f}" for s in SETUPS) + " |")
    out += ["", f"Total run time: {elapsed:.0f} s on this machine.", ""]
    return "\n".join(out)


if __name__ == "__main__":
    raise SystemExit(main())
