"""Peer implementations run side by side with the toolkit in benchmarks (``peer = "NAME"`` in a
matching task of a config): the one copy of each peer's pipeline.

``pyfm``: pyFM (pip ``pyfmaps``, pinned to 1.3.1 in the ``bench`` extra), the quick-start pipeline
of its README: ``TriMesh(..., area_normalize=True, center=True)``, ``preprocess(descr_type="WKS",
subsample_step=2)``, ``fit(K=30, w_descr=1, w_lap=0.1, w_dcomm=1, w_orient=1)``,
``zoomout_refine(nit=16, step=5)``, ``get_p2p``. pyFM's ``p2p_21`` maps its second mesh to its
first, so its first mesh is our target. A peer computes its own Laplacian spectrum inside its
timed call (the toolkit's methods get theirs from the run's cache, timed separately).

``scipy-eigsh`` (``peer = "scipy-eigsh"`` in a spectrum task): the spectrum of the same Laplacian and mass
computed by SciPy's shift-invert ``eigsh`` instead of the toolkit's eigensolver (:class:`ScipyEigsh`).

``maps``: published maps read from files (``peer = "maps"``, ``path = "maps/BCICP"``: a folder
relative to the dataset's, holding ``A_B.map`` for the pair (A, B): one 1-based vertex id of B per
vertex of A, as the BIM and BCICP maps of ``tosca_noniso``). Each file is validated strictly
(:func:`read_map_file`): a missing file, a length other than A's vertex count, a token that is not
an integer or an id outside ``0..n_B`` raise :class:`~shape_toolkit.errors.ShapeFileError` naming
the file; ``0`` is the files' "no vertex" (a few BIM maps hold it on 1-3 vertices) and becomes an
unmatched vertex (-1), left out of the mean error and counted by ``matched_fraction``. Nothing in
a file is executed or unpickled: it is read as text integers. Its row has no time or memory (null:
the published method's own cost is not known here; reading the file is not it).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError, ShapeFileError
from shape_toolkit.results.correspondence import Correspondence

__all__ = ["PEERS", "SPECTRUM_PEERS", "Peer", "MapsPeer", "ScipyEigsh", "create_peer", "create_spectrum_peer",
           "pyfm_map", "read_map_file", "map_file"]


def pyfm_map(source: Shape, target: Shape) -> np.ndarray:
    """pyFM's README quick start from ``source`` to ``target``: int64 ``(n_source,)`` target vertex
    of each source vertex."""
    from pyFM.functional import FunctionalMapping
    from pyFM.mesh import TriMesh

    source.require_faces("pyFM")
    target.require_faces("pyFM")
    mesh1 = TriMesh(np.array(target.vertices), np.array(target.faces), area_normalize=True, center=True)
    mesh2 = TriMesh(np.array(source.vertices), np.array(source.faces), area_normalize=True, center=True)
    model = FunctionalMapping(mesh1, mesh2)
    model.preprocess(descr_type="WKS", subsample_step=2, verbose=False)
    model.fit(K=30, w_descr=1e0, w_lap=1e-1, w_dcomm=1e0, w_orient=1e0, verbose=False)
    fm = model.zoomout_refine(nit=16, step=5, verbose=False)
    return np.asarray(model.get_p2p(fm), dtype=np.int64)


class Peer:
    """A peer method with the dense-matcher call of the benchmark (``match(source, target, **_)``
    returning a :class:`Correspondence`); it declares no spectrum (it computes its own)."""

    def __init__(self, name: str, fn: Callable[[Shape, Shape], np.ndarray], package: str):
        self.name, self.fn, self.package = name, fn, package

    def match(self, source: Shape, target: Shape, **_: Any) -> Correspondence:
        """The peer's map from ``source`` to ``target``."""
        import warnings

        with warnings.catch_warnings():  # a peer's own deprecation chatter is not ours to show
            warnings.simplefilter("ignore")
            t = self.fn(source, target)
        return Correspondence(t, target.n_vertices, info={"peer": self.name, "package": self.package})

    def __repr__(self) -> str:
        return f"Peer({self.name!r}, {self.package})"


