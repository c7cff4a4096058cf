"""Helpers shared by CLI subcommands."""

from __future__ import annotations

import json
import sys
from typing import Any

import numpy as np

from shape_toolkit.errors import ParameterError


def _default(o: Any) -> Any:
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.bool_):
        return bool(o)
    return str(o)


def print_json(obj: Any) -> None:
    """Print ``obj`` as JSON (numpy values converted) on stdout."""
    json.dump(obj, sys.stdout, default=_default, indent=2)
    sys.stdout.write("\n")


def to_json_text(obj: Any) -> str:
    """``obj`` as a JSON string (numpy values converted)."""
    return json.dumps(obj, default=_default, indent=2)


def parse_params(items: list[str] | None) -> dict[str, Any]:
    """Parse ``KEY=VALUE`` strings; values are read as JSON when possible (numbers, true, lists)."""
    out: dict[str, Any] = {}
    for item in items or []:
        if "=" not in item:
            raise ParameterError(f"--param expects KEY=VALUE, got {item!r}")
        key, value = item.split("=", 1)
        key = key.strip().replace("-", "_")
        if not key:
            raise ParameterError(f"--param expects KEY=VALUE, got {item!r}")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out
