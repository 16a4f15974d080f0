"""The legs alone: forward kinematics, foot soles and a closed-form IK, for foot locking.

Only what moves a foot is computed: the pelvis (root rotation and translation), then per leg the
hip, knee, ankle and ball-of-foot joints (SMPL 1/2, 4/5, 7/8, 10/11), and the foot's sole
vertices by linear blend skinning over those joints (no pose-corrective shapes: they move a
sole by well under a millimetre). A :class:`LegModel` holds the rest geometry of one body
shape. Pure numpy, float64, batched over frames B: the arrays are small, and numpy's per-call
cost is a fraction of torch's, which is what a 60-frame clip's time is made of.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mdvae_cli.body.data import NUM_BODY_JOINTS
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.geometry.rotations_np import (
    cross,
    rotmat_between,
    rotmat_to_rotvec,
    rotvec_to_rotmat,
)
from mdvae_cli.motion.contacts import FOOT_SIDE, foot_vertex_ids
from mdvae_cli.motion.motion import Motion
from mdvae_cli.workers import map_in_order

#: per leg (left, right): hip, knee, ankle, ball-of-foot joints (SMPL indices)
LEGS = ((1, 4, 7, 10), (2, 5, 8, 11))
#: foot vertices up to this far above the foot's lowest one at rest (m) make its sole: a foot's
#: lowest point is among them unless it is pitched far (on 3,600 noisy and denoised frames the
#: lowest point moved by over 1 mm in 0.8 % of frames with a 2 cm band)
SOLE_BAND = 0.03
#: how far (rad) a knee may bend backward of straight before IK prefers the other solution
HYPEREXTENSION = 0.05
#: frames posed at once (bounded memory on long takes: a chunk's rotations take ~10 MB)
CHUNK_FRAMES = 8192


@dataclass(frozen=True)
class LegModel:
    """Rest geometry of the legs of one body shape.

    pelvis: (3,) rest pelvis joint; bones: (2, 4, 3) rest offsets pelvis->hip, hip->knee,
    knee->ankle, ankle->ball per leg; joints: (2, 4, 3) rest positions of those four joints;
    soles: per leg, the rest sole vertices (F, 3); weights: per leg, their skinning weights over
    the leg's four joints (F, 4), rows summing to 1.
    """

    pelvis: np.ndarray
    bones: np.ndarray
    joints: np.ndarray
    soles: tuple[np.ndarray, np.ndarray]
    weights: tuple[np.ndarray, np.ndarray]

    @staticmethod
    def build(body: BodyModel, betas: np.ndarray) -> LegModel:
        """The legs of ``body`` with shape ``betas`` (any length, padded or cut)."""
        S = body.num_betas
        b = np.zeros(S)
        given = np.asarray(betas, dtype=np.float64).reshape(-1)[:S]
        b[: len(given)] = given  # padded or cut, as the body model does
        data = body.data
        # the body model's joint regressor applied to the template and shape directions
        J = body.J_template.numpy().astype(np.float64) + body.J_shapedirs.numpy() @ b
        chains = np.asarray(LEGS)
        parents = np.asarray(body.parents[:NUM_BODY_JOINTS])
        soles, weights = [], []
        for leg, ids in enumerate(foot_vertex_ids(data.weights)):
            ids = ids[data.v_template[ids, 1] <= data.v_template[ids, 1].min() + SOLE_BAND]
            soles.append(data.v_template[ids] + data.shapedirs[ids] @ b)
            w = np.asarray(data.weights)[ids][:, chains[leg]]
            weights.append(w / w.sum(1, keepdims=True))
        return LegModel(
            pelvis=J[0],
            bones=J[chains] - J[parents[chains]],
            joints=J[chains],
            soles=(soles[0], soles[1]),
            weights=(weights[0], weights[1]),
        )


def leg_rotations(motion: Motion, frames: np.ndarray | slice = slice(None)) -> np.ndarray:
    """Local rotations of hip, knee, ankle, ball per leg.  -> (B, 2, 4, 3, 3)"""
    return rotvec_to_rotmat(motion.pose_body[frames][:, np.asarray(LEGS) - 1])


def leg_chain(
    root: np.ndarray, legs: np.ndarray, pelvis: np.ndarray, bones: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Forward kinematics of the two legs.

    root: (B, 3, 3) world rotation of the pelvis; legs: (B, 2, 4, 3, 3) local rotations of
    hip, knee, ankle, ball per leg (left, right); pelvis: (B, 3) world position of the pelvis
    joint; bones: (2, 4, 3) as in :class:`LegModel`.
    -> positions (B, 2, 4, 3) and world rotations (B, 2, 4, 3, 3) of hip, knee, ankle, ball.
    """
    B = root.shape[0]
    pos = np.empty((B, 2, 4, 3))
    rot = np.empty((B, 2, 4, 3, 3))
    G = np.broadcast_to(root[:, None], (B, 2, 3, 3))
    o = np.broadcast_to(pelvis[:, None], (B, 2, 3))
    for i in range(4):
        o = o + (G @ bones[:, i, :, None])[..., 0]
        G = G @ legs[:, :, i]
        pos[:, :, i], rot[:, :, i] = o, G
    return pos, rot


