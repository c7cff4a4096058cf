"""The interface of every plugin family, in the scikit-learn estimator style.

``__init__`` only stores keyword parameters (all visible in ``repr`` and :meth:`get_params`),
the work happens in one method, and randomness comes from a ``random_state`` parameter.
A plugin may subclass these bases (recommended) or simply provide the same method.
"""

from __future__ import annotations

import inspect
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol, TypeAlias

import numpy as np
import scipy.sparse as sp

from shape_toolkit.api.params import Param, check_before, validate_params
from shape_toolkit.errors import ParameterError

# This layer names no type of the layers above it, not even for type checkers (no type-only import
# cycle): the data objects below are those of shape_toolkit.core and shape_toolkit.results.
#: a :class:`shape_toolkit.core.shape.Shape`
Shape: TypeAlias = Any
#: a :class:`shape_toolkit.core.spectrum.Spectrum`
Spectrum: TypeAlias = Any
#: a :class:`shape_toolkit.results.correspondence.Correspondence`
Correspondence: TypeAlias = Any
#: a :class:`shape_toolkit.results.segmentation.Segmentation`
Segmentation: TypeAlias = Any


class SpectrumSpec(Protocol):
    """What a plugin declares it needs (a :class:`shape_toolkit.spectra.SpectrumSpec`): what this layer uses of it."""

    k: int

    @property
    def kind(self) -> tuple[Any, ...]:
        """Everything but ``k``: two specs of one kind share their eigenpairs."""

    def compute(self, shape: Shape) -> Spectrum:
        """The spectrum of ``shape`` this spec describes."""

    def check(self, spectrum: Spectrum, shape: Shape, who: str = ...) -> Spectrum:
        """``spectrum`` when it satisfies this spec on ``shape``; else a typed error."""

    def pick(self, spectra: Iterable[Spectrum], shape: Shape, who: str = ...) -> Spectrum:
        """The first of ``spectra`` that satisfies this spec on ``shape``; else a typed error."""


def merge_specs(specs: Iterable[SpectrumSpec | None]) -> list[SpectrumSpec]:
    """One spec per kind (the largest ``k`` of each), in first-seen order; None entries are skipped.
    A caller computes these once and every method picks its own."""
    out: list[SpectrumSpec] = []
    for spec in specs:
        if spec is None:
            continue
        for i, have in enumerate(out):
            if have.kind == spec.kind:
                out[i] = have if have.k >= spec.k else spec
                break
        else:
            out.append(spec)
    return out


class BasePlugin:
    """Parameter handling shared by all plugins, with scikit-learn's semantics: ``get_params``
    (``deep=True`` adds ``name__param`` entries of nested plugins), ``set_params`` (nested too),
    ``repr``; so ``sklearn.base.clone(plugin)`` works. A plugin that needs a spectrum says which
    in :meth:`spectrum_spec`; callers compute it and pass it in."""

    family: ClassVar[str] = ""
    #: named parameter sets, e.g. {"sparse": {...}, "dense": {...}}
    presets: ClassVar[dict[str, dict[str, Any]]] = {}
    #: per constructor parameter: accepted values and a one-line description (:mod:`shape_toolkit.api.params`)
    parameter_constraints: ClassVar[dict[str, Param]] = {}
    #: methods that check the parameters first (the family's work method and ``spectrum_spec``)
    _validated_methods: ClassVar[tuple[str, ...]] = ("spectrum_spec",)

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        check_before(cls, cls._validated_methods)

    def _validate_params(self) -> None:
        """Check the current parameter values against :attr:`parameter_constraints` (raises
        :class:`ParameterError`); done before the family method and ``spectrum_spec`` run."""
        declared = self.parameter_constraints
        validate_params(type(self).__name__, declared, {n: getattr(self, n) for n in declared if hasattr(self, n)})

    @classmethod
    def _param_names(cls) -> list[str]:
        sig = inspect.signature(cls.__init__)
        return [
            p.name
            for p in sig.parameters.values()
            if p.name != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)
        ]

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """The constructor parameters and their current values; with ``deep``, also those of
        nested plugins as ``name__param``."""
        out: dict[str, Any] = {}
        for name in self._param_names():
            value = getattr(self, name)
            out[name] = value
            if deep and hasattr(value, "get_params") and not isinstance(value, type):
                out.update({f"{name}__{k}": v for k, v in value.get_params(deep=True).items()})
        return out

    def set_params(self, **params: Any) -> BasePlugin:
        """Set constructor parameters (``name__param`` for nested plugins); unknown names raise
        :class:`ParameterError`."""
        valid = set(self._param_names())
        nested: dict[str, dict[str, Any]] = {}
        for key, value in params.items():
            head, sep, rest = key.partition("__")
            if head not in valid:
                raise ParameterError(
                    f"{type(self).__name__} has no parameter {head!r}; valid: {sorted(valid)}"
                )
            if sep:
                nested.setdefault(head, {})[rest] = value
            else:
                setattr(self, key, value)
        for head, sub in nested.items():
            inner = getattr(self, head)
            if not hasattr(inner, "set_params"):
                raise ParameterError(f"{type(self).__name__}.{head} is not a plugin; cannot set {sorted(sub)}")
            inner.set_params(**sub)
        return self

    def spectrum_spec(self) -> SpectrumSpec | None:
        """The spectrum this plugin needs (weighting, Laplacian, mass, ``k``), or None."""
        return None

    def spectrum_specs(self) -> list[SpectrumSpec]:
        """Every spectrum this plugin needs: its own and its nested plugins', one per kind."""
        own = self.spectrum_spec()
        specs = ([own] if own is not None else []) + [s for p in self._nested_plugins() for s in p.spectrum_specs()]
        return merge_specs(specs)

    def _nested_plugins(self) -> list[BasePlugin]:
        """Plugins this one calls (e.g. a matcher's descriptor), for :meth:`spectrum_specs`."""
        return [v for v in self.get_params(deep=False).values() if isinstance(v, BasePlugin)]

    def _spectrum(self, shape: Shape, spectrum: Spectrum | Sequence[Spectrum] | None) -> Spectrum:
        """The spectrum of :meth:`spectrum_spec` among ``spectrum`` (one Spectrum, or several of which
        one matches), checked: a typed error when it is too short or of another kind. When None,
        the declared spectrum through the shared content cache (what a caller would pass)."""
        spec = self.spectrum_spec()
        if spec is None:  # pragma: no cover - programming error in a plugin
            raise TypeError(f"{type(self).__name__} declares no spectrum")
        if spectrum is None:
            return spec.compute(shape)
        if isinstance(spectrum, (list, tuple)):
            return spec.pick(spectrum, shape)
        return spec.check(spectrum, shape, who=type(self).__name__)

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params(deep=False).items())
        return f"{type(self).__name__}({args})"


