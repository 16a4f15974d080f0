"""Rest-pose first frames (``infer.rest_pose``): found, kept verbatim, the take denoised."""

from __future__ import annotations

import numpy as np
from conftest import motion_arrays

from mdvae_cli.formats.npz_io import motion_from_arrays
from mdvae_cli.infer.rest_pose import keep_rest_frames, leading_rest_frames
from mdvae_cli.motion.motion import Motion, slice_frames

SHIFT = 0.01  # what the stub denoiser adds to every body value


def take(T: int = 90, rest: int = 0, seed: int = 0) -> Motion:
    """A smooth 30 Hz take whose first ``rest`` frames are a T-pose (every body joint near
    zero); a per-frame extra rides along."""
    m = motion_from_arrays(motion_arrays(T=T, width=156, seed=seed))
    m.pose_body[:, 15:17] += [0.0, 0.0, 1.2]  # arms down: no take is near a T-pose
    m.pose_body[:rest] = 0.0
    m.pose_body[:rest, 2:6] = 0.12  # a rig's T-pose on the body: near zero, not exactly
    m.extras["frame_ids"] = np.arange(T, dtype=np.int64)
    m.notes = ["read from a test"]
    return m


def stub_denoise(motions: list[Motion]) -> list[Motion]:
    """Adds SHIFT to the root, body and translation of every frame (frames seen recorded)."""
    stub_denoise.seen = [m.num_frames for m in motions]
    return [
        m.with_body(m.root_orient + SHIFT, m.pose_body + SHIFT, m.trans + SHIFT) for m in motions
    ]


def test_a_t_pose_frame_0_is_found_and_kept_byte_for_byte():
    for rest in (1, 3):
        m = take(rest=rest)
        before = {k: getattr(m, k).copy() for k in ("root_orient", "pose_body", "trans")}
        assert leading_rest_frames(m) == rest
        (out,) = keep_rest_frames([m], stub_denoise)
        assert stub_denoise.seen == [m.num_frames - rest]
        assert out.num_frames == m.num_frames and out.fps == m.fps
        for key in ("root_orient", "pose_body", "trans", "pose_extra"):
            got, src = getattr(out, key), getattr(m, key)
            assert got.shape == src.shape
            assert got[:rest].tobytes() == src[:rest].tobytes(), key  # verbatim
        for key in ("root_orient", "pose_body", "trans"):  # the take: denoised, exactly
            np.testing.assert_array_equal(getattr(out, key)[rest:], before[key][rest:] + SHIFT)
            np.testing.assert_array_equal(getattr(m, key), before[key])  # input untouched
        np.testing.assert_array_equal(out.extras["frame_ids"], np.arange(m.num_frames))
        which = "frame 0" if rest == 1 else f"frames 0–{rest - 1}"
        assert out.notes == ["read from a test", f"{which}: a rest pose, kept as it came"]
        assert m.notes == ["read from a test"]


def test_several_rest_frames_identical_but_not_zero_are_found():
    m = take(rest=0)
    m.pose_body[:4] = m.pose_body[40]  # an A-pose held 4 frames, then the take
    m.pose_body[4:] += 0.5
    assert leading_rest_frames(m) == 4


def test_a_take_starting_still_or_normally_gives_zero():
    m = take()
    assert leading_rest_frames(m) == 0
    still = take()
    still.pose_body[:20] = still.pose_body[20]  # stands still for 20 frames, then moves off
    assert leading_rest_frames(still) == 0
    zero = take()
    zero.pose_body[:] *= 0.01  # every frame near zero: no jump out of it
    assert leading_rest_frames(zero) == 0
    spike = take()
    spike.pose_body[0] += 0.8  # a glitch at frame 0, no rest pose: the denoiser's to clean
    assert leading_rest_frames(spike) == 0
    slow = take()
    slow.pose_body[:30] *= np.linspace(0, 1, 30)[:, None, None]  # eases out of a T-pose
    assert leading_rest_frames(slow) == 0
    (out,) = keep_rest_frames([m], stub_denoise)
    assert stub_denoise.seen == [m.num_frames]
    np.testing.assert_array_equal(out.pose_body, m.pose_body + SHIFT)
    assert out.notes == m.notes


def test_a_take_too_short_after_the_cut_goes_whole():
    m = slice_frames(take(rest=1), 0, 6)  # 6 frames at 30 Hz: 5 left after the cut
    m.notes = []
    assert leading_rest_frames(m) == 1
    (out,) = keep_rest_frames([m], stub_denoise)
    assert stub_denoise.seen == [6]
    np.testing.assert_array_equal(out.pose_body, m.pose_body + SHIFT)
    assert out.notes == []


def test_several_motions_each_cut_on_its_own():
    a, b = take(rest=2, seed=1), take(T=60, seed=2)
    out = keep_rest_frames([a, b], stub_denoise)
    assert stub_denoise.seen == [88, 60]
    assert [o.num_frames for o in out] == [90, 60]
    assert out[0].pose_body[:2].tobytes() == a.pose_body[:2].tobytes()
    np.testing.assert_array_equal(out[1].trans, b.trans + SHIFT)


def test_with_the_shipped_denoiser_the_t_pose_stays_and_the_take_is_denoised():
    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.body.skinning import BodyModel
    from mdvae_cli.infer.denoise import denoise_motions
    from mdvae_cli.infer.settings import RefineConfig
    from mdvae_cli.model.denoiser import load_denoiser

    den, _ = load_denoiser(None)
    body = BodyModel(load_body_model(None))
    m = take(T=60, rest=1)
    (out,) = keep_rest_frames(
        [m], lambda ms: denoise_motions(ms, den, body, refine=RefineConfig(steps=0), guard=True)
    )
    assert out.num_frames == 60 and out.fps == m.fps
    assert out.pose_body[0].tobytes() == m.pose_body[0].tobytes()
    assert out.trans[0].tobytes() == m.trans[0].tobytes()
    assert not np.allclose(out.pose_body[1:], m.pose_body[1:])  # the take went through it
    assert out.notes[-1] == "frame 0: a rest pose, kept as it came"
