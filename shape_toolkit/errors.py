"""One exception hierarchy for the whole shape_toolkit.

Every user mistake (bad file, bad parameter, unknown plugin) raises a subclass of
:class:`ToolkitError`; the CLI turns it into one line on stderr and a non-zero exit code.
"""

from __future__ import annotations


class ToolkitError(Exception):
    """Base class of every error the toolkit raises on purpose."""

    exit_code = 2


def printable(text: object) -> str:
    """``text`` for a one-line message: as is when printable, else with its control characters (a
    newline in a file name, say) escaped, so an error stays one line."""
    t = str(text)
    if t.isprintable():
        return t
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in t)


class ShapeFileError(ToolkitError):
    """A shape file is missing, unreadable, of unknown format, or malformed."""

    def __init__(self, path: object, problem: str):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{printable(self.path)}: {problem}")

    def __reduce__(self):  # picklable with its two arguments
        return (type(self), (self.path, self.problem))


class InvalidShapeError(ToolkitError):
    """Arrays do not describe a valid shape (empty, NaN/inf, bad faces, ...)."""


class MeshRequiredError(InvalidShapeError):
    """A step that needs triangles was given a point cloud (:meth:`~shape_toolkit.core.shape.Shape.require_faces`)."""


class ParameterError(ToolkitError, ValueError):
    """A parameter value is out of range or of the wrong kind."""


class PluginError(ToolkitError):
    """A plugin is unknown, broken, or does not implement its family's interface."""


#: what to do with a graph of several components (named by every disconnection error)
COMPONENT_OPTIONS = (
    "compute_spectrum(..., components='largest') analyses the largest component only; "
    "component_spectra(graph, k) gives one spectrum per component; "
    "Shape cleanup (keep_largest_component) removes the small pieces, as does "
    "'shape-toolkit clean --keep-largest FILE' from the command line"
)


class DisconnectedGraphError(ToolkitError):
    """A graph has several connected components where one is required; the message names the sizes
    and every option (largest component, per-component spectra, cleanup); ``shape`` names the shape when known."""

    shape: str | None = None

    def __init__(self, n_components: int, sizes: list[int], shape: str | None = None, coincident: int = 0):
        self.n_components = int(n_components)
        self.sizes = [int(s) for s in sizes]
        self.shape = shape
        self.coincident = int(coincident)
        shown = ", ".join(str(s) for s in self.sizes[:8]) + (", ..." if len(self.sizes) > 8 else "")
        of = f" of {shape}" if shape else ""
        welded = (f"{self.coincident} vertices lie on another vertex (an unwelded mesh, as a triangle soup): "
                  "'shape-toolkit clean FILE' (clean_shape) merges them, which may join the pieces; other options: "
                  if self.coincident else "Options: ")
        super().__init__(
            f"the shape graph{of} has {self.n_components} connected components (sizes {shown}); a spectrum "
            f"of a disconnected graph mixes its components. {welded}{COMPONENT_OPTIONS}"
        )

    def __reduce__(self):  # picklable (Dask workers send errors back)
        return (type(self), (self.n_components, self.sizes, self.shape, self.coincident))


class NumericallyDisconnectedGraphError(DisconnectedGraphError):
    """A graph that is connected (or has ``n_components`` components) structurally, but whose
    Laplacian has more eigenvalues that are zero to solver precision than it has components: some
    cut of its edges weighs (next to) nothing, so its spectrum would mix unrelated pieces and every
    eigenpair count downstream would be off."""

    def __init__(self, message: str, n_null: int = 0, n_components: int = 1, sizes: list[int] | None = None):
        self.n_null = int(n_null)
        self.n_components = int(n_components)
        self.sizes = list(sizes) if sizes is not None else []
        ToolkitError.__init__(self, message)

    def __reduce__(self):
        return (type(self), (str(self), self.n_null, self.n_components, self.sizes))


class SolverError(ToolkitError):
    """A numerical solver failed to converge or met a singular system."""


class SpectrumMismatchError(ParameterError):
    """A spectrum handed to a method is too short or of another kind than the one it declares."""


class TimeLimitError(ToolkitError):
    """A computation stopped because it ran, or would clearly run, past the time limit its caller
    set; the message says how far it got and the estimated total."""
