"""Plugin discovery through entry points, lazily, and lookup by ``(family, name)``.

Each family has its own entry-point group, ``shape_toolkit.<family>`` (for example
``shape_toolkit.dense_matchers``). An entry point's name *is* the plugin's registry name; its value
is either a module implementing the family's pluggy hook (what the built-ins use) or a class::

    [project.entry-points."shape_toolkit.weightings"]
    inverse-length = "my_package.weights"                 # a module with @hookimpl toolkit_weightings
    [project.entry-points."shape_toolkit.descriptors"]
    my-descriptor = "my_package.desc:MyDescriptor"        # or the class itself

Listing reads entry-point metadata only; nothing is imported until a plugin is used, and then
only its own module. The older single group ``toolkit`` (a module per entry point, any family,
found through its hooks) keeps working: those modules are imported when a full table is needed.
"""

from __future__ import annotations

import importlib.metadata
import types
import warnings
from typing import Any

import pluggy

from shape_toolkit.api.hookspecs import (
    ENTRY_POINT_GROUP,
    FAMILY_GROUPS,
    FAMILY_HOOKS,
    PROJECT,
    ToolkitHookSpecs,
)
from shape_toolkit.api.interfaces import FAMILY_INTERFACES, BasePlugin
from shape_toolkit.errors import ParameterError, PluginError

__all__ = [
    "Registry", "get_registry", "get_plugin", "create_plugin", "available_plugins", "plugins_taking_constraints",
]


