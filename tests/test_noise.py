"""add_pose_noise: Pose-NDF statistics, untouched parameters, determinism, missing joints."""

from __future__ import annotations

from pathlib import Path, PurePosixPath

import numpy as np
import pytest
from conftest import motion_arrays

from mdvae_cli.errors import InputError
from mdvae_cli.motion.noise import NoiseSettings, add_pose_noise, file_rng
from mdvae_cli.motion.npz_io import load_motion, motion_from_arrays, save_motion


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
