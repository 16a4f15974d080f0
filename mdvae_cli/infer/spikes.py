"""A take's spikes: frames of a channel that jump away from both neighbours and back by far
more than its noise, read by the blend (``infer.noise_blend``: filled as short holes) and the
foot lock's reference (``noise_blend.source_spikes``).

Pure numpy on one take's channels: values (T, C, 3), rotation vectors or positions.
"""

from __future__ import annotations

import numpy as np

#: a frame this many noise levels away from its neighbours' midpoint (and back) is a spike
SPIKE_LEVELS = 8.0
#: ... and at least this far from it (rad for rotations, m for the root's translation)
SPIKE_FLOOR_RAD = 0.15
SPIKE_FLOOR_M = 0.05
#: the rate at which a channel whose spike threshold (SPIKE_LEVELS noise levels) is under its
#: floor was read as clean; under it a smooth motion's third differences, which the noise is
#: read from, grow as (CLEAN_FPS / fps)^3 (a clean 24 Hz walk's ankle reads 0.8 degrees of
#: noise from its own motion, 0.05 at 120 Hz), and the floor with them (:func:`spike_frames`)
CLEAN_FPS = 30.0


def spike_frames(
    values: np.ndarray, noise_var: np.ndarray, floor: float, fps: float = CLEAN_FPS
) -> np.ndarray:
    """Frames of each channel that jump away from both neighbours and back, by far more than
    the noise and by at least ``floor`` (a fast move also bends the track, but it does not
    come back; on a clean take the noise is tiny, and only a real glitch is that far). On a
    clean channel (its spike threshold under the floor, scaled by :data:`CLEAN_FPS` under 30
    Hz) a frame is also one that neither side's line leads to (:func:`missed_by_both_sides`):
    a toe snapping back at toe-off, an ankle's peak at 24 Hz leave their neighbours' midpoint
    too, but the frames before them lead there; under 30 Hz the lines must miss it by
    :data:`OWN_STEP_MARGIN` of the channel's own fast steps too (a flick can last one frame).

    values: (T, C, 3), noise_var: (C,), fps: the values' rate -> (T, C) bool"""
    T = values.shape[0]
    out = np.zeros(values.shape[:2], dtype=bool)
    if T < 3:
        return out
    away = np.linalg.norm(values[1:-1] - 0.5 * (values[2:] + values[:-2]), axis=-1)
    across = np.linalg.norm(values[2:] - values[:-2], axis=-1)
    # a frame's distance from its neighbours' midpoint: variance 1.5 s^2 per component
    level = np.sqrt(1.5 * 3.0 * noise_var) + 1e-9
    out[1:-1] = (away > np.maximum(SPIKE_LEVELS * level, floor)) & (away > across)
    clean = SPIKE_LEVELS * level <= floor * max(1.0, CLEAN_FPS / fps) ** 3  # (C,)
    if T >= 5 and clean.any():
        if fps < CLEAN_FPS:  # a real flick can last one frame: missed by more than its own
            floor = np.maximum(floor, OWN_STEP_MARGIN * fast_steps(values))
        out[2:-2] &= missed_by_both_sides(values, floor) | ~clean
    return out


def missed_by_both_sides(values: np.ndarray, floor: float | np.ndarray) -> np.ndarray:
    """(T - 4, C) bool: whether frame t (2 .. T-3) lies further than ``floor`` from both the
    line through frames t-2, t-1 and the line through t+2, t+1 (extended to t).

    values: (T, C, 3); floor: one for all channels or (C,)"""
    left = np.linalg.norm(values[2:-2] - (2 * values[1:-3] - values[:-4]), axis=-1)
    right = np.linalg.norm(values[2:-2] - (2 * values[3:-1] - values[4:]), axis=-1)
    return np.minimum(left, right) > floor


#: under :data:`CLEAN_FPS` a clean channel's frame is a spike only where both sides' lines miss
#: it by this many times the channel's own fast steps (:func:`fast_steps`): a breakdance toe
#: (CMU 90_28 at 25 Hz) flicks out and back within one frame, 26 degrees off both lines, where
#: its steps reach 12 degrees on a tenth of its frames (and 90 at most)
OWN_STEP_MARGIN = 2.5
#: ... the share of a channel's frame steps at or above its fast step
FAST_STEP_SHARE = 0.1


def fast_steps(values: np.ndarray) -> np.ndarray:
    """Each channel's fast step: the size of its frame-to-frame steps that a tenth of them
    (:data:`FAST_STEP_SHARE`) reach (a glitch's own two steps are too few to move it).

    values: (T, C, 3) -> (C,)"""
    steps = np.linalg.norm(np.diff(values, axis=0), axis=-1)
    return np.quantile(steps, 1.0 - FAST_STEP_SHARE, axis=0)
