"""Named, declarative matching pipelines: keypoints -> sparse matcher -> descriptors -> dense
matcher -> refinement -> orientation repair, each stage a plugin that can be swapped in a small dict/TOML spec.

A spec (dict, or a TOML file with the same layout)::

    name = "my-pipeline"
    [keypoints]                       # optional: needed by [sparse]
    plugin = "adf-maxima"
    preset = "dense"
    [sparse]                          # optional: keypoint matches -> seeds
    plugin = "replicator"
    [descriptors]                     # optional: computed with the seeds as matched keypoints
    plugin = "heat-distance"
    [dense]                           # required
    plugin = "seed-growing"
    params = { beta = 0.25 }
    [refine]                          # optional: a dense matcher seeded with the dense map
    plugin = "em-registration"
    [orient]                          # optional: the [refine] registration's map made to keep orientation
    plugin = "orientation-repair"

Each stage takes ``plugin``, optional ``preset`` and ``params``. ``[orient]`` wraps the ``[refine]``
registration (it restarts it from repaired maps), which then registers only; the orientation is set in
``[orient]``. Seeds given by the caller replace the keypoint and sparse stages, and decide the sides in
``[orient]`` (its ``landmarks``; without ``[orient]``, in the ``[refine]`` registration's own side check). The
result is a
:class:`Correspondence` whose ``info`` records the stages, their wall and CPU seconds (``timings``,
``cpu_timings``) and the number of seeds.
"""

from __future__ import annotations

import copy
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.errors import ParameterError, ShapeFileError
from shape_toolkit.plugins.matching.dense.orientation_repair import OrientationRepair
from shape_toolkit.plugins.matching.descriptors import paired_descriptors
from shape_toolkit.plugins.matching.multires import PROXY_VERTICES, check_proxy_size
from shape_toolkit.plugins.matching.orientation import orientation_verdict, side_cache_scope
from shape_toolkit.results.correspondence import Correspondence, read_seeds
from shape_toolkit.spectra import SpectrumSpec, compute_declared, merge_specs
from shape_toolkit.validation import check_seeds

__all__ = [
    "STAGES", "PRESETS", "ORIENT_PLUGINS", "Pipeline", "load_pipeline", "run_pipeline", "run_pair_timed", "read_seeds",
    "paired_descriptors",
]

#: stage name -> plugin family, in execution order (``orientation``: no registry family, see ORIENT_PLUGINS)
STAGES: dict[str, str] = {
    "keypoints": "keypoints",
    "sparse": "sparse_matchers",
    "descriptors": "descriptors",
    "dense": "dense_matchers",
    "refine": "dense_matchers",
    "orient": "orientation",
}

#: the [orient] stage's plugins: each wraps the [refine] registration
ORIENT_PLUGINS: dict[str, type] = {"orientation-repair": OrientationRepair}

#: built-in pipelines
#: the candidate shares of the whole's area of the ``partial`` preset besides the shapes' areas' ratio (the one
#: whose map is closest to an isometry is kept): steps of 0.1, the pipeline's maps change that much with the ratio
#: (benchmarks/results/partial_matching_notes.md); below 0.4 the declared spectrum truncates the target basis
PARTIAL_AREA_RATIOS = [0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]

