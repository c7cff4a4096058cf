"""Correspondences between two shapes as data: hard maps, confidences, sparse soft assignments.

A :class:`Correspondence` maps each *source* vertex to one *target* vertex (``-1`` when unmatched),
optionally with a per-match confidence and a sparse ``(n_src, n_tgt)`` matrix of posteriors
(soft assignment, rows sum to at most 1; the missing mass is the probability of "unmatched").
Functions here move scalar functions and labels through such maps, and read/write map files
(one 0-based target vertex per line, ``-1`` for unmatched).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from shape_toolkit.errors import ParameterError, ShapeFileError
from shape_toolkit.results.labels import _INT_TOKEN, _MAX_ABS_INT, _read_small_text, read_int_file
from shape_toolkit.validation import atomic_output, check_seeds

__all__ = [
    "read_seeds",
    "Correspondence",
    "from_pairs",
    "transfer_function",
    "transfer_labels",
    "save_map",
    "load_map",
]


@dataclass(frozen=True, eq=False)
class Correspondence:
    """A map from ``n_src`` source vertices to ``n_tgt`` target vertices.

    ``target_of`` int64 ``(n_src,)``: target vertex of each source vertex, ``-1`` when unmatched.
    ``confidence`` float64 ``(n_src,)`` or None (higher is more certain; NaN where unmatched is fine).
    ``posteriors`` CSR ``(n_src, n_tgt)`` or None: non-negative soft assignment; entry ``(i, j)`` is
    the probability that source ``i`` and target ``j`` correspond (EM registration stores
    ``P(source i | target j)``, so its columns sum to at most 1; ``info`` says which).
    """

    target_of: np.ndarray
    n_target: int
    confidence: np.ndarray | None = None
    posteriors: sp.csr_matrix | None = None
    info: dict | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.target_of)
        if t.ndim != 1:
            raise ParameterError(f"target_of must be 1-D, got shape {t.shape}")
        if t.size and not np.issubdtype(t.dtype, np.integer):
            if not np.all(np.equal(np.mod(t, 1), 0)):
                raise ParameterError("target_of must hold integer vertex ids")
        t = t.astype(np.int64, copy=True)
        n_tgt = int(self.n_target)
        if n_tgt < 1:
            raise ParameterError(f"n_target must be positive, got {n_tgt}")
        if t.size and (t.min() < -1 or t.max() >= n_tgt):
            raise ParameterError(
                f"target_of must lie in [-1, {n_tgt - 1}], found range [{t.min()}, {t.max()}]"
            )
        t.setflags(write=False)
        object.__setattr__(self, "target_of", t)
        object.__setattr__(self, "n_target", n_tgt)
        if self.confidence is not None:
            c = np.asarray(self.confidence, dtype=np.float64).ravel()
            if c.shape != t.shape:
                raise ParameterError(f"confidence must have shape {t.shape}, got {c.shape}")
            object.__setattr__(self, "confidence", c)
        if self.posteriors is not None:
            P = sp.csr_matrix(self.posteriors, dtype=np.float64)
            if P.shape != (t.size, n_tgt):
                raise ParameterError(f"posteriors must be {(t.size, n_tgt)}, got {P.shape}")
            if P.nnz and (P.data.min() < -1e-12 or not np.isfinite(P.data).all()):
                raise ParameterError("posteriors must be finite and non-negative")
            object.__setattr__(self, "posteriors", P)
        if self.info is None:
            object.__setattr__(self, "info", {})

    @property
    def n_source(self) -> int:
        """Number of source vertices."""
        return int(self.target_of.size)

    @property
    def matched(self) -> np.ndarray:
        """Boolean ``(n_src,)`` mask of matched source vertices."""
        return self.target_of >= 0

    @property
    def n_matched(self) -> int:
        """Number of matched source vertices."""
        return int(self.matched.sum())

    def pairs(self) -> np.ndarray:
        """Matched ``[source, target]`` pairs as int64 ``(q, 2)``."""
        src = np.flatnonzero(self.matched)
        return np.column_stack([src, self.target_of[src]]).astype(np.int64)

    def is_injective(self) -> bool:
        """True when no two source vertices share a target (one-to-one on the matched part)."""
        t = self.target_of[self.matched]
        return bool(np.unique(t).size == t.size)

    def one_to_one(self) -> Correspondence:
        """A copy where each target keeps only its most confident source (others become -1)."""
        t = self.target_of.copy()
        conf = self.confidence if self.confidence is not None else np.zeros(t.size)
        src = np.flatnonzero(t >= 0)
        order = src[np.lexsort((src, -np.nan_to_num(conf[src], nan=-np.inf)))]
        _, first = np.unique(t[order], return_index=True)
        keep = np.zeros(t.size, dtype=bool)
        keep[order[first]] = True
        t[~keep] = -1
        return Correspondence(t, self.n_target, self.confidence, self.posteriors, dict(self.info))

    def with_pairs(self, pairs: np.ndarray) -> Correspondence:
        """A copy that holds the known matches ``pairs`` int ``(q, 2)`` ``[source, target]`` (a user's seeds)
        everywhere the map is read: each source sends its vertex to its target, its confidence is above every
        other (so :meth:`one_to_one` and :meth:`inverse` keep the pair), and the posteriors give the pair
        probability 1 and its source and target no other mass. ``info`` is kept. The pairs are checked as seeds are
        (:func:`~shape_toolkit.validation.check_seeds`: inside both shapes, one target per source vertex)."""
        p = check_seeds(pairs, self.n_source, self.n_target)  # one target per source: a posterior row sums to 1
        t = self.target_of.copy()
        t[p[:, 0]] = p[:, 1]
        conf = None
        if self.confidence is not None:
            conf = self.confidence.copy()
            finite = conf[np.isfinite(conf)]
            # finite (a map's confidences go to JSON), and above every other match's, ties included
            conf[p[:, 0]] = np.nextafter(max(1.0, float(finite.max()) if finite.size else 1.0), np.inf)
        post = None
        if self.posteriors is not None:
            P = self.posteriors.tocoo()
            drop = np.isin(P.row, p[:, 0]) | np.isin(P.col, p[:, 1])
            post = sp.csr_matrix((np.r_[P.data[~drop], np.ones(len(p))],
                                  (np.r_[P.row[~drop], p[:, 0]], np.r_[P.col[~drop], p[:, 1]])),
                                 shape=P.shape)
        return Correspondence(t, self.n_target, conf, post, dict(self.info))

    def soft(self) -> sp.csr_matrix:
        """The posteriors, or the 0/1 matrix of the hard map when there are none."""
        if self.posteriors is not None:
            return self.posteriors
        src = np.flatnonzero(self.matched)
        return sp.csr_matrix(
            (np.ones(src.size), (src, self.target_of[src])), shape=(self.n_source, self.n_target)
        )

    def inverse(self) -> Correspondence:
        """The target -> source map of the matched pairs (a target hit several times keeps the
        most confident source)."""
        c = self.one_to_one()
        inv = np.full(self.n_target, -1, dtype=np.int64)
        src = np.flatnonzero(c.matched)
        inv[c.target_of[src]] = src
        conf = None
        if self.confidence is not None:
            conf = np.full(self.n_target, np.nan)
            conf[c.target_of[src]] = self.confidence[src]
        post = self.posteriors.T.tocsr() if self.posteriors is not None else None
        return Correspondence(inv, self.n_source, conf, post)

    def __repr__(self) -> str:
        return (
            f"Correspondence(n_source={self.n_source}, n_target={self.n_target}, "
            f"n_matched={self.n_matched}, soft={self.posteriors is not None})"
        )


def from_pairs(
    pairs: np.ndarray, n_source: int, n_target: int, confidence: np.ndarray | None = None
) -> Correspondence:
    """A Correspondence from int ``(q, 2)`` ``[source, target]`` pairs (later duplicates win)."""
    p = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if p.size and (p[:, 0].min() < 0 or p[:, 0].max() >= n_source):
        raise ParameterError(f"source ids must lie in [0, {n_source - 1}]")
    if p.size and (p[:, 1].min() < 0 or p[:, 1].max() >= n_target):
        raise ParameterError(f"target ids must lie in [0, {n_target - 1}]")
    t = np.full(n_source, -1, dtype=np.int64)
    t[p[:, 0]] = p[:, 1]
    conf = None
    if confidence is not None:
        conf = np.full(n_source, np.nan)
        conf[p[:, 0]] = np.asarray(confidence, dtype=np.float64).ravel()
    return Correspondence(t, n_target, conf)


def _check_side(to: str) -> None:
    if to not in ("target", "source"):
        raise ParameterError(f"to must be 'target' or 'source', got {to!r}")


def transfer_function(
    corr: Correspondence, values: np.ndarray, *, to: str = "target", soft: bool = False,
    fill: float = np.nan,
) -> np.ndarray:
    """Carry a function ``(n, ...)`` across the map.

    ``to="target"``: values live on the source; target vertex ``j`` gets the value of the source
    vertex mapped onto it (the most confident one if several), or with ``soft`` the mean weighted
    by column ``j`` of the posteriors. ``to="source"``: values live on the target; source vertex
    ``i`` gets ``values[target_of[i]]``, or with ``soft`` the mean weighted by row ``i``.
    ``fill`` where nothing maps (no match or no posterior mass).
    """
    _check_side(to)
    f = np.asarray(values, dtype=np.float64)
    n_in, n_out = (corr.n_source, corr.n_target) if to == "target" else (corr.n_target, corr.n_source)
    if f.ndim == 0 or f.shape[0] != n_in:
        raise ParameterError(
            f"the function has {f.shape[0] if f.ndim else 0} values, the "
            f"{'source' if to == 'target' else 'target'} shape {n_in} vertices"
        )
    if soft:
        P = corr.soft()
        P = P.T.tocsr() if to == "target" else P
        mass = np.asarray(P.sum(axis=1)).ravel()
        out = np.asarray(P @ f, dtype=np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            out = out / (mass if f.ndim == 1 else mass.reshape((-1,) + (1,) * (f.ndim - 1)))
        out[mass <= 0] = fill
        return out
    out = np.full((n_out,) + f.shape[1:], fill, dtype=np.float64)
    if to == "source":
        m = corr.matched
        out[m] = f[corr.target_of[m]]
    else:
        inv = corr.inverse()
        m = inv.matched
        out[m] = f[inv.target_of[m]]
    return out


def transfer_labels(
    corr: Correspondence, labels: np.ndarray, *, to: str = "target", soft: bool = False,
    unmatched: int = -1,
) -> np.ndarray:
    """Carry integer labels across the map (``to`` as in :func:`transfer_function`).

    Hard: the label of the matched vertex. Soft (probabilistic label transfer, eq. 5.7-5.9 with
    the labels as hard assignments, eq. 5.8): the label of largest posterior mass
    ``argmax_l sum_j p_ij delta_jl``. ``unmatched`` where nothing maps; negative input labels
    mean "unlabelled" and never win.
    """
    _check_side(to)
    lab = np.asarray(labels)
    n_in, n_out = (corr.n_source, corr.n_target) if to == "target" else (corr.n_target, corr.n_source)
    if lab.shape != (n_in,):
        raise ParameterError(f"labels must have shape ({n_in},), got {lab.shape}")
    if lab.size and not np.issubdtype(lab.dtype, np.integer):
        if not np.all(np.equal(np.mod(lab, 1), 0)):
            raise ParameterError("labels must be integers")
    lab = lab.astype(np.int64)
    if not soft:
        idx = transfer_function(corr, np.arange(n_in, dtype=np.float64), to=to, fill=-1.0)
        out = np.full(n_out, unmatched, dtype=np.int64)
        ok = idx >= 0
        out[ok] = lab[idx[ok].astype(np.int64)]
        return out
    valid = lab >= 0
    values, inv = np.unique(lab[valid], return_inverse=True)
    if values.size == 0:
        return np.full(n_out, unmatched, dtype=np.int64)
    rows = np.flatnonzero(valid)
    onehot = sp.csr_matrix((np.ones(rows.size), (rows, inv)), shape=(n_in, values.size))
    P = corr.soft()
    P = P.T.tocsr() if to == "target" else P
    votes = np.asarray((P @ onehot).todense())  # (n_out, n_labels): labels are few
    best = votes.argmax(axis=1)
    out = values[best].astype(np.int64)
    out[votes.max(axis=1) <= 0] = unmatched
    return out


def save_map(path: str | os.PathLike, corr: Correspondence | np.ndarray) -> None:
    """Write one 0-based target vertex per source vertex (``-1`` when unmatched), one per line."""
    t = corr.target_of if isinstance(corr, Correspondence) else np.asarray(corr, dtype=np.int64)
    with atomic_output(path, "map file") as tmp:
        np.savetxt(tmp, t, fmt="%d")


def load_map(
    path: str | os.PathLike, n_source: int | None = None, n_target: int | None = None
) -> Correspondence:
    """Read a map written by :func:`save_map` (0-based, -1 unmatched) and check its size."""
    p = Path(path)
    t = read_int_file(p, "map")  # typed errors for missing / binary / non-integer / huge values
    if n_source is not None and t.size != n_source:
        raise ShapeFileError(p, f"has {t.size} entries, the source shape has {n_source} vertices")
    if t.min() < -1:
        raise ShapeFileError(p, f"invalid vertex id {int(t.min())} (0-based, -1 = unmatched)")
    if n_target is None:
        n_target = int(t.max()) + 1 if t.max() >= 0 else 1
    if t.max() >= n_target:
        raise ShapeFileError(
            p, f"vertex id {int(t.max())} is out of range for a target of {n_target} vertices "
            "(map files are 0-based)"
        )
    return Correspondence(t, n_target)


def read_seeds(
    path: str | os.PathLike, n_source: int | None = None, n_target: int | None = None
) -> np.ndarray:
    """Seed matches from a text file: one ``source target`` pair of 0-based vertex ids per line
    (``#`` comments, commas allowed), int64 ``(q, 2)``, checked against the vertex counts when
    given. Every problem (not text, a token that is not a plain integer, out of range, empty, one source vertex
    given two targets) raises :class:`ShapeFileError` naming the line; a pair repeated as it is counts once."""
    p = Path(path)
    rows: list[tuple[int, int]] = []
    seen: dict[int, tuple[int, int]] = {}  # source vertex -> (its target, the line that gave it)
    for ln, line in enumerate(_read_small_text(p, "seed").splitlines(), 1):
        parts = line.split("#", 1)[0].replace(",", " ").split()
        if not parts:
            continue
        if len(parts) != 2:
            raise ShapeFileError(p, f"line {ln}: expected 'source target' (two 0-based ids), got {line[:80]!r}")
        for tok in parts:
            if not _INT_TOKEN.match(tok) or abs(int(tok)) > _MAX_ABS_INT:
                raise ShapeFileError(p, f"line {ln}: vertex ids must be integers in range, got {tok[:40]!r}")
        pair = (int(parts[0]), int(parts[1]))
        if pair[0] in seen and seen[pair[0]][0] != pair[1]:  # one source vertex, two places: which is meant?
            other, at = seen[pair[0]]
            raise ShapeFileError(p, f"line {ln}: source vertex {pair[0]} is matched to {pair[1]} here and to {other} "
                                    f"on line {at}; keep one")
        if pair[0] not in seen:  # a pair repeated as it is adds nothing
            seen[pair[0]] = (pair[1], ln)
            rows.append(pair)
    if not rows:
        raise ShapeFileError(p, "no seed pairs in the file")
    s = np.asarray(rows, dtype=np.int64)
    try:
        return check_seeds(s, n_source or int(s[:, 0].max()) + 1, n_target or int(s[:, 1].max()) + 1,
                           allow_empty=False)
    except ParameterError as exc:
        raise ShapeFileError(p, str(exc)) from None
