"""Plugin discovery (entry-point group ``toolkit``) and lookup by ``(family, name)``."""

from __future__ import annotations

import importlib.metadata
import warnings
from typing import Any

import pluggy

from .errors import ParameterError, PluginError
from .hookspecs import ENTRY_POINT_GROUP, FAMILY_HOOKS, PROJECT, ToolkitHookSpecs
from .interfaces import FAMILY_INTERFACES, BasePlugin

__all__ = ["Registry", "get_registry", "get_plugin", "create_plugin", "available_plugins"]


class Registry:
    """A pluggy plugin manager plus the ``(family, name) -> class`` table built from its hooks."""

    def __init__(self, load_entry_points: bool = True):
        self.pm = pluggy.PluginManager(PROJECT)
        self.pm.add_hookspecs(ToolkitHookSpecs)
        self.broken: dict[str, str] = {}
        self._table: dict[str, dict[str, type]] | None = None
        if load_entry_points:
            self._load_entry_points()

    def _load_entry_points(self) -> None:
        for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
            if self.pm.get_plugin(ep.name) is not None or self.pm.is_blocked(ep.name):
                continue
            try:
                module = ep.load()
            except Exception as exc:  # a broken third-party plugin must not break the rest
                self.broken[ep.name] = f"{type(exc).__name__}: {exc}"
                warnings.warn(f"toolkit plugin {ep.name!r} failed to load: {exc}", stacklevel=2)
                continue
            if self.pm.is_registered(module):
                continue
            self.pm.register(module, name=ep.name)

    def register(self, plugin: object, name: str | None = None) -> None:
        """Register a module or object implementing toolkit hooks (e.g. in tests or notebooks)."""
        self.pm.register(plugin, name=name)
        self._table = None

    def _build(self) -> dict[str, dict[str, type]]:
        table: dict[str, dict[str, type]] = {fam: {} for fam in FAMILY_HOOKS}
        for family, hook_name in FAMILY_HOOKS.items():
            base, method = FAMILY_INTERFACES[family]
            for impl in getattr(self.pm.hook, hook_name).get_hookimpls():
                provided = impl.function() or {}
                for name, cls in provided.items():
                    if not callable(getattr(cls, method, None)):
                        raise PluginError(
                            f"plugin {impl.plugin_name!r} offers {family} {name!r} without a "
                            f"{method}() method (see {base.__module__}.{base.__name__})"
                        )
                    if name in table[family] and table[family][name] is not cls:
                        raise PluginError(
                            f"two plugins register {family} {name!r}: "
                            f"{table[family][name].__module__} and {cls.__module__}"
                        )
                    table[family][name] = cls
        return table

    @property
    def table(self) -> dict[str, dict[str, type]]:
        """``{family: {name: class}}`` for every registered plugin."""
        if self._table is None:
            self._table = self._build()
        return self._table

    def families(self) -> dict[str, list[str]]:
        """``{family: sorted names}`` for every family (empty lists allowed)."""
        return {fam: sorted(names) for fam, names in self.table.items()}

    def get(self, family: str, name: str) -> type:
        """The class registered as ``name`` in ``family``; unknown names list the available ones."""
        if family not in self.table:
            raise PluginError(f"unknown plugin family {family!r}; families: {sorted(self.table)}")
        try:
            return self.table[family][name]
        except KeyError:
            avail = ", ".join(sorted(self.table[family])) or "none"
            raise PluginError(f"unknown {family} plugin {name!r}; available: {avail}") from None

    def create(self, family: str, name: str, preset: str | None = None, **params: Any) -> Any:
        """Instantiate ``(family, name)`` with a named preset and/or keyword parameters."""
        cls = self.get(family, name)
        merged: dict[str, Any] = {}
        if preset is not None:
            presets = getattr(cls, "presets", {}) or {}
            if preset not in presets:
                raise ParameterError(
                    f"{family} plugin {name!r} has no preset {preset!r}; "
                    f"presets: {', '.join(sorted(presets)) or 'none'}"
                )
            merged.update(presets[preset])
        merged.update(params)
        if issubclass(cls, BasePlugin):
            valid = set(cls._param_names())
            unknown = sorted(set(merged) - valid)
            if unknown:
                raise ParameterError(
                    f"{family} plugin {name!r} has no parameter {', '.join(map(repr, unknown))}; "
                    f"valid: {', '.join(sorted(valid)) or 'none'}"
                )
        try:
            return cls(**merged)
        except TypeError as exc:
            raise ParameterError(f"{family} plugin {name!r}: {exc}") from None


_DEFAULT: Registry | None = None


def get_registry() -> Registry:
    """The process-wide registry, loading entry points on first use."""
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = Registry()
    return _DEFAULT


def get_plugin(family: str, name: str) -> type:
    """Shortcut for ``get_registry().get(family, name)``."""
    return get_registry().get(family, name)


def create_plugin(family: str, name: str, preset: str | None = None, **params: Any) -> Any:
    """Shortcut for ``get_registry().create(family, name, preset, **params)``."""
    return get_registry().create(family, name, preset, **params)


def available_plugins() -> dict[str, list[str]]:
    """``{family: [names...]}`` for all families."""
    return get_registry().families()
