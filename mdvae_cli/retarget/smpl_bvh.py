"""An SMPL motion as a BVH file on the SMPL skeleton of its own shape.

The 22 body joints (SMPL's names) with their rest offsets from the body model and the motion's
betas; End Sites at the hands (SMPL's hand joints), the toe tips and the top of the head. Y up
(the axis Blender's and MotionBuilder's BVH importers take as up by default), the body facing
+Z; ZXY rotation channels; the root (pelvis) with position channels. Each joint's BVH rotation is
its SMPL local rotation exactly (every rest frame is the world frame), so importing the file
again gives back the motion.
"""

from __future__ import annotations

import numpy as np
import torch

from mdvae_cli.body.data import NUM_BODY_JOINTS, SMPL_JOINT_NAMES, SMPL_PARENTS
from mdvae_cli.formats.bvh_write import bvh_text
from mdvae_cli.geometry.euler import rotmat_to_euler
from mdvae_cli.geometry.rotations_np import rotvec_to_rotmat
from mdvae_cli.motion.motion import Motion
from mdvae_cli.retarget.fit_shape import BodyJoints

_N = NUM_BODY_JOINTS

#: metres per unit of each ``--units`` choice
UNITS = {"cm": 0.01, "m": 1.0, "mm": 0.001, "in": 0.0254}

#: AMASS z-up world -> BVH y-up world: (x, y, z) -> (x, z, -y)
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])

#: End Site lengths (metres) where the body model has no joint: head top, toe tip
_HEAD_TOP, _TOE = 0.18, 0.05


def continuous_euler(R: np.ndarray, axes: str) -> np.ndarray:
    """Euler angles (radians) of rotations R (T, N, 3, 3), each frame's the exact solution
    nearest the frame before (of the two, ``(a, b, c)`` and ``(a + pi, pi - b, c + pi)``, moved
    by whole turns): a channel moves as its joint does, with no jump of a turn at +-180 degrees
    nor of half turns where a knee bends past 90 degrees, so that curves resampled or edited in
    an animation tool stay the motion.  -> (T, N, 3)

    Worked out on whole arrays (a frame-by-frame loop took 1.0 s of a 10-minute 120 Hz take's
    22 joints): which solution a frame takes depends only on the one before's, through the
    angles' distances modulo a turn, so each frame's choice is a map of the one before
    (:func:`_chain_choices`); each channel's whole turns are then the running sum of its
    frame-to-frame ones."""
    one = rotmat_to_euler(R, axes)
    two = one * np.array([1.0, -1.0, 1.0]) + np.array([np.pi, np.pi, np.pi])
    if len(R) < 2:
        return one

    def nearer_two(prev: np.ndarray) -> np.ndarray:  # frames 1.. take two after prev (T-1, N)
        return _turn_distance(two[1:], prev) < _turn_distance(one[1:], prev)

    picked = _chain_choices(nearer_two(one[:-1]), nearer_two(two[:-1]))
    x = np.where(picked[..., None], two, one)
    turns = np.zeros(x.shape)
    turns[1:] = np.cumsum(np.round((x[:-1] - x[1:]) / (2 * np.pi)), axis=0)
    return x + 2 * np.pi * turns


def _turn_distance(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Sum over the last axis of each angle's distance from y's modulo a whole turn.
    (..., 3) -> (...)"""
    return np.abs(x - y - 2 * np.pi * np.round((x - y) / (2 * np.pi))).sum(-1)


def _chain_choices(after_one: np.ndarray, after_two: np.ndarray) -> np.ndarray:
    """Which of two choices each frame takes, the first frame the first, when frame t's is
    ``after_one[t - 1]`` after a first and ``after_two[t - 1]`` after a second (bool (T - 1,
    ...) each): a map of the choice before that keeps it, flips it or sets it; a frame that
    sets it starts a run whose choices are that one flipped by the flips since.
    -> (T, ...) bool"""
    follows = after_one != after_two  # keeps (after_one False) or flips (True) the one before
    flip = after_one & follows
    sets = np.concatenate([np.ones_like(follows[:1]), ~follows])  # frame 0 sets "first"
    value = np.concatenate([np.zeros_like(after_one[:1]), after_one])
    flips = np.concatenate([np.zeros_like(flip[:1]), flip]).cumsum(axis=0)
    t = np.arange(len(sets)).reshape((-1,) + (1,) * (sets.ndim - 1))
    start = np.maximum.accumulate(np.where(sets, t, 0), axis=0)  # the last frame that set it
    at = np.take_along_axis
    return at(value, start, 0) ^ ((flips - at(flips, start, 0)) % 2).astype(bool)


def smpl_bvh(motion: Motion, body: BodyJoints, units: str = "cm", order: str = "ZXY") -> str:
    """The BVH text of ``motion`` (AMASS layout, z up) on the body's skeleton for its betas.

    units: one of UNITS. order: the rotation channel order (first listed outermost).
    """
    scale = UNITS[units]
    betas = torch.as_tensor(np.asarray(motion.betas, dtype=np.float64))
    nb = min(len(betas), body.num_betas)
    full = torch.zeros(body.num_betas, dtype=torch.float64)
    full[:nb] = betas[:nb]
    X = body.rest_joints(full).numpy()
    parents = [int(p) for p in SMPL_PARENTS[:_N]]
    offsets = np.zeros((_N, 3))
    offsets[1:] = X[1:_N] - X[[parents[j] for j in range(1, _N)]]
    ends = {15: np.array([0.0, _HEAD_TOP, 0.0]), 10: np.array([0.0, 0.0, _TOE]),
            11: np.array([0.0, 0.0, _TOE])}  # fmt: skip
    for wrist, hand in ((20, 22), (21, 23)):
        if len(X) > hand:
            ends[wrist] = X[hand] - X[wrist]
        else:
            d = X[wrist] - X[wrist - 2]
            ends[wrist] = d / np.linalg.norm(d) * 0.08
    T = motion.num_frames
    body_pose = np.reshape(motion.pose_body, (T, -1, 3))[:, : _N - 1]
    pose = np.concatenate([np.reshape(motion.root_orient, (T, 1, 3)), body_pose], axis=1)
    L = rotvec_to_rotmat(pose)
    L[:, 0] = Z_UP_TO_Y_UP @ L[:, 0]
    root = (np.asarray(motion.trans, dtype=np.float64) + X[0]) @ Z_UP_TO_Y_UP.T
    angles = np.rad2deg(continuous_euler(L, order.lower())).reshape(T, 3 * _N)
    data = np.concatenate([root / scale, angles], axis=1)
    ends = {j: v / scale for j, v in ends.items()}
    return bvh_text(list(SMPL_JOINT_NAMES[:_N]), parents, offsets / scale, ends, data,
                    1.0 / motion.fps, order=order.upper())  # fmt: skip
