"""Holes (missing frames and joints): making them, the classical fills (motion.holes), and
how denoising treats them (the blend takes the denoiser's values there, infer.fill writes
them, the rest of the take keeps what it had)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from conftest import motion_arrays

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError
from mdvae_cli.geometry.rotations import rotvec_to_quat, rotvec_unwrap
from mdvae_cli.infer.denoise_settings import DenoiseSettings, denoise
from mdvae_cli.infer.fill import (
    CURVE_NOISE_RAD,
    fill_holes,
    has_holes,
    holes_from,
    input_curve,
    result_shares,
)
from mdvae_cli.infer.input_noise import noise_variance
from mdvae_cli.infer.noise_blend import blend_motion
from mdvae_cli.model.denoiser import load_denoiser
from mdvae_cli.motion.holes import (
    LIMBS,
    fill_gaps,
    finite_mask,
    frame_holes,
    hole_count,
    limb_holes,
    observed,
    with_holes,
)
from mdvae_cli.motion.motion import Motion


def clip(T: int = 120, seed: int = 0) -> Motion:
    a = motion_arrays(T=T, width=66, seed=seed)
    return Motion.from_poses(a["poses"], a["trans"], a["betas"], 30.0)


def rotation_gap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (rad) between axis-angle rotations.  (..., 3), (..., 3) -> (...)"""
    qa, qb = rotvec_to_quat(torch.as_tensor(a)), rotvec_to_quat(torch.as_tensor(b))
    return (2 * torch.acos((qa * qb).sum(-1).abs().clamp(max=1.0))).numpy()


def test_frame_holes_are_where_and_as_long_as_asked_and_seeded():
    mask = frame_holes(200, 15, 3, np.random.default_rng(0), margin=5)
    again = frame_holes(200, 15, 3, np.random.default_rng(0), margin=5)
    np.testing.assert_array_equal(mask, again)
    assert hole_count(mask) == (45, 45 * 22)
    rows = ~mask.all(axis=1)
    assert not rows[:5].any() and not rows[-5:].any()
    assert (mask.all(axis=1) | ~mask.any(axis=1)).all()  # whole frames
    starts = np.flatnonzero(np.diff(rows.astype(int)) == 1) + 1
    assert len(starts) == 3


def test_limb_holes_take_one_limb_and_nothing_else():
    mask = limb_holes(120, 30, 1, np.random.default_rng(3))
    cols = np.flatnonzero(~mask.all(axis=0))
    assert tuple(cols) in {tuple(sorted(v)) for v in LIMBS.values()}
    assert hole_count(mask) == (30, 90)


def test_finite_mask_marks_nan_joints_and_nan_translations():
    poses = np.zeros((5, 156))
    trans = np.zeros((5, 3))
    poses[1, 3 * 4] = np.nan  # joint 4 of frame 1
    trans[3, 2] = np.inf  # every joint of frame 3
    mask = finite_mask(poses, trans)
    assert not mask[1, 4] and mask[1].sum() == 21
    assert not mask[3].any()
    assert mask[[0, 2, 4]].all()


def test_slerp_fill_is_exact_on_a_constant_speed_turn_and_keeps_observed_frames():
    m = clip(60)
    t = np.arange(60)[:, None]
    m.pose_body[:, 5] = t * np.array([0.0, 0.02, 0.0])  # a steady turn about y
    mask = np.ones((60, 22), bool)
    mask[20:35, 6] = False  # joint 6 = pose_body[5]
    holed = with_holes(m, mask)
    assert holed.joint_mask is not None and not holed.joint_mask[25, 6]
    np.testing.assert_allclose(holed.pose_body[:, 5], m.pose_body[:, 5], atol=1e-9)
    untouched = np.ones(60, bool)
    untouched[20:35] = False
    np.testing.assert_array_equal(holed.pose_body[untouched], m.pose_body[untouched])


@pytest.mark.parametrize("method", ["hermite", "spline"])
def test_curve_fills_reproduce_a_smooth_path_and_beat_slerp_on_it(method):
    m = clip(90)
    mask = frame_holes(90, 20, 1, np.random.default_rng(1), margin=20)
    miss = ~mask[:, 0]
    holed_curve, holed_lerp = with_holes(m, mask, method), with_holes(m, mask, "slerp")
    t = np.arange(90) / 30.0
    quadratic = np.stack([0.5 * t**2, 0.2 * t, 0.9 + 0.1 * t**2], 1)  # a quadratic path
    short = frame_holes(90, 12, 1, np.random.default_rng(1), margin=20)  # ends' velocities kept
    exact = with_holes(m.with_body(trans=quadratic), short, method)
    np.testing.assert_allclose(exact.trans, quadratic, atol=1e-9)
    err = lambda h: rotation_gap(h.pose_body[miss], m.pose_body[miss]).mean()  # noqa: E731
    assert err(holed_curve) < 0.6 * err(holed_lerp)


