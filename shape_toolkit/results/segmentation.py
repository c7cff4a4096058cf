"""What a segmenter returns: a :class:`Segmentation` (vertex labels, face labels, info).

A segmenter labels vertices or faces, whichever its graph's nodes are (the dual graph's nodes are
faces); the other labels are derived, deterministically: face labels from vertex labels by each
face's majority (:func:`~shape_toolkit.results.labels.vertex_to_face_labels`), vertex labels from
face labels by the largest incident area (:func:`~shape_toolkit.results.labels.face_segments_to_vertices`).
``info["per"]`` says which of the two the method made.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from shape_toolkit.errors import ParameterError
from shape_toolkit.results.labels import face_segments_to_vertices, vertex_to_face_labels

if TYPE_CHECKING:  # pragma: no cover
    from shape_toolkit.core.shape import Shape

__all__ = ["Segmentation"]


@dataclass(frozen=True, eq=False)
class Segmentation:
    """A segmentation of one shape.

    ``labels``: int64 ``(n,)``, one label per vertex in ``0..k-1``; ``face_labels``: int64 ``(m,)``,
    one per face, on a mesh (None on a point cloud); ``info``: what the segmenter reports, JSON-able:
    ``per`` (``"vertex"`` or ``"face"``: which labels the method made, the others being derived),
    ``constraints`` (:func:`~shape_toolkit.results.labels.constraint_report` of the labels, when
    constraints were given), ``n_components`` and ``segments_per_component`` (when the shape was
    segmented piece by piece)."""

    labels: np.ndarray
    face_labels: np.ndarray | None = None
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        labels = np.asarray(self.labels)
        if labels.ndim != 1 or (labels.size and not np.issubdtype(labels.dtype, np.integer)):
            raise ParameterError(f"segmentation labels must be integers of shape (n,), got {labels.dtype} "
                                 f"{labels.shape}")
        object.__setattr__(self, "labels", labels.astype(np.int64, copy=False))
        if self.face_labels is not None:
            fl = np.asarray(self.face_labels)
            if fl.ndim != 1 or (fl.size and not np.issubdtype(fl.dtype, np.integer)):
                raise ParameterError(f"face labels must be integers of shape (m,), got {fl.dtype} {fl.shape}")
            object.__setattr__(self, "face_labels", fl.astype(np.int64, copy=False))
        if not isinstance(self.info, dict):
            raise ParameterError(f"segmentation info must be a dict, got {type(self.info).__name__}")

    @classmethod
    def of_vertices(cls, shape: Shape, labels: np.ndarray, **info: Any) -> Segmentation:
        """The segmentation of the vertex ``labels`` ``(n,)`` of ``shape``; on a mesh the face labels
        are each face's majority vertex label."""
        labels = np.asarray(labels, dtype=np.int64)
        faces = vertex_to_face_labels(shape.faces, labels) if shape.is_mesh else None
        return cls(labels, faces, {"per": "vertex", **info})

    @classmethod
    def of_faces(cls, shape: Shape, face_labels: np.ndarray, **info: Any) -> Segmentation:
        """The segmentation of the ``face_labels`` ``(m,)`` of the mesh ``shape``; a vertex takes the
        label of its largest incident area (a vertex on no face, its nearest vertex's)."""
        face_labels = np.asarray(face_labels, dtype=np.int64)
        return cls(face_segments_to_vertices(shape, face_labels), face_labels, {"per": "face", **info})

    @property
    def n_segments(self) -> int:
        """The number of distinct vertex labels."""
        return int(np.unique(self.labels).size)

    def with_info(self, **info: Any) -> Segmentation:
        """A copy whose ``info`` also holds ``info`` (same label arrays)."""
        return dataclasses.replace(self, info={**self.info, **info})
