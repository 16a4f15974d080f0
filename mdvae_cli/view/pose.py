"""Pose a motion's skeleton for drawing: joint positions and world rotations of the 22 body
joints, and the few series (heights, bend angles, rotation angles) the viewer and the figure
plot. Pure numpy/torch; no files."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from mdvae_cli.body.data import NUM_BODY_JOINTS, SMPL_JOINT_NAMES, SMPL_PARENTS
from mdvae_cli.body.skinning import BodyModel, batch_rigid_transform
from mdvae_cli.geometry.rotations import rotvec_to_quat, rotvec_to_rotmat
from mdvae_cli.geometry.rotations_np import quat_continuous
from mdvae_cli.motion.motion import Motion

BODY_JOINT_NAMES = SMPL_JOINT_NAMES[:NUM_BODY_JOINTS]
BODY_PARENTS = SMPL_PARENTS[:NUM_BODY_JOINTS]
#: the joint whose bone out of a joint measures its bend angle (joints with a parent and a
#: child among the 22; the others have no bend angle)
BEND_CHILD: dict[int, int] = {
    1: 4, 2: 5, 3: 6, 4: 7, 5: 8, 6: 9, 7: 10, 8: 11, 9: 12, 12: 15,
    13: 16, 14: 17, 16: 18, 17: 19, 18: 20, 19: 21,
}  # fmt: skip
#: frames posed at once (bounded memory for long takes)
CHUNK_FRAMES = 4096


@dataclass
class PosedSkeleton:
    """A motion's body joints, posed.

    joints: (T, 22, 3) world positions, metres (z-up, as the motion).
    rest_joints: (22, 3) the joints at rest for the motion's shape (no translation).
    """

    joints: np.ndarray
    rest_joints: np.ndarray


def rotation_channels(motion: Motion) -> np.ndarray:
    """The pose as the viewer reads it: the root's world quaternion (w, x, y, z), sign-continuous
    over time, then each body joint's local quaternion as (x, y, z) with w >= 0 implied
    (w = sqrt(1 - x^2 - y^2 - z^2): a joint turns less than 180 degrees from its parent).
    -> (T, 4 + 21 * 3)"""
    rotvecs = motion.joint_rotations
    q = rotvec_to_quat(torch.as_tensor(rotvecs, dtype=torch.float64)).numpy()
    root = quat_continuous(q[:, 0], first_positive=True)
    local = q[:, 1:] * np.where(q[:, 1:, :1] < 0, -1.0, 1.0)
    return np.concatenate([root, local[..., 1:].reshape(len(q), -1)], axis=1)


def pose_skeleton(motion: Motion, body: BodyModel, chunk_frames: int = CHUNK_FRAMES):
    """Pose the 22 body joints of ``motion`` with ``body`` (the joints of
    ``BodyModel.forward``).  -> :class:`PosedSkeleton`"""
    dtype = torch.float64
    betas = body.fit_betas(torch.as_tensor(motion.betas, dtype=dtype)[None])
    J_template = body.J_template[:NUM_BODY_JOINTS].to(dtype)
    J_dirs = body.J_shapedirs[:NUM_BODY_JOINTS].to(dtype)
    rest = J_template + torch.einsum("bk,jck->bjc", betas, J_dirs)[0]
    parents = list(BODY_PARENTS)
    T = motion.num_frames
    joints = np.zeros((T, NUM_BODY_JOINTS, 3))
    for start in range(0, T, chunk_frames):
        sl = slice(start, min(T, start + chunk_frames))
        rotvecs = np.concatenate([motion.root_orient[sl, None], motion.pose_body[sl]], axis=1)
        R = rotvec_to_rotmat(torch.as_tensor(rotvecs, dtype=dtype))
        posed, _ = batch_rigid_transform(R, rest.expand(R.shape[0], -1, -1), parents)
        joints[sl] = (posed + torch.as_tensor(motion.trans[sl], dtype=dtype)[:, None]).numpy()
    return PosedSkeleton(joints=joints, rest_joints=rest.numpy())


def bend_angles(joints: np.ndarray) -> np.ndarray:
    """The angle between the bone into each joint and the bone out of it, degrees (0 = straight;
    a bent knee ~60). NaN for joints without both (pelvis, feet, head, wrists).

    joints: (T, 22, 3) -> (T, 22)
    """
    joints = np.asarray(joints, dtype=np.float64)
    out = np.full(joints.shape[:2], np.nan)
    for j, child in BEND_CHILD.items():
        a = joints[:, j] - joints[:, BODY_PARENTS[j]]
        b = joints[:, child] - joints[:, j]
        lengths = np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1)
        cos = np.sum(a * b, -1) / np.maximum(lengths, 1e-12)
        out[:, j] = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    return out


def rotation_angles(motion: Motion) -> np.ndarray:
    """Each joint's rotation angle relative to its parent (the file's own axis-angle size),
    degrees in [0, 180].  -> (T, 22)"""
    rotvecs = motion.joint_rotations
    angles = np.linalg.norm(rotvecs, axis=-1)
    return np.degrees(np.abs((angles + np.pi) % (2 * np.pi) - np.pi))


#: the series a plot can show: name -> (label, unit)
SERIES = {
    "bend": ("bend angle", "deg"),
    "rotation": ("joint angle", "deg"),
    "height": ("height", "m"),
    "speed": ("speed", "m/s"),
}


def joint_series(kind: str, posed: PosedSkeleton, motion: Motion) -> np.ndarray:
    """One of SERIES for all 22 joints.  -> (T, 22) (NaN where undefined)"""
    from mdvae_cli.motion.contacts import joint_speeds

    if kind == "bend":
        return bend_angles(posed.joints)
    if kind == "rotation":
        return rotation_angles(motion)
    if kind == "height":
        return posed.joints[..., 2].copy()
    if kind == "speed":
        return joint_speeds(posed.joints, motion.fps)
    raise ValueError(f"unknown series {kind!r}; choose one of {', '.join(SERIES)}")
