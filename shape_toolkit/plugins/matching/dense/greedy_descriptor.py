"""Greedy descriptor matching (Ovsjanikov et al. 2010, the second baseline of thesis 7.5):
every source vertex goes to the target vertex with the nearest descriptor, with no
neighbourhood consistency. Default descriptors are the heat-kernel maps of the seed points
(``heat-diffusion``, eq. 6.61-6.63), i.e. the one-or-few-point heat kernel matching of the paper.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from shape_toolkit.api.interfaces import DenseMatcher
from shape_toolkit.api.params import Param
from shape_toolkit.core.geometry import nearest_neighbors
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.errors import ParameterError
from shape_toolkit.plugins._params import DESCRIPTOR, DESCRIPTOR_PARAMS, POSITIVE_INT
from shape_toolkit.plugins.matching.descriptors import UsesDescriptor
from shape_toolkit.plugins.matching.validation import check_descriptors, check_seeds
from shape_toolkit.results.correspondence import Correspondence

__all__ = ["GreedyDescriptorMatcher"]


class GreedyDescriptorMatcher(UsesDescriptor, DenseMatcher):
    """Nearest-descriptor map. ``descriptor``/``descriptor_params``: plugin computed on both
    shapes with the seeds as matched keypoints (when it uses keypoints), unless the caller
    passes descriptors. ``log_scale`` compares log descriptors (heat values span decades).
    ``one_to_one``: greedy global assignment over the ``candidates`` nearest targets of each
    source vertex, most similar pairs first (leaves some vertices unmatched)."""

    parameter_constraints = {
        "descriptor": DESCRIPTOR,
        "descriptor_params": DESCRIPTOR_PARAMS,
        "log_scale": Param(bool, doc="compare log descriptors"),
        "one_to_one": Param(bool, doc="greedy one-to-one assignment"),
        "candidates": Param(POSITIVE_INT, doc="nearest targets considered per source vertex (one_to_one)"),
    }

    def __init__(
        self,
        descriptor: str = "heat-diffusion",
        descriptor_params: dict | None = None,
        log_scale: bool = True,
        one_to_one: bool = False,
        candidates: int = 8,
    ):
        self.descriptor = descriptor
        self.descriptor_params = descriptor_params
        self.log_scale = log_scale
        self.one_to_one = one_to_one
        self.candidates = candidates

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
        """Dense map source -> target by nearest descriptors; confidence ``1 / (1 + distance)``."""
        seeds = check_seeds(seeds, source.n_vertices, target.n_vertices)
        if source_descriptors is None or target_descriptors is None:
            plugin = self._descriptor_plugin()
            kp_s = kp_t = None
            if seeds is not None and len(seeds):
                kp_s, kp_t = seeds[:, 0], seeds[:, 1]
            source_descriptors = plugin.compute(source, spectrum=source_spectrum, keypoints=kp_s)
            target_descriptors = plugin.compute(target, spectrum=target_spectrum, keypoints=kp_t)
        ds = check_descriptors(source_descriptors, source.n_vertices, "source")
        dt = check_descriptors(target_descriptors, target.n_vertices, "target")
        if ds.shape[1] != dt.shape[1]:
            raise ParameterError(f"descriptor widths differ: {ds.shape[1]} and {dt.shape[1]}")
        if self.log_scale:
            floor = 1e-12 * max(float(np.abs(ds).max()), float(np.abs(dt).max()), 1e-300)
            ds, dt = np.log(np.maximum(ds, floor)), np.log(np.maximum(dt, floor))
        # columns on a common scale so that no scale dominates
        scale = np.maximum(np.concatenate([ds, dt]).std(axis=0), 1e-12)
        ds, dt = ds / scale, dt / scale
        if not self.one_to_one:
            d2, j = nearest_neighbors(dt, ds, 1)
            return Correspondence(j, target.n_vertices, 1.0 / (1.0 + np.sqrt(d2)))
        c = int(max(1, min(self.candidates, target.n_vertices)))
        d2, J = nearest_neighbors(dt, ds, c)
        d2, J = np.asarray(d2).reshape(len(ds), c), np.asarray(J).reshape(len(ds), c)
        order = np.argsort(d2, axis=None, kind="stable")
        rows, cols = np.unravel_index(order, d2.shape)
        target_of = np.full(source.n_vertices, -1, dtype=np.int64)
        conf = np.zeros(source.n_vertices)
        used = np.zeros(target.n_vertices, dtype=bool)
        for r, c_ in zip(rows, cols):
            j = J[r, c_]
            if target_of[r] < 0 and not used[j]:
                target_of[r] = j
                used[j] = True
                conf[r] = 1.0 / (1.0 + np.sqrt(d2[r, c_]))
        return Correspondence(target_of, target.n_vertices, conf)
