"""How much a take's feet shake (the foot lock's ``input_jitter``), read as at 30 Hz.

The foot lock (``infer.feet``) trusts an input's own feet as its goal, and smooths them, by how
much they shake: the median second difference of the foot joints. Its thresholds were set on
30 Hz takes; under 30 Hz a motion's own second differences grow as 1 / fps^2 while white
noise's do not, so there the share the cleaned motion explains is read as at 30 Hz (a clean
24 Hz walk would otherwise read 1.6 times as shaky and have its feet moved). Pure numpy.
"""

from __future__ import annotations

import math

import numpy as np

#: the frame rate the foot jitter's thresholds (``FootLockConfig``) were set at
JITTER_FPS = 30.0


def input_jitter(
    feet: np.ndarray, cleaned: np.ndarray | None = None, fps: float = JITTER_FPS
) -> float:
    """How much a take's foot joints shake: the median over frames and joints of
    |x[t-1] - 2 x[t] + x[t+1]| / sqrt(6), in metres. White noise of std s per axis gives 1.54 s
    (the median of a chi distribution with 3 degrees of freedom); clean mocap gives a few
    millimetres at 30 Hz, the feet being still or moving smoothly most of the time (CMU val
    clips: 0.6 to 7 mm clean, 18 to 27 mm with Pose-NDF noise of 0.02 rad, 45 to 68 mm at
    0.05 rad). Under 30 Hz (``fps``) with ``cleaned`` given, its share is read as at 30 Hz
    (:func:`at_jitter_rate`). feet, cleaned: (T, 4, 3) -> metres"""
    if len(feet) < 3:
        return 0.0
    d2 = lambda x: x[:-2] - 2 * x[1:-1] + x[2:]  # noqa: E731
    return jitter_of(at_jitter_rate(d2(feet), None if cleaned is None else d2(cleaned), fps))


def at_jitter_rate(d2: np.ndarray, d2_cleaned: np.ndarray | None, fps: float) -> np.ndarray:
    """A take's second differences as they would read at :data:`JITTER_FPS`, where the
    jitter's thresholds were set: under it a motion's own second differences grow as
    1 / fps^2 (a clean 24 Hz walk's feet read 1.6 times its 30 Hz jitter) while white noise's
    do not, so the share the cleaned motion explains is scaled by (fps / 30)^2 and the rest
    (the noise) kept. At 30 Hz and over, or without ``cleaned``, ``d2`` itself.
    d2, d2_cleaned: (N, ...) the take's and the cleaned motion's, same frames -> (N, ...)"""
    k = (fps / JITTER_FPS) ** 2
    if d2_cleaned is None or k >= 1.0:
        return d2
    return d2 - (1.0 - k) * d2_cleaned


def jitter_of(d2: np.ndarray) -> float:
    """The jitter (m) of second differences d2 (N, ..., 3): the median norm over sqrt(6)."""
    return float(np.median(np.linalg.norm(d2, axis=-1)) / math.sqrt(6))
