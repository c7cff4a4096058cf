"""Procedurally generated articulated shapes with exact ground truth (no downloads needed).

A sphere is mapped onto a "body with limbs": each limb is a spherical cap of the sphere that is
smoothly mapped onto a capsule. Because the map is a deformation of one closed sphere, the
result is a closed, connected, manifold triangle mesh. Poses bend each limb at its joint by linear
blend skinning, so every pose keeps the vertex order: the ground-truth map between two poses
is the identity, and limb labels give a ground-truth segmentation. :func:`pose_sequence` makes a
smoothly moving sequence of such poses, with the feet glued together in chosen frames (thesis
7.5.3) and the ground truth carried through.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from shape_toolkit.core.cache import LRUCache
from shape_toolkit.core.geometry import edge_components
from shape_toolkit.core.shape import Shape
from shape_toolkit.data.generate import icosphere
from shape_toolkit.errors import ParameterError
from shape_toolkit.validation import shown_value

__all__ = [
    "cached_pose_sequence",
    "ArticulatedShape",
    "articulated_shape",
    "synthetic_dataset",
    "procedural_texture",
    "DEFAULT_LIMBS",
    "PoseSequence",
    "pose_sequence",
    "SEQUENCE_LIMB_LENGTHS",
    "MAX_POSES",
    "MAX_FRAMES",
]

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
    limb_length: float | np.ndarray = 1.4,
    limb_radius: float = 0.28,
    random_state: int | None = None,
    texture_seed: int = 0,
    bend_axes: np.ndarray | None = None,
) -> ArticulatedShape:
    """An articulated mesh with one limb per row of ``limbs`` ``(L, 3)``, bent by ``angles`` ``(L,)``.
    ``colors``: :func:`procedural_texture` of the rest sphere (seed ``texture_seed``), the same
    for every pose.

    ``limb_length``: one length for every limb, or one per limb ``(L,)``. ``bend_axes`` ``(L, 3)``:
    the axis each joint turns about (its component along the limb is removed); default a fixed
    perpendicular of the limb (limbs in the xy-plane then bend out of it).

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
    lengths = np.broadcast_to(np.asarray(limb_length, dtype=np.float64), (len(dirs),)) \
        if np.ndim(limb_length) == 0 else np.asarray(limb_length, dtype=np.float64).ravel()
    if lengths.shape != (len(dirs),) or not np.all(np.isfinite(lengths)):
        raise ParameterError(f"limb_length must be a number or one finite length per limb ({len(dirs)})")
    if not 0 < cap_angle < 1.2 or np.any(lengths <= 0) or not 0 < limb_radius < np.sin(cap_angle):
        raise ParameterError("need 0 < cap_angle < 1.2, limb_length > 0, limb_radius < sin(cap_angle)")
    axes = None
    if bend_axes is not None:
        axes = np.asarray(bend_axes, dtype=np.float64)
        if axes.shape != dirs.shape:
            raise ParameterError(f"bend_axes must have shape {dirs.shape}, got {axes.shape}")
        axes = axes - (axes * dirs).sum(axis=1, keepdims=True) * dirs
        norms = np.linalg.norm(axes, axis=1)
        if not np.all(np.isfinite(norms)) or np.any(norms < 1e-9):
            raise ParameterError("every bend axis must be finite and not parallel to its limb")
        axes = axes / norms[:, None]
    cosines = dirs @ dirs.T - 2 * np.eye(len(dirs))
    if np.any(np.arccos(np.clip(cosines, -1, 1)) < 2 * cap_angle):
        raise ParameterError("limbs are too close to each other for this cap_angle")

    sphere = icosphere(subdivisions)
    p = np.array(sphere.vertices)
    out = p.copy()
    labels = np.zeros(len(p), dtype=np.int64)
    rim_h, rim_r = np.cos(cap_angle), np.sin(cap_angle)
    for j, d in enumerate(dirs):
        limb_length = float(lengths[j])
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
        R = _rotation(e1 if axes is None else axes[j], angles[j])
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
    limb_lengths: list[float] | np.ndarray | None = None,
) -> list[ArticulatedShape]:
    """``n_poses`` poses of the same articulated shape (same vertices, faces and labels order):
    pose 0 is the rest pose, pose i > 0 bends every joint by an angle drawn uniformly in
    ``[-max_angle, max_angle]`` rad from ``random_state``. The ground-truth map between any two
    poses is the identity; ``labels`` are the parts (0 body, 1..5 limbs). ``limb_lengths``: one length
    per limb (5; e.g. :data:`SEQUENCE_LIMB_LENGTHS`, so that no two limbs are alike), or None: every limb 1.4
    (five identical limbs, which an intrinsic matcher may permute)."""
    if isinstance(n_poses, bool) or not isinstance(n_poses, (int, np.integer)) or not 1 <= n_poses <= MAX_POSES:
        raise ParameterError(f"n_poses must be an integer in [1, {MAX_POSES}] (every pose is made), got "
                             f"{shown_value(n_poses)}")
    lengths = 1.4 if limb_lengths is None else np.asarray(limb_lengths, dtype=np.float64)
    if limb_lengths is not None and lengths.shape != (len(DEFAULT_LIMBS),):
        raise ParameterError(f"limb_lengths must hold {len(DEFAULT_LIMBS)} lengths, got shape {lengths.shape}")
    if not 0 <= max_angle <= MAX_POSE_ANGLE:
        raise ParameterError(f"max_angle must be in [0, {MAX_POSE_ANGLE}] rad, got {max_angle}")
    rng = np.random.default_rng(random_state)
    out = []
    for i in range(int(n_poses)):
        n_limbs = len(DEFAULT_LIMBS)
        angles = np.zeros(n_limbs) if i == 0 else rng.uniform(-max_angle, max_angle, n_limbs)
        a = articulated_shape(angles, subdivisions=subdivisions, limb_length=lengths)
        out.append(ArticulatedShape(Shape(a.shape.vertices, a.shape.faces, f"pose{i}"), a.labels, a.angles,
                                    a.colors))
    return out


