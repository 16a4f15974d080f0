"""Takes that loop (a game cycle whose last frame meets its first), denoised as a cycle.

A loop played on repeat has no ends: its first frames follow its last ones. Denoised as a
take, the two ends are each guessed from one side only and the seam jumps when it plays. As a
cycle it is tiled three times (the root moving on by the loop's own displacement each time, so
a walk cycle keeps walking), denoised as one motion, and the middle copy is kept, with context
on both sides; what small mismatch remains between the middle copy's start and the next copy's
is spread linearly over the cycle, so that the last frame leads into the first exactly as any
two frames do.

A take is a loop only when its ends meet twice over: in rotations, relative to its own
frame-to-frame steps, and in joint positions, within an absolute few centimetres (a take
that ends 13 cm from where it started is no loop, however fast it moves between). The root
may move on by the loop's displacement only when the take travels steadily (a walk cycle);
a take that wanders and comes back nearly where it started must come back exactly.

Pure numpy on Motion values.
"""

from __future__ import annotations

import functools
from dataclasses import replace

import numpy as np
import torch

from mdvae_cli.body.data import SMPL_PARENTS, BodyModelData
from mdvae_cli.filters import savgol_smooth
from mdvae_cli.geometry import rotations_np
from mdvae_cli.geometry.kinematics import forward_kinematics
from mdvae_cli.geometry.rotations import rotvec_unwrap
from mdvae_cli.motion.motion import Motion

#: a take is a loop when its last pose is this close to its first, in frame-to-frame steps
LOOP_STEPS = 2.0
#: copies of a loop denoised together (the middle one is kept)
COPIES = 3
#: a loop's first and last poses meet within this mean joint distance (m)
LOOP_DISTANCE = 0.05
#: a take travels steadily when its root ends at least this share of its (horizontal) path
#: length from where it started
STEADY_TRAVEL = 0.5


