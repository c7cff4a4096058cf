"""Orientation repair: a registration's map made to keep (or reverse) orientation; the pipelines' ``[orient]``
stage.

EM registration, like every intrinsic method, cannot tell a map from its mirror image, and on articulated
bodies it can settle on a map that is right on some parts and mirrored on others (FAUST: legs swapped).
:class:`OrientationRepair` wraps a registration matcher (:class:`~shape_toolkit.plugins.matching.dense.
em_registration.EMRegistrationMatcher`): it decides the side of each region against an orientation-aware
functional map (:meth:`~OrientationRepair.side_check`) and replaces a map that still reverses orientation on
the whole (:meth:`~OrientationRepair.rescue`). Both restart the registration from repaired maps, so the stage
wraps the matcher rather than following it. With ``polish`` (``topo-robust``), the final map is chosen among the
registration's and the stage's two references, each polished by ZoomOut (:meth:`~OrientationRepair.select`).
Design notes and measurements: ``benchmarks/results/em_registration_notes.md``.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import replace
from typing import Any, Protocol

import numpy as np

from shape_toolkit.api.interfaces import DenseMatcher
from shape_toolkit.api.params import InstanceOf, Interval, Options, Param
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.errors import ParameterError
from shape_toolkit.features.basis import POLISH_START, Basis, basis_of, map_residual, polish_map
from shape_toolkit.plugins._params import ORIENTATION
from shape_toolkit.plugins.matching.validation import check_seeds
from shape_toolkit.results.correspondence import Correspondence
from shape_toolkit.spectra import SpectrumSpec

__all__ = ["CONFLICT_AREA", "ORIENTATION_K", "OrientationRepair", "Registration"]

#: embedding size of the refined maps the orientation is scored on (see :meth:`OrientationRepair.score`)
ORIENTATION_K = 30
#: number of farthest-point samples of the source the orientation is scored on
N_SCORED = 120
#: share of the source's area beyond which a map that disagrees with the side reference (``SideReference.
#: conflict_area``) is rescued: more than half the shape elsewhere than the reference puts it is not a side
#: question but a wrong map -- or a wrong reference (glued contacts can mislead it), so a rescued map must also
#: be smoother than the map it replaces (ZoomOut residual, :func:`~shape_toolkit.features.basis.map_residual`)
CONFLICT_AREA = 0.5


class Registration(Protocol):
    """What :class:`OrientationRepair` needs of the matcher it wraps (``EMRegistrationMatcher`` has it):
    ``emb`` is the matcher's embedding (``K``, ``bases``), a fit has ``target_of``, ``Q``, ``sigma``,
    ``posteriors``, ``confidence`` and ``n_confident`` (a dataclass)."""

    def embedding_spec(self, min_dim: int = 0) -> SpectrumSpec: ...

    def start(self, source: Shape, target: Shape, seeds: np.ndarray | None, source_spectrum: Any,
              target_spectrum: Any, min_dim: int = 0) -> tuple[Any, np.ndarray, dict]: ...

    def solve(self, emb: Any, Q0: np.ndarray) -> Any: ...

    def transform_of(self, emb: Any, target_of: np.ndarray) -> np.ndarray: ...

    def refines(self, emb: Any) -> bool: ...

    def refine(self, emb: Any, target_of: np.ndarray, k_final: int | None = None,
               rows: np.ndarray | None = None) -> np.ndarray: ...

    def finish(self, emb: Any, fit: Any, source: Shape, target: Shape, info: dict, k_done: int | None = None,
               source_spectrum: Any = None, target_spectrum: Any = None) -> Correspondence: ...


class _Fine:
    """The fine orientation-aware functional map of one pair (the rescue's start and judge, a candidate of
    :meth:`OrientationRepair.select`): its matcher, spectra and map, each computed once."""

    def __init__(self, orientation: str, source: Shape, target: Shape, source_spectrum: Any, target_spectrum: Any,
                 landmarks: np.ndarray | None):
        self.orientation, self.source, self.target = orientation, source, target
        self.given, self.landmarks = (source_spectrum, target_spectrum), landmarks

    @functools.cached_property
    def spectra(self) -> tuple[Any, Spectrum, Spectrum]:
        """The fine matcher and the two spectra it runs on."""
        from shape_toolkit.plugins.matching.descriptors import shared_spectra
        from shape_toolkit.plugins.matching.orientation import fine_matcher

        fm = fine_matcher(self.orientation)
        return (fm, fm._spectrum(self.source, shared_spectra(self.given[0])),
                fm._spectrum(self.target, shared_spectra(self.given[1])))

    @functools.cached_property
    def target_of(self) -> tuple[np.ndarray, int]:
        """The fine map ``(n_s,)`` and the basis size it is refined to."""
        fm, ss, st = self.spectra
        res = fm.match(self.source, self.target, seeds=self.landmarks, source_spectrum=[ss], target_spectrum=[st])
        return np.asarray(res.target_of), int(res.info["k_final"])

    def bases(self, k: int) -> tuple[Basis, Basis]:
        """The first ``k`` Laplace-Beltrami eigenfunctions of both shapes (fewer if a spectrum has fewer)."""
        _, ss, st = self.spectra
        k = int(min(k, ss.k, st.k))
        return basis_of(ss, k), basis_of(st, k)


class OrientationRepair(DenseMatcher):
    """The map of the registration ``matcher`` with the side of ``orientation`` (``"preserving"``,
    ``"reversing"``; ``"none"``: the registration's map as it is). Only meshes are repaired (the side
    reference needs outward normals); ``info`` records every decision (``orientation_*``)."""

    parameter_constraints = {
        "orientation": ORIENTATION,
        "landmarks": Param(None, InstanceOf(np.ndarray, list, tuple), doc="matches known to be right, (q, 2): "
                           "they decide the sides where they reach (a caller's seeds)"),
        "polish": Param(Options(0), Interval(int, POLISH_START + 1, 200),
                        doc="0: the registration's map; else the final map is the one of least ZoomOut residual "
                        "among the registration's map, the side reference's and the fine functional map's, each "
                        "polished by ZoomOut to this many Laplace-Beltrami eigenfunctions (select)"),
    }

    def __init__(self, matcher: Any = None, orientation: str = "preserving", landmarks: np.ndarray | None = None,
                 polish: int = 0):
        self.matcher = matcher
        self.orientation = orientation
        self.landmarks = landmarks
        self.polish = polish

    def registration(self) -> Registration:
        """The wrapped matcher, checked: a :class:`Registration`."""
        self._validate_params()
        needed = ("embedding_spec", "start", "solve", "transform_of", "refines", "refine", "finish")
        if self.matcher is None or not all(hasattr(self.matcher, a) for a in needed):
            raise ParameterError(f"orientation repair wraps a registration matcher such as em-registration "
                                 f"(it restarts the registration), got {self.matcher!r}")
        return self.matcher

    def reference_plugins(self) -> list:
        """The matchers the side is decided against: the symmetry self-map, the side reference, the fine map."""
        from shape_toolkit.plugins.matching.orientation import fine_matcher, side_matcher, symmetry_matcher

        if self.orientation == "none":
            return []
        return [symmetry_matcher(), side_matcher(self.orientation), fine_matcher(self.orientation)]

    def _nested_plugins(self) -> list:
        return ([] if self.matcher is None else [self.matcher]) + self.reference_plugins()

    def spectrum_spec(self) -> SpectrumSpec | None:
        """The registration's embedding spectrum with ``ORIENTATION_K + 1`` eigenpairs at least (scoring)."""
        if self.matcher is None or self.orientation == "none":
            return None
        return self.registration().embedding_spec(ORIENTATION_K)

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
        """The registration's dense map, its side repaired (descriptors, ``n_times``, ``progress``: unused)."""
        m = self.registration()
        on = self.orientation != "none"
        lm = self.checked_landmarks(source, target)
        emb, Q0, info = m.start(source, target, seeds, source_spectrum, target_spectrum, ORIENTATION_K if on else 0)
        info["orientation_landmarks"] = 0 if lm is None else int(len(lm))
        fit, k_done = m.solve(emb, Q0), emb.K
        if not (on and source.is_mesh and target.is_mesh):
            return m.finish(emb, fit, source, target, info, k_done, source_spectrum, target_spectrum)
        from shape_toolkit.plugins.matching.orientation import side_cache_scope

        fine = _Fine(self.orientation, source, target, source_spectrum, target_spectrum, lm)
        with side_cache_scope():  # the side check, the rescue and the selection share one side reference
            fit = self.side_check(emb, fit, source, target, info, source_spectrum, target_spectrum, lm)
            info["orientation_score"] = self.score(emb, source, target, fit.target_of)
            info["orientation_conflict_area"] = self.conflict(source, target, fit.target_of, source_spectrum,
                                                              target_spectrum, lm)
            if info["orientation_score"] < 0 or info["orientation_conflict_area"] > CONFLICT_AREA:
                fit, k_done = self.rescue(emb, fit, source, target, info, source_spectrum, target_spectrum, lm, fine)
            corr = m.finish(emb, fit, source, target, info, k_done, source_spectrum, target_spectrum)
            return self.select(corr, source, target, fine, source_spectrum, target_spectrum) if self.polish else corr

    def checked_landmarks(self, source: Shape, target: Shape) -> np.ndarray | None:
        """``landmarks`` checked against the shapes, int64 ``(q, 2)``; at most ``ORIENTATION_K`` of them,
        farthest-point samples of their source vertices (the side reference decides sides at a coarse
        resolution: more add cost, not information); None when there are none."""
        from shape_toolkit.core.geometry import farthest_point_sampling

        try:
            lm = check_seeds(self.landmarks, source.n_vertices, target.n_vertices)
        except ParameterError as e:
            raise ParameterError(f"orientation landmarks (the caller's seeds): {e}") from None
        if lm is None or len(lm) == 0:
            return None
        if len(lm) > ORIENTATION_K:
            lm = lm[farthest_point_sampling(np.asarray(source.vertices)[lm[:, 0]], ORIENTATION_K)]
        return lm

    def score(self, emb: Any, source: Shape, target: Shape, t: np.ndarray, refined: bool = True) -> float:
        """Signed local triple-product score (``orientation_score``; about +1 for the wanted orientation) of
        the map ``t`` ``(n,)`` on ``N_SCORED`` farthest-point samples of the source (~10 % of its size apart:
        local enough for articulations, coarse enough for the map's noise); unmatched samples are skipped.
        ``refined``: the map is first refined to ``ORIENTATION_K`` dimensions on the registration's bases
        (only for scoring: a coarse EM map is too noisy locally for its triplets to vote reliably)."""
        from shape_toolkit.core.geometry import farthest_point_sampling
        from shape_toolkit.plugins.matching.orientation import orientation_score

        rows = farthest_point_sampling(np.asarray(source.vertices), min(N_SCORED, source.n_vertices))
        if refined and emb.bases is not None and 0 < emb.K < ORIENTATION_K and np.all(t >= 0):
            t = self.matcher.refine(emb, t, ORIENTATION_K, rows=rows)
        rows = rows[t[rows] >= 0]
        want = 1.0 if self.orientation == "preserving" else -1.0
        return want * orientation_score(source, target, np.column_stack([rows, t[rows]]))

    def conflict(self, source: Shape, target: Shape, t: np.ndarray, source_spectrum: Any = None,
                 target_spectrum: Any = None, landmarks: np.ndarray | None = None) -> float:
        """:meth:`~shape_toolkit.plugins.matching.orientation.SideReference.conflict_area` of the map ``t``
        ``(n,)``: the share of the source's area the side reference puts elsewhere."""
        from shape_toolkit.plugins.matching.orientation import side_reference

        ref = side_reference(source, target, source_spectrum, target_spectrum, self.orientation,
                             landmarks=landmarks)
        return ref.conflict_area(t)

    def side_check(self, emb: Any, first: Any, source: Shape, target: Shape, info: dict,
                   source_spectrum: Any = None, target_spectrum: Any = None,
                   landmarks: np.ndarray | None = None) -> Any:
        """Each region takes ``T(x)`` or its mirror image ``T(S(x))`` (``S`` the source's intrinsic symmetry),
        whichever is nearer the side reference ``R`` (an orientation-aware functional map); ``R(x)`` where
        ``S`` is no symmetry, or where neither is near ``R`` while ``T`` piles two parts onto one. When a
        region changes, that map and the registration run again from it compete with the fit ``first``:
        the one nearest ``R`` on average is returned."""
        from shape_toolkit.plugins.matching.orientation import side_reference, symmetry_map, symmetry_validity

        m = self.matcher
        ref = side_reference(source, target, source_spectrum, target_spectrum, self.orientation,
                             landmarks=landmarks)
        t = first.target_of
        sym = symmetry_map(source, source_spectrum)
        valid = symmetry_validity(source, sym, ref.basis, ref.k_smooth)
        area = ref.basis.mass.sum()
        info["orientation_symmetry_valid_area"] = float(ref.basis.mass[valid].sum() / area)
        swap = ref.prefer(t, np.where(valid, t[sym], -1))
        info["orientation_mirrored_area"] = float(ref.basis.mass[swap].sum() / area)
        t_c = np.where(swap, t[sym], t)
        # neither T nor T(S) where the reference is, and T piles two parts onto one: a wrong part
        # (where T is one-to-one the reference may be the one that is wrong); and the parts the
        # reference puts on the other side where S is no symmetry (its mirror image cannot be trusted)
        lost = (ref.disagrees(t_c) & ref.overlaps(t_c)) | (ref.prefer(t, t[sym]) & ~valid)
        info["orientation_replaced_area"] = float(ref.basis.mass[lost].sum() / area)
        info["orientation_flipped"] = False
        if not swap.any() and not lost.any():
            return first
        # the combined map (refined as the registration refines its own) and the registration run again
        # from it (EM smooths the seams, but may fall back to the first map) are candidates
        t_c = np.where(lost, ref.target_of, t_c)
        Qc = m.transform_of(emb, t_c)
        if m.refines(emb) and np.all(t_c >= 0):
            t_c = m.refine(emb, t_c)
        cands = {"first": first, "combined": replace(first, Q=Qc, target_of=t_c, confidence=np.zeros(len(t_c)),
                                                     n_confident=0),
                 "em_again": m.solve(emb, Qc)}
        errs = {name: ref.mean_sq_distance(c.target_of) for name, c in cands.items()}
        info["orientation_reference"] = errs
        best = min(errs, key=errs.get)
        info["orientation_choice"] = best
        if best == "first":
            return first
        info["orientation_flipped"] = "all" if info["orientation_mirrored_area"] > 0.5 else "local"
        return cands[best]

    def rescue(self, emb: Any, first: Any, source: Shape, target: Shape, info: dict,
               source_spectrum: Any = None, target_spectrum: Any = None,
               landmarks: np.ndarray | None = None, fine: _Fine | None = None) -> tuple[Any, int]:
        """For a map that still reverses orientation on the whole (:meth:`score` < 0), or else that the side
        reference puts elsewhere on more than :data:`CONFLICT_AREA` of the source (:meth:`conflict`: a half turn
        keeps orientation): the first candidate that scores positive -- and, for a map in conflict, is in conflict on
        at most that share itself and has a smaller ZoomOut residual than ``first`` (neither the reference nor
        the registration judges their own quarrel; the residual is in the first ``RESIDUAL_K``
        Laplace-Beltrami eigenfunctions of both shapes) -- among the registration run again from the side
        reference's map, from the fine orientation-aware functional map, then (not for a map in conflict: only
        EM fits compare like with like) those two maps themselves (``first`` when none does). Returns the fit
        and the embedding size its map is refined to (polishing goes on from there);
        ``info["orientation_rescue"]``: the scores, the conflicts, the residuals and the choice."""
        from shape_toolkit.plugins.matching.orientation import RESIDUAL_K, side_reference

        m, K = self.matcher, emb.K
        fine = fine or _Fine(self.orientation, source, target, source_spectrum, target_spectrum, landmarks)
        rescue = {"score_before": info["orientation_score"], "choice": "first"}
        # rescued for its conflict alone (a map that reverses orientation keeps the rules above)
        in_conflict = info["orientation_score"] >= 0 and info.get("orientation_conflict_area", 0.0) > CONFLICT_AREA
        residual = None
        if in_conflict:  # the judge of a rescue from a conflict: smoothness in a common basis of both shapes
            bs, bt = fine.bases(RESIDUAL_K)
            k = bs.k

            def residual(t: np.ndarray) -> float:
                return map_residual(bs, bt, np.asarray(t), k)

            rescue["residual_first"] = residual(first.target_of)
        info["orientation_rescue"] = rescue
        starts: dict[str, tuple[np.ndarray, int]] = {}

        def start(name: str) -> tuple[np.ndarray, int]:
            if name not in starts:
                if name == "reference_map":
                    ref = side_reference(source, target, source_spectrum, target_spectrum, self.orientation,
                                         landmarks=landmarks)
                    starts[name] = (np.asarray(ref.target_of), int(ref.source_points.shape[1]))
                else:
                    starts[name] = fine.target_of
            return starts[name]

        # a map in conflict competes with EM fits only (at the same embedding size: a functional map's own map
        # is a ZoomOut fixed point, smoother by construction, and the residual would not compare like with like)
        names = ("em_from_reference_map", "em_from_fine_map") + (() if in_conflict else ("reference_map", "fine_map"))
        for name in names:
            t, k_map = start(name.removeprefix("em_from_"))
            Q = m.transform_of(emb, t)
            if name.startswith("em_from_"):
                cand, k_done = m.solve(emb, Q), K
                score = self.score(emb, source, target, cand.target_of)
            else:  # a functional map's own map is already fine: scored as it is, EM's Q, sigma, P kept
                cand, k_done = replace(first, Q=Q, target_of=t, confidence=np.zeros(len(t)), n_confident=0), k_map
                score = self.score(emb, source, target, t, refined=False)
            rescue[f"score_{name}"] = score
            accept = score > 0
            if accept and residual is not None:
                rescue[f"conflict_{name}"] = self.conflict(source, target, cand.target_of, source_spectrum,
                                                           target_spectrum, landmarks)
                rescue[f"residual_{name}"] = residual(cand.target_of)
                accept = (rescue[f"conflict_{name}"] <= CONFLICT_AREA
                          and rescue[f"residual_{name}"] < rescue["residual_first"])
            if accept:
                rescue["choice"] = name
                info["orientation_score"] = score
                if not name.startswith("em_from_"):
                    info["posteriors_of"] = "em-before-rescue"
                return cand, k_done
        return first, K

    def select(self, corr: Correspondence, source: Shape, target: Shape, fine: _Fine,
               source_spectrum: Any = None, target_spectrum: Any = None) -> Correspondence:
        """The final map when ``polish`` is set: the registration's map ``corr``, the side reference's and the fine
        functional map's, each polished by ZoomOut from 20 to ``polish`` Laplace-Beltrami eigenfunctions (5 at a
        time; the caller's landmarks kept), the one of least ZoomOut residual in the first ``RESIDUAL_K`` (at most
        ``polish``) kept -- best-of's rule on the maps this stage already has (glued contacts mislead the
        registration and the reference in different places). The residual cannot tell a map from its mirror image
        (an intrinsic symmetry is as smooth as the identity), and the side was decided above: a candidate other
        than the registration's map competes only if it keeps the side (:meth:`score` > 0, the rescue's rule).
        ``corr``'s confidence and posteriors are kept and describe the registration's map before the polish
        (``posteriors_of``); ``info["orientation_polish"]``: the residuals, the scores and the choice."""
        from shape_toolkit.plugins.matching.orientation import RESIDUAL_K, side_reference

        ref = side_reference(source, target, source_spectrum, target_spectrum, self.orientation,
                             landmarks=fine.landmarks)
        bs, bt = fine.bases(self.polish)
        rs, rt = fine.bases(min(RESIDUAL_K, self.polish))
        residuals: dict[str, float] = {}
        scores: dict[str, float] = {}
        best: tuple[float, str, np.ndarray] | None = None
        for name, t in (("registration", corr.target_of), ("reference_map", ref.target_of),
                        ("fine_map", fine.target_of[0])):
            t = np.asarray(t)
            if not np.all(t >= 0):  # a partial map has no functional map to polish
                continue
            _, tp = polish_map(t, bs, bt, seeds=fine.landmarks)
            if name != "registration":
                scores[name] = self.score(None, source, target, tp, refined=False)
                if scores[name] <= 0:
                    continue
            residuals[name] = map_residual(rs, rt, tp, rs.k)
            if best is None or residuals[name] < best[0]:
                best = (residuals[name], name, tp)
        if best is None:
            return corr
        info = {**corr.info, "orientation_polish": {"k": bs.k, "residual_k": rs.k, "residuals": residuals,
                                                    "scores": scores, "choice": best[1]}}
        info["posteriors_of"] = "em-before-polish"  # every candidate is polished
        return Correspondence(best[2], corr.n_target, corr.confidence, corr.posteriors, info)