#: distinct limb lengths of :func:`pose_sequence` (right arm, left arm, right leg, left leg, head):
#: identical limbs would make limb swaps as good as the truth for an intrinsic matcher
#: the largest joint angles (rad) of :func:`synthetic_dataset`'s poses and of :func:`pose_sequence`'s frames
MAX_POSE_ANGLE, MAX_SEQUENCE_ANGLE = 2.5, 1.5
#: the most poses of :func:`synthetic_dataset` and frames of :func:`pose_sequence`: both make (and hold) every one
#: of them, so a count is work and memory, not only a length (a thousand frames of 642 vertices: about 0.1 GB)
MAX_POSES, MAX_FRAMES = 1000, 1000
SEQUENCE_LIMB_LENGTHS = np.array([1.4, 1.2, 1.55, 1.35, 0.8])


@dataclass(frozen=True, eq=False)
class PoseSequence:
    """``T`` frames of one articulated shape in motion, with ground truth carried through.

    ``frames``: the shapes a matcher sees (glued in merge frames, remeshed and/or vertices
    shuffled on request), each with its ``Shape.colors``. ``colors``: the same per-frame RGB
    ``(n_t, 3)`` in [0, 1] of the procedural texture, which moves with the surface.
    ``material``: per frame int64 ``(n_t,)``, the material point (vertex of the clean mesh) each
    vertex of the frame is: exact, or the nearest one for a remeshed frame. ``clean``: the
    unglued, unshuffled, not remeshed frames (vertex ``i`` = material point ``i`` in every
    frame), where drift is measured. ``welded``: per frame, the material points welded away by a
    glued contact (empty when not merged). ``labels`` ``(n,)``: part of each material point (0
    body, ``j + 1`` limb ``j``); ``angles`` ``(T, L)`` bend angles (rad); ``contacts``: glued
    contacts per frame (0: not merged)."""

    frames: tuple[Shape, ...]
    colors: tuple[np.ndarray, ...]
    material: tuple[np.ndarray, ...]
    clean: tuple[Shape, ...]
    labels: np.ndarray
    angles: np.ndarray
    contacts: tuple[int, ...]
    welded: tuple[np.ndarray, ...] = ()

    @property
    def n_frames(self) -> int:
        """Number of frames ``T``."""
        return len(self.frames)

    def frame_labels(self, t: int) -> np.ndarray:
        """Part labels ``(n_t,)`` of the vertices of frame ``t``."""
        return self.labels[self.material[t]]

    def truth(self) -> np.ndarray:
        """Ground-truth trajectories: int64 ``(n_0, T)``, the vertex of frame ``t`` that is (or,
        remeshed, stands nearest to) the material point of vertex ``j`` of frame 0. A point
        welded away by a glued contact goes to the vertex standing nearest to it on the clean
        frame (``data.corruptions.invert_vertex_map``; -1 when none is within three mean edge
        lengths of the frame)."""
        from shape_toolkit.data.corruptions import invert_vertex_map

        m0 = self.material[0]
        out = np.empty((m0.size, self.n_frames), dtype=np.int64)
        for t in range(self.n_frames):
            exact = np.unique(self.material[t]).size == self.clean[t].n_vertices
            inv = invert_vertex_map(self.material[t], self.clean[t], resampled=not exact,
                                    max_distance=3.0 * self.frames[t].mean_edge_length)
            out[:, t] = inv[m0]
        return out

    def drift(
        self, trajectories: Any, *, method: str = "dijkstra", radius: float = 0.05, sample: int | None = None
    ) -> dict[str, Any]:
        """Per-frame drift of ``trajectories`` (``Trajectories`` or ids ``(n_0, T)`` on
        :attr:`frames`) against the truth, measured on the clean frames
        (``results.trajectories.trajectory_drift``, units of ``sqrt(area)``). Material points
        welded away in a glued frame have no true vertex there and are left out of that frame.
        On remeshed frames the truth itself drifts by the rounding to the nearest material point
        (about half an edge); ``drift(truth())`` measures that floor."""
        from shape_toolkit.results.trajectories import trajectory_drift

        m0 = self.material[0]
        gone = self.welded or tuple(np.zeros(0, dtype=np.int64) for _ in range(self.n_frames))
        truth = np.stack([np.where(np.isin(m0, g), -1, m0) for g in gone], axis=1)
        return trajectory_drift(trajectories, self.clean, truth, vertex_maps=self.material,
                                method=method, radius=radius, sample=sample)