def _rotations(motion: Motion) -> np.ndarray:
    """(T, 22, 3): root orientation then the 21 body joints."""
    return motion.joint_rotations


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Mean rotation angle between two sets of axis-angles (..., 22, 3) -> (...)

    Through quaternions (the angle of conj(q_a) q_b is 2 atan2(|v|, |w|)): the same angle as
    the norm of ``rotmat_to_rotvec(R_a^T R_b)``, a quarter of the work on a long take."""
    qa, qb = rotations_np.rotvec_to_quat(a), rotations_np.rotvec_to_quat(b)
    wa, va, wb, vb = qa[..., 0], qa[..., 1:], qb[..., 0], qb[..., 1:]
    w = wa * wb + (va * vb).sum(-1)
    v = wa[..., None] * vb - wb[..., None] * va - rotations_np.cross(va, vb)
    return (2 * np.arctan2(np.linalg.norm(v, axis=-1), np.abs(w))).mean(axis=-1)


def looks_like_loop(
    motion: Motion, steps: float = LOOP_STEPS, body: BodyModelData | None = None
) -> bool:
    """Whether the last frame meets the first (module docstring), both measured on the
    motion smoothed over 9 frames (local quadratics): its pose (every joint's rotation, the
    root's heading included) is within ``steps`` typical frame-to-frame steps of the first's,
    and within LOOP_DISTANCE in joint positions (:func:`end_gaps`, posed on ``body``, None:
    the built-in body). Takes under 4 frames are never loops."""
    if motion.num_frames < 4:
        return False
    # judged on the motion smoothed over 9 frames (local quadratics, which keep a cycle's ends
    # where they are): on a noisy take every frame-to-frame step is mostly noise, and any two
    # poses would look a step or two apart
    T = motion.num_frames
    window = min(9, T - 1 + T % 2)
    body = _default_body() if body is None else body
    joints = rest_joints(body, np.asarray(motion.betas, dtype=np.float64))
    # the end poses first: they need the ends alone, and most takes fail there (a long take is
    # then never smoothed whole)
    near = slice(None) if T <= 2 * window else np.r_[:window, T - window : T]
    if pose_gap(smoothed_ends(motion.joint_rotations_at(near), window), joints) > LOOP_DISTANCE:
        return False
    raw = _rotations(motion)
    rot = savgol_smooth(raw, window, 2)
    step = float(np.median(_angle(rot[:-1], rot[1:])))
    gap = float(_angle(rot[-1:], rot[:1])[0])
    if gap > steps * max(step, 1e-4):
        return False
    trans = savgol_smooth(np.asarray(motion.trans, dtype=np.float64), window, 2)
    return root_gap(trans) <= LOOP_DISTANCE


def which_loop(motions: list[Motion]) -> list[bool]:
    """:func:`looks_like_loop` on each motion, its ends posed on the built-in body, built once
    for all of them."""
    body = _default_body() if motions else None
    return [looks_like_loop(m, body=body) for m in motions]


@functools.cache
def _default_body() -> BodyModelData:
    """The built-in body the ends are posed on (imported here: it is built only when asked),
    built once in a process (0.035 s; ``mdvae denoise`` judges its takes' ends twice) and
    only read."""
    from mdvae_cli.body.builtin import builtin_body_model

    return builtin_body_model()


def smoothed_ends(x: np.ndarray, window: int) -> np.ndarray:
    """The first and last frames of ``savgol_smooth(x, window, 2)``, from the first and last
    ``window`` frames alone (the smoothing fits the end frames to them).  (T, ...) -> (2, ...)"""
    if x.shape[0] <= 2 * window:
        return savgol_smooth(x, window, 2)[[0, -1]]
    return np.stack([savgol_smooth(x[:window], window, 2)[0],
                     savgol_smooth(x[-window:], window, 2)[-1]])  # fmt: skip


def rest_joints(body: BodyModelData, betas: np.ndarray) -> np.ndarray:
    """The body's 22 rest joints for shape ``betas`` (extra coefficients dropped, missing ones
    zero).  betas: (S,) -> (22, 3)"""
    S = min(body.num_betas, betas.shape[-1])
    verts = body.v_template + body.shapedirs[..., :S] @ betas[:S]
    return body.J_regressor[:22] @ verts


def posed_joints(rot: np.ndarray, joints: np.ndarray) -> np.ndarray:
    """Forward kinematics of the 22 body joints, root at the origin.

    rot: (N, 22, 3) axis-angles (root first); joints: (22, 3) rest joints -> (N, 22, 3)
    """
    parents = SMPL_PARENTS[:22]
    offsets = joints - joints[[max(p, 0) for p in parents]]  # the root's: zero
    return forward_kinematics(rotations_np.rotvec_to_rotmat(rot), offsets, parents)[1]


def pose_gap(rot: np.ndarray, joints: np.ndarray) -> float:
    """The mean distance (m) of the first and last poses' joints, the root's translation
    removed.  rot: (T, 22, 3) axis-angles (only the first and last frames are read); joints:
    (22, 3) rest joints"""
    ends = posed_joints(rot[[0, -1]], joints)
    return float(np.linalg.norm(ends[1] - ends[0], axis=-1).mean())


def root_gap(trans: np.ndarray) -> float:
    """How far (m) the root ends from where it started, less the loop's displacement when the
    take travels steadily (its root ends at least STEADY_TRAVEL of its horizontal path length
    from its start).  trans: (T, 3) root translation (z up)"""
    moved = trans[-1] - trans[0]
    path = float(np.linalg.norm(np.diff(trans[:, :2], axis=0), axis=-1).sum())
    steady = float(np.linalg.norm(moved[:2])) >= STEADY_TRAVEL * max(path, 1e-9)
    return abs(float(moved[2])) if steady else float(np.linalg.norm(moved))


def displacement(motion: Motion) -> np.ndarray:
    """How far the root moves per cycle: last minus first position plus one more step (the
    step from the last frame into the next cycle's first).  -> (3,)"""
    trans = motion.trans
    return trans[-1] - trans[0] + (trans[-1] - trans[-2])


def tile(motion: Motion, copies: int = COPIES) -> Motion:
    """The cycle played ``copies`` times; each copy's root moved on by :func:`displacement`.
    Per-frame extras are tiled too."""
    T = motion.num_frames
    shift = np.repeat(np.arange(copies), T)[:, None] * displacement(motion)[None]

    def rep(a: np.ndarray) -> np.ndarray:
        return np.concatenate([a] * copies, axis=0)

    extras = {
        k: (rep(v) if v.ndim >= 1 and v.shape[0] == T and v.dtype.kind in "biuf" else v)
        for k, v in motion.extras.items()
    }
    return replace(
        motion,
        root_orient=rep(motion.root_orient),
        pose_body=rep(motion.pose_body),
        trans=rep(motion.trans) + shift,
        pose_extra=rep(motion.pose_extra),
        joint_mask=None if motion.joint_mask is None else rep(motion.joint_mask),
        extras=extras,
        notes=[],
    )


def untile(denoised: Motion, motion: Motion, copies: int = COPIES) -> Motion:
    """The middle copy of a denoised tiling, closed into a cycle: the jump between its start
    and the next copy's start (less the loop's displacement) is spread linearly over the
    cycle. Written into a copy of ``motion`` (the input cycle)."""
    T = motion.num_frames
    mid = (copies // 2) * T
    rot = denoised.joint_rotations
    # continuous axis-angles over the middle copy and the first frame of the next one
    seq = rotvec_unwrap(torch.as_tensor(rot[mid : mid + T + 1], dtype=torch.float64)).numpy()
    ramp = (np.arange(T) / T)[:, None, None]
    rot_out = seq[:T] - ramp * (seq[T] - seq[0])[None]
    step = displacement(motion)
    trans = denoised.trans[mid : mid + T + 1] - (copies // 2) * step  # back to the first copy
    jump = trans[T] - trans[0] - step
    trans_out = trans[:T] - (np.arange(T) / T)[:, None] * jump[None]
    return motion.with_body(root_orient=rot_out[:, 0], pose_body=rot_out[:, 1:], trans=trans_out)
