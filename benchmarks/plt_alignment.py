"""Algorithm 5 (PLT) under holes and shortcuts (issue 30 item 3): each shape matched by ``eigvec-alignment`` to a
corrupted copy of itself (``apply_corruption(shape, kind, random_state=0, strength=s)``), 8 geodesic Voronoi cells
carried to the copy by the corruption's exact vertex map, mean recall of the soft transfer of eq. 5.9 and of the
runner's hard-map metric. Variants: ``new`` (the defaults), ``thesis`` (preset), ``former`` (the defaults before
the fix: histogram alignment, holes kept, no orientation cue). Prints one line per copy and the means; the
numbers of ``benchmarks/results/plt_alignment_notes.md`` came from

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 nice python benchmarks/plt_alignment.py --variant new \\
        wolf0 wolf1 wolf2 cat0 cat1 cat2 cat3 cat4 cat5 tr_reg_010 tr_reg_020 tr_reg_030 tr_reg_040

(and ``--variant thesis``, ``--variant former``); shapes are looked up in ``$TOOLKIT_DATA/tosca5k`` and
``$TOOLKIT_DATA/faust5k``. Development was on the TOSCA dogs; the shapes above are the report half.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from shape_toolkit.api.registry import create_plugin
from shape_toolkit.data.corruptions import apply_corruption
from shape_toolkit.io.mesh import load_shape
from shape_toolkit.metrics.correspondence import label_transfer_scores, map_label_scores, truth_segments
from shape_toolkit.results.correspondence import transfer_labels

VARIANTS = {
    "new": (None, {}),
    "thesis": ("thesis", {}),
    "former": (None, {"alignment": "histogram", "holes": "keep", "side": "none"}),
}
CORRUPTIONS = (("holes", 2), ("holes", 4), ("shortcut", 1), ("shortcut", 3))


def _path(root: Path, name: str) -> Path:
    for sub in ("tosca5k", "faust5k"):
        p = root / sub / f"{name}.off"
        if p.exists():
            return p
    raise SystemExit(f"no shape {name!r} under {root}/tosca5k or {root}/faust5k")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("shapes", nargs="+", help="shape names (e.g. wolf0 tr_reg_010)")
    ap.add_argument("--variant", choices=sorted(VARIANTS), default="new")
    args = ap.parse_args()
    root = Path(os.environ.get("TOOLKIT_DATA", "../shared/data"))
    preset, params = VARIANTS[args.variant]
    means: dict[str, list[float]] = {}
    for name in args.shapes:
        src = load_shape(_path(root, name))
        ident = np.arange(src.n_vertices)
        labels, _ = truth_segments(src, src, ident, ident, 8)
        for kind, strength in CORRUPTIONS:
            tgt, vmap = apply_corruption(src, kind, random_state=0, strength=strength)
            t0 = time.perf_counter()
            corr = create_plugin("dense_matchers", "eigvec-alignment", preset, **params).match(src, tgt)
            soft = label_transfer_scores(transfer_labels(corr, labels, to="target", soft=True), labels[vmap])
            hard = map_label_scores(corr.target_of, labels, labels[vmap], tgt)
            means.setdefault(f"{kind} {strength}", []).append(soft["recall"])
            print(f"{name} {kind} {strength}: recall {soft['recall']:.3f} (runner's hard map {hard['recall']:.3f}), "
                  f"{time.perf_counter() - t0:.0f} s", flush=True)
    for key, vals in means.items():
        print(f"mean recall, {key}: {np.mean(vals):.3f} over {len(vals)} shapes")


if __name__ == "__main__":
    main()
