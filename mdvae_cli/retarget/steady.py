"""How the way back reads what the retarget's per-frame fit jitters with, smoothed over time.

The retarget fits each frame of a take on its own, so on a noisy take what it gives jitters
with the share of the noise the fit spread over neighbouring joints: each driven source joint's
offset from its SMPL driver, the retargeted pelvis's miss of its target and its frame. Where
the cleaning turned the body, the way back (``way_back``, ``way_back_amc``) reads those smoothed
over time, by the weights here; where it left the body alone, exactly as they were.

A turn of a frame or two (a spike the blend filled in a clean take) is no turn of the body:
there each offset is read as it was (:func:`lasting`), but where the retarget's own offset
jumped on that frame (:func:`offset_jumps`) its neighbours' is used, and an undriven joint
under the turned one keeps its world rotation in the share it did not jump with it
(:func:`kept_below_brief_turn`).
"""

from __future__ import annotations

import numpy as np

from mdvae_cli.filters import gaussian_smooth
from mdvae_cli.geometry.rotations_np import (
    rotmat_to_rotvec,
    rotvec_to_rotmat,
)
from mdvae_cli.infer.spike_worlds import followed_share, world_jumps

#: where the cleaning turned a joint by this much or more (degrees), its source joint's offset
#: from it is read wholly smoothed over time (less: in proportion from STEADY_FROM_DEG on)
STEADY_TURN_DEG = 1.0
#: turns below this (degrees) are a joint left alone (rounding: the offset as it was)
STEADY_FROM_DEG = 0.01
#: the offsets' smoothing: a Gaussian of this standard deviation (seconds: one model frame)
STEADY_SECONDS = 1.0 / 30.0
#: an offset that leaves its neighbours' midpoint by more than this (rad) for a frame, where
#: the cleaning turned its joint briefly, is the retarget's miss of that frame
#: (:func:`offset_jumps`): CMU 05_06's right wrist jumped 15 and 21 degrees and back in the
#: retarget where the file's hand moved 2, CMU 01's upper necks and thighs 5-7. Taken only
#: where it leaves the joint steadier (:func:`brief_jumps`); at the spike floor (0.15) the
#: thighs' misses were left in, over CMU 01's 14 takes 94 pops over 5 degrees against 72
OFFSET_JUMP_RAD = 0.08


def miss_jitter(fitted: np.ndarray, target, w: np.ndarray, fps: float) -> np.ndarray:
    """What of a retargeted point's miss of its target (``fitted - target``, (T, 3) each) is
    jitter about its course over time (:data:`STEADY_SECONDS`), by ``w`` (T,) (0: none;
    :func:`turn_reading`'s weight): added to the point's move, the move goes from the miss's course
    instead of from each frame's miss.  -> (T, 3)"""
    if not w.any():
        return np.zeros_like(fitted)
    miss = fitted - np.asarray(target, dtype=np.float64)
    return w[:, None] * (miss - gaussian_smooth(miss, STEADY_SECONDS * fps))


