"""The one cache class (``core.cache.LRUCache``): eviction order, the cost bound, resizing, clearing,
thread safety; and the package's caches are named instances of it."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from shape_toolkit.core.cache import LRUCache
from shape_toolkit.errors import ParameterError


def test_least_recently_used_goes_first_and_get_refreshes():
    c = LRUCache(3)
    for k in "abc":
        c.put(k, k.upper())
    assert c.get("a") == "A"  # a is now the most recent: b is the oldest
    c.put("d", "D")
    assert c.keys() == ["c", "a", "d"] and "b" not in c and c.get("b") is None
    assert c.get("b", "missing") == "missing"
    c.put("c", "C2")  # overwriting refreshes too
    c.put("e", "E")
    assert c.keys() == ["d", "c", "e"] and c.get("c") == "C2" and len(c) == 3


def test_get_or_compute_computes_once_per_key_and_stores_none_values():
    c = LRUCache(2)
    calls = []

    def f(v):
        calls.append(v)
        return v

    assert c.get_or_compute("x", lambda: f(1)) == 1
    assert c.get_or_compute("x", lambda: f(2)) == 1
    assert c.get_or_compute("n", lambda: f(None)) is None
    assert c.get_or_compute("n", lambda: f(3)) is None  # a stored None is a hit
    assert calls == [1, None]


def test_the_cost_bound_evicts_the_oldest_and_refuses_a_value_over_it():
    c = LRUCache(None, max_cost=10, cost=lambda a: a.size, name="rows")
    c.put(1, np.zeros(4))
    c.put(2, np.zeros(4))
    assert c.total_cost == 8 and len(c) == 2
    c.put(3, np.zeros(4))  # 12 > 10: the oldest goes
    assert c.keys() == [2, 3] and c.total_cost == 8
    c.put(4, np.zeros(11))  # alone over the budget: not stored, nothing else evicted
    assert c.keys() == [2, 3] and c.total_cost == 8
    c.put(3, np.zeros(1))  # overwriting replaces its cost
    assert c.total_cost == 5
    c.put(5, np.zeros(6))  # 11 > 10: the oldest goes (2), 3 stays
    assert c.keys() == [3, 5] and c.total_cost == 7
    assert "cost 7/10" in repr(c) and "'rows'" in repr(c)


def test_both_bounds_together_and_resizing_evicts_at_once():
    c = LRUCache(3, max_cost=100, cost=len)
    for k in range(5):
        c.put(k, "x" * 10)
    assert c.keys() == [2, 3, 4] and c.total_cost == 30
    c.max_cost = 15
    assert c.keys() == [4] and c.total_cost == 10
    c.max_cost = None
    c.max_entries = 2
    for k in range(5, 8):
        c.put(k, "y")
    assert c.keys() == [6, 7]
    c.max_entries = 0
    assert len(c) == 0
    c.put("z", "z")
    assert len(c) == 0


def test_clear_forgets_entries_and_cost():
    c = LRUCache(4, max_cost=50, cost=len)
    c.put("a", "aaa")
    c.put("b", "bb")
    c.clear()
    assert len(c) == 0 and c.total_cost == 0 and c.keys() == [] and c.get("a") is None
    c.put("a", "a")
    assert c.total_cost == 1


@pytest.mark.parametrize("kwargs", [{"max_entries": -1}, {"max_entries": True}, {"max_entries": 2, "max_cost": 5}])
def test_bad_bounds_are_refused(kwargs):
    with pytest.raises(ParameterError):
        LRUCache(**kwargs)


class _SlowKey:
    """A key whose hashing lets other threads run (as a hash of array bytes would): every dict operation of
    the cache becomes a point where a thread may be interrupted."""

    def __init__(self, k: int):
        self.k = k

    def __hash__(self) -> int:
        time.sleep(0)
        return hash(self.k)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, _SlowKey) and other.k == self.k


def test_thread_safety_under_a_few_threads():
    """Threads putting, reading and computing on one small cost-bounded cache: no error, and afterwards the
    bounds hold and the kept cost is the sum of the kept values' costs (an unlocked cache loses updates)."""
    c = LRUCache(16, max_cost=200, cost=len)
    errors: list[BaseException] = []
    start = threading.Barrier(4)

    def work(t: int) -> None:
        try:
            start.wait()
            rng = np.random.default_rng(t)
            for i in range(1000):
                k = _SlowKey(int(rng.integers(40)))
                op = i % 3
                if op == 0:
                    c.put(k, "v" * int(rng.integers(1, 30)))
                elif op == 1:
                    c.get(k)
                else:
                    c.get_or_compute(k, lambda: "w" * 7)
                if i % 200 == 0:
                    c.keys()
        except BaseException as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(t,)) for t in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert not errors, errors
    kept = [c.get(k) for k in c.keys()]
    assert len(kept) <= 16 and all(v is not None for v in kept)
    assert c.total_cost == sum(map(len, kept)) <= 200


