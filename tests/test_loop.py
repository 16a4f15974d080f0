"""Loop detection (``infer.loop.looks_like_loop``): the ends must meet in joint positions too."""

from __future__ import annotations

import numpy as np
from conftest import motion_arrays

from mdvae_cli.body.builtin import builtin_body_model
from mdvae_cli.formats.npz_io import motion_from_arrays
from mdvae_cli.infer.loop import looks_like_loop, pose_gap, posed_joints, rest_joints, root_gap

T = 60
t = np.arange(T) / 30.0
phase = 2 * np.pi * t / 2.0  # one period over the 60 frames: frame 60 would equal frame 0


def cycle(trans: np.ndarray):
    """A 60-frame cycle of the body joints (root upright) on the root path ``trans`` (T, 3)."""
    m = motion_from_arrays(motion_arrays(T=T, width=72))
    pose = 0.4 * np.sin(phase[:, None, None] + np.arange(21)[None, :, None] * 0.3)
    root = np.tile([[np.pi / 2, 0.0, 0.0]], (T, 1))
    pose = np.broadcast_to(pose, (T, 21, 3)).copy()
    return m.with_body(root_orient=root, pose_body=pose, trans=trans)


def test_an_in_place_cycle_and_a_walk_cycle_are_loops():
    bounce = 0.9 + 0.02 * np.cos(2 * phase)
    in_place = np.stack([0.05 * np.sin(phase), 0.05 * np.cos(phase) - 0.05, bounce], 1)
    assert looks_like_loop(cycle(in_place))
    walk = np.stack([1.2 * t, 0.02 * np.sin(phase), bounce], 1)
    assert looks_like_loop(cycle(walk))


def test_a_take_whose_ends_are_13_cm_apart_is_not_a_loop():
    """The poses meet (same rotations at both ends), but the root wanders and ends 13 cm from
    where it started: dance2's case."""
    wander = 0.5 * np.sin(2 * np.pi * t / t[-1])[:, None] * [1.0, 0.6, 0.0]  # 0 at both ends
    drift = (t / t[-1])[:, None] * [0.13, 0.0, 0.0]
    trans = wander + drift + [0.0, 0.0, 0.9]
    m = cycle(trans)
    rot = np.concatenate([m.root_orient[:, None], m.pose_body], 1)
    assert pose_gap(rot, rest_joints(builtin_body_model(), m.betas)) < 0.05
    assert abs(root_gap(m.trans) - 0.13) < 0.01
    assert not looks_like_loop(m)
    m.trans[:, 2] += 0.13 * t / t[-1] - drift[:, 0]  # ends 13 cm higher instead: no loop either
    assert not looks_like_loop(m)


def test_posed_joints_turn_with_the_root():
    joints = rest_joints(builtin_body_model(), np.zeros(10))
    rest = posed_joints(np.zeros((1, 22, 3)), joints)[0]
    np.testing.assert_allclose(rest, joints - joints[0], atol=1e-12)
    turned = np.zeros((1, 22, 3))
    turned[0, 0] = [0.0, 0.0, np.pi / 2]  # a quarter turn about z: (x, y) -> (-y, x)
    np.testing.assert_allclose(
        posed_joints(turned, joints)[0],
        (rest @ np.array([[0, 1, 0], [-1, 0, 0], [0, 0, 1]])),
        atol=1e-12,
    )


def test_angle_matches_the_rotation_matrix_route():
    """The quaternion route gives the angle of R_a^T R_b (float noise), any angle up to pi."""
    import torch

    from mdvae_cli.geometry.rotations import rotmat_to_rotvec, rotvec_to_rotmat
    from mdvae_cli.infer.loop import _angle

    rng = np.random.default_rng(0)
    a = rng.normal(size=(50, 22, 3)) * rng.uniform(0, 1.5, size=(50, 22, 1))
    b = a + rng.normal(size=(50, 22, 3)) * rng.choice([1e-5, 0.01, 1.0], size=(50, 22, 1))
    ra = rotvec_to_rotmat(torch.as_tensor(a))
    rb = rotvec_to_rotmat(torch.as_tensor(b))
    ref = rotmat_to_rotvec(ra.transpose(-1, -2) @ rb).norm(dim=-1).mean(-1).numpy()
    np.testing.assert_allclose(_angle(a, b), ref, rtol=1e-6, atol=1e-9)


def test_the_ends_smoothed_alone_are_the_ends_of_the_whole_take_smoothed():
    """looks_like_loop checks the end poses from the first and last frames alone."""
    from mdvae_cli.filters import savgol_smooth
    from mdvae_cli.infer.loop import smoothed_ends

    x = np.random.default_rng(0).normal(size=(100, 22, 3))
    for window in (3, 5, 9):
        assert np.array_equal(smoothed_ends(x, window), savgol_smooth(x, window, 2)[[0, -1]])
    assert np.array_equal(smoothed_ends(x[:12], 9), savgol_smooth(x[:12], 9, 2)[[0, -1]])
