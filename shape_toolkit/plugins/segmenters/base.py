"""The base of the built-in segmenters: :meth:`BaseSegmenter.segment`, a template method.

A segmenter implements :meth:`BaseSegmenter._segment` (the algorithm, on a shape of one piece) and
returns a :class:`~shape_toolkit.results.segmentation.Segmentation`; the template refuses constraints
it does not use, forgets the fitted attributes of a previous call, segments a shape of several pieces
piece by piece through :class:`~shape_toolkit.plugins.segmenters.per_component.PerComponent`, and
reports the constraints (:func:`~shape_toolkit.plugins.segmenters.constraints.report_constraints`).

Default shape graph of the segmenters (thesis 3.3.3, 4.1.2, 5.2): mesh connectivity (kNN for point
clouds) with Gaussian weights ``exp(-d^2 / 2 sigma^2)``, sigma = mean edge length, so that
``0 < w_ij <= 1``; their spectra are declared with :func:`segmenter_spec` (no mass matrix).
"""

from __future__ import annotations

from abc import abstractmethod
from typing import Any, ClassVar

from shape_toolkit.api.interfaces import Segmenter
from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import DisconnectedGraphError, NumericallyDisconnectedGraphError
from shape_toolkit.plugins.segmenters.constraints import inner_segmentation, report_constraints
from shape_toolkit.plugins.segmenters.per_component import PerComponent
from shape_toolkit.results.segmentation import Segmentation
from shape_toolkit.spectra import SpectrumSpec, default_spec

__all__ = ["BaseSegmenter", "segmenter_spec"]


def segmenter_spec(k: int, weighting: str, laplacian: str) -> SpectrumSpec:
    """The spectrum a segmenter declares: ``k`` eigenpairs of the ``laplacian`` of the ``weighting``
    graph, no mass matrix (:func:`shape_toolkit.core.spectrum.default_spec` of kind ``graph``)."""
    return default_spec(int(k), "graph", weighting=weighting, laplacian=laplacian)


class BaseSegmenter(Segmenter):
    """A segmenter whose :meth:`segment` runs :meth:`_segment` on each piece of the shape.

    Hooks: :meth:`component_graph` (which pieces of a mesh are segmented one by one), ``split_clouds``
    (whether a point cloud whose graph falls apart is), :meth:`_check_params` (checks made before any
    split)."""

    #: a point cloud given no spectrum whose graph falls apart (``_segment`` raises
    #: :class:`~shape_toolkit.errors.DisconnectedGraphError`) is segmented piece by piece
    split_clouds: ClassVar[bool] = False

    def component_graph(self, shape: Shape) -> str | None:
        """Whose connected pieces of the mesh ``shape`` are segmented one by one: ``"vertex"`` (the vertex
        graph, the default), ``"dual"`` (the dual graph, for a segmenter of faces) or None (the segmenter
        handles pieces itself)."""
        return "vertex"

    def _check_params(self, shape: Shape) -> None:
        """Raise :class:`~shape_toolkit.errors.ParameterError` for parameters ``shape`` cannot take, before
        it is split into pieces (default: none; each piece is checked by :meth:`_segment`)."""

    @abstractmethod
    def _segment(self, shape: Shape, *, spectrum: Any, constraints: Any) -> Segmentation:
        """The segmentation of ``shape``, of one piece unless :meth:`component_graph` is None."""

    def segment(self, shape: Shape, *, spectrum: Any = None, constraints: Any | None = None) -> Segmentation:
        """The :class:`~shape_toolkit.results.segmentation.Segmentation` of ``shape``: vertex labels
        ``(n,)`` in ``0..k-1``, face labels ``(m,)`` on a mesh, ``info``. ``constraints`` (Constraints,
        dict or JSON path) go to a segmenter that uses them and are refused by the others
        (:class:`~shape_toolkit.errors.ParameterError`); ``info["constraints"]`` says which were kept."""
        self.check_constraints(constraints)
        for name in [a for a in vars(self) if a.endswith("_") and not a.startswith("_")]:  # fitted before
            del vars(self)[name]
        with inner_segmentation():
            result = self._segment_pieces(shape, spectrum, constraints)
        return report_constraints(self, result, constraints, shape.n_vertices)

    def _segment_pieces(self, shape: Shape, spectrum: Any, constraints: Any) -> Segmentation:
        """:meth:`_segment` on ``shape``, or on each of its pieces (:class:`PerComponent`)."""
        self._check_params(shape)
        graph = self.component_graph(shape) if shape.is_mesh else None
        if graph is not None:
            split = PerComponent(self, pieces=graph).segment_pieces(shape, constraints)
            if split is not None:
                return split
        try:
            return self._segment(shape, spectrum=spectrum, constraints=constraints)
        except DisconnectedGraphError as exc:
            if (not self.split_clouds or shape.is_mesh or spectrum is not None
                    or isinstance(exc, NumericallyDisconnectedGraphError)):
                raise
            split = PerComponent(self).segment_pieces(shape, constraints)  # the pieces of its kNN graph
            if split is None:
                raise
            return split
