"""Graph Laplacians (thesis 2.6.1) and their smallest eigenpairs, cached by content.

What spectrum a method needs, by plugin name (``SpectrumSpec``), and computing it from names, live in
:mod:`shape_toolkit.spectra`: this module takes graphs, which take weighting objects."""

from __future__ import annotations

import hashlib
import json
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from shape_toolkit.core.cache import LRUCache
from shape_toolkit.core.eigen import EigenSolver, fix_signs
from shape_toolkit.core.graph import ShapeGraph
from shape_toolkit.errors import DisconnectedGraphError, ParameterError
from shape_toolkit.validation import atomic_output

__all__ = [
    "LAPLACIANS",
    "SPECTRUM_MEMORY",
    "spectrum_memory",
    "Spectrum",
    "laplacian_matrix",
    "compute_spectrum",
    "component_spectra",
    "fix_signs",
    "set_cache_dir",
    "clear_cache",
    "is_cached",
    "null_count",
]

LAPLACIANS = ("combinatorial", "normalized", "random-walk")
#: peak memory of ``shape-toolkit spectrum`` in bytes, ``a + n (b + c k)`` for ``n`` vertices and ``k`` eigenpairs:
#: ``(a, b, c)`` fitted to its measured peaks (``benchmarks/results/memory_models.md``, 2026-12-06: cotangent
#: weighting, 80k-500k vertices, k = 20-200; every row within 11 %). An estimate for refusing a shape too large for
#: the memory before reading it (``--memory-limit``), not a bound
SPECTRUM_MEMORY = (77e6, 1500.0, 31.0)


def spectrum_memory(n: int, k: int) -> float:
    """Estimated peak bytes of ``shape-toolkit spectrum`` for ``k`` eigenpairs of ``n`` vertices
    (:data:`SPECTRUM_MEMORY`)."""
    a, b, c = SPECTRUM_MEMORY
    return a + n * (b + c * max(k, 0))
_CACHE_VERSION = "3"  # 3: each cache file carries its key, verified on read