def test_the_package_caches_are_named_instances():
    from shape_toolkit.core import spectrum, surface
    from shape_toolkit.data import synthetic
    from shape_toolkit.features import geodesics
    from shape_toolkit.plugins.segmenters import sdf

    caches = [spectrum.SPECTRUM_CACHE, surface.NORMALS_CACHE, surface.SHEET_CACHE, geodesics.GEODESIC_ROWS_CACHE,
              geodesics.GEODESIC_SOLVERS_CACHE, synthetic.POSE_SEQUENCE_CACHE, sdf.SDF_CACHE]
    assert all(isinstance(c, LRUCache) for c in caches)
    assert all(c.max_entries is not None or c.max_cost is not None for c in caches)  # every one bounded
    assert geodesics.GEODESIC_ROWS_CACHE.max_cost == 50_000_000


def test_geodesic_rows_keep_within_their_float_budget_and_clear(sphere):
    from shape_toolkit.features import geodesics as g

    rows = g.GEODESIC_ROWS_CACHE
    old = rows.max_cost
    g.clear_geodesic_cache()
    try:
        rows.max_cost = 3 * sphere.n_vertices
        d = g.geodesic_distances(sphere, [0, 1, 2, 3, 4], method="dijkstra")
        assert len(rows) == 3 and rows.total_cost == 3 * sphere.n_vertices
        assert [k[2] for k in rows.keys()] == [2, 3, 4]  # the last sources solved are kept
        np.testing.assert_array_equal(g.geodesic_distances(sphere, [4], method="dijkstra")[0], d[4])
        assert len(g.GEODESIC_SOLVERS_CACHE) >= 1
        g.clear_geodesic_cache()
        assert len(rows) == 0 and len(g.GEODESIC_SOLVERS_CACHE) == 0 and rows.total_cost == 0
    finally:
        rows.max_cost = old


def test_a_value_too_costly_to_store_does_not_leave_the_former_value_under_its_key():
    """put(k, v) that cannot store v (over max_cost alone) left the former value under k: get(k) then returned
    a value that was no longer the one put, silently."""
    c = LRUCache(None, max_cost=10, cost=lambda a: a.size)
    c.put("k", np.zeros(4))
    c.put("other", np.zeros(2))
    c.put("k", np.zeros(11))
    assert "k" not in c and c.get("k") is None and c.keys() == ["other"] and c.total_cost == 2


def test_bounds_may_be_numpy_numbers_and_a_cost_must_be_finite_and_non_negative():
    """np.int64(3) was refused as 'must be None or a non-negative number'; a NaN cost made the summed cost NaN
    and a negative one lowered it, and either way the cost bound stopped evicting for good."""
    c = LRUCache(np.int64(2), max_cost=np.float64(10), cost=lambda v: v)
    c.max_entries = np.int32(3)
    assert c.max_entries == 3
    for bad in (float("nan"), -1.0, float("inf")):
        with pytest.raises(ParameterError, match="finite number >= 0"):
            c.put("x", bad)
    assert len(c) == 0 and c.total_cost == 0
    for i in range(5):
        c.put(i, 4)
    assert c.keys() == [3, 4] and c.total_cost == 8
    with pytest.raises(ParameterError):
        LRUCache(np.bool_(True))
