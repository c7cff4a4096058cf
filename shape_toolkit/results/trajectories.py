"""Dense trajectories through a sequence of frames (thesis 7.5.3, Figs. 7.17-7.18) as data.

A :class:`Trajectories` holds, for every vertex ``j`` of frame 0, the vertex it has reached in each
frame: an int64 ``(n_0, T)`` array ``ids`` (``ids[:, 0] = arange(n_0)``, ``-1`` once a trajectory is
lost, i.e. a frame map left its vertex unmatched). :func:`chain_maps` builds it by composing the
maps of consecutive frames (``Correspondence.target_of`` arrays); :func:`compose_maps` composes a
list of maps into one. :meth:`Trajectories.save` / :meth:`Trajectories.load` use ``.npz`` files
read with ``allow_pickle=False`` (no object arrays; the metadata is a JSON string).
:func:`trajectory_drift` measures, per frame, how far the tracked vertices are from the true ones.
"""

from __future__ import annotations

import json
import os
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError, ShapeFileError
from shape_toolkit.results.correspondence import Correspondence
from shape_toolkit.validation import atomic_output, dumps_json

__all__ = [
    "Trajectories",
    "chain_maps",
    "compose_maps",
    "trajectory_drift",
    "DRIFT_METHODS",
]

#: file format tag written into every trajectory ``.npz``
FORMAT = "shape-toolkit-trajectories/1"
#: distance kinds of :func:`trajectory_drift`: Euclidean, or a method of ``features.geodesics``
DRIFT_METHODS = ("euclidean", "dijkstra", "exact", "fmm", "heat")


