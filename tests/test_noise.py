"""add_pose_noise: Pose-NDF statistics, untouched parameters, determinism, missing joints."""

from __future__ import annotations

from pathlib import Path, PurePosixPath

import numpy as np
import pytest
from conftest import motion_arrays

from mdvae_cli.errors import InputError
from mdvae_cli.formats.npz_io import load_motion, motion_from_arrays, save_motion
from mdvae_cli.motion.noise import NoiseSettings, add_pose_noise, file_rng


def clip(T: int = 200, width: int = 156, seed: int = 0):
    return motion_from_arrays(motion_arrays(T=T, width=width, seed=seed))


@pytest.mark.parametrize("sigma", [0.1, 0.15, 0.2])
def test_pose_noise_statistics(sigma):
    motion = clip(T=200)  # 200 * 21 * 3 = 12,600 samples: std measured to ~0.6 %
    noisy = add_pose_noise(motion, sigma, np.random.default_rng(1))
    delta = (noisy.pose_body - motion.pose_body).reshape(-1)
    assert delta.size == 12_600
    assert abs(delta.std() / sigma - 1.0) < 0.05
    assert abs(delta.mean()) < 0.05 * sigma
    # every joint and axis is perturbed, at about the same level
    per_joint = (noisy.pose_body - motion.pose_body).std(axis=(0, 2))
    assert np.all(np.abs(per_joint / sigma - 1.0) < 0.2)


def test_only_body_joints_change():
    motion = clip(T=50, width=165)
    noisy = add_pose_noise(motion, 0.2, np.random.default_rng(0))
    assert np.array_equal(noisy.root_orient, motion.root_orient)
    assert np.array_equal(noisy.trans, motion.trans)
    assert np.array_equal(noisy.pose_extra, motion.pose_extra)  # hands, jaw, eyes
    assert np.array_equal(noisy.betas, motion.betas)
    assert noisy.fps == motion.fps and noisy.gender == motion.gender
    assert noisy.joint_mask is None
    assert np.all(noisy.pose_body != motion.pose_body)
    # full poses array: only columns 3..65 differ
    changed = np.any(noisy.poses != motion.poses, axis=0)
    assert changed[3:66].all() and not changed[:3].any() and not changed[66:].any()


def test_input_motion_not_modified():
    motion = clip(T=30)
    before = (motion.pose_body.copy(), motion.trans.copy())
    add_pose_noise(motion, 0.3, np.random.default_rng(0), trans_sigma=0.1, drop_frac=0.5)
    assert np.array_equal(motion.pose_body, before[0])
    assert np.array_equal(motion.trans, before[1])
    assert motion.joint_mask is None


def test_zero_sigma_is_identity():
    motion = clip(T=20)
    noisy = add_pose_noise(motion, 0.0, np.random.default_rng(0))
    assert np.array_equal(noisy.pose_body, motion.pose_body)


def test_deterministic_with_seed():
    motion = clip(T=40)
    a = add_pose_noise(motion, 0.1, np.random.default_rng(7), trans_sigma=0.01, drop_frac=0.1)
    b = add_pose_noise(motion, 0.1, np.random.default_rng(7), trans_sigma=0.01, drop_frac=0.1)
    c = add_pose_noise(motion, 0.1, np.random.default_rng(8), trans_sigma=0.01, drop_frac=0.1)
    assert np.array_equal(a.pose_body, b.pose_body)
    assert np.array_equal(a.trans, b.trans)
    assert np.array_equal(a.joint_mask, b.joint_mask)
    assert not np.allclose(a.pose_body, c.pose_body)


def test_pose_noise_independent_of_extras():
    """Turning on jitter or drops does not change the pose noise for the same seed."""
    motion = clip(T=40)
    plain = add_pose_noise(motion, 0.1, np.random.default_rng(3))
    full = add_pose_noise(motion, 0.1, np.random.default_rng(3), trans_sigma=0.05, drop_frac=0.3)
    assert np.array_equal(plain.pose_body, full.pose_body)


def test_spikes_hit_the_asked_fraction_of_body_joint_entries_on_top_of_the_same_noise():
    motion = clip(T=400)
    plain = add_pose_noise(motion, 0.05, np.random.default_rng(3))
    spiky = add_pose_noise(motion, 0.05, np.random.default_rng(3), spike_frac=0.05, spike_rad=1.0)
    changed = np.any(spiky.pose_body != plain.pose_body, axis=-1)  # (T, 21)
    assert abs(changed.mean() - 0.05) < 0.01  # 8,400 entries: 3.5 standard errors
    jump = (spiky.pose_body - plain.pose_body)[changed]
    assert abs(jump.std() - 1.0) < 0.1  # N(0, 1 rad^2) per component
    # everything else as without spikes: the other entries, root, translation, hands
    np.testing.assert_array_equal(spiky.pose_body[~changed], plain.pose_body[~changed])
    for k in ("root_orient", "trans", "pose_extra"):
        np.testing.assert_array_equal(getattr(spiky, k), getattr(plain, k))
    # and drops / jitter do not change the spikes' stream
    both = add_pose_noise(
        motion, 0.05, np.random.default_rng(3), drop_frac=0.2, spike_frac=0.05, spike_rad=1.0
    )
    np.testing.assert_array_equal(both.pose_body, spiky.pose_body)


