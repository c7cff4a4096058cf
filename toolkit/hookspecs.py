"""pluggy hook specifications: one hook per plugin family.

A plugin module (built-in or third party) implements any of these hooks, returning a mapping
``{name: class}``, and is announced through the entry-point group ``toolkit``::

    [project.entry-points.toolkit]
    my-detector = "my_package.my_module"

Each class follows its family's interface in :mod:`toolkit.interfaces`.
"""

from __future__ import annotations

import pluggy

PROJECT = "toolkit"
ENTRY_POINT_GROUP = "toolkit"

hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


class ToolkitHookSpecs:
    """The hooks every plugin family is discovered through."""

    @hookspec
    def toolkit_weightings(self) -> dict[str, type]:
        """Edge-weighting schemes (:class:`toolkit.interfaces.Weighting`)."""

    @hookspec
    def toolkit_keypoint_detectors(self) -> dict[str, type]:
        """Keypoint detectors (:class:`toolkit.interfaces.KeypointDetector`)."""

    @hookspec
    def toolkit_descriptors(self) -> dict[str, type]:
        """Per-vertex descriptors (:class:`toolkit.interfaces.Descriptor`)."""

    @hookspec
    def toolkit_sparse_matchers(self) -> dict[str, type]:
        """Keypoint matchers (:class:`toolkit.interfaces.SparseMatcher`)."""

    @hookspec
    def toolkit_dense_matchers(self) -> dict[str, type]:
        """Dense matchers (:class:`toolkit.interfaces.DenseMatcher`)."""

    @hookspec
    def toolkit_segmenters(self) -> dict[str, type]:
        """Segmentation methods (:class:`toolkit.interfaces.Segmenter`)."""


#: family name -> hook name
FAMILY_HOOKS: dict[str, str] = {
    "weightings": "toolkit_weightings",
    "keypoints": "toolkit_keypoint_detectors",
    "descriptors": "toolkit_descriptors",
    "sparse_matchers": "toolkit_sparse_matchers",
    "dense_matchers": "toolkit_dense_matchers",
    "segmenters": "toolkit_segmenters",
}