def pose_legs(
    motion: Motion, model: LegModel, soles: bool = True, chunk: int = CHUNK_FRAMES
) -> tuple[np.ndarray, np.ndarray | None]:
    """A motion's leg joints and soles, ``chunk`` frames at a time (memory stays flat on long
    takes).  -> positions (T, 2, 4, 3), soles (T, 2): the height of each foot's lowest sole
    vertex (z-up metres), or None with ``soles=False``."""
    T = motion.num_frames
    pos = np.empty((T, 2, 4, 3))
    low = np.empty((T, 2)) if soles else None

    def one(s: int) -> None:  # each chunk writes its own rows: the chunks side by side
        sl = slice(s, min(s + chunk, T))
        root = rotvec_to_rotmat(np.asarray(motion.root_orient[sl], dtype=np.float64))
        pelvis = motion.trans[sl] + model.pelvis
        pos[sl], G = leg_chain(root, leg_rotations(motion, sl), pelvis, model.bones)
        if low is not None:
            low[sl] = sole_heights(pos[sl], G, model)

    for _ in map_in_order(one, range(0, T, chunk)):
        pass
    return pos, low


def sole_heights(pos: np.ndarray, G: np.ndarray, model: LegModel) -> np.ndarray:
    """Height of each foot's lowest sole vertex.  pos (B, 2, 4, 3), G (B, 2, 4, 3, 3) -> (B, 2)

    Only the joints that skin the sole (ankle and ball on SMPL bodies) are used; call it on
    chunks of frames (the vertices of B frames take B x F floats per joint)."""
    out = np.empty(pos.shape[:2])
    for leg in range(2):
        w = model.weights[leg]
        used = np.flatnonzero(w.any(0))
        # z of sum_i w_i (R_i (v - J_i) + o_i) over the joints i that skin the sole
        local = model.soles[leg][None] - model.joints[leg][used][:, None]  # (U, F, 3)
        weighted = (local * w[:, used].T[..., None]).transpose(0, 2, 1)  # (U, 3, F)
        z = G[:, leg, used, 2].reshape(len(G), -1) @ weighted.reshape(-1, weighted.shape[-1])
        out[:, leg] = (z + pos[:, leg, used, 2] @ w[:, used].T).min(-1)
    return out


def knee_turn(
    q: np.ndarray, p: np.ndarray, n: np.ndarray, reach: np.ndarray, flexion: np.ndarray
) -> np.ndarray:
    """The angle to turn a knee about its hinge so that the ankle is ``reach`` from the hip.

    q: (..., 3) hip -> knee; p: (..., 3) knee -> ankle; n: (..., 3) the hinge axis (unit, the
    knee's x axis in the world); reach: (...,) the wanted hip-ankle distance; flexion: (...,)
    the knee's current flexion (rad). Turning p by phi about n gives |q + R(phi) p|^2 =
    |q|^2 + |p|^2 + 2 (A + B cos phi + D sin phi); of the two solutions, the smaller turn that
    does not bend the knee backward past straight; out of reach, the nearest distance.
    -> phi (...,)
    """
    along = (p * n).sum(-1, keepdims=True) * n
    perp = p - along
    A = (q * along).sum(-1)
    B = (q * perp).sum(-1)
    D = (q * cross(n, perp)).sum(-1)
    E = 0.5 * (reach**2 - (q * q).sum(-1) - (p * p).sum(-1)) - A
    R = np.maximum(np.sqrt(B * B + D * D), 1e-12)
    base = np.arctan2(D, B)
    spread = np.arccos(np.clip(E / R, -1.0, 1.0))
    phi = np.stack([base + spread, base - spread], axis=-1)
    phi = np.remainder(phi + math.pi, 2 * math.pi) - math.pi
    cost = np.abs(phi) + 10.0 * (flexion[..., None] + phi < -HYPEREXTENSION)
    return np.take_along_axis(phi, cost.argmin(-1)[..., None], -1)[..., 0]


