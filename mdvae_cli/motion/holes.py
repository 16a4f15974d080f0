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

from mdvae_cli.geometry.rotations import quat_slerp, quat_to_rotvec, rotvec_to_quat
from mdvae_cli.motion.motion import Motion

NUM_JOINTS = 22
FILL_METHODS = ("slerp", "spline", "hermite")
#: frames each side of a hole that the Hermite fill's end values and velocities are read from
HERMITE_FRAMES = 6
#: a hole longer than this (frames) has its end velocities scaled down by this over its length:
#: a person's velocity does not hold for long, and a small error in it grows with the hole
TANGENT_FRAMES = 30
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


def fill_gaps(
    motion: Motion, method: str = "slerp", tangent_frames: float = TANGENT_FRAMES
) -> Motion:
    """Rewrite the missing joints of a motion from its observed frames, joint by joint.

    "slerp": spherical linear interpolation between the nearest observed frames (linear for
    the translation); "spline": a cubic spline through every observed frame (quaternions made
    sign-continuous, then normalised), what studio tools call a spline fill; "hermite": a
    cubic from each side's value and velocity, read by a quadratic least-squares fit to
    :data:`HERMITE_FRAMES` frames beside the hole (a frame's small error does not swing the
    curve, as it does a spline's). Before the first
    and after the last observed frame a joint holds its nearest observed value. A joint never
    observed keeps its values. The mask stays: the values are placeholders.
    """
    if method not in FILL_METHODS:
        raise ValueError(f"fill method must be one of {FILL_METHODS}, got {method!r}")
    mask = observed(motion)
    if mask.all():
        return motion
    rot = motion.joint_rotations
    rot = np.array(rot, dtype=np.float64)
    trans = np.array(motion.trans, dtype=np.float64)
    fill = {"slerp": _fill_quats, "spline": _spline_quats,
            "hermite": lambda r, m: _hermite_quats(r, m, tangent_frames)}[method]  # fmt: skip
    for j in np.flatnonzero(~mask.all(axis=0)):
        if mask[:, j].any():
            rot[:, j] = fill(rot[:, j], mask[:, j])
    if not mask[:, 0].all() and mask[:, 0].any():
        if method == "hermite":
            trans = _hermite(_fill_values(trans, mask[:, 0], "slerp"), mask[:, 0], tangent_frames)
        else:
            trans = _fill_values(trans, mask[:, 0], method)
    return motion.with_body(root_orient=rot[:, 0], pose_body=rot[:, 1:], trans=trans)


def unfilled(result: Motion, source: Motion) -> Motion:
    """``result`` (a motion made from ``source``, same frames) with ``source``'s values in
    ``source``'s holes: its missing joints' rotations, and its translation where the pelvis is
    missing (``denoise`` with ``fill=False``). The result keeps ``source``'s mask."""
    mask = observed(source)
    if mask.all() or result.num_frames != source.num_frames:
        return result
    rot = result.joint_rotations.copy()
    src = source.joint_rotations
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
    from scipy.interpolate import CubicSpline

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


def _hermite_quats(rotvecs: np.ndarray, mask: np.ndarray, tangent_frames: float) -> np.ndarray:
    """Hermite fill of one joint on sign-continuous quaternions.  (T, 3), (T,) -> (T, 3)"""
    q = rotvec_to_quat(torch.as_tensor(_fill_quats(rotvecs, mask))).numpy()
    flips = np.sign(np.einsum("ti,ti->t", q[1:], q[:-1]))
    q = q * np.concatenate([[1.0], np.cumprod(np.where(flips == 0, 1.0, flips))])[:, None]
    filled = _hermite(q, mask, tangent_frames)
    filled /= np.linalg.norm(filled, axis=-1, keepdims=True)
    out = rotvecs.copy()
    out[~mask] = quat_to_rotvec(torch.as_tensor(filled[~mask])).numpy()
    return out


def hermite_fill_rows(
    rot: np.ndarray, trans: np.ndarray, frames: np.ndarray, joints: list[int]
) -> tuple[np.ndarray, np.ndarray]:
    """The Hermite fill of the same frames of several joints at once (a frame hole, or a limb
    missing together): ``joints`` rewritten where ``frames`` is False, the translation too
    when the pelvis (0) is among them.

    rot: (T, 22, 3), trans: (T, 3), frames: (T,) bool -> (rot, trans) copies"""
    rot, trans = rot.copy(), trans.copy()
    seen = np.flatnonzero(frames)
    q = rotvec_to_quat(torch.as_tensor(rot[seen][:, joints])).numpy()  # (S, J, 4)
    flips = np.sign(np.einsum("tji,tji->tj", q[1:], q[:-1]))
    signs = np.cumprod(
        np.concatenate([np.ones((1, len(joints))), np.where(flips == 0, 1.0, flips)]), 0
    )
    full = np.zeros((len(frames), len(joints), 4))
    full[seen] = q * signs[..., None]
    filled = _hermite(full.reshape(len(frames), -1), frames).reshape(full.shape)[~frames]
    filled /= np.linalg.norm(filled, axis=-1, keepdims=True)
    holes = np.flatnonzero(~frames)
    rot[np.ix_(holes, joints)] = quat_to_rotvec(torch.as_tensor(filled)).numpy()
    if 0 in joints:
        trans = _hermite(trans, frames)
    return rot, trans


