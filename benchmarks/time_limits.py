"""Every computing command stops within its ``--time-limit`` plus 5 s (issue 27), measured.

Runs each command as a user would (a subprocess) on a 164k-vertex sphere with ``--time-limit 2``
and records the exit code, the wall time from launch to exit (Python start-up included) and the
one stderr line; ``bench run`` gets ``benchmarks/fixtures/time_limits.toml``. Writes
``benchmarks/results/time_limits.md``.

    python benchmarks/time_limits.py [--limit 2]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "time_limits.md"


def commands(d: Path) -> dict[str, list[str]]:
    """Each computing command on the big mesh ``d/big.ply`` (and its side files)."""
    big, lab, m = str(d / "big.ply"), str(d / "big.labels.txt"), str(d / "map.txt")
    return {
        "match": ["match", big, big, "-o", str(d / "o.map.txt")],
        "segment": ["segment", big, "--method", "ncut", "-k", "6", "-o", str(d / "o.seg.txt")],
        "spectrum": ["spectrum", big, "-k", "300", "-o", str(d / "o.spec.npz")],
        "keypoints": ["keypoints", big, "-o", str(d / "o.kp.txt")],
        "describe": ["describe", big, "--descriptor", "wks", "-o", str(d / "o.desc.npz")],
        "geodesics": ["geodesics", big, "--sources", "0,1,2", "--method", "exact", "-o", str(d / "o.geo.npz")],
        "evaluate-map": ["evaluate-map", big, big, m, "--geodesics", "exact", "--truth-src", str(d / "t.vts"),
                         "--truth-dst", str(d / "t.vts")],
        "transfer-labels": ["transfer-labels", big, lab, big, "-o", str(d / "o.tl.txt")],
        "clean": ["clean", big, "--remesh", "0.005", "-o", str(d / "o.clean.ply")],
        "track": ["track", big, big, big, "-o", str(d / "o.track.npz")],
        "bench run": ["bench", "run", str(d / "bench.toml"), "-o", str(d / "run"), "--no-progress"],
    }


#: the config given to `bench run`
BENCH = HERE / "fixtures" / "time_limits.toml"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--limit", type=float, default=2.0, help="the --time-limit given (seconds)")
    args = ap.parse_args(argv)
    from shape_toolkit.bench.report import markdown_table
    from shape_toolkit.data.generate import icosphere
    from shape_toolkit.io.mesh import save_shape

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        shape = icosphere(7)
        save_shape(shape, d / "big.ply")
        n = shape.n_vertices
        np.savetxt(d / "big.labels.txt", (shape.vertices[:, 2] > 0).astype(int), fmt="%d")
        np.savetxt(d / "map.txt", np.arange(n), fmt="%d")
        np.savetxt(d / "t.vts", np.arange(1, n + 1, 997), fmt="%d")
        (d / "bench.toml").write_text(BENCH.read_text())
        for name, cmd in commands(d).items():
            t0 = time.perf_counter()
            proc = subprocess.run(
                [sys.executable, "-m", "shape_toolkit", *cmd, "--time-limit", f"{args.limit:g}"],
                capture_output=True, text=True, timeout=600, cwd=d, env={**os.environ, "SHAPE_TOOLKIT_PROGRESS": "0"},
            )
            wall = time.perf_counter() - t0
            err = proc.stderr.strip().splitlines()
            rows.append((name, proc.returncode, wall, len(err), err[-1] if err else ""))
            print(f"{name}: exit {proc.returncode}, {wall:.1f} s", flush=True)
    ok = all(w <= args.limit + 5 for _, _, w, _, _ in rows)
    lines = [
        "# Time limits",
        "",
        f"Regenerate: `python benchmarks/time_limits.py --limit {args.limit:g}`. Each command as a subprocess on a",
        f"{n:,}-vertex sphere with `--time-limit {args.limit:g}`; wall time from launch to exit, Python start-up",
        f"included. Target: every command stops within the limit + 5 s: **{'met' if ok else 'NOT met'}**.",
        "A command is killed at the limit, except `geodesics` and `evaluate-map`, which stop themselves between",
        "geodesic sources (saying how far they got) and are killed only 2 s later (`cli/supervise.py`, `GRACE`).",
        "",
        *markdown_table(["command", "exit", "wall (s)", "stderr lines", "last stderr line"],
                        [[name, code, f"{wall:.1f}", nerr, last[:150]] for name, code, wall, nerr, last in rows]),
    ]
    RESULTS.write_text("\n".join(lines) + "\n")
    print(f"-> {RESULTS}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
