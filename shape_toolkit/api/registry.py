"""Plugin discovery through entry points, lazily, and lookup by ``(family, name)``.

One plugin is one class and one entry-point line naming it. Each family has its own group,
``shape_toolkit.<family>`` (for example ``shape_toolkit.dense_matchers``); an entry point's name *is* the
plugin's registry name and its value the class::

    [project.entry-points."shape_toolkit.weightings"]
    inverse-length = "my_package.weights:InverseLength"

Listing reads entry-point metadata only; nothing is imported until a plugin is used, and then only its
own module. Classes can also be registered in-process (:meth:`Registry.register`: tests, notebooks).
"""

from __future__ import annotations

import importlib.metadata
import inspect
from typing import Any

from shape_toolkit.api.interfaces import FAMILY_INTERFACES, BasePlugin
from shape_toolkit.errors import ParameterError, PluginError

__all__ = [
    "FAMILY_GROUPS", "Registry", "get_registry", "get_plugin", "create_plugin", "create_seeded", "available_plugins",
    "plugins_taking_constraints",
]

#: family name -> entry-point group whose names are that family's plugin names
FAMILY_GROUPS: dict[str, str] = {family: f"shape_toolkit.{family}" for family in FAMILY_INTERFACES}


def _class_path(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"


class Registry:
    """Entry-point names per family (read without importing) and the ``(family, name) -> class`` table,
    filled as plugins are used or registered."""

    def __init__(self, load_entry_points: bool = True):
        self.broken: dict[str, str] = {}
        self._entry_points: dict[str, dict[str, importlib.metadata.EntryPoint]] = {f: {} for f in FAMILY_GROUPS}
        self._classes: dict[str, dict[str, type]] = {f: {} for f in FAMILY_GROUPS}
        if load_entry_points:
            for family, group in FAMILY_GROUPS.items():
                for ep in importlib.metadata.entry_points(group=group):
                    self._entry_points[family].setdefault(ep.name, ep)

    # -- registration -------------------------------------------------------------------------
    def register(self, family: str, name: str, cls: type) -> None:
        """Register ``cls`` as the ``family`` plugin ``name`` in this process (tests, notebooks); a name an
        entry point already gives another class is refused."""
        self._check_family(family)
        self._add_class(family, name, cls, _class_path(cls) if isinstance(cls, type) else repr(cls))

    def unregister(self, family: str, name: str) -> None:
        """Forget the class registered (or loaded) as ``name`` in ``family``."""
        self._classes[family].pop(name, None)

    def _add_class(self, family: str, name: str, cls: Any, origin: str) -> None:
        base, method = FAMILY_INTERFACES[family]
        if not isinstance(cls, type) or not callable(getattr(cls, method, None)):
            raise PluginError(
                f"plugin {origin!r} offers {family} {name!r} without a {method}() method "
                f"(see {base.__module__}.{base.__name__})"
            )
        known = self._classes[family].get(name)
        if known is not None and known is not cls:
            raise PluginError(f"two plugins register {family} {name!r}: {_class_path(known)} and {origin}")
        ep = self._entry_points[family].get(name)
        if known is None and ep is not None and origin != ep.value:
            raise PluginError(f"two plugins register {family} {name!r}: {ep.value} and {origin}")
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
        if not isinstance(obj, type):
            raise PluginError(
                f"entry point {name!r} of group {ep.group!r} names {ep.value!r}, not a class: write "
                f"'package.module:Class' (installed metadata older than the package? reinstall it)"
            )
        self._add_class(family, name, obj, ep.value)

    # -- lookup -------------------------------------------------------------------------------
    def names(self, family: str) -> list[str]:
        """Sorted plugin names of ``family``, without importing any plugin."""
        self._check_family(family)
        return sorted(set(self._entry_points[family]) | set(self._classes[family]))

    def families(self) -> dict[str, list[str]]:
        """``{family: sorted names}`` for every family (empty lists allowed)."""
        return {fam: self.names(fam) for fam in FAMILY_GROUPS}

    def entry_point(self, family: str, name: str) -> str | None:
        """The ``module:Class`` an entry point declares for ``(family, name)``, without importing it."""
        ep = self._entry_points.get(family, {}).get(name)
        return None if ep is None else ep.value

    def _check_family(self, family: str) -> None:
        if family not in FAMILY_GROUPS:
            raise PluginError(f"unknown plugin family {family!r}; families: {sorted(FAMILY_GROUPS)}")

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


def create_seeded(family: str, name: str, preset: str | None, seed: Any, **params: Any) -> Any:
    """:func:`create_plugin` with ``random_state=seed`` passed only to a plugin that takes it, unless ``params``
    give one: a seed for a whole run or command line, harmless for deterministic plugins (None: no seed)."""
    cls = get_registry().get(family, name)
    names = cls._param_names() if issubclass(cls, BasePlugin) else list(inspect.signature(cls).parameters)
    if seed is not None and "random_state" in names and "random_state" not in params:
        params["random_state"] = seed
    return create_plugin(family, name, preset, **params)


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
