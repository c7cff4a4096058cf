"""The number of segments a segmenter is asked for, checked (one rule for every segmenter)."""

from __future__ import annotations

from typing import Any

import numpy as np

from shape_toolkit.errors import ParameterError


def check_n_segments(k: Any, n: int, *, allow_none: bool, elements: str = "vertices") -> int | None:
    """Validate the number of segments: an int in ``[2, n]`` (or None when the method can choose); ``elements``:
    what the ``n`` segmented elements are, for the message."""
    if k is None:
        if allow_none:
            return None
        raise ParameterError("n_segments is required for this method (an integer >= 2; -k N on the command line)")
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)):
        raise ParameterError(f"n_segments must be an integer >= 2, got {k!r}")
    if k < 2:
        raise ParameterError(f"n_segments must be >= 2, got {k}")
    if k > n:
        raise ParameterError(f"n_segments = {k} exceeds the number of {elements} ({n})")
    return int(k)
