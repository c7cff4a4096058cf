"""Several dense matchers on one pair, the most plausible map kept: the one of least ZoomOut residual
(:func:`~shape_toolkit.features.basis.map_residual`) in a common basis of both
shapes. The ``auto`` pipeline runs ``fmap-zoomout`` (intrinsic: robust to pose, fragile under non-isometry
and merged contacts) and ``shell-alignment`` (extrinsic and spectral: robust to non-isometry and merges,
fragile under a change of pose) and keeps what the pair calls for.

An extrinsic matcher needs the shapes in one frame, and scans are not always captured facing the same way
(FAUST people turn by 90-180 degrees between scans). So the intrinsic map, which does not see frames, is asked
for one: when it keeps orientation (:func:`~shape_toolkit.plugins.matching.orientation.orientation_verdict`,
3 sigma), the rotation that best carries the source onto its images (:func:`~shape_toolkit.core.geometry.
rigid_rotation`, mass-weighted) turns the source, and the extrinsic matcher runs again in that frame. Its maps
are also polished by ZoomOut (an intrinsic refinement of an extrinsic map), and all compete on the residual.
On the tuning half (FAUST people 0-1 mapped across the two people, 11 pairs; dogs; gorillas to men) this took
a pair turned by 113 degrees from 0.505 (left and right swapped) to 0.022 and the 11 pairs' mean from 0.143 to
0.096; one pair turned by 115 degrees stays swapped (its intrinsic map, 0.30, gives a poor frame).
``frame_from = "best"`` (not the default: it flipped a glued FAUST pair of the report half, session 36,
``auto_speed_notes.md``) takes the frame from the map of least residual once the extrinsic matcher ran in the given one.

Pose. An extrinsic matcher also needs the two shapes in one pose, and a gorilla crouching is not a person
standing. So the extrinsic matchers run once more on the two shapes' canonical forms
(:func:`~shape_toolkit.features.canonical.canonical_form`: geodesic MDS, which bending leaves unchanged up to
a rigid motion), the source's turned onto the target's by the rigid rotation that best carries it along the best
map so far; that map is polished by ZoomOut too, and competes on the residual. Simulated on the tuning half: gorillas
to men 0.212 -> 0.172, dogs 0.0250 -> 0.0241, glued dogs 0.0398 -> 0.0368, FAUST and glued FAUST unchanged; about 1 s
CPU more at 5k (0.2 s the two forms, then one shells run and one polish).

Point clouds take both steps too: they judge orientation with their outward normals (signed by visibility), and
their canonical forms are taken on their local surface (:func:`~shape_toolkit.core.surface.cloud_surface`: each
point's oriented fan of neighbours, whose edges carry the geodesics and whose orientation picks the mirror). On
the tuning half's vertex clouds (6 dog pairs, 10 FAUST pairs of people 0-1, noise 0 and 0.5 %) this took the
mean error from 0.048 / 0.080 to 0.041 / 0.051 on dogs and from 0.074 / 0.130 to 0.046 / 0.097 on FAUST (the
frame estimate alone: 0.041 / 0.060 and 0.052 / 0.108), for 1-2 s CPU more per pair. When either cloud's fans
fall apart (an unevenly sampled cloud: dense patches whose 8 nearest points are all in the patch, as on every TOSCA
dog's vertex cloud), both clouds take their sheet surfaces instead (:func:`~shape_toolkit.core.surface.
sheet_surface`: the triangles of the point-cloud Laplacian, one piece wherever the Laplacian is); before, their
canonical forms were skipped (tuning dog vertex clouds 0.041 -> 0.034; the sheets for every cloud: within the scatter).

Cost. An estimated frame turned by less than ``same_frame`` degrees (15) from the given one is not run again:
the shells' coarse-to-fine start absorbs such a turn (on the tuning pairs turned by 2-22 degrees the two maps
were within 0.0007; the choice among candidates, simulated on 27 + 30 tuning pairs, moved the mean by at most
0.0001), and it saves a shells run and a polish, about 0.8 s of 5 s CPU at 5k, on most pairs of a capture set-up.
Meshes only: on clouds the second run was better on 2 of 64 tuning pairs and worse on none, so they always run it.
When the first intrinsic map and the extrinsic matcher's polished map in the given frame send the source within
``settle`` (0.03 sqrt(area), :func:`~shape_toolkit.plugins.matching.selection.map_distance`) of each other, two
independent methods (one blind to frames, one to intrinsic symmetries) agree, and the estimated frame and the
canonical forms, there to repair a wrong map, are not run (``info["settled"]``). Session 37 (``auto_speed_notes.md``):
no tuning map worse by more than 0.0003, 24-30 % less CPU on FAUST and TOSCA.
``given_frame_first`` (off: it flipped a glued FAUST pair) leaves the frame's run out when the map in the given frame
has a lower residual than the intrinsic map the frame came from (``info["estimated_frame"]["not_run"]``).
The polishes' ZoomOut iterations query ``polish_samples`` (1,000) farthest-point samples of the source, each
fitted with the area of its Voronoi cell, then one iteration queries every vertex: tuning half, the groups' means
within 2 %, 20-28 % less CPU; report half 21-25 % less CPU, FAUST 0.0262 -> 0.0270 (``auto_speed_notes.md``).

Seeds. Most matchers write the user's seeds into their maps, so a map that disagrees with them still holds them (in a
frame the shells cannot bridge, the given-frame shells held every seed and won on the residual). A candidate torn at
half the seeds or more (:func:`~shape_toolkit.plugins.matching.selection.seed_tears`) is kept only when every
candidate is (``honour_seeds``); half, not any, since a right map can be locally wrong at one seed. Tuning half, six
seeds: gorillas to men turned 144 degrees 0.168 -> 0.100, dogs and FAUST unchanged (``seeded_frames_notes.md``).

Mirrored parts. A map can keep orientation on the whole and mirror a part: on FAUST people the feet or the arms
swapped left for right, every candidate alike, since all start from the same intrinsic ambiguity. Where the kept map
reverses orientation on a part (:func:`~shape_toolkit.plugins.matching.orientation.reversing_region`: the local
orientation votes low-pass filtered, the region where they are negative, counted when the map there reverses
orientation at 3 standard errors), the map is trusted on the rest only: ZoomOut restarts from the functional map
in ``reorient`` (10) eigenfunctions fitted on the rest (:func:`~shape_toolkit.features.basis.polish_map` with
``rows``), which extends it smoothly over the mirrored part. The refitted map (``NAME+reoriented``) competes on
the residual only when it reverses orientation on less of the shape than the map it repairs (a refit that mirrors
more is no repair: on FAUST pairs across people 0 and 1 the residual preferred such refits, smoother and wrong,
0.02-0.03 -> 0.07); ``info["mirrored_part"]`` names the map, the part's share of the area before and after the
refit and whether the refit competed. Tuning half (``auto_mirrored_notes.md``): FAUST people 0-1 0.0292 (1 flipped
pair of 22) -> 0.0214 (none); the other groups within 0.001 but one glued FAUST pair. About 0.8 s CPU where it runs.

Ambiguity. The residual cannot tell a person's half turn (left for right and front for back, which keeps
orientation) from the right map, and no judge tried so far can (``auto_mirrored_notes.md``). So ``info["ambiguity"]``
reports the kept map's rival (:func:`map_ambiguity`): the candidate of least residual among those whose images lie
on average at least ``RIVAL_DISTANCE`` (0.15 sqrt(area)) from the kept map's, and whether its residual is within
``AMBIGUOUS_RATIO`` (1.1) of the kept map's. Nothing is chosen by it, but for one case: when the map of least
residual reverses orientation (a mirror image) and a candidate within that ratio does not, that candidate is kept
(``keep_orientation``, :func:`~shape_toolkit.plugins.matching.selection.preserving_alternative`,
``info["orientation_switch"]``): the residual cannot see a mirror, the orientation verdict can. Tuning half (78 FAUST
pairs of people 0-1, dogs, gorillas to men, glued): it changes 3 FAUST pairs (two 0.097 -> 0.022, one 0.528 -> 0.577)
and nothing else (``benchmarks/results/rigid_motion_notes.md``).

Why the residual: the point map of a sound correspondence is, to a good approximation, the point map of a
smooth functional map in the first eigenfunctions (it is what ZoomOut converges to); a part sent to the wrong
place, or a map that folds a limb, leaves energy that no ``k x k`` functional map explains. On 48 tuning pairs (FAUST
people 0-1, dogs, gorillas to men; clean and glued) it kept the better of the two first maps, or one within 0.005 of
it, on 44.

The residual's basis (``k = None``): the polish's 100 eigenfunctions, where each polished map is a ZoomOut fixed point,
so every map is judged in the basis it was refined in (until session 46 a separate 64, where an unpolished shells map,
smooth but reaching a third of the target, read as more plausible). Tuning half (``auto_mirrored_notes.md``): 120
FAUST pairs of people 0-1 0.0534 -> 0.0467 (29 -> 24 above 0.05), gorillas to men 0.127 -> 0.112, glued dogs 0.037 ->
0.028, dogs 0.0181 -> 0.0185, glued FAUST unchanged.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from shape_toolkit.api.interfaces import DenseMatcher
from shape_toolkit.api.params import InstanceOf, Interval, ListOf, Options, Param
from shape_toolkit.core.geometry import farthest_point_sampling, sample_weights
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.errors import InvalidShapeError, ParameterError
from shape_toolkit.features.basis import POLISH_START, Basis, basis_of, map_residual, polish_map
from shape_toolkit.plugins.matching.descriptors import resolve_plugin, shared_spectra
from shape_toolkit.plugins.matching.frames import canonical_pair, estimated_frame
from shape_toolkit.plugins.matching.orientation import RESIDUAL_K, reversing_region
from shape_toolkit.plugins.matching.selection import (
    AMBIGUOUS_RATIO,
    RIVAL_DISTANCE,
    map_ambiguity,
    map_distance,
    preserving_alternative,
    seed_rings,
    seed_tears,
)
from shape_toolkit.plugins.matching.validation import check_seeds
from shape_toolkit.results.correspondence import Correspondence
from shape_toolkit.spectra import SpectrumSpec, declared_specs, default_spec, merge_specs

__all__ = ["BestOfMatcher", "estimated_frame", "map_ambiguity", "RIVAL_DISTANCE", "AMBIGUOUS_RATIO"]  # (re-exported)


#: the default of ``reorient``: the kept map, where a part of it is mirrored, is refitted from a functional map in this
#: many eigenfunctions fitted on the rest (a coarse start extends the trusted part smoothly over the mirrored one);
#: chosen on the tuning half between 10 and 20: 20 took a glued FAUST pair from 0.10 to 0.59 and helped nowhere
REORIENT_START = 10

#: the default of ``polish_samples``: source vertices the polish's iterations query, before one on every vertex
POLISH_SAMPLES = 1000

#: the default of ``same_frame``: an estimated frame turned by less than this (degrees) from the given one is the
#: given one to the shells, whose coarse-to-fine start absorbs the turn (tuning pairs turned by 2-22 degrees: the
#: two maps within 0.0007), so the extrinsic matchers are not run twice
SAME_FRAME_DEGREES = 15.0

#: the default of ``settle``: when the first intrinsic map and an extrinsic matcher's (polished) map in the given frame
#: lie within this distance of each other (:func:`~shape_toolkit.plugins.matching.selection.map_distance`, sqrt(area)
#: of the target), two independent methods agree and the further frames are not run (0: always run them). 1.5x the
#: error of a sound FAUST map (0.02), a fifth of ``RIVAL_DISTANCE``; on the tuning half the simulated choice was the
#: same for any value from 0.01 to 0.05 (``auto_speed_notes.md``, session 37)
SETTLE_DISTANCE = 0.03


def _matcher(spec: Any) -> Any:
    """A dense matcher from an instance, a registry name or a table ``{plugin, preset, params}``."""
    if isinstance(spec, str) and spec == "best-of":
        raise ParameterError("best-of cannot nest itself")
    return resolve_plugin("dense_matchers", spec, None, method="match", what="matcher", kind="dense matcher")


class BestOfMatcher(DenseMatcher):
    """Runs every matcher of ``matchers`` (names, ``{plugin, preset, params}`` tables or instances) and keeps the map
    of least ZoomOut residual in the first ``k`` Laplace-Beltrami eigenfunctions of both shapes (None: the polish's,
    ``RESIDUAL_K`` without a polish; module docstring). Intrinsic matchers
    run first. ``reframe``: each extrinsic matcher (``extrinsic = True``) runs a second time with the source turned
    into the frame of the first intrinsic map (``frame_from = "best"``: of the map of least residual once the first
    extrinsic matcher ran in the given frame), when that map keeps orientation and it is turned by at least
    ``same_frame`` degrees, meshes only (``info["estimated_frame"]["same_as_given"]`` otherwise; module docstring),
    and, with ``given_frame_first``, only when its map in the given frame has no lower residual than that intrinsic
    map (meshes only; ``info["estimated_frame"]["not_run"]`` otherwise).
    ``polish``:
    each extrinsic map is also refined by ZoomOut from 20 to ``polish`` eigenfunctions (0 or None: not),
    ``polish_step`` at a time, its iterations querying ``polish_samples`` farthest-point samples of the source (each
    fitted with its Voronoi cell's area) and then every vertex once (0 or None: every vertex throughout).
    ``canonical``: each extrinsic matcher also runs on the canonical forms (module docstring).
    ``info["candidates"]`` lists each map's residual and its disagreement with the kept map (``NAME@frame``: in the
    estimated frame, ``NAME@canonical``: on the canonical forms, ``NAME+zoomout``: polished; a matcher listed twice
    is ``NAME#2`` the second time), ``info["chosen"]`` the one kept, ``info["ambiguity"]`` its rival
    (:func:`map_ambiguity`),
    ``info["estimated_frame"]`` the estimated frame's rotation in degrees and the verdict it rests on,
    ``info["canonical_frame"]`` the canonical forms' rotation and the map it came from. ``reorient``: where the kept
    map mirrors a part, it is also refitted from a ``reorient x reorient`` functional map fitted on the rest (0 or
    None: not; module docstring), ``info["mirrored_part"]``; ``keep_orientation``: a mirror image of least residual
    gives way to a close candidate that keeps orientation (module docstring), ``info["orientation_switch"]``; the rest
    of ``info`` is the chosen matcher's. Seeds go to every matcher and stay in polished maps; ``honour_seeds``: a map
    torn at half of them or more is kept only when every candidate is (module docstring; ``seeds_torn``).
    A matcher that cannot take the pair (a point cloud for a matcher that needs faces:
    :class:`~shape_toolkit.errors.InvalidShapeError`) is left out and named in ``info["skipped"]``; when none can, the
    first one's error is raised."""

    presets: dict = {}
    parameter_constraints = {
        "matchers": Param(ListOf(InstanceOf(str, dict, DenseMatcher, name="dense matcher")),
                          doc="dense matchers to run (names, tables or objects)"),
        "k": Param(None, Interval(int, 2), doc="Laplace-Beltrami eigenfunctions of the ZoomOut residual (None: the "
                   "polish's, where every polished map is a ZoomOut fixed point; 64 without a polish)"),
        "reframe": Param(InstanceOf(bool), doc="also run extrinsic matchers in the frame of the intrinsic map"),
        "polish": Param(None, Interval(int, 0), doc="ZoomOut size extrinsic maps are also polished to, above 20 "
                        "(0 or None: no polish)"),
        "canonical": Param(InstanceOf(bool), doc="also run extrinsic matchers on the shapes' canonical forms "
                           "(pose removed), turned by the best map so far"),
        "polish_step": Param(Interval(int, 1), doc="eigenfunctions added per ZoomOut iteration of the polish"),
        "same_frame": Param(Interval(float, 0.0, 180.0), doc="degrees below which an estimated frame counts as the "
                            "given one, for two meshes (the extrinsic matchers are not run again; 0: always run "
                            "again; point clouds always run again)"),
        "reorient": Param(None, Interval(int, 0), doc="ZoomOut start size of the kept map refitted where it keeps "
                          "orientation, when a part of it is mirrored (0 or None: not)"),
        "polish_samples": Param(None, Interval(int, 0), doc="source vertices (farthest point samples) the polish's "
                                "iterations query before one on every vertex (0 or None: every vertex throughout)"),
        "given_frame_first": Param(InstanceOf(bool), doc="two meshes: an extrinsic matcher is not run again in the "
                                   "estimated frame when its map in the given frame already has a lower residual "
                                   "than the intrinsic map the frame was estimated from"),
        "frame_from": Param(Options("intrinsic", "best"), doc="the map the estimated frame is taken from: the "
                            "first intrinsic matcher's, or the least residual once the first extrinsic matcher ran in "
                            "the given frame"),
        "settle": Param(None, Interval(float, 0.0), doc="when the first intrinsic map and an extrinsic matcher's map "
                        "in the given frame lie within this distance (sqrt(area)), the estimated frame and the "
                        "canonical forms are not run (0 or None: always run)"),
        "keep_orientation": Param(InstanceOf(bool), doc="when the map of least residual reverses orientation, keep "
                                  "a candidate that does not, of residual within AMBIGUOUS_RATIO of it"),
        "honour_seeds": Param(InstanceOf(bool), doc="with seeds, a map that agrees with half of them or fewer "
                              "(selection.seed_tears) is not kept while another agrees with more (False: the residual "
                              "alone decides, as before session 44)"),
    }

    def __init__(self, matchers: tuple | list = ("fmap-zoomout", "shell-alignment"), k: int | None = None,
                 reframe: bool = True, polish: int | None = 100, canonical: bool = True, polish_step: int = 5,
                 same_frame: float = SAME_FRAME_DEGREES, reorient: int | None = REORIENT_START,
                 polish_samples: int | None = POLISH_SAMPLES, given_frame_first: bool = False,
                 keep_orientation: bool = True, frame_from: str = "intrinsic", settle: float | None = SETTLE_DISTANCE,
                 honour_seeds: bool = True):
        self.matchers = matchers
        self.k = k
        self.reframe = reframe
        self.polish = polish
        self.canonical = canonical
        self.polish_step = polish_step
        self.same_frame = same_frame
        self.reorient = reorient
        self.polish_samples = polish_samples
        self.given_frame_first = given_frame_first
        self.keep_orientation = keep_orientation
        self.frame_from = frame_from
        self.settle = settle
        self.honour_seeds = honour_seeds

    def _residual_k(self) -> int:
        """The residual's basis size: ``k``, or when None the polish's (``RESIDUAL_K`` without a polish)."""
        return int(self.k if self.k is not None else self.polish if self.polish else RESIDUAL_K)

    def _matchers(self) -> list:
        return [_matcher(m) for m in self.matchers]

    def _names(self) -> list[str]:
        """Each matcher's label in ``info``: its plugin name, ``NAME#2``, ``NAME#3``, ... when the name repeats."""
        names = [m if isinstance(m, str) else str(m["plugin"]) if isinstance(m, dict) else type(m).__name__
                 for m in self.matchers]
        return [n if names[:i].count(n) == 0 else f"{n}#{names[:i].count(n) + 1}" for i, n in enumerate(names)]

    def _nested_plugins(self) -> list:
        return self._matchers()

    def spectrum_spec(self) -> SpectrumSpec:
        """The Laplace-Beltrami spectrum with ``max(k, polish) + 1`` eigenpairs (the residual's common basis
        and the polish's), or as many as a nested matcher's of the same kind when more (``fmap-zoomout``'s 111):
        called without spectra, ``match`` then solves one eigenproblem per shape for every matcher, not two."""
        own = default_spec(max(self._residual_k(), int(self.polish or 0)) + 1)
        return merge_specs([own, *declared_specs(self._matchers())])[0]

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
        if self.polish and self.polish <= POLISH_START:
            raise ParameterError(f"polish must be 0 (none) or above {POLISH_START}, got {self.polish}")
        if self.polish and self.polish_samples and self.polish_samples < self.polish:
            raise ParameterError(f"polish_samples must be 0 (every vertex) or at least polish ({self.polish}): a "
                                 f"{self.polish} x {self.polish} functional map is fitted on them, got "
                                 f"{self.polish_samples}")
        matchers = self._matchers()
        seeds = check_seeds(seeds, source.n_vertices, target.n_vertices)
        spec_s, spec_t = self._spectrum(source, source_spectrum), self._spectrum(target, target_spectrum)
        k = int(min(self._residual_k(), spec_s.k, spec_t.k))
        bs, bt = basis_of(spec_s, k), basis_of(spec_t, k)
        kp = int(min(self.polish, spec_s.k, spec_t.k)) if self.polish else None
        bps, bpt = (basis_of(spec_s, kp), basis_of(spec_t, kp)) if kp and kp > POLISH_START else (None, None)
        drawn: dict[str, np.ndarray] = {}  # polish_map's source samples and the mass each stands for

        def sampled() -> dict[str, np.ndarray]:  # drawn when a polish or a refit first needs them
            if not drawn and bps is not None and self.polish_samples and self.polish_samples < source.n_vertices:
                ids = farthest_point_sampling(source.vertices, int(self.polish_samples))
                drawn.update(samples=ids, sample_mass=sample_weights(source.vertices, ids, bps.mass))
            return drawn

        # each matcher picks its own spectra among these
        share_s, share_t = shared_spectra(source_spectrum), shared_spectra(target_spectrum)
        best, candidates, skipped, first_error = None, [], [], None
        frame: dict[str, Any] = {}
        turned: Shape | None = None
        first: tuple[str, np.ndarray] | None = None  # the first intrinsic map, for settle
        settled: dict[str, Any] = {}

        maps: list[np.ndarray] = []  # each candidate's map, for info["ambiguity"]
        corrs: list[Correspondence] = []  # each candidate, in the order of candidates and maps

        # the seeds are the user's matches: a map torn at half of them or more (selection.seed_tears) is kept only
        # when every candidate is, whatever its residual; without seeds the residual alone decides
        torn: dict[str, int] = {}
        rings = seed_rings(source, seeds) if seeds is not None else None  # the seeds' neighbours, once per pair

        def contradicts(name: str) -> bool:
            return bool(self.honour_seeds and seeds is not None and len(seeds) and 2 * torn.get(name, 0) >= len(seeds))

        def consider(name: str, corr: Correspondence) -> None:
            nonlocal best
            residual = map_residual(bs, bt, np.asarray(corr.target_of), k)
            candidates.append({"matcher": name, "residual": residual})
            if seeds is not None:
                torn[name] = candidates[-1]["seeds_torn"] = seed_tears(source, target, corr.target_of, seeds,
                                                                           spec_t.area, rings)
            maps.append(np.asarray(corr.target_of))
            corrs.append(corr)
            if progress is not None:
                progress(f"best-of: {name} residual {residual:.4g}")
            if best is None or (contradicts(name), residual) < (contradicts(best[1]), best[0]):
                best = (residual, name, corr)

        def run(name: str, m: Any, src: Shape, tgt: Shape = target) -> Correspondence | None:
            nonlocal first_error
            try:
                return m.match(src, tgt, seeds=seeds, source_spectrum=share_s, target_spectrum=share_t)
            except InvalidShapeError as exc:  # e.g. a cloud for a matcher that needs a mesh
                skipped.append({"matcher": name, "reason": str(exc)})
                first_error = first_error or exc
                return None

        same = float(self.same_frame) if source.is_mesh and target.is_mesh else 0.0
        order = sorted(zip(self._names(), matchers), key=lambda nm: bool(getattr(nm[1], "extrinsic", False)))
        for name, m in order:
            if not getattr(m, "extrinsic", False):
                corr = run(name, m, source)
                if corr is not None:
                    consider(name, corr)
                    first = first or (name, np.asarray(corr.target_of))
                    if self.reframe and self.frame_from == "intrinsic" and turned is None and not frame:
                        turned, frame = estimated_frame(source, target, np.asarray(corr.target_of), bs.mass, name,
                                                        same)
                continue
            for label in (name, f"{name}@frame"):
                if label != name and settled:
                    continue
                if label != name and self.reframe and self.frame_from == "best" and not frame and best is not None:
                    turned, frame = estimated_frame(source, target, np.asarray(best[2].target_of), bs.mass, best[1],
                                                    same)
                src = source if label == name else turned
                if src is None:
                    continue
                if src is turned and self.given_frame_first and source.is_mesh and target.is_mesh:
                    given = min((c["residual"] for c in candidates if c["matcher"] in (name, f"{name}+zoomout")),
                                default=np.inf)  # inf: the matcher gave no map in the given frame
                    origin = min((c["residual"] for c in candidates if c["matcher"] == frame["from"]), default=np.inf)
                    if given < origin:  # the given frame's map is more plausible than the frame's evidence
                        frame["not_run"] = {"matcher": name, "given_residual": given, "from_residual": origin}
                        continue
                corr = run(label, m, src)
                if corr is None:
                    continue
                if src is turned:  # its own info would say "given"
                    corr = Correspondence(corr.target_of, corr.n_target, corr.confidence, corr.posteriors,
                                          {**corr.info, "frame": "estimated (info['estimated_frame'])"})
                consider(label, corr)
                if bps is not None and np.all(np.asarray(corr.target_of) >= 0):
                    consider(f"{label}+zoomout", self._polished(corr, bps, bpt, seeds, sampled()))
                if label == name and self.settle and first is not None and not settled:
                    d = map_distance(first[1], maps[-1], target, bs.mass, spec_t.area)
                    if d < self.settle:  # two independent methods agree: no frame left to repair
                        settled = {"intrinsic": first[0], "extrinsic": candidates[-1]["matcher"], "distance": d}
        canon: dict[str, Any] = {}
        extrinsic = [(name, m) for name, m in order if getattr(m, "extrinsic", False)]
        if self.canonical and extrinsic and best is not None and not settled:
            try:
                pair, canon = canonical_pair(source, target, np.asarray(best[2].target_of), bs.mass, best[1])
            except InvalidShapeError as exc:  # e.g. a shape in several pieces
                skipped.append({"matcher": "canonical forms", "reason": str(exc)})
                pair = None
            for name, m in extrinsic if pair is not None else []:
                corr = run(f"{name}@canonical", m, *pair)
                if corr is None:
                    continue
                corr = Correspondence(corr.target_of, corr.n_target, corr.confidence, corr.posteriors,
                                      {**corr.info, "frame": "canonical forms (info['canonical_frame'])"})
                consider(f"{name}@canonical", corr)
                if bps is not None and np.all(np.asarray(corr.target_of) >= 0):
                    consider(f"{name}@canonical+zoomout", self._polished(corr, bps, bpt, seeds, sampled()))
        if best is None:
            raise first_error
        # a map that contradicts the seeds is no alternative to one that does not
        eligible = [j for j, c in enumerate(candidates) if contradicts(c["matcher"]) <= contradicts(best[1])]
        switched = preserving_alternative(source, target, [candidates[j] for j in eligible],
                                          [maps[j] for j in eligible], best[1]) if self.keep_orientation else None
        if switched:  # the least residual reverses orientation; a map the residual cannot tell from it does not
            j = next(j for j, c in enumerate(candidates) if c["matcher"] == switched["to"])
            best = (candidates[j]["residual"], switched["to"], corrs[j])
        mirrored: dict[str, Any] = {}
        t = np.asarray(best[2].target_of)
        if self.reorient and bps is not None and np.all(t >= 0):
            region = reversing_region(source, target, t, bps)
            if region.any():
                name, area = best[1], float(bps.mass[region].sum())
                k0 = int(min(self.reorient, bps.k))
                C, T = polish_map(t, bps, bpt, k0, self.polish_step, seeds, rows=np.flatnonzero(~region),
                                  **sampled())
                after = float(bps.mass[reversing_region(source, target, T, bps)].sum())
                # the refit is there to remove the mirrored part: one that mirrors more of the shape is no repair
                mirrored = {"from": name, "area": area, "refit_area": after, "refit_competes": after < area}
                if after < area:
                    consider(f"{name}+reoriented", Correspondence(T, target.n_vertices, info={
                        **best[2].info, "C": C, "reoriented": f"ZoomOut {k0} -> {bps.k} from the unmirrored part"}))
        info = dict(best[2].info)
        refuted = frozenset(c["matcher"] for c in candidates if contradicts(c["matcher"]))  # no rivals: seeds decided
        info.update({"candidates": candidates, "chosen": best[1], "skipped": skipped,
                     "ambiguity": map_ambiguity(candidates, maps, best[1], target, bs.mass, spec_t.area, refuted)})
        if frame:
            info["estimated_frame"] = frame
        if canon:
            info["canonical_frame"] = canon
        if mirrored:
            info["mirrored_part"] = mirrored
        if settled:
            info["settled"] = settled
        if switched:
            info["orientation_switch"] = switched
        return Correspondence(best[2].target_of, target.n_vertices, best[2].confidence, best[2].posteriors, info)

    def _polished(self, corr: Correspondence, bs: Basis, bt: Basis, seeds: np.ndarray | None,
                  sampled: dict[str, np.ndarray]) -> Correspondence:
        """``corr``'s map refined by ZoomOut from its functional map in 20 eigenfunctions to ``bs.k``, ``polish_step``
        eigenfunctions at a time, querying the source samples of ``sampled`` (polish_map's ``samples`` and
        ``sample_mass``; empty: every vertex) before every vertex (:func:`~shape_toolkit.features.basis.polish_map`)."""
        C, T = polish_map(np.asarray(corr.target_of), bs, bt, POLISH_START, self.polish_step, seeds, **sampled)
        how = f", iterations on {len(sampled['samples'])} source samples, the last on every vertex" if sampled else ""
        return Correspondence(T, corr.n_target, info={**corr.info, "C": C,
                                                      "polished": f"ZoomOut {POLISH_START} -> {bs.k}{how}"})
