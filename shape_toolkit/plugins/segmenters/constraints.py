"""Must-link / cannot-link constraints on the segmenters' side: the clicked groups, and the report every
segmentation given constraints carries (``info["constraints"]``, and a :class:`ConstraintWarning` when
some are broken), so a segmenter keeps every click or says so."""

from __future__ import annotations

import contextlib
import contextvars
import warnings
from collections.abc import Iterator
from typing import Any

import numpy as np

from shape_toolkit.core.geometry import edge_components
from shape_toolkit.results.labels import coerce_constraints, constraint_report
from shape_toolkit.results.segmentation import Segmentation


def must_link_groups(must_link: np.ndarray) -> list[np.ndarray]:
    """The node sets ``[ids, ...]`` joined by the ``(m, 2)`` must-link pairs: connected components of
    the must-link graph over the constrained nodes (a chain of clicks is one group), each sorted, the
    groups in order of first appearance in ``must_link`` (row-major)."""
    ml = np.asarray(must_link, dtype=np.int64).reshape(-1, 2)
    if len(ml) == 0:
        return []
    nodes, inv = np.unique(ml, return_inverse=True)
    inv = inv.reshape(-1, 2)
    _, comp = edge_components(len(nodes), inv)
    seen, first = np.unique(comp[inv.ravel()], return_index=True)
    return [nodes[comp == c] for c in seen[np.argsort(first)]]


class ConstraintWarning(UserWarning):
    """A constrained segmenter returned labels that break some of its must-links or cannot-links."""


#: how deep in nested segment calls we are: a segmenter's own pieces (per component) or base (``smoothed``)
#: are reported through the outermost call only
_DEPTH: contextvars.ContextVar[int] = contextvars.ContextVar("segment_depth", default=0)


@contextlib.contextmanager
def inner_segmentation() -> Iterator[None]:
    """Context of the segment calls a segmenter makes on its way (pieces, a base): they do not report."""
    token = _DEPTH.set(_DEPTH.get() + 1)
    try:
        yield
    finally:
        _DEPTH.reset(token)


def report_constraints(segmenter: Any, result: Segmentation, constraints: Any, n_vertices: int) -> Segmentation:
    """``result`` with ``info["constraints"]`` (:func:`~shape_toolkit.results.labels.constraint_report` of
    its vertex labels) when ``constraints`` (Constraints, dict or path over ``n_vertices`` vertices) hold
    any pair, and a :class:`ConstraintWarning` (one line: how many ``segmenter`` could not keep and why)
    when some are broken. Inside :func:`inner_segmentation`, ``result`` unchanged."""
    if constraints is None or _DEPTH.get() > 0:
        return result
    cons = coerce_constraints(constraints, n_vertices)
    if cons is None or len(cons) == 0:
        return result
    rep = constraint_report(result.labels, cons)
    if rep["reason"] is not None:
        warnings.warn(
            f"{type(segmenter).__name__} broke {rep['must_link_broken']} of {rep['must_link']} must-links and "
            f"{rep['cannot_link_broken']} of {rep['cannot_link']} cannot-links: {rep['reason']}",
            ConstraintWarning, stacklevel=4,  # the caller of segment (past the template and the parameter check)
        )
    return result.with_info(constraints=rep)
