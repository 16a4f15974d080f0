"""Metrics against hand-computed values; evaluate_pair on a tiny body; frame-weighted means."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from conftest import motion_arrays

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError
from mdvae_cli.export import pose_motion_chunks
from mdvae_cli.formats.npz_io import motion_from_arrays
from mdvae_cli.metrics import (
    EvalResult,
    acceleration,
    acceleration_error,
    evaluate_pair,
    joint_acceleration,
    mean_result,
    mpjpe,
    v2v,
)
from mdvae_cli.motion.motion import slice_frames

RNG = np.random.default_rng(0)


def test_mpjpe_hand_computed():
    gt = np.zeros((1, 2, 3))
    pred = np.array([[[3.0, 4.0, 0.0], [0.0, 0.0, 1.0]]])  # errors 5 and 1
    assert np.allclose(mpjpe(pred, gt), [3.0])


def test_constant_offset_gives_offset_errors():
    T, V = 5, 100
    gt_v = RNG.normal(size=(T, V, 3))
    gt_j = RNG.normal(size=(T, 22, 3))
    offset = np.array([0.006, 0.0, 0.008])  # |offset| = 1 cm
    pred_v, pred_j = gt_v + offset, gt_j + offset
    assert np.allclose(v2v(pred_v, gt_v) * 100, 1.0)
    assert np.allclose(mpjpe(pred_j, gt_j) * 100, 1.0)
    assert np.allclose(v2v(pred_v, gt_v, pred_j[:, 0], gt_j[:, 0]), 0.0, atol=1e-12)


def test_root_relative_v2v_hand_computed():
    gt = np.zeros((1, 2, 3))
    pred = np.array([[[1.0, 0.0, 0.0], [1.0, 2.0, 0.0]]])
    pelvis_gt, pelvis_pred = np.zeros((1, 3)), np.array([[1.0, 0.0, 0.0]])
    # after removing the pelvis: pred = (0,0,0), (0,2,0) -> errors 0 and 2
    assert np.allclose(v2v(pred, gt, pelvis_pred, pelvis_gt), [1.0])
    with pytest.raises(ValueError):
        v2v(pred, gt, pelvis_pred, None)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_torch_in_torch_out(dtype):
    a = torch.zeros(4, 22, 3, dtype=dtype)
    b = a + torch.tensor([0.0, 0.0, 0.02], dtype=dtype)
    out = mpjpe(b, a)
    assert isinstance(out, torch.Tensor) and out.shape == (4,) and out.dtype == dtype
    assert torch.allclose(out, torch.full((4,), 0.02, dtype=dtype))
    assert isinstance(joint_acceleration(a, 30.0), torch.Tensor)
    assert isinstance(mpjpe(b.numpy(), a.numpy()), np.ndarray)


def quadratic(T: int, fps: float, p0, v0, a):
    """x(t) = p0 + v0 t + a t^2 / 2 for every one of 22 joints.  -> (T, 22, 3)"""
    t = np.arange(T)[:, None, None] / fps
    p0, v0, a = (np.broadcast_to(np.asarray(x, float), (22, 3)) for x in (p0, v0, a))
    return p0 + v0 * t + 0.5 * a * t**2


def test_quadratic_trajectory_has_known_acceleration():
    fps, a = 30.0, np.array([0.0, 3.0, -4.0])  # |a| = 5 m/s^2
    x = quadratic(20, fps, RNG.normal(size=(22, 3)), RNG.normal(size=(22, 3)), a)
    acc = acceleration(x, fps)
    assert acc.shape == (18, 22, 3)
    assert np.allclose(acc, a, atol=1e-9)
    assert np.allclose(joint_acceleration(x, fps), 5.0)
    still = quadratic(20, fps, 0.0, 1.0, 0.0)  # constant velocity: zero acceleration
    assert np.allclose(joint_acceleration(still, fps), 0.0, atol=1e-9)
    assert np.allclose(acceleration_error(x, still, fps), 5.0)
    assert np.allclose(acceleration_error(x, x + 0.3, fps), 0.0, atol=1e-9)


def test_acceleration_hand_computed_and_batched():
    # 1 joint moving 0, 1, 4 (m) along x at 2 fps: (0 - 2 + 4) * 4 = 8 m/s^2
    x = np.zeros((3, 1, 3))
    x[:, 0, 0] = [0.0, 1.0, 4.0]
    assert np.allclose(joint_acceleration(x, 2.0), [8.0])
    batch = np.stack([x, 2 * x])  # leading batch dim
    assert np.allclose(joint_acceleration(batch, 2.0), [[8.0], [16.0]])


# --- evaluate_pair on the tiny body -----------------------------------------------------------


def clip(T=40, fps=30.0, seed=0):
    return motion_from_arrays(motion_arrays(T=T, fps=fps, seed=seed))


def test_evaluate_identical_is_zero(tiny_body):
    m = clip()
    r = evaluate_pair(m, m, tiny_body)
    assert r.num_frames == 40 and r.fps == 30.0
    assert r.v2v_cm == pytest.approx(0, abs=1e-9)
    assert r.v2v_abs_cm == pytest.approx(0, abs=1e-9)
    assert r.mpjpe_cm == pytest.approx(0, abs=1e-9)
    assert r.accel_error == pytest.approx(0, abs=1e-9)
    assert r.accel_gt == pytest.approx(r.accel_pred) and r.accel_gt > 0


def test_evaluate_translation_offset(tiny_body):
    gt = clip()
    pred = gt.with_body(trans=gt.trans + np.array([0.0, 0.01, 0.0]))
    r = evaluate_pair(gt, pred, tiny_body)
    assert r.v2v_abs_cm == pytest.approx(1.0, abs=1e-4)
    assert r.mpjpe_cm == pytest.approx(1.0, abs=1e-4)
    assert r.v2v_cm == pytest.approx(0.0, abs=1e-4)
    assert r.accel_error == pytest.approx(0.0, abs=1e-2)


def test_evaluate_known_acceleration(tiny_body):
    """Rigid body on a parabola: every joint accelerates at exactly |a|."""
    T, fps = 30, 30.0
    t = np.arange(T)[:, None] / fps
    a = np.array([0.0, 0.0, -9.81])
    arrays = motion_arrays(T=T, fps=fps)
    arrays["poses"] = np.zeros_like(arrays["poses"])
    arrays["trans"] = np.array([0.1, 0.2, 1.0]) + np.array([1.0, 0.0, 2.0]) * t + 0.5 * a * t**2
    gt = motion_from_arrays(arrays)
    pred = gt.with_body(trans=gt.trans + 0.0 * t)  # same
    r = evaluate_pair(gt, pred, tiny_body)
    assert r.accel_gt == pytest.approx(9.81, rel=1e-3)
    still = gt.with_body(trans=np.repeat(gt.trans[:1], T, axis=0))
    r2 = evaluate_pair(gt, still, tiny_body)
    assert r2.accel_pred == pytest.approx(0.0, abs=1e-2)
    assert r2.accel_error == pytest.approx(9.81, rel=1e-3)


def test_evaluate_matches_direct_computation_and_is_chunk_invariant(tiny_body):
    gt, pred = clip(T=23, seed=1), clip(T=23, seed=2)
    whole = evaluate_pair(gt, pred, tiny_body, chunk_frames=1000)
    chunked = evaluate_pair(gt, pred, tiny_body, chunk_frames=4)
    for name in ("v2v_cm", "v2v_abs_cm", "mpjpe_cm", "accel_gt", "accel_pred", "accel_error"):
        assert getattr(chunked, name) == pytest.approx(getattr(whole, name), rel=1e-6)

    model = BodyModel(tiny_body, dtype=torch.float64)
    f = lambda a: torch.as_tensor(a)  # noqa: E731
    betas = f(gt.betas)
    og = model(f(gt.root_orient), f(gt.pose_body), f(gt.trans), betas, vertices=True)
    op = model(f(pred.root_orient), f(pred.pose_body), f(pred.trans), betas, vertices=True)
    vg, vp = og.vertices.numpy(), op.vertices.numpy()
    jg, jp = og.joints.numpy(), op.joints.numpy()
    rel = np.linalg.norm((vp - jp[:, :1]) - (vg - jg[:, :1]), axis=-1).mean()
    assert whole.v2v_cm == pytest.approx(100 * rel, rel=1e-4)
    assert whole.v2v_abs_cm == pytest.approx(100 * np.linalg.norm(vp - vg, axis=-1).mean(), 1e-4)
    assert whole.mpjpe_cm == pytest.approx(100 * np.linalg.norm(jp - jg, axis=-1).mean(), 1e-4)
    acc = lambda j: (j[:-2] - 2 * j[1:-1] + j[2:]) * 30.0**2  # noqa: E731
    assert whole.accel_gt == pytest.approx(np.linalg.norm(acc(jg), axis=-1).mean(), rel=1e-3)
    err = np.linalg.norm(acc(jp) - acc(jg), axis=-1).mean()
    assert whole.accel_error == pytest.approx(err, rel=1e-3)


def test_evaluate_uses_ground_truth_betas(tiny_body):
    gt = clip(T=10)
    pred = gt.with_body()
    pred.betas = gt.betas + 3.0  # ignored: both posed with the GT shape
    r = evaluate_pair(gt, pred, tiny_body)
    assert r.v2v_abs_cm == pytest.approx(0.0, abs=1e-9)


def test_evaluate_two_frames_has_no_acceleration(tiny_body):
    m = clip(T=2)
    r = evaluate_pair(m, m, tiny_body)
    assert r.accel_gt is None and r.accel_error is None and r.accel_frames == 0


def test_frames_missing_in_either_file_are_not_scored(tiny_body):
    """A hole in the ground truth or the prediction is no measurement: the scores equal those
    of the observed frames alone, and accelerations skip inner frames beside a hole."""
    gt, pred = clip(T=30, seed=1), clip(T=30, seed=2)
    hole_gt = gt.with_body()
    hole_gt.joint_mask = np.ones((30, 22), bool)
    hole_gt.joint_mask[10:14] = False  # whole frames 10-13
    hole_gt.joint_mask[20, 7] = False  # one joint of frame 20
    hole_gt.pose_body = hole_gt.pose_body.copy()
    hole_gt.pose_body[10:14] = 2.0  # a placeholder far from anything
    r = evaluate_pair(hole_gt, pred, tiny_body)
    assert (r.num_frames, r.unscored_frames) == (25, 5)
    keep = np.ones(30, bool)
    keep[[10, 11, 12, 13, 20]] = False
    whole = evaluate_pair(gt, pred, tiny_body)
    assert whole.unscored_frames == 0 and whole.accel_count == 28
    per_frame = []
    for t in range(30):
        one = evaluate_pair(slice_frames(gt, t, t + 1), slice_frames(pred, t, t + 1), tiny_body)
        per_frame.append(one.v2v_cm)
    # float32 skinning is one product over the frames given: its rounding moves with their count
    assert r.v2v_cm == pytest.approx(np.mean(np.array(per_frame)[keep]), rel=1e-6)
    # inner frames t with t-1, t, t+1 all scored: 1-8, 15-18, 22-28
    assert r.accel_count == 8 + 4 + 7 and r.accel_frames == 19
    swapped = evaluate_pair(pred, hole_gt, tiny_body)
    assert (swapped.num_frames, swapped.unscored_frames) == (25, 5)
    mean = mean_result([r, whole])
    assert (mean.num_frames, mean.unscored_frames, mean.accel_count) == (55, 5, 47)
    nothing = gt.with_body()
    nothing.joint_mask = np.zeros((30, 22), bool)
    with pytest.raises(InputError, match="no frame is observed in both"):
        evaluate_pair(nothing, pred, tiny_body)


def test_evaluate_refuses_mismatched_rate_or_length(tiny_body):
    with pytest.raises(InputError, match="frame rates differ"):
        evaluate_pair(clip(fps=30.0), clip(fps=60.0), tiny_body)
    with pytest.raises(InputError, match="lengths differ"):
        evaluate_pair(clip(T=40), clip(T=41), tiny_body)


def test_files_at_two_rates_are_scored_at_the_slower(tiny_body):
    from mdvae_cli.metrics import common_rate
    from mdvae_cli.motion.resample import resample_motion

    fast = clip(T=121, fps=120.0)
    slow = resample_motion(fast, 30.0)  # every 4th frame, exactly
    for gt, pred, which in ((fast, slow, "ground truth"), (slow, fast, "prediction")):
        a, b, note = common_rate(gt, pred)
        assert note == f"evaluated at 30 fps: the {which} resampled from 120 fps"
        assert a.fps == b.fps == 30.0 and a.num_frames == b.num_frames == 31
        r = evaluate_pair(a, b, tiny_body)
        assert r.fps == 30.0 and r.v2v_cm == pytest.approx(0.0, abs=1e-6)
    # a frame more at the fast rate rounds to the same length; a quarter second more does not
    a, b, _ = common_rate(clip(T=124, fps=120.0), slow)
    assert a.num_frames == b.num_frames == 31
    with pytest.raises(InputError, match="durations differ: ground truth 1.30 s, prediction"):
        common_rate(clip(T=156, fps=120.0), slow)
    same = clip(T=10)
    assert common_rate(same, same) == (same, same, None)


def test_mean_result_is_frame_weighted():
    a = EvalResult(10, 30.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
    b = EvalResult(30, 30.0, 3.0, 4.0, 5.0, 8.0, 9.0, 10.0)
    m = mean_result([a, b])
    assert m.num_frames == 40 and m.fps == 30.0
    assert m.v2v_cm == pytest.approx((10 * 1 + 30 * 3) / 40)
    assert m.mpjpe_cm == pytest.approx((10 * 3 + 30 * 5) / 40)
    assert m.accel_gt == pytest.approx((8 * 4 + 28 * 8) / 36)  # inner frames T - 2
    two = EvalResult(2, 60.0, 1.0, 1.0, 1.0, None, None, None)
    m2 = mean_result([a, two])
    assert m2.fps is None and m2.accel_gt == pytest.approx(4.0)
    assert m2.v2v_cm == pytest.approx(1.0)


def test_pose_motion_chunks_uses_matching_extra_joints_and_keeps_grad_mode(tiny_body):
    m = motion_from_arrays(motion_arrays(T=4, width=72))  # SMPL layout: 2 hand joints extra
    moved = m.with_body()
    moved.pose_extra = m.pose_extra + 0.5
    chunks = pose_motion_chunks(m, tiny_body, chunk_frames=3)
    ids, out = next(chunks)
    assert torch.is_grad_enabled()  # no_grad does not leak out of the generator
    assert list(ids) == [0, 1, 2] and out.vertices.shape == (3, tiny_body.num_vertices, 3)
    [(_, a)] = pose_motion_chunks(m, tiny_body, 4)
    [(_, b)] = pose_motion_chunks(moved, tiny_body, 4)
    assert torch.allclose(a.joints, b.joints)  # body joints do not depend on the hands
    assert not torch.allclose(a.vertices, b.vertices)  # hand vertices do
