"""Validation of the inputs every layer shares: random states, vertex ids, seed pairs, JSON output,
output files written whole (:func:`atomic_output`).

One helper per kind of input, so that a bad value gets the same typed error and message wherever
it enters the toolkit.
"""

from __future__ import annotations

import json
import math
import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from shape_toolkit.errors import ParameterError, ShapeFileError

__all__ = ["check_random_state", "check_vertex_ids", "check_seeds", "finite_number", "jsonable", "dumps_json",
           "atomic_output", "shown_value", "machine_memory", "first_per_source"]


def finite_number(value: Any) -> bool:
    """Whether the number ``value`` is finite as a float: an integer past float's range (> 1.8e308: Python's and
    TOML's integers have any number of digits) is not, since the numerics compute with floats."""
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


def shown_value(value: Any, width: int = 60) -> str:
    """``repr(value)`` on one line for an error message, at most ``width`` characters; an integer of 30 digits or
    more as its digit count (Python refuses to print one of more than 4,300)."""
    if isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_)) and abs(int(value)) >= 10**30:
        return f"an integer of {len(str(abs(int(value)))) if abs(int(value)) < 10**4000 else 'over 4,000'} digits"
    text = " ".join(repr(value).split())
    return text if len(text) <= width else text[: width - 3] + "..."


def check_random_state(random_state: Any) -> np.random.RandomState:
    """A ``numpy.random.RandomState`` from ``random_state`` with scikit-learn's semantics: None (the
    global state), an int in ``[0, 2**32 - 1]``, a ``RandomState`` (used as is) or a numpy
    ``Generator`` (seeds a new ``RandomState`` from it). Anything else raises :class:`ParameterError`."""
    if random_state is None or isinstance(random_state, np.random.RandomState):
        return np.random.mtrand._rand if random_state is None else random_state
    if isinstance(random_state, np.random.Generator):
        return np.random.RandomState(int(random_state.integers(0, 2**32 - 1)))
    if isinstance(random_state, (int, np.integer)) and not isinstance(random_state, (bool, np.bool_)):
        if not 0 <= int(random_state) <= 2**32 - 1:
            raise ParameterError(f"random_state must be in [0, 2**32 - 1], got {random_state}")
        return np.random.RandomState(int(random_state))
    raise ParameterError(
        f"random_state must be None, an integer, a numpy RandomState or Generator, got {random_state!r}"
    )


def seed_of(random_state: Any) -> int:
    """An int seed drawn from :func:`check_random_state` (for libraries that want an int)."""
    return int(check_random_state(random_state).randint(0, 2**31 - 1))


def check_vertex_ids(
    ids: object, n: int, what: str = "vertex ids", *, allow_empty: bool = True, unique: bool = False
) -> np.ndarray:
    """``ids`` as a 1-D int64 array of 0-based vertex ids in ``[0, n)``; integral floats are accepted,
    anything else (booleans too: a mask is not a list of ids) raises :class:`ParameterError` naming
    ``what``. ``unique``: repeated ids are dropped, keeping the first occurrences in their order."""
    a = np.atleast_1d(np.asarray(ids))
    if a.size == 0:
        if not allow_empty:
            raise ParameterError(f"{what} must not be empty")
        return np.zeros(0, dtype=np.int64)
    if a.ndim != 1:
        raise ParameterError(f"{what} must be a 1-D array of vertex ids, got shape {a.shape}")
    a = _integral(a, what)
    if a.min() < 0 or a.max() >= n:
        raise ParameterError(f"{what} must be vertex ids in [0, {n - 1}] (0-based), found [{a.min()}, {a.max()}]")
    if unique:
        a = a[np.sort(np.unique(a, return_index=True)[1])]
    return a


def check_seeds(seeds: object, n_source: int, n_target: int, *, allow_empty: bool = True) -> np.ndarray:
    """Seed matches as int64 ``(q, 2)`` ``[source vertex, target vertex]`` inside both shapes, one target per
    source vertex: a pair repeated as it is counts once (the later copies are dropped, the order kept), one source
    vertex given two different targets is refused (:class:`ParameterError` naming the vertex and both targets), as
    :func:`~shape_toolkit.results.correspondence.read_seeds` refuses it in a file."""
    s = np.asarray(seeds)
    if s.size == 0:
        if not allow_empty:
            raise ParameterError("seeds must be a non-empty (q, 2) array of [source, target] ids")
        return np.zeros((0, 2), dtype=np.int64)
    if s.ndim != 2 or s.shape[1] != 2:
        raise ParameterError(f"seeds must be a (q, 2) array of [source, target] ids, got shape {s.shape}")
    s = _integral(s, "seeds")
    for col, n, side in ((0, n_source, "source"), (1, n_target, "target")):
        lo, hi = int(s[:, col].min()), int(s[:, col].max())
        if lo < 0 or hi >= n:
            raise ParameterError(f"seed {side} ids must lie in [0, {n - 1}] (0-based), found [{lo}, {hi}]")
    _, first = np.unique(s, axis=0, return_index=True)
    if len(first) < len(s):  # a pair repeated as it is adds nothing
        s = s[np.sort(first)]
    order = np.argsort(s[:, 0], kind="stable")
    same = np.flatnonzero(s[order[1:], 0] == s[order[:-1], 0])
    if same.size:  # one source vertex, two places: which is meant?
        a, b = s[order[same[0]]], s[order[same[0] + 1]]
        raise ParameterError(f"seed source vertex {int(a[0])} is given two targets, {int(a[1])} and {int(b[1])}; "
                             "keep one pair per source vertex")
    return s


