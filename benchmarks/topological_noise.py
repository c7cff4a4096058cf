"""Topological noise: every matching pipeline and pyFM's README pipeline, side by side, on TOSCA and
FAUST pairs whose target has glued contacts (``data.corruptions.glue``: the closest approaches
between parts welded, as a visual hull fuses touching parts) at several strengths.

    python benchmarks/topological_noise.py [--strengths 0,3,6] [--tosca 4] [--faust 4]
                                           [--methods a,b,...] [--split held-out|tuning|all]
                                           [--output benchmarks/results/topological_noise.md]
                                           [--replace]   # run --methods again, keep the others' rows
    python benchmarks/topological_noise.py --report-only   # the markdown from the saved rows

The commands that produced the saved rows (and the code, ``bench.worker.code_revision``) are kept in
``topological_noise.runs.json`` next to the rows (``--rows``), so ``--report-only`` writes them back
into the header; rows saved before that file existed take them from the header of the existing report.

Protocol:

- Pairs (A, B) from ``tosca5k/pairs.txt`` and ``faust5k/pairs.txt``. Tuning split (the pairs the
  presets' parameters were chosen on during development, never reported as results): tosca
  ``cat0-cat2``, ``cat0-cat3``, ``cat0-cat5``; faust ``tr_reg_002-tr_reg_007``,
  ``tr_reg_000-tr_reg_004``. Held-out split (reported): the other pairs, ``--tosca``/``--faust``
  of them evenly spaced in file order (so different classes / people appear).
- The target B is corrupted with ``glue(strength=s, random_state=pair index)`` (``s`` contacts,
  ``s = 0`` is the clean pair); the map A -> glued B is composed with the corruption's vertex
  map, so every error is measured on the *clean* B: geodesic distance (Dijkstra on the clean
  mesh edges) between the image and the true vertex of 200 evenly spaced ground-truth points,
  divided by sqrt(area(B)). ``sym-aware``: the smaller of the errors to the true and the
  left-right symmetric vertex. ``flipped``: mean error > 2 x sym-aware + 0.02.
- pyFM: ``pyfmaps`` 1.3.1 README quick start (WKS, K=30, w_descr=1, w_lap=0.1, w_dcomm=1,
  w_orient=1, ZoomOut nit=16 step=5), as in ``benchmarks/tosca_matching.py``.
- One process, one BLAS thread; rows are appended to ``topological_noise.jsonl`` as they come.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import re  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from tosca_matching import run_pyfm  # noqa: E402  (one copy of pyFM's README pipeline)

from shape_toolkit.data.corruptions import glue  # noqa: E402
from shape_toolkit.data.datasets import read_vts  # noqa: E402
from shape_toolkit.io.mesh import load_shape  # noqa: E402
from shape_toolkit.metrics.correspondence import DEFAULT_THRESHOLDS, error_curve, is_flipped  # noqa: E402

METHODS = ["topo-robust", "sharma2012", "seed-growing", "ovsjanikov2010", "mateus2008", "zoomout", "pyfm"]
TUNING = {
    "tosca5k": [("cat0", "cat2"), ("cat0", "cat3"), ("cat0", "cat5")],
    "faust5k": [("tr_reg_002", "tr_reg_007"), ("tr_reg_000", "tr_reg_004")],
}
#: pairs also looked at while developing the left/right side decision of issue 14 (besides TUNING);
#: kept out of TUNING so that the evenly spaced held-out selection stays the same; the report says
#: whether any reported pair is among them
DEVELOPMENT = {
    # 2026-12-02, diagnosing clean FAUST failures and trying a stronger side reference (not adopted)
    "tosca5k": [("cat1", "cat3"), ("cat2", "cat3"), ("cat2", "cat5"), ("cat4", "cat5"), ("dog0", "dog2"),
                ("dog1", "dog3"), ("wolf0", "wolf1")],
    "faust5k": [("tr_reg_004", "tr_reg_009"), ("tr_reg_021", "tr_reg_023"), ("tr_reg_031", "tr_reg_036"),
                # added while developing the symmetry check, the reference fallback and the polishing
                ("tr_reg_012", "tr_reg_015"), ("tr_reg_010", "tr_reg_019"), ("tr_reg_027", "tr_reg_029"),
                ("tr_reg_033", "tr_reg_039"),
                # 2026-12-02 (see the TOSCA list above)
                ("tr_reg_001", "tr_reg_004"), ("tr_reg_018", "tr_reg_019"), ("tr_reg_023", "tr_reg_028"),
                ("tr_reg_026", "tr_reg_029"), ("tr_reg_046", "tr_reg_049"), ("tr_reg_041", "tr_reg_049"),
                ("tr_reg_002", "tr_reg_042"), ("tr_reg_024", "tr_reg_044"), ("tr_reg_026", "tr_reg_036"),
                ("tr_reg_009", "tr_reg_039"), ("tr_reg_018", "tr_reg_044"), ("tr_reg_019", "tr_reg_048"),
                ("tr_reg_013", "tr_reg_019"), ("tr_reg_021", "tr_reg_024"), ("tr_reg_030", "tr_reg_037"),
                ("tr_reg_000", "tr_reg_020"), ("tr_reg_004", "tr_reg_034"), ("tr_reg_016", "tr_reg_032")],
}
RESULTS = REPO / "benchmarks" / "results"
N_TRUTH = 200


def data_dir() -> Path:
    return Path(os.environ.get("TOOLKIT_DATA", REPO.parent / "shared" / "data"))


def read_pairs(ds: Path) -> list[tuple[str, str]]:
    return [tuple(line.split()) for line in (ds / "pairs.txt").read_text().splitlines() if line.strip()]


def choose_pairs(dataset: str, n: int, split: str) -> list[tuple[str, str]]:
    pairs = read_pairs(data_dir() / dataset)
    tuning = set(TUNING[dataset])
    if split == "tuning":
        return [p for p in pairs if p in tuning]
    rest = [p for p in pairs if p not in tuning] if split == "held-out" else pairs
    if n >= len(rest):
        return rest
    return [rest[i] for i in np.linspace(0, len(rest) - 1, n).round().astype(int)]


def truth_rows(B, tb: np.ndarray, tbs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Dijkstra rows on the clean target from the true and symmetric vertices of the truth sample."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import dijkstra

    e, n = B.edges, B.n_vertices
    G = sp.coo_matrix((B.edge_lengths, (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    return dijkstra(G, directed=False, indices=tb), dijkstra(G, directed=False, indices=tbs)


def evaluate(method: str, A, Bg, vmap, ta, rows, rows_sym, area) -> dict:
    from shape_toolkit.pipeline import load_pipeline

    t0, c0 = time.perf_counter(), time.process_time()
    try:
        if method == "pyfm":
            t = run_pyfm(A, Bg)
        else:
            t = np.asarray(load_pipeline(method).run(A, Bg).target_of, dtype=np.int64)
    except Exception as exc:  # a failing method is a row, not a crash
        return {"error": f"{type(exc).__name__}: {exc}"}
    pred = t[ta]
    ok = pred >= 0
    clean = np.where(ok, vmap[np.maximum(pred, 0)], -1)
    idx = np.arange(len(ta))
    err = np.full(len(ta), np.inf)
    err_s = np.full(len(ta), np.inf)
    err[ok] = rows[idx[ok], clean[ok]] / np.sqrt(area)
    err_s[ok] = np.minimum(err[ok], rows_sym[idx[ok], clean[ok]] / np.sqrt(area))
    fin = np.isfinite(err)
    return {
        "mean": float(err[fin].mean()) if fin.any() else float("nan"),
        "mean_sym": float(err_s[fin].mean()) if fin.any() else float("nan"),
        "curve": error_curve(err)[1].tolist(),
        "matched": float(fin.mean()),
        "seconds": time.perf_counter() - t0,
        "cpu": time.process_time() - c0,
    }


def runs_path(rows: Path) -> Path:
    """The side file of the rows that keeps the commands that produced them."""
    return Path(rows).with_name(Path(rows).stem + ".runs.json")


def _methods_of(command: str) -> list[str]:
    words = command.split()
    return words[words.index("--methods") + 1].split(",") if "--methods" in words[:-1] else list(METHODS)


def saved_commands(args) -> dict | None:
    """``{"command": the full run, "code": ..., "reruns": [{"command", "methods", "code"}]}`` of the
    saved rows: from :func:`runs_path`, else read back from the header of the report at
    ``args.output`` (rows saved before the side file), else None."""
    try:
        return json.loads(runs_path(args.rows).read_text())
    except (OSError, ValueError):
        pass
    try:
        text = Path(args.output).read_text()
    except (OSError, UnicodeDecodeError):
        return None
    full = re.search(r"^Regenerate: `([^`]+)`", text, re.M)
    if not full:
        return None
    reruns = [{"command": c, "methods": _methods_of(c), "code": None}
              for c in re.findall(r"^Last rerun \(`--replace`[^\n]*?: `([^`]+)`\.", text, re.M)]
    return {"command": full.group(1), "code": None, "reruns": reruns}


def record_commands(args) -> dict:
    """Before a run: note its command (and the code it runs) in :func:`runs_path`. A full run
    replaces the command (``--fresh`` also drops the reruns); ``--replace`` keeps the full command
    and adds a rerun, dropping earlier reruns of no other methods."""
    from shape_toolkit.bench.worker import code_revision

    code = code_revision(REPO, paths=["shape_toolkit", "benchmarks/topological_noise.py",
                                      "benchmarks/tosca_matching.py"])  # this script and its pyFM runner
    prior = None if args.fresh else saved_commands(args)
    if args.replace:
        methods = args.methods.split(",")
        kept = [r for r in (prior or {}).get("reruns", []) if not set(r.get("methods") or METHODS) <= set(methods)]
        state = {"command": (prior or {}).get("command") or args.command, "code": (prior or {}).get("code"),
                 "reruns": kept + [{"command": args.rerun, "methods": methods, "code": code}]}
    else:
        state = {"command": args.command, "code": code, "reruns": (prior or {}).get("reruns", [])}
    path = runs_path(args.rows)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(state, indent=1) + "\n")
    return state


def header_lines(args) -> list[str]:
    """The report's lines naming the commands (and code) that produced the rows."""
    from shape_toolkit.bench.worker import revision_label

    state = saved_commands(args)
    if state is None:
        return [f"Regenerate: not recorded (rows in `{args.rows}`).", ""]

    def code(entry: dict) -> str:
        return f" Code: {revision_label(entry['code'])}." if entry.get("code") else ""

    lines = [f"Regenerate: `{state['command']}` (then `python benchmarks/topological_noise.py --report-only`)."
             + code(state)]
    reruns = state.get("reruns") or []
    what = "(`--replace`: these methods' rows replaced, the other methods' rows kept)"
    if len(reruns) == 1:
        lines.append(f"Last rerun {what}: `{reruns[0]['command']}`.{code(reruns[0])}")
    elif reruns:
        lines.append(f"Reruns {what}, in order: " + " Then ".join(f"`{r['command']}`.{code(r)}" for r in reruns))
    return lines + [""]


