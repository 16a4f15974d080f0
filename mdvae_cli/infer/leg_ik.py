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
from mdvae_cli.motion.contacts import foot_vertex_ids
from mdvae_cli.motion.motion import Motion

#: per leg (left, right): hip, knee, ankle, ball-of-foot joints (SMPL indices)
LEGS = ((1, 4, 7, 10), (2, 5, 8, 11))
#: foot vertices up to this far above the foot's lowest one at rest (m) make its sole: a foot's
#: lowest point is among them unless it is pitched far (on 3,600 noisy and denoised frames the
#: lowest point moved by over 1 mm in 0.8 % of frames with a 2 cm band)
SOLE_BAND = 0.03
#: how far (rad) a knee may bend backward of straight before IK prefers the other solution
HYPEREXTENSION = 0.05


def rotvec_to_rotmat_np(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues' formula in numpy.  (..., 3) -> (..., 3, 3)"""
    theta = np.linalg.norm(rotvec, axis=-1)[..., None, None]
    small = theta < 1e-8
    k = rotvec / np.where(small[..., 0], 1.0, theta[..., 0])
    K = np.zeros((*rotvec.shape[:-1], 3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -k[..., 2], k[..., 1], -k[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = k[..., 2], -k[..., 1], k[..., 0]
    sin, cos = np.where(small, 0.0, np.sin(theta)), np.where(small, 1.0, np.cos(theta))
    return np.eye(3) + sin * K + (1 - cos) * (K @ K)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product over the last axis (numpy's ``cross`` costs more on small arrays)."""
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx], axis=-1)


def rotmat_to_rotvec_np(R: np.ndarray) -> np.ndarray:
    """Rotation matrices to axis-angles with angles in [0, pi], in numpy, through the
    quaternion (the largest of the four pivots, as ``geometry.rotations.rotmat_to_quat``).
    (..., 3, 3) -> (..., 3)"""
    m = R
    pivots = np.stack(
        [
            1 + m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2],
            1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
            1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2],
            1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2],
        ],
        axis=-1,
    )
    a, b, c = m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]
    d, e, f = m[..., 1, 0] + m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0], m[..., 2, 1] + m[..., 1, 2]
    cand = np.stack(
        [
            np.stack([pivots[..., 0], a, b, c], -1),
            np.stack([a, pivots[..., 1], d, e], -1),
            np.stack([b, d, pivots[..., 2], f], -1),
            np.stack([c, e, f, pivots[..., 3]], -1),
        ],
        axis=-2,
    )  # row k is 4 q_k q
    best = pivots.argmax(-1)
    q = np.take_along_axis(cand, best[..., None, None], -2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[..., :1] < 0, -q, q)
    s = np.linalg.norm(q[..., 1:], axis=-1)
    angle = 2 * np.arctan2(s, q[..., 0])
    scale = np.where(s > 1e-12, angle / np.maximum(s, 1e-12), 2.0)
    return q[..., 1:] * scale[..., None]


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
    return rotvec_to_rotmat_np(motion.pose_body[frames][:, np.asarray(LEGS) - 1])


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


def pose_legs(motion: Motion, model: LegModel) -> tuple[np.ndarray, np.ndarray]:
    """A motion's leg joints and soles.  -> positions (T, 2, 4, 3), soles (T, 2): the height of
    each foot's lowest sole vertex (z-up metres)."""
    root = rotvec_to_rotmat_np(np.asarray(motion.root_orient, dtype=np.float64))
    pos, G = leg_chain(root, leg_rotations(motion), motion.trans + model.pelvis, model.bones)
    return pos, sole_heights(pos, G, model)


def sole_heights(pos: np.ndarray, G: np.ndarray, model: LegModel, chunk: int = 4096) -> np.ndarray:
    """Height of each foot's lowest sole vertex.  pos (B, 2, 4, 3), G (B, 2, 4, 3, 3) -> (B, 2)

    Computed ``chunk`` frames at a time (the vertices of a chunk take chunk x 4 x F floats)."""
    out = np.empty(pos.shape[:2])
    for leg in range(2):
        # z of sum_i w_i (R_i (v - J_i) + o_i) over the joints i
        local = model.soles[leg][None] - model.joints[leg][:, None]  # (4, F, 3)
        weighted = (local * model.weights[leg].T[..., None]).transpose(0, 2, 1)  # (4, 3, F)
        for s in range(0, len(pos), chunk):
            sl = slice(s, s + chunk)
            z = (G[sl, leg, :, 2:3] @ weighted)[:, :, 0].sum(1)  # (b, F)
            out[sl, leg] = (z + pos[sl, leg, :, 2] @ model.weights[leg].T).min(-1)
    return out


