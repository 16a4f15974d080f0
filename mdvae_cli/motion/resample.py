"""Change a motion's frame rate: slerp on rotations, lerp on translation."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from mdvae_cli.geometry.rotations import rotvec_slerp, rotvec_wrap
from mdvae_cli.motion.motion import Motion


def resample_times(num_frames: int, fps_in: float, fps_out: float) -> np.ndarray:
    """Fractional source-frame indices of the output frames.  -> (T_out,)

    Output frames are spaced 1/fps_out apart from the first source frame and never run past
    the last one.
    """
    duration = (num_frames - 1) / fps_in
    n_out = int(np.floor(duration * fps_out + 1e-6)) + 1
    return np.arange(n_out) * (fps_in / fps_out)


def interp_linear(values: np.ndarray, src: np.ndarray) -> np.ndarray:
    """Linear interpolation along axis 0 at fractional indices.  (T, ...), (T',) -> (T', ...)"""
    i0 = np.clip(np.floor(src).astype(int), 0, len(values) - 1)
    i1 = np.clip(i0 + 1, 0, len(values) - 1)
    w = (src - i0).reshape(-1, *([1] * (values.ndim - 1)))
    return values[i0] * (1.0 - w) + values[i1] * w


def interp_cubic(values: np.ndarray, src: np.ndarray) -> np.ndarray:
    """Cubic (Catmull-Rom) interpolation along axis 0 at fractional indices; past the last
    sample the last step's velocity carries on, before the first the first one's.
    (T, ...), (T',) -> (T', ...)"""
    T = len(values)
    if T < 2:
        return np.repeat(values[:1], len(src), axis=0)
    # one extra sample at each end, continuing the end steps, so every segment has 4 points
    padded = np.concatenate([2 * values[:1] - values[1:2], values, 2 * values[-1:] - values[-2:-1]])
    i = np.clip(np.floor(src).astype(int), 0, T - 2)
    t = (src - i).reshape(-1, *([1] * (values.ndim - 1)))
    t2, t3 = t * t, t * t * t
    # the curve's weights on its four points p0..p3 (p1 at t = 0, p2 at t = 1)
    weights = (0.5 * (2 * t2 - t - t3), 0.5 * (2 - 5 * t2 + 3 * t3),
               0.5 * (t + 4 * t2 - 3 * t3), 0.5 * (t3 - t2))  # fmt: skip
    out = padded[i] * weights[0]
    term = np.empty_like(out)
    for k in (1, 2, 3):
        out += np.multiply(padded[i + k], weights[k], out=term)
    return out


def interp_rotvec(rotvecs: np.ndarray, src: np.ndarray) -> np.ndarray:
    """Slerp axis-angles along axis 0 at fractional indices.  (T, ..., 3), (T',) -> (T', ..., 3)"""
    i0 = np.clip(np.floor(src).astype(int), 0, len(rotvecs) - 1)
    i1 = np.clip(i0 + 1, 0, len(rotvecs) - 1)
    r = torch.as_tensor(rotvecs, dtype=torch.float64)
    # a time on a frame (w = 0) is that frame, wrapped as the slerp wraps it (a 120 Hz take
    # read at 30 Hz has no other)
    out = rotvec_wrap(r[i0]).numpy()
    between = np.flatnonzero(src - i0 != 0.0)
    if len(between):
        w = torch.as_tensor(src[between] - i0[between]).reshape(-1, *([1] * (rotvecs.ndim - 2)))
        a, b = r[i0[between]], r[i1[between]]
        out[between] = rotvec_slerp(a, b, w.expand(a.shape[:-1])).numpy()
    return out


def resample_motion(motion: Motion, fps_out: float) -> Motion:
    """Resample to ``fps_out``; returns ``motion`` itself when the rate already matches.

    Per-frame extras (arrays whose first dim is T, numeric) are linearly interpolated; the
    joint mask takes the nearest frame.
    """
    if abs(motion.fps - fps_out) < 1e-9:
        return motion
    src = resample_times(motion.num_frames, motion.fps, fps_out)
    return sampled_motion(
        motion,
        src,
        fps_out,
        interp_rotvec(motion.root_orient, src),
        interp_rotvec(motion.pose_body, src),
        interp_linear(motion.trans, src),
    )


def sampled_motion(
    motion: Motion,
    src: np.ndarray,
    fps_out: float,
    root_orient: np.ndarray,
    pose_body: np.ndarray,
    trans: np.ndarray,
) -> Motion:
    """``motion`` at the fractional frames ``src`` (T',), with its body parameters there
    given (root_orient (T', 3), pose_body (T', 21, 3), trans (T', 3)) and the rest
    interpolated as :func:`resample_motion` does."""
    T = motion.num_frames
    extra = motion.pose_extra
    if extra.shape[1] % 3 == 0 and extra.shape[1] > 0:
        extra = interp_rotvec(extra.reshape(T, -1, 3), src).reshape(len(src), -1)
    else:
        extra = interp_linear(extra, src)
    extras = {}
    for k, v in motion.extras.items():
        per_frame = v.ndim >= 1 and v.shape[0] == T and np.issubdtype(v.dtype, np.number)
        extras[k] = interp_linear(v.astype(np.float64), src).astype(v.dtype) if per_frame else v
    mask = None
    if motion.joint_mask is not None:
        mask = motion.joint_mask[np.clip(np.rint(src).astype(int), 0, T - 1)]
    return Motion(
        root_orient=root_orient,
        pose_body=pose_body,
        trans=trans,
        betas=motion.betas.copy(),
        fps=float(fps_out),
        pose_extra=extra,
        gender=motion.gender,
        joint_mask=mask,
        extras=extras,
        layout=dict(motion.layout),
        notes=list(motion.notes),
    )


def time_warp(motion: Motion, speed: float, fps_out: float) -> Motion:
    """The motion played ``speed`` times as fast (0.8 = slower, 1.25 = faster), sampled at
    ``fps_out``: the same poses and path, reached in 1/speed of the time (training-data
    augmentation: a walk at another cadence, a kick thrown faster). ``speed`` > 0."""
    if not speed > 0:
        raise ValueError(f"speed must be > 0, got {speed}")
    return resample_motion(replace(motion, fps=motion.fps * speed), fps_out)
