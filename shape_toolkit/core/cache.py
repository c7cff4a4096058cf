"""One explicit, bounded, thread-safe cache class for the toolkit's in-process caches.

Every cache of the package is a named instance of :class:`LRUCache`, a module attribute next to the code that
fills it, so a user can find it, read its size, resize it or clear it:

* ``core.spectrum.SPECTRUM_CACHE``: computed spectra (the disk cache is ``set_cache_dir``'s folder);
* ``core.surface.NORMALS_CACHE``: outward normals of point clouds;
* ``core.surface.SHEET_CACHE``: the sheet triangulations of point clouds (bounded by their bytes);
* ``features.geodesics.GEODESIC_ROWS_CACHE`` (bounded by float64 entries) and ``GEODESIC_SOLVERS_CACHE``;
* ``data.synthetic.POSE_SEQUENCE_CACHE``: generated pose sequences;
* ``plugins.segmenters.sdf.SDF_CACHE``: normalised per-face shape diameter functions.

The caches a caller owns (``plugins.matching.side_cache.SideCache``) store their entries in it too.
"""

from __future__ import annotations

import math
import numbers
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Any

import numpy as np

from shape_toolkit.errors import ParameterError

__all__ = ["LRUCache"]


def _check_bound(value: Any, what: str) -> None:
    if value is None:
        return
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real) or not value >= 0:
        raise ParameterError(f"{what} must be None or a non-negative number, got {value!r}")


class LRUCache:
    """A least-recently-used mapping bounded by its number of entries and, optionally, by the sum of a
    ``cost`` of its values (e.g. float64 entries of arrays). Thread-safe: one lock guards every read and
    write; :meth:`get_or_compute` computes outside the lock (two threads missing the same key may both
    compute; the last value stored wins).

    ``max_entries``: entries kept (None: no count bound); ``max_cost``: bound on the summed ``cost(value)``
    (None: none; needs ``cost``); a value whose own cost exceeds ``max_cost`` is not stored. Both bounds are
    attributes that may be changed at any time (the oldest entries are evicted at once). ``name`` appears in
    the ``repr``. Values are returned as stored, not copied: the caller copies where it must."""

    def __init__(
        self,
        max_entries: int | None,
        *,
        max_cost: float | None = None,
        cost: Callable[[Any], float] | None = None,
        name: str = "cache",
    ):
        _check_bound(max_entries, "max_entries")
        _check_bound(max_cost, "max_cost")
        if max_cost is not None and cost is None:
            raise ParameterError("max_cost needs a cost function")
        self.name = name
        self._cost = cost
        self._lock = threading.RLock()
        self._data: OrderedDict[Hashable, tuple[Any, float]] = OrderedDict()
        self._total = 0.0
        self._max_entries = max_entries
        self._max_cost = max_cost

    # -- bounds -----------------------------------------------------------------------------------
    @property
    def max_entries(self) -> int | None:
        """Entries kept at most (None: unbounded by count)."""
        return self._max_entries

    @max_entries.setter
    def max_entries(self, value: int | None) -> None:
        _check_bound(value, "max_entries")
        with self._lock:
            self._max_entries = value
            self._evict()

    @property
    def max_cost(self) -> float | None:
        """Bound on the summed cost of the values kept (None: unbounded by cost)."""
        return self._max_cost

    @max_cost.setter
    def max_cost(self, value: float | None) -> None:
        _check_bound(value, "max_cost")
        if value is not None and self._cost is None:
            raise ParameterError("max_cost needs a cost function")
        with self._lock:
            self._max_cost = value
            self._evict()

    @property
    def total_cost(self) -> float:
        """Summed cost of the values kept (0 without a cost function)."""
        return self._total

    def _evict(self) -> None:
        while self._data and (
            (self._max_entries is not None and len(self._data) > self._max_entries)
            or (self._max_cost is not None and self._total > self._max_cost)
        ):
            _, (_, c) = self._data.popitem(last=False)
            self._total -= c

    # -- access -----------------------------------------------------------------------------------
    def get(self, key: Hashable, default: Any = None) -> Any:
        """The value stored under ``key`` (it becomes the most recently used), else ``default``."""
        with self._lock:
            hit = self._data.get(key)
            if hit is None:
                return default
            self._data.move_to_end(key)
            return hit[0]

    def put(self, key: Hashable, value: Any) -> None:
        """Store ``value`` under ``key`` as the most recently used entry and evict the least recently used
        ones past the bounds; a value costing more than ``max_cost`` on its own is not stored (the others
        stay; a former value under ``key`` goes: it is not the value put)."""
        c = float(self._cost(value)) if self._cost is not None else 0.0
        if not (math.isfinite(c) and c >= 0):  # a NaN or negative cost would unbound the cache for good
            raise ParameterError(f"{self.name}: the cost of a value must be a finite number >= 0, got {c!r}")
        with self._lock:
            old = self._data.pop(key, None)
            if old is not None:
                self._total -= old[1]
            if self._max_entries == 0 or (self._max_cost is not None and c > self._max_cost):
                return
            self._data[key] = (value, c)
            self._total += c
            self._evict()

    def get_or_compute(self, key: Hashable, compute: Callable[[], Any]) -> Any:
        """The value under ``key``; on a miss ``compute()`` (outside the lock), stored, and returned."""
        with self._lock:
            hit = self._data.get(key)
            if hit is not None:
                self._data.move_to_end(key)
                return hit[0]
        value = compute()
        self.put(key, value)
        return value

    def clear(self) -> None:
        """Forget every entry."""
        with self._lock:
            self._data.clear()
            self._total = 0.0

    def keys(self) -> list[Hashable]:
        """The keys, least recently used first (a snapshot; reading it changes no recency)."""
        with self._lock:
            return list(self._data)

    def __contains__(self, key: object) -> bool:
        with self._lock:
            return key in self._data

    def __len__(self) -> int:
        with self._lock:
            return len(self._data)

    def __repr__(self) -> str:
        entries = f"{len(self)}" + ("" if self._max_entries is None else f"/{self._max_entries}")
        cost = "" if self._max_cost is None else f", cost {self._total:g}/{self._max_cost:g}"
        return f"LRUCache({self.name!r}: {entries} entries{cost})"
