"""Missing frames and joints (holes) in a motion: making them, and the classical ways of
filling them (slerp / lerp, a cubic spline) that studio tools use and the learned fill is
measured against.

A hole is where ``Motion.joint_mask`` is False: (T, 22) per body joint, pelvis first; the root
translation follows the pelvis. Inside a hole the motion's values are placeholders (never NaN:
every stage downstream reads finite numbers); :func:`fill_gaps` writes them.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.interpolate import CubicSpline

from mdvae_cli.geometry.rotations import quat_slerp, quat_to_rotvec, rotvec_to_quat
from mdvae_cli.motion.motion import Motion

NUM_JOINTS = 22
FILL_METHODS = ("slerp", "spline")
#: SMPL body joints of each limb (pelvis = 0), the parts a marker set loses together
LIMBS = {
    "left_arm": (16, 18, 20),
    "right_arm": (17, 19, 21),
    "left_leg": (4, 7, 10),
    "right_leg": (5, 8, 11),
}


def observed(motion: Motion) -> np.ndarray:
    """(T, 22) bool: True where a body joint was observed (all, when the motion has no mask)."""
    if motion.joint_mask is None:
        return np.ones((motion.num_frames, NUM_JOINTS), bool)
    return np.asarray(motion.joint_mask, bool)


def hole_count(mask: np.ndarray) -> tuple[int, int]:
    """(frames with any joint missing, missing (frame, joint) entries) of a (T, 22) mask."""
    missing = ~np.asarray(mask, bool)
    return int(missing.any(axis=1).sum()), int(missing.sum())


def finite_mask(poses: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """Where a file's values are there: (T, 22) bool, False for a joint whose axis-angle has a
    NaN / inf, and for every joint of a frame whose translation has one.

    poses: (T, >= 66) axis-angles, body joints first; trans: (T, 3)."""
    T = len(poses)
    body = np.asarray(poses[:, : 3 * NUM_JOINTS], float).reshape(T, NUM_JOINTS, 3)
    ok = np.isfinite(body).all(axis=-1)
    return ok & np.isfinite(np.asarray(trans, float)).all(axis=-1, keepdims=True)


def with_holes(motion: Motion, mask: np.ndarray, method: str = "slerp") -> Motion:
    """The motion with the joints where ``mask`` (T, 22) is False marked missing (on top of
    those already missing) and their values replaced by ``method``'s fill of the rest."""
    keep = observed(motion) & np.asarray(mask, bool)
    marked = motion.with_body()
    marked.joint_mask = None if keep.all() else keep
    return fill_gaps(marked, method)


def fill_gaps(motion: Motion, method: str = "slerp") -> Motion:
    """Rewrite the missing joints of a motion from its observed frames, joint by joint.

    "slerp": spherical linear interpolation between the nearest observed frames (linear for
    the translation); "spline": a cubic spline through every observed frame (quaternions made
    sign-continuous, then normalised), what studio tools call a spline fill. Before the first
    and after the last observed frame a joint holds its nearest observed value. A joint never
    observed keeps its values. The mask stays: the values are placeholders.
    """
    if method not in FILL_METHODS:
        raise ValueError(f"fill method must be one of {FILL_METHODS}, got {method!r}")
    mask = observed(motion)
    if mask.all():
        return motion
    rot = np.concatenate([motion.root_orient[:, None], motion.pose_body], axis=1)
    rot = np.array(rot, dtype=np.float64)
    trans = np.array(motion.trans, dtype=np.float64)
    fill = _fill_quats if method == "slerp" else _spline_quats
    for j in np.flatnonzero(~mask.all(axis=0)):
        if mask[:, j].any():
            rot[:, j] = fill(rot[:, j], mask[:, j])
    if not mask[:, 0].all() and mask[:, 0].any():
        trans = _fill_values(trans, mask[:, 0], method)
    return motion.with_body(root_orient=rot[:, 0], pose_body=rot[:, 1:], trans=trans)


def unfilled(result: Motion, source: Motion) -> Motion:
    """``result`` (a motion made from ``source``, same frames) with ``source``'s values in
    ``source``'s holes: its missing joints' rotations, and its translation where the pelvis is
    missing (``denoise`` with ``fill=False``). The result keeps ``source``'s mask."""
    mask = observed(source)
    if mask.all() or result.num_frames != source.num_frames:
        return result
    rot = np.concatenate([result.root_orient[:, None], result.pose_body], axis=1).copy()
    src = np.concatenate([source.root_orient[:, None], source.pose_body], axis=1)
    rot[~mask] = src[~mask]
    trans = np.array(result.trans, dtype=np.float64)
    trans[~mask[:, 0]] = source.trans[~mask[:, 0]]
    out = result.with_body(root_orient=rot[:, 0], pose_body=rot[:, 1:], trans=trans)
    out.joint_mask = mask.copy()
    return out


