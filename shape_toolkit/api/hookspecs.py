"""pluggy hook specifications: one hook per plugin family.

A plugin module (built-in or third party) implements its family's hook, returning a mapping
``{name: class}``, and is announced in that family's entry-point group under the same name::

    [project.entry-points."shape_toolkit.keypoints"]
    my-detector = "my_package.my_module"

The older single group ``toolkit`` (``my-detector = "my_package.my_module"``) is still read.

Each class follows its family's interface in :mod:`shape_toolkit.api.interfaces`.
"""

from __future__ import annotations

import pluggy

PROJECT = "shape_toolkit"
#: the older single entry-point group (any family, modules found through their hooks)
ENTRY_POINT_GROUP = "toolkit"

hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


class ToolkitHookSpecs:
    """The hooks every plugin family is discovered through."""

    @hookspec
    def toolkit_weightings(self) -> dict[str, type]:
        """Edge-weighting schemes (:class:`shape_toolkit.api.interfaces.Weighting`)."""

    @hookspec
    def toolkit_keypoint_detectors(self) -> dict[str, type]:
        """Keypoint detectors (:class:`shape_toolkit.api.interfaces.KeypointDetector`)."""

    @hookspec
    def toolkit_descriptors(self) -> dict[str, type]:
        """Per-vertex descriptors (:class:`shape_toolkit.api.interfaces.Descriptor`)."""

    @hookspec
    def toolkit_sparse_matchers(self) -> dict[str, type]:
        """Keypoint matchers (:class:`shape_toolkit.api.interfaces.SparseMatcher`)."""

    @hookspec
    def toolkit_dense_matchers(self) -> dict[str, type]:
        """Dense matchers (:class:`shape_toolkit.api.interfaces.DenseMatcher`)."""

    @hookspec
    def toolkit_segmenters(self) -> dict[str, type]:
        """Segmentation methods (:class:`shape_toolkit.api.interfaces.Segmenter`)."""


#: family name -> hook name
FAMILY_HOOKS: dict[str, str] = {
    "weightings": "toolkit_weightings",
    "keypoints": "toolkit_keypoint_detectors",
    "descriptors": "toolkit_descriptors",
    "sparse_matchers": "toolkit_sparse_matchers",
    "dense_matchers": "toolkit_dense_matchers",
    "segmenters": "toolkit_segmenters",
}

#: family name -> entry-point group whose names are that family's plugin names
FAMILY_GROUPS: dict[str, str] = {family: f"shape_toolkit.{family}" for family in FAMILY_HOOKS}
