"""Eigensolver benchmark: shape_toolkit.core.eigen against SciPy's ``eigsh`` shift-invert, side by side.

    python benchmarks/bench_eigensolver.py                     # the grid: n ~ 500 ... 200k, k = 20 ... 200
    python benchmarks/bench_eigensolver.py --quick             # a 2k/5k smoke test (seconds)
    python benchmarks/bench_eigensolver.py --crossover         # dense vs block Krylov at small n (the
                                                               # measurement behind eigen.DENSE_MAX_N)

Problem: cotangent Laplacian ``L = -igl.cotmatrix`` with the Voronoi mass ``M`` (what ``compute_spectrum``
hands ``smallest_eigenpairs`` for a mesh with mass) of a bumpy icosphere (the icosahedron of
``shape_toolkit.data.generate`` with every triangle split into ``s x s``, projected on a bumpy radius)
at n ~ 500, 2k, 5k, 20k, 50k, 200k, and of the real 5k meshes TOSCA ``cat0`` and FAUST ``tr_reg_000``
(skipped when ``/work/shared/data`` or ``$TOOLKIT_DATA`` does not have them).

How it measures. Per mesh and BLAS setting, one worker process (started with ``OPENBLAS_NUM_THREADS=1``, or
with it unset = OpenBLAS's default, one thread per core) loads the matrices once and then, for every k,
runs SciPy and the toolkit **interleaved in that process** (SciPy, toolkit, SciPy, toolkit, ...), best of
``--repeats`` rounds (imports and threadpoolctl's one-off library scan done before). Peak memory comes
from one more run of each in a ``fork`` of the worker (``VmHWM`` at the end minus ``VmRSS`` at the fork),
so that each run's peak is its own. Cells with one round (200k) run once each, in the fork, which gives
both. Times per run: wall clock, CPU time of the process (``time.process_time``: all threads, BLAS
workers included) and of the calling thread (``time.thread_time``). Best = the minimum over the rounds,
taken separately for each. Eigenvalue errors are against a reference computed once per case with ARPACK
on a CHOLMOD factor at ``tol=0``. A method whose runs of one case took more than ``--budget`` seconds in
all is not run again (the row says how many runs it got).
Writes ``benchmarks/results/eigensolver.md`` (``--raw`` also the rows as JSON; ``--from-raw`` renders
saved rows of several runs into one table, e.g. the small cells and the 200k cells run separately).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import signal
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
CROSSOVER = REPO / "benchmarks" / "results" / "eigensolver_crossover.md"

#: method name -> human label; "baseline" is what pyFM / LaPy do.
METHODS = {
    "baseline": "SciPy eigsh shift-invert + SuperLU (peers)",
    "reference": "reference: ARPACK + CHOLMOD, tol=0",
    "auto": "toolkit auto (what compute_spectrum runs)",
    "krylov-threaded": "toolkit block Krylov-Schur, BLAS threads not capped",
    "dense": "toolkit dense (LAPACK)",
    "krylov": "toolkit block Krylov-Schur (BLAS capped)",
    "arpack": "toolkit arpack (ARPACK + CHOLMOD via cholespy)",
    "krylov-sksparse": "block Krylov-Schur + CHOLMOD via scikit-sparse",
    "primme": "PRIMME (GD+k) on the CHOLMOD shift-invert operator",
    "lobpcg": "SciPy LOBPCG preconditioned by the CHOLMOD factor",
}
#: seconds after which one run is stopped (a method that is this slow has lost)
RUN_TIMEOUT = 600
ERR_OK = 1e-10

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
    """Split every triangle into ``s * s`` congruent ones on a barycentric grid (shared edges): the
    library's :func:`shape_toolkit.data.corruptions.split_triangles` (original vertices first)."""
    from shape_toolkit.data.corruptions import split_triangles

    return split_triangles(v, f, s)


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


# -- solvers  --------------------------------------------------------
def sigma_for(A: sp.csr_matrix, mass: np.ndarray) -> float:
    """The shift every method uses: ``-1e-8 * max(diag(A) / diag(M))`` (toolkit's default)."""
    return -1e-8 * float(np.max(A.diagonal() / mass))


def _status_kb() -> dict[str, int]:
    """``VmRSS`` and ``VmHWM`` (peak) of this process in KiB, from /proc (zeros where it is missing)."""
    out = {"VmRSS": 0, "VmHWM": 0}
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            key = line.split(":")[0]
            if key in out:
                out[key] = int(line.split()[1])
    except OSError:
        pass
    return out


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