@dataclass(frozen=True, eq=False, repr=False)
class Spectrum:
    """The ``k`` smallest eigenpairs of a graph Laplacian, eigenvalues ascending.

    Normalisation of ``eigenvectors`` ``(n, k)``: orthonormal for ``combinatorial`` (``U^T M U = I``
    when the mass matrix is used) and ``normalized``; ``D``-orthonormal for ``random-walk``.
    ``degrees`` ``(n,)`` and ``volume`` (sum of degrees) come from the weight matrix.
    """

    eigenvalues: np.ndarray
    eigenvectors: np.ndarray
    laplacian: str
    weighting: str
    mass: np.ndarray | None
    degrees: np.ndarray
    sign_fixed: bool = False
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def k(self) -> int:
        """Number of eigenpairs."""
        return int(self.eigenvalues.shape[0])

    @property
    def n_vertices(self) -> int:
        """Number of graph vertices ``n``."""
        return int(self.eigenvectors.shape[0])

    @property
    def generalized(self) -> bool:
        """True when the problem was ``L u = lambda M u`` with the mass matrix."""
        return self.mass is not None

    @property
    def area(self) -> float:
        """Sum of the mass (the surface area, for a spectrum with the mass matrix); without one, the vertex count
        (each vertex a unit of area)."""
        return float(np.sum(self.mass)) if self.mass is not None else float(self.n_vertices)

    @property
    def volume(self) -> float:
        """Graph volume ``Vol(G) = sum_i d_i``."""
        return float(self.degrees.sum())

    def __repr__(self) -> str:
        lam = ", ".join(f"{x:.4g}" for x in self.eigenvalues[:4])
        return (
            f"Spectrum(k={self.k}, n={self.n_vertices}, laplacian={self.laplacian!r}, "
            f"weighting={self.weighting!r}, generalized={self.generalized}, eigenvalues=[{lam}, ...])"
        )

    def truncated(self, k: int) -> Spectrum:
        """The first ``k`` eigenpairs of this spectrum."""
        if not 1 <= k <= self.k:
            raise ParameterError(f"k must be in [1, {self.k}], got {k}")
        return Spectrum(
            self.eigenvalues[:k], self.eigenvectors[:, :k], self.laplacian, self.weighting,
            self.mass, self.degrees, self.sign_fixed, dict(self.meta),
        )

    @property
    def n_null(self) -> int:
        """Number of (numerically) zero eigenvalues, see :func:`null_count`."""
        return null_count(self.eigenvalues)

    def save(self, path: str | os.PathLike, *, cache_key: str = "") -> None:
        """Write the spectrum to an ``.npz`` file (plain arrays and JSON text, no pickle);
        ``cache_key``: the content cache's key text, which the cache verifies when it reads the
        file back."""
        meta = {k: v for k, v in self.meta.items() if k != "vertices"}
        vertices = self.meta.get("vertices")
        np.savez(
            path,
            eigenvalues=self.eigenvalues,
            eigenvectors=self.eigenvectors,
            laplacian=self.laplacian,
            weighting=self.weighting,
            mass=self.mass if self.mass is not None else np.zeros(0),
            degrees=self.degrees,
            sign_fixed=self.sign_fixed,
            meta=json.dumps(meta, default=_json_default),
            vertices=np.asarray(vertices, dtype=np.int64) if vertices is not None else np.zeros(0, np.int64),
            has_vertices=vertices is not None,
            cache_key=np.array(cache_key),
        )

    @classmethod
    def load(cls, path: str | os.PathLike) -> Spectrum:
        """Read a spectrum written by :meth:`save` (``allow_pickle=False``), validated: array shapes
        and dtypes consistent, values finite, a known Laplacian; else ``ValueError``."""
        with np.load(path, allow_pickle=False) as z:
            vals, vecs = np.asarray(z["eigenvalues"], np.float64), np.asarray(z["eigenvectors"], np.float64)
            mass, degrees = np.asarray(z["mass"], np.float64), np.asarray(z["degrees"], np.float64)
            laplacian = str(z["laplacian"])
            meta = json.loads(str(z["meta"])) if "meta" in z.files else {}
            if not isinstance(meta, dict):
                raise ValueError("spectrum meta is not a JSON object")
            if "has_vertices" in z.files and bool(z["has_vertices"]):
                meta["vertices"] = np.asarray(z["vertices"], np.int64)
            weighting, sign_fixed = str(z["weighting"]), bool(z["sign_fixed"])
        n = vecs.shape[0] if vecs.ndim == 2 else -1
        if (vals.ndim != 1 or vecs.ndim != 2 or vecs.shape[1] != vals.size or degrees.shape != (n,)
                or mass.size not in (0, n) or laplacian not in LAPLACIANS):
            raise ValueError(f"{path}: not a consistent spectrum file")
        if not (np.isfinite(vals).all() and np.isfinite(vecs).all() and np.isfinite(degrees).all()
                and np.isfinite(mass).all()):
            raise ValueError(f"{path}: non-finite values in a spectrum file")
        return cls(vals, vecs, laplacian, weighting, mass if mass.size else None, degrees, sign_fixed, meta)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return str(obj)


def _require_positive_degrees(d: np.ndarray, kind: str) -> None:
    if np.any(d <= 0):
        raise ParameterError(
            f"the {kind} Laplacian needs positive degrees; {int(np.sum(d <= 0))} vertices have none"
        )


def laplacian_matrix(W: sp.spmatrix, kind: str = "combinatorial") -> sp.csr_matrix:
    """The ``(n, n)`` Laplacian of weights ``W``: ``D - W`` (eq. 2.63), ``D^-1/2 (D - W) D^-1/2``
    (eq. 2.64) or ``D^-1 (D - W)`` (eq. 2.65, not symmetric)."""
    W = sp.csr_matrix(W, dtype=np.float64)
    d = np.asarray(W.sum(axis=1)).ravel()
    L = sp.diags(d) - W
    if kind == "combinatorial":
        return sp.csr_matrix(L)
    if kind not in LAPLACIANS:
        raise ParameterError(f"unknown Laplacian {kind!r}; choose one of {', '.join(LAPLACIANS)}")
    _require_positive_degrees(d, kind)
    if kind == "normalized":
        s = sp.diags(1.0 / np.sqrt(d))
        return sp.csr_matrix(s @ L @ s)
    return sp.csr_matrix(sp.diags(1.0 / d) @ L)


# -- cache ------------------------------------------------------------------------------------
#: spectra computed in this process (the last 32), keyed by the key text of :func:`_spectrum_key`
SPECTRUM_CACHE = LRUCache(32, name="spectra")
_CACHE_DIR: Path | None = None