@dataclass(frozen=True, eq=False)
class Trajectories:
    """Dense trajectories: ``ids`` int64 ``(n_0, T)`` (vertex of frame ``t`` reached by the
    trajectory starting at vertex ``j`` of frame 0, ``-1`` when lost), ``n_vertices`` the vertex
    count of each frame ``(T,)``, ``info`` JSON-able metadata (pipeline, timings, frame names)."""

    ids: np.ndarray
    n_vertices: tuple[int, ...]
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        a = np.asarray(self.ids)
        if a.ndim != 2 or a.shape[1] < 1 or a.shape[0] < 1:
            raise ParameterError(f"trajectory ids must be a non-empty (n_0, T) array, got shape {a.shape}")
        if not np.issubdtype(a.dtype, np.integer):
            raise ParameterError(f"trajectory ids must be integers, got {a.dtype}")
        a = a.astype(np.int64, copy=True)
        nv = tuple(int(x) for x in np.asarray(self.n_vertices).ravel())
        if len(nv) != a.shape[1]:
            raise ParameterError(f"n_vertices has {len(nv)} entries for {a.shape[1]} frames")
        if nv[0] != a.shape[0] or min(nv) < 1:
            raise ParameterError(f"frame 0 has {nv[0]} vertices but there are {a.shape[0]} trajectories")
        if a.min() < -1 or np.any(a.max(axis=0) >= np.asarray(nv)):
            raise ParameterError("trajectory ids must lie in [-1, n_t - 1] for each frame t")
        if not np.array_equal(a[:, 0], np.arange(a.shape[0])):
            raise ParameterError("trajectory j must start at vertex j of frame 0")
        lost = a < 0
        if np.any(lost[:, :-1] & ~lost[:, 1:]):
            raise ParameterError("a lost trajectory (-1) cannot reappear in a later frame")
        a.setflags(write=False)
        object.__setattr__(self, "ids", a)
        object.__setattr__(self, "n_vertices", nv)
        object.__setattr__(self, "info", dict(self.info or {}))

    @property
    def n_frames(self) -> int:
        """Number of frames ``T``."""
        return int(self.ids.shape[1])

    @property
    def n_tracks(self) -> int:
        """Number of trajectories ``n_0`` (the vertices of frame 0)."""
        return int(self.ids.shape[0])

    @property
    def alive(self) -> np.ndarray:
        """Boolean ``(n_0, T)``: the trajectory still has a vertex in frame ``t``."""
        return self.ids >= 0

    def positions(self, shapes: Sequence[Shape]) -> np.ndarray:
        """Coordinates ``(n_0, T, 3)`` of the tracked vertices in the ``T`` frame ``shapes`` (NaN
        where lost), in the shapes' length units."""
        self._check_shapes(shapes)
        out = np.full((self.n_tracks, self.n_frames, 3), np.nan)
        for t, s in enumerate(shapes):
            ok = self.ids[:, t] >= 0
            out[ok, t] = s.vertices[self.ids[ok, t]]
        return out

    def _check_shapes(self, shapes: Sequence[Shape]) -> None:
        if len(shapes) != self.n_frames:
            raise ParameterError(f"{len(shapes)} shapes given for {self.n_frames} frames")
        for t, s in enumerate(shapes):
            if s.n_vertices != self.n_vertices[t]:
                raise ParameterError(
                    f"frame {t} has {s.n_vertices} vertices, the trajectories expect {self.n_vertices[t]}"
                )

    def save(self, path: str | os.PathLike) -> Path:
        """Write ``path`` (``.npz``): arrays ``ids``, ``n_vertices`` and ``info`` (a JSON string,
        NaN as null), plus a format tag; written to a temporary file, then renamed."""
        p = Path(path)
        with atomic_output(p, ".npz file", suffix=".npz") as tmp:
            np.savez_compressed(
                tmp, ids=self.ids, n_vertices=np.asarray(self.n_vertices, dtype=np.int64),
                info=np.asarray(dumps_json(self.info)), format=np.asarray(FORMAT),
            )
        return p

    @classmethod
    def load(cls, path: str | os.PathLike) -> Trajectories:
        """Read a file written by :meth:`save` (``allow_pickle=False``); every problem (missing,
        not a zip, other format, bad arrays) is a :class:`ShapeFileError`."""
        p = Path(path)
        if not p.is_file():
            raise ShapeFileError(p, "no such trajectory file")
        try:
            with np.load(p, allow_pickle=False) as z:
                keys = set(z.files)
                need = {"ids", "n_vertices", "info", "format"}
                if not need <= keys:
                    raise ShapeFileError(p, f"not a trajectory file (missing {', '.join(sorted(need - keys))})")
                tag = z["format"]
                if tag.shape != () or str(tag) != FORMAT:
                    raise ShapeFileError(p, f"unknown trajectory format {str(tag)[:60]!r}")
                ids, nv, info = z["ids"], z["n_vertices"], z["info"]
        except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError) as exc:
            raise ShapeFileError(p, f"not a readable .npz trajectory file ({type(exc).__name__})") from None
        if info.shape != () or info.dtype.kind != "U":
            raise ShapeFileError(p, "the info entry must be a JSON string")
        try:
            meta = json.loads(str(info))
        except (json.JSONDecodeError, RecursionError):
            raise ShapeFileError(p, "the info entry is not valid JSON") from None
        if not isinstance(meta, dict):
            raise ShapeFileError(p, "the info entry must be a JSON object")
        if not np.issubdtype(ids.dtype, np.integer) or not np.issubdtype(nv.dtype, np.integer):
            raise ShapeFileError(p, "ids and n_vertices must be integer arrays")
        try:
            return cls(ids, tuple(nv.ravel().tolist()), meta)
        except ParameterError as exc:
            raise ShapeFileError(p, str(exc)) from None


def _map_array(m: Correspondence | np.ndarray, what: str) -> tuple[np.ndarray, int | None]:
    if isinstance(m, Correspondence):
        return m.target_of, m.n_target
    a = np.asarray(m)
    if a.ndim != 1 or (a.size and not np.issubdtype(a.dtype, np.integer)):
        raise ParameterError(f"{what} must be a Correspondence or a 1-D integer array")
    return a.astype(np.int64), None