@dataclass
class Weights:
    """What a weighting scheme returns: symmetric weights ``W`` (n, n) CSR, optional lumped mass
    ``mass`` (n,) (area units), and ``info`` (e.g. counts of negative weights)."""

    W: sp.csr_matrix
    mass: np.ndarray | None = None
    info: dict[str, Any] = field(default_factory=dict)


class Weighting(BasePlugin, ABC):
    """Edge-weighting scheme of a shape graph (thesis 3.3.3)."""

    family = "weightings"
    _validated_methods = ("weigh", "spectrum_spec")
    #: True when the scheme ignores the given edges and needs triangles (e.g. cotangent)
    needs_faces: ClassVar[bool] = False
    #: the weighting (registry name) a spectrum declared with this one uses on a point cloud, if it needs faces
    point_cloud_weighting: ClassVar[str | None] = None
    #: what to do when its Laplacian is numerically disconnected (empty: the general advice)
    disconnection_hint: ClassVar[str] = ""

    @abstractmethod
    def weigh(self, shape: Shape, edges: np.ndarray) -> Weights:
        """Weights for the undirected ``(e, 2)`` int64 ``edges`` of ``shape``."""


class KeypointDetector(BasePlugin, ABC):
    """Detects sparse, repeatable vertices."""

    family = "keypoints"
    _validated_methods = ("detect", "spectrum_spec")

    @abstractmethod
    def detect(self, shape: Shape, *, spectrum: Spectrum | None = None) -> np.ndarray:
        """0-based int64 vertex ids ``(p,)`` of the keypoints, in a deterministic order."""


class Descriptor(BasePlugin, ABC):
    """Per-vertex feature vectors."""

    family = "descriptors"
    #: whether :meth:`compute` reads its ``keypoints`` (False: they are ignored, and the CLI refuses them)
    uses_keypoints = False
    _validated_methods = ("compute", "spectrum_spec")

    @abstractmethod
    def compute(
        self,
        shape: Shape,
        *,
        spectrum: Spectrum | None = None,
        keypoints: np.ndarray | None = None,
    ) -> np.ndarray:
        """A float64 ``(n, d)`` descriptor matrix, one row per vertex."""

    def output_width(self, n_keypoints: int | None = None) -> int | None:
        """``d``, the columns :meth:`compute` will return given ``n_keypoints`` keypoints (None: none given), when
        known before computing (the memory estimate of ``shape-toolkit describe``); None: not known."""
        return None