def turn_about(v: np.ndarray, n: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """``v`` turned by ``phi`` about the unit axis ``n`` (Rodrigues).  (..., 3), (..., 3),
    (...,) -> (..., 3)"""
    cos, sin = np.cos(phi)[..., None], np.sin(phi)[..., None]
    return v * cos + cross(n, v) * sin + n * ((n * v).sum(-1, keepdims=True) * (1 - cos))


def on_sphere(rel: np.ndarray, radius: np.ndarray, limit: float = math.inf) -> np.ndarray:
    """The point at ``radius`` from the origin nearest ``rel`` in the horizontal (z-up): its
    horizontal place kept and its height moved, on the side of the horizontal plane that
    ``rel`` is on; where the sphere does not reach that far out (or the move would be more
    than ``limit`` times the radial one), the point on the ray to ``rel`` instead.
    rel (..., 3), radius (...,) -> (..., 3)"""
    dist = np.linalg.norm(rel, axis=-1)
    radial = rel * (radius / np.maximum(dist, 1e-12))[..., None]
    out2 = rel[..., 0] ** 2 + rel[..., 1] ** 2
    z = np.copysign(np.sqrt(np.maximum(radius**2 - out2, 0.0)), rel[..., 2])
    level = np.concatenate([rel[..., :2], z[..., None]], axis=-1)
    ok = out2 < radius**2
    if math.isfinite(limit):
        ok &= np.abs(z - rel[..., 2]) <= limit * np.abs(dist - radius) + 1e-9
    return np.where(ok[..., None], level, radial)


def swing_ik(
    root: np.ndarray,
    legs: np.ndarray,
    pelvis: np.ndarray,
    bones: np.ndarray,
    targets: np.ndarray,
    held: np.ndarray,
    flexion: np.ndarray,
    stiffness: float | np.ndarray,
    bend_stiffness: float | np.ndarray = 0.0,
) -> np.ndarray:
    """Put ankles and balls of the feet on targets by swinging each leg about its hip, its
    knee bent as it was unless a target is off the reach that bend gives.

    root, legs, pelvis, bones: as :func:`leg_chain`; targets: (B, 2, 2, 3) positions of
    (ankle, ball) per leg; held: (B, 2, 2) bool, which of them have a target (with only the
    ball held, the ankle's target is the ankle moved as the ball must move); flexion: (B, 2)
    each knee's flexion (rad, the x component of its axis-angle); stiffness (m/rad):
    how far an ankle may miss a target further than the leg reaches rather than straighten the
    knee by one radian; bend_stiffness: the same for a target nearer than that (0: the knee
    bends as far as the target needs, as a foot under the floor is lifted); both floats or
    (B, 2) arrays. Per leg,
    closed form: the knee turns about its hinge by the damped least-squares step on
    (hip-ankle distance - target distance)^2 + (stiffness x turn)^2, linearised at the knee as
    it is, and never further than the turn that reaches the target exactly (the larger the
    slope of reach against bend, the larger the share of the miss the knee takes: a bent knee
    follows most of it, a nearly straight one hardly turns and is never pulled straight). The
    hip then turns (smallest rotation) to point the leg at the ankle's target, kept at its
    horizontal place where the leg's reach allows (the miss goes to the height). The foot
    turns with the hip's swing, not with the knee's (a turn on a planted foot is the motion's
    own: aiming the foot at the ball's target twisted ankles by up to 138 degrees); with both
    joints held, the ankle's goal is the midpoint of its own target and the one the ball's
    target gives the foot as it is.
    -> (B, 2, 4, 3, 3) the new local rotations (the ball's own unchanged).
    """
    pos, G = leg_chain(root, legs, pelvis, bones)
    hip, knee, ankle, ball = (pos[:, :, i] for i in range(4))
    hold_ankle, hold_ball = held[..., 0, None], held[..., 1, None]
    moved = np.where(hold_ball, ankle + targets[:, :, 1] - ball, ankle)
    own = np.where(hold_ball, 0.5 * (targets[:, :, 0] + moved), targets[:, :, 0])
    goal = np.where(hold_ankle, own, moved)
    n = G[:, :, 1, :, 0]
    thigh, shank = knee - hip, ankle - knee
    reach = np.linalg.norm(goal - hip, axis=-1)
    exact = knee_turn(thigh, shank, n, reach, flexion)
    leg = ankle - hip
    now = np.linalg.norm(leg, axis=-1)
    slope = (leg * cross(n, shank)).sum(-1) / np.maximum(now, 1e-12)  # d reach / d turn
    cost = np.where(reach > now, stiffness, bend_stiffness)
    step = (reach - now) * slope / np.maximum(slope**2 + cost**2, 1e-12)
    phi = np.where(cost > 0, np.clip(step, np.minimum(exact, 0.0), np.maximum(exact, 0.0)), exact)
    x_axis = np.zeros_like(n)
    x_axis[..., 0] = phi
    knee_local = legs[:, :, 1] @ rotvec_to_rotmat(x_axis)
    turned_leg = thigh + turn_about(shank, n, phi)
    aim_at = on_sphere(goal - hip, np.linalg.norm(turned_leg, axis=-1), limit=2.0)
    R0 = root[:, None]
    swing = rotmat_between(turned_leg, aim_at)  # the leg's turn about the hip, in the world
    hip_local = R0.swapaxes(-1, -2) @ swing @ R0 @ legs[:, :, 0]
    knee_world = R0 @ hip_local @ knee_local
    ankle_local = knee_world.swapaxes(-1, -2) @ swing @ G[:, :, 2]
    return np.stack([hip_local, knee_local, ankle_local, legs[:, :, 3]], axis=2)


def to_rotvecs(rotmats: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Axis-angles of ``rotmats`` on the branch nearest ``reference`` (angle t or t - 2 pi about
    the same axis), so a track keeps its convention.  (..., 3, 3), (..., 3) -> (..., 3)"""
    rotvec = rotmat_to_rotvec(rotmats)
    angle = np.linalg.norm(rotvec, axis=-1, keepdims=True)
    other = rotvec * (1.0 - 2 * math.pi / np.maximum(angle, 1e-12))
    far = np.linalg.norm(other - reference, axis=-1) < np.linalg.norm(rotvec - reference, axis=-1)
    return np.where((far & (angle[..., 0] > 1e-12))[..., None], other, rotvec)


def feet_of(pos: np.ndarray) -> np.ndarray:
    """Leg positions (T, 2, 4, 3) -> the foot joints (T, 4, 3) in ``FOOT_JOINTS`` order."""
    return pos[:, :, 2:].transpose(0, 2, 1, 3).reshape(-1, 4, 3)


def solve_legs(
    motion: Motion,
    model: LegModel,
    frames: np.ndarray,
    targets: np.ndarray,
    held: np.ndarray,
    sunk: np.ndarray,
    stiffness: tuple[float, float],
    rotvecs: bool,
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """:func:`swing_ik` on ``frames`` of ``motion``, ``CHUNK_FRAMES`` at a time (the foot
    lock's legs, ``infer.feet``).

    targets: (B, 2, 2, 3), held: (B, 2, 2) bool, per leg (ankle, ball); sunk: (B, 2) bool, legs
    whose foot is deeper than ``sunk_tol`` under the floor (their knees bend as far as needed);
    stiffness: (knee_stiffness, bend_stiffness) of :func:`swing_ik`.
    -> with ``rotvecs`` (the last pass): (None, the new hip, knee and ankle axis-angles
    (B, 2, 3, 3) on the branch of the motion's own); else (the foot joints' heights above their
    soles as posed after it (B, 4), None), for the next pass."""
    B = len(frames)
    clearance = None if rotvecs else np.empty((B, 4))
    out = np.empty((B, 2, 3, 3)) if rotvecs else None
    rows = np.asarray(LEGS)[:, :3] - 1  # pose_body rows of hip, knee, ankle per leg

    def one(s: int) -> None:  # each chunk writes its own rows: the chunks side by side
        sl = slice(s, min(s + CHUNK_FRAMES, B))
        f = frames[sl]
        root = rotvec_to_rotmat(np.asarray(motion.root_orient[f], dtype=np.float64))
        pelvis = motion.trans[f] + model.pelvis
        legs = leg_rotations(motion, f)
        flexion = motion.pose_body[f][:, rows[:, 1], 0]
        new = swing_ik(root, legs, pelvis, model.bones, targets[sl], held[sl], flexion,
                       stiffness[0], np.where(sunk[sl], 0.0, stiffness[1]))  # fmt: skip
        if out is not None:
            out[sl] = to_rotvecs(new[:, :, :3], motion.pose_body[f][:, rows])
        else:
            pos, G = leg_chain(root, new, pelvis, model.bones)
            clearance[sl] = feet_of(pos)[..., 2] - sole_heights(pos, G, model)[:, list(FOOT_SIDE)]

    for _ in map_in_order(one, range(0, B, CHUNK_FRAMES)):
        pass
    return clearance, out
