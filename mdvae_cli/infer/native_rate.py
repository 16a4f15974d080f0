"""The denoiser reads motion at 30 Hz; a take keeps its own rate.

:func:`to_model_rate` gives the networks a faster take averaged over one 30 Hz frame (not one
frame picked in every few, which keeps all of their noise and aliases the motion), and
:func:`to_input_rate` puts the 30 Hz result back at the take's own frame times along cubic
curves (no straight lines between samples, no frozen frames after the last one). What the
take's own motion between the samples holds is put back by the blend (``infer.noise_blend``).
"""

from __future__ import annotations

import numpy as np
import torch

from mdvae_cli.filters import gaussian_smooth, smooth_rotvecs
from mdvae_cli.geometry.rotations import rotvec_unwrap, rotvec_wrap
from mdvae_cli.model.chunks import MODEL_FPS
from mdvae_cli.model.state import BodyParams
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.resample import (
    interp_cubic,
    interp_linear,
    interp_rotvec,
    resample_motion,
    resample_times,
    sampled_motion,
)


def to_input_rate(params30: BodyParams, source: Motion) -> BodyParams:
    """Sample a 30 Hz result at the source's own frame times (same frame count as the input),
    by cubic curves through the 30 Hz samples (Catmull-Rom, on unwrapped axis-angles), so that
    a high-rate take comes back as smooth motion at its own rate, not as 30 Hz samples joined
    by straight lines; frames past the last 30 Hz sample carry its motion on (no frozen tail).
    """
    if abs(source.fps - MODEL_FPS) < 1e-9:
        return params30
    src = np.arange(source.num_frames) * (MODEL_FPS / source.fps)

    def rotations(r: torch.Tensor) -> torch.Tensor:
        unwrapped = rotvec_unwrap(r.double(), dim=0).numpy()
        return rotvec_wrap(torch.as_tensor(interp_cubic(unwrapped, src)))

    return BodyParams(
        rotations(params30.root_orient),
        rotations(params30.pose_body),
        torch.as_tensor(interp_cubic(params30.trans.double().numpy(), src)),
    )


def to_model_rate(motion: Motion) -> Motion:
    """The motion at 30 Hz as the denoiser reads it. A faster take is first smoothed over
    about one 30 Hz frame (a Gaussian of 0.4 of the rate ratio, in its own frames), so that
    the 30 Hz samples average the frames between them instead of picking one of each few
    (which keeps all of its noise and aliases its motion). The smoothing is worked out only
    at the frames the 30 Hz samples read (a quarter of a 120 Hz take's)."""
    ratio = motion.fps / MODEL_FPS
    if ratio <= 1.0 + 1e-6:
        return resample_motion(motion, MODEL_FPS)
    T, sigma = motion.num_frames, 0.4 * ratio
    src = resample_times(T, motion.fps, MODEL_FPS)
    below = np.clip(np.floor(src).astype(np.int64), 0, T - 1)
    between = src - below > 1e-9
    frames = np.unique(np.concatenate([below, np.minimum(below[between] + 1, T - 1)]))
    at = np.searchsorted(frames, below) + (src - below)  # src, in the rows of ``frames``

    def smooth(x: np.ndarray) -> np.ndarray:
        return gaussian_smooth(x, sigma, at=frames)

    body = motion.joint_rotations
    rot = smooth_rotvecs(body, smooth, at=frames)
    rot = interp_rotvec(rot, at)
    trans = interp_linear(smooth(np.asarray(motion.trans, np.float64)), at)
    return sampled_motion(motion, src, MODEL_FPS, rot[:, 0], rot[:, 1:], trans)
