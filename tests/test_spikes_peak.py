"""A clean take's one-frame-wide peak under 30 Hz is motion, not a spike (infer/noise_blend.py).

A walk's ankle at toe-off (AV_8Walk, xyz_end_joints rig, clean, read at 24 Hz) peaks on one
frame 15 degrees from its neighbours' midpoint; its own motion reads as 0.8 degrees of noise
(0.05 at 120 Hz), which made the channel "noisy" and the peak a spike: filled, the ankle's
peak came back 10.7 degrees lower."""

from __future__ import annotations

import numpy as np

from mdvae_cli.infer.input_noise import noise_variance
from mdvae_cli.infer.noise_blend import SPIKE_FLOOR_RAD, spike_frames


def _ankle(fps: float, noise_deg: float, seed: int = 0) -> np.ndarray:
    """(T, 1, 3): a bump of 0.5 rad, 0.1 s wide, every whole second (sampled on its top), with
    white noise of ``noise_deg`` per component."""
    t = np.arange(int(6 * fps)) / fps
    phase = (t + 0.5) % 1.0 - 0.5
    x = 0.5 * np.exp(-((phase / 0.05) ** 2))
    v = np.zeros((len(t), 1, 3))
    v[:, 0, 0] = x
    return v + np.radians(noise_deg) * np.random.default_rng(seed).normal(size=v.shape)


def test_a_clean_peak_at_24hz_is_no_spike_and_a_glitch_still_is():
    v = _ankle(24.0, 0.7)
    noise = noise_variance(v)
    # its noise reads as 0.7 degrees: spikes are SPIKE_LEVELS levels of it, over the floor
    assert 8 * np.sqrt(4.5 * noise[0]) > SPIKE_FLOOR_RAD
    peaks = np.arange(24, len(v) - 2, 24)  # the bump's top, one frame a second
    assert len(peaks) >= 5
    assert not spike_frames(v, noise, SPIKE_FLOOR_RAD, 24.0)[peaks].any()  # were all spikes
    # read as 30 Hz values, where the floor was set, the rule is as it was
    assert spike_frames(v, noise, SPIKE_FLOOR_RAD)[peaks].any()
    glitch = v.copy()
    glitch[42, 0] += [0.0, 0.6, 0.0]  # a frame jumping away and back
    spikes = spike_frames(glitch, noise_variance(glitch), SPIKE_FLOOR_RAD, 24.0)
    assert np.flatnonzero(spikes[:, 0]).tolist() == [42]


def test_a_noisy_channel_keeps_the_midpoint_rule_alone():
    v = _ankle(24.0, 3.0)  # noise: 8 levels are 3 floors and more
    noise = noise_variance(v)
    glitch = v.copy()
    glitch[42, 0] += [0.0, 1.2, 0.0]
    assert 42 in np.flatnonzero(spike_frames(glitch, noise, SPIKE_FLOOR_RAD, 24.0)[:, 0])