def run_method(method: str, A: sp.csr_matrix, mass: np.ndarray, k: int) -> tuple[np.ndarray, dict]:
    """Eigenvalues ``(k,)`` by ``method`` and what the toolkit reports it did (``info``)."""
    import scipy.sparse.linalg as sla

    import shape_toolkit.core.eigen as eigen
    from shape_toolkit.core.eigen import smallest_eigenpairs

    sigma = sigma_for(A, mass)
    info: dict = {}
    if method == "baseline":
        vals, _ = sla.eigsh(A, k=k, M=sp.diags(mass).tocsr(), sigma=sigma, which="LM")
    elif method == "reference":
        vals, _ = smallest_eigenpairs(A, k, mass, method="arpack", tol=0.0, sigma=sigma, blas_threads=None)
    elif method == "auto":
        vals, _ = smallest_eigenpairs(A, k, mass, info=info)
    elif method == "krylov-threaded":
        vals, _ = smallest_eigenpairs(A, k, mass, method="krylov", blas_threads=None, info=info)
    elif method in ("arpack", "dense", "krylov"):
        vals, _ = smallest_eigenpairs(A, k, mass, method=method, info=info)
    elif method == "krylov-sksparse":
        eigen._cholmod_solver = _sksparse_solver
        vals, _ = smallest_eigenpairs(A, k, mass, method="krylov", info=info)
    elif method == "primme":
        vals = solve_primme(A, mass, k, sigma)
    elif method == "lobpcg":
        vals = solve_lobpcg(A, mass, k, sigma)
    else:
        raise ValueError(f"unknown method {method!r}")
    keep = ("method", "backend", "blas_threads", "n_op", "restarts", "block_size", "max_basis", "escalated_from")
    return np.sort(vals), {key: info[key] for key in keep if key in info}


def timed(method: str, A: sp.csr_matrix, mass: np.ndarray, k: int, timeout: float) -> dict:
    """One run of ``method`` in this process: wall, process CPU and thread CPU time, eigenvalues."""
    try:
        signal.alarm(int(timeout))
        rss0 = _status_kb()["VmRSS"]
        c0, t0, w0 = time.process_time(), time.thread_time(), time.perf_counter()
        vals, info = run_method(method, A, mass, k)
        out = {"wall": time.perf_counter() - w0, "cpu": time.process_time() - c0,
               "thread_cpu": time.thread_time() - t0, "peak_mb": (_status_kb()["VmHWM"] - rss0) / 1024,
               "vals": vals.tolist(), "info": info}  # fmt: skip
    except BaseException as exc:  # noqa: BLE001 - reported as a failed run
        out = {"failed": f"{type(exc).__name__}: {exc}"[:160]}
    finally:
        signal.alarm(0)
    return out


