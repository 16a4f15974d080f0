"""Under 30 Hz a clean channel's one-frame peak is a spike only where it leaves the lines of
both sides by far more than the channel's own fast steps (``spikes.fast_steps``): a
breakdance toe (CMU 90_28 read at 25 Hz) flicks out and back within one frame, 26 degrees
off both lines, and was filled as a glitch (its largest change 39 degrees)."""

from __future__ import annotations

import numpy as np

from mdvae_cli.infer.input_noise import noise_variance
from mdvae_cli.infer.noise_blend import SPIKE_FLOOR_RAD, spike_frames
from mdvae_cli.infer.spikes import fast_steps


def _channels(fps: float) -> np.ndarray:
    """(T, 2, 3): channel 0 swings fast (0.5 rad at 3 Hz: steps up to 22 degrees at 25 Hz),
    channel 1 slowly (0.2 rad at 0.5 Hz); both with 0.2 degrees of white noise and the same
    one-frame excursion of 0.5 rad across the swing at 1 s (frame ``fps``, its top)."""
    t = np.arange(int(6 * fps)) / fps
    v = np.zeros((len(t), 2, 3))
    v[:, 0, 0] = 0.5 * np.cos(2 * np.pi * 3.0 * t)
    v[:, 1, 0] = 0.2 * np.sin(2 * np.pi * 0.5 * t)
    v += np.radians(0.2) * np.random.default_rng(0).normal(size=v.shape)
    v[int(fps), :, 1] += 0.5
    return v


def test_a_flick_on_a_fast_channel_at_25_hz_is_motion_and_on_a_calm_one_a_glitch():
    v = _channels(25.0)
    steps = fast_steps(v)
    assert steps[0] > 0.3 and steps[1] < 0.03  # radians a frame, a tenth of frames
    spikes = spike_frames(v, noise_variance(v), SPIKE_FLOOR_RAD, 25.0)
    assert np.flatnonzero(spikes[:, 0]).tolist() == []  # before: [25]
    assert np.flatnonzero(spikes[:, 1]).tolist() == [25]


def test_at_30_hz_the_rule_is_as_it_was():
    v = _channels(30.0)
    spikes = spike_frames(v, noise_variance(v), SPIKE_FLOOR_RAD, 30.0)
    assert np.flatnonzero(spikes[:, 0]).tolist() == [30]
    assert np.flatnonzero(spikes[:, 1]).tolist() == [30]