def run(args) -> None:
    warnings.filterwarnings("ignore")
    out = Path(args.rows)
    done = set()
    methods = args.methods.split(",")
    if out.exists() and not args.fresh:
        kept = []
        for line in out.read_text().splitlines():
            r = json.loads(line)
            if args.replace and r["method"] in methods:
                continue  # --replace: these methods run again, their saved rows go
            kept.append(line)
            done.add((r["dataset"], r["pair"], r["strength"], r["method"]))
        if args.replace:
            out.write_text("".join(x + "\n" for x in kept))
    elif out.exists():
        out.unlink()
    strengths = [int(s) for s in args.strengths.split(",")]
    jobs = [("tosca5k", p) for p in choose_pairs("tosca5k", args.tosca, args.split)]
    jobs += [("faust5k", p) for p in choose_pairs("faust5k", args.faust, args.split)]
    for pi, (ds, (a, b)) in enumerate(jobs):
        root = data_dir() / ds
        A, B = load_shape(root / f"{a}.off"), load_shape(root / f"{b}.off")
        ta_all = read_vts(root / "corres" / f"{a}.vts")
        sel = np.linspace(0, len(ta_all) - 1, N_TRUTH).round().astype(int)
        ta = ta_all[sel]
        tb = read_vts(root / "corres" / f"{b}.vts")[sel]
        tbs = read_vts(root / "corres" / f"{b}.sym.vts")[sel]
        rows, rows_sym = truth_rows(B, tb, tbs)
        for s in strengths:
            Bg, vmap = glue(B, strength=s, random_state=pi)
            for m in methods:
                key = (ds, f"{a}-{b}", s, m)
                if key in done:
                    continue
                res = evaluate(m, A, Bg, vmap, ta, rows, rows_sym, B.area)
                row = {"dataset": ds, "pair": f"{a}-{b}", "strength": s, "method": m,
                       "n_removed": int(B.n_vertices - Bg.n_vertices), "split": args.split, **res}
                with out.open("a") as fh:
                    fh.write(json.dumps(row) + "\n")
                print(f"{ds} {a}-{b} s={s} {m}: {res.get('mean', res.get('error'))}", flush=True)


