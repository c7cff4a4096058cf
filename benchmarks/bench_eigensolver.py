"""Eigensolver benchmark: shape_toolkit.core.eigen against the peers' ``eigsh`` shift-invert, in one run.

    python benchmarks/bench_eigensolver.py            # ~50k and ~200k vertices, k = 20 and 100
    python benchmarks/bench_eigensolver.py --quick    # a 5k-vertex smoke test (seconds)

Problem: cotangent Laplacian ``L = -igl.cotmatrix`` with the Voronoi mass ``M`` (and once the
combinatorial graph Laplacian with ``M = I``) of TOSCA ``cat0`` (5,000 vertices) whose triangles are
each split into ``s x s`` congruent triangles (s = 3: 44,984 vertices, s = 6: 179,930 vertices).
Without the shared data an icosphere with a bumpy radius is used instead (and said so).

Every solver runs in a fresh child process that loads the matrices from a temporary ``.npz``; its
peak memory is the child's ``ru_maxrss`` minus that of a child that only loads the matrices. Times
are wall-clock seconds of the solver call, the best of ``--repeats`` runs. Eigenvalue errors are
against a reference computed once per case with ARPACK at ``tol=0`` (machine precision).
Writes ``benchmarks/results/eigensolver.md`` and prints it.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

RESULTS = REPO / "benchmarks" / "results" / "eigensolver.md"

#: method name -> human label; "baseline" is what pyFM / LaPy do.
METHODS = {
    "baseline": "scipy eigsh shift-invert + SuperLU (peers)",
    "reference": "reference: eigsh + CHOLMOD operator, tol=0",
    "auto": "toolkit auto (block Krylov-Schur + CHOLMOD)",
}
#: the methods timed ``runs`` times (the reference runs once per case)
TIMED = ("baseline", "auto")


# -- meshes ---------------------------------------------------------------------------------------
def read_off(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices ``(n, 3)`` and triangles ``(m, 3)`` of a plain OFF file."""
    toks = path.read_text().split()
    if toks[0] != "OFF":
        raise ValueError(f"{path}: not an OFF file")
    nv, nf = int(toks[1]), int(toks[2])
    v = np.array(toks[4 : 4 + 3 * nv], dtype=np.float64).reshape(nv, 3)
    f = np.array(toks[4 + 3 * nv : 4 + 3 * nv + 4 * nf], dtype=np.int64).reshape(nf, 4)
    if not np.all(f[:, 0] == 3):
        raise ValueError(f"{path}: only triangles are supported")
    return v, f[:, 1:]


def subdivide(v: np.ndarray, f: np.ndarray, s: int) -> tuple[np.ndarray, np.ndarray]:
    """Split every triangle into ``s * s`` congruent ones on a barycentric grid (shared edges)."""
    grid = [(i, j) for i in range(s + 1) for j in range(s + 1 - i)]
    w = np.array([(i, j, s - i - j) for i, j in grid])
    pos = {t: q for q, t in enumerate(grid)}
    tris = []
    for i in range(s):
        for j in range(s - i):
            tris.append((pos[i, j], pos[i + 1, j], pos[i, j + 1]))
            if i + j < s - 1:
                tris.append((pos[i + 1, j], pos[i + 1, j + 1], pos[i, j + 1]))
    tris = np.array(tris)
    nf, npt = len(f), len(w)
    # a point's identity: its (vertex id, weight) pairs with non-zero weight, sorted by vertex id
    vid = np.where(w[None] > 0, f[:, None, :], -1)
    ww = np.broadcast_to(w, (nf, npt, 3))
    o = np.argsort(vid, axis=2)
    key = np.concatenate(
        [np.take_along_axis(vid, o, 2), np.take_along_axis(ww, o, 2)], axis=2
    ).reshape(-1, 6)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    xyz = np.einsum("pk,fkd->fpd", w / s, v[f]).reshape(-1, 3)
    return xyz[first], inv.ravel().reshape(nf, npt)[:, tris].reshape(-1, 3)