PRESETS: dict[str, dict[str, Any]] = {
    "sharma2012": {
        "description": "thesis ch. 7: ADF keypoints, replicator matching, heat-distance "
        "descriptors, seed growing (Alg. 6), EM registration (Alg. 7), its map polished on 100 "
        "Laplace-Beltrami eigenvectors (an extension) after the orientation repair",
        "keypoints": {"plugin": "adf-maxima", "preset": "thesis-dense"},
        "sparse": {"plugin": "replicator"},
        "descriptors": {"plugin": "heat-distance"},
        "dense": {"plugin": "seed-growing"},
        "refine": {"plugin": "em-registration", "params": {"polish_k": 100}},
        "orient": {"plugin": "orientation-repair"},
    },
    "topo-robust": {
        "description": "thesis 7.4: ADF keypoints, replicator matching (orientation-checked), small-scale "
        "heat-diffusion descriptors (eq. 6.61-6.63), seed growing (Alg. 6), EM on the thesis's embedding "
        "(graph Laplacian, commute-time scaling, scree dimension; Alg. 7), coarse-to-fine refinement (40 graph, "
        "then 100 Laplace-Beltrami eigenvectors; an extension), orientation repair; the final map is the one of "
        "least ZoomOut residual among EM's, the side reference's and the fine functional map's, each polished by "
        "ZoomOut to 100 eigenfunctions (glued contacts mislead each in different places)",
        "keypoints": {"plugin": "adf-maxima", "preset": "thesis-dense"},
        "sparse": {"plugin": "replicator"},
        "descriptors": {"plugin": "heat-diffusion", "params": {"K": 50, "time_ratio": 1.5}},
        "dense": {"plugin": "seed-growing", "params": {
            "descriptor": "heat-diffusion", "descriptor_params": {"K": 50, "time_ratio": 1.5}}},
        "refine": {"plugin": "em-registration", "preset": "topo-robust", "params": {"k_final": 40, "polish_k": 100}},
        "orient": {"plugin": "orientation-repair", "params": {"polish": 100}},
    },
    "seed-growing": {
        "description": "ADF keypoints, replicator matching, heat-distance descriptors, seed growing",
        "keypoints": {"plugin": "adf-maxima", "preset": "thesis-dense"},
        "sparse": {"plugin": "replicator"},
        "descriptors": {"plugin": "heat-distance"},
        "dense": {"plugin": "seed-growing"},
    },
    "zoomout": {
        "description": "WKS functional map with orientation-preserving term, refined by ZoomOut",
        "dense": {"plugin": "fmap-zoomout"},
    },
    "auto": {
        "description": "zoomout and shells on the same pair, the map of least ZoomOut residual kept (best-of): "
        "isometric pairs across poses go to the functional maps, non-isometric and merged pairs to the shells; "
        "the shells also run in the frame of the functional map when it keeps orientation (scans turned "
        "between captures) and on the two shapes' canonical forms (pose removed), unless their map in the given "
        "frame already agrees with the functional map, and their maps are also polished by ZoomOut",
        "dense": {"plugin": "best-of"},
    },
    "shells": {
        "description": "non-isometric pairs (a gorilla and a person): coarse-to-fine alignment of smooth shells "
        "(after Smooth Shells, Eisenberger et al. 2020), bijective point maps in the product of positions and "
        "spectral coordinates; the shapes must share a frame (upright the same way)",
        "dense": {"plugin": "shell-alignment"},
    },
    "partial": {
        "description": "a part (a scan seeing one side, a region cut away) to a whole shape: "
        "zoomout with rectangular functional maps whose target basis spans the part's frequencies (the slanted "
        "diagonal of Rodola et al. 2017), WKS at shared energies; a map for each area ratio (the diagonal's slope: "
        "the shapes' areas' one and 0.4-1.0), each also refined on the eigenbasis of its support on the whole, the "
        "one closest to an isometry up to scale kept (shapes in any units); the part's smooth shells placed on the "
        "whole from that map (only the part pulls), in the given frame and the map's, compete on the same "
        "distortion",
        "dense": {"plugin": "fmap-zoomout",
                  "params": {"partial": True, "area_ratios": PARTIAL_AREA_RATIOS, "part_shells": True}},
    },
    "zoomout-fast": {
        "description": "zoomout with 8 ZoomOut steps of 10 instead of 16 of 5 (same final basis)",
        "dense": {"plugin": "fmap-zoomout", "preset": "fast"},
    },
    "mateus2008": {
        "description": "eigenvector histogram alignment + EM registration (unsupervised)",
        # Mateus 2008's own alignment: eigvec-alignment's default search and hole closing are issue 30's PLT
        "dense": {"plugin": "eigvec-alignment", "params": {"alignment": "histogram", "holes": "keep", "side": "none"}},
    },
    "ovsjanikov2010": {
        "description": "ADF keypoints, replicator matching, greedy heat-kernel-map matching (Ovsjanikov et al. "
        "2010's own greedy step, as thesis 7.3 describes it; not the Table 7.2 baseline: see ovsjanikov2010-thesis)",
        "keypoints": {"plugin": "adf-maxima", "preset": "thesis-dense"},
        "sparse": {"plugin": "replicator"},
        "dense": {"plugin": "greedy-descriptor"},
    },
    # the literal chains (issue 30): every stage in its 'thesis' preset, no orientation repair, no refinement
    # beyond the text; the improved chains above stay the defaults
    "sharma2012-thesis": {
        "description": "thesis ch. 7 as written: ADF keypoints (Table 6.1's dense setup, t = 50, K = 50; its "
        "sparse one, t = 500, finds 2 keypoints on small shapes, too few to match), association graph + "
        "replicator on the Gaussian graph (7.2.1, up to symmetry), heat-diffusion descriptors at t = {0, 20, 40, "
        "80, 100} (7.4-7.5), seed growing (Alg. 6), EM on the plain eigenvectors of D - W (eq. 6.24 at t = 0, "
        "Alg. 7: posterior > 0.5, the rest unmatched); no orientation repair, no polishing",
        "keypoints": {"plugin": "adf-maxima", "preset": "thesis-dense"},
        "sparse": {"plugin": "replicator", "preset": "thesis"},
        "descriptors": {"plugin": "heat-diffusion", "preset": "thesis"},
        "dense": {"plugin": "seed-growing", "preset": "thesis"},
        "refine": {"plugin": "em-registration", "preset": "thesis"},
    },
    "mateus2008-thesis": {
        "description": "the Table 7.2 baseline '[Mateus 2008]' as the thesis ran it (7.5: 'the same set of "
        "parameters used for our method'): eigenvector histogram alignment, then EM on the plain eigenvectors of "
        "the Gaussian graph's D - W (k = 10, the top of 7.4.1's range), posterior > 0.5 or unmatched",
        "dense": {"plugin": "eigvec-alignment", "params": {
            "spectrum": "graph", "weighting": "gaussian", "scaling": "none", "k": 10, "fill_unmatched": False,
            "alignment": "histogram", "holes": "keep", "side": "none"}},
    },
    "ovsjanikov2010-thesis": {
        "description": "the Table 7.2 baseline '[Ovsjanikov 2010]' as the thesis ran it (7.5): HKS "
        "(heat-diffusion) descriptors with the thesis's parameters (t = {0, 20, 40, 80, 100}) propagated by seed "
        "growing (Alg. 6) from the same keypoints and sparse matches, no EM (the greedy original: ovsjanikov2010)",
        "keypoints": {"plugin": "adf-maxima", "preset": "thesis-dense"},
        "sparse": {"plugin": "replicator", "preset": "thesis"},
        "descriptors": {"plugin": "heat-diffusion", "preset": "thesis"},
        "dense": {"plugin": "seed-growing", "preset": "thesis"},
    },
}

