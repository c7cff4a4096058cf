"""shape-toolkit: spectral analysis of 3D shapes (meshes and point clouds).

The data flow: file -> :class:`Shape` -> :class:`ShapeGraph` -> :class:`Spectrum` -> embeddings,
heat kernels, descriptors, keypoints -> matchers and segmenters -> metrics -> benchmarks.
"""

from .errors import (
    DisconnectedGraphError,
    InvalidShapeError,
    ParameterError,
    PluginError,
    ShapeFileError,
    SolverError,
    ToolkitError,
)
from .graph import ShapeGraph, build_graph
from .hookspecs import hookimpl
from .registry import available_plugins, create_plugin, get_plugin, get_registry
from .shape import Shape
from .spectrum import Spectrum, compute_spectrum, laplacian_matrix

__version__ = "0.1.0"

__all__ = [
    "Shape",
    "ShapeGraph",
    "Spectrum",
    "build_graph",
    "compute_spectrum",
    "laplacian_matrix",
    "hookimpl",
    "get_registry",
    "get_plugin",
    "create_plugin",
    "available_plugins",
    "ToolkitError",
    "ShapeFileError",
    "InvalidShapeError",
    "ParameterError",
    "PluginError",
    "DisconnectedGraphError",
    "SolverError",
    "__version__",
]