def set_cache_dir(path: str | os.PathLike | None) -> None:
    """Also cache spectra on disk in ``path`` (None: memory only). ``$TOOLKIT_CACHE_DIR`` sets
    the default."""
    global _CACHE_DIR
    _CACHE_DIR = Path(path) if path is not None else None
    if _CACHE_DIR is not None:
        _CACHE_DIR.mkdir(parents=True, exist_ok=True)


def _cache_dir() -> Path | None:
    if _CACHE_DIR is not None:
        return _CACHE_DIR
    env = os.environ.get("TOOLKIT_CACHE_DIR")
    return Path(env) if env else None


def clear_cache() -> None:
    """Forget every spectrum cached in memory (:data:`SPECTRUM_CACHE`; disk files are left alone)."""
    SPECTRUM_CACHE.clear()


def _cache_key(graph: ShapeGraph, *parts: object) -> str:
    """The cache key text: the graph's content hash (weights and mass), its weighting, the request
    and the format version. Its SHA-1 names the file; the file holds the text itself."""
    return json.dumps([_CACHE_VERSION, graph.content_hash, graph.weighting, *map(repr, parts)])


def _cache_file(d: Path, key: str) -> Path:
    return d / f"{hashlib.sha1(key.encode()).hexdigest()}.npz"


class CacheWarning(UserWarning):
    """A disk cache file was corrupt or belonged to another key: it was ignored and recomputed."""


_REPORTED: set[str] = set()


def _report_bad_cache(path: Path, problem: str) -> None:
    if str(path) not in _REPORTED:  # once per file and process
        _REPORTED.add(str(path))
        warnings.warn(f"spectrum cache file {path} ignored ({problem}); recomputing it", CacheWarning, stacklevel=3)


def _read_cache_file(path: Path, key: str) -> Spectrum | None:
    """The spectrum cached in ``path`` when the file is readable and holds ``key``; else None (a
    miss, reported once)."""
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:  # fh: closed on a bad zip too
            stored = str(z["cache_key"]) if "cache_key" in z.files else ""
        if stored != key:
            _report_bad_cache(path, "written for another key" if stored else "no key: an older format")
            return None
        return Spectrum.load(path)
    except Exception as exc:  # truncated, empty, not an npz, inconsistent: all a miss
        _report_bad_cache(path, f"unreadable: {type(exc).__name__}")
        return None


def _cache_get(key: str) -> Spectrum | None:
    d = _cache_dir()
    spec = SPECTRUM_CACHE.get(key)
    if spec is not None:
        if d is not None and not _cache_file(d, key).exists():  # a new cache folder gets it too
            _cache_put(key, spec)
        return spec
    if d is not None and (path := _cache_file(d, key)).exists():
        spec = _read_cache_file(path, key)
        if spec is not None:
            _cache_put(key, spec, disk=False)
        return spec
    return None


def _cache_put(key: str, spec: Spectrum, disk: bool = True) -> None:
    SPECTRUM_CACHE.put(key, spec)
    d = _cache_dir()
    if disk and d is not None:
        with atomic_output(_cache_file(d, key), "spectrum cache file", suffix=".npz", make_parents=True) as tmp:
            spec.save(tmp, cache_key=key)


# -- solving ----------------------------------------------------------------------------------
def _solve(W: sp.csr_matrix, mass: np.ndarray | None, k: int, laplacian: str, solver: Any):
    d = np.asarray(W.sum(axis=1)).ravel()
    L = sp.csr_matrix(sp.diags(d) - W)
    # a diagonal mass goes to the solver as its diagonal vector: no sparse diagonal matrix to build and scan
    if laplacian == "combinatorial":
        return solver(L, k, None if mass is None else np.asarray(mass, dtype=np.float64))
    _require_positive_degrees(d, laplacian)
    # both go through the better-conditioned generalized problem (D - W) v = lambda D v (eq. 2.79)
    vals, v = solver(L, k, d)
    if laplacian == "normalized":
        u = v * np.sqrt(d)[:, None]
        return vals, u / np.linalg.norm(u, axis=0)
    return vals, v


def _spectrum_key(
    graph: ShapeGraph, k: int, laplacian: str, use_mass: bool, sign_fix: bool, components: str, solver: Any
) -> str:
    """The cache key of :func:`compute_spectrum` (``use_mass`` resolved); the default ``solver`` adds nothing
    to it, so keys of earlier versions hold."""
    solver_part = () if solver is None or solver == EigenSolver() else (solver,)
    return _cache_key(graph, int(k), laplacian, bool(use_mass), bool(sign_fix), components, *solver_part)


