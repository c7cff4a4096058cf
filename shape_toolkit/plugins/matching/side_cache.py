"""The cache of a pair's symmetry maps and side references (:mod:`.orientation`): they are costly and asked for
more than once per pair (a pipeline's sparse stage and EM), so a caller that wants them computed once owns a
:class:`SideCache` and passes it as ``cache=``, or opens a scope (``with side_cache_scope():``) in which every call
without ``cache=`` shares one (a pipeline run does; nothing is kept after the scope)."""

from __future__ import annotations

import contextlib
import weakref
from collections.abc import Callable, Iterator
from contextvars import ContextVar
from typing import Any

from shape_toolkit.core.cache import LRUCache

__all__ = ["SideCache", "side_cache_scope", "scoped", "cached"]


class _IdentityCache:
    """A small LRU of computed values keyed on the *identity* of objects (shapes, spectra) plus a
    hashable ``extra``: entries hold weak references, and a key only hits while every object is
    alive and is the very object it was computed for (an ``id`` reused by a new object misses).
    Shapes and spectra are frozen, so identity stands for content. The entries live in an
    :class:`~shape_toolkit.core.cache.LRUCache` (``entries``); a key function alone could not replace this
    class, since a hit must also be checked against the live objects."""

    def __init__(self, size: int = 2):
        self.entries = LRUCache(size, name="identity")

    def get(self, objs: tuple, extra: Any, compute: Callable[[], Any]) -> Any:
        key = (tuple(id(o) for o in objs), extra)
        hit = self.entries.get(key)
        if hit is not None and all(r() is o for r, o in zip(hit[0], objs)):
            return hit[1]
        value = compute()
        self.entries.put(key, (tuple(weakref.ref(o) for o in objs), value))
        return value

    def clear(self) -> None:
        """Forget every entry."""
        self.entries.clear()


class SideCache:
    """The symmetry maps and side references of the last ``size`` shapes (pairs) a caller asked for, kept
    for the caller that asks again (a pipeline's sparse stage and EM ask for the same ones): keyed on the
    identity of the Shape and Spectrum objects used. Owned by the caller and passed as ``cache=``."""

    def __init__(self, size: int = 2):
        self.symmetry = _IdentityCache(size)
        self.sides = _IdentityCache(size)

    def clear(self) -> None:
        """Forget the cached symmetry maps and side references."""
        self.symmetry.clear()
        self.sides.clear()


#: the cache of the innermost :func:`side_cache_scope` (None outside any)
_SCOPE: ContextVar[SideCache | None] = ContextVar("side_cache_scope", default=None)


@contextlib.contextmanager
def side_cache_scope(cache: SideCache | None = None) -> Iterator[SideCache]:
    """A scope in which calls given no ``cache=`` share ``cache`` (None: the open scope's, else a new
    :class:`SideCache`): a pipeline opens one per run, so its sparse stage and its orientation repair compute
    each symmetry map and side reference once. The scope is per thread and per task (a context variable)."""
    cache = (_SCOPE.get() or SideCache()) if cache is None else cache
    token = _SCOPE.set(cache)
    try:
        yield cache
    finally:
        _SCOPE.reset(token)


def scoped(cache: SideCache | None) -> SideCache | None:
    """``cache``, or the open scope's (None outside any)."""
    return cache if cache is not None else _SCOPE.get()


def cached(cache: _IdentityCache | None, objs: tuple, extra: Any, compute: Callable[[], Any]) -> Any:
    """``compute()``, kept in ``cache`` under the identity of ``objs`` and ``extra`` (None: not kept)."""
    return compute() if cache is None else cache.get(objs, extra, compute)
