"""Graph Laplacians (thesis 2.6.1) and their smallest eigenpairs, cached by content."""

from __future__ import annotations

import hashlib
import os
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from .eigen import smallest_eigenpairs
from .errors import DisconnectedGraphError, ParameterError
from .graph import ShapeGraph

__all__ = [
    "LAPLACIANS",
    "Spectrum",
    "laplacian_matrix",
    "compute_spectrum",
    "component_spectra",
    "fix_signs",
    "set_cache_dir",
    "clear_cache",
    "is_cached",
]

LAPLACIANS = ("combinatorial", "normalized", "random-walk")
_CACHE_VERSION = "1"


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

    def save(self, path: str | os.PathLike) -> None:
        """Write the spectrum to an ``.npz`` file."""
        np.savez(
            path,
            eigenvalues=self.eigenvalues,
            eigenvectors=self.eigenvectors,
            laplacian=self.laplacian,
            weighting=self.weighting,
            mass=self.mass if self.mass is not None else np.zeros(0),
            degrees=self.degrees,
            sign_fixed=self.sign_fixed,
        )

    @classmethod
    def load(cls, path: str | os.PathLike) -> Spectrum:
        """Read a spectrum written by :meth:`save`."""
        with np.load(path, allow_pickle=False) as z:
            mass = z["mass"]
            return cls(
                z["eigenvalues"], z["eigenvectors"], str(z["laplacian"]), str(z["weighting"]),
                mass if mass.size else None, z["degrees"], bool(z["sign_fixed"]),
            )


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


def fix_signs(vectors: np.ndarray) -> np.ndarray:
    """Flip each column of ``(n, k)`` ``vectors`` so that its third moment is positive, falling
    back to its largest-magnitude entry; invariant to vertex permutation and to sign flips."""
    out = np.array(vectors, dtype=np.float64, copy=True)
    for j in range(out.shape[1]):
        u = out[:, j]
        skew = float(np.sum(u**3))
        scale = float(np.sum(np.abs(u) ** 3))
        if abs(skew) > 1e-8 * max(scale, 1e-300):
            s = np.sign(skew)
        else:
            i = int(np.argmax(np.abs(u)))
            s = np.sign(u[i]) or 1.0
        out[:, j] = s * u
    return out


# -- cache ------------------------------------------------------------------------------------
_MEMORY: OrderedDict[str, Spectrum] = OrderedDict()
_MEMORY_MAX = 32
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
    """Forget every spectrum cached in memory (disk files are left alone)."""
    _MEMORY.clear()


def _cache_key(graph: ShapeGraph, *parts: object) -> str:
    h = hashlib.sha1(graph.content_hash.encode())
    h.update(repr((_CACHE_VERSION, graph.weighting) + parts).encode())
    return h.hexdigest()


def _cache_get(key: str) -> Spectrum | None:
    if key in _MEMORY:
        _MEMORY.move_to_end(key)
        return _MEMORY[key]
    d = _cache_dir()
    if d is not None and (d / f"{key}.npz").exists():
        try:
            spec = Spectrum.load(d / f"{key}.npz")
        except (OSError, ValueError, KeyError):
            return None
        _cache_put(key, spec, disk=False)
        return spec
    return None


def _cache_put(key: str, spec: Spectrum, disk: bool = True) -> None:
    _MEMORY[key] = spec
    _MEMORY.move_to_end(key)
    while len(_MEMORY) > _MEMORY_MAX:
        _MEMORY.popitem(last=False)
    d = _cache_dir()
    if disk and d is not None:
        d.mkdir(parents=True, exist_ok=True)
        tmp = d / f".{key}.{os.getpid()}.tmp.npz"
        spec.save(tmp)
        os.replace(tmp, d / f"{key}.npz")


# -- solving ----------------------------------------------------------------------------------
def _solve(W: sp.csr_matrix, mass: np.ndarray | None, k: int, laplacian: str):
    d = np.asarray(W.sum(axis=1)).ravel()
    L = sp.csr_matrix(sp.diags(d) - W)
    if laplacian == "combinatorial":
        M = sp.diags(mass) if mass is not None else None
        return smallest_eigenpairs(L, k, M)
    _require_positive_degrees(d, laplacian)
    # both go through the better-conditioned generalized problem (D - W) v = lambda D v (eq. 2.79)
    vals, v = smallest_eigenpairs(L, k, sp.diags(d))
    if laplacian == "normalized":
        u = v * np.sqrt(d)[:, None]
        return vals, u / np.linalg.norm(u, axis=0)
    return vals, v


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
) -> bool:
    """True when :func:`compute_spectrum` with these arguments would be served from the cache."""
    use_mass = _resolve_use_mass(graph, laplacian, use_mass)
    key = _cache_key(graph, int(k), laplacian, use_mass, bool(sign_fix), components)
    return _cache_get(key) is not None


def compute_spectrum(
    graph: ShapeGraph,
    k: int,
    *,
    laplacian: str = "combinatorial",
    use_mass: bool | None = None,
    sign_fix: bool = False,
    components: str = "raise",
    cache: bool = True,
) -> Spectrum:
    """The ``k`` smallest eigenpairs of the chosen Laplacian of ``graph``, ascending.

    ``use_mass`` (default: whenever the graph has a mass and ``laplacian='combinatorial'``) solves
    ``L u = lambda M u``. A disconnected graph raises :class:`DisconnectedGraphError` unless
    ``components='largest'``, which analyses the largest component only (the other vertices get
    zero rows; ``meta['vertices']`` lists the analysed ones); see also :func:`component_spectra`.
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
            "clean the shape first"
        )
    key = _cache_key(graph, int(k), laplacian, bool(use_mass), bool(sign_fix), components)
    if cache and (hit := _cache_get(key)) is not None:
        return hit

    n_comp, labels = graph.components
    W, mass = graph.W, graph.mass if use_mass else None
    vertices = None
    if n_comp > 1:
        sizes = np.bincount(labels)
        if components == "raise":
            raise DisconnectedGraphError(n_comp, sorted(sizes.tolist(), reverse=True))
        vertices = np.flatnonzero(labels == int(np.argmax(sizes)))
        if not 1 <= k <= len(vertices):
            raise ParameterError(f"k must be in [1, {len(vertices)}] (largest component)")
        W = W[vertices][:, vertices]
        mass = mass[vertices] if mass is not None else None
    vals, vecs = _solve(sp.csr_matrix(W), mass, int(k), laplacian)
    vals = np.maximum(vals, 0.0) if vals[0] > -1e-9 * max(abs(vals[-1]), 1.0) else vals
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
        {"vertices": vertices} if vertices is not None else {},
    )
    if cache:
        _cache_put(key, spec)
    return spec


def component_spectra(
    graph: ShapeGraph, k: int, **kwargs: Any
) -> list[tuple[np.ndarray, Spectrum]]:
    """One spectrum per connected component: ``[(vertex ids, Spectrum of that subgraph)]``,
    largest component first; ``k`` is capped at each component's size."""
    from .graph import ShapeGraph as _G

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
