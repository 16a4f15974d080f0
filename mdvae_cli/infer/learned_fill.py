"""The learned fill on a whole motion: each hole's cubic curve corrected by the infiller
(``model.infiller``), which reads a window of the motion around the hole.

The infiller works at 30 Hz on windows of ``cfg.window`` frames centred on each hole; a take
at another rate is read at 30 Hz and its corrections brought back to its own frame times.
"""

from __future__ import annotations

import numpy as np
import torch

from mdvae_cli.model.infiller import (
    LONGEST_HOLE,
    NUM_ROTATIONS,
    OUTPUT_WIDTH,
    Infiller,
    apply_corrections,
    canonical,
    features,
    turn_xy,
)
from mdvae_cli.motion.holes import fill_gaps, observed
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.resample import interp_linear, resample_motion

MODEL_FPS = 30.0


def hole_runs(missing: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) of each run of True in a (T,) bool array."""
    edges = np.diff(np.concatenate([[0], missing.astype(int), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True))


def window_corrections(
    rot: np.ndarray, trans: np.ndarray, mask: np.ndarray, infiller: Infiller
) -> np.ndarray:
    """Corrections for every hole of a 30 Hz motion, in the world's heading (rotations on the
    right, per joint; the translation in world axes).

    rot: (T, 22, 3) curve-filled; trans: (T, 3); mask: (T, 22) bool -> (T, OUTPUT_WIDTH), zero
    outside the holes"""
    T = len(rot)
    L = min(infiller.cfg.window, T)
    out = np.zeros((T, OUTPUT_WIDTH))
    runs = hole_runs(~mask.all(axis=1))
    if not runs:
        return out
    starts = [int(np.clip((a + b) // 2 - L // 2, 0, T - L)) for a, b in runs]
    place, length = np.zeros((len(runs), L)), np.zeros((len(runs), L))
    for i, ((a, b), s) in enumerate(zip(runs, starts, strict=True)):
        lo, hi = max(a, s), min(b, s + L)
        place[i, lo - s : hi - s] = (np.arange(lo, hi) - a + 1) / (b - a + 1)
        length[i, lo - s : hi - s] = min(b - a, 2 * LONGEST_HOLE) / LONGEST_HOLE
    take = lambda x: torch.as_tensor(np.stack([x[s : s + L] for s in starts]))  # noqa: E731
    r, t, m = take(rot), take(trans), take(mask.astype(np.float64))
    rc, tc, yaw = canonical(r, t)
    with torch.no_grad():
        pred = infiller(features(rc, tc, m, torch.as_tensor(place), torch.as_tensor(length)))
    pred = pred.double()
    world_t = turn_xy(pred[..., 3 * NUM_ROTATIONS :], yaw)
    pred = torch.cat([pred[..., : 3 * NUM_ROTATIONS], world_t], dim=-1).numpy()
    for i, ((a, b), s) in enumerate(zip(runs, starts, strict=True)):
        lo, hi = max(a, s), min(b, s + L)
        out[lo:hi] = pred[i, lo - s : hi - s]
    return out


def learned_fill(motion: Motion, infiller: Infiller) -> Motion:
    """``motion``'s holes (``joint_mask`` False) filled by the cubic curve from the frames
    beside them, corrected by the infiller; its other frames and joints stay."""
    mask = observed(motion)
    curve = fill_gaps(motion, "hermite")
    at30 = curve if abs(curve.fps - MODEL_FPS) < 1e-6 else resample_motion(curve, MODEL_FPS)
    rot30 = np.concatenate([at30.root_orient[:, None], at30.pose_body], axis=1)
    corr = window_corrections(rot30, np.asarray(at30.trans, float), observed(at30), infiller)
    if at30 is not curve:  # back to the take's own frame times
        corr = interp_linear(corr, _source_times(curve))
    rot = np.concatenate([curve.root_orient[:, None], curve.pose_body], axis=1)
    new_rot, new_trans = apply_corrections(
        torch.as_tensor(rot)[None], torch.as_tensor(np.asarray(curve.trans, float))[None],
        torch.as_tensor(corr)[None], torch.zeros(1, dtype=torch.float64),
    )  # fmt: skip
    new_rot, new_trans = new_rot[0].numpy(), new_trans[0].numpy()
    miss = ~mask
    rot = np.where(miss[..., None], new_rot, rot)
    trans = np.where(miss[:, :1], new_trans, np.asarray(curve.trans, float))
    return curve.with_body(
        root_orient=rot[:, 0].astype(motion.root_orient.dtype),
        pose_body=rot[:, 1:].astype(motion.pose_body.dtype),
        trans=trans.astype(motion.trans.dtype),
    )


def _source_times(motion: Motion) -> np.ndarray:
    """Each of the motion's frames as a fractional 30 Hz frame index.  -> (T,)"""
    return np.arange(motion.num_frames) * (MODEL_FPS / motion.fps)
