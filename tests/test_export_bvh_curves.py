"""``mdvae export-bvh`` writes channel curves an animator can edit: each frame's Euler angles
are the exact solution nearest the frame before, so a turning body or a knee bending past 90
degrees moves its channels smoothly (no jump of a turn at +-180 degrees, no half-turn flip of
two channels), and a reader by the BVH spec still poses the same joints."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.geometry.euler import euler_to_rotmat
from mdvae_cli.geometry.rotations_np import rotmat_to_rotvec, rotvec_to_rotmat
from mdvae_cli.motion.motion import slice_frames
from mdvae_cli.retarget.fit_shape import BodyJoints
from mdvae_cli.retarget.smpl_bvh import Z_UP_TO_Y_UP, continuous_euler, smpl_bvh
from mdvae_cli.retarget.way_back import smpl_globals

WALK = Path(__file__).resolve().parents[1] / "examples" / "walk.npz"


def channels(text: str) -> tuple[list[str], np.ndarray]:
    """The joints' names in file order and the MOTION rows (T, C) of a BVH text."""
    head, motion = text.split("MOTION", 1)
    words = head.split()
    names = [words[i + 1] for i, w in enumerate(words) if w in ("ROOT", "JOINT")]
    rows = motion.strip().splitlines()[2:]
    return names, np.array([[float(v) for v in r.split()] for r in rows])


@pytest.mark.parametrize("order", ["ZXY", "YXZ"])  # X in the middle: far from gimbal lock
def test_a_spinning_body_and_a_deep_knee_bend_give_smooth_exact_channels(order):
    """The walk's root yawing through two full turns and its left knee bending from 0 to 150
    degrees: every rotation channel steps under 30 degrees a frame (it was 360 at the wraps
    and 180 where the knee passed 90 degrees) and the angles give each rotation back."""
    joints = BodyJoints(load_body_model(None))
    walk = slice_frames(load_motion(WALK), 0, 72)
    T = walk.num_frames
    yaw = np.stack([np.zeros(T), np.zeros(T), np.linspace(0, 4 * np.pi, T)], -1)
    # the walk's own root, turned about the z-up world's vertical
    root = rotmat_to_rotvec(rotvec_to_rotmat(yaw) @ rotvec_to_rotmat(np.asarray(walk.root_orient)))
    knee = np.zeros((T, 21, 3))
    knee[:] = np.reshape(walk.pose_body, (T, 21, 3))
    knee[:, 3] = np.stack([np.linspace(0, np.radians(150), T), np.zeros(T), np.zeros(T)], -1)
    motion = walk.with_body(root_orient=root, pose_body=knee.reshape(T, -1))
    names, data = channels(smpl_bvh(motion, joints, order=order))
    angles = data[:, 3:]
    assert np.abs(np.diff(angles, axis=0)).max() < 30.0  # the walk itself: up to 23
    # the knee's channels give its rotation, the root's its turn (in the file's y-up world)
    axes = order.lower()
    k = names.index("left_knee")
    R = euler_to_rotmat(np.radians(angles[:, 3 * k : 3 * k + 3]), axes)
    want = smpl_globals(motion, joints)[0][:, 4]  # (T, 3, 3) world rotations: knee
    parent = smpl_globals(motion, joints)[0][:, 1]
    np.testing.assert_allclose(R, np.swapaxes(parent, -1, -2) @ want, atol=1e-5)
    R0 = euler_to_rotmat(np.radians(angles[:, :3]), axes)
    np.testing.assert_allclose(R0, Z_UP_TO_Y_UP @ smpl_globals(motion, joints)[0][:, 0],
                               atol=1e-5)  # fmt: skip


def test_continuous_euler_keeps_each_rotation_and_steps_little():
    rng = np.random.default_rng(0)
    turn = np.linspace(0, 6 * np.pi, 400)
    R = euler_to_rotmat(np.stack([turn, 1.2 * np.sin(turn), 0.3 * turn], -1), "zxy")[:, None]
    R = R @ euler_to_rotmat(rng.normal(0, 1e-3, (400, 1, 3)), "zxy")
    out = continuous_euler(R, "zxy")
    np.testing.assert_allclose(euler_to_rotmat(out, "zxy"), R, atol=1e-9)
    assert np.abs(np.diff(out, axis=0)).max() < 0.2  # radians; a frame turns ~0.05


def _continuous_euler_frame_by_frame(R: np.ndarray, axes: str) -> np.ndarray:
    """The definition, a frame at a time: of the two solutions, each moved by whole turns to
    lie nearest the frame before's, the one nearer it."""
    from mdvae_cli.geometry.euler import rotmat_to_euler

    one = rotmat_to_euler(R, axes)
    two = one * np.array([1.0, -1.0, 1.0]) + np.pi
    out = np.empty_like(one)
    out[0] = one[0]
    for t in range(1, len(R)):
        prev = out[t - 1]
        a = one[t] + 2 * np.pi * np.round((prev - one[t]) / (2 * np.pi))
        b = two[t] + 2 * np.pi * np.round((prev - two[t]) / (2 * np.pi))
        pick = np.abs(b - prev).sum(-1) < np.abs(a - prev).sum(-1)
        out[t] = np.where(pick[:, None], b, a)
    return out


@pytest.mark.parametrize("step", [0.05, 0.4, 1.5])
def test_continuous_euler_on_whole_arrays_is_the_frame_by_frame_definition(step):
    """Each frame's solution chosen by a map of the one before, worked out on whole arrays:
    the same angles, bit for bit, as choosing them a frame at a time, through wraps of whole
    turns and switches between the two solutions (large steps switch often)."""
    rng = np.random.default_rng(1)
    R = rotvec_to_rotmat(np.cumsum(rng.normal(0, step, (600, 5, 3)), axis=0))
    for axes in ("zxy", "xyz", "yzx"):
        want = _continuous_euler_frame_by_frame(R, axes)
        np.testing.assert_array_equal(continuous_euler(R, axes), want)
    assert continuous_euler(R[:1], "zxy").shape == (1, 5, 3)  # one frame: as it is
