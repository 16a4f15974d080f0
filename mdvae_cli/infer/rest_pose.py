"""Rest-pose first frames (a T-pose that exporters write before the take), kept as they came.

Perception Neuron, Rokoko and other exporters write frame 0 (sometimes the first few frames)
as the skeleton's rest pose, then the take. Denoised with the take, that rest frame is
smeared into the take's first quarter second; it is no noise to remove, so it is cut off
before denoising and put back verbatim after.

A leading block of frames is a rest pose when its body-joint rotations are near zero (a
T-pose on the SMPL body) or, over two frames or more, identical to each other, and the take
then jumps away from it by far more than its own typical frame-to-frame step. A take that
merely starts standing still moves off smoothly: no jump, no rest pose.

Pure numpy on Motion values; ``keep_rest_frames`` wraps any denoise callable.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.geometry.rotations_np import rotmat_to_rotvec, rotvec_to_rotmat
from mdvae_cli.motion.motion import Motion, slice_frames

#: at most this many leading frames are taken for a rest pose
MAX_REST_FRAMES = 10
#: a frame whose body joints are turned less than this (rad) from zero on average is at rest
#: (a T-pose on the SMPL body): a rig's T-pose retargeted onto the body leaves its joints
#: 0.09-0.23 rad from zero on average (the CMU Daz-friendly BVH takes' frame 0; shared real
#: BVH takes with their frame 0 set to their rest pose), while frames of takes are 0.25 and
#: more (the 1st percentile of the imported CMU corpus, file by file)
REST_ANGLE = 0.25
#: two frames whose body joints differ by less than this (rad) are the same pose
SAME_ANGLE = 1e-4
#: the jump out of a rest pose: at least this (rad, the joint that turns most) ...
MIN_JUMP = 0.3
#: ... and at least this many times the take's median frame-to-frame step (a fast 30 Hz take
#: jumps out of its T-pose by 7x its median step)
JUMP_RATIO = 5.0


def joint_angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation angle (rad) between two sets of axis-angles, joint by joint.

    a, b: (..., J, 3) -> (..., J)
    """
    ra, rb = rotvec_to_rotmat(a), rotvec_to_rotmat(b)
    return np.linalg.norm(rotmat_to_rotvec(ra.swapaxes(-1, -2) @ rb), axis=-1)


def _leading_run(flags: np.ndarray) -> int:
    """How many leading entries of a bool array (T,) are True."""
    off = np.flatnonzero(~flags)
    return int(off[0]) if off.size else int(flags.size)


def rest_block(pose_body: np.ndarray, max_frames: int = MAX_REST_FRAMES) -> int:
    """Length of the leading block of rest-like frames (before any jump is looked at): frames
    whose body joints are within REST_ANGLE of zero on average, or (two frames or more) all
    the same pose as frame 0.

    pose_body: (T, 21, 3) -> int in [0, max_frames]
    """
    head = pose_body[: max_frames + 1]
    zero = np.linalg.norm(head, axis=-1).mean(axis=-1) < REST_ANGLE  # (n,)
    same = joint_angles(head[:1], head).max(axis=-1) < SAME_ANGLE  # (n,)
    n_zero, n_same = _leading_run(zero), _leading_run(same)
    n = max(n_zero, n_same if n_same >= 2 else 0)
    return min(n, max_frames)


def leading_rest_frames(motion: Motion, max_frames: int = MAX_REST_FRAMES) -> int:
    """How many leading frames of ``motion`` are a rest pose the take then jumps away from
    (module docstring); 0 for a take that starts as takes do, or that is all rest pose.

    The jump (the most any body joint turns from the block's last frame to the next) must be
    at least MIN_JUMP and JUMP_RATIO times the median of the same measure over the rest of
    the take.
    """
    pose = np.asarray(motion.pose_body, dtype=np.float64)
    T = pose.shape[0]
    n = rest_block(pose, max_frames)
    if n == 0 or n >= T - 2:  # no block, or hardly any take after it to compare with
        return 0
    steps = joint_angles(pose[n - 1 : -1], pose[n:]).max(axis=-1)  # (T - n,)
    jump, typical = float(steps[0]), float(np.median(steps[1:]))
    return n if jump >= MIN_JUMP and jump >= JUMP_RATIO * typical else 0