#: the 7.4 chain seeded by colour features (7.2.2): topo-robust with its sparse stage swapped
PRESETS["topo-robust-photometric"] = {
    **copy.deepcopy(PRESETS["topo-robust"]),
    "description": "thesis 7.4 with the colour-feature seeds of 7.2.2: ADF keypoints matched by the shapes' "
    "surface colours (photometric: ring colour descriptors, mutual nearest neighbours, ratio test, target "
    "refined by colour; a geometric texture when neither shape is coloured), then the topo-robust chain; "
    "left and right are decided by the colour seeds (a texture is not symmetric), so EM's intrinsic side check "
    "is off (on uncoloured shapes use topo-robust)",
    "sparse": {"plugin": "photometric"},
}
# EM's geometry-only side reference can mirror a map that the colour seeds got right: no [orient] stage, and EM
# registers only (measured: benchmarks/results/em_registration_notes.md)
del PRESETS["topo-robust-photometric"]["orient"]
PRESETS["topo-robust-photometric"]["refine"]["params"]["orientation"] = "none"

_STAGE_KEYS = {"plugin", "preset", "params"}


class Pipeline:
    """A validated pipeline spec: ``name``, ``description`` and ``stages`` (stage -> dict with
    ``plugin``, ``preset``, ``params``), checked against the plugin registry."""

    def __init__(self, spec: dict[str, Any], name: str | None = None):
        if not isinstance(spec, dict):
            raise ParameterError(f"a pipeline spec must be a mapping, got {type(spec).__name__}")
        unknown = sorted(set(spec) - set(STAGES) - {"name", "description"})
        if unknown:
            raise ParameterError(
                f"unknown pipeline keys {unknown}; valid: name, description, {', '.join(STAGES)}"
            )
        self.name = str(spec.get("name") or name or "custom")
        self.description = str(spec.get("description", ""))
        self.stages: dict[str, dict[str, Any]] = {}
        for stage in STAGES:
            if stage not in spec or spec[stage] is None:
                continue
            st = spec[stage]
            if isinstance(st, str):
                st = {"plugin": st}
            if not isinstance(st, dict) or "plugin" not in st:
                raise ParameterError(f"pipeline stage [{stage}] needs a 'plugin' name")
            bad = sorted(set(st) - _STAGE_KEYS)
            if bad:
                raise ParameterError(f"stage [{stage}] has unknown keys {bad}; valid: plugin, preset, params")
            params = st.get("params") or {}
            if not isinstance(params, dict):
                raise ParameterError(f"stage [{stage}] params must be a mapping")
            self.stages[stage] = {
                "plugin": str(st["plugin"]), "preset": st.get("preset"), "params": dict(params)
            }
        if "dense" not in self.stages:
            raise ParameterError("a pipeline needs a [dense] stage")
        if ("sparse" in self.stages) != ("keypoints" in self.stages):
            raise ParameterError("the [sparse] and [keypoints] stages go together")
        if "orient" in self.stages:
            if "refine" not in self.stages:
                raise ParameterError("the [orient] stage repairs the [refine] registration: add a [refine] stage")
            if "orientation" in self.stages["refine"]["params"] or "matcher" in self.stages["orient"]["params"]:
                raise ParameterError("with an [orient] stage, the orientation is set in [orient], which wraps the "
                                     "[refine] matcher (it registers only)")
        self.plugins()  # fail early on unknown plugins and parameters

    def _create(self, stage: str) -> Any:
        from shape_toolkit.api.registry import create_plugin

        st = self.stages[stage]
        if STAGES[stage] == "orientation":
            if st["plugin"] not in ORIENT_PLUGINS or st["preset"]:
                raise ParameterError(f"[{stage}] takes one of {', '.join(ORIENT_PLUGINS)} without a preset, "
                                     f"got {st['plugin']!r}" + (f" preset {st['preset']!r}" if st["preset"] else ""))
            return ORIENT_PLUGINS[st["plugin"]]().set_params(**st["params"])
        return create_plugin(STAGES[stage], st["plugin"], st["preset"], **st["params"])

    def to_dict(self) -> dict[str, Any]:
        """The spec as a plain dict (round-trips through :class:`Pipeline`)."""
        out: dict[str, Any] = {"name": self.name, "description": self.description}
        out.update(copy.deepcopy(self.stages))
        return out

    def __repr__(self) -> str:
        chain = " -> ".join(f"{s}:{v['plugin']}" for s, v in self.stages.items())
        return f"Pipeline({self.name!r}: {chain})"

    def plugins(self) -> dict[str, Any]:
        """A fresh plugin instance per stage, ``{stage: plugin}``, in execution order; the [orient] plugin
        wraps the [refine] one, which then registers only (``orientation="none"``); the [refine] registration
        starts from the dense stage's map without taking it as right (``trust_seeds=False``)."""
        plugins = {stage: self._create(stage) for stage in self.stages}
        if "refine" in plugins and "trust_seeds" in plugins["refine"].get_params(deep=False):
            plugins["refine"].set_params(trust_seeds=False)  # its seeds are the dense stage's map
        if "orient" in plugins:
            refine = plugins["refine"]
            if "orientation" in refine.get_params(deep=False):
                refine.set_params(orientation="none")
            plugins["orient"].set_params(matcher=refine).registration()
        return plugins

    def spectrum_specs(self) -> list[SpectrumSpec]:
        """Every spectrum the stages need (one per kind, the largest ``k``): what a caller computes
        once per shape and passes to :meth:`run`."""
        return merge_specs(s for specs in _declared(self.plugins()).values() for s in specs)

    def run(
        self,
        source: Shape,
        target: Shape,
        seeds: np.ndarray | None = None,
        *,
        spectra: dict[str, Sequence[Spectrum]] | None = None,
        progress: Callable[[str], None] | None = None,
        proxy: int | None = PROXY_VERTICES,
    ) -> Correspondence:
        """Run the stages on ``source`` -> ``target``; ``seeds`` ``(q, 2)`` replace the keypoint and
        sparse stages. ``spectra`` ``{"source": [...], "target": [...]}`` holds the spectra of
        :meth:`spectrum_specs` (computed here through the content cache when None); every stage
        receives them and picks the one it declares. ``info['spectra']`` records, per stage, the
        spectra each stage declared and received; ``info['orientation']`` whether the final map keeps
        orientation (:func:`~shape_toolkit.plugins.matching.orientation.orientation_verdict`: ``preserving``,
        ``reversing`` for a mirror image, or ``undecided``; two clouds matched through proxies: the proxies'
        verdict, with ``"on": "proxies"``). ``progress(message)`` hears each stage, and the
        messages of the dense matchers (their ``match``'s ``progress``). Shapes of more
        than 1.5 ``proxy`` vertices (None or 0: never) are matched through proxies of ``proxy`` vertices
        and the map lifted to full resolution (:mod:`~shape_toolkit.plugins.matching.multires`;
        ``info['proxy']``, which also holds the dense matcher's functional map ``C``, in the proxies' eigenbases;
        the other matcher entries of ``info``, such as candidates and their residuals, describe the proxy pair),
        unless ``spectra`` are given."""
        say = progress or (lambda _msg: None)
        if proxy is not None and not (proxy is False or (_is_integer(proxy) and proxy == 0)):
            proxy = check_proxy_size(proxy)  # before any work: not a string's TypeError, nor NaN or 150.7 let pass
        if proxy and spectra is None and max(source.n_vertices, target.n_vertices) > 1.5 * proxy:
            return self._run_through_proxies(source, target, seeds, int(proxy), say)
        with side_cache_scope():  # the sparse stage and the orientation repair share symmetry map and sides
            return self._run_stages(source, target, seeds, spectra, progress, say)

    def _run_stages(self, source: Shape, target: Shape, seeds: np.ndarray | None,
                    spectra: dict[str, Sequence[Spectrum]] | None, progress: Callable[[str], None] | None,
                    say: Callable[[str], None]) -> Correspondence:
        """:meth:`run` at full resolution."""
        timings: dict[str, float] = {}
        cpu: dict[str, float] = {}
        info: dict[str, Any] = {"pipeline": self.name}
        plugins = self.plugins()

        def timed(stage: str, fn: Callable[[], Any]) -> Any:
            say(f"{self.name}: {stage} ({self.stages[stage]['plugin']})")
            t0, c0 = time.perf_counter(), time.process_time()
            out = fn()
            timings[stage], cpu[stage] = time.perf_counter() - t0, time.process_time() - c0
            return out

        def counts(stage: str) -> Callable[..., None] | None:
            """The ``progress`` a dense matcher of ``stage`` reports to: its messages under the stage's name."""
            if progress is None:
                return None
            head = f"{self.name}: {stage} ({self.stages[stage]['plugin']})"
            return lambda done, total=None: say(f"{head} {done}/{total}" if total else f"{head} {done}")

        declared = _declared(plugins)
        if spectra is None:
            specs = merge_specs(s for specs in declared.values() for s in specs)
            t0, c0 = time.perf_counter(), time.process_time()
            say(f"{self.name}: spectra ({', '.join(str(s.to_dict()) for s in specs) or 'none'})")
            src_list, tgt_list = compute_declared([source, target], specs)
            spectra = {"source": src_list, "target": tgt_list}
            timings["spectra"], cpu["spectra"] = time.perf_counter() - t0, time.process_time() - c0
            src_spectra, tgt_spectra = spectra["source"], spectra["target"]
        else:  # given by the caller: fail before any work when one does not fit a stage
            src_spectra, tgt_spectra = _spectrum_lists(spectra)
            for spec in (s for specs in declared.values() for s in specs):
                spec.pick(src_spectra, source)
                spec.pick(tgt_spectra, target)
        info["spectra"] = {stage: [s.for_shape(source).to_dict() for s in specs] for stage, specs in declared.items()}
        sides = {"source_spectrum": src_spectra, "target_spectrum": tgt_spectra}

        if seeds is not None:
            seeds = check_seeds(seeds, source.n_vertices, target.n_vertices, allow_empty=False)
            info["seed_source"] = "given"
            if "orient" in plugins:  # the caller's seeds are right: they decide the sides where they reach
                plugins["orient"].set_params(landmarks=seeds)
            elif "refine" in plugins and "landmarks" in plugins["refine"].get_params(deep=False):
                plugins["refine"].set_params(landmarks=seeds)  # its own side check, when it has one
        elif "sparse" in self.stages:
            det = plugins["keypoints"]
            kps = timed("keypoints", lambda: (det.detect(source, spectrum=src_spectra),
                                              det.detect(target, spectrum=tgt_spectra)))
            info["n_keypoints"] = [int(len(kps[0])), int(len(kps[1]))]
            matcher = plugins["sparse"]
            seeds = timed("sparse", lambda: matcher.match(source, target, kps[0], kps[1], **sides))
            # one target per source vertex, inside both shapes: as the caller's seeds, before any stage uses them
            seeds = check_seeds(np.asarray(seeds).reshape(-1, 2), source.n_vertices, target.n_vertices)
            if len(seeds) == 0:
                raise ParameterError(
                    f"pipeline {self.name!r}: the sparse matcher found no keypoint matches "
                    f"({info['n_keypoints'][0]} and {info['n_keypoints'][1]} keypoints)"
                )
            info["seed_source"] = self.stages["sparse"]["plugin"]
        info["n_seeds"] = 0 if seeds is None else int(len(seeds))

        dense = plugins["dense"]
        kwargs: dict[str, Any] = {"seeds": seeds, **sides, "progress": counts("dense")}
        if "descriptors" in self.stages:
            if seeds is None or len(seeds) == 0:
                raise ParameterError(
                    f"pipeline {self.name!r}: the [descriptors] stage needs seeds (matched keypoints)"
                )
            desc = plugins["descriptors"]
            ds, dt, n_times = timed("descriptors", lambda: paired_descriptors(
                desc, source, target, seeds[:, 0], seeds[:, 1], **sides
            ))
            kwargs.update(source_descriptors=ds, target_descriptors=dt, n_times=n_times)
        corr = timed("dense", lambda: dense.match(source, target, **kwargs))
        info["n_dense"] = corr.n_matched
        if "refine" in self.stages:
            pairs = corr.pairs()
            if len(pairs) == 0:
                raise ParameterError(f"pipeline {self.name!r}: the dense stage matched no vertex")
            ref = plugins.get("orient", plugins["refine"])  # [orient] runs the [refine] registration itself
            corr = timed("refine", lambda: ref.match(source, target, seeds=pairs, **sides, progress=counts("refine")))
        if info.get("seed_source") == "given":  # the caller's pairs stay in the map, whatever its stages made of them
            corr = corr.with_pairs(seeds)  # (its confidences and posteriors too)
        # every pipeline says whether its map keeps orientation: a mirror image is never returned silently
        info["orientation"] = orientation_verdict(source, target, corr.target_of)
        if info["orientation"]["verdict"] != "preserving":
            say(f"{self.name}: orientation {info['orientation']['verdict']} "
                f"(score {info['orientation']['score']:+.2f}, z {info['orientation']['z']:+.1f})")
        info["timings"], info["cpu_timings"] = timings, cpu
        info["seconds"] = float(sum(timings.values()))
        merged = dict(corr.info)
        merged.update(info)
        return Correspondence(corr.target_of, corr.n_target, corr.confidence, corr.posteriors, merged)


    def _run_through_proxies(self, source: Shape, target: Shape, seeds: np.ndarray | None, proxy: int,
                             say: Callable[[str], None]) -> Correspondence:
        """:meth:`run` on proxies of ``proxy`` vertices, the map lifted to the full shapes."""
        from shape_toolkit.plugins.matching.multires import lift_map, make_proxy, proxy_seeds, values_from_proxy

        t0, c0 = time.perf_counter(), time.process_time()
        say(f"{self.name}: proxies of {proxy} vertices")
        ps, ids_s = make_proxy(source, proxy) if source.n_vertices > 1.5 * proxy else (source, None)
        pt, ids_t = make_proxy(target, proxy) if target.n_vertices > 1.5 * proxy else (target, None)
        ids_s = np.arange(source.n_vertices) if ids_s is None else ids_s
        ids_t = np.arange(target.n_vertices) if ids_t is None else ids_t
        t_proxy, c_proxy = time.perf_counter() - t0, time.process_time() - c0
        pseeds = None if seeds is None else proxy_seeds(seeds, source, target, ids_s, ids_t)
        inner = self.run(ps, pt, pseeds, progress=say, proxy=None)
        say(f"{self.name}: lifting the proxy map to {source.n_vertices} and {target.n_vertices} vertices")
        t1, c1 = time.perf_counter(), time.process_time()
        full, lift = lift_map(source, target, ids_s, ids_t, inner.target_of, proxies=(ps, pt))
        if seeds is not None:  # the user's pairs stay in the map, as when the shapes are matched directly
            full = Correspondence(full, target.n_vertices).with_pairs(seeds).target_of
        t_lift, c_lift = time.perf_counter() - t1, time.process_time() - c1
        info = {k: v for k, v in inner.info.items() if k not in ("orientation", "timings", "cpu_timings", "seconds")}
        info["proxy"] = {**lift, "proxy_orientation": inner.info.get("orientation")}
        if "C" in info:  # a functional map between the proxies' eigenbases, not the shapes': filed with the proxy
            info["proxy"]["C"] = info.pop("C")
        if isinstance(info.get("partial"), dict) and "support" in info["partial"] and ids_t.size != target.n_vertices:
            # the part's support is a mask of the target proxy's vertices: carried to the target's, as the map is
            info["partial"] = {**info["partial"], "support": values_from_proxy(info["partial"]["support"], target, pt)}
        if source.is_mesh and target.is_mesh:
            info["orientation"] = orientation_verdict(source, target, full)
        else:  # a full cloud's outward normals cost ~n log n per view (40 s at 245k points): the proxies' verdict
            info["orientation"] = {**(inner.info.get("orientation") or {}), "on": "proxies"}
        timings = {"proxies": t_proxy, **{f"proxy {k}": v for k, v in inner.info.get("timings", {}).items()},
                   "lift": t_lift}
        info["cpu_timings"] = {"proxies": c_proxy,
                               **{f"proxy {k}": v for k, v in inner.info.get("cpu_timings", {}).items()},
                               "lift": c_lift}
        info["timings"], info["seconds"] = timings, float(sum(timings.values()))
        return Correspondence(full, target.n_vertices, info=info)


