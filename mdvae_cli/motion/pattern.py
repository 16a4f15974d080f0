"""Pattern fill: a long hole written from another stretch of the same take, one whose frames
either side match the frames either side of the hole (what studio tools call a pattern fill).

A walk, a run, a dance step repeat: where a take misses half a second or more of every joint,
the same movement is usually somewhere else in it. For each such hole (every body joint
missing for at least :data:`MIN_SECONDS`), the stretch of the take's own observed frames of the
hole's length whose context (:data:`CONTEXT_FRAMES` frames before it and after it, at 30 Hz
spacing) is closest to the hole's context is found (the mean squared angle between their body
joints' rotations, the pelvis's heading left out); if that is within :data:`MAX_COST`, the
stretch is copied into the hole, turned so that it starts where the take left off, and bent
so that it also ends where the take comes back: each joint's rotation by a correction slerped
from the one that matches the frame before the hole to the one that matches the frame after
it, the translation by the stretch's own displacement turned by the pelvis's change of
heading, its miss at the far end spread linearly over the hole. Holes with no match keep the
fill they were given (the spline or Hermite curve).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from mdvae_cli.geometry.rotations import quat_multiply, quat_slerp, quat_to_rotvec, rotvec_to_quat
from mdvae_cli.model.windows import heading, rotation_about_z
from mdvae_cli.motion.motion import Motion

#: whole-frame holes this long or longer (seconds) are pattern-filled where a match is found;
#: shorter ones are the spline's (on 5-frame holes a match's small misfit costs more than the
#: spline's, 0.34 -> 0.37-0.40 cm on 19 test clips)
MIN_SECONDS = 0.3
#: frames of context each side of the hole and of a candidate stretch, 1/30 s apart
CONTEXT_FRAMES = 4
#: the largest mean squared angle (rad^2) between the contexts' body-joint rotations that
#: counts as a match (an RMS of 8 degrees)
MAX_COST = 0.02
#: candidate stretches start within this (seconds) of the hole: the same take's nearby motion
SEARCH_SECONDS = 120.0
#: candidate stretches compared at once
_CANDIDATE_CHUNK = 2048


def pattern_fill(
    motion: Motion, base: Motion, which: Callable[[int], bool] | None = None
) -> tuple[Motion, list[tuple[int, int, int]]]:
    """``base`` (``motion`` with its holes already filled, same frames) with each long
    whole-frame hole of ``motion`` that has a match written from the matched stretch.

    motion: the take with ``joint_mask`` (its observed frames are searched); which: whether
    the hole that starts at a frame is to be searched (None: every one; the others keep
    ``base``'s fill); -> (the filled motion, [(hole start, hole end, stretch start)] for each
    hole written)"""
    if motion.joint_mask is None:
        return base, []
    seen = np.asarray(motion.joint_mask, bool)
    whole_hole = ~seen.any(axis=1)
    frame_seen = seen.all(axis=1)
    step = max(1, int(round(motion.fps / 30.0)))
    before = -step * np.arange(CONTEXT_FRAMES, 0, -1)  # relative to the hole's first frame
    after = step * np.arange(CONTEXT_FRAMES)  # relative to the frame after the hole
    edges = np.diff(np.concatenate([[0], whole_hole.astype(int), [0]]))
    holes = list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True))
    least = max(2, int(round(MIN_SECONDS * motion.fps)))
    rot = motion.joint_rotations
    q = rotvec_to_quat(torch.as_tensor(rot, dtype=torch.float64))  # (T, 22, 4)
    out_rot = base.joint_rotations.astype(float)
    out_trans = np.array(base.trans, dtype=float)
    trans = np.asarray(motion.trans, dtype=float)
    unseen_before = np.concatenate([[0], np.cumsum(~frame_seen)])  # frames not seen in [0, t)
    # candidates are ranked in float32 (half the memory traffic; the threshold, 0.14 rad RMS,
    # is far above its rounding)
    body = q[:, 1:].float()
    written = []
    for a, b in holes:
        n = int(b - a)
        if n < least or (which is not None and not which(int(a))):
            continue
        s = best_stretch(body, unseen_before, int(a), n, before, after, motion.fps)
        if s is None:
            continue
        rows = stretch_rows(q, trans, int(a), n, s)
        out_rot[a:b], out_trans[a:b] = rows
        written.append((int(a), int(b), s))
    if not written:
        return base, []
    dtype = base.pose_body.dtype
    filled = base.with_body(
        root_orient=out_rot[:, 0].astype(dtype),
        pose_body=out_rot[:, 1:].astype(dtype),
        trans=out_trans.astype(base.trans.dtype),
    )
    return filled, written


def best_stretch(
    body: torch.Tensor,
    unseen_before: np.ndarray,
    a: int,
    n: int,
    before: np.ndarray,
    after: np.ndarray,
    fps: float,
) -> int | None:
    """The start of the observed stretch of ``n`` frames whose context best matches the
    context of the hole [a, a + n), or None when none is within :data:`MAX_COST` (or the
    hole's own context is not all observed).

    body: (T, 21, 4) the body joints' quaternions (the pelvis's heading is free to differ);
    unseen_before: (T + 1,) frames not wholly observed before each frame; before / after:
    context offsets from the first frame and from the frame after."""
    T = body.shape[0]
    first, last = int(before[0]), int(after[-1])  # the context's reach either side

    def clear(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:  # [lo, hi) all observed
        ok = (lo >= 0) & (hi <= T)
        lo_c, hi_c = np.clip(lo, 0, T), np.clip(hi, 0, T)
        return ok & (unseen_before[hi_c] == unseen_before[lo_c])

    if not (clear(np.array([a + first]), np.array([a]))[0]
            and clear(np.array([a + n]), np.array([a + n + last + 1]))[0]):  # fmt: skip
        return None
    reach = int(SEARCH_SECONDS * fps)
    starts = np.arange(max(0, a - reach), min(T, a + reach) + 1)
    starts = starts[clear(starts + first, starts + n + last + 1)]
    if len(starts) == 0:
        return None
    context = np.concatenate([a + before, a + n + after])
    offsets = torch.as_tensor(np.concatenate([before, n + after]))
    target = body[context]  # (2k, 21, 4)
    best, best_cost = None, MAX_COST
    for i in range(0, len(starts), _CANDIDATE_CHUNK):
        s = torch.as_tensor(starts[i : i + _CANDIDATE_CHUNK])
        cand = body[s[:, None] + offsets[None]]  # (S, 2k, 21, 4)
        dot = (cand * target[None]).sum(-1).abs().clamp(max=1.0)
        cost = (2.0 * torch.arccos(dot)).square().mean(dim=(1, 2))  # (S,)
        k = int(torch.argmin(cost))
        if float(cost[k]) <= best_cost:
            best, best_cost = int(s[k]), float(cost[k])
    return best


def stretch_rows(
    q: torch.Tensor, trans: np.ndarray, a: int, n: int, s: int
) -> tuple[np.ndarray, np.ndarray]:
    """The stretch [s, s + n) bent to fit the hole [a, a + n): rotations (n, 22, 3) and the
    translation (n, 3).  q: (T, 22, 4); trans: (T, 3)"""
    conj = torch.tensor([1.0, -1.0, -1.0, -1.0], dtype=q.dtype)
    start = quat_multiply(q[a - 1], q[s - 1] * conj)  # (22, 4): the stretch's frame before
    end = quat_multiply(q[a + n], q[s + n] * conj)  # onto the take's, and its frame after
    u = torch.arange(1, n + 1, dtype=q.dtype)[:, None] / (n + 1)  # (n, 1)
    fix = quat_slerp(start[None].expand(n, -1, -1), end[None].expand(n, -1, -1), u)
    rot = quat_to_rotvec(quat_multiply(fix, q[s : s + n])).numpy()
    yaw = heading(quat_to_rotvec(q[[a - 1, s - 1], 0]))  # the pelvis's headings either side
    turn = rotation_about_z(yaw[0] - yaw[1]).numpy()
    moved = (trans[s : s + n + 1] - trans[s - 1]) @ turn.T  # (n + 1, 3)
    miss = trans[a + n] - (trans[a - 1] + moved[-1])
    return rot, trans[a - 1] + moved[:-1] + u.numpy() * miss
