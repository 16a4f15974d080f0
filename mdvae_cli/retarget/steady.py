"""How the way back reads what the retarget's per-frame fit jitters with, smoothed over time.

The retarget fits each frame of a take on its own, so on a noisy take what it gives jitters
with the share of the noise the fit spread over neighbouring joints: each driven source joint's
offset from its SMPL driver, the retargeted pelvis's miss of its target and its frame. Where
the cleaning turned the body, the way back (``way_back``, ``way_back_amc``) reads those smoothed
over time, by the weights here; where it left the body alone, exactly as they were.
"""

from __future__ import annotations

import numpy as np

from mdvae_cli.filters import gaussian_smooth

#: where the cleaning turned a joint by this much or more (degrees), its source joint's offset
#: from it is read wholly smoothed over time (less: in proportion from STEADY_FROM_DEG on)
STEADY_TURN_DEG = 1.0
#: turns below this (degrees) are a joint left alone (rounding: the offset as it was)
STEADY_FROM_DEG = 0.01
#: the offsets' smoothing: a Gaussian of this standard deviation (seconds: one model frame)
STEADY_SECONDS = 1.0 / 30.0


def body_weight(turn: np.ndarray) -> np.ndarray:
    """:func:`steady_weight` of the joint the cleaning turned most, frame by frame: the fit
    spreads every joint's noise over its points, so its misses are read smoothed wherever the
    cleaning turned any joint.  turn: (T, 22, 3, 3) -> (T,)"""
    return steady_weight(turn).max(axis=1)


def miss_jitter(fitted: np.ndarray, target, w: np.ndarray, fps: float) -> np.ndarray:
    """What of a retargeted point's miss of its target (``fitted - target``, (T, 3) each) is
    jitter about its course over time (:data:`STEADY_SECONDS`), by ``w`` (T,) (0: none;
    :func:`steady_weight`): added to the point's move, the move goes from the miss's course
    instead of from each frame's miss.  -> (T, 3)"""
    if not w.any():
        return np.zeros_like(fitted)
    miss = fitted - np.asarray(target, dtype=np.float64)
    return w[:, None] * (miss - gaussian_smooth(miss, STEADY_SECONDS * fps))


def steady_weight(turn: np.ndarray) -> np.ndarray:
    """How wholly an offset is read smoothed where the cleaning turned a joint by ``turn``
    (..., 3, 3): 1 from :data:`STEADY_TURN_DEG` on, 0 under :data:`STEADY_FROM_DEG` (the
    joint left alone), in proportion between.  -> (...)"""
    cos = np.clip((np.trace(turn, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.degrees(np.arccos(cos))
    return np.clip((angle - STEADY_FROM_DEG) / (STEADY_TURN_DEG - STEADY_FROM_DEG), 0.0, 1.0)


def steady_halo(fps: float) -> int:
    """Frames of context a stretch of a take needs each side for the way back's smoothed reads
    (``way_back.driven_rotations``, the pelvis's) to give its frames as the whole take's would
    (the smoothing's reach)."""
    return int(np.ceil(4.0 * STEADY_SECONDS * fps)) + 2