def test_a_joint_never_seen_keeps_its_values_and_the_ends_hold():
    m = clip(40)
    mask = np.ones((40, 22), bool)
    mask[:, 9] = False  # never seen
    mask[:5, 3] = False  # missing at the start: holds frame 5
    holed = with_holes(m, mask)
    np.testing.assert_array_equal(holed.pose_body[:, 8], m.pose_body[:, 8])
    np.testing.assert_allclose(holed.pose_body[:5, 2], np.repeat(m.pose_body[5:6, 2], 5, 0))
    with pytest.raises(ValueError, match="fill method"):
        fill_gaps(holed, "cubic")


def test_the_blend_takes_the_denoisers_values_in_a_hole_and_keeps_the_rest():
    src = clip(120)
    mask = np.ones((120, 22), bool)
    mask[50:70] = False
    holed = with_holes(src, mask)
    denoised = src.with_body(
        pose_body=src.pose_body + 0.05, root_orient=src.root_orient - 0.05, trans=src.trans + 0.1
    )
    out, _ = blend_motion(holed, denoised)
    np.testing.assert_allclose(out.pose_body[50:70], denoised.pose_body[50:70], atol=1e-9)
    np.testing.assert_allclose(out.trans[50:70], denoised.trans[50:70], atol=1e-9)
    # a clean input far from the hole comes back as it came
    assert np.abs(out.pose_body[:30] - src.pose_body[:30]).max() < 0.01


def test_fill_holes_writes_only_the_holes():
    src = clip(80)
    mask = frame_holes(80, 10, 1, np.random.default_rng(2), margin=20)
    holed = with_holes(src, mask)
    result = src.with_body(pose_body=src.pose_body + 0.01)
    miss = ~mask[:, 0]
    off = fill_holes(holed, result, "off")
    np.testing.assert_array_equal(off.pose_body[miss], holed.pose_body[miss])
    np.testing.assert_array_equal(off.pose_body[~miss], result.pose_body[~miss])
    model = fill_holes(holed, result, "model")
    np.testing.assert_array_equal(model.pose_body, result.pose_body)
    curve = fill_holes(holed, result, "curve")
    np.testing.assert_array_equal(curve.pose_body[~miss], result.pose_body[~miss])
    assert has_holes(curve) and not has_holes(src)
    taken = holes_from(holed, result)
    np.testing.assert_array_equal(taken.pose_body[miss], result.pose_body[miss])
    with pytest.raises(InputError, match="fill must be one of"):
        DenoiseSettings(fill="spline")


def smooth_take_with_a_fast_joint(T: int = 150) -> Motion:
    """Slow sinusoids on every joint, and the left elbow (pose_body row 17) swinging at 4 Hz."""
    t = np.arange(T)[:, None, None] / 30.0
    phase = np.arange(22)[None, :, None] * 0.3 + np.arange(3)[None, None, :]
    rot = 0.3 * np.sin(2 * np.pi * 0.5 * t + phase)
    rot[:, 18] = 0.6 * np.sin(2 * np.pi * 4.0 * t[:, 0] + phase[0, 18])
    return Motion.from_poses(
        rot.reshape(T, 66), 0.1 * np.sin(t[:, 0] + np.arange(3)), np.zeros(10), 30.0
    )


