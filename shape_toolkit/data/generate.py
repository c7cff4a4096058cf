"""Small synthetic shapes with known geometry, for tests and examples."""

from __future__ import annotations

import numpy as np

from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError

__all__ = ["icosphere"]


def _icosahedron() -> tuple[np.ndarray, np.ndarray]:
    t = (1.0 + 5.0**0.5) / 2.0
    v = np.array(
        [
            [-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0],
            [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
            [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1],
        ],
        dtype=np.float64,
    )  # fmt: skip
    f = np.array(
        [
            [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
            [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
            [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
            [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
        ],
        dtype=np.int64,
    )  # fmt: skip
    return v / np.linalg.norm(v, axis=1, keepdims=True), f


#: most subdivisions of :func:`icosphere` (10 * 4**7 + 2 = 163,842 vertices)
MAX_SUBDIVISIONS = 7


def icosphere(subdivisions: int = 3, radius: float = 1.0) -> Shape:
    """Icosphere of the given radius centred at the origin, outward-oriented triangles.

    ``subdivisions`` midpoint subdivisions of the icosahedron: ``10 * 4**s + 2`` vertices and
    ``20 * 4**s`` faces (s=3: 642 vertices, 1280 faces). Vertices lie exactly on the sphere.
    """
    if int(subdivisions) != subdivisions or subdivisions < 0 or subdivisions > MAX_SUBDIVISIONS:
        raise ParameterError(f"subdivisions must be an integer in [0, 7], got {subdivisions!r}")
    if not radius > 0:
        raise ParameterError(f"radius must be positive, got {radius!r}")
    v, f = _icosahedron()
    for _ in range(int(subdivisions)):
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, inv = np.unique(e, axis=0, return_inverse=True)
        mid = v[uniq[:, 0]] + v[uniq[:, 1]]
        v = np.concatenate([v, mid / np.linalg.norm(mid, axis=1, keepdims=True)])
        m = len(f)
        inv = inv.ravel() + (len(v) - len(uniq))
        a, b, c = inv[:m], inv[m : 2 * m], inv[2 * m :]  # midpoints of edges 01, 12, 20
        f = np.concatenate(
            [
                np.stack([f[:, 0], a, c], axis=1),
                np.stack([a, f[:, 1], b], axis=1),
                np.stack([c, b, f[:, 2]], axis=1),
                np.stack([a, b, c], axis=1),
            ]
        )
    return Shape(v * float(radius), f, name=f"icosphere{int(subdivisions)}")
