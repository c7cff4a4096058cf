"""Bounded parameter declarations shared by several segmenters (:mod:`shape_toolkit.api.params`).

Each upper or lower bound keeps the arithmetic of the parameter finite (no overflow, hence no numpy
warning and no hang) and is stated, with its reason, in the ``doc`` that ``shape-toolkit plugins show``
prints. The defaults of every segmenter lie well inside them.
"""

from __future__ import annotations

from shape_toolkit.api.params import Interval, Param

#: largest convex_factor: a ratio of crease weights
MAX_CONVEX_FACTOR = 1e6
#: largest smoothing_lambda: a ratio of boundary to data cost
MAX_SMOOTHING_LAMBDA = 1e6
#: smallest concavity_scale: sigma = concavity_scale * mean dissimilarity
MIN_CONCAVITY_SCALE = 1e-6

#: convex_factor of the concavity-weighted dual graphs (affinities and graph-cut costs)
CONVEX_FACTOR = Param(
    Interval(float, 0, MAX_CONVEX_FACTOR),
    doc="weight of convex edges relative to concave ones; <= 1e6: at 1e6 a convex crease of 0.12 degrees already "
        "counts as much as the sharpest concave one, and per-edge terms of at most 2e6 cannot overflow their sums",
)
#: convex_factor of the graph cut (sdf, smoothed): the cut cost of an edge is -log(max(theta / pi * s, EPS))
GRAPH_CUT_CONVEX_FACTOR = Param(
    Interval(float, 0, 1),
    doc="scale of convex angles in the cut cost -log(theta/pi * s); <= 1: 1 treats convex creases as concave "
        "ones, above it theta/pi * s can pass 1 and the cost turn negative (a cut that lowers the energy)",
)
#: the weight of the boundary cost of the alpha-expansion graph cut
SMOOTHING_LAMBDA_DOC = (
    "; <= 1e6: a million times the data cost's weight, and lambda times the cut costs (at most -log(5e-6) = "
    "12.2 an edge, times its relative length) cannot overflow"
)
#: concavity_scale of the concavity-weighted affinities (ncut, seeded-walk)
CONCAVITY_SCALE = Param(
    Interval(float, MIN_CONCAVITY_SCALE, None),
    doc="how strongly concave edges are weakened (sigma = scale * mean dissimilarity); >= 1e-6: below it every "
        "edge but near-flat ones is already at min_weight, and d / sigma (<= edges / scale) cannot overflow",
)


def smoothing_lambda(doc: str) -> Param:
    """The ``smoothing_lambda`` declaration with ``doc`` (the plugin's meaning) and the bound's reason."""
    return Param(Interval(float, 0, MAX_SMOOTHING_LAMBDA), doc=doc + SMOOTHING_LAMBDA_DOC)