def test_translation_jitter_statistics():
    motion = clip(T=2000)  # 6,000 samples
    noisy = add_pose_noise(motion, 0.0, np.random.default_rng(0), trans_sigma=0.02)
    delta = noisy.trans - motion.trans
    assert abs(delta.std() / 0.02 - 1.0) < 0.05
    assert np.all(np.abs(delta.std(axis=0) / 0.02 - 1.0) < 0.1)
    assert np.array_equal(noisy.root_orient, motion.root_orient)


@pytest.mark.parametrize("frac", [0.0, 0.1, 0.5, 1.0])
def test_drop_frac_marks_exact_count(frac):
    T = 37
    motion = clip(T=T)
    noisy = add_pose_noise(motion, 0.1, np.random.default_rng(0), drop_frac=frac)
    if frac == 0:
        assert noisy.joint_mask is None
        return
    assert noisy.joint_mask.shape == (T, 22) and noisy.joint_mask.dtype == bool
    assert int((~noisy.joint_mask).sum()) == round(frac * T * 22)


def test_drop_frac_combines_with_existing_mask():
    motion = clip(T=10)
    motion.joint_mask = np.ones((10, 22), dtype=bool)
    motion.joint_mask[:, 5] = False
    noisy = add_pose_noise(motion, 0.0, np.random.default_rng(0), drop_frac=0.2)
    assert not noisy.joint_mask[:, 5].any()
    assert (~noisy.joint_mask).sum() >= 44  # 10 already missing, 44 drawn (some may overlap)


def test_joint_mask_round_trips(tmp_path: Path):
    motion = clip(T=12)
    noisy = add_pose_noise(motion, 0.1, np.random.default_rng(0), drop_frac=0.25)
    save_motion(noisy, tmp_path / "n.npz")
    back = load_motion(tmp_path / "n.npz")
    assert np.array_equal(back.joint_mask, noisy.joint_mask)
    assert np.allclose(back.pose_body, noisy.pose_body)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"sigma": -0.1},
        {"sigma": float("nan")},
        {"sigma": 0.1, "trans_sigma": -1.0},
        {"sigma": 0.1, "drop_frac": 1.5},
        {"sigma": 0.1, "drop_frac": -0.1},
        {"sigma": 0.1, "spike_frac": 1.5},
        {"sigma": 0.1, "spike_frac": 0.1, "spike_rad": -1.0},
    ],
)
def test_bad_settings_raise_input_error(kwargs):
    with pytest.raises(InputError):
        add_pose_noise(clip(T=5), rng=np.random.default_rng(0), **kwargs)
    with pytest.raises(InputError):
        NoiseSettings(**{"sigma": 0.1, **kwargs}).validate()


def test_file_rng_depends_on_seed_and_path_only():
    draw = lambda seed, rel: file_rng(seed, rel).normal(size=4)  # noqa: E731
    assert np.array_equal(draw(0, "a/b.npz"), draw(0, PurePosixPath("a/b.npz")))
    assert np.array_equal(draw(0, "a/b.npz"), draw(0, Path("a") / "b.npz"))
    assert not np.allclose(draw(0, "a/b.npz"), draw(1, "a/b.npz"))
    assert not np.allclose(draw(0, "a/b.npz"), draw(0, "a/c.npz"))
    # pinned value: the stream must not change between versions or machines
    expected = [-0.86508326, -0.6010402, -0.09077255]
    assert np.allclose(file_rng(0, "clip.npz").normal(size=3), expected, atol=1e-7)
    with pytest.raises(InputError):
        file_rng(-1, "x.npz")


# --------------------------------------------------------------------------------------------
# video-like noise (--preset video)


def _video_clip(T=300, fps=30.0):
    from conftest import motion_arrays

    from mdvae_cli.formats.npz_io import motion_from_arrays

    return motion_from_arrays(motion_arrays(T=T, width=72, fps=fps, seed=5, num_betas=10))


def _only(**kept):
    from mdvae_cli.motion.noise import VideoNoise

    zero = {k: 0.0 for k in vars(VideoNoise()) if k not in ("swap_frames", "slow_time")}
    return VideoNoise().with_overrides({**zero, **kept})


def test_video_noise_white_and_slow_parts_have_their_std():
    from mdvae_cli.motion.noise import add_video_noise

    m = _video_clip(T=3000)
    white = add_video_noise(m, _only(pose_white=0.05), np.random.default_rng(0))
    d = white.pose_body - m.pose_body
    assert abs(d.std() - 0.05) < 0.002 and abs(np.corrcoef(d[1:, 0, 0], d[:-1, 0, 0])[0, 1]) < 0.1
    slow = add_video_noise(m, _only(pose_slow=0.1), np.random.default_rng(0))
    d = slow.pose_body - m.pose_body
    assert abs(d.std() - 0.1) < 0.02  # 300 slow time scales: a loose bound
    assert np.corrcoef(d[1:, 3, 1], d[:-1, 3, 1])[0, 1] > 0.98  # smooth over frames
    np.testing.assert_array_equal(slow.root_orient, m.root_orient)
    np.testing.assert_array_equal(slow.trans, m.trans)