def _check_chain(
    maps: Sequence[Correspondence | np.ndarray], n_vertices: Sequence[int] | None
) -> tuple[list[np.ndarray], list[int]]:
    """The maps as int64 arrays and the vertex counts of the ``len(maps) + 1`` frames, checked."""
    if len(maps) == 0:
        raise ParameterError("need at least one frame map")
    arrays, targets = zip(*(_map_array(m, f"map {i}") for i, m in enumerate(maps)))
    if n_vertices is None:
        counts = [arrays[0].size]
        for i, (a, nt) in enumerate(zip(arrays, targets)):
            nxt = nt if nt is not None else (arrays[i + 1].size if i + 1 < len(arrays) else int(a.max(initial=-1)) + 1)
            counts.append(int(nxt))
    else:
        counts = [int(x) for x in n_vertices]
        if len(counts) != len(arrays) + 1:
            raise ParameterError(f"n_vertices needs {len(arrays) + 1} counts for {len(arrays)} maps")
    for i, a in enumerate(arrays):
        if a.size != counts[i]:
            raise ParameterError(f"map {i} has {a.size} entries but frame {i} has {counts[i]} vertices")
        if targets[i] is not None and targets[i] != counts[i + 1]:
            raise ParameterError(f"map {i} targets {targets[i]} vertices but frame {i + 1} has {counts[i + 1]}")
        if a.size and (a.min() < -1 or a.max() >= counts[i + 1]):
            raise ParameterError(f"map {i} must hold vertex ids of frame {i + 1} in [-1, {counts[i + 1] - 1}]")
    return list(arrays), counts


def chain_maps(
    maps: Sequence[Correspondence | np.ndarray],
    *,
    n_vertices: Sequence[int] | None = None,
    info: dict[str, Any] | None = None,
) -> Trajectories:
    """Chain the maps of consecutive frames (map ``t``: frame ``t`` -> frame ``t + 1``, a
    :class:`Correspondence` or a ``target_of`` array ``(n_t,)`` with ``-1`` for unmatched) into
    :class:`Trajectories` ``(n_0, len(maps) + 1)``: ``ids[:, t + 1] = map_t[ids[:, t]]``; a
    trajectory reaching an unmatched vertex is lost (-1) from then on. ``n_vertices`` (one count
    per frame) is needed only when plain arrays leave the last frame's size unknown (default:
    the largest id + 1)."""
    arrays, counts = _check_chain(maps, n_vertices)
    ids = np.empty((counts[0], len(arrays) + 1), dtype=np.int64)
    ids[:, 0] = np.arange(counts[0])
    for t, a in enumerate(arrays):
        cur = ids[:, t]
        ok = cur >= 0
        ids[:, t + 1] = -1
        ids[ok, t + 1] = a[cur[ok]]
    return Trajectories(ids, tuple(counts), dict(info or {}))


def compose_maps(
    maps: Sequence[Correspondence | np.ndarray], *, n_vertices: Sequence[int] | None = None
) -> np.ndarray:
    """The composition of maps ``frame 0 -> 1 -> ... -> T`` as one ``target_of`` array
    ``(n_0,)`` of frame-``T`` vertex ids (``-1`` where any map on the way is unmatched)."""
    return chain_maps(maps, n_vertices=n_vertices).ids[:, -1].copy()


def _distances(shape: Shape, a: np.ndarray, b: np.ndarray, method: str) -> np.ndarray:
    """``d(a_i, b_i)`` on ``shape`` for vertex ids ``a``, ``b`` ``(p,)``: Euclidean, or geodesic
    (:func:`~shape_toolkit.features.geodesics.paired_geodesic_distances`)."""
    if method == "euclidean":
        return np.linalg.norm(shape.vertices[a] - shape.vertices[b], axis=1)
    from shape_toolkit.features.geodesics import paired_geodesic_distances

    return paired_geodesic_distances(shape, a, b, method=method)