def measure(method: str, A: sp.csr_matrix, mass: np.ndarray, k: int, timeout: float) -> dict:
    """One run of ``method`` in a forked copy of this process: its own peak memory (and times)."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the run
        os.close(r)
        os.write(w, json.dumps(timed(method, A, mass, k, timeout)).encode())
        os._exit(0)
    os.close(w)
    chunks = []
    while chunk := os.read(r, 1 << 16):
        chunks.append(chunk)
    os.close(r)
    _, status = os.waitpid(pid, 0)
    if not chunks:
        return {"failed": f"run ended without a result (status {status}; timeout {timeout:.0f} s?)"}
    return json.loads(b"".join(chunks))


def worker(npz: str, ks: list[int], methods: list[str], repeats: int, budget: float, reference: bool) -> None:
    """Measure ``methods`` interleaved on the matrices in ``npz`` for each k; print one JSON line per k."""
    z = np.load(npz)
    A = sp.csr_matrix((z["data"], z["indices"], z["indptr"]), shape=tuple(z["shape"]))
    mass = z["mass"]
    import scipy.sparse.linalg  # noqa: F401 - imported before any clock starts, like the toolkit
    import threadpoolctl

    import shape_toolkit.core.eigen as eigen

    threadpoolctl.threadpool_info()
    with eigen._blas_limit(1):  # threadpoolctl's one-off library scan, once per process
        pass
    for k in ks:
        load = os.getloadavg()[0]
        result: dict = {"k": k, "load": load, "runs": {}}
        if reference:
            result["reference"] = measure("reference", A, mass, k, RUN_TIMEOUT)
        runs: dict[str, list[dict]] = {m: [] for m in methods}
        if repeats == 1:  # one run each, in a fork: times and peak memory of the same run
            for m in methods:
                runs[m].append(measure(m, A, mass, k, RUN_TIMEOUT))
        else:
            spent = dict.fromkeys(methods, 0.0)
            for _ in range(repeats):  # timing: interleaved runs in this process
                for m in methods:
                    if runs[m] and (spent[m] > budget or "failed" in runs[m][-1]):
                        continue
                    t0 = time.perf_counter()
                    runs[m].append(timed(m, A, mass, k, RUN_TIMEOUT))
                    spent[m] += time.perf_counter() - t0
            for m in methods:  # peak memory: one more run each, in a fork
                mem = measure(m, A, mass, k, RUN_TIMEOUT)
                for run in runs[m]:
                    run["peak_mb"] = mem.get("peak_mb", float("nan"))
        result["runs"] = runs
        print(json.dumps(result), flush=True)


def run_worker(npz: Path, ks: list[int], methods: list[str], threads: int | None, repeats: int, budget: float,
               reference: bool) -> list[dict]:  # fmt: skip
    """A worker process with ``OPENBLAS_NUM_THREADS=threads`` (None: unset, OpenBLAS's default)."""
    env = dict(os.environ)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.pop(var, None)
        if threads is not None:
            env[var] = str(threads)
    cmd = [sys.executable, __file__, "--worker", str(npz), ",".join(map(str, ks)), ",".join(methods),
           str(repeats), str(budget), "1" if reference else "0"]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"worker failed: {(done.stderr.strip().splitlines() or ['?'])[-1]}")
    return [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]


def rel_error(vals: np.ndarray, ref: np.ndarray) -> float:
    """max_i |l_i - ref_i| / max(|ref_i|, ref_1): the null eigenvalue is judged against ref_1."""
    if len(vals) != len(ref):
        return float("inf")
    den = np.maximum(np.abs(ref), ref[1])
    return float(np.max(np.abs(np.sort(vals) - ref) / den))


def summarize(runs: list[dict], ref: np.ndarray | None) -> dict:
    """Best-of summary of one method's runs: minima of wall, CPU, thread CPU; worst error; peak memory."""
    ok = [r for r in runs if "failed" not in r]
    if not ok:
        return {"failed": runs[0]["failed"] if runs else "not run", "runs": len(runs)}
    out = {key: min(r[key] for r in ok) for key in ("wall", "cpu", "thread_cpu")}
    out.update(runs=len(ok), peak_mb=max(r["peak_mb"] for r in ok), info=ok[0].get("info", {}),
               all_cpu=[r["cpu"] for r in ok], all_wall=[r["wall"] for r in ok])  # fmt: skip
    if ref is not None:
        out["err"] = max(rel_error(np.array(r["vals"]), ref) for r in ok)
        out["deterministic"] = all(r["vals"] == ok[0]["vals"] for r in ok)
    return out


# -- the plan ----------------------------------------------------------------------------------------------
def plan(quick: bool, full_200k: bool) -> list[tuple[str, list[int]]]:
    if quick:
        return [("sphere 2k", [20, 100]), ("FAUST tr_reg_000", [20])]
    ks = [20, 50, 100, 200]
    cases = [("sphere 500", [20, 50, 100])]
    cases += [(m, ks) for m in ("sphere 2k", "sphere 5k", "TOSCA cat0", "FAUST tr_reg_000", "sphere 20k",
                               "sphere 50k")]  # fmt: skip
    cases.append(("sphere 200k", ks if full_200k else [20, 50]))
    return cases