def test_video_noise_depth_jitter_is_horizontal_and_mostly_along_one_axis():
    from mdvae_cli.motion.noise import add_video_noise

    m = _video_clip(T=3000)
    d = add_video_noise(m, _only(depth_white=0.05), np.random.default_rng(1)).trans - m.trans
    assert np.abs(d[:, 2]).max() < 1e-12
    s = np.linalg.svd(d - d.mean(0), compute_uv=False)
    assert s[1] < 1e-6 * s[0] and abs(np.linalg.norm(d, axis=1).std() - 0.05 * 0.6) < 0.02


def test_video_noise_leg_swaps_exchange_and_mirror_the_legs():
    from mdvae_cli.motion.noise import add_video_noise

    m = _video_clip(T=600)
    noisy = add_video_noise(m, _only(swap_rate=2.0), np.random.default_rng(2))
    changed = np.flatnonzero(np.abs(noisy.pose_body - m.pose_body).max(axis=(1, 2)) > 0)
    assert 0 < len(changed) < 600
    t = changed[0]
    flip = np.array([1.0, -1.0, -1.0])
    np.testing.assert_allclose(noisy.pose_body[t, 0], m.pose_body[t, 1] * flip)  # hips
    np.testing.assert_allclose(noisy.pose_body[t, 10], m.pose_body[t, 9] * flip)  # feet
    np.testing.assert_array_equal(noisy.pose_body[t, 2], m.pose_body[t, 2])  # spine kept


def test_video_noise_turns_the_root_half_a_turn_about_the_vertical():
    import torch

    from mdvae_cli.geometry.rotations import rotvec_to_rotmat
    from mdvae_cli.motion.noise import add_video_noise

    m = _video_clip(T=600)
    noisy = add_video_noise(m, _only(turn_rate=1.0), np.random.default_rng(3))
    rel = rotvec_to_rotmat(torch.tensor(noisy.root_orient)) @ rotvec_to_rotmat(
        torch.tensor(m.root_orient)
    ).transpose(1, 2)
    turned = (rel - torch.eye(3)).abs().amax(dim=(1, 2)) > 1e-6
    assert 0 < int(turned.sum()) < 600
    np.testing.assert_allclose(rel[turned].numpy(), np.tile(np.diag([-1.0, -1.0, 1.0]),
                               (int(turned.sum()), 1, 1)), atol=1e-9)  # fmt: skip


def test_video_noise_is_seeded_and_its_streams_independent():
    from mdvae_cli.motion.noise import PRESETS, add_video_noise

    m = _video_clip(T=120)
    a = add_video_noise(m, PRESETS["video"], np.random.default_rng(7))
    b = add_video_noise(m, PRESETS["video"], np.random.default_rng(7))
    np.testing.assert_array_equal(a.pose_body, b.pose_body)
    no_spikes = PRESETS["video"].with_overrides({"spike_frac": 0, "swap_rate": 0})
    c = add_video_noise(m, no_spikes, np.random.default_rng(7))
    np.testing.assert_array_equal(a.trans, c.trans)  # translation draws unchanged
    np.testing.assert_array_equal(m.pose_body, _video_clip(T=120).pose_body)  # input untouched


def test_video_noise_on_clean_clips_matches_its_calibration():
    """The preset's documented calibration (docs/model.md): on a smooth clip, the root-relative
    joint error is of the order of a frame-wise estimator's (tens of mm) and the white part's
    acceleration error is ~20 m/s^2 at 30 fps."""
    from mdvae_cli.body.builtin import builtin_body_model
    from mdvae_cli.export import pose_motion_chunks
    from mdvae_cli.motion.noise import PRESETS, add_video_noise

    m = _video_clip(T=300)
    quiet = PRESETS["video"].with_overrides({"swap_rate": 0, "turn_rate": 0, "spike_frac": 0})
    noisy = add_video_noise(m, quiet, np.random.default_rng(0))
    body = builtin_body_model()

    def joints(x):
        return np.concatenate([o.joints.double().numpy() for _, o in pose_motion_chunks(x, body)])

    jg, jn = joints(m), joints(noisy)
    rel = np.linalg.norm((jn - jn[:, :1]) - (jg - jg[:, :1]), axis=-1).mean()
    acc = lambda j: j[2:] - 2 * j[1:-1] + j[:-2]  # noqa: E731
    accel = np.linalg.norm(acc(jn) - acc(jg), axis=-1).mean() * 30**2
    assert 0.04 < rel < 0.10 and 40 < accel < 110
