"""How ``best-of`` reads its candidate maps of one pair beyond their ZoomOut residual.

- :func:`map_ambiguity`: the kept map's rival, a different map of close residual (a report, ``info["ambiguity"]``).
- :func:`preserving_alternative`: when the map of least residual reverses orientation (a mirror image, as a whole
  or on most of it) and a candidate of nearly the same residual does not, that candidate. Two oriented surfaces of
  real objects correspond by an orientation-preserving map, and the residual, intrinsic, cannot see a mirror; the
  orientation verdict (:func:`~shape_toolkit.plugins.matching.orientation.orientation_verdict`) can. "Nearly the same
  residual" is the ambiguity's own ratio (:data:`AMBIGUOUS_RATIO`), so only maps the residual cannot tell apart are
  decided by orientation (``benchmarks/results/rigid_motion_notes.md``).
- :func:`seed_tears`: at how many of the user's seed pairs a map is torn. Most matchers write the seeds into their
  maps, so a map whose own solution disagrees with them still holds them, pasted into a map that sends their
  neighbours elsewhere; ``best-of`` keeps a map torn at half the seeds or more only when every candidate is
  (``seeded_frames_notes.md``, session 44), and ``match --seeds`` warns when its final map is torn at any.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from shape_toolkit.core.shape import Shape
from shape_toolkit.plugins.matching.orientation import orientation_verdict

__all__ = ["map_ambiguity", "map_distance", "preserving_alternative", "seed_tears", "seed_rings", "RIVAL_DISTANCE",
           "AMBIGUOUS_RATIO", "SEED_NEIGHBORS"]

#: ``info["ambiguity"]``: a candidate is a rival of the kept map when its images lie on average at least this far from
#: the kept map's (Euclidean, in sqrt(area) of the target): 7 times a sound FAUST map's error; the FAUST rivals that
#: were the right map or its half turn lay 0.16-0.24 away (tuning half)
RIVAL_DISTANCE = 0.15
#: the pair is reported ambiguous when a rival's residual is within this factor of the kept map's; a report, not a
#: choice (``auto_mirrored_notes.md``, session 33: on the tuning half most kept maps so flagged were wrong)
AMBIGUOUS_RATIO = 1.1
#: :func:`seed_tears`: the source points nearest each seed whose images show whether a map is continuous there
SEED_NEIGHBORS = 8


def map_distance(a: np.ndarray, b: np.ndarray, target: Shape, mass: np.ndarray, area: float) -> float:
    """How far apart two maps ``a``, ``b`` ``(n_s,)`` of one source into ``target`` send the source: the mean distance
    between the two images of each source vertex matched by both (Euclidean, weights ``mass`` ``(n_s,)``), over
    sqrt(``area``) of the target (unitless); 0.0 when no vertex is matched by both."""
    X = np.asarray(target.vertices, dtype=np.float64)
    a, b = np.asarray(a), np.asarray(b)
    ok = (a >= 0) & (b >= 0)
    if not ok.any():
        return 0.0
    w = mass[ok] / max(float(mass[ok].sum()), 1e-300)
    return float(w @ np.linalg.norm(X[a[ok]] - X[b[ok]], axis=1) / np.sqrt(area))


def map_ambiguity(candidates: list[dict[str, Any]], maps: list[np.ndarray], kept: str, target: Shape,
                  mass: np.ndarray, area: float, excluded: frozenset[str] = frozenset()) -> dict[str, Any]:
    """How far each candidate's map ``(n_s,)`` lies from the kept one's (``candidates[i]["disagreement"]``, set here:
    :func:`map_distance`), and the rival of least residual among those at least :data:`RIVAL_DISTANCE` away:
    ``{"rival", "residual_ratio", "disagreement", "ambiguous"}``, ambiguous when its residual is within
    :data:`AMBIGUOUS_RATIO` of the kept map's (two different maps explain the pair about as well: a half turn or a
    swapped part may have been kept). The candidates named in ``excluded`` are no rivals (maps the user's seeds
    contradict: the seeds decided against them)."""
    i = next(j for j, c in enumerate(candidates) if c["matcher"] == kept)
    for c, T in zip(candidates, maps):
        c["disagreement"] = map_distance(T, maps[i], target, mass, area)
    rivals = [c for c in candidates if c["disagreement"] >= RIVAL_DISTANCE and c["matcher"] not in excluded]
    if not rivals:
        return {"rival": None, "ambiguous": False}
    r = min(rivals, key=lambda c: c["residual"])
    ratio = r["residual"] / max(candidates[i]["residual"], 1e-300)
    return {"rival": r["matcher"], "residual_ratio": ratio, "disagreement": r["disagreement"],
            "ambiguous": bool(ratio <= AMBIGUOUS_RATIO)}


def seed_rings(source: Shape, seeds: np.ndarray) -> np.ndarray:
    """The :data:`SEED_NEIGHBORS` source vertices nearest each seed's source vertex (itself left out): int64
    ``(q, k)``, what :func:`seed_tears` looks at; they depend on the source and the seeds only, so a caller judging
    several maps of one pair computes them once."""
    from scipy.spatial import cKDTree

    sd = np.asarray(seeds, dtype=np.int64).reshape(-1, 2)
    X = np.asarray(source.vertices, dtype=np.float64)
    k = int(min(SEED_NEIGHBORS + 1, len(X)))
    if not len(sd):
        return np.zeros((0, k - 1), dtype=np.int64)
    return np.asarray(cKDTree(X).query(X[sd[:, 0]], k)[1], dtype=np.int64).reshape(len(sd), k)[:, 1:]


def seed_tears(source: Shape, target: Shape, target_of: np.ndarray, seeds: np.ndarray, area: float,
               rings: np.ndarray | None = None) -> int:
    """At how many of the seed pairs ``seeds`` ``(q, 2)`` (source vertex, target vertex) the map ``target_of``
    ``(n_s,)`` goes elsewhere: the :data:`SEED_NEIGHBORS` source points nearest the seed's source are sent, at the
    median, at least :data:`RIVAL_DISTANCE` sqrt(``area``) of the target from the seed's target (Euclidean): there the
    map is another map than the seed's (the distance at which two maps are rivals). A map that agrees with a seed sends
    its neighbours next to it, however the shapes differ; a map that holds the seed only because it was written into
    it sends them where the map itself goes. Unmatched neighbours (``-1``) do not count; a seed none of whose
    neighbours is matched does not either. ``rings``: :func:`seed_rings` of the source and seeds, if computed."""
    sd = np.asarray(seeds, dtype=np.int64).reshape(-1, 2)
    if not len(sd):
        return 0
    t = np.asarray(target_of)
    Y = np.asarray(target.vertices, dtype=np.float64)
    nb = seed_rings(source, sd) if rings is None else rings
    reach = RIVAL_DISTANCE * np.sqrt(area)
    torn = 0
    for j, ring in zip(sd[:, 1], nb):
        ring = ring[t[ring] >= 0]
        if len(ring):
            torn += bool(np.median(np.linalg.norm(Y[t[ring]] - Y[j], axis=1)) >= reach)
    return int(torn)


def preserving_alternative(source: Shape, target: Shape, candidates: list[dict[str, Any]], maps: list[np.ndarray],
                           kept: str) -> dict[str, Any] | None:
    """When the kept candidate's map ``(n_s,)`` reverses orientation (verdict ``reversing``) and another candidate's,
    of residual within :data:`AMBIGUOUS_RATIO` of it, does not: the least residual such candidate, as
    ``{"from", "to", "residual_ratio", "z_from", "verdict_to", "z_to"}``; None otherwise (the kept map does not
    reverse, or every close candidate does too)."""
    i = next(j for j, c in enumerate(candidates) if c["matcher"] == kept)
    v = orientation_verdict(source, target, maps[i])
    if v["verdict"] != "reversing":
        return None
    r0 = max(candidates[i]["residual"], 1e-300)
    close = sorted((j for j, c in enumerate(candidates)
                    if j != i and np.all(maps[j] >= 0) and c["residual"] <= AMBIGUOUS_RATIO * r0),
                   key=lambda j: candidates[j]["residual"])
    for j in close:
        w = orientation_verdict(source, target, maps[j])
        if w["verdict"] != "reversing":
            return {"from": kept, "to": candidates[j]["matcher"], "residual_ratio": candidates[j]["residual"] / r0,
                    "z_from": v["z"], "verdict_to": w["verdict"], "z_to": w["z"]}
    return None