def concat_frames(head: Motion, tail: Motion) -> Motion:
    """``head``'s frames followed by ``tail``'s, as one Motion; every per-frame array (body,
    ``pose_extra``, ``joint_mask``, per-frame numeric extras) is joined, everything else
    (betas, fps, layout, notes, constant extras) is ``tail``'s.

    head: Th frames, tail: Tt frames -> Th + Tt frames
    """
    Th, Tt = head.num_frames, tail.num_frames

    def per_frame(v, n: int) -> bool:
        return (
            isinstance(v, np.ndarray) and v.ndim >= 1 and v.shape[0] == n and v.dtype.kind in "biuf"
        )

    extras = {}
    for k, v in tail.extras.items():
        h = head.extras.get(k)
        joinable = per_frame(v, Tt) and per_frame(h, Th) and h.shape[1:] == v.shape[1:]
        extras[k] = np.concatenate([h, v.astype(h.dtype, copy=False)]) if joinable else v
    if head.joint_mask is None and tail.joint_mask is None:
        mask = None
    else:
        mask = np.concatenate([_mask(head), _mask(tail)])
    return replace(
        tail,
        root_orient=np.concatenate([head.root_orient, tail.root_orient]),
        pose_body=np.concatenate([head.pose_body, tail.pose_body]),
        trans=np.concatenate([head.trans, tail.trans]),
        pose_extra=np.concatenate([head.pose_extra, tail.pose_extra]),
        joint_mask=mask,
        extras=extras,
        layout=dict(tail.layout),
        notes=list(tail.notes),
    )


def _mask(m: Motion) -> np.ndarray:
    """(T, 22) bool: the motion's joint mask, all observed when it has none."""
    return np.ones((m.num_frames, 22), bool) if m.joint_mask is None else m.joint_mask


def rest_note(frames: int) -> str:
    """The note a motion gets for its ``frames`` leading rest frames."""
    which = "frame 0" if frames == 1 else f"frames 0–{frames - 1}"
    return f"{which}: a rest pose, kept as it came"


def keep_rest_frames(
    motions: list[Motion], denoise: Callable[[list[Motion]], list[Motion]]
) -> list[Motion]:
    """``denoise(motions)`` with each motion's leading rest-pose frames
    (:func:`leading_rest_frames`) cut off before and put back verbatim after, with one note.

    A motion whose take after its rest frames would be too short to denoise
    (``infer.denoise.check_length``) goes to ``denoise`` whole. ``denoise`` must return one
    motion per motion given, each with the frame count it was given (as
    ``infer.denoise.denoise_motions`` does). -> one motion per input, same frame count and rate
    """
    from mdvae_cli.infer.denoise import check_length

    cuts = []
    for m in motions:
        k = leading_rest_frames(m)
        if k:
            try:
                check_length(slice_frames(m, k, m.num_frames))
            except InputError:
                k = 0
        cuts.append(k)
    inputs = []
    for m, k in zip(motions, cuts, strict=True):
        if k:
            take = slice_frames(m, k, m.num_frames)
            take.notes = list(m.notes)
            inputs.append(take)
        else:
            inputs.append(m)
    outputs = denoise(inputs)
    if len(outputs) != len(motions):
        raise ValueError(f"denoise gave {len(outputs)} motion(s) for {len(motions)}")
    out = []
    for m, k, o in zip(motions, cuts, outputs, strict=True):
        if k:
            o = concat_frames(slice_frames(m, 0, k), o)
            o.notes = [*o.notes, rest_note(k)]
        out.append(o)
    return out