def _hermite(
    values: np.ndarray, mask: np.ndarray, tangent_frames: float = TANGENT_FRAMES
) -> np.ndarray:
    """Each inner run of missing frames of ``values`` (T, D) rewritten as the cubic Hermite
    curve between its sides' fitted values and velocities; runs at the ends stay."""
    out = values.copy()
    T = len(mask)
    edges = np.diff(np.concatenate([[1], mask.astype(int), [1]]))
    for a, b in zip(np.flatnonzero(edges == -1), np.flatnonzero(edges == 1), strict=True):
        if a == 0 or b == T:
            continue
        p0, v0 = _side_fit(values, mask, a - 1, -1)
        p1, v1 = _side_fit(values, mask, b, 1)
        span = b - (a - 1)
        scale = min(1.0, tangent_frames / span)
        v0, v1 = scale * v0, scale * v1
        t = (np.arange(a, b) - (a - 1))[:, None] / span
        h00, h10 = 2 * t**3 - 3 * t**2 + 1, t**3 - 2 * t**2 + t
        h01, h11 = -2 * t**3 + 3 * t**2, t**3 - t**2
        out[a:b] = h00 * p0 + h10 * span * v0 + h01 * p1 + h11 * span * v1
    return out


def _side_fit(values: np.ndarray, mask: np.ndarray, edge: int, step: int):
    """Value and velocity (per frame) at frame ``edge`` from a quadratic least-squares fit to
    the observed frames running from it away from the hole (``step`` -1: back, 1: on)."""
    idx = [edge]
    while len(idx) < HERMITE_FRAMES:
        nxt = idx[-1] + step
        if not 0 <= nxt < len(mask) or not mask[nxt]:
            break
        idx.append(nxt)
    if len(idx) < 3:
        vel = (values[idx[-1]] - values[idx[0]]) / (step * max(len(idx) - 1, 1))
        return values[edge], vel if len(idx) > 1 else np.zeros_like(values[edge])
    t = np.asarray(idx, float) - edge
    design = np.stack([np.ones_like(t), t, t**2], axis=1)
    coef, *_ = np.linalg.lstsq(design, values[idx], rcond=None)
    return coef[0], coef[1]


def _fill_values(values: np.ndarray, mask: np.ndarray, method: str) -> np.ndarray:
    """Linear or cubic-spline fill of a (T, D) array where mask (T,) is False."""
    holes, prev, nxt, w = _neighbours(mask)
    out = values.copy()
    out[holes] = values[prev] * (1.0 - w[:, None]) + values[nxt] * w[:, None]
    seen = np.flatnonzero(mask)
    if method == "spline" and len(seen) >= 3:
        from scipy.interpolate import CubicSpline

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


#: the holes :func:`random_holes` draws: whole-frame holes (every joint) and one-limb holes,
#: lengths in frames at 30 Hz, drawn uniformly in [low, high]
RANDOM_FRAME_HOLES = (3, 45)
RANDOM_LIMB_HOLES = (10, 60)


def random_holes(num_frames: int, rng: np.random.Generator, every: int = 120) -> np.ndarray:
    """A (T, 22) mask with about one hole per ``every`` frames (at least one), each of every
    joint or of one limb (even odds), of a length drawn from :data:`RANDOM_FRAME_HOLES` or
    :data:`RANDOM_LIMB_HOLES`: what ``fit-dataset --holes`` trains the networks to read. The
    holes are drawn independently, so two may overlap into a longer one."""
    mask = np.ones((num_frames, NUM_JOINTS), bool)
    for _ in range(max(1, num_frames // every)):
        limb = bool(rng.integers(2))
        low, high = RANDOM_LIMB_HOLES if limb else RANDOM_FRAME_HOLES
        length = int(rng.integers(low, high + 1))
        make = limb_holes if limb else frame_holes
        mask &= make(num_frames, length, 1, rng, margin=2)
    return mask
