"""Spectra named by plugin names: the one place that turns a weighting's name into the weighting object.

:mod:`shape_toolkit.core` takes objects (``core.graph.build_graph(shape, CotangentWeighting())``) and knows no
plugin name. This module resolves names through the registry and serves what callers and plugins declare:

- :func:`build_graph` (a weighting by name, or an object), :func:`point_cloud_weighting`;
- :class:`SpectrumSpec` (what a method needs, as data), :func:`default_spec`, :func:`shape_spectrum`,
  :func:`merge_specs`;
- :func:`compute_declared`: the spectra some plugins declare, computed once per shape (the CLI, the pipeline
  and the benchmarks all go through it), with the one rule for how many eigenpairs a shape has
  (:func:`spectrum_k`).

It sits right below ``plugins/`` in the layer map (plugins declare their spectra with :func:`default_spec` and
compute them when called without one) and imports no plugin module: names are looked up in the registry.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from shape_toolkit.api.interfaces import merge_specs as _merge_by_kind
from shape_toolkit.api.registry import create_plugin, get_plugin
from shape_toolkit.core import graph as _graph
from shape_toolkit.core.graph import ShapeGraph
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import LAPLACIANS, Spectrum, compute_spectrum, is_cached
from shape_toolkit.errors import DisconnectedGraphError, ParameterError, PluginError, SpectrumMismatchError

__all__ = [
    "build_graph",
    "weighting_object",
    "point_cloud_weighting",
    "spectrum_k",
    "SpectrumSpec",
    "default_spec",
    "shape_spectrum",
    "merge_specs",
    "declared_specs",
    "compute_declared",
]


def weighting_object(weighting: Any, **params: Any) -> tuple[Any, str]:
    """``(weighting object, its name)``: a registry name made into its plugin with ``params``, or an
    object (with ``weigh()``) used as it is, named by its class."""
    if isinstance(weighting, str):
        return create_plugin("weightings", weighting, **params), weighting
    if callable(getattr(weighting, "weigh", None)) and not isinstance(weighting, type):
        if params:
            raise ParameterError(f"give the parameters {sorted(params)} to the weighting object itself")
        return weighting, type(weighting).__name__
    # a dict or list from a JSON parameter (--param weighting={...})
    shown = repr(weighting) if len(repr(weighting)) <= 60 else repr(weighting)[:57] + "..."
    raise ParameterError(
        f"weighting must be the name of a weighting plugin, got {type(weighting).__name__} {shown} "
        "(or pass a weighting object)"
    )


def build_graph(
    shape: Shape,
    weighting: Any = "gaussian",
    *,
    connectivity: str = "auto",
    n_neighbors: int | None = None,
    radius: float | None = None,
    memory_limit: float | None = None,
    **params: Any,
) -> ShapeGraph:
    """The shape graph of ``shape`` with a weighting plugin named ``weighting`` (made with ``params``) or a
    weighting object; the arguments of :func:`shape_toolkit.core.graph.build_graph` (``memory_limit``: bytes a kNN
    or epsilon graph may need, None: this machine's memory)."""
    scheme, name = weighting_object(weighting, **params)
    return _graph.build_graph(
        shape, scheme, name=name, connectivity=connectivity, n_neighbors=n_neighbors, radius=radius,
        memory_limit=memory_limit,
    )


def point_cloud_weighting(weighting: str) -> str:
    """The weighting a spectrum declared with ``weighting`` uses on a point cloud: its plugin's
    ``point_cloud_weighting`` when it needs faces (cotangent: intrinsic Delaunay), else itself."""
    try:
        cls = get_plugin("weightings", weighting)
    except PluginError:  # not a registered name: nothing to swap (the graph will say what is wrong)
        return weighting
    return getattr(cls, "point_cloud_weighting", None) or weighting


def spectrum_k(k: int, graph: ShapeGraph, components: str = "raise") -> int:
    """How many eigenpairs a spectrum asking for ``k`` gets on ``graph``: at most one per analysed vertex
    (the eigensolver returns all ``n`` of an ``n``-vertex graph, by dense LAPACK once ``3 k >= n``), i.e. the
    vertex count, or the largest component's size with ``components='largest'``."""
    n = graph.n_vertices
    if components == "largest":
        count, labels = graph.components
        if count > 1:
            n = int(np.bincount(labels).max())
    return int(min(int(k), n))


@dataclass(frozen=True)
class SpectrumSpec:
    """The spectrum a method needs, as data: a weighting plugin and its parameters, a Laplacian,
    the mass matrix or not, and ``k`` eigenpairs (capped at the vertex count).

    Methods declare one through ``spectrum_spec()``; callers compute it once with
    :meth:`compute` (through the content cache) and pass it in; methods check what they are
    given with :meth:`check`. ``use_mass=None`` means: whenever the weighting has a mass and the
    Laplacian is combinatorial.
    """

    k: int
    weighting: str = "cotangent"
    laplacian: str = "combinatorial"
    use_mass: bool | None = None
    weighting_params: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self) -> None:
        if isinstance(self.k, bool) or not isinstance(self.k, (int, np.integer)) or self.k < 1:
            raise ParameterError(f"a spectrum spec needs k >= 1 eigenpairs, got {self.k!r}")
        if self.laplacian not in LAPLACIANS:
            raise ParameterError(f"unknown Laplacian {self.laplacian!r}; choose one of {', '.join(LAPLACIANS)}")
        if isinstance(self.weighting_params, dict):
            object.__setattr__(self, "weighting_params", tuple(sorted(self.weighting_params.items())))

    def for_shape(self, shape: Shape) -> SpectrumSpec:
        """This spec as it applies to ``shape``: ``k`` capped at the vertex count, and a mesh-only
        weighting (cotangent) replaced by its point-cloud counterpart (intrinsic Delaunay)."""
        weighting = self.weighting if shape.is_mesh else point_cloud_weighting(self.weighting)
        k = int(min(self.k, shape.n_vertices))
        if weighting == self.weighting and k == self.k:
            return self
        return SpectrumSpec(k, weighting, self.laplacian, self.use_mass, self.weighting_params)

    def merge(self, other: SpectrumSpec) -> SpectrumSpec | None:
        """One spec serving both ``self`` and ``other`` (the larger ``k``), or None if their kinds differ."""
        if self.kind != other.kind:
            return None
        return self if self.k >= other.k else other

    @classmethod
    def merge_all(cls, specs: Iterable[SpectrumSpec | None]) -> list[SpectrumSpec]:
        """One spec per kind (the largest ``k`` of each), in first-seen order; None entries skipped."""
        return merge_specs(specs)

    @property
    def kind(self) -> tuple[Any, ...]:
        """Everything but ``k``: two specs of one kind share their eigenpairs."""
        return (self.weighting, self.weighting_params, self.laplacian, self.use_mass)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready description (what a benchmark row records)."""
        out: dict[str, Any] = {"weighting": self.weighting, "laplacian": self.laplacian, "k": int(self.k)}
        if self.use_mass is not None:
            out["use_mass"] = bool(self.use_mass)
        if self.weighting_params:
            out["params"] = dict(self.weighting_params)
        return out

    def compute(self, shape: Shape, *, components: str = "raise", solver: Any = None, cache: bool = True) -> Spectrum:
        """The spectrum of ``shape`` that this spec describes, through the content cache (``cache=False``:
        solved afresh, e.g. to time the solver); ``k`` capped by :func:`spectrum_k` (with
        ``components='largest'``, at the largest component's size); ``solver``: another eigensolver than
        the default (see :func:`~shape_toolkit.core.spectrum.compute_spectrum`)."""
        try:
            graph, kwargs = self._request(shape, components)
            return compute_spectrum(graph, **kwargs, solver=solver, cache=cache)
        except DisconnectedGraphError as exc:  # named: of two shapes matched, the user learns which one it is
            if type(exc) is not DisconnectedGraphError or exc.shape:
                raise
            named = f"{shape.name!r} ({shape.n_vertices} vertices)"
            raise DisconnectedGraphError(exc.n_components, exc.sizes, named, exc.coincident) from None

    def is_cached(self, shape: Shape, *, components: str = "raise", solver: Any = None) -> bool:
        """Whether :meth:`compute` with these arguments would be served from the cache."""
        graph, kwargs = self._request(shape, components)
        return is_cached(graph, **kwargs, solver=solver)

    def _request(self, shape: Shape, components: str) -> tuple[ShapeGraph, dict[str, Any]]:
        """The graph and the :func:`compute_spectrum` arguments of this spec on ``shape``."""
        spec = self.for_shape(shape)
        graph = build_graph(shape, spec.weighting, **dict(spec.weighting_params))
        k = spectrum_k(spec.k, graph, components)
        return graph, {"k": k, "laplacian": spec.laplacian, "use_mass": spec.use_mass, "components": components}

    def check(self, spectrum: Spectrum, shape: Shape, who: str = "this method") -> Spectrum:
        """``spectrum`` if it is of this spec's kind for ``shape`` with at least ``k`` eigenpairs;
        else :class:`~shape_toolkit.errors.SpectrumMismatchError` saying what was expected."""
        spec = self.for_shape(shape)
        if not isinstance(spectrum, Spectrum):
            raise SpectrumMismatchError(f"{who} needs a Spectrum, got {type(spectrum).__name__}")
        problems = []
        if spectrum.n_vertices != shape.n_vertices:
            problems.append(f"{spectrum.n_vertices} rows for {shape.n_vertices} vertices")
        if spectrum.k < spec.k:
            problems.append(f"{spectrum.k} eigenpairs, fewer than {spec.k}")
        if spectrum.weighting != spec.weighting:
            problems.append(f"weighting {spectrum.weighting!r}")
        if spectrum.laplacian != spec.laplacian:
            problems.append(f"Laplacian {spectrum.laplacian!r}")
        if spec.use_mass is not None and spectrum.generalized != spec.use_mass:
            problems.append("the mass matrix" if spectrum.generalized else "no mass matrix")
        given_params = spectrum.meta.get("weighting_params")
        if spec.weighting_params and given_params is not None and dict(spec.weighting_params) != {
            k: given_params.get(k) for k, _ in spec.weighting_params
        }:
            problems.append(f"weighting parameters {given_params}")
        if problems:
            raise SpectrumMismatchError(
                f"{who} needs the spectrum {spec.to_dict()}, but was given one with {', '.join(problems)}"
            )
        return spectrum

    def pick(self, spectra: Iterable[Spectrum], shape: Shape, who: str = "this method") -> Spectrum:
        """The first of ``spectra`` that satisfies this spec on ``shape``; a typed error when none does."""
        candidates = list(spectra)
        for s in candidates:
            try:
                return self.check(s, shape, who)
            except SpectrumMismatchError:
                continue
        given = ", ".join(repr(s) for s in candidates) or "none"
        raise SpectrumMismatchError(
            f"{who} needs the spectrum {self.for_shape(shape).to_dict()}; none given matches (given: {given})"
        )


def shape_spectrum(shape: Shape, k: int, *, kind: str = "lbo", **spec: Any) -> Spectrum:
    """The toolkit's default spectrum of ``shape``, ``k`` eigenpairs (the one place that says what
    "default" means): ``kind='lbo'`` is the Laplace-Beltrami operator (cotangent weights with
    Voronoi mass, intrinsic Delaunay on point clouds); ``kind='graph'`` the combinatorial
    Laplacian of the Gaussian-weighted graph (thesis ch. 2-3; with another ``weighting``, its mass
    matrix too when it has one). Extra keywords override the spec."""
    return default_spec(k, kind, **spec).compute(shape)


def default_spec(k: int, kind: str = "lbo", **overrides: Any) -> SpectrumSpec:
    """The :class:`SpectrumSpec` behind :func:`shape_spectrum`."""
    if kind == "lbo":
        base: dict[str, Any] = {"weighting": "cotangent", "laplacian": "combinatorial", "use_mass": True}
    elif kind == "graph":  # the weighting's own operator: a mass only where the weighting has one
        base = {"weighting": "gaussian", "laplacian": "combinatorial", "use_mass": None}
    else:
        raise ParameterError(f"unknown spectrum kind {kind!r}; choose 'lbo' or 'graph'")
    base.update(overrides)
    return SpectrumSpec(int(k), **base)


def merge_specs(specs: Iterable[SpectrumSpec | None]) -> list[SpectrumSpec]:
    """One spec per kind (the largest ``k`` of each), in first-seen order; None entries are skipped.
    A caller computes these once and every method picks its own with :meth:`SpectrumSpec.pick`."""
    return list(_merge_by_kind(specs))



def _specs_of(obj: Any) -> list[SpectrumSpec]:
    """The specs ``obj`` declares: a spec, a plugin or pipeline (``spectrum_specs()``, else ``spectrum_spec()``),
    None (none), or an iterable of these."""
    if obj is None:
        return []
    if isinstance(obj, SpectrumSpec):
        return [obj]
    if hasattr(obj, "spectrum_specs"):
        return list(obj.spectrum_specs() or [])
    if hasattr(obj, "spectrum_spec"):
        return [s for s in [obj.spectrum_spec()] if s is not None]
    if isinstance(obj, Iterable) and not isinstance(obj, (str, bytes, dict)):
        return [s for item in obj for s in _specs_of(item)]
    return []


def declared_specs(plugins: Any) -> list[SpectrumSpec]:
    """Every spectrum ``plugins`` declare (a plugin, a pipeline, a spec, or an iterable of these), one per
    kind with the largest ``k`` (:func:`merge_specs`)."""
    return merge_specs(_specs_of(plugins))


def compute_declared(
    shapes: Shape | Sequence[Shape],
    plugins: Any,
    *,
    components: str = "raise",
    errors: list[str] | None = None,
) -> list[Spectrum] | list[list[Spectrum]]:
    """The spectra ``plugins`` declare (:func:`declared_specs`), computed once per shape through the content
    cache, to pass in as ``spectrum=`` (each plugin picks its own): a list for one shape, one list per shape
    for several. ``errors``: when a list is given, a spectrum that cannot be computed is left out and
    described there (``"{spec}: {error type}: {message}"``) instead of raising."""
    specs = declared_specs(plugins)
    single = isinstance(shapes, Shape)
    out: list[list[Spectrum]] = []
    for shape in [shapes] if single else list(shapes):
        spectra = []
        for spec in specs:
            try:
                spectra.append(spec.compute(shape, components=components))
            except Exception as exc:
                if errors is None:
                    raise
                errors.append(f"{spec.to_dict()}: {type(exc).__name__}: {exc}")
        out.append(spectra)
    return out[0] if single else out