def read_map_file(path: str | os.PathLike, n_source: int, n_target: int) -> np.ndarray:
    """A published map file: one 1-based target vertex id per source vertex (``0``: no vertex), as
    int64 ``(n_source,)`` 0-based target ids (-1 where the file says 0). Any problem raises
    :class:`ShapeFileError` naming the file: missing, not integers, ``n_source`` lines expected,
    ids outside ``0..n_target``."""
    from shape_toolkit.results.labels import read_int_file

    p = Path(path)
    if not p.is_file():
        raise ShapeFileError(p, "published map file not found")
    ids = read_int_file(p, "map")  # integers of a text file, nothing else is read
    if ids.size != n_source:
        raise ShapeFileError(p, f"has {ids.size} vertex ids, expected one per source vertex ({n_source})")
    bad = np.flatnonzero((ids < 0) | (ids > n_target))
    if bad.size:
        raise ShapeFileError(p, f"line {int(bad[0]) + 1}: vertex id {int(ids[bad[0]])} is outside 1..{n_target} "
                             "(1-based target ids; 0 for no vertex)")
    return np.where(ids > 0, ids - 1, -1).astype(np.int64)


def map_file(folder: str | os.PathLike, path: str, source_name: str, target_name: str) -> Path:
    """Where the published map of the pair ``(source_name, target_name)`` lies: ``folder/path/A_B.map``."""
    return Path(folder) / path / f"{source_name}_{target_name}.map"


class MapsPeer:
    """Published maps read from files as a peer (``peer = "maps"``): ``path`` is the folder of the
    ``A_B.map`` files relative to the dataset's folder; see the module docstring."""

    name = "maps"
    package = "published maps"

    def __init__(self, path: str):
        if not isinstance(path, str) or not path or Path(path).is_absolute() or ".." in Path(path).parts:
            raise ParameterError(f"maps: path must be a folder relative to the dataset's, got {path!r}")
        self.path = path

    def match_item(self, prepared: Any) -> Correspondence:
        """The published map of a prepared pair (its ``meta`` names the dataset folder and the pair)."""
        meta = getattr(prepared, "meta", {}) or {}
        if "folder" not in meta or "pair" not in meta:
            raise ParameterError(f"item {prepared.name!r}: published maps need a pair dataset (kind = \"tosca\")")
        target = prepared.target
        vmap = np.asarray(prepared.vertex_map)
        if vmap.size != target.n_vertices or not np.array_equal(vmap, np.arange(vmap.size)):
            raise ParameterError(f"item {prepared.name!r}: a published map is a map of the clean pair, "
                                 "not of a corrupted target")
        path = map_file(meta["folder"], self.path, *meta["pair"])
        t = read_map_file(path, prepared.source.n_vertices, target.n_vertices)
        return Correspondence(t, target.n_vertices, info={"peer": "maps", "file": str(path)})

    def match(self, source: Shape, target: Shape, **_: Any) -> Correspondence:
        """Refused: a published map belongs to a dataset pair, not to two shapes."""
        raise ParameterError("the maps peer reads a dataset pair's published map; it cannot match two shapes")

    def __repr__(self) -> str:
        return f"MapsPeer({self.path!r})"


#: peer name -> (function, distribution, import module)
PEERS: dict[str, tuple[Callable[[Shape, Shape], np.ndarray], str, str]] = {
    "pyfm": (pyfm_map, "pyfmaps", "pyFM"),
}


def create_peer(name: str, **params: Any) -> Peer | MapsPeer:
    """The peer ``name`` of :data:`PEERS`, or ``maps`` (``path=`` the maps' folder);
    :class:`ParameterError` when unknown, not installed, or given parameters it does not take."""
    import importlib.util

    if name == "maps":
        if set(params) != {"path"}:
            raise ParameterError('peer "maps" needs path = "FOLDER" (the A_B.map files, relative to the dataset)')
        return MapsPeer(params["path"])
    if name not in PEERS:
        raise ParameterError(f"unknown peer {name!r}; known: {', '.join(sorted([*PEERS, 'maps']))}")
    if params:
        raise ParameterError(f"peer {name!r} takes no parameters (it runs its own published pipeline)")
    fn, dist, module = PEERS[name]
    if importlib.util.find_spec(module) is None:
        raise ParameterError(
            f"peer {name!r} needs {dist} (import {module}), which is not installed: "
            "pip install 'shape-toolkit[bench]'"
        )
    import importlib.metadata

    try:
        version = importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:  # pragma: no cover - installed from source
        version = "unknown"
    return Peer(name, fn, f"{dist} {version}")