def _neighbours(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For each missing frame of a (T,) mask: (frames, previous observed, next observed,
    weight of the next); the ends hold the nearest observed frame."""
    seen = np.flatnonzero(mask)
    holes = np.flatnonzero(~mask)
    k = np.searchsorted(seen, holes)
    prev = seen[np.clip(k - 1, 0, len(seen) - 1)]
    nxt = seen[np.clip(k, 0, len(seen) - 1)]
    span = np.maximum(nxt - prev, 1)
    w = np.clip((holes - prev) / span, 0.0, 1.0)
    w = np.where(k == 0, 1.0, np.where(k == len(seen), 0.0, w))
    return holes, prev, nxt, w


def _fill_quats(rotvecs: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Slerp fill of one joint.  rotvecs: (T, 3), mask: (T,) -> (T, 3)"""
    holes, prev, nxt, w = _neighbours(mask)
    r = torch.as_tensor(rotvecs)
    q = quat_slerp(rotvec_to_quat(r[prev]), rotvec_to_quat(r[nxt]), torch.as_tensor(w))
    out = rotvecs.copy()
    out[holes] = quat_to_rotvec(q).numpy()
    return out


def _spline_quats(rotvecs: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Cubic-spline fill of one joint through its observed frames.  (T, 3), (T,) -> (T, 3)"""
    seen = np.flatnonzero(mask)
    if len(seen) < 3:
        return _fill_quats(rotvecs, mask)
    q = rotvec_to_quat(torch.as_tensor(rotvecs[seen])).numpy()
    flips = np.sign(np.einsum("ti,ti->t", q[1:], q[:-1]))
    q = q * np.concatenate([[1.0], np.cumprod(np.where(flips == 0, 1.0, flips))])[:, None]
    holes, prev, nxt, w = _neighbours(mask)
    inside = (holes > seen[0]) & (holes < seen[-1])
    out = _fill_quats(rotvecs, mask)  # the ends: held
    qs = CubicSpline(seen, q, axis=0)(holes[inside])
    qs /= np.linalg.norm(qs, axis=-1, keepdims=True)
    out[holes[inside]] = quat_to_rotvec(torch.as_tensor(qs)).numpy()
    return out


def _fill_values(values: np.ndarray, mask: np.ndarray, method: str) -> np.ndarray:
    """Linear or cubic-spline fill of a (T, D) array where mask (T,) is False."""
    holes, prev, nxt, w = _neighbours(mask)
    out = values.copy()
    out[holes] = values[prev] * (1.0 - w[:, None]) + values[nxt] * w[:, None]
    seen = np.flatnonzero(mask)
    if method == "spline" and len(seen) >= 3:
        inside = holes[(holes > seen[0]) & (holes < seen[-1])]
        out[inside] = CubicSpline(seen, values[seen], axis=0)(inside)
    return out


def frame_holes(
    num_frames: int, length: int, count: int, rng: np.random.Generator, margin: int = 2
) -> np.ndarray:
    """A (T, 22) mask with ``count`` holes of ``length`` frames (every joint), apart from
    each other and at least ``margin`` observed frames from the ends; fewer when they do not
    fit."""
    mask = np.ones((num_frames, NUM_JOINTS), bool)
    for start in _starts(num_frames, length, count, rng, margin):
        mask[start : start + length] = False
    return mask


def limb_holes(
    num_frames: int,
    length: int,
    count: int,
    rng: np.random.Generator,
    limbs: tuple[str, ...] = tuple(LIMBS),
    margin: int = 2,
) -> np.ndarray:
    """A (T, 22) mask with ``count`` holes of ``length`` frames, each one limb (drawn from
    ``limbs``) missing while the rest of the body is seen."""
    mask = np.ones((num_frames, NUM_JOINTS), bool)
    for start in _starts(num_frames, length, count, rng, margin):
        joints = list(LIMBS[limbs[rng.integers(len(limbs))]])
        mask[start : start + length, joints] = False
    return mask


def _starts(T: int, length: int, count: int, rng: np.random.Generator, margin: int) -> list[int]:
    """Up to ``count`` hole starts, holes ``length`` long, apart by >= ``margin`` frames."""
    starts: list[int] = []
    room = T - 2 * margin - length
    for _ in range(20 * count):
        if len(starts) == count or room < 0:
            break
        s = margin + int(rng.integers(room + 1))
        if all(abs(s - o) >= length + margin for o in starts):
            starts.append(s)
    return sorted(starts)
