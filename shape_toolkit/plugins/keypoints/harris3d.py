"""Harris 3D interest points (Sipiran and Bustos, The Visual Computer 2011), thesis Table 6.1."""

from __future__ import annotations

import numpy as np

from shape_toolkit.api.interfaces import KeypointDetector
from shape_toolkit.api.params import Interval, Options, Param
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.errors import ParameterError
from shape_toolkit.features.geodesics import adjacency, k_ring_all, ring_maxima
from shape_toolkit.plugins._params import POSITIVE, POSITIVE_INT

_MIN_POINTS = 10  # enough points for a well-posed 6-parameter quadratic fit

#: ``k`` of the response: the matrix ``[[A, C], [C, B]]`` is the Gram matrix of ``(p4, sqrt2 p1, sqrt2 p2)`` and
#: ``(p5, sqrt2 p2, sqrt2 p3)``, so ``0 <= AB - C^2 <= (A + B)^2 / 4``: with ``k >= 1/4`` no response is positive,
#: with ``k <= 0`` none is negative (corners and edges are no longer told apart)
HARRIS_K = Interval(float, 0, 0.25, closed="neither")


def harris_response(shape: Shape, neighbourhoods: list[np.ndarray], k: float = 0.04) -> np.ndarray:
    """Harris 3D response ``(n,)``: per vertex, PCA frame of its neighbourhood (normal = least
    variance), quadratic patch ``z = p1/2 x^2 + p2 xy + p3/2 y^2 + p4 x + p5 y + p6`` fitted with
    the vertex at the origin, Gaussian-integrated derivative products ``A = p4^2 + 2 p1^2 +
    2 p2^2``, ``B = p5^2 + 2 p2^2 + 2 p3^2``, ``C = p4 p5 + 2 p1 p2 + 2 p2 p3`` and
    ``R = AB - C^2 - k (A + B)^2``."""
    V = shape.vertices
    n = V.shape[0]
    out = np.zeros(n)
    for i in range(n):
        P = V[neighbourhoods[i]]
        c = P.mean(axis=0)
        Q = P - c
        _, vecs = np.linalg.eigh(Q.T @ Q)  # ascending: vecs[:, 0] is the normal
        R = vecs[:, [2, 1, 0]]  # x: largest variance, y: middle, z: normal
        X = (P - V[i]) @ R
        x, y, z = X[:, 0], X[:, 1], X[:, 2]
        A_ = np.column_stack([0.5 * x * x, x * y, 0.5 * y * y, x, y, np.ones_like(x)])
        p, *_ = np.linalg.lstsq(A_, z, rcond=None)
        p1, p2, p3, p4, p5 = p[:5]
        A = p4 * p4 + 2 * p1 * p1 + 2 * p2 * p2
        B = p5 * p5 + 2 * p2 * p2 + 2 * p3 * p3
        C = p4 * p5 + 2 * p1 * p2 + 2 * p2 * p3
        out[i] = A * B - C * C - k * (A + B) ** 2
    return out