# -- eigensolver peers (``peer = "scipy-eigsh"`` in a spectrum task) ---------------------------------------
@dataclass(frozen=True)
class ScipyEigsh:
    """SciPy's ``eigsh`` in shift-invert mode (SuperLU factor of ``A - sigma M``, ARPACK Lanczos), as
    pyFM and LaPy compute a Laplacian spectrum; ``sigma`` is the toolkit solver's default shift
    (``-1e-8 max(diag(A) / diag(M))``), so both solve the same shifted problem. Called as a spectrum
    solver, ``solver(A, k, M)`` -> eigenvalues ``(k,)`` ascending and eigenvectors ``(n, k)``."""

    tol: float = 0.0

    def __call__(
        self, A: sp.spmatrix, k: int, M: np.ndarray | sp.spmatrix | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` smallest eigenpairs of ``A u = lambda M u`` by ``scipy.sparse.linalg.eigsh``."""
        import scipy.sparse.linalg as sla

        A = sp.csr_matrix(A, dtype=np.float64)
        n = A.shape[0]
        if M is None:
            Ms = None
        else:
            Ms = sp.diags(np.asarray(M, np.float64)).tocsr() if np.ndim(M) == 1 else sp.csr_matrix(M)
        dm = np.ones(n) if Ms is None else Ms.diagonal()
        sigma = -1e-8 * float(np.max(A.diagonal() / dm))
        if k >= n - 1:  # ARPACK needs k < n - 1: what eigsh's users do, a dense solve
            import scipy.linalg as la

            vals, vecs = la.eigh(A.toarray(), None if Ms is None else Ms.toarray(), subset_by_index=(0, k - 1))
            return vals, vecs
        vals, vecs = sla.eigsh(A, k=int(k), M=Ms, sigma=sigma, which="LM", tol=self.tol)
        order = np.argsort(vals)
        return vals[order], vecs[:, order]


def _toolkit_solver(method: str) -> Callable[[], Any]:
    """A factory of the toolkit's own eigensolver with ``method`` fixed (:class:`shape_toolkit.core.eigen.EigenSolver`):
    the solvers ``auto`` chooses between, as rows of their own (e.g. the dense-vs-Krylov crossover)."""
    def make() -> Any:
        from shape_toolkit.core.eigen import EigenSolver

        return EigenSolver(method=method)

    return make


#: eigensolver peer name -> (solver factory, distribution): SciPy's eigsh, and the toolkit's solver with its
#: method fixed (``toolkit-dense``: LAPACK; ``toolkit-krylov``: block Krylov-Schur; ``toolkit-arpack``: ARPACK on
#: the CHOLMOD factor), which ``auto`` (the plain ``plugin`` row) picks between
SPECTRUM_PEERS: dict[str, tuple[Callable[[], Any], str]] = {
    "scipy-eigsh": (ScipyEigsh, "scipy"),
    "toolkit-dense": (_toolkit_solver("dense"), "shape-toolkit"),
    "toolkit-krylov": (_toolkit_solver("krylov"), "shape-toolkit"),
    "toolkit-arpack": (_toolkit_solver("arpack"), "shape-toolkit"),
}


def create_spectrum_peer(name: str) -> Any:
    """The eigensolver peer ``name`` of :data:`SPECTRUM_PEERS` (a ``solver(A, k, M)`` callable);
    :class:`ParameterError` when unknown."""
    if name not in SPECTRUM_PEERS:
        raise ParameterError(f"unknown eigensolver peer {name!r}; known: {', '.join(sorted(SPECTRUM_PEERS))}")
    return SPECTRUM_PEERS[name][0]()