class SparseMatcher(BasePlugin, ABC):
    """One-to-one matching of the keypoints of two shapes."""

    family = "sparse_matchers"
    _validated_methods = ("match", "spectrum_spec")

    @abstractmethod
    def match(
        self,
        source: Shape,
        target: Shape,
        source_keypoints: np.ndarray,
        target_keypoints: np.ndarray,
        *,
        source_spectrum: Spectrum | None = None,
        target_spectrum: Spectrum | None = None,
    ) -> np.ndarray:
        """Matched vertex pairs as an int64 ``(q, 2)`` array ``[source_vertex, target_vertex]``."""


class DenseMatcher(BasePlugin, ABC):
    """A correspondence for every source vertex.

    Every dense matcher accepts every argument of :meth:`match` and ignores those it does not use (a
    pipeline passes them all; they are declared here, not discovered)."""

    family = "dense_matchers"
    _validated_methods = ("match", "spectrum_spec")
    #: True when the map depends on the shapes' coordinates and so on their frames (an extrinsic alignment),
    #: not only on their intrinsic geometry: ``best-of`` then also runs it in a frame it estimates
    extrinsic: bool = False

    @abstractmethod
    def match(
        self,
        source: Shape,
        target: Shape,
        *,
        seeds: np.ndarray | None = None,
        source_spectrum: Spectrum | None = None,
        target_spectrum: Spectrum | None = None,
        source_descriptors: np.ndarray | None = None,
        target_descriptors: np.ndarray | None = None,
        n_times: int | None = None,
        progress: Callable[[str], None] | None = None,
    ) -> Correspondence:
        """The dense map. Optional: ``seeds`` int64 ``(q, 2)`` known matches; ``source_descriptors``,
        ``target_descriptors`` float64 ``(n, d)`` and ``(n', d)`` per-vertex descriptors (a pipeline's
        [descriptors] stage, computed with the seeds as matched keypoints: keypoint-major, ``n_times`` values
        per keypoint); ``progress(message)`` hears the matcher's iterations."""


class Segmenter(BasePlugin, ABC):
    """Assigns one label per vertex (and per face, on a mesh): a
    :class:`~shape_toolkit.results.segmentation.Segmentation`.

    ``takes_constraints``: whether :meth:`segment` uses must-link / cannot-link ``constraints``
    (semi-supervised methods set it True). One that does not refuses them with
    :class:`ParameterError` (:meth:`check_constraints`) instead of ignoring them silently."""

    family = "segmenters"
    _validated_methods = ("segment", "spectrum_spec")
    #: whether :meth:`segment` uses its ``constraints``; False: they are refused
    takes_constraints: ClassVar[bool] = False
    #: whether :meth:`segment` needs ``n_segments`` (the method cannot choose the number of segments)
    requires_n_segments: ClassVar[bool] = False

    def lacks_n_segments(self) -> bool:
        """Whether this segmenter needs ``n_segments`` and has none, so that :meth:`segment` would refuse any
        shape (the command line says so before reading the file); a wrapper answers for the segmenter it wraps."""
        return bool(self.requires_n_segments) and getattr(self, "n_segments", None) is None

    def accepts_constraints(self) -> bool:
        """Whether this segmenter uses ``constraints`` (default: the class's ``takes_constraints``;
        a wrapper answers for the segmenter it wraps)."""
        return bool(self.takes_constraints)

    def check_constraints(self, constraints: Any | None) -> None:
        """Raise :class:`ParameterError` when ``constraints`` are given (not None) to a segmenter that
        does not use them (:func:`shape_toolkit.api.registry.plugins_taking_constraints` lists those that do)."""
        if constraints is None or self.accepts_constraints():
            return
        raise ParameterError(
            f"{type(self).__name__} takes no constraints (it is unsupervised) and would ignore them; drop them "
            "or use a semi-supervised segmenter (takes_constraints = True, e.g. csc)"
        )

    @abstractmethod
    def segment(
        self,
        shape: Shape,
        *,
        spectrum: Spectrum | None = None,
        constraints: Any | None = None,
    ) -> Segmentation:
        """The segmentation: int64 vertex labels ``(n,)`` in ``0..k-1``, int64 face labels ``(m,)`` on a
        mesh (None on a point cloud), and ``info`` (e.g. the constraints kept)."""


#: family name -> (base class, name of the method a plugin must provide)
FAMILY_INTERFACES: dict[str, tuple[type, str]] = {
    "weightings": (Weighting, "weigh"),
    "keypoints": (KeypointDetector, "detect"),
    "descriptors": (Descriptor, "compute"),
    "sparse_matchers": (SparseMatcher, "match"),
    "dense_matchers": (DenseMatcher, "match"),
    "segmenters": (Segmenter, "segment"),
}