class Harris3D(KeypointDetector):
    """Harris 3D detector.

    Neighbourhood (``neighbourhood``): ``"adaptive"``: the vertices connected to ``v`` through the
    mesh within Euclidean distance ``neighbourhood_param x`` bounding-box diagonal of ``v``
    (searched up to ``max_rings`` rings, and grown ring by ring to at least 10 vertices);
    ``"rings"``: the ``neighbourhood_param``-ring. Response with Harris parameter ``k``;
    candidates are the strict maxima over their ``ring``-ring; ``selection="fraction"`` keeps the
    ``selection_param x n`` strongest candidates (at least one), ``"clustering"`` visits the
    candidates strongest first and keeps those farther than ``selection_param x`` diagonal from
    every kept one. Presets ``sparse``/``dense`` are the two setups of thesis Table 6.1. Needs a
    triangle mesh; the ``spectrum`` argument is ignored.
    """

    presets = {
        "sparse": {
            "neighbourhood": "adaptive", "neighbourhood_param": 0.01, "k": 0.04, "ring": 2,
            "selection": "fraction", "selection_param": 0.001,
        },
        "dense": {
            "neighbourhood": "adaptive", "neighbourhood_param": 0.01, "k": 0.04, "ring": 2,
            "selection": "clustering", "selection_param": 0.001,
        },
    }

    parameter_constraints = {
        "neighbourhood": Param(Options("adaptive", "rings"), doc="Euclidean radius within the mesh, or k-rings"),
        "neighbourhood_param": Param(
            POSITIVE, doc="radius (x bounding-box diagonal), or for 'rings' a whole ring count >= 1 (saturates)"
        ),
        "k": Param(HARRIS_K, doc="Harris parameter of R = AB - C^2 - k (A + B)^2; 0 <= AB - C^2 <= (A + B)^2 / 4, "
                                 "so k >= 1/4 leaves no positive response and k <= 0 no negative one"),
        "ring": Param(POSITIVE_INT, doc="candidates are strict maxima over their ring-ring (saturates)"),
        "selection": Param(Options("fraction", "clustering"), doc="keep the strongest fraction, or spread them"),
        "selection_param": Param(Interval(float, 0, 1, closed="right"), doc="fraction of the vertices, or min "
                                 "distance (x diagonal); at most 1: every vertex, or one keypoint"),
        "max_rings": Param(POSITIVE_INT, doc="rings searched for the adaptive neighbourhood"),
    }

    def __init__(
        self,
        neighbourhood: str = "adaptive",
        neighbourhood_param: float = 0.01,
        k: float = 0.04,
        ring: int = 2,
        selection: str = "fraction",
        selection_param: float = 0.001,
        max_rings: int = 6,
    ):
        self.neighbourhood = neighbourhood
        self.neighbourhood_param = neighbourhood_param
        self.k = k
        self.ring = ring
        self.selection = selection
        self.selection_param = selection_param
        self.max_rings = max_rings

    def _validate(self) -> None:
        self._validate_params()
        if self.neighbourhood == "rings" and int(self.neighbourhood_param) != self.neighbourhood_param:
            raise ParameterError(
                f"{type(self).__name__}: with neighbourhood='rings', neighbourhood_param must be a whole ring count "
                f">= 1, got {self.neighbourhood_param!r}"
            )

    def neighbourhoods(self, shape: Shape) -> list[np.ndarray]:
        """Per-vertex neighbourhood ids (each includes the vertex)."""
        A = adjacency(shape)
        V = shape.vertices
        n = shape.n_vertices
        if self.neighbourhood == "rings":
            R = k_ring_all(A, int(self.neighbourhood_param))  # saturates: a huge count costs no more
            return [R.indices[R.indptr[i] : R.indptr[i + 1]] for i in range(n)]
        radius = float(self.neighbourhood_param) * shape.diagonal
        out: list[np.ndarray] = []
        indptr, indices = A.indptr, A.indices
        for i in range(n):
            seen = {i}
            keep = [i]
            front = [i]
            for _ in range(int(self.max_rings)):
                nxt = []
                for a in front:
                    for b in indices[indptr[a] : indptr[a + 1]]:
                        if b not in seen:
                            seen.add(b)
                            nxt.append(b)
                if not nxt:
                    break
                nb = np.asarray(nxt)
                close = nb[np.linalg.norm(V[nb] - V[i], axis=1) <= radius]
                if len(keep) < _MIN_POINTS:  # too few within the radius: take the whole ring
                    close = nb
                keep.extend(close.tolist())
                front = close.tolist()
                if not front:
                    break
            out.append(np.asarray(sorted(keep), dtype=np.int64))
        return out

    def response(self, shape: Shape) -> np.ndarray:
        """Harris response ``(n,)`` of every vertex."""
        self._validate()
        shape.require_faces("the harris3d detector")
        return harris_response(shape, self.neighbourhoods(shape), float(self.k))

    def detect(self, shape: Shape, *, spectrum: Spectrum | None = None) -> np.ndarray:
        """0-based int64 keypoint ids ``(p,)``, strongest response first."""
        return self.select(shape, self.response(shape))

    def select(self, shape: Shape, resp: np.ndarray) -> np.ndarray:
        """Ring maxima of a response ``(n,)`` and the fraction/clustering selection."""
        self._validate()
        resp = np.asarray(resp, dtype=np.float64)
        if resp.shape != (shape.n_vertices,):
            raise ParameterError(f"response must have shape ({shape.n_vertices},), got {resp.shape}")
        scale = float(np.abs(resp).max()) or 1.0
        cand = ring_maxima(np.round(resp / scale, 12), adjacency(shape), int(self.ring))
        if self.selection == "fraction":
            count = max(1, int(round(float(self.selection_param) * shape.n_vertices)))
            return cand[:count]
        min_dist = float(self.selection_param) * shape.diagonal
        kept: list[int] = []
        V = shape.vertices
        for c in cand:
            if not kept or np.min(np.linalg.norm(V[kept] - V[c], axis=1)) > min_dist:
                kept.append(int(c))
        return np.asarray(kept, dtype=np.int64)
