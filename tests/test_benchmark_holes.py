"""The hole benchmark's bookkeeping (benchmarks/holes.py): which observed frames count as
beside a hole, the pooled means its rows are made of, the takes slerped over as before holes
were read, and its noise conditions."""

import numpy as np
from conftest import motion_arrays
from test_holes import rotation_gap

from benchmarks.common import Clip
from benchmarks.holes import conditions, near_hole, pooled, slerped_over
from mdvae_cli.motion.holes import with_holes
from mdvae_cli.motion.motion import Motion


def _clip(seed: int) -> Clip:
    a = motion_arrays(T=60, width=66, seed=seed)
    return Clip(f"clip{seed}.npz#0", Motion.from_poses(a["poses"], a["trans"], a["betas"], 30.0))


def test_near_hole_marks_observed_frames_within_reach_on_both_sides():
    missing = np.zeros(20, bool)
    missing[8:11] = True  # frames 8, 9, 10
    near = near_hole(missing, 2)
    assert np.flatnonzero(near).tolist() == [6, 7, 11, 12]
    assert not (near & missing).any()


def test_near_hole_with_two_holes_and_a_hole_at_the_start():
    missing = np.zeros(12, bool)
    missing[[0, 1, 9]] = True
    assert np.flatnonzero(near_hole(missing, 1)).tolist() == [2, 8, 10]


def test_pooled_weighs_every_frame_alike():
    errors = [np.array([1.0, 2.0, 3.0]), np.array([10.0])]
    where = [np.array([True, False, True]), np.array([True])]
    assert pooled(errors, where) == (1.0 + 3.0 + 10.0) / 3


def test_slerped_over_reads_the_hole_as_motion():
    clip = _clip(0).motion
    mask = np.ones((60, 22), bool)
    mask[20:35] = False
    (over,) = slerped_over([clip], [mask])
    assert over.joint_mask is None  # nothing marked missing: the old path read it as motion
    np.testing.assert_array_equal(over.pose_body, with_holes(clip, mask, "slerp").pose_body)
    assert clip.joint_mask is None and not np.allclose(over.pose_body[25], clip.pose_body[25])


def test_noise_conditions_pose_ndf_and_video():
    clips = [_clip(1), _clip(2)]
    (clean_label, clean, kind0), (noisy_label, noisy, kind1) = conditions("pose-ndf")
    assert (clean_label, noisy_label) == ("sigma = 0", "sigma = 0.1")
    assert kind0 == kind1 == "mocap"
    assert clean(clips)[0] is clips[0].motion
    gap = rotation_gap(noisy(clips)[0].pose_body, clips[0].motion.pose_body).mean()
    assert abs(gap - 0.1 * np.sqrt(8 / np.pi)) < 0.01  # the mean angle of N(0, 0.1^2 I3) turns
    ((label, video, kind),) = conditions("video")
    assert kind == "video" and "video" in label
    a, b = video(clips)[0], video(clips)[0]
    np.testing.assert_array_equal(a.pose_body, b.pose_body)  # seeded by the clip's name
    assert not np.allclose(a.pose_body, clips[0].motion.pose_body)
