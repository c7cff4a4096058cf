"""Procedurally generated articulated shapes with exact ground truth (no downloads needed).

A sphere is mapped onto a "body with limbs": each limb is a spherical cap of the sphere that is
smoothly mapped onto a capsule. Because the map is a deformation of one closed sphere, the
result is a closed, connected, manifold triangle mesh. Poses bend each limb at its joint by linear
blend skinning, so every pose keeps the vertex order: the ground-truth map between two poses
is the identity, and limb labels give a ground-truth segmentation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shape_toolkit.core.shape import Shape
from shape_toolkit.data.generate import icosphere
from shape_toolkit.errors import ParameterError

__all__ = ["ArticulatedShape", "articulated_shape", "synthetic_dataset", "procedural_texture", "DEFAULT_LIMBS"]

#: unit directions of the limbs of the default "starfish-humanoid" (two arms, two legs, head)
DEFAULT_LIMBS = np.array(
    [[1.0, 0.25, 0.0], [-1.0, 0.25, 0.0], [0.7, -1.0, 0.0], [-0.7, -1.0, 0.0], [0.0, 1.0, 0.1]]
)


@dataclass(frozen=True)
class ArticulatedShape:
    """A generated shape: the mesh, per-vertex part ``labels`` (0 = body, ``j + 1`` = limb ``j``),
    the bend angles (radians) of the pose and per-vertex RGB ``colors`` ``(n, 3)`` in [0, 1] of a
    procedural texture painted on the rest sphere (:func:`procedural_texture`), so the colours
    move with the surface: vertex ``i`` has the same colour in every pose (the photometric
    consistency of a sequence, thesis 7.2.2). :class:`Shape` has no colour attribute, so they are
    returned alongside."""

    shape: Shape
    labels: np.ndarray
    angles: np.ndarray
    colors: np.ndarray | None = None


def procedural_texture(points: np.ndarray, *, n_waves: int = 6, frequency: float = 4.0,
                       random_state: int = 0) -> np.ndarray:
    """RGB colours ``(n, 3)`` in [0, 1] of ``points`` ``(n, 3)`` (rest-pose coordinates, so the
    texture moves with the surface): per channel, a sum of ``n_waves`` plane waves of random
    directions, frequencies up to ``frequency`` (cycles per unit length) and phases, squashed by
    a logistic; plus a fine checker (period ``1 / frequency``) on the value, so that nearby
    points differ too. Deterministic given ``random_state``."""
    if n_waves < 1 or not frequency > 0:
        raise ParameterError("need n_waves >= 1 and frequency > 0")
    rng = np.random.default_rng(random_state)
    p = np.asarray(points, dtype=np.float64)
    out = np.empty((len(p), 3))
    for c in range(3):
        d = rng.normal(size=(n_waves, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        f = rng.uniform(0.3, 1.0, n_waves) * frequency * 2 * np.pi
        ph = rng.uniform(0, 2 * np.pi, n_waves)
        v = np.sin((p @ d.T) * f + ph).sum(axis=1) / np.sqrt(n_waves)
        out[:, c] = 1.0 / (1.0 + np.exp(-2.0 * v))
    checker = (np.floor(p * frequency * 2).sum(axis=1) % 2) * 0.15
    return np.clip(out * 0.85 + checker[:, None], 0.0, 1.0)


def _perp(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(d, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(d, e1)


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def articulated_shape(
    angles: np.ndarray | list[float] | None = None,
    *,
    subdivisions: int = 4,
    limbs: np.ndarray | None = None,
    cap_angle: float = 0.6,
    limb_length: float = 1.4,
    limb_radius: float = 0.28,
    random_state: int | None = None,
    texture_seed: int = 0,
) -> ArticulatedShape:
    """An articulated mesh with one limb per row of ``limbs`` ``(L, 3)``, bent by ``angles`` ``(L,)``.
    ``colors``: :func:`procedural_texture` of the rest sphere (seed ``texture_seed``), the same
    for every pose.

    ``subdivisions`` sets the resolution (4: 2,562 vertices; 5: 10,242). ``random_state`` draws
    random bend angles in [-1, 1] rad when ``angles`` is None (zero angles when both are None).
    Lengths are in units of the body radius (1).
    """
    limbs = DEFAULT_LIMBS if limbs is None else np.asarray(limbs, dtype=np.float64)
    if limbs.ndim != 2 or limbs.shape[1] != 3 or len(limbs) == 0:
        raise ParameterError(f"limbs must be an (L, 3) array, got shape {limbs.shape}")
    dirs = limbs / np.linalg.norm(limbs, axis=1, keepdims=True)
    if angles is None:
        rng = np.random.default_rng(random_state)
        angles = (
            rng.uniform(-1.0, 1.0, len(dirs)) if random_state is not None else np.zeros(len(dirs))
        )
    angles = np.asarray(angles, dtype=np.float64).ravel()
    if angles.shape != (len(dirs),):
        raise ParameterError(f"angles must have one value per limb ({len(dirs)})")
    if not 0 < cap_angle < 1.2 or limb_length <= 0 or not 0 < limb_radius < np.sin(cap_angle):
        raise ParameterError("need 0 < cap_angle < 1.2, limb_length > 0, limb_radius < sin(cap_angle)")
    cosines = dirs @ dirs.T - 2 * np.eye(len(dirs))
    if np.any(np.arccos(np.clip(cosines, -1, 1)) < 2 * cap_angle):
        raise ParameterError("limbs are too close to each other for this cap_angle")

    sphere = icosphere(subdivisions)
    p = np.array(sphere.vertices)
    out = p.copy()
    labels = np.zeros(len(p), dtype=np.int64)
    rim_h, rim_r = np.cos(cap_angle), np.sin(cap_angle)
    for j, d in enumerate(dirs):
        e1, e2 = _perp(d)
        theta = np.arccos(np.clip(p @ d, -1.0, 1.0))
        inside = np.flatnonzero(theta < cap_angle)
        labels[inside] = j + 1
        u = 1.0 - theta[inside] / cap_angle  # 0 on the rim, 1 at the tip
        psi = np.arctan2(p[inside] @ e2, p[inside] @ e1)
        radial = np.cos(psi)[:, None] * e1 + np.sin(psi)[:, None] * e2
        # profile: neck blend (u < .15), tube (.15 .. .85), hemispherical tip (> .85)
        h = np.empty_like(u)
        r = np.empty_like(u)
        a, b = 0.15, 0.85
        m = u < a
        s = u[m] / a
        h[m] = rim_h + s * 0.15 * limb_length
        r[m] = rim_r + (limb_radius - rim_r) * (3 * s**2 - 2 * s**3)
        m = (u >= a) & (u <= b)
        h[m] = rim_h + 0.15 * limb_length + (u[m] - a) / (b - a) * 0.85 * limb_length
        r[m] = limb_radius
        m = u > b
        phi = (u[m] - b) / (1.0 - b) * (np.pi / 2)
        h[m] = rim_h + limb_length + limb_radius * np.sin(phi)
        r[m] = limb_radius * np.cos(phi)
        out[inside] = h[:, None] * d + r[:, None] * radial
        # bend at the joint (middle of the tube) with a smooth blend over +-0.15 limb lengths
        joint_h = rim_h + 0.55 * limb_length
        R = _rotation(e1, angles[j])
        wgt = np.clip((h - joint_h) / (0.3 * limb_length) + 0.5, 0.0, 1.0)
        wgt = wgt * wgt * (3 - 2 * wgt)
        local = out[inside] - joint_h * d
        bent = local @ R.T + joint_h * d
        out[inside] = (1 - wgt)[:, None] * out[inside] + wgt[:, None] * bent
    colors = procedural_texture(p, random_state=texture_seed)
    return ArticulatedShape(Shape(out, sphere.faces, "articulated"), labels, angles, colors)


def synthetic_dataset(
    n_poses: int = 4,
    *,
    subdivisions: int = 3,
    random_state: int = 0,
    max_angle: float = 1.0,
) -> list[ArticulatedShape]:
    """``n_poses`` poses of the same articulated shape (same vertices, faces and labels order):
    pose 0 is the rest pose, pose i > 0 bends every joint by an angle drawn uniformly in
    ``[-max_angle, max_angle]`` rad from ``random_state``. The ground-truth map between any two
    poses is the identity; ``labels`` are the parts (0 body, 1..5 limbs)."""
    if not isinstance(n_poses, (int, np.integer)) or n_poses < 1:
        raise ParameterError(f"n_poses must be a positive integer, got {n_poses!r}")
    if not 0 <= max_angle <= 2.5:
        raise ParameterError(f"max_angle must be in [0, 2.5] rad, got {max_angle}")
    rng = np.random.default_rng(random_state)
    out = []
    for i in range(int(n_poses)):
        n_limbs = len(DEFAULT_LIMBS)
        angles = np.zeros(n_limbs) if i == 0 else rng.uniform(-max_angle, max_angle, n_limbs)
        a = articulated_shape(angles, subdivisions=subdivisions)
        out.append(ArticulatedShape(Shape(a.shape.vertices, a.shape.faces, f"pose{i}"), a.labels, a.angles,
                                    a.colors))
    return out