def _is_integer(value: object) -> bool:
    """True for a Python or numpy integer that is not a bool."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _declared(plugins: dict[str, Any]) -> dict[str, list[SpectrumSpec]]:
    """``{stage: [SpectrumSpec, ...]}`` the stage plugins declare (third-party plugins without
    ``spectrum_specs`` declare none)."""
    return {stage: list(p.spectrum_specs()) if hasattr(p, "spectrum_specs") else [] for stage, p in plugins.items()}


def _spectrum_lists(spectra: Any) -> tuple[list[Spectrum], list[Spectrum]]:
    if not isinstance(spectra, dict) or set(spectra) != {"source", "target"}:
        raise ParameterError("spectra must be a mapping {'source': [Spectrum, ...], 'target': [Spectrum, ...]}")
    out = []
    for side in ("source", "target"):
        v = spectra[side]
        out.append([v] if isinstance(v, Spectrum) else list(v))
    return out[0], out[1]


def load_pipeline(spec_or_name: str | os.PathLike | dict[str, Any] | Pipeline) -> Pipeline:
    """A :class:`Pipeline` from a preset name, a TOML file path or a dict."""
    if isinstance(spec_or_name, Pipeline):
        return spec_or_name
    if isinstance(spec_or_name, dict):
        return Pipeline(spec_or_name)
    key = str(spec_or_name)
    if key in PRESETS:
        return Pipeline(PRESETS[key], name=key)
    if not key.strip():
        raise ParameterError(f"an empty pipeline name: give a preset ({', '.join(sorted(PRESETS))}) or a .toml file")
    p = Path(key)
    if p.suffix.lower() == ".toml" or p.exists():
        if p.is_dir():
            raise ShapeFileError(p, "is a folder, not a pipeline file (a .toml file or a preset name)")
        if not p.is_file():
            raise ShapeFileError(p, "no such pipeline file")
        try:
            import tomllib
        except ModuleNotFoundError:  # pragma: no cover - Python 3.10
            import tomli as tomllib
        try:
            spec = tomllib.loads(p.read_text())
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise ShapeFileError(p, f"invalid TOML: {exc}") from None
        return Pipeline(spec, name=p.stem)
    raise ParameterError(
        f"unknown pipeline {key!r}: give a preset ({', '.join(sorted(PRESETS))}) or a .toml file"
    )


def run_pipeline(
    spec_or_name: str | os.PathLike | dict[str, Any] | Pipeline,
    source: Shape,
    target: Shape,
    seeds: np.ndarray | None = None,
    *,
    progress: Callable[[str], None] | None = None,
) -> Correspondence:
    """Load a pipeline (preset name, TOML path, dict) and run it on ``source`` -> ``target``."""
    return load_pipeline(spec_or_name).run(source, target, seeds, progress=progress)


def run_pair_timed(
    spec_or_name: str | os.PathLike | dict[str, Any] | Pipeline,
    source: Shape,
    target: Shape,
    seeds: np.ndarray | None = None,
    proxy: int | None = PROXY_VERTICES,
) -> tuple[Correspondence, dict[str, float]]:
    """One frame pair as ``shape-toolkit track`` and the runner's sequence task match it: a fresh
    pipeline loaded from ``spec_or_name`` run with one BLAS thread (and ``proxy`` as :meth:`Pipeline.run`'s), so the
    map does not depend on where it runs; returns the map and ``{"wall": s, "cpu": s}`` (process CPU seconds)."""
    from threadpoolctl import threadpool_limits

    t0, c0 = time.perf_counter(), time.process_time()
    with threadpool_limits(limits=1):
        corr = load_pipeline(spec_or_name).run(source, target, seeds, proxy=proxy)
    return corr, {"wall": time.perf_counter() - t0, "cpu": time.process_time() - c0}