def _smooth_curves(rng: np.random.RandomState, n_frames: int, n_curves: int, max_angle: float) -> np.ndarray:
    """``(n_frames, n_curves)`` angles: random keys in ``[-max_angle, max_angle]`` every ~3 frames,
    joined by monotone cubic (PCHIP) interpolation, so the motion is smooth and stays in range."""
    from scipy.interpolate import PchipInterpolator

    n_keys = max(2, int(np.ceil((n_frames - 1) / 3)) + 1)
    knots = np.linspace(0.0, n_frames - 1, n_keys)
    keys = rng.uniform(-max_angle, max_angle, size=(n_keys, n_curves))
    return PchipInterpolator(knots, keys, axis=0)(np.arange(n_frames, dtype=np.float64))


def _contact_angle(
    pair: tuple[int, int], dirs: np.ndarray, lengths: np.ndarray, axes: np.ndarray, subdivisions: int
) -> tuple[float, float]:
    """``(angle, gap)``: the bend angle (rad, in [1.2, 2.6]) of both limbs of ``pair`` at which
    their lower halves (beyond the joints) come closest while staying at least 1.3 times as far
    from the body (so the feet touch each other, not the crotch), found by a scan with only
    those joints bent; and that smallest vertex-to-vertex gap (length units)."""
    from scipy.spatial import cKDTree

    rest = articulated_shape(np.zeros(len(dirs)), subdivisions=subdivisions, limbs=dirs,
                             limb_length=lengths, bend_axes=axes)
    lower = []
    for j in pair:
        h = rest.shape.vertices @ dirs[j]
        lower.append(np.flatnonzero((rest.labels == j + 1) & (h > np.cos(0.6) + 0.55 * lengths[j])))
    best, best_gap = 2.0, np.inf
    for a in np.linspace(1.2, 2.6, 29):
        ang = np.zeros(len(dirs))
        ang[list(pair)] = a
        a_shape = articulated_shape(ang, subdivisions=subdivisions, limbs=dirs, limb_length=lengths,
                                    bend_axes=axes)
        v = a_shape.shape.vertices
        gap = float(cKDTree(v[lower[1]]).query(v[lower[0]])[0].min())
        body = cKDTree(v[a_shape.labels == 0])
        to_body = min(float(body.query(v[ids])[0].min()) for ids in lower)
        if gap < best_gap and to_body >= 1.3 * gap:
            best, best_gap = float(a), gap
    return best, best_gap