def methods_for(n: int, threads: int | None, extras: bool) -> list[str]:
    """The methods measured at one BLAS setting: SciPy and the toolkit always; more with ``extras``."""
    out = ["baseline", "auto"]
    if threads is None and extras and n <= 25000:
        out.append("krylov-threaded")  # the measurement behind eigen.DEFAULT_BLAS_THREADS
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small meshes, smoke test")
    ap.add_argument("--full-200k", action="store_true", help="all four k at 200k (else k = 20, 50)")
    ap.add_argument("--meshes", nargs="+", choices=list(MESHES), help="only these meshes of the plan")
    ap.add_argument("--skip-meshes", nargs="+", choices=list(MESHES), default=[], help="not these")
    ap.add_argument("--ks", type=int, nargs="+", help="only these k of the plan")
    ap.add_argument("--repeats", type=int, default=5, help="rounds of interleaved runs (best of)")
    ap.add_argument("--budget", type=float, default=40.0,
                    help="a method whose runs took this many seconds in total is not run again for that k")
    ap.add_argument("--extras", action="store_true", help="also the uncapped block solver at default threads")
    ap.add_argument("--threads", nargs="+", choices=["1", "default"], default=["1", "default"],
                    help="BLAS settings to run (default both; the reference is computed with the first)")
    ap.add_argument("--ref-from", type=Path, nargs="*", default=[],
                    help="saved rows (JSON) whose reference eigenvalues to reuse when '1' is not run")
    ap.add_argument("--alternatives", nargs="*", default=[], choices=["arpack", "krylov-sksparse", "primme",
                    "lobpcg", "dense", "krylov"], help="also these solvers (one BLAS thread)")  # fmt: skip
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--raw", type=Path, default=None, help="also write the rows as JSON here")
    ap.add_argument("--from-raw", type=Path, nargs="+", help="render saved rows (JSON) instead of measuring")
    ap.add_argument("--crossover", action="store_true", help="dense vs block Krylov at small n (one thread)")
    ap.add_argument("--worker", nargs=6, help=argparse.SUPPRESS)
    ap.add_argument("--crossover-worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        npz, ks, methods, repeats, budget, ref = args.worker
        worker(npz, [int(x) for x in ks.split(",")], methods.split(","), int(repeats), float(budget), ref == "1")
        return 0
    if args.crossover_worker:
        crossover_worker(args.repeats)
        return 0
    if args.crossover:
        return crossover(args)
    if args.from_raw:
        saved = [json.loads(p.read_text()) for p in args.from_raw]
        # a later file re-measures cells of an earlier one: its rows replace theirs (the old ones are listed)
        by_key: dict[tuple, dict] = {}
        superseded: list[dict] = []
        for s in saved:
            for r in s["rows"]:
                key = (r["mesh"], r["k"], r["threads"], r["method"])
                if key in by_key:
                    superseded.append(by_key[key])
                by_key[key] = r
        rows = list(by_key.values())
        meta = {"commands": [c for s in saved for c in s["meta"]["commands"]],
                "minutes": sum(s["meta"]["minutes"] for s in saved),
                "load_start": saved[0]["meta"]["load_start"], "load_end": saved[-1]["meta"]["load_end"],
                "skipped": [x for s in saved for x in s["meta"]["skipped"]], "superseded": superseded}  # fmt: skip
        table = render(rows, meta)
        args.out.write_text(table)
        print(table)
        return 0

    t_start = time.perf_counter()
    load_start = os.getloadavg()
    rows: list[dict] = []
    references: list[dict] = []
    skipped: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, ks in plan(args.quick, args.full_200k):
            if (args.meshes and name not in args.meshes) or name in args.skip_meshes:
                continue
            ks = [k for k in ks if not args.ks or k in args.ks]
            if not ks:
                continue
            case = build_case(name)
            if case is None:
                skipped.append(f"{name} (file not found)")
                continue
            A, mass = case
            n = A.shape[0]
            npz = Path(tmp) / "case.npz"
            np.savez(npz, data=A.data, indices=A.indices, indptr=A.indptr, shape=np.array(A.shape), mass=mass)
            repeats = args.repeats if n <= 25000 else max(1, min(args.repeats, 2 if n <= 100000 else 1))
            refs: dict[int, np.ndarray] = {}
            for saved in args.ref_from:
                for r in json.loads(saved.read_text()).get("references", []):
                    if r["mesh"] == name:
                        refs[r["k"]] = np.array(r["vals"])
            for threads in [1 if t == "1" else None for t in args.threads]:
                methods = methods_for(n, threads, args.extras)
                if threads == 1:
                    methods += args.alternatives
                print(f"[{time.perf_counter() - t_start:6.0f}s] {name} n={n} k={ks} BLAS={threads or 'default'} "
                      f"load {os.getloadavg()[0]:.1f}", file=sys.stderr, flush=True)  # fmt: skip
                need_ref = threads == 1 or any(k not in refs for k in ks)
                for res in run_worker(npz, ks, methods, threads, repeats, args.budget, reference=need_ref):
                    k = res["k"]
                    if "reference" in res:
                        ref_run = res["reference"]
                        if "failed" in ref_run:
                            skipped.append(f"{name} k={k} (reference failed: {ref_run['failed']})")
                            continue
                        refs[k] = np.array(ref_run["vals"])
                        references.append({"mesh": name, "k": k, "vals": ref_run["vals"]})
                    if k not in refs:
                        continue
                    for m, runs in res["runs"].items():
                        row = {"mesh": name, "n": n, "k": k, "method": m,
                               "threads": "1" if threads == 1 else "default", "load": res["load"],
                               **summarize(runs, refs[k])}  # fmt: skip
                        rows.append(row)
                        brief = {key: v for key, v in row.items() if key not in ("info", "all_cpu", "all_wall")}
                        print("   ", json.dumps(brief), file=sys.stderr, flush=True)
    cmd = "python benchmarks/bench_eigensolver.py" + " ".join(a if " " not in a else f"'{a}'" for a in [""] + (
        argv if argv is not None else sys.argv[1:]))  # fmt: skip
    meta = {"commands": [cmd.strip()], "minutes": (time.perf_counter() - t_start) / 60,
            "load_start": list(load_start), "load_end": list(os.getloadavg()), "skipped": skipped}  # fmt: skip
    if args.raw:
        args.raw.write_text(json.dumps({"meta": meta, "rows": rows, "references": references}, indent=1))
    table = render(rows, meta)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(table)
    print(table)
    return 0


# -- the report --------------------------------------------------------------------------------------------
def _x(num: float, den: float) -> str:
    return f"{num / max(den, 1e-9):.2f}x"


def render(rows: list[dict], meta: dict) -> str:
    import scipy

    base = {(r["mesh"], r["k"], r["threads"]): r for r in rows if r["method"] == "baseline"}
    l1, l5, l15 = meta["load_start"]
    # the measuring commands, without where they wrote (--raw/--out files are not part of the recipe)
    clean = [re.sub(r" --(raw|out) \S+", "", c) for c in meta["commands"]]
    cmds = "; ".join(f"`{c}`" for c in clean)
    loads = [r["load"] for r in rows]
    lines = [
        "# Eigensolver benchmark",
        "",
        f"Regenerate: {cmds} ({meta['minutes']:.0f} min in all).",
        "",
        f"**Load**: {os.cpu_count()} cores shared with other jobs; 1-min load average {l1:.1f} / {l5:.1f} / "
        f"{l15:.1f} (1 / 5 / 15 min) at the start, {meta['load_end'][0]:.1f} at the end, "
        f"{min(loads, default=0):.1f}-{max(loads, default=0):.1f} at the start of the cells (each row gives its "
        "own). On a loaded machine wall times are inflated and noisy; CPU time is the steadier measure. "
        f"{platform.machine()}, Python {platform.python_version()}, NumPy {np.__version__} (OpenBLAS), "
        f"SciPy {scipy.__version__}.",
        "",
        "**Method.** Per mesh and BLAS setting one worker process loads the matrices and runs SciPy and the "
        "toolkit interleaved in that process, best of the rounds ('runs'; imports and the toolkit's one-off "
        "threadpoolctl library scan are done before); peak memory from one more run of each in a fork of the "
        "worker. Cells with one run (200k) run once each in a fork, which gives both. "
        "`BLAS 1`: the worker was started with OPENBLAS_NUM_THREADS=1; `default`: unset, OpenBLAS uses one "
        "thread per core (2 here). The toolkit caps its own BLAS at one thread inside the call whatever the "
        "process has (`DEFAULT_BLAS_THREADS`). CPU = process CPU time (all threads, BLAS workers included); "
        "thread = CPU time of the calling thread; wall = elapsed. Peak MB: the run's peak resident memory "
        "over its size at the fork. Error: max relative eigenvalue error against the reference (ARPACK on a "
        "CHOLMOD factor, tol=0; the null eigenvalue judged against the first non-zero one); target <= "
        f"{ERR_OK:.0e}. Speed-up = SciPy's time / the toolkit's: above 1x the toolkit wins.",
        "",
        "## compute_spectrum's solver (`smallest_eigenpairs`, auto) vs SciPy eigsh shift-invert (SuperLU)",
        "",
        "| mesh | n | k | BLAS | SciPy CPU s | SciPy thread s | SciPy wall s | toolkit CPU s | toolkit thread s "
        "| toolkit wall s | CPU speed-up | wall speed-up | toolkit method | error | SciPy error | peak MB "
        "toolkit / SciPy | runs | verdict | load |",
        "|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---|---:|",
    ]
    wins = misses = 0
    for r in rows:
        if r["method"] != "auto":
            continue
        b = base.get((r["mesh"], r["k"], r["threads"]))
        if b is None or "failed" in b or "failed" in r:
            why = f"SciPy: {(b or {}).get('failed', '-')}; toolkit: {r.get('failed', '-')}"
            lines.append(f"| {r['mesh']} | {r['n']} | {r['k']} | {r['threads']} | {why} |||||||||||||| "
                         f"{'MISS (failed)' if 'failed' in r else 'SciPy failed'} | {r['load']:.1f} |")  # fmt: skip
            misses += "failed" in r
            wins += "failed" not in r and r["err"] <= ERR_OK
            continue
        bad = [w for w, miss in (("accuracy", r["err"] > ERR_OK), ("CPU", r["cpu"] >= b["cpu"]),
                                 ("wall", r["wall"] >= b["wall"])) if miss]  # fmt: skip
        verdict = "win" if not bad else "MISS (" + ", ".join(bad) + ")"
        wins += not bad
        misses += bool(bad)
        lines.append(
            f"| {r['mesh']} | {r['n']} | {r['k']} | {r['threads']} | {b['cpu']:.3f} | {b['thread_cpu']:.3f} "
            f"| {b['wall']:.3f} | {r['cpu']:.3f} | {r['thread_cpu']:.3f} | {r['wall']:.3f} | {_x(b['cpu'], r['cpu'])} "
            f"| {_x(b['wall'], r['wall'])} | {r.get('info', {}).get('method', '?')} | {r['err']:.1e} | {b['err']:.1e} "
            f"| {r['peak_mb']:.0f} / {b['peak_mb']:.0f} | {r['runs']} / {b['runs']} | {verdict} | {r['load']:.1f} |"
        )
    lines += ["", f"**{wins} wins, {misses} misses** (a win: less CPU time and less wall time than SciPy, "
              f"best against best, and error <= {ERR_OK:.0e}).", ""]  # fmt: skip
    others = [r for r in rows if r["method"] not in ("auto", "baseline")]
    if others:
        lines += ["## Other measurements", "",
                  "| mesh | n | k | BLAS | method | CPU s | thread s | wall s | CPU speed-up vs SciPy "
                  "| wall speed-up vs SciPy | error | peak MB | runs | load |",
                  "|---|---:|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
        for r in others:
            b = base.get((r["mesh"], r["k"], r["threads"]))
            if "failed" in r:
                lines.append(f"| {r['mesh']} | {r['n']} | {r['k']} | {r['threads']} | {METHODS[r['method']]} "
                             f"| failed: {r['failed']} |||||||| {r['load']:.1f} |")  # fmt: skip
                continue
            sb = "-" if b is None or "failed" in b else _x(b["cpu"], r["cpu"])
            wb = "-" if b is None or "failed" in b else _x(b["wall"], r["wall"])
            lines.append(
                f"| {r['mesh']} | {r['n']} | {r['k']} | {r['threads']} | {METHODS[r['method']]} | {r['cpu']:.3f} "
                f"| {r['thread_cpu']:.3f} | {r['wall']:.3f} | {sb} | {wb} | {r['err']:.1e} | {r['peak_mb']:.0f} "
                f"| {r['runs']} | {r['load']:.1f} |"
            )
        lines.append("")
    if any(r.get("deterministic") is False for r in rows if r["method"] == "auto"):
        lines += ["**Warning**: the toolkit returned different eigenvalues across runs of one case.", ""]
    old = meta.get("superseded", [])
    old_base = {(r["mesh"], r["k"], r["threads"]): r for r in old if r["method"] == "baseline"}
    old_auto = [r for r in old if r["method"] == "auto" and "failed" not in r]
    if old_auto:
        lines += ["## Superseded cells", "",
                  "Measured by an earlier command above and re-measured by a later one (the table above has the "
                  "later run); kept because the code may have changed in between (the block size column says "
                  "what the toolkit ran).", "",
                  "| mesh | n | k | BLAS | SciPy CPU s | toolkit CPU s | CPU speed-up | wall speed-up | block | "
                  "verdict | load |", "|---|---:|---:|---|---:|---:|---:|---:|---:|---|---:|"]  # fmt: skip
        for r in old_auto:
            b = old_base.get((r["mesh"], r["k"], r["threads"]))
            if b is None or "failed" in b:
                continue
            bad = r["err"] > ERR_OK or r["cpu"] >= b["cpu"] or r["wall"] >= b["wall"]
            lines.append(f"| {r['mesh']} | {r['n']} | {r['k']} | {r['threads']} | {b['cpu']:.3f} | {r['cpu']:.3f} "
                         f"| {_x(b['cpu'], r['cpu'])} | {_x(b['wall'], r['wall'])} "
                         f"| {r.get('info', {}).get('block_size', '?')} | {'MISS' if bad else 'win'} "
                         f"| {r['load']:.1f} |")  # fmt: skip
        lines.append("")
    if meta["skipped"]:
        lines += ["Skipped: " + "; ".join(meta["skipped"]) + ".", ""]
    return "\n".join(lines)


# -- dense vs block Krylov at small n ------------------------------------------------------------------------
#: bumpy spheres split s x s (n = 10 s^2 + 2) and the k measured on each
CROSSOVER_SPHERES = (5, 7, 9, 11, 14)
CROSSOVER_KS = (10, 20, 50, 100, 200)


def crossover_worker(repeats: int) -> None:
    """One BLAS thread: dense vs krylov CPU time, interleaved, best of ``repeats``; JSON lines."""
    from shape_toolkit.core.eigen import _prefer_dense

    for s in CROSSOVER_SPHERES:
        V, F = icosphere(s)
        import igl

        A = sp.csr_matrix(-igl.cotmatrix(V, F))
        mass = igl.massmatrix(V, F, igl.MASSMATRIX_TYPE_VORONOI).diagonal().copy()
        n = A.shape[0]
        for k in CROSSOVER_KS:
            if 3 * k >= n:
                continue
            runs: dict[str, list[dict]] = {"dense": [], "krylov": []}
            for _ in range(repeats):
                for m in runs:
                    runs[m].append(timed(m, A, mass, k, RUN_TIMEOUT))
            best = {m: min(r["cpu"] for r in rs if "failed" not in r) for m, rs in runs.items()}
            print(json.dumps({"n": n, "k": k, "dense": best["dense"], "krylov": best["krylov"],
                              "auto_dense": bool(_prefer_dense(n, k)), "load": os.getloadavg()[0]}), flush=True)


def crossover(args: argparse.Namespace) -> int:
    from shape_toolkit.core.eigen import DENSE_MAX_N, DENSE_PER_K

    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    t0, load0 = time.perf_counter(), os.getloadavg()
    done = subprocess.run([sys.executable, __file__, "--crossover-worker", "--repeats", str(args.repeats)],
                          capture_output=True, text=True, env=env, check=True)  # fmt: skip
    rows = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]
    lines = ["# Dense LAPACK vs block Krylov-Schur at small n (the `auto` crossover)", "",
             f"Regenerate: `python benchmarks/bench_eigensolver.py --crossover --repeats {args.repeats}` "
             f"({(time.perf_counter() - t0) / 60:.1f} min). Bumpy icospheres (cotangent + Voronoi mass), one BLAS "
             f"thread, CPU time (process), best of {args.repeats} runs interleaved in one process. 1-min load "
             f"average {load0[0]:.1f} at the start, {os.getloadavg()[0]:.1f} at the end.", "",
             f"Rule in `core/eigen.py`: dense when n <= max(DENSE_MAX_N = {DENSE_MAX_N}, DENSE_PER_K = "
             f"{DENSE_PER_K} x k) or 3k >= n.", "",
             "| n | k | dense CPU ms | krylov CPU ms | faster | rule picks | rule's loss vs the faster | load |",
             "|---:|---:|---:|---:|---|---|---:|---:|"]  # fmt: skip
    for r in rows:
        faster = "dense" if r["dense"] < r["krylov"] else "krylov"
        pick = "dense" if r["auto_dense"] else "krylov"
        loss = r[pick] / min(r["dense"], r["krylov"])
        lines.append(f"| {r['n']} | {r['k']} | {r['dense'] * 1e3:.1f} | {r['krylov'] * 1e3:.1f} | {faster} "
                     f"| {pick} | {loss:.2f}x | {r['load']:.1f} |")  # fmt: skip
    lines.append("")
    out = CROSSOVER if args.out == RESULTS else args.out
    out.write_text("\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