class Registry:
    """Entry-point names per family (read without importing), a pluggy plugin manager for hook
    modules, and the ``(family, name) -> class`` table filled as plugins are used."""

    def __init__(self, load_entry_points: bool = True):
        self.pm = pluggy.PluginManager(PROJECT)
        self.pm.add_hookspecs(ToolkitHookSpecs)
        self.broken: dict[str, str] = {}
        self._entry_points: dict[str, dict[str, importlib.metadata.EntryPoint]] = {f: {} for f in FAMILY_HOOKS}
        self._legacy: list[importlib.metadata.EntryPoint] = []
        self._classes: dict[str, dict[str, type]] = {f: {} for f in FAMILY_HOOKS}
        self._hooks_read = False
        if load_entry_points:
            for family, group in FAMILY_GROUPS.items():
                for ep in importlib.metadata.entry_points(group=group):
                    self._entry_points[family].setdefault(ep.name, ep)
            self._legacy = list(importlib.metadata.entry_points(group=ENTRY_POINT_GROUP))

    # -- registration -------------------------------------------------------------------------
    def register(self, plugin: object, name: str | None = None) -> None:
        """Register a module or object implementing the family hooks (tests, notebooks)."""
        self.pm.register(plugin, name=name)
        self._add_hook_classes(plugin, name or repr(plugin))

    def unregister(self, name: str) -> None:
        """Forget the plugin object registered as ``name`` and every class it provided."""
        plugin = self.pm.unregister(name=name)
        for table in self._classes.values():
            for key in [k for k, cls in table.items() if getattr(cls, "_toolkit_provider", None) == name]:
                del table[key]
        del plugin

    def _add_hook_classes(self, plugin: object, origin: str, only: tuple[str, str] | None = None) -> None:
        for family, hook in FAMILY_HOOKS.items():
            if only is not None and family != only[0]:
                continue
            fn = getattr(plugin, hook, None)
            if fn is None:
                continue
            for pname, cls in (fn() or {}).items():
                if only is not None and pname != only[1]:
                    continue
                self._add_class(family, pname, cls, origin)

    def _add_class(self, family: str, name: str, cls: type, origin: str) -> None:
        base, method = FAMILY_INTERFACES[family]
        if not callable(getattr(cls, method, None)):
            raise PluginError(
                f"plugin {origin!r} offers {family} {name!r} without a {method}() method "
                f"(see {base.__module__}.{base.__name__})"
            )
        known = self._classes[family].get(name)
        if known is not None and known is not cls:
            raise PluginError(f"two plugins register {family} {name!r}: {known.__module__} and {cls.__module__}")
        ep = self._entry_points[family].get(name)
        if known is None and ep is not None and origin != ep.value:
            raise PluginError(f"two plugins register {family} {name!r}: {ep.value} and {cls.__module__}")
        try:
            cls._toolkit_provider = origin
        except (AttributeError, TypeError):  # pragma: no cover - exotic class objects
            pass
        self._classes[family][name] = cls

    def _load_entry_point(self, family: str, name: str) -> None:
        ep = self._entry_points[family][name]
        try:
            obj = ep.load()
        except ModuleNotFoundError as exc:
            raise PluginError(
                f"{family} plugin {name!r} needs the missing package {exc.name!r}; install it "
                f"(or the extra that provides it) and try again"
            ) from None
        except Exception as exc:  # a broken third-party plugin must not break the rest
            self.broken[name] = f"{type(exc).__name__}: {exc}"
            raise PluginError(f"{family} plugin {name!r} failed to load: {type(exc).__name__}: {exc}") from None
        if isinstance(obj, types.ModuleType):
            if not self.pm.is_registered(obj):
                self.pm.register(obj, name=f"{family}:{name}")
            self._add_hook_classes(obj, ep.value, only=(family, name))
            if name not in self._classes[family]:
                raise PluginError(
                    f"entry point {name!r} of group {ep.group!r} names module {ep.value!r}, whose "
                    f"{FAMILY_HOOKS[family]}() hook does not offer {name!r}"
                )
        else:
            self._add_class(family, name, obj, ep.value)

    def _read_legacy_hooks(self) -> None:
        """Import the modules of the older ``toolkit`` group and read every hook once."""
        if self._hooks_read:
            return
        self._hooks_read = True
        for ep in self._legacy:
            if self.pm.get_plugin(ep.name) is not None or self.pm.is_blocked(ep.name):
                continue
            try:
                module = ep.load()
            except Exception as exc:  # a broken third-party plugin must not break the rest
                self.broken[ep.name] = f"{type(exc).__name__}: {exc}"
                warnings.warn(f"shape_toolkit plugin {ep.name!r} failed to load: {exc}", stacklevel=3)
                continue
            if not self.pm.is_registered(module):
                self.pm.register(module, name=ep.name)
                self._add_hook_classes(module, ep.name)

    # -- lookup -------------------------------------------------------------------------------
    def names(self, family: str) -> list[str]:
        """Sorted plugin names of ``family``, without importing any lazily declared plugin."""
        self._check_family(family)
        if self._legacy:
            self._read_legacy_hooks()
        return sorted(set(self._entry_points[family]) | set(self._classes[family]))

    def families(self) -> dict[str, list[str]]:
        """``{family: sorted names}`` for every family (empty lists allowed)."""
        return {fam: self.names(fam) for fam in FAMILY_HOOKS}

    def entry_point(self, family: str, name: str) -> str | None:
        """The ``module[:attr]`` an entry point declares for ``(family, name)``, without importing it."""
        ep = self._entry_points.get(family, {}).get(name)
        return None if ep is None else ep.value

    def _check_family(self, family: str) -> None:
        if family not in FAMILY_HOOKS:
            raise PluginError(f"unknown plugin family {family!r}; families: {sorted(FAMILY_HOOKS)}")

    def has(self, family: str, name: str) -> bool:
        """Whether ``name`` is a plugin of ``family`` (reads metadata; imports nothing new)."""
        return name in self.names(family)

    def get(self, family: str, name: str) -> type:
        """The class registered as ``name`` in ``family``; only its own module is imported."""
        self._check_family(family)
        if not isinstance(name, str):  # a dict or list from a JSON parameter: unhashable, not a name
            shown = repr(name) if len(repr(name)) <= 60 else repr(name)[:57] + "..."
            raise PluginError(f"a {family} plugin is named by a string, got {type(name).__name__} {shown}")
        if name not in self._classes[family] and name in self._entry_points[family]:
            self._load_entry_point(family, name)
        if name not in self._classes[family]:
            self._read_legacy_hooks()
        try:
            return self._classes[family][name]
        except KeyError:
            avail = ", ".join(self.names(family)) or "none"
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
    """The process-wide registry (entry-point metadata read on first use)."""
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


def plugins_taking_constraints() -> list[str]:
    """Names of the registered segmenters whose ``takes_constraints`` is True (semi-supervised ones)."""
    reg = get_registry()
    names = []
    for name in reg.names("segmenters"):
        try:
            cls = reg.get("segmenters", name)
        except Exception:  # noqa: BLE001 - a broken plugin is reported where it is used, not here
            continue
        if getattr(cls, "takes_constraints", False) is True:
            names.append(name)
    return names


def available_plugins() -> dict[str, list[str]]:
    """``{family: [names...]}`` for all families, without importing the plugins."""
    return get_registry().families()