def test_a_clean_takes_fast_joint_is_filled_from_its_own_frames():
    take = smooth_take_with_a_fast_joint()
    mask = frame_holes(150, 5, 1, np.random.default_rng(1), margin=40)
    holed = with_holes(take, mask)
    share, _ = result_shares(holed)
    own = np.sqrt(noise_variance(take.pose_body, None))
    assert own[17] > 2 * CURVE_NOISE_RAD  # a per-joint rule would read the elbow as noisy
    assert share.max() < 1e-3
    result = take.with_body(pose_body=take.pose_body + 0.05)  # a result off by 0.05 rad
    filled = fill_holes(holed, result, "curve")
    miss = ~mask[:, 0]
    np.testing.assert_allclose(
        filled.pose_body[miss], input_curve(holed).pose_body[miss], atol=1e-3
    )
    # the same take with white noise of 0.03 rad: every joint takes the result's curve
    noisy = take.with_body(
        pose_body=take.pose_body + np.random.default_rng(0).normal(0, 0.03, take.pose_body.shape)
    )
    share, _ = result_shares(with_holes(noisy, mask))
    assert share[1:].min() > 0.9 and share[0] < 1e-3  # the root came clean
    # the blend's own unwrap of the take, handed over, gives the same shares
    unwrapped = rotvec_unwrap(torch.as_tensor(noisy.joint_rotations), 0).numpy()
    again, _ = result_shares(with_holes(noisy, mask), unwrapped)
    np.testing.assert_array_equal(again, share)


@pytest.fixture(scope="module")
def model():
    den, _ = load_denoiser(None)
    return den, BodyModel(load_body_model(None))


def test_denoise_fills_a_hole_from_the_take_and_keeps_the_rest(model):
    den, body = model
    src = clip(150, seed=4)
    mask = frame_holes(150, 15, 1, np.random.default_rng(5), margin=40)
    miss = ~mask[:, 0]
    holed = with_holes(src, mask)
    whole, filled, off = (
        denoise([m], DenoiseSettings(fill=f), den, body)[0]
        for m, f in ((src, "curve"), (holed, "curve"), (holed, "off"))
    )
    assert np.isfinite(filled.pose_body).all() and filled.num_frames == 150
    np.testing.assert_array_equal(observed(filled), mask)
    # the hole: closer to the take than the straight-line placeholder it read
    err = lambda m: rotation_gap(m.pose_body[miss], src.pose_body[miss]).mean()  # noqa: E731
    assert err(filled) < 0.8 * err(holed)
    # off: the holes as they came
    np.testing.assert_allclose(off.pose_body[miss], holed.pose_body[miss], atol=1e-6)
    # a second away from the hole, the take comes back as it did without one
    far = np.ones(150, bool)
    far[np.flatnonzero(miss)[0] - 30 : np.flatnonzero(miss)[-1] + 31] = False
    gap = rotation_gap(filled.pose_body[far], whole.pose_body[far])
    assert gap.mean() < 0.005


def test_a_long_hole_splits_the_take_and_each_side_is_denoised_on_its_own(model):
    from mdvae_cli.infer.denoise import denoise_motions
    from mdvae_cli.infer.input_kinds import refine_config
    from mdvae_cli.motion.motion import slice_frames

    den, body = model
    src = clip(150, seed=6)
    mask = np.ones((150, 22), bool)
    mask[60:90] = False  # 1 s: long enough to split
    holed = with_holes(src, mask)
    cfg, _ = refine_config("mocap", steps=0)
    run = lambda ms: denoise_motions(ms, den, body, refine=cfg, blend=True)  # noqa: E731
    out = run([holed])[0]
    before, after = run([slice_frames(holed, 0, 60), slice_frames(holed, 90, 150)])
    np.testing.assert_allclose(out.pose_body[:60], before.pose_body, atol=1e-6)
    np.testing.assert_allclose(out.pose_body[90:], after.pose_body, atol=1e-6)
    assert np.isfinite(out.pose_body[60:90]).all()
    assert not np.allclose(out.pose_body[60:90], holed.pose_body[60:90])  # filled, not kept


def test_a_video_estimates_short_hole_is_slerped_a_mocap_takes_splined(model):
    den, body = model
    src = clip(150, seed=9)
    mask = np.ones((150, 22), bool)
    mask[70:78] = False  # 8 frames: inside the take, not split
    holed = with_holes(src, mask)
    gap = {}
    for kind in ("mocap", "video"):
        out = denoise([holed], DenoiseSettings(input_kind=kind), den, body)[0]
        for curve in ("slerp", "spline"):
            ref = with_holes(src, mask, curve).pose_body[70:78]
            gap[kind, curve] = rotation_gap(out.pose_body[70:78], ref).mean()
    # a clean take is filled from its own frames: the spline for mocap, slerp for video
    assert gap["mocap", "spline"] < 0.1 * gap["mocap", "slerp"]
    assert gap["video", "slerp"] < 0.1 * gap["video", "spline"]