def pose_sequence(
    n_frames: int = 8,
    *,
    subdivisions: int = 3,
    merge_frames: tuple[int, ...] | list[int] = (),
    max_angle: float = 0.8,
    limb_lengths: np.ndarray | None = None,
    remesh: int | None = None,
    permute: bool = False,
    texture_seed: int = 0,
    random_state: Any = 0,
) -> PoseSequence:
    """A smoothly moving articulated shape whose feet are glued together in ``merge_frames``.

    Every joint follows a smooth curve through random key angles in ``[-max_angle, max_angle]``
    rad (PCHIP, keys every ~3 frames); the legs bend in the body's plane (inwards for positive
    angles), the arms and head out of it. Around each merge frame both knees bend inwards
    (raised-cosine blend over +-2 frames) to the angle where the feet come closest (a scan of
    the pose); in the merge frame itself that contact is welded with ``data.corruptions.glue``
    (one contact of patches of radius ``0.06 sqrt(area)``, about a limb's radius; every vertex a
    candidate; gap at most 1.5 times the closest approach; parts
    more than ``0.3 sqrt(area)`` apart along the surface), as a visual hull fuses touching
    parts. Limbs have distinct lengths (``limb_lengths``, default
    :data:`SEQUENCE_LIMB_LENGTHS`; pass five equal ones for the symmetric body of
    :func:`articulated_shape`). ``remesh`` (a vertex count): every frame is independently
    remeshed (``data.corruptions.remesh``, isotropic, after the gluing), as independently
    reconstructed frames are, and each new vertex stands for its nearest material point.
    ``permute`` shuffles the vertex order of every frame (faces renumbered), so a map must be
    found, not assumed. ``subdivisions`` 3: 642 vertices per
    clean frame, 4: 2,562. All randomness (angles, glue sampling,
    permutations) comes from ``random_state``.
    """
    from shape_toolkit.data.corruptions import glue
    from shape_toolkit.data.corruptions import remesh as remesh_shape
    from shape_toolkit.validation import check_random_state

    if not isinstance(n_frames, (int, np.integer)) or isinstance(n_frames, bool) or not 2 <= n_frames <= MAX_FRAMES:
        raise ParameterError(f"n_frames must be an integer in [2, {MAX_FRAMES}] (every frame is made and kept), got "
                             f"{shown_value(n_frames)}")
    if not 0 <= max_angle <= MAX_SEQUENCE_ANGLE:
        raise ParameterError(f"max_angle must be in [0, {MAX_SEQUENCE_ANGLE}] rad, got {max_angle}")
    merges = sorted({int(m) for m in merge_frames})
    if merges and (merges[0] < 0 or merges[-1] >= n_frames):
        raise ParameterError(f"merge_frames must lie in [0, {n_frames - 1}], got {list(merge_frames)}")
    if remesh is not None and (isinstance(remesh, bool) or not isinstance(remesh, (int, np.integer)) or remesh < 20):
        raise ParameterError(f"remesh must be a vertex count >= 20 or None, got {remesh!r}")
    rng = check_random_state(random_state)
    dirs = DEFAULT_LIMBS / np.linalg.norm(DEFAULT_LIMBS, axis=1, keepdims=True)
    lengths = SEQUENCE_LIMB_LENGTHS if limb_lengths is None else np.asarray(limb_lengths, dtype=np.float64)
    if lengths.shape != (len(dirs),):
        raise ParameterError(f"limb_lengths must hold {len(dirs)} lengths, got shape {lengths.shape}")
    # legs (limbs 2, 3) turn in the body's plane, towards the midline for positive angles
    axes = np.array([np.cross(d, [-np.sign(d[0]), 0.0, 0.0]) if j in (2, 3) else _perp(d)[0]
                     for j, d in enumerate(dirs)])
    angles = _smooth_curves(rng, int(n_frames), len(dirs), max_angle)
    if merges:
        reach = np.zeros(n_frames)
        for m in merges:
            x = np.abs(np.arange(n_frames) - m) / 2.0
            reach = np.maximum(reach, np.where(x < 1, 0.5 * (1 + np.cos(np.pi * x)), 0.0))
        contact, gap = _contact_angle((2, 3), dirs, lengths, axes, subdivisions)
        for j in (2, 3):
            angles[:, j] = (1 - reach) * angles[:, j] + reach * contact
    texture = None
    frames, colors, material, clean, contacts, welded = [], [], [], [], [], []
    labels = None
    for t in range(int(n_frames)):
        a = articulated_shape(angles[t], subdivisions=subdivisions, limbs=dirs, limb_length=lengths,
                              bend_axes=axes, texture_seed=texture_seed)
        if texture is None:
            texture, labels = a.colors, a.labels
        base = Shape(a.shape.vertices, a.shape.faces, f"frame{t:03d}")
        shape, vm = base, np.arange(base.n_vertices, dtype=np.int64)
        n_contacts = 0
        if t in merges:
            limit = 1.5 * gap / np.sqrt(base.area)
            shape, vm = glue(base, strength=1, radius=0.06, min_geodesic=0.3, max_gap=limit, candidates=base.n_vertices,
                             random_state=int(rng.randint(0, 2**31 - 1)))
            shape = Shape(shape.vertices, shape.faces, base.name)
            n_contacts = _count_contacts(base, vm)
        welded.append(np.setdiff1d(np.arange(base.n_vertices), vm))
        if remesh is not None:
            shape, near = remesh_shape(shape, n_vertices=int(remesh), random_state=int(rng.randint(0, 2**31 - 1)))
            shape, vm = Shape(shape.vertices, shape.faces, base.name), vm[near]
        if permute:
            perm = rng.permutation(shape.n_vertices)  # new vertex k is old vertex perm[k]
            inv = np.empty_like(perm)
            inv[perm] = np.arange(perm.size)
            shape = Shape(shape.vertices[perm], inv[shape.faces], shape.name)
            vm = vm[perm]
        frames.append(Shape(shape.vertices, shape.faces, shape.name, texture[vm]))
        material.append(vm.astype(np.int64))
        colors.append(texture[vm])
        clean.append(base)
        contacts.append(n_contacts)
    return PoseSequence(tuple(frames), tuple(colors), tuple(material), tuple(clean), labels, angles,
                        tuple(contacts), tuple(welded))


