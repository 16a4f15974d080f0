"""Foot contact (motion/contacts.py): low and slow, per foot joint, on known trajectories."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError
from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.motion.contacts import (
    FOOT_JOINTS,
    HEIGHT_TOL,
    SPEED_MAX,
    foot_contacts,
    foot_floor_levels,
    joint_speeds,
)
from mdvae_cli.view.pose import pose_skeleton

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def feet_track(heights: np.ndarray, xs: np.ndarray, up: int = 2) -> np.ndarray:
    """(T, 22, 3) joints: every foot joint at the given height and forward position, the
    other joints a metre up (they do not matter)."""
    T = len(heights)
    J = np.zeros((T, 22, 3))
    J[..., up] = 1.0
    for j in FOOT_JOINTS:
        J[:, j, up] = heights
        J[:, j, 0] = xs
    return J


def test_still_foot_on_the_floor_is_in_contact_and_lifted_or_moving_is_not():
    fps, T = 30.0, 90
    h = np.zeros(T)
    h[30:60] = 0.12  # lifted 12 cm for a second
    x = np.zeros(T)
    x[60:] = np.arange(T - 60) / fps * 1.0  # then sliding at 1 m/s on the floor
    c = foot_contacts(feet_track(h, x), fps)
    assert c.shape == (T, 4) and c.dtype == bool
    assert c[3:27].all()  # standing (away from the lift's edges, where the speed rises)
    assert not c[30:60].any()  # 12 cm up
    assert not c[62:].any()  # 1 m/s is not still


def test_thresholds_are_the_documented_ones():
    fps, T = 100.0, 50
    for speed, expect in ((0.9 * SPEED_MAX, True), (1.1 * SPEED_MAX, False)):
        c = foot_contacts(feet_track(np.zeros(T), np.arange(T) / fps * speed), fps)
        assert c[1:-1].all() == expect
    h = np.zeros(T)
    h[10:20] = 0.9 * HEIGHT_TOL
    h[30:40] = 1.1 * HEIGHT_TOL
    # a foot that rises slowly (within the speed limit) stays in contact up to HEIGHT_TOL
    c = foot_contacts(feet_track(h, np.zeros(T)), fps, speed_max=np.inf)
    assert c[12:18].all() and not c[32:38].any()
    assert HEIGHT_TOL == 0.05 and SPEED_MAX == 0.2


def test_floor_is_each_joints_low_quantile_and_can_be_given():
    T = 200
    J = feet_track(np.full(T, 0.3), np.zeros(T))
    J[:, 7, 2] = 0.08  # the ankle rests 8 cm up, the toe 3 cm: each joint its own floor
    J[:, 10, 2] = 0.03
    levels = foot_floor_levels(J)
    assert np.allclose(levels, [0.08, 0.3, 0.03, 0.3])
    assert foot_contacts(J, 30.0).all()  # every joint at its own floor level
    c = foot_contacts(J, 30.0, floor=0.0)  # a floor at z = 0 for all: only the toe is low
    assert c[:, 2].all() and not c[:, [0, 1, 3]].any()
    # a few noisy frames far below do not move the floor (2 % quantile)
    J[:3, 10, 2] = -0.5
    assert abs(foot_floor_levels(J)[2] - 0.03) < 1e-9


def test_y_up_single_frame_and_empty():
    J = feet_track(np.zeros(5), np.zeros(5), up=1)
    assert foot_contacts(J, 30.0, up=1).all()
    assert foot_contacts(J[:1], 30.0).all()  # one frame: no speed, counts as still
    assert foot_contacts(np.zeros((0, 22, 3)), 30.0).shape == (0, 4)
    assert np.allclose(joint_speeds(np.zeros((1, 3, 3)), 30.0), 0)


@pytest.mark.parametrize(
    "joints, fps, message",
    [(np.zeros((5, 10, 3)), 30.0, "J >= 12"), (np.zeros((5, 22)), 30.0, "J >= 12"),
     (np.zeros((5, 22, 3)), 0.0, "frame rate")],
)  # fmt: skip
def test_bad_input_is_one_line_error(joints, fps, message):
    with pytest.raises(InputError, match=message):
        foot_contacts(joints, fps)


def test_bundled_walk_alternates_heel_and_toe_contacts():
    """The bundled clean walk (79 frames, 30 Hz): each foot planted about a third of the time,
    the two feet's contacts mostly apart, and the heel (ankle) strikes before the toe."""
    motion = load_motion(EXAMPLES / "walk.npz")
    joints = pose_skeleton(motion, BodyModel(load_body_model(None))).joints
    c = foot_contacts(joints, motion.fps)
    frac = c.mean(axis=0)
    assert np.allclose(frac, [20 / 79, 30 / 79, 31 / 79, 37 / 79], atol=1.5 / 79)
    left, right = c[:, 0] | c[:, 2], c[:, 1] | c[:, 3]
    assert (left & right).mean() < 0.1
    first_heel, first_toe = np.flatnonzero(c[:, 0])[0], np.flatnonzero(c[:, 2])[0]
    assert first_heel <= first_toe or first_toe == 0
