"""One exception hierarchy for the whole shape_toolkit.

Every user mistake (bad file, bad parameter, unknown plugin) raises a subclass of
:class:`ToolkitError`; the CLI turns it into one line on stderr and a non-zero exit code.
"""

from __future__ import annotations


class ToolkitError(Exception):
    """Base class of every error the toolkit raises on purpose."""

    exit_code = 2


class ShapeFileError(ToolkitError):
    """A shape file is missing, unreadable, of unknown format, or malformed."""

    def __init__(self, path: object, problem: str):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class InvalidShapeError(ToolkitError):
    """Arrays do not describe a valid shape (empty, NaN/inf, bad faces, ...)."""


class ParameterError(ToolkitError, ValueError):
    """A parameter value is out of range or of the wrong kind."""


class PluginError(ToolkitError):
    """A plugin is unknown, broken, or does not implement its family's interface."""


class DisconnectedGraphError(ToolkitError):
    """A graph has several connected components where one is required."""

    def __init__(self, n_components: int, sizes: list[int]):
        self.n_components = n_components
        self.sizes = sizes
        shown = ", ".join(str(s) for s in sizes[:8]) + (", ..." if len(sizes) > 8 else "")
        super().__init__(
            f"the shape graph has {n_components} connected components (sizes {shown}); "
            "a spectrum of a disconnected graph mixes its components: clean the shape "
            "(keep_largest_component), or ask for components='largest' or a per-component analysis"
        )


class SolverError(ToolkitError):
    """A numerical solver failed to converge or met a singular system."""


class SpectrumMismatchError(ParameterError):
    """A spectrum handed to a method is too short or of another kind than the one it declares."""
