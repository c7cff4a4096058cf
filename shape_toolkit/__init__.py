"""shape-toolkit: spectral analysis of 3D shapes (meshes and point clouds).

The data flow: file -> :class:`Shape` -> :class:`ShapeGraph` -> :class:`Spectrum` -> embeddings,
heat kernels, descriptors, keypoints -> matchers and segmenters -> metrics -> benchmarks.
"""

from shape_toolkit.api.registry import available_plugins, create_plugin, get_plugin, get_registry
from shape_toolkit.core.graph import ShapeGraph
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum, compute_spectrum, laplacian_matrix
from shape_toolkit.errors import (
    DisconnectedGraphError,
    InvalidShapeError,
    MeshRequiredError,
    NumericallyDisconnectedGraphError,
    ParameterError,
    PluginError,
    ShapeFileError,
    SolverError,
    SpectrumMismatchError,
    ToolkitError,
)
from shape_toolkit.spectra import SpectrumSpec, build_graph, default_spec

__version__ = "0.1.0"

__all__ = [
    "Shape",
    "ShapeGraph",
    "Spectrum",
    "SpectrumSpec",
    "default_spec",
    "build_graph",
    "compute_spectrum",
    "laplacian_matrix",
    "get_registry",
    "get_plugin",
    "create_plugin",
    "available_plugins",
    "ToolkitError",
    "ShapeFileError",
    "InvalidShapeError",
    "MeshRequiredError",
    "ParameterError",
    "PluginError",
    "DisconnectedGraphError",
    "NumericallyDisconnectedGraphError",
    "SolverError",
    "SpectrumMismatchError",
    "__version__",
]