def report(args) -> None:
    rows = [json.loads(x) for x in Path(args.rows).read_text().splitlines()]
    rows = [r for r in rows if "mean" in r]
    methods = [m for m in METHODS if any(r["method"] == m for r in rows)]
    strengths = sorted({r["strength"] for r in rows})
    # only (pair, strength) cells where every method ran, so means compare like with like
    cells = {}
    for r in rows:
        cells.setdefault((r["dataset"], r["pair"], r["strength"]), {})[r["method"]] = r
    complete = {k: v for k, v in cells.items() if all(m in v for m in methods)}

    def agg(ds_filter, s, m, field):
        vals = [v[m][field] for (ds, _, st), v in complete.items() if st == s and ds in ds_filter]
        return float(np.mean(vals)) if vals else float("nan")

    def flips(ds_filter, s, m):
        return sum(
            is_flipped(v[m]["mean"], v[m]["mean_sym"])
            for (ds, _, st), v in complete.items() if st == s and ds in ds_filter
        )

    lines = [
        "# Topological noise: glued contacts on the target (tosca5k, faust5k)",
        "",
        *header_lines(args),
        "Protocol: see the docstring of `benchmarks/topological_noise.py` (A -> glued B, scored on the clean B,",
        "200 ground-truth points per pair, error / sqrt(area), Dijkstra geodesics; `strength` = number of glued",
        "contacts; only held-out pairs, never those the presets were tuned on).",
        "",
    ]
    pairs = sorted({(ds, p) for (ds, p, _) in complete})
    lines.append(f"Pairs ({len(pairs)}): " + ", ".join(f"{p} ({ds[:-2]})" for ds, p in pairs))
    lines.append("")
    dev = [f"{a}-{b}" for ds in DEVELOPMENT for a, b in DEVELOPMENT[ds] + TUNING[ds]]
    overlap = sorted({p for _, p in pairs} & set(dev))
    lines += [f"Development pairs (tuning split and those looked at while developing the left/right decision, "
              f"never reported here): {', '.join(dev)}; overlap with the reported pairs: "
              f"{', '.join(overlap) if overlap else 'none'}.", ""]
    for title, dsf in (("all pairs", ("tosca5k", "faust5k")), ("tosca5k", ("tosca5k",)),
                       ("faust5k", ("faust5k",))):
        lines += [f"## Mean geodesic error, {title} (sym-aware in brackets; flipped pairs after the slash)", "",
                  "| method | " + " | ".join(f"s={s}" for s in strengths) + " |",
                  "|---|" + "---|" * len(strengths)]
        for m in methods:
            cells_txt = [f"{agg(dsf, s, m, 'mean'):.4f} ({agg(dsf, s, m, 'mean_sym'):.4f}) / {flips(dsf, s, m)}"
                         for s in strengths]
            lines.append(f"| {m} | " + " | ".join(cells_txt) + " |")
        lines.append("")
    thesis = [m for m in ("topo-robust", "sharma2012", "seed-growing") if m in methods]
    if thesis and {"zoomout", "pyfm"} <= set(methods) and strengths:
        lines += ["## Targets of issue 14 (computed from the table above)", ""]
        for title, dsf in (("all pairs", ("tosca5k", "faust5k")), ("tosca5k", ("tosca5k",)),
                           ("faust5k", ("faust5k",))):
            s_max, s0 = max(strengths), min(strengths)
            best = min(thesis, key=lambda m: agg(dsf, s_max, m, "mean"))
            b, p, z = (agg(dsf, s_max, m, "mean") for m in (best, "pyfm", "zoomout"))
            bc = min(agg(dsf, s0, m, "mean") for m in thesis)
            zc = agg(dsf, s0, "zoomout", "mean")
            ok1, ok2, ok3 = b <= 0.8 * p, b <= z, bc <= 1.2 * zc
            lines.append(
                f"- {title}: at {s_max} contacts the best thesis preset ({best}) has {b:.4f} = {b / p:.2f}x pyFM "
                f"({'met' if ok1 else 'NOT met'}: <= 0.8x) and {b / z:.2f}x zoomout "
                f"({'met' if ok2 else 'NOT met'}: <= 1x); clean (s={s0}) best thesis preset {bc:.4f} = "
                f"{bc / zc:.2f}x zoomout ({'met' if ok3 else 'NOT met'}: <= 1.2x)."
            )
        lines.append("")
    lines += [
        "## Observations (written for the 2026-12-02 runs; re-check when the numbers change)", "",
        "- Last runs of 2026-12-02 (`topo-robust` and `sharma2012` only; every other row unchanged): EM's "
        "orientation rescue (`EMRegistrationMatcher._rescue`): a map whose triple-product orientation score is "
        "still negative after the side check is usually a mirror image, and EM restarts from the side reference's "
        "map, then from a finer orientation-aware functional map (`matching.orientation.fine_matcher`), then those "
        "maps themselves; the first with a positive score wins. Decided on development pairs only (listed above): "
        "clean FAUST 0.064 -> 0.038 (14 pairs; `zoomout` 0.037 there), clean TOSCA and TOSCA at 6 contacts never "
        "triggered (16 runs), FAUST at 6 contacts +0.013 (8 pairs: 0.348 -> 0.458 on tr_reg_016-032, 0.153 -> "
        "0.149 on 030-037). A first held-out run (commit 9a7c13c) polished a functional map's map chosen by the "
        "rescue again from EM's few dimensions, which drifted back toward the mirror; a code review traced that on "
        "tr_reg_013-032 (held out: clean 0.091 -> 0.190 then). The fix (polishing goes on from the map's own "
        "resolution) has no parameter; on the development pairs where it applies it gives 0.016 / 0.057 -> "
        "0.016 / 0.048 clean and 0.443 -> 0.458 at 6 contacts.",
        "- Then (commit 7fca95d) the side check's third rule: where the reference puts a part on the other side "
        "but S is no symmetry there (`symmetry_validity` false: T(S(x)) cannot be trusted), the part takes the "
        "reference's own map R(x), as parts lost to an overlap already did (clean FAUST failure mode c below). "
        "Decided on development pairs only: clean FAUST 0.0385 -> 0.0265 (tr_reg_024-044 0.186 -> 0.018; "
        "`zoomout` 0.037), clean TOSCA cat2-cat3 0.062 -> 0.049 and cat2-cat5 0.035 -> 0.049 (6 pairs unchanged), "
        "FAUST at 6 contacts tr_reg_004-034 0.676 -> 0.144 (7 unchanged), TOSCA at 6 contacts unchanged.",
        "- Held-out effect, all pairs at 0/3/6 contacts: `topo-robust` 0.070/0.122/0.090 at the start of the day "
        "-> 0.065/0.106/0.054 with the rescue -> 0.043/0.100/0.064 with the third rule (the rows above); "
        "`sharma2012` 0.081/0.132/0.116 -> 0.074/0.134/0.109 -> 0.066/0.139/0.106. The rescue's gains: "
        "tr_reg_000-001 clean 0.087 -> 0.015 and at 3 contacts 0.086 -> 0.016, 013-032 at 6 contacts 0.162 -> "
        "0.029, 023-029 at 3 contacts 0.088 -> 0.014, cat3-cat5 at 6 contacts 0.276 -> 0.047; its losses: "
        "013-032 clean 0.091 -> 0.121 (`zoomout` 0.116), `sharma2012` on dog1-dog2 at 3 and 6 contacts. The "
        "third rule's: tr_reg_028-038 clean 0.267 -> 0.016 (the mirrored pair) and cat3-cat5 at 3 contacts "
        "0.129 -> 0.066; against it, 028-038 at 6 contacts 0.018 -> 0.118 and cat3-cat5 clean 0.043 -> 0.067.",
        "- Targets: at 6 contacts `topo-robust` is 0.52x pyFM (target 0.8x: **met**) and 0.45x `zoomout` (met); "
        "by dataset FAUST 0.41x and TOSCA 0.68x pyFM (both met). Clean: 0.043 = 0.99x `zoomout` (target 1.2x: "
        "**met**; TOSCA 0.94x, FAUST 1.06x). With 10 pairs one pair moves a mean by up to 0.03: these are real "
        "results on held-out pairs, not margins to rely on.",
        "- First run of 2026-12-02: the source's symmetry map S (`matching.orientation.symmetry_matcher`) became a "
        "finer functional map (k = 30, ZoomOut to 110 on every vertex, instead of k = 20 -> 50 on 1000 samples), "
        "chosen on development pairs (clean FAUST 0.069 -> 0.064, clean TOSCA unchanged, FAUST at 6 contacts "
        "0.257 -> 0.232); held out, `topo-robust` went 0.077/0.118/0.128 -> 0.070/0.122/0.090. The `zoomout` and "
        "pyFM rows were re-run then (`zoomout` moved from 0.054/0.084/0.137 to 0.043/0.091/0.143 since its "
        "2026-11-29 rows, through code changes in between); `mateus2008` dates from 2026-11-29.",
        "- `seed-growing` and `ovsjanikov2010` at 3 contacts: the guess of the previous run (that dropping "
        "far-out keypoint matches in `orient_pairs` left them too few seeds) is wrong on development pairs: "
        "without the drop, 5 FAUST pairs at 3 contacts go 0.305 -> 0.339 (`seed-growing`) and 0.253 -> 0.272 "
        "(`ovsjanikov2010`), 5 TOSCA pairs are unchanged; the drop stays.",
        "- Clean FAUST failures diagnosed on development pairs (2026-12-02, before the rescue; 14 FAUST pairs "
        "outside the reported ones, with the coarse S of before: `topo-robust` 0.069 against `zoomout` 0.037; "
        "the rescue now undoes (a) and (b), both of which score negative on the whole, and the side check's "
        "third rule (c)): (a) the side "
        "reference is itself mirrored, so EM run again from the 'corrected' map converges to the full mirror "
        "(tr_reg_046-049, 0.30); (b) a limb mapped front-to-back onto the right limb: 11 % of the points, "
        "invisible to the low-frequency reference (neither `disagrees` nor `overlaps` fires; tr_reg_009-039, "
        "0.086); (c) S valid on only 74 % of the area, so a mirrored region cannot take T(S(x)) "
        "(tr_reg_024-044, 0.25). Tried and NOT adopted: the full-strength `fmap-zoomout` (k = 30, ZoomOut to 110 "
        "on every vertex) as the side reference instead of k = 20 -> 50 on 1000 samples: clean FAUST 0.069 -> "
        "0.044 (fixes a and most of c), but clean TOSCA (8 development pairs) 0.028 -> 0.039 and FAUST at 6 "
        "contacts (8 development pairs) 0.257 -> 0.290; it costs about 1 s more per pair.",
        "- Under glue, the keypoints themselves change (ADF maxima of glued hands disappear), so the sparse stage "
        "degrades before the local descriptors can help; thesis 7.4 relies on texture (photometric) seeds for "
        "exactly this reason, which these datasets do not have.",
        "",
    ]
    th = DEFAULT_THRESHOLDS
    show = [2, 5, 10, 25]
    lines += ["## Cumulative error curves per strength (fraction of points with error <= x), all pairs", ""]
    for s in strengths:
        lines += [f"strength {s}:", "", "| method | " + " | ".join(f"<= {th[i]:.2f}" for i in show) + " | CPU s/pair |",
                  "|---|" + "---|" * (len(show) + 1)]
        for m in methods:
            curves = [v[m]["curve"] for (ds, _, st), v in complete.items() if st == s]
            cpu = [v[m]["cpu"] for (ds, _, st), v in complete.items() if st == s]
            if not curves:
                continue
            c = np.mean(curves, axis=0)
            lines.append(f"| {m} | " + " | ".join(f"{c[i]:.3f}" for i in show) + f" | {np.mean(cpu):.1f} |")
        lines.append("")
    failed = [r for r in (json.loads(x) for x in Path(args.rows).read_text().splitlines())
              if "error" in r]
    if failed:
        lines += ["## Failures", ""] + [f"- {r['method']} on {r['pair']} s={r['strength']}: {r['error']}"
                                        for r in failed] + [""]
    Path(args.output).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def parse_args(argv: list[str]) -> argparse.Namespace:
    """The options, plus ``command`` (the full run: ``--methods`` dropped for ``--replace``) and
    ``rerun`` (the ``--replace`` command as given, else empty)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--strengths", default="0,3,6")
    ap.add_argument("--tosca", type=int, default=4)
    ap.add_argument("--faust", type=int, default=4)
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--split", default="held-out", choices=["held-out", "tuning", "all"])
    ap.add_argument("--output", default=str(RESULTS / "topological_noise.md"))
    ap.add_argument("--fresh", action="store_true", help="discard saved rows")
    ap.add_argument("--replace", action="store_true",
                    help="discard the saved rows of --methods only and run them again (the others are kept)")
    ap.add_argument("--rows", default=str(RESULTS / "topological_noise.jsonl"),
                    help="the saved rows (JSON lines); the commands go to a .runs.json beside them")
    ap.add_argument("--report-only", action="store_true")
    args = ap.parse_args(argv)
    rerun_argv = [a for a in argv if a != "--report-only"]
    argv = [a for a in argv if a not in ("--report-only", "--fresh", "--replace")]
    args.rerun = "python benchmarks/topological_noise.py " + " ".join(rerun_argv) if args.replace else ""
    if args.replace and "--methods" in argv:  # the full command, every method
        i = argv.index("--methods")
        del argv[i : i + 2]
    args.command = " ".join(["python benchmarks/topological_noise.py", *argv])
    return args


def main() -> None:
    args = parse_args(sys.argv[1:])
    if not args.report_only:
        record_commands(args)
        run(args)
    report(args)


if __name__ == "__main__":
    main()