def icosphere(s: int) -> tuple[np.ndarray, np.ndarray]:
    """A subdivided icosahedron projected on a bumpy sphere (fallback when no data is present)."""
    t = (1 + 5**0.5) / 2
    v = np.array(
        [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
         [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], dtype=float
    )  # fmt: skip
    f = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
         [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
         [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    )  # fmt: skip
    V, F = subdivide(v, f, s)
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    r = 1 + 0.25 * np.sin(3 * V[:, 0]) * np.cos(2 * V[:, 1]) + 0.4 * V[:, 2] ** 2
    return V * r[:, None], F


def find_cat() -> Path | None:
    """TOSCA cat0.off in $TOOLKIT_DATA or <repo>/../shared/data, if present."""
    env = os.environ.get("TOOLKIT_DATA")
    base = Path(env) if env else REPO.parent / "shared" / "data"
    p = base / "tosca5k" / "cat0.off"
    return p if p.is_file() else None


def build_case(s: int, combinatorial: bool) -> tuple[str, sp.csr_matrix, np.ndarray | None]:
    """Mesh label, Laplacian ``A`` and lumped mass diagonal (None for the combinatorial case)."""
    import igl

    cat = find_cat()
    if cat is not None:
        v, f = read_off(cat)
        V, F = subdivide(v, f, s)
        label = f"cat0 x{s * s}" if s > 1 else "cat0"
    else:
        V, F = icosphere(22 * s)
        label = f"bumpy icosphere s={22 * s}"
    if combinatorial:
        adj = sp.csr_matrix(igl.adjacency_matrix(F), dtype=np.float64)
        A = sp.csr_matrix(sp.diags(np.asarray(adj.sum(axis=1)).ravel()) - adj)
        return label, A, None
    A = sp.csr_matrix(-igl.cotmatrix(V, F))
    mass = igl.massmatrix(V, F, igl.MASSMATRIX_TYPE_VORONOI).diagonal().copy()
    return label, A, mass


# -- the child process: load, (solve), report --------------------------------------------------------
def sigma_for(A: sp.csr_matrix, mass: np.ndarray | None) -> float:
    """The shift every method uses: ``-1e-8 * max(diag(A) / diag(M))`` (toolkit's default)."""
    d = np.ones(A.shape[0]) if mass is None else mass
    return -1e-8 * float(np.max(A.diagonal() / d))


def peak_rss_kb() -> int:
    """This process's peak resident memory in KiB (VmHWM; ru_maxrss where /proc is missing).

    ``ru_maxrss`` of a child started by fork+exec also counts the parent's memory at the fork
    (Linux keeps the pre-exec high-water mark), so it is only a fallback.
    """
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


def child(npz: str, method: str, k: int) -> None:
    """Run one solver on the matrices in ``npz`` and print a JSON line (time, memory, values)."""
    z = np.load(npz)
    A = sp.csr_matrix((z["data"], z["indices"], z["indptr"]), shape=tuple(z["shape"]))
    mass = z["mass"] if z["mass"].size else None
    M = None if mass is None else sp.diags(mass).tocsr()
    import scipy.sparse.linalg as sla

    from shape_toolkit.core.eigen import smallest_eigenpairs

    sigma = sigma_for(A, mass)
    rss0 = peak_rss_kb()
    c0, t0 = time.process_time(), time.perf_counter()
    vals = np.zeros(0)
    if method == "baseline":
        vals, _ = sla.eigsh(A, k=k, M=M, sigma=sigma, which="LM")
    elif method == "reference":
        vals, _ = smallest_eigenpairs(A, k, mass, method="arpack", tol=0.0, sigma=sigma)
    elif method != "load":
        vals, _ = smallest_eigenpairs(A, k, mass, method=method)
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    out = {"seconds": seconds, "cpu": cpu, "maxrss_kb": peak_rss_kb(), "rss_before_kb": rss0}
    out["vals"] = np.sort(vals).tolist()
    print(json.dumps(out))


def run_child(npz: Path, method: str, k: int, threads: int) -> dict:
    env = dict(os.environ)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env[var] = str(threads)
    cmd = [sys.executable, __file__, "--child", str(npz), method, str(k)]
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{method} k={k} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def rel_error(vals: np.ndarray, ref: np.ndarray) -> float:
    """max_i |l_i - ref_i| / max(|ref_i|, ref_1): the null eigenvalue is judged against ref_1."""
    den = np.maximum(np.abs(ref), ref[1])
    return float(np.max(np.abs(np.sort(vals) - ref) / den))


# -- the parent: cases, table ------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small mesh, smoke test in seconds")
    ap.add_argument("--repeats", type=int, default=None, help="runs per solver (best time kept)")
    ap.add_argument("--threads", type=int, default=1, help="BLAS threads in every child")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--child", nargs=3, metavar=("NPZ", "METHOD", "K"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child(args.child[0], args.child[1], int(args.child[2]))
        return 0

    # (subdivision s, combinatorial?, ks, runs per solver)
    if args.quick:
        cases = [(1, False, [10], 1), (1, True, [10], 1)]
    else:
        cases = [(3, False, [20, 100], 2), (6, False, [20, 100], 1), (3, True, [100], 2)]
    if args.repeats:
        cases = [(s, c, ks, args.repeats) for s, c, ks, _ in cases]
    t_start = time.perf_counter()
    args.load_start = os.getloadavg()[0]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for s, combinatorial, ks, repeats in cases:
            label, A, mass = build_case(s, combinatorial)
            kind = "combinatorial, M = I" if combinatorial else "cotangent + Voronoi M"
            npz = Path(tmp) / f"case_{s}_{int(combinatorial)}.npz"
            np.savez(
                npz,
                data=A.data,
                indices=A.indices,
                indptr=A.indptr,
                shape=np.array(A.shape),
                mass=np.zeros(0) if mass is None else mass,
            )
            n = A.shape[0]
            load_rss = max(run_child(npz, "load", 0, args.threads)["maxrss_kb"] for _ in range(2))
            for k in ks:
                print(f"[{time.perf_counter() - t_start:6.0f}s] {label} n={n} k={k} {kind}",
                      file=sys.stderr, flush=True)  # fmt: skip
                res: dict[str, list[dict]] = {m: [] for m in METHODS}
                res["reference"].append(run_child(npz, "reference", k, args.threads))
                ref = np.array(res["reference"][0]["vals"])
                for _ in range(repeats):
                    for m in TIMED:
                        res[m].append(run_child(npz, m, k, args.threads))
                for m, runs in res.items():
                    rows.append(
                        {
                            "mesh": label,
                            "kind": kind,
                            "n": n,
                            "k": k,
                            "method": m,
                            "seconds": min(r["seconds"] for r in runs),
                            "cpu": min(r["cpu"] for r in runs),
                            "peak_mb": max(r["maxrss_kb"] for r in runs) / 1024 - load_rss / 1024,
                            "err": max(rel_error(np.array(r["vals"]), ref) for r in runs),
                            "runs": len(runs),
                        }
                    )
    table = render(rows, args, time.perf_counter() - t_start)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(table)
    print(table)
    return 0


def render(rows: list[dict], args: argparse.Namespace, total: float) -> str:
    import scipy

    base = {(r["mesh"], r["kind"], r["k"]): r for r in rows if r["method"] == "baseline"}
    lines = [
        "# Eigensolver benchmark" + (" (--quick smoke test)" if args.quick else ""),
        "",
        "Generated by `python benchmarks/bench_eigensolver.py"
        + (" --quick" if args.quick else "")
        + "`; see benchmarks/README.md. "
        "Each run in a fresh process; times are the best of the `runs` column's count; "
        f"{args.threads} BLAS thread(s), {os.cpu_count()} cores, load average at the start "
        f"{args.load_start:.1f} and at the end {os.getloadavg()[0]:.1f} "
        f"({platform.machine()}, Python {platform.python_version()}, NumPy {np.__version__}, "
        f"SciPy {scipy.__version__}); whole run {total:.0f} s.",
        "Seconds: wall clock of the solver call; CPU s: its process CPU time (robust to other "
        "load on a shared machine). Peak MB: the solver's increase of the process's peak resident "
        "memory (VmHWM) over a process that only loads the matrices. "
        "Error: max relative eigenvalue error against the reference row (ARPACK at machine "
        "precision; the null eigenvalue is judged against the first non-zero one).",
        "",
        "| mesh | problem | n | k | method | runs | seconds | CPU s | peak MB "
        "| max rel eigenvalue error | speedup vs baseline | CPU speedup | memory ratio |",
        "|---|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        b = base[(r["mesh"], r["kind"], r["k"])]
        lines.append(
            f"| {r['mesh']} | {r['kind']} | {r['n']} | {r['k']} | {METHODS[r['method']]} | {r['runs']} "
            f"| {r['seconds']:.2f} | {r['cpu']:.2f} | {r['peak_mb']:.0f} | {r['err']:.1e} "
            f"| {b['seconds'] / r['seconds']:.2f}x | {b['cpu'] / r['cpu']:.2f}x "
            f"| {r['peak_mb'] / max(b['peak_mb'], 1e-9):.2f} |"
        )
    lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
