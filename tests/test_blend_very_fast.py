"""A noisy take at 120 Hz: a hinge's one noisy axis read as spikes, and the translation's noise
on one axis read at the still axes' level (CMU 07_01 AMC at 120 Hz, sigma 0.1: acceleration 71
m/s^2 against the truth's 17, with the fast band above 15 Hz, split off then, 47 without it)."""

from __future__ import annotations

import numpy as np

from mdvae_cli.infer.noise_blend import blend_rotations, blend_translation


def _walkish(T: int, fps: float, J: int = 6, seed: int = 0) -> np.ndarray:
    """(T, J, 3) smooth rotation vectors: slow swings on every axis."""
    t = np.arange(T)[:, None, None] / fps
    rng = np.random.default_rng(seed)
    amp, phase = rng.uniform(0.1, 0.5, (1, J, 3)), rng.uniform(0, 6.3, (1, J, 3))
    return amp * np.sin(2 * np.pi * 0.9 * t + phase)


def _noisy_take(T: int = 1200, fps: float = 120.0):
    """A 120 Hz take: joint 0 with heavy-tailed white noise of 0.007 rad (a Gaussian three
    times wider on 15 % of frames: its third differences' kurtosis 5.5, as a retarget's
    pelvis), the others Gaussian of 0.07 rad; the truth, the take, a denoiser's output (the
    truth with a slow error)."""
    rng = np.random.default_rng(4)
    smooth = _walkish(T, fps)
    clean = smooth.copy()
    clean[:, 0] += 0.015 * np.sin(2 * np.pi * 8.0 * np.arange(T) / fps)[:, None]
    noisy = clean + 0.07 * rng.standard_normal(clean.shape)
    wide = np.where(rng.random((T, 1)) < 0.15, 3.0, 1.0) / np.sqrt(0.85 + 0.15 * 9.0)
    noisy[:, 0] = clean[:, 0] + 0.007 * wide * rng.standard_normal((T, 3))
    denoised = smooth + 0.02 * np.sin(np.arange(T) / 30.0)[:, None, None]
    return clean, noisy, denoised


def test_a_noisy_hinge_at_120_hz_has_no_spikes():
    """An AMC knee's one dof under 0.07 rad of noise: read at its still axes' level, every
    tenth frame was a spike, filled from the noisy frames' own curve."""
    rng = np.random.default_rng(5)
    clean = _walkish(1200, 120.0)
    noisy = clean + 0.07 * rng.standard_normal(clean.shape)
    noisy[:, 1, 1:] = 0.0  # the hinge: one axis moving, with noise on it alone
    noisy[:, 1, 0] = clean[:, 1, 0] + 0.12 * rng.standard_normal(1200)
    _, _, spikes = blend_rotations(noisy, clean, 120.0)
    assert spikes[:, 1].sum() == 0, spikes[:, 1].sum()  # before: 187 of 1200


def test_translation_noise_on_one_axis_is_taken_out_of_a_noisy_take():
    """A retarget's pelvis height jitter (2 mm on one axis) beside a bounce at 8 Hz that the
    denoiser missed: the share of the jitter left (third differences) was 0.97."""
    rng = np.random.default_rng(6)
    t = np.arange(1200) / 120.0
    smooth = np.stack([0.5 * t, 0.02 * np.sin(3 * t), 0.9 + 0.01 * np.sin(6 * t)], -1)
    clean = smooth.copy()
    clean[:, 2] += 0.003 * np.sin(2 * np.pi * 8.0 * t)
    noisy = clean.copy()
    noisy[:, 2] += 0.002 * rng.standard_normal(len(t))
    out, _, _ = blend_translation(noisy, smooth, 120.0, noisy=True)
    left = np.sqrt(np.mean(np.diff(out - clean, 3, axis=0)[:, 2] ** 2) / 20) / 0.002
    assert left < 0.2, left  # before: 0.97
    same, _, _ = blend_translation(clean, clean + 1e-4, 120.0, noisy=False)
    assert np.abs(same - clean).max() < 2e-5  # a clean take's: as it came
