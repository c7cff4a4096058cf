"""The descriptor plugins a matcher computes: resolution from a name, table or instance, the same times
on both shapes, column normalization, and the spectra handed to a nested plugin."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.errors import ParameterError

__all__ = [
    "resolve_plugin", "descriptor_plugin", "UsesDescriptor", "paired_descriptors", "normalize_columns",
    "shared_spectra",
]


def resolve_plugin(family: str, spec: Any, params: dict | None, *, method: str, what: str, kind: str) -> Any:
    """The plugin of ``family`` a parameter names: an instance (anything with ``method``, used as is), a
    registry name with ``params``, or a table ``{plugin, preset, params}`` (as written in TOML configs).
    ``what`` names the parameter and ``kind`` the instance type in the errors."""
    from shape_toolkit.api.registry import create_plugin

    if params is not None and not isinstance(params, dict):
        raise ParameterError(f"{what}_params must be a table of {what} parameters, got {params!r}")
    if hasattr(spec, method) and not isinstance(spec, (str, dict, type)):
        if params:
            raise ParameterError(f"{what}_params apply to a {what} given by name, not to an instance")
        return spec
    if isinstance(spec, dict):
        bad = sorted(set(spec) - {"plugin", "preset", "params"})
        if bad or "plugin" not in spec:
            raise ParameterError(
                f"a {what} table needs 'plugin' (and optional preset, params); got {sorted(spec)}"
            )
        return create_plugin(family, str(spec["plugin"]), spec.get("preset"),
                             **{**(spec.get("params") or {}), **(params or {})})
    if isinstance(spec, str):
        return create_plugin(family, spec, **(params or {}))
    raise ParameterError(f"{what} must be a plugin name, a table or a {kind}, got {spec!r}")


def descriptor_plugin(descriptor: Any, params: dict | None = None) -> Any:
    """The descriptor plugin a matcher names (:func:`resolve_plugin`: an instance, a registry name with
    ``params``, or a table ``{plugin, preset, params}``)."""
    return resolve_plugin("descriptors", descriptor, params, method="compute", what="descriptor", kind="Descriptor")


class UsesDescriptor:
    """Mixin of the dense matchers that compute a descriptor plugin (``descriptor`` and
    ``descriptor_params`` parameters): the plugin instance, and its spectra in ``spectrum_specs()``."""

    def _descriptor_plugin(self) -> Any:
        return descriptor_plugin(self.descriptor, self.descriptor_params)

    def _nested_plugins(self) -> list:
        return [self._descriptor_plugin()]


def paired_descriptors(
    plugin: Any, source: Shape, target: Shape, kp_source: np.ndarray, kp_target: np.ndarray, *,
    source_spectrum: Spectrum | Sequence[Spectrum] | None = None,
    target_spectrum: Spectrum | Sequence[Spectrum] | None = None,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Keypoint descriptors ``(n, M * tau)`` of both shapes on matched keypoints, and ``tau``.

    Multi-scale heat descriptors must use the *same* times on both shapes to be comparable
    (thesis 7.3.1): when the plugin has a ``times`` parameter left to None, the times it would use
    on the source (its ``descriptor_times``, the scree rule on its own spectrum) are set on a copy
    and reused on the target."""
    import copy

    if getattr(plugin, "times", "absent") is None and hasattr(plugin, "descriptor_times"):
        times = plugin.descriptor_times(source, spectrum=source_spectrum)
        plugin = copy.deepcopy(plugin)
        plugin.set_params(times=[float(t) for t in times])
    ds = plugin.compute(source, spectrum=source_spectrum, keypoints=kp_source)
    dt = plugin.compute(target, spectrum=target_spectrum, keypoints=kp_target)
    times = getattr(plugin, "times", None)
    n_times = len(times) if times is not None else int(getattr(plugin, "n_times", 1))
    return ds, dt, n_times


def normalize_columns(desc: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """Descriptor columns divided by their ``mass``-weighted L2 norm (constant columns kept)."""
    norms = np.sqrt((mass[:, None] * desc**2).sum(axis=0))
    norms[norms <= 1e-300] = 1.0
    return desc / norms


def shared_spectra(given: Spectrum | Sequence[Spectrum] | None) -> list[Spectrum] | None:
    """What to hand a nested plugin: the caller's spectra as a list (it picks its own among them), or,
    when the caller gave none, None (it computes its declared spectrum through the cache)."""
    return None if given is None else (list(given) if isinstance(given, (list, tuple)) else [given])