def trajectory_drift(
    trajectories: Trajectories | np.ndarray,
    shapes: Sequence[Shape],
    truth: np.ndarray,
    *,
    vertex_maps: Sequence[np.ndarray] | None = None,
    method: str = "dijkstra",
    radius: float = 0.05,
    sample: int | None = None,
) -> dict[str, Any]:
    """Drift of dense trajectories against the ground truth, per frame.

    ``trajectories``: :class:`Trajectories` or ids ``(n_0, T)`` (``-1`` lost). ``shapes``: the
    ``T`` shapes distances are measured on (for glued frames, the clean ones), ``truth`` int
    ``(n_0, T)``: the true vertex of each trajectory on ``shapes[t]``, ``-1`` where the truth is
    undefined (a point welded away by a glued contact): such entries are left out of every
    statistic of that frame. ``sample``: measure only that many trajectories, evenly spaced in
    vertex order (geodesic rows cost one shortest-path tree each). ``vertex_maps`` (optional,
    one ``(n_t,)`` array per frame): the vertex of ``shapes[t]`` each vertex of frame ``t`` stands
    for (e.g. ``glue``'s vertex map); default the identity. The distance between tracked and true
    vertex is Euclidean (``method="euclidean"``) or geodesic (``"dijkstra"``: shortest paths along
    the edges, an upper bound, exact at 0 and on edges; ``"exact"``, ``"fmm"``, ``"heat"``: see
    ``features.geodesics``), divided by ``sqrt(area(shapes[t]))``.

    Returns lists of ``T`` values: ``mean``, ``median``, ``max`` over the measured trajectories
    still alive (None when none is), ``within`` (fraction of the measured trajectories within
    ``radius``; lost ones never are), ``lost`` (fraction lost) and ``n_measured``; plus
    ``radius``, ``method``, ``n_tracks`` and ``sample``.
    """
    ids = trajectories.ids if isinstance(trajectories, Trajectories) else np.asarray(trajectories)
    if ids.ndim != 2 or not np.issubdtype(ids.dtype, np.integer):
        raise ParameterError(f"trajectories must be an integer (n_0, T) array, got {ids.dtype} {ids.shape}")
    ids = ids.astype(np.int64)
    n0, T = ids.shape
    tr = np.asarray(truth)
    if tr.shape != (n0, T) or (tr.size and not np.issubdtype(tr.dtype, np.integer)):
        raise ParameterError(f"truth must be an integer array of shape {(n0, T)}, got {tr.dtype} {tr.shape}")
    tr = tr.astype(np.int64)
    if len(shapes) != T:
        raise ParameterError(f"{len(shapes)} shapes given for {T} frames")
    if method not in DRIFT_METHODS:
        raise ParameterError(f"method must be one of {', '.join(DRIFT_METHODS)}, got {method!r}")
    if not (np.isfinite(radius) and radius >= 0):
        raise ParameterError(f"radius must be a finite number >= 0, got {radius!r}")
    if vertex_maps is not None and len(vertex_maps) != T:
        raise ParameterError(f"{len(vertex_maps)} vertex maps given for {T} frames")
    if sample is not None:
        if isinstance(sample, bool) or not isinstance(sample, (int, np.integer)) or sample < 1:
            raise ParameterError(f"sample must be a positive integer or None, got {sample!r}")
        rows = np.unique(np.linspace(0, n0 - 1, min(int(sample), n0)).round().astype(np.int64))
        ids, tr = ids[rows], tr[rows]
    out: dict[str, Any] = {"mean": [], "median": [], "max": [], "within": [], "lost": [], "n_measured": [],
                           "radius": float(radius), "method": method, "n_tracks": int(n0),
                           "sample": None if sample is None else int(sample)}
    for t, shape in enumerate(shapes):
        n_ref = shape.n_vertices
        if tr[:, t].min() < -1 or tr[:, t].max() >= n_ref:
            raise ParameterError(f"truth of frame {t} must hold vertex ids in [-1, {n_ref - 1}]")
        defined = tr[:, t] >= 0
        cur = ids[defined, t]
        true_t = tr[defined, t]
        if vertex_maps is not None:
            vm = np.asarray(vertex_maps[t], dtype=np.int64).ravel()
            if vm.size and (vm.min() < 0 or vm.max() >= n_ref):
                raise ParameterError(f"vertex map {t} must hold vertex ids in [0, {n_ref - 1}]")
            if cur.size and cur.max() >= vm.size:
                raise ParameterError(f"frame {t}: trajectory ids past the {vm.size} vertices of its vertex map")
            tracked = np.where(cur >= 0, vm[np.maximum(cur, 0)], -1)
        else:
            if cur.size and cur.max() >= n_ref:
                raise ParameterError(f"frame {t}: trajectory ids past the {n_ref} vertices of its shape")
            tracked = cur
        ok = tracked >= 0
        d = np.full(cur.size, np.inf)
        if ok.any():
            d[ok] = _distances(shape, true_t[ok], tracked[ok], method) / np.sqrt(shape.area)
        alive = d[ok]
        out["mean"].append(float(alive.mean()) if alive.size else None)
        out["median"].append(float(np.median(alive)) if alive.size else None)
        out["max"].append(float(alive.max()) if alive.size else None)
        out["within"].append(float(np.mean(d <= radius)) if d.size else None)
        out["lost"].append(float(np.mean(~ok)) if d.size else None)
        out["n_measured"].append(int(d.size))
    return out