def _integral(a: np.ndarray, what: str) -> np.ndarray:
    if np.issubdtype(a.dtype, np.integer):
        return a.astype(np.int64)
    if a.dtype.kind == "b":  # True/False would silently become vertices 1 and 0
        raise ParameterError(f"{what} must be integer vertex ids, got booleans (a mask? use np.flatnonzero(mask))")
    if a.dtype.kind != "f" or not np.all(np.isfinite(a)) or not np.all(np.mod(a, 1) == 0):
        raise ParameterError(f"{what} must be integer vertex ids")
    if np.abs(a).max() > 2**62:
        raise ParameterError(f"{what} are out of range")
    return a.astype(np.int64)


def jsonable(obj: Any) -> Any:
    """``obj`` with numpy values, tuples and sets turned into JSON types; NaN and infinities become
    None (JSON has neither), so the output is always valid JSON."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, set, frozenset)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        f = float(obj)
        return f if math.isfinite(f) else None
    if obj is None or isinstance(obj, str):
        return obj
    if hasattr(obj, "to_dict"):
        return jsonable(obj.to_dict())
    return str(obj)


def dumps_json(obj: Any, **kwargs: Any) -> str:
    """``json.dumps(jsonable(obj))``, refusing NaN and infinities (``allow_nan=False``)."""
    return json.dumps(jsonable(obj), allow_nan=False, **kwargs)


@contextmanager
def atomic_output(
    path: str | os.PathLike,
    what: str = "file",
    suffix: str = "",
    *,
    make_parents: bool = False,
    durable: bool = False,
) -> Iterator[Path]:
    """Write ``path`` whole or not at all: checks that its folder exists (``make_parents``: creates
    it) and that ``path`` is not a directory (:class:`ShapeFileError` naming ``what``), yields a
    temporary path next to it, unique to this writer (ending in ``suffix``, for writers that append
    one, e.g. ``.npz``), and renames it to ``path`` when the block ends (``durable``: after an
    ``fsync`` of its contents). Readers see the old file or the new one, never a part; concurrent
    writers of one path do not share a temporary file (the last rename wins). On any error the
    temporary file is removed and ``path`` is left as it was; ``OSError`` becomes
    :class:`ShapeFileError` ("cannot write")."""
    p = Path(path)
    if p.is_dir():
        raise ShapeFileError(p, f"is a directory, expected a {what} to write")
    if make_parents:
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise ShapeFileError(p, f"cannot create the output folder: {e.strerror or e}") from None
    elif not p.parent.is_dir():
        raise ShapeFileError(p, "the output folder does not exist")
    tmp = p.with_name(f".{p.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp{suffix}")
    try:
        yield tmp
        if durable:
            _fsync(tmp)
        os.replace(tmp, p)
    except OSError as e:
        raise ShapeFileError(p, f"cannot write: {e.strerror or e}") from None
    finally:
        tmp.unlink(missing_ok=True)


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def first_per_source(pairs: np.ndarray) -> np.ndarray:
    """The rows of ``pairs`` ``(q, 2)`` whose first column (the source vertex) has not appeared before, in their
    order: one target per source vertex, the earlier (preferred) pair kept."""
    p = np.asarray(pairs)
    _, first = np.unique(p[:, 0], return_index=True)
    return p[np.sort(first)]


def machine_memory() -> int | None:
    """Bytes of memory this process may use: the machine's physical memory, or the container's limit (cgroup v2
    ``memory.max``, v1 ``memory.limit_in_bytes``) when lower; None when neither can be read."""
    found = []
    try:
        found.append(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, OSError, ValueError):
        pass
    for f in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            found.append(int(Path(f).read_text().strip()))  # "max" (no limit): ValueError
        except (OSError, ValueError):
            pass
    found = [v for v in found if v > 0]
    return min(found) if found else None