def swing(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The smallest rotation turning direction ``u`` into direction ``v``.  (..., 3) x 2 ->
    (..., 3, 3)"""
    axis = cross(u, v)
    sin = np.linalg.norm(axis, axis=-1, keepdims=True)
    angle = np.arctan2(sin, (u * v).sum(-1, keepdims=True))
    return rotvec_to_rotmat_np(axis / np.maximum(sin, 1e-12) * angle)


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


def two_bone_ik(
    root: np.ndarray,
    legs: np.ndarray,
    pelvis: np.ndarray,
    bones: np.ndarray,
    targets: np.ndarray,
    held: np.ndarray,
    flexion: np.ndarray,
) -> np.ndarray:
    """Put ankles and balls of the feet on targets by turning hips, knees and ankles.

    root, legs, pelvis, bones: as :func:`leg_chain`; targets: (B, 2, 2, 3) positions of
    (ankle, ball) per leg; held: (B, 2, 2) bool, which of them have a target; flexion: (B, 2)
    each knee's flexion (rad, the x component of its axis-angle). Closed form, per leg: the knee
    turns about its hinge (its x axis) until the hip-ankle distance is right, the hip turns
    (smallest rotation) to point the leg at the ankle's target, and the ankle turns to point the
    foot at the ball's target, or, with no ball target, to keep the foot's world orientation.
    With only the ball held, the ankle's target is the ankle moved as the ball must move. Out of
    reach, the leg straightens toward the target.
    -> (B, 2, 4, 3, 3) the new local rotations (the ball's own unchanged).
    """
    pos, G = leg_chain(root, legs, pelvis, bones)
    hip, knee, ankle, ball = (pos[:, :, i] for i in range(4))
    hold_ankle, hold_ball = held[..., 0, None], held[..., 1, None]
    moved = np.where(hold_ball, ankle + targets[:, :, 1] - ball, ankle)
    goal = np.where(hold_ankle, targets[:, :, 0], moved)
    n = G[:, :, 1, :, 0]
    phi = knee_turn(knee - hip, ankle - knee, n, np.linalg.norm(goal - hip, axis=-1), flexion)
    x_axis = np.zeros_like(n)
    x_axis[..., 0] = phi
    knee_local = legs[:, :, 1] @ rotvec_to_rotmat_np(x_axis)
    shank = (rotvec_to_rotmat_np(n * phi[..., None]) @ (ankle - knee)[..., None])[..., 0]
    R0 = root[:, None]
    hip_local = R0.swapaxes(-1, -2) @ swing(knee + shank - hip, goal - hip) @ R0 @ legs[:, :, 0]
    knee_world = R0 @ hip_local @ knee_local
    turned = knee_world @ legs[:, :, 2]  # the foot turned with the shank
    aim = swing((turned @ bones[:, 3, :, None])[..., 0], targets[:, :, 1] - goal) @ turned
    foot_world = np.where(hold_ball[..., None], aim, G[:, :, 2])
    ankle_local = knee_world.swapaxes(-1, -2) @ foot_world
    return np.stack([hip_local, knee_local, ankle_local, legs[:, :, 3]], axis=2)


def to_rotvecs(rotmats: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Axis-angles of ``rotmats`` on the branch nearest ``reference`` (angle t or t - 2 pi about
    the same axis), so a track keeps its convention.  (..., 3, 3), (..., 3) -> (..., 3)"""
    rotvec = rotmat_to_rotvec_np(rotmats)
    angle = np.linalg.norm(rotvec, axis=-1, keepdims=True)
    other = rotvec * (1.0 - 2 * math.pi / np.maximum(angle, 1e-12))
    far = np.linalg.norm(other - reference, axis=-1) < np.linalg.norm(rotvec - reference, axis=-1)
    return np.where((far & (angle[..., 0] > 1e-12))[..., None], other, rotvec)