def _resolve_use_mass(graph: ShapeGraph, laplacian: str, use_mass: bool | None) -> bool:
    if use_mass is None:
        return graph.mass is not None and laplacian == "combinatorial"
    return bool(use_mass)


def is_cached(
    graph: ShapeGraph,
    k: int,
    *,
    laplacian: str = "combinatorial",
    use_mass: bool | None = None,
    sign_fix: bool = False,
    components: str = "raise",
    solver: Any = None,
) -> bool:
    """True when :func:`compute_spectrum` with these arguments would be served from the cache."""
    use_mass = _resolve_use_mass(graph, laplacian, use_mass)
    return _cache_get(_spectrum_key(graph, k, laplacian, use_mass, sign_fix, components, solver)) is not None


def compute_spectrum(
    graph: ShapeGraph,
    k: int,
    *,
    laplacian: str = "combinatorial",
    use_mass: bool | None = None,
    sign_fix: bool = False,
    components: str = "raise",
    cache: bool = True,
    solver: Any = None,
) -> Spectrum:
    """The ``k`` smallest eigenpairs of the chosen Laplacian of ``graph``, ascending.

    ``use_mass`` (default: whenever the graph has a mass and ``laplacian='combinatorial'``) solves
    ``L u = lambda M u``. A disconnected graph raises :class:`DisconnectedGraphError` unless
    ``components='largest'``, which analyses the largest component only (the other vertices get
    zero rows; ``meta['vertices']`` lists the analysed ones); see also :func:`component_spectra`.
    ``solver``: the eigensolver object, called as ``solver(L, k, M)`` (default :class:`EigenSolver()`, i.e.
    :func:`~shape_toolkit.core.eigen.smallest_eigenpairs` with ``method="auto"``); another one is part of the
    cache key through its ``repr``.
    """
    if laplacian not in LAPLACIANS:
        raise ParameterError(f"unknown Laplacian {laplacian!r}; choose one of {', '.join(LAPLACIANS)}")
    if components not in ("raise", "largest"):
        raise ParameterError(f"components must be 'raise' or 'largest', got {components!r}")
    n = graph.n_vertices
    if not isinstance(k, (int, np.integer)) or not 1 <= k <= n:
        raise ParameterError(f"k must be an integer in [1, {n}] (the vertex count), got {k}")
    use_mass = _resolve_use_mass(graph, laplacian, use_mass)
    if use_mass and graph.mass is None:
        raise ParameterError(f"weighting {graph.weighting!r} provides no mass matrix")
    if use_mass and laplacian != "combinatorial":
        raise ParameterError("the mass matrix applies to the combinatorial Laplacian only")
    if use_mass and np.any(graph.mass <= 0):
        raise ParameterError(
            f"{int(np.sum(graph.mass <= 0))} vertices have zero mass (unreferenced or degenerate): "
            "clean the shape first (shape-toolkit clean; from Python: clean_shape)"
        )
    key = _spectrum_key(graph, k, laplacian, use_mass, sign_fix, components, solver)
    if cache and (hit := _cache_get(key)) is not None:
        return hit

    n_comp, labels = graph.components
    W, mass = graph.W, graph.mass if use_mass else None
    vertices = None
    if n_comp > 1:
        sizes = np.bincount(labels)
        if components == "raise":
            from shape_toolkit.core.inspect import duplicate_vertex_map

            first = duplicate_vertex_map(graph.shape.vertices)  # an unwelded mesh: merging joins the pieces
            coincident = int(np.sum(first != np.arange(len(first))))
            raise DisconnectedGraphError(n_comp, sorted(sizes.tolist(), reverse=True), coincident=coincident)
        vertices = np.flatnonzero(labels == int(np.argmax(sizes)))
        if not 1 <= k <= len(vertices):
            raise ParameterError(f"k must be in [1, {len(vertices)}] (largest component)")
        W = W[vertices][:, vertices]
        mass = mass[vertices] if mass is not None else None
    vals, vecs = _solve(sp.csr_matrix(W), mass, int(k), laplacian, EigenSolver() if solver is None else solver)
    vals = np.maximum(vals, 0.0) if vals[0] > -1e-9 * max(abs(vals[-1]), 1.0) else vals
    # Numerically disconnected: one zero eigenvalue per component is expected (thesis 2.6.1), here
    # one (the analysed graph is connected). The spectrum's scale is the median of L_ii / M_ii (M the
    # mass, the identity, or D for the normalized and random-walk Laplacians, where it is 1): the
    # mean eigenvalue of the whole spectrum is tr(M^-1 L) / n, and the median is its robust version,
    # blind to a few near-zero masses of degenerate vertices. Eigenvalues below 1e-8 of it (the
    # solver's relative tolerance) -- or counted null by null_count, which methods use to skip null
    # eigenpairs -- are zero to solver precision; more than one means a cut of (next to) no weight.
    d_sub = np.asarray(sp.csr_matrix(W).sum(axis=1)).ravel()
    if laplacian == "combinatorial":
        scale = float(np.median(d_sub / mass)) if mass is not None else float(np.median(d_sub))
    else:
        scale = 1.0
    null_tol = 1e-8 * max(scale, 0.0)
    n_null = max(int(np.sum(vals <= null_tol)), null_count(vals))
    if n_null > 1:
        from shape_toolkit.errors import COMPONENT_OPTIONS, NumericallyDisconnectedGraphError

        shown = ", ".join(f"{x:.2e}" for x in vals[: min(len(vals), n_null + 1)])
        what = "connected" if vertices is None else f"largest component ({len(vertices)} vertices) is connected"
        hint = graph.hint or ("use a weighting whose weights do not vanish (binary, intrinsic-delaunay, "
                              "gaussian with its default local bandwidth)")
        raise NumericallyDisconnectedGraphError(
            f"the shape graph is structurally {what} but numerically disconnected: the {laplacian} "
            f"Laplacian ({graph.weighting!r} weights) has {n_null} eigenvalues that are zero to solver "
            f"precision (<= {null_tol:.2e}, 1e-8 of the spectrum's typical scale; first eigenvalues: {shown}), "
            "so some cut of its edges weighs next to nothing and the spectrum would mix unrelated pieces. "
            f"To fix: {hint}. If the pieces are really separate parts, split them: {COMPONENT_OPTIONS}",
            n_null, n_comp, sorted(np.bincount(labels).tolist(), reverse=True),
        )
    if sign_fix:
        vecs = fix_signs(vecs)
    degrees = graph.degrees
    if vertices is not None:
        full = np.zeros((n, vecs.shape[1]))
        full[vertices] = vecs
        vecs = full
    spec = Spectrum(
        np.ascontiguousarray(vals),
        np.ascontiguousarray(vecs),
        laplacian,
        graph.weighting,
        graph.mass if use_mass else None,
        degrees,
        bool(sign_fix),
        {"weighting_params": dict(graph.params), **({"vertices": vertices} if vertices is not None else {})},
    )
    if cache:
        _cache_put(key, spec)
    return spec


