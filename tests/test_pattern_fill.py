"""Pattern fill (motion.pattern): a long hole of every joint written from a stretch of the
same take whose frames either side match the hole's; nothing where none matches."""

from __future__ import annotations

import numpy as np

from mdvae_cli.geometry.rotations_np import rotmat_to_rotvec, rotvec_to_rotmat
from mdvae_cli.infer.fill import input_curve
from mdvae_cli.motion.holes import with_holes
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.pattern import MIN_SECONDS, pattern_fill

PERIOD = 30  # frames of one gait cycle at 30 Hz


def cyclic_walk(T: int = 240, turn_at: int | None = None, chirp: bool = False) -> Motion:
    """Every joint swings on one 30-frame cycle (or on a rising frequency, ``chirp``: no two
    stretches alike); the pelvis walks 1 m per cycle, heading along x, or turned by 90 degrees
    about z (up) from frame ``turn_at`` on."""
    t = np.arange(T, dtype=float)
    phase = 2 * np.pi * (t / PERIOD + (t / T) ** 2 * 3 if chirp else t / PERIOD)
    amp = np.linspace(0.2, 0.6, 21)[None, :, None] * np.array([1.0, 0.3, 0.2])
    pose = amp * np.sin(phase[:, None, None] + np.arange(21)[None, :, None] * 0.3)
    yaw = np.zeros(T) if turn_at is None else np.where(t >= turn_at, np.pi / 2, 0.0)
    up = np.array([0.0, 0.0, 1.0])
    sway = np.array([0.1, 0.0, 0.0]) * np.sin(phase)[:, None]
    root = rotmat_to_rotvec(rotvec_to_rotmat(yaw[:, None] * up) @ rotvec_to_rotmat(sway))
    step = np.stack([np.cos(yaw), np.sin(yaw), np.zeros(T)], axis=1) / PERIOD
    trans = np.cumsum(step, axis=0) + np.array([0.0, 0.0, 0.9])
    trans[:, 2] += 0.02 * np.sin(2 * phase)
    return Motion(root_orient=root, pose_body=pose, trans=trans, betas=np.zeros(10), fps=30.0)


def hole_mask(T: int, a: int, b: int) -> np.ndarray:
    mask = np.ones((T, 22), bool)
    mask[a:b] = False
    return mask


def rotation_error(a: Motion, b: Motion, frames: slice) -> float:
    """The largest angle (rad) between two motions' joint rotations over some frames."""
    ra = np.concatenate([a.root_orient[:, None], a.pose_body], axis=1)[frames]
    rb = np.concatenate([b.root_orient[:, None], b.pose_body], axis=1)[frames]
    rel = np.swapaxes(rotvec_to_rotmat(ra), -1, -2) @ rotvec_to_rotmat(rb)
    cos = (np.trace(rel, axis1=-2, axis2=-1) - 1) / 2
    return float(np.arccos(np.clip(cos, -1, 1)).max())


def test_a_repeated_motion_fills_a_long_hole_from_its_own_cycle():
    truth = cyclic_walk()
    a, b = 100, 130  # one second of every joint
    holed = with_holes(truth, hole_mask(truth.num_frames, a, b))
    spline = with_holes(truth, hole_mask(truth.num_frames, a, b), "spline")
    filled, written = pattern_fill(holed, spline)
    assert len(written) == 1 and written[0][:2] == (a, b)
    assert (a - written[0][2]) % PERIOD == 0  # the same phase of another cycle
    assert rotation_error(filled, truth, slice(a, b)) < 1e-6
    assert np.abs(filled.trans[a:b] - truth.trans[a:b]).max() < 1e-6
    assert rotation_error(spline, truth, slice(a, b)) > 0.05  # the spline cannot know the cycle
    # a hole not asked for keeps the base's fill
    assert pattern_fill(holed, spline, which=lambda start: start != a) == (spline, [])
    assert pattern_fill(holed, spline, which=lambda start: start == a)[1] == written
    # every frame outside the hole is the base's
    outside = np.r_[0:a, b : truth.num_frames]
    assert np.array_equal(filled.pose_body[outside], spline.pose_body[outside])
    assert np.array_equal(filled.trans[outside], spline.trans[outside])


def test_a_stretch_walked_another_way_is_turned_onto_the_takes_heading():
    """The take's cycle before the hole was walked along x, the hole is after a 90-degree
    turn: the stretch's pelvis turn and its steps are turned to the new heading."""
    truth = cyclic_walk(T=270, turn_at=200)  # no whole cycle after the turn to copy
    a, b = 220, 240
    holed = with_holes(truth, hole_mask(truth.num_frames, a, b))
    base = with_holes(truth, hole_mask(truth.num_frames, a, b), "spline")
    filled, written = pattern_fill(holed, base)
    assert len(written) == 1 and written[0][2] + (b - a) <= 200  # walked along x
    assert rotation_error(filled, truth, slice(a, b)) < 1e-6
    assert np.abs(filled.trans[a:b] - truth.trans[a:b]).max() < 1e-6


def test_no_match_short_holes_and_holes_at_the_ends_keep_their_fill():
    chirp = cyclic_walk(chirp=True)
    T = chirp.num_frames
    base = with_holes(chirp, hole_mask(T, 100, 130), "spline")
    filled, written = pattern_fill(with_holes(chirp, hole_mask(T, 100, 130)), base)
    assert written == [] and filled is base  # nothing in the take matches the hole's ends

    walk = cyclic_walk()
    short = int(round(MIN_SECONDS * 30)) - 1
    base = with_holes(walk, hole_mask(T, 100, 100 + short), "spline")
    assert pattern_fill(with_holes(walk, hole_mask(T, 100, 100 + short)), base)[1] == []
    base = with_holes(walk, hole_mask(T, 0, 30), "spline")  # no frames before it to match
    assert pattern_fill(with_holes(walk, hole_mask(T, 0, 30)), base)[1] == []
    limb = hole_mask(T, 100, 130)
    limb[100:130, :10] = True  # not every joint: the spline's
    base = with_holes(walk, limb, "spline")
    assert pattern_fill(with_holes(walk, limb), base)[1] == []


def test_a_clean_takes_long_hole_is_filled_from_its_cycle_by_the_default_curve():
    """``infer.fill.input_curve`` (a clean take's holes from its own frames) uses the pattern
    where one matches, at the take's own rate too."""
    truth = cyclic_walk()
    holed = with_holes(truth, hole_mask(truth.num_frames, 100, 130))
    assert rotation_error(input_curve(holed), truth, slice(100, 130)) < 1e-6
    fast = cyclic_walk(T=480)  # the same cycle read as 120 Hz frames: 30-frame cycles still
    fast = Motion(root_orient=fast.root_orient, pose_body=fast.pose_body, trans=fast.trans,
                  betas=fast.betas, fps=120.0)  # fmt: skip
    holed = with_holes(fast, hole_mask(fast.num_frames, 300, 360))
    assert rotation_error(input_curve(holed), fast, slice(300, 360)) < 1e-6
