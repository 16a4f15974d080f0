"""The foot lock reads a take's foot jitter as at 30 Hz, whatever its rate (infer/foot_jitter.py).

Under 30 Hz a clean take's own motion reads as jitter ((30 / fps)^2 times its 30 Hz reading),
which let the lock smooth and lift a clean 24 Hz take's feet (ankles turned by 1.4 degrees on
the example walk at 24 Hz, 10.6 at 15 Hz, against 0.6 at 30 Hz)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.infer.feet import lock_feet
from mdvae_cli.infer.foot_jitter import input_jitter
from mdvae_cli.motion.resample import resample_motion

WALK = Path(__file__).resolve().parents[1] / "examples" / "walk.npz"


@pytest.fixture(scope="module")
def body() -> BodyModel:
    return BodyModel(load_body_model(None))


def _swing(fps: float, seconds: float = 20.0) -> np.ndarray:
    """Foot joints (T, 4, 3) swinging 20 cm at 1.37 Hz, sampled at ``fps``."""
    t = np.arange(int(seconds * fps)) / fps
    x = 0.2 * np.sin(2 * np.pi * 1.37 * t)
    return np.broadcast_to(np.stack([x, 0 * x, 0 * x], -1)[:, None], (len(t), 4, 3)).copy()


def test_a_smooth_motion_reads_its_30hz_jitter_and_white_noise_its_own():
    at30 = input_jitter(_swing(30.0))
    slow = _swing(24.0)
    assert input_jitter(slow) == pytest.approx(at30 * (30 / 24) ** 2, rel=0.05)  # the old reading
    assert input_jitter(slow, slow, 24.0) == pytest.approx(at30, rel=0.05)
    noise = np.random.default_rng(0).normal(0, 0.01, slow.shape)
    # the cleaned motion is the swing: the noise on it reads in full
    assert input_jitter(slow + noise, slow, 24.0) == pytest.approx(0.01 * 1.538, rel=0.08)
    # at 30 Hz and over, the cleaned motion is not read
    fast = _swing(60.0)
    assert input_jitter(fast, fast, 60.0) == input_jitter(fast)


@pytest.mark.parametrize("fps", [24.0, 15.0])
def test_a_clean_take_under_30hz_keeps_its_legs_as_at_30hz(body, fps):
    walk = load_motion(WALK)
    assert walk.fps == 30.0
    moved30 = np.abs(lock_feet(walk, body, source=walk).pose_body - walk.pose_body).max()
    slow = resample_motion(walk, fps)
    moved = np.abs(lock_feet(slow, body, source=slow).pose_body - slow.pose_body).max()
    # before: 1.41 degrees at 24 Hz, 10.57 at 15 Hz; at 30 Hz: 0.57
    assert np.degrees(moved30) < 0.6
    assert np.degrees(moved) <= np.degrees(moved30) + 0.05