def component_spectra(
    graph: ShapeGraph, k: int, **kwargs: Any
) -> list[tuple[np.ndarray, Spectrum]]:
    """One spectrum per connected component: ``[(vertex ids, Spectrum of that subgraph)]``,
    largest component first; ``k`` is capped at each component's size."""
    from shape_toolkit.core.graph import ShapeGraph as _G

    n_comp, labels = graph.components
    out = []
    for c in np.argsort(-np.bincount(labels), kind="stable"):
        ids = np.flatnonzero(labels == c)
        sub = _G(
            graph.shape.submesh(ids)[0],
            sp.csr_matrix(graph.W[ids][:, ids]),
            graph.mass[ids] if graph.mass is not None else None,
            graph.weighting,
            graph.params,
            graph.info,
        )
        out.append((ids, compute_spectrum(sub, min(k, len(ids)), **kwargs)))
    return out


def null_count(eigenvalues: np.ndarray, rtol: float = 1e-8) -> int:
    """Number of eigenvalues ``<= rtol * max(|eigenvalue|, 1e-300)``: the null space of a
    Laplacian, one per connected component (thesis 2.6.1). ``eigenvalues`` ascending ``(k,)``."""
    vals = np.asarray(eigenvalues, dtype=np.float64)
    if vals.size == 0:
        return 0
    scale = max(float(np.abs(vals).max()), 1e-300)
    return int(np.sum(vals <= rtol * scale))
