"""The blend on a noisy take leaves the root rotation's fast band to the denoiser: its local
rotations below the root were made for the denoiser's root, and the input's fast root turns
and shakes the whole body with them (``infer.noise_blend``). The root's position keeps the
input's, as before: a translation turns no joint."""

from __future__ import annotations

import numpy as np

from mdvae_cli.infer.noise_blend import blend_rotations, blend_translation

T, FPS = 360, 120.0


def _track(seed: int = 0) -> np.ndarray:
    """Slow axis-angles (T, 22, 3) at FPS, amplitude <= 0.4 rad."""
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None, None] / FPS
    f = rng.uniform(0.3, 1.2, (1, 22, 3))
    ph = rng.uniform(0, 2 * np.pi, (1, 22, 3))
    return rng.uniform(0.1, 0.4, (1, 22, 3)) * np.sin(2 * np.pi * f * t + ph)


def _jolt(size: float) -> np.ndarray:
    """A quick move out and back (a Gaussian bump of 1.5 frames at frame 180, ``size`` high)
    on every axis.  -> (T, 3)"""
    return size * np.exp(-0.5 * ((np.arange(T) - 180) / 1.5) ** 2)[:, None] * np.ones(3)


def _root_input(noisy_body: bool) -> tuple[np.ndarray, np.ndarray]:
    """(input, denoised): the denoiser's output is the truth; the input's root has no noise
    but a slow offset of 0.05 rad and a jolt of 0.03 rad the denoiser's root lacks; its body
    has 0.1 rad of white noise or none."""
    truth = _track()
    src = truth.copy()
    src[:, 0] += 0.05 + _jolt(0.03)
    if noisy_body:
        src[:, 1:] += np.random.default_rng(1).normal(0.0, 0.1, src[:, 1:].shape)
    return src, truth


def test_a_noisy_takes_root_keeps_its_slow_course_and_not_its_fast_band():
    src, den = _root_input(noisy_body=True)
    out = blend_rotations(src, den, FPS)[0]
    middle = slice(30, T - 30)
    change = out[middle, 0] - den[middle, 0]
    # the slow offset, which the root's own (zero) noise does not explain, is put back ...
    np.testing.assert_allclose(change.mean(axis=0), 0.05, atol=0.005)
    # ... the jolt is not: what is left of it is its slow band's share, a quarter
    assert np.abs(change - change.mean(axis=0)).max() < 0.008
    # the body's noise is not put back either
    assert np.sqrt(((out[:, 1:] - den[:, 1:]) ** 2).mean()) < 0.015


def test_a_clean_takes_root_comes_back_whole():
    src, den = _root_input(noisy_body=False)
    out = blend_rotations(src, den, FPS)[0]
    assert np.abs(out[30:-30, 0] - src[30:-30, 0]).max() < 0.002


def test_the_translation_keeps_its_fast_band_on_a_noisy_take_too():
    t = np.arange(T) / FPS
    den = np.stack([0.8 * t, 0.1 * np.sin(2 * np.pi * 0.5 * t), 0.9 + 0.02 * np.sin(4 * t)], 1)
    src = den + 0.03 + _jolt(0.01)
    for noisy in (False, True):
        out = blend_translation(src, den, FPS, noisy=noisy)[0]
        assert np.abs(out[30:-30] - src[30:-30]).max() < 0.0005
