"""Several dense matchers on one pair, the most plausible map kept: the one of least ZoomOut residual
(:func:`~shape_toolkit.features.basis.zoomout_residual`) in a common basis of both
shapes. The ``auto`` pipeline runs ``fmap-zoomout`` (intrinsic: robust to pose, fragile under non-isometry
and merged contacts) and ``shell-alignment`` (extrinsic and spectral: robust to non-isometry and merges,
fragile under a change of pose) and keeps what the pair calls for.

Why the residual: the point map of a sound correspondence is, to a good approximation, the point map of a
smooth functional map in the first eigenfunctions (it is what ZoomOut converges to); a part sent to the wrong
place, or a map that folds a limb, leaves energy that no ``k x k`` functional map explains. On the tuning half
of the former ``benchmarks/matching_field.py``'s split (FAUST people 0-1, dogs, gorillas to men; clean and with 6 glued
contacts; 48 pairs) it kept the better of the two maps, or one within 0.005 of it, on 44; it missed on two
glued FAUST pairs (0.156 kept against 0.039, 0.486 against 0.109) and by 0.012-0.015 on two clean ones.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from shape_toolkit.api.interfaces import DenseMatcher
from shape_toolkit.api.params import InstanceOf, Interval, ListOf, Param
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.errors import InvalidShapeError, ParameterError
from shape_toolkit.features.basis import basis_of, fmap_from_p2p, zoomout_residual
from shape_toolkit.plugins.matching.descriptors import resolve_plugin, shared_spectra
from shape_toolkit.plugins.matching.validation import check_seeds
from shape_toolkit.results.correspondence import Correspondence
from shape_toolkit.spectra import SpectrumSpec, default_spec

__all__ = ["BestOfMatcher"]


def _matcher(spec: Any) -> Any:
    """A dense matcher from an instance, a registry name or a table ``{plugin, preset, params}``."""
    if isinstance(spec, str) and spec == "best-of":
        raise ParameterError("best-of cannot nest itself")
    return resolve_plugin("dense_matchers", spec, None, method="match", what="matcher", kind="dense matcher")


class BestOfMatcher(DenseMatcher):
    """Runs every matcher of ``matchers`` (names, ``{plugin, preset, params}`` tables or instances) and keeps
    the map of least ZoomOut residual in the first ``k`` Laplace-Beltrami eigenfunctions of both shapes.
    ``info["candidates"]`` lists each matcher's residual, ``info["chosen"]`` the one kept; the rest of
    ``info`` is the chosen matcher's. Seeds go to every matcher. A matcher that cannot take the pair (a point
    cloud for a matcher that needs faces: :class:`~shape_toolkit.errors.InvalidShapeError`) is left out and
    named in ``info["skipped"]``; when none can, the first one's error is raised."""

    presets: dict = {}
    parameter_constraints = {
        "matchers": Param(ListOf(InstanceOf(str, dict, DenseMatcher, name="dense matcher")),
                          doc="dense matchers to run (names, tables or objects)"),
        "k": Param(Interval(int, 2), doc="Laplace-Beltrami eigenfunctions of the ZoomOut residual"),
    }

    def __init__(self, matchers: tuple | list = ("fmap-zoomout", "shell-alignment"), k: int = 64):
        self.matchers = matchers
        self.k = k

    def _matchers(self) -> list:
        return [_matcher(m) for m in self.matchers]

    def _names(self) -> list[str]:
        return [m if isinstance(m, str) else str(m["plugin"]) if isinstance(m, dict) else type(m).__name__
                for m in self.matchers]

    def _nested_plugins(self) -> list:
        return self._matchers()

    def spectrum_spec(self) -> SpectrumSpec:
        """The Laplace-Beltrami spectrum with ``k + 1`` eigenpairs (the common basis of the residual)."""
        return default_spec(int(self.k) + 1)

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
        """The map of least residual among the matchers' maps source -> target."""
        matchers = self._matchers()
        seeds = check_seeds(seeds, source.n_vertices, target.n_vertices)
        spec_s, spec_t = self._spectrum(source, source_spectrum), self._spectrum(target, target_spectrum)
        k = int(min(self.k, spec_s.k, spec_t.k))
        bs, bt = basis_of(spec_s, k), basis_of(spec_t, k)
        # each matcher picks its own spectra among these
        share_s, share_t = shared_spectra(source_spectrum), shared_spectra(target_spectrum)
        best, candidates, skipped, first_error = None, [], [], None
        for name, m in zip(self._names(), matchers):
            try:
                corr = m.match(source, target, seeds=seeds, source_spectrum=share_s, target_spectrum=share_t)
            except InvalidShapeError as exc:  # e.g. a cloud for a matcher that needs a mesh
                skipped.append({"matcher": name, "reason": str(exc)})
                first_error = first_error or exc
                continue
            t = np.asarray(corr.target_of)
            if np.all(t >= 0):
                residual = zoomout_residual(fmap_from_p2p(bs, bt, t, k, k), bs, bt, t)
            else:  # a partial map is judged on its matched vertices
                ok = np.flatnonzero(t >= 0)
                C = fmap_from_p2p(bs, bt, t[ok], k, k, rows=ok) if len(ok) else None
                residual = float("inf") if C is None else zoomout_residual(C, bs, bt, t, rows=ok)
            candidates.append({"matcher": name, "residual": residual})
            if progress is not None:
                progress(f"best-of: {name} residual {residual:.4g}")
            if best is None or residual < best[0]:
                best = (residual, name, corr)
        if best is None:
            raise first_error
        info = dict(best[2].info)
        info.update({"candidates": candidates, "chosen": best[1], "skipped": skipped})
        return Correspondence(best[2].target_of, target.n_vertices, best[2].confidence, best[2].posteriors, info)
