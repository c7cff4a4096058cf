"""Declarative constraints on plugin parameters, in the spirit of scikit-learn's ``_parameter_constraints``.

A plugin class declares, per constructor parameter, the values it takes and a one-line description::

    class GaussianWeighting(Weighting):
        parameter_constraints = {
            "bandwidth": Param(None, Options("auto", "local", "mean"), Interval(float, 0, None, closed="neither"),
                               doc="sigma in the shape's length units, or an automatic rule"),
            "bandwidth_scale": Param(Interval(float, 0, None, closed="neither"), doc="multiplies automatic sigmas"),
        }

A value is valid when any of the listed constraints accepts it. :class:`~shape_toolkit.api.interfaces.BasePlugin`
checks the current values when the plugin is used (never in ``__init__``: scikit-learn's ``clone`` contract) and
raises a one-line :class:`~shape_toolkit.errors.ParameterError` naming the plugin, the parameter, the value and what
is allowed; ``shape-toolkit plugins show NAME`` prints the same declarations. Checks across parameters, or against
the shape, stay as code in the plugin.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from shape_toolkit.errors import ParameterError
from shape_toolkit.validation import finite_number, shown_value

__all__ = [
    "Constraint", "Interval", "Options", "InstanceOf", "ListOf", "PluginRef", "Param", "RANDOM_STATE",
    "validate_params", "check_before",
]


def _fmt(x: float) -> str:
    return f"{x:g}" if isinstance(x, float) else str(x)


class Constraint:
    """One kind of accepted value: :meth:`accepts` a value, :meth:`describe` in words, :attr:`type_name`."""

    type_name = "object"

    def accepts(self, value: Any) -> bool:  # pragma: no cover - abstract
        """Whether ``value`` satisfies this constraint."""
        raise NotImplementedError

    def describe(self) -> str:  # pragma: no cover - abstract
        """The accepted values in words, e.g. ``"a positive int"``."""
        raise NotImplementedError


class _NoneConstraint(Constraint):
    type_name = "None"

    def accepts(self, value: Any) -> bool:
        return value is None

    def describe(self) -> str:
        return "None"


class Interval(Constraint):
    """A number of ``kind`` (``int``: Python or numpy integers; ``float``: any finite real, int included) in
    ``[low, high]``; ``None`` is an open end, ``closed`` one of ``"both"``, ``"left"``, ``"right"``, ``"neither"``.
    Booleans and NaN are never numbers here; floats are finite."""

    def __init__(self, kind: type, low: float | None = None, high: float | None = None, closed: str = "both"):
        if kind not in (int, float) or closed not in ("both", "left", "right", "neither"):
            raise ValueError(f"Interval(kind={kind!r}, closed={closed!r})")  # programming error in a plugin
        self.kind, self.low, self.high, self.closed = kind, low, high, closed
        self.type_name = kind.__name__

    def accepts(self, value: Any) -> bool:
        if isinstance(value, (bool, np.bool_)):
            return False
        if self.kind is int:
            if not isinstance(value, (int, np.integer)):
                return False
        elif not isinstance(value, (int, float, np.integer, np.floating)) or not finite_number(value):
            return False
        if self.low is not None and (value < self.low or (value == self.low and self.closed in ("right", "neither"))):
            return False
        return not (
            self.high is not None and (value > self.high or (value == self.high and self.closed in ("left", "neither")))
        )

    def describe(self) -> str:
        noun = "an int" if self.kind is int else "a float"
        low_in = self.closed in ("both", "left")
        high_in = self.closed in ("both", "right")
        if self.low is None and self.high is None:
            return noun if self.kind is int else "a finite float"
        if self.high is None:
            if self.low == 0:
                return f"{'a non-negative' if low_in else 'a positive'} {noun.split()[-1]}"
            if self.kind is int and self.low == 1 and low_in:
                return "a positive int"
            return f"{noun} {'>=' if low_in else '>'} {_fmt(self.low)}"
        if self.low is None:
            return f"{noun} {'<=' if high_in else '<'} {_fmt(self.high)}"
        return f"{noun} in {'[' if low_in else '('}{_fmt(self.low)}, {_fmt(self.high)}{']' if high_in else ')'}"


class Options(Constraint):
    """One of the listed values (strings, usually), compared by type and equality."""

    def __init__(self, *values: Any):
        self.values = values
        self.type_name = type(values[0]).__name__ if values else "object"

    def accepts(self, value: Any) -> bool:
        return any(type(value) is type(v) and value == v for v in self.values)

    def describe(self) -> str:
        return repr(self.values[0]) if len(self.values) == 1 else f"one of {', '.join(repr(v) for v in self.values)}"


class InstanceOf(Constraint):
    """An instance of one of ``types`` (``bool`` also takes numpy booleans), or any callable with ``callable``."""

    def __init__(self, *types: type | Callable, name: str | None = None):
        self.types = types
        names = ["callable" if t is callable else t.__name__ for t in types]
        self.type_name = name or " | ".join(names)

    def accepts(self, value: Any) -> bool:
        for t in self.types:
            if t is callable:
                if callable(value):
                    return True
            elif t is bool:
                if isinstance(value, (bool, np.bool_)):
                    return True
            elif isinstance(value, t) and not (t in (int, float) and isinstance(value, bool)):
                return True
        return False

    def describe(self) -> str:
        return " or ".join(("an " if n[0].lower() in "aeiou" else "a ") + n for n in self.type_name.split(" | "))


class ListOf(Constraint):
    """A list, tuple or 1-D array of at least ``min_len`` items, each accepted by ``item``."""

    def __init__(self, item: Constraint, min_len: int = 1):
        self.item, self.min_len = item, min_len
        self.type_name = f"list[{item.type_name}]"

    def accepts(self, value: Any) -> bool:
        if isinstance(value, np.ndarray):
            if value.ndim != 1:
                return False
            value = value.tolist()
        return isinstance(value, (list, tuple)) and len(value) >= self.min_len and all(map(self.item.accepts, value))

    def describe(self) -> str:
        count = f"at least {self.min_len}" if self.min_len > 1 else "one or more"
        return f"a list of {count}, each {self.item.describe()}"


class PluginRef(Constraint):
    """A plugin of ``family``: its registry name (a string, resolved when used) or a plugin object."""

    def __init__(self, family: str):
        self.family = family
        self.type_name = f"{family} plugin"

    def accepts(self, value: Any) -> bool:
        return isinstance(value, str) or (not isinstance(value, type) and getattr(value, "family", None) == self.family)

    def describe(self) -> str:
        return f"a {self.family} plugin (its name or an object)"


def _as_constraint(c: Any) -> Constraint:
    if c is None:
        return _NoneConstraint()
    if isinstance(c, Constraint):
        return c
    if isinstance(c, type) or c is callable:
        return InstanceOf(c)
    raise TypeError(f"not a parameter constraint: {c!r}")  # programming error in a plugin


class Param:
    """The declaration of one parameter: accepted values (any of the constraints; ``None`` for None, a type
    for its instances) and a one-line description ``doc``."""

    def __init__(self, *constraints: Any, doc: str):
        self.constraints = [_as_constraint(c) for c in constraints]
        self.doc = doc

    def accepts(self, value: Any) -> bool:
        """Whether any constraint accepts ``value``."""
        return any(c.accepts(value) for c in self.constraints)

    @property
    def type_name(self) -> str:
        """The accepted types, e.g. ``"float | str | None"``."""
        names = list(dict.fromkeys(c.type_name for c in self.constraints))
        return " | ".join(sorted(names, key=lambda n: n == "None"))

    def describe(self) -> str:
        """The accepted values in words, e.g. ``"None, 'auto', 'mean' or a positive float"``."""
        parts = [c.describe() for c in sorted(self.constraints, key=lambda c: not isinstance(c, _NoneConstraint))]
        return parts[0] if len(parts) == 1 else f"{', '.join(parts[:-1])} or {parts[-1]}"


#: scikit-learn's random_state: None, a seed in [0, 2**32 - 1], or a numpy Generator / RandomState
RANDOM_STATE = Param(
    None, Interval(int, 0, 2**32 - 1), InstanceOf(np.random.Generator, np.random.RandomState),
    doc="seed or numpy generator of the random choices (None: fresh entropy)",
)


def validate_params(owner: str, constraints: Mapping[str, Param], values: Mapping[str, Any]) -> None:
    """Raise :class:`ParameterError` (one line: ``owner``, parameter, value, what is allowed) for the first of
    ``values`` that its declaration in ``constraints`` refuses; undeclared parameters are not checked."""
    for name, param in constraints.items():
        if name in values and not param.accepts(values[name]):
            raise ParameterError(f"{owner}: {name} must be {param.describe()}, got {shown_value(values[name])}")


def _checked(fn: Callable) -> Callable:
    @functools.wraps(fn)
    def wrapper(self: Any, *args: Any, **kwargs: Any) -> Any:
        self._validate_params()
        for arg in (*args, *kwargs.values()):  # the shapes given: within the computations' range
            check = getattr(type(arg), "check_computable", None)
            if callable(check):
                check(arg)
        return fn(self, *args, **kwargs)

    wrapper._validates = True  # type: ignore[attr-defined]
    return wrapper


def check_before(cls: type, methods: tuple[str, ...]) -> None:
    """Make each of ``methods`` of ``cls`` (its own or a mixin's; abstract ones aside) call
    ``self._validate_params()`` first: checked at use, as scikit-learn checks at ``fit``, never in ``__init__``;
    and check every argument that can check itself (a ``Shape``'s ``check_computable``: coordinates within the
    range the computations' products of areas fit in float64)."""
    for name in methods:
        fn = getattr(cls, name, None)
        if callable(fn) and not getattr(fn, "__isabstractmethod__", False) and not hasattr(fn, "_validates"):
            setattr(cls, name, _checked(fn))