def _count_contacts(base: Shape, kept: np.ndarray) -> int:
    """Number of welded patches: connected groups (along ``base``'s edges) of removed vertices."""
    gone = np.setdiff1d(np.arange(base.n_vertices), kept)
    if gone.size == 0:
        return 0
    e = base.edges
    sel = np.isin(e[:, 0], gone) & np.isin(e[:, 1], gone)
    pos = np.full(base.n_vertices, -1)
    pos[gone] = np.arange(gone.size)
    return edge_components(gone.size, np.column_stack([pos[e[sel, 0]], pos[e[sel, 1]]]))[0]


#: pose sequences of the last two parameter sets (:func:`cached_pose_sequence`), keyed by the parameters' JSON
POSE_SEQUENCE_CACHE = LRUCache(2, name="pose sequences")


def cached_pose_sequence(params: dict[str, Any]) -> PoseSequence:
    """:func:`pose_sequence` ``(**params)``, kept for the last two parameter sets of this process in
    :data:`POSE_SEQUENCE_CACHE` (a benchmark's methods and its prepare step share one generation of the same
    sequence; the same object is returned)."""
    import json

    def generate() -> PoseSequence:
        prm = dict(params)
        return pose_sequence(prm.pop("n_frames"), **prm)

    return POSE_SEQUENCE_CACHE.get_or_compute(json.dumps(params, sort_keys=True, default=str), generate)
