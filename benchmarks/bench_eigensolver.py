"""Eigensolver benchmark: shape_toolkit.core.eigen against SciPy's ``eigsh`` shift-invert, in one run.

    python benchmarks/bench_eigensolver.py            # the grid: n ~ 2k ... 200k, k = 20 ... 200
    python benchmarks/bench_eigensolver.py --quick    # a 5k-vertex smoke test (seconds)

Problem: cotangent Laplacian ``L = -igl.cotmatrix`` with the Voronoi mass ``M`` (what ``compute_spectrum``
hands ``smallest_eigenpairs`` for a mesh with mass) of a bumpy icosphere (the icosahedron of
``shape_toolkit.data.generate`` with every triangle split into ``s x s``, projected on a bumpy radius)
at n ~ 2k, 5k, 20k, 50k, 200k, and of the real 5k meshes TOSCA ``cat0`` and FAUST ``tr_reg_000`` (skipped
when ``/work/shared/data`` or ``$TOOLKIT_DATA`` does not have them).

Every measurement runs in a fresh child process that loads the matrices from a temporary ``.npz``, with the
BLAS thread count set by environment (``1``, or unset = OpenBLAS's default, one per core); its peak memory
is the child's VmHWM minus that of a child that only loads the matrices. Times are the solver call's wall
clock and process CPU time. Eigenvalue errors are against a reference computed once per case with ARPACK
on a CHOLMOD factor at ``tol=0`` (machine precision). The alternatives (PRIMME, LOBPCG, ARPACK and the
block solver on a scikit-sparse CHOLMOD factor) run with one BLAS thread on a subset of the grid.
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
    "baseline": "SciPy eigsh shift-invert + SuperLU (peers)",
    "reference": "reference: ARPACK + CHOLMOD, tol=0",
    "auto": "toolkit auto (block Krylov-Schur + CHOLMOD, BLAS capped)",
    "krylov-threaded": "toolkit block Krylov-Schur, BLAS threads not capped",
    "dense": "toolkit dense (LAPACK)",
    "krylov": "toolkit block Krylov-Schur (BLAS capped)",
    "arpack": "toolkit arpack (ARPACK + CHOLMOD via cholespy)",
    "krylov-sksparse": "block Krylov-Schur + CHOLMOD via scikit-sparse",
    "primme": "PRIMME (GD+k) on the CHOLMOD shift-invert operator",
    "lobpcg": "SciPy LOBPCG preconditioned by the CHOLMOD factor",
}
#: seconds after which a child is stopped (an alternative that is this slow has lost)
CHILD_TIMEOUT = 150


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
    """The icosahedron of ``shape_toolkit.data.generate`` split ``s x s`` (``10 s^2 + 2`` vertices), bumpy."""
    from shape_toolkit.data.generate import icosphere as ico

    base = ico(0)
    V, F = subdivide(np.asarray(base.vertices, dtype=float), np.asarray(base.faces), s)
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    r = 1 + 0.25 * np.sin(3 * V[:, 0]) * np.cos(2 * V[:, 1]) + 0.4 * V[:, 2] ** 2
    return V * r[:, None], F


def data_dir() -> Path:
    env = os.environ.get("TOOLKIT_DATA")
    return Path(env) if env else REPO.parent / "shared" / "data"


#: mesh name -> how to make it; "sphere:s" is the bumpy icosphere split s x s
MESHES = {
    "sphere 500": "sphere:7",
    "sphere 2k": "sphere:14",
    "sphere 5k": "sphere:22",
    "TOSCA cat0": "tosca5k/cat0.off",
    "FAUST tr_reg_000": "faust5k/tr_reg_000.off",
    "sphere 20k": "sphere:45",
    "sphere 50k": "sphere:71",
    "sphere 200k": "sphere:141",
    "TOSCA cat0 x196": "tosca5k/cat0.off:14",  # ~1M vertices: see eigensolver_notes.md, not in the grid
}


def build_case(name: str) -> tuple[sp.csr_matrix, np.ndarray] | None:
    """Cotangent Laplacian ``A`` and Voronoi mass diagonal of mesh ``name``; None if its file is absent."""
    import igl

    how = MESHES[name]
    if how.startswith("sphere:"):
        V, F = icosphere(int(how.split(":")[1]))
    else:
        rel, _, split = how.partition(":")
        path = data_dir() / rel
        if not path.is_file():
            return None
        V, F = read_off(path)
        if split:
            V, F = subdivide(V, F, int(split))
    A = sp.csr_matrix(-igl.cotmatrix(V, F))
    mass = igl.massmatrix(V, F, igl.MASSMATRIX_TYPE_VORONOI).diagonal().copy()
    return A, mass


# -- the child process: load, (solve), report --------------------------------------------------------
def sigma_for(A: sp.csr_matrix, mass: np.ndarray) -> float:
    """The shift every method uses: ``-1e-8 * max(diag(A) / diag(M))`` (toolkit's default)."""
    return -1e-8 * float(np.max(A.diagonal() / mass))


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


def _sksparse_solver(S: sp.csr_matrix):
    """``solve(B, X)`` with a scikit-sparse (system CHOLMOD) factor: the block solver's other backend."""
    from sksparse.cholmod import cholesky

    fac = cholesky(sp.csc_matrix(S))

    def solve(B: np.ndarray, X: np.ndarray) -> None:
        X[...] = fac(B)

    return solve


def _shift_invert(A: sp.csr_matrix, mass: np.ndarray, sigma: float):
    """The operator ``M^1/2 (A - sigma M)^-1 M^1/2`` on blocks, through the toolkit's CHOLMOD factor."""
    from shape_toolkit.core.eigen import _cholmod_solver

    solve = _cholmod_solver(sp.csr_matrix(A - sigma * sp.diags(mass)))
    sq = np.sqrt(mass)[:, None]

    def matmat(X: np.ndarray) -> np.ndarray:
        B = np.ascontiguousarray(X.reshape(len(mass), -1) * sq)
        out = np.empty_like(B)
        solve(B, out)
        return out * sq

    return solve, matmat


def solve_primme(A: sp.csr_matrix, mass: np.ndarray, k: int, sigma: float) -> np.ndarray:
    import primme
    import scipy.sparse.linalg as sla

    n = A.shape[0]
    _, matmat = _shift_invert(A, mass, sigma)
    op = sla.LinearOperator((n, n), matvec=lambda x: matmat(x).ravel(), matmat=matmat, dtype=np.float64)
    theta, Y = primme.eigsh(
        op, k, which="LA", maxBlockSize=4 if k <= 40 else 8, ncv=max(2 * k + 16, k + 48),
        method="PRIMME_DEFAULT_MIN_MATVECS", convtest=lambda ev, _v, res: res <= 1e-8 * abs(ev),
        v0=np.random.default_rng(0).standard_normal((n, 1)),
    )  # fmt: skip
    U = Y / np.sqrt(mass)[:, None]
    return np.einsum("ij,ij->j", U, A @ U) / np.einsum("ij,ij->j", U, mass[:, None] * U)


def solve_lobpcg(A: sp.csr_matrix, mass: np.ndarray, k: int, sigma: float) -> np.ndarray:
    import scipy.sparse.linalg as sla

    from shape_toolkit.core.eigen import _cholmod_solver

    n = A.shape[0]
    solve = _cholmod_solver(sp.csr_matrix(A - sigma * sp.diags(mass)))

    def prec(X: np.ndarray) -> np.ndarray:
        B = np.ascontiguousarray(X.reshape(n, -1))
        out = np.empty_like(B)
        solve(B, out)
        return out

    P = sla.LinearOperator((n, n), matvec=lambda x: prec(x).ravel(), matmat=prec, dtype=np.float64)
    X0 = np.random.default_rng(0).standard_normal((n, k + max(4, k // 10)))
    # residual ||A x - lambda M x|| in units of the largest diagonal ratio: 1e-6 gives ~1e-12 eigenvalue error
    tol = 1e-6 * float(np.sqrt(np.max(A.diagonal() / mass)))
    vals, _ = sla.lobpcg(A, X0, B=sp.diags(mass), M=P, largest=False, tol=tol, maxiter=200)
    return np.sort(vals)[:k]


def child(npz: str, method: str, k: int) -> None:
    """Run one solver on the matrices in ``npz`` and print a JSON line (time, memory, values)."""
    z = np.load(npz)
    A = sp.csr_matrix((z["data"], z["indices"], z["indptr"]), shape=tuple(z["shape"]))
    mass = z["mass"]
    M = sp.diags(mass).tocsr()
    import scipy.sparse.linalg as sla

    import shape_toolkit.core.eigen as eigen
    from shape_toolkit.core.eigen import smallest_eigenpairs

    if method == "primme":
        import primme  # noqa: F401 - imported before the clock starts, like SciPy
    if method == "krylov-sksparse":
        eigen._cholmod_solver = _sksparse_solver
    sigma = sigma_for(A, mass)
    info: dict = {}
    rss0 = peak_rss_kb()
    c0, t0 = time.process_time(), time.perf_counter()
    vals = np.zeros(0)
    if method == "baseline":
        vals, _ = sla.eigsh(A, k=k, M=M, sigma=sigma, which="LM")
    elif method == "reference":
        vals, _ = smallest_eigenpairs(A, k, mass, method="arpack", tol=0.0, sigma=sigma, blas_threads=None)
    elif method == "krylov-threaded":
        vals, _ = smallest_eigenpairs(A, k, mass, method="krylov", blas_threads=None, info=info)
    elif method in ("krylov-sksparse", "arpack", "dense", "krylov"):
        m = "krylov" if method == "krylov-sksparse" else method
        vals, _ = smallest_eigenpairs(A, k, mass, method=m, info=info)
    elif method == "primme":
        vals = solve_primme(A, mass, k, sigma)
    elif method == "lobpcg":
        vals = solve_lobpcg(A, mass, k, sigma)
    elif method == "auto":
        vals, _ = smallest_eigenpairs(A, k, mass, info=info)
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    out = {"seconds": seconds, "cpu": cpu, "maxrss_kb": peak_rss_kb(), "rss_before_kb": rss0}
    out["vals"] = np.sort(vals).tolist()
    out["info"] = {key: info[key] for key in ("method", "backend", "blas_threads", "n_op") if key in info}
    print(json.dumps(out))


def run_child(npz: Path, method: str, k: int, threads: int | None) -> dict:
    """One measurement in a fresh process; ``threads`` None leaves OpenBLAS's default (one per core)."""
    env = dict(os.environ)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.pop(var, None)
        if threads is not None:
            env[var] = str(threads)
    cmd = [sys.executable, __file__, "--child", str(npz), method, str(k)]
    load = os.getloadavg()[0]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False, timeout=CHILD_TIMEOUT)
    except subprocess.TimeoutExpired:
        return {"failed": f"timeout after {CHILD_TIMEOUT} s", "load": load}
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["?"])[-1]
        return {"failed": last[:160], "load": load}
    out = json.loads(done.stdout.strip().splitlines()[-1])
    out["load"] = load
    return out


def rel_error(vals: np.ndarray, ref: np.ndarray) -> float:
    """max_i |l_i - ref_i| / max(|ref_i|, ref_1): the null eigenvalue is judged against ref_1."""
    if len(vals) != len(ref):
        return float("inf")
    den = np.maximum(np.abs(ref), ref[1])
    return float(np.max(np.abs(np.sort(vals) - ref) / den))


# -- the parent: cases, table ------------------------------------------------------------------------
#: the alternatives measured with one BLAS thread, and on which (mesh, k)
ALTERNATIVES = ("arpack", "krylov-sksparse", "primme", "lobpcg")
ALT_CASES = {("sphere 2k", 20), ("sphere 2k", 100), ("TOSCA cat0", 20), ("TOSCA cat0", 50), ("TOSCA cat0", 200),
             ("sphere 20k", 20), ("sphere 20k", 100), ("sphere 50k", 50), ("sphere 200k", 20)}  # fmt: skip
ERR_OK = 1e-10


def plan(quick: bool, full_200k: bool) -> list[tuple[str, list[int]]]:
    if quick:
        return [("TOSCA cat0", [20]), ("sphere 2k", [20])]
    ks = [20, 50, 100, 200]
    cases = [("sphere 500", [20, 50])]
    cases += [(m, ks) for m in ("sphere 2k", "sphere 5k", "TOSCA cat0", "FAUST tr_reg_000", "sphere 20k",
                               "sphere 50k")]  # fmt: skip
    cases.append(("sphere 200k", ks if full_200k else [20, 50]))
    return cases


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small meshes, smoke test")
    ap.add_argument("--full-200k", action="store_true", help="all four k at 200k (else k = 20, 50)")
    ap.add_argument("--no-alternatives", action="store_true", help="skip PRIMME, LOBPCG, ...")
    ap.add_argument("--meshes", nargs="+", choices=list(MESHES), help="only these meshes of the plan")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--raw", type=Path, default=None, help="also write the rows as JSON here")
    ap.add_argument("--child", nargs=3, metavar=("NPZ", "METHOD", "K"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child(args.child[0], args.child[1], int(args.child[2]))
        return 0

    t_start = time.perf_counter()
    args.load_start = os.getloadavg()
    rows: list[dict] = []
    skipped: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, ks in plan(args.quick, args.full_200k):
            if args.meshes and name not in args.meshes:
                continue
            case = build_case(name)
            if case is None:
                skipped.append(name)
                continue
            A, mass = case
            n = A.shape[0]
            npz = Path(tmp) / "case.npz"
            np.savez(npz, data=A.data, indices=A.indices, indptr=A.indptr, shape=np.array(A.shape), mass=mass)
            load_rss = max(run_child(npz, "load", 0, 1)["maxrss_kb"] for _ in range(2))
            for k in ks:
                print(f"[{time.perf_counter() - t_start:6.0f}s] {name} n={n} k={k} load {os.getloadavg()[0]:.1f}",
                      file=sys.stderr, flush=True)  # fmt: skip
                ref_run = run_child(npz, "reference", k, 1)
                if "failed" in ref_run:
                    skipped.append(f"{name} k={k} (reference failed: {ref_run['failed']})")
                    continue
                ref = np.array(ref_run["vals"])
                todo: list[tuple[str, int | None]] = [("reference", 1)]
                for threads in (1, None):
                    todo += [("baseline", threads), ("auto", threads)]
                todo.append(("krylov-threaded", None))
                if not args.no_alternatives and (args.quick or (name, k) in ALT_CASES):
                    todo += [(m, 1) for m in ALTERNATIVES]
                if n <= 2500:
                    todo += [("dense", 1), ("krylov", 1)]
                for method, threads in todo:
                    r = ref_run if method == "reference" else run_child(npz, method, k, threads)
                    row = {"mesh": name, "n": n, "k": k, "method": method,
                           "threads": "1" if threads == 1 else "default", "load": r["load"]}  # fmt: skip
                    if "failed" in r:
                        row["failed"] = r["failed"]
                    else:
                        row.update(seconds=r["seconds"], cpu=r["cpu"], info=r.get("info", {}),
                                   peak_mb=(r["maxrss_kb"] - load_rss) / 1024,
                                   err=rel_error(np.array(r["vals"]), ref))  # fmt: skip
                    rows.append(row)
                    brief = {k2: v for k2, v in row.items() if k2 != "info"}
                    print("   ", json.dumps(brief), file=sys.stderr, flush=True)
    table = render(rows, args, time.perf_counter() - t_start, skipped)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(table)
    if args.raw:
        args.raw.write_text(json.dumps(rows, indent=1))
    print(table)
    return 0


def _ratio(b: dict | None, r: dict, key: str) -> str:
    if b is None or "failed" in b or "failed" in r:
        return "-"
    return f"{b[key] / max(r[key], 1e-9):.2f}x"


def render(rows: list[dict], args: argparse.Namespace, total: float, skipped: list[str]) -> str:
    import scipy

    cmd = "python benchmarks/bench_eigensolver.py" + (" --quick" if args.quick else "")
    cmd += " --full-200k" if args.full_200k else ""
    cmd += " --no-alternatives" if args.no_alternatives else ""
    cmd += " --meshes " + " ".join(f"'{m}'" for m in args.meshes) if args.meshes else ""
    cmd += f" --out {args.out}" if args.out != RESULTS else ""
    base = {(r["mesh"], r["k"], r["threads"]): r for r in rows if r["method"] == "baseline"}
    l1, l5, l15 = args.load_start
    lines = [
        "# Eigensolver benchmark" + (" (--quick smoke test)" if args.quick else ""),
        "",
        f"Regenerate: `{cmd}` (one run, {total / 60:.0f} min).",
        "",
        f"**The machine was loaded**: {os.cpu_count()} cores shared with other jobs, load average at the start "
        f"{l1:.1f} / {l5:.1f} / {l15:.1f} (1 / 5 / 15 min) and {os.getloadavg()[0]:.1f} at the end; every row "
        "gives the 1-min load average when it started. Wall times are inflated by the load and noisy; CPU "
        "time (the child's process time) is the steadier comparison. "
        f"{platform.machine()}, Python {platform.python_version()}, NumPy {np.__version__} (OpenBLAS), "
        f"SciPy {scipy.__version__}.",
        "",
        "Each measurement is a fresh process; one run each. `BLAS` is the thread count the process was "
        "started with (`1`: OPENBLAS_NUM_THREADS=1; `default`: unset, OpenBLAS uses one thread per core). "
        "The toolkit's `auto` caps BLAS to one thread inside the solver whatever the process has, so its two "
        "rows differ only by noise; `krylov-threaded` is the same solver with the cap off, the measurement "
        "behind `DEFAULT_BLAS_THREADS = 1`. Peak MB: increase of the peak resident memory (VmHWM) over a "
        "process that only loads the matrices. Error: max relative eigenvalue error against the reference "
        f"(null eigenvalue judged against the first non-zero one); target <= {ERR_OK:.0e}. Speedups are "
        "SciPy's time over the row's time at the same BLAS setting: above 1x the row wins, below 1x it loses.",
        "",
    ]
    # the headline: auto vs baseline per (mesh, k, threads)
    lines += ["## Toolkit `auto` vs SciPy eigsh shift-invert (SuperLU)", "",
              "| mesh | n | k | BLAS | SciPy wall s | SciPy CPU s | auto wall s | auto CPU s | wall speedup "
              "| CPU speedup | auto error | SciPy error | auto peak MB | SciPy peak MB | verdict | load |",
              "|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|"]  # fmt: skip
    wins = misses = 0
    for r in rows:
        if r["method"] != "auto":
            continue
        b = base.get((r["mesh"], r["k"], r["threads"]))
        if b is None or "failed" in b or "failed" in r:
            why = f"{(b or {}).get('failed', '')} {r.get('failed', '')}"
            lines.append(f"| {r['mesh']} | {r['n']} | {r['k']} | {r['threads']} | failed: {why} "
                         f"|||||||||||| {r['load']:.1f} |")  # fmt: skip
            misses += 1
            continue
        ok = r["err"] <= ERR_OK and r["cpu"] < b["cpu"] and r["seconds"] < b["seconds"]
        verdict = "win" if ok else "MISS (" + ", ".join(
            w for w, bad in (("accuracy", r["err"] > ERR_OK), ("CPU", r["cpu"] >= b["cpu"]),
                             ("wall", r["seconds"] >= b["seconds"])) if bad) + ")"  # fmt: skip
        wins += ok
        misses += not ok
        lines.append(
            f"| {r['mesh']} | {r['n']} | {r['k']} | {r['threads']} | {b['seconds']:.3f} | {b['cpu']:.3f} "
            f"| {r['seconds']:.3f} | {r['cpu']:.3f} | {_ratio(b, r, 'seconds')} | {_ratio(b, r, 'cpu')} "
            f"| {r['err']:.1e} | {b['err']:.1e} | {r['peak_mb']:.0f} | {b['peak_mb']:.0f} | {verdict} "
            f"| {r['load']:.1f} |"
        )
    lines += ["", f"**{wins} wins, {misses} misses** (a win: faster in both wall and CPU time and error <= "
              f"{ERR_OK:.0e}).", ""]  # fmt: skip
    lines += ["## Every measurement", "",
              "| mesh | n | k | BLAS | method | wall s | CPU s | peak MB | max rel eigenvalue error "
              "| wall speedup vs SciPy | CPU speedup vs SciPy | load |",
              "|---|---:|---:|---|---|---:|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    for r in rows:
        if r["method"] == "reference":
            b_key = (r["mesh"], r["k"], "1")
        else:
            b_key = (r["mesh"], r["k"], r["threads"])
        b = base.get(b_key)
        if "failed" in r:
            lines.append(f"| {r['mesh']} | {r['n']} | {r['k']} | {r['threads']} | {METHODS[r['method']]} "
                         f"| failed: {r['failed']} | | | | | | {r['load']:.1f} |")  # fmt: skip
            continue
        lines.append(
            f"| {r['mesh']} | {r['n']} | {r['k']} | {r['threads']} | {METHODS[r['method']]} | {r['seconds']:.3f} "
            f"| {r['cpu']:.3f} | {r['peak_mb']:.0f} | {r['err']:.1e} | {_ratio(b, r, 'seconds')} "
            f"| {_ratio(b, r, 'cpu')} | {r['load']:.1f} |"
        )
    if skipped:
        lines += ["", "Skipped: " + "; ".join(skipped) + "."]
    lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