def turn_angle(turn: np.ndarray) -> np.ndarray:
    """The angle (degrees) of rotations (..., 3, 3).  -> (...)"""
    cos = np.clip((np.trace(turn, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    return np.degrees(np.arccos(cos))


def turn_reading(turn: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """How the cleaning's turns are read, from one pass over their angles.

    weight: how wholly an offset is read smoothed where the cleaning turned a joint by
    ``turn``: 1 from :data:`STEADY_TURN_DEG` on, 0 under :data:`STEADY_FROM_DEG` (the joint
    left alone), in proportion between, of the turn as it lasts (:func:`lasting`). A turn of a
    frame or two alone (a spike filled in a clean take) leaves the offset as it was there,
    since the offset read smoothed at that frame alone would step away from its own frames
    either side by the retarget's jitter (CMU 01_08 through its own skeleton: 5-7 degree pops
    in the chest where the input was smooth). brief: where a joint was turned by
    :data:`STEADY_TURN_DEG` or more for too short a time to read its offset smoothed.
    turn: (T, ..., 3, 3) at ``fps`` -> (weight (T, ...), brief (T, ...) bool)"""
    angle = turn_angle(turn)
    lasted = lasting(angle, _radius(fps))
    weight = np.clip((lasted - STEADY_FROM_DEG) / (STEADY_TURN_DEG - STEADY_FROM_DEG), 0.0, 1.0)
    return weight, (angle >= STEADY_TURN_DEG) & (lasted < STEADY_TURN_DEG)


def offset_jumps(
    before: np.ndarray, now: np.ndarray, after: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Whether an offset jumps away at a frame and back, by more than
    :data:`OFFSET_JUMP_RAD` and more than it moves across it (the retarget missed a joint
    for a frame: the file's joint did not jump, the retargeted one did), and the midpoint of
    its neighbours.  before, now, after: the offset at the frame before, at it and after,
    (n, 3, 3) each -> (n,) bool, (n, 3, 3)"""
    jump = world_jumps(before, now, after)  # now = exp(jump) @ midpoint
    away = np.linalg.norm(jump, axis=-1)
    across = np.linalg.norm(rotmat_to_rotvec(after @ np.swapaxes(before, -1, -2)), axis=-1)
    mid = rotvec_to_rotmat(-jump) @ now
    return (away > OFFSET_JUMP_RAD) & (away > across), mid


def _radius(fps: float) -> int:
    """Frames either side of a frame over which a turn must last (one model frame, at least
    one)."""
    return max(1, int(round(STEADY_SECONDS * fps)))


def lasting(x: np.ndarray, radius: int) -> np.ndarray:
    """The morphological opening of ``x`` (T, ...) along time: the moving minimum over
    2 radius + 1 frames, then the moving maximum over as many (edges repeated): a rise that
    lasts fewer frames than that is cut down to its surroundings, a longer one kept as it
    is, dips kept.  -> (T, ...)"""
    return _moving(_moving(x, radius, np.min), radius, np.max)


def _moving(x: np.ndarray, radius: int, reduce) -> np.ndarray:
    """``reduce`` (np.min / np.max) over the frames within ``radius`` of each, along axis 0
    with edge values repeated.  x: (T, ...) -> (T, ...)"""
    padded = np.concatenate([np.repeat(x[:1], radius, 0), x, np.repeat(x[-1:], radius, 0)])
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * radius + 1, axis=0)
    return reduce(windows, axis=-1)


def steady_halo(fps: float) -> int:
    """Frames of context a stretch of a take needs each side for the way back's smoothed reads
    (``way_back.driven_rotations``, the pelvis's) to give its frames as the whole take's would
    (the smoothing's reach)."""
    return int(np.ceil(4.0 * STEADY_SECONDS * fps)) + 2 + 2 * _radius(fps)


def kept_below_brief_turn(
    G2p: np.ndarray, Gp: np.ndarray, Gj: np.ndarray, brief: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """New local rotations of a joint the cleaning does not drive, under a parent it turned
    briefly (a spike filled): the parent's turn ``D = G2p Gp^T`` carried down only in the
    share the joint's world rotation jumped with its parent in the file
    (``infer.spike_worlds.followed_share``). A joint that jumped with its parent (a glitch
    of the limb) follows it, as every undriven joint does elsewhere; one that stayed put (the
    file's hand steady under a forearm that jumped) keeps its world rotation there.

    G2p, Gp: the parent's world rotations after and before (T, 3, 3); Gj: the joint's
    before (T, 3, 3); brief: (T,) bool (:func:`turn_reading` of the parent's driver) ->
    (the frames (n,), the joint's local rotations there (n, 3, 3))"""
    t = np.flatnonzero(brief[1:-1]) + 1
    if not len(t):
        return t, np.empty((0, 3, 3))
    u = rotmat_to_rotvec(G2p[t] @ np.swapaxes(Gp[t], -1, -2))
    lam = followed_share(u, world_jumps(Gj[t - 1], Gj[t], Gj[t + 1]))
    return t, np.swapaxes(G2p[t], -1, -2) @ rotvec_to_rotmat(lam[:, None] * u) @ Gj[t]


def below_brief_turn(G2, G, brief, drive, p: int, j: int):
    """:func:`kept_below_brief_turn` of undriven joint j under p (world rotations after
    ``G2`` and before ``G`` (T, J, 3, 3); ``brief`` (T, 22) of the body's joints); nothing
    where no SMPL joint drives p. -> (frames (n,), j's local rotations there (n, 3, 3))"""
    if drive[p] < 0:
        return np.empty(0, int), np.empty((0, 3, 3))
    return kept_below_brief_turn(G2[:, p], G[:, p], G[:, j], brief[:, drive[p]])


def brief_jumps(R, before, after, Gj, brief) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the cleaning turned a driven joint briefly (``brief`` (T, n): a spike filled)
    and its offset from its driver jumped there (:func:`offset_jumps`: the retarget's own
    miss, not the file's), ``R`` (T, n, 3, 3) takes ``after`` with the offset of the frames
    either side, in place: turned by the fill of a jump the file never had, the file's joint
    would jump the other way (CMU 05_06's right hand: 18 degrees for a frame where it moved 2).
    before, after, Gj: (T, n, 3, 3) -> where (frames (m,), joints (m,)) and the offset used
    there (m, 3, 3): what reads the offset after this must read that one."""
    t, k = np.nonzero(brief[1 : len(R) - 1])
    if not len(t):
        return t, k, np.empty((0, 3, 3))
    t = t + 1
    Y = [np.swapaxes(before[t + d, k], -1, -2) @ Gj[t + d, k] for d in (-1, 0, 1)]
    jumped, mid = offset_jumps(*Y)
    # only where the neighbours' offset leaves the joint steadier than its own: where the
    # cleaning kept its driver's jump (``after`` jumps with it), its own offset keeps the
    # joint where the file had it
    own = np.linalg.norm(world_jumps(R[t - 1, k], R[t, k], R[t + 1, k]), axis=-1)
    steadier = np.linalg.norm(world_jumps(R[t - 1, k], after[t, k] @ mid, R[t + 1, k]), axis=-1)
    jumped &= steadier < own
    t, k, mid = t[jumped], k[jumped], mid[jumped]
    R[t, k] = after[t, k] @ mid
    return t, k, mid
