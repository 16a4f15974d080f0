"""Noise on one axis of a joint alone (an AMC knee's one dof, a BVH hinge whose other
channels hold still) is read at its share of the joint's residual: the blend takes it out
as it takes out noise on all three axes (``input_noise.component_noise_variance``)."""

from __future__ import annotations

import numpy as np

from mdvae_cli.infer.input_noise import component_noise_variance, noise_variance
from mdvae_cli.infer.noise_blend import blend_rotations


def _walkish(T: int, fps: float, seed: int = 0) -> np.ndarray:
    """(T, 4, 3) smooth rotation vectors: slow swings on every axis."""
    t = np.arange(T)[:, None, None] / fps
    rng = np.random.default_rng(seed)
    amp, phase = rng.uniform(0.1, 0.5, (1, 4, 3)), rng.uniform(0, 6.3, (1, 4, 3))
    return amp * np.sin(2 * np.pi * 0.9 * t + phase)


def test_the_noise_of_one_axis_is_its_share_of_the_joint():
    rng = np.random.default_rng(1)
    clean = _walkish(2400, 120.0)
    noisy = clean.copy()
    noisy[:, 1, 0] += 0.1 * rng.standard_normal(2400)  # joint 1: a hinge, one axis noisy
    noisy[:, 2] += 0.1 * rng.standard_normal((2400, 3))  # joint 2: all three axes
    per_joint = component_noise_variance(noisy)
    np.testing.assert_allclose(per_joint[1], 0.1**2 / 3, rtol=0.15)
    np.testing.assert_allclose(per_joint[2], 0.1**2, rtol=0.15)
    assert per_joint[0] < 1e-6 and per_joint[3] < 1e-6
    assert noise_variance(noisy)[1] < 0.1 * 0.1**2 / 3  # the pooled median sees the still axes


def test_the_blend_takes_a_hinges_noise_out():
    """A perfect denoiser's output against a 120 Hz take with white noise on one axis of a
    joint: the blend keeps under a fifth of that noise (it kept most of it when the noise was
    read by the still axes), and a clean joint comes back as it came."""
    rng = np.random.default_rng(2)
    clean = _walkish(1200, 120.0, seed=3)
    noisy = clean.copy()
    noisy[:, 1, 0] += 0.1 * rng.standard_normal(1200)
    wobble = 0.01 * np.sin(np.arange(1200) / 40.0)[:, None]  # the denoiser's own slow error
    denoised = clean.copy()
    denoised[:, 0] += wobble
    out, _, _ = blend_rotations(noisy, denoised, 120.0)
    left = np.sqrt(np.mean((out[:, 1, 0] - clean[:, 1, 0]) ** 2))
    assert left < 0.2 * 0.1, left
    assert np.abs(out[:, 0] - clean[:, 0]).max() < 2e-3  # the clean joint: the input's own


def test_a_noisy_takes_hinge_is_taken_out_under_the_clean_margin():
    """A noisy take (every joint's three axes at 0.05 rad) with a hinge whose still axes
    carry a little noise too (0.1 rad on its axis, 0.015 on the others, as a BVH knee reads
    after the retarget: 7 times the pooled median, under ``ONE_AXIS_MARGIN``): the blend
    keeps under a fifth of the hinge's noise, as on the hinge read above the margin (it kept
    three fifths of it: a CMU rider's left knee kept its noise, the right came back clean)."""
    rng = np.random.default_rng(0)
    clean = _walkish(600, 120.0, seed=3)
    clean = np.concatenate([clean, clean[:, :1] * 0.5], axis=1)  # (600, 5, 3)
    noisy = clean + 0.05 * rng.standard_normal(clean.shape)
    noisy[:, 4] = clean[:, 4] + np.array([0.1, 0.015, 0.015]) * rng.standard_normal((600, 3))
    ratio = component_noise_variance(noisy, margin=1.0)[4] / noise_variance(noisy)[4]
    assert 3.0 < ratio < 9.0, ratio  # between the noisy take's margin and the clean one's
    denoised = clean + 0.01 * np.sin(np.arange(600) / 40.0)[:, None, None]
    out, _, _ = blend_rotations(noisy, denoised, 120.0)
    left = np.sqrt(np.mean((out[:, 4, 0] - clean[:, 4, 0]) ** 2))
    assert left < 0.2 * 0.1, left
    others = np.sqrt(np.mean((out[:, :4] - clean[:, :4]) ** 2))
    assert others < 0.2 * 0.05, others  # the joints noisy on every axis: as before
