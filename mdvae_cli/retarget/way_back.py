"""The way back: a cleaned SMPL motion onto the source file's own skeleton.

A take is retargeted onto SMPL (``retarget``), cleaned there, and written again on its own
skeleton. Each source joint that drives an SMPL joint (its *rotation source*) turns by the same
world-space change as that SMPL joint did: ``G'_s = D_j G_s`` with ``D_j = G_clean_j
G_orig_j^T``, starting from the file's own rotations, so a joint the cleaning left alone keeps
its channels exactly, whatever its rest pose. Joints the SMPL proxy does not cover (fingers,
toes, twist and extra spine joints, props) keep their local channels and follow their parent.
A rotation channel that holds one value through the whole take (a hinge's other axes, feet
a video estimate never turns) is written as it came, the joint's other channels solved for
the cleaned rotation (``held_channels``). The pelvis point moves as the SMPL pelvis did; the
translation goes to the channels that carried it (the root's, or a moving pelvis's own), in
the file's units and axes; a skeleton with no position channels (a root with rotation
channels alone) drops it and stays in place.

Where the cleaning turned a joint, its source joint's offset from it is read smoothed over
time (:func:`driven_rotations`): the retarget fits each frame on its own, and on a noisy take
the offsets carry the share of the noise the fit spread over neighbouring joints, which the
turn alone would hand back to the file.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import torch

from mdvae_cli.body.data import NUM_BODY_JOINTS, SMPL_PARENTS
from mdvae_cli.errors import InputError
from mdvae_cli.filters import gaussian_smooth
from mdvae_cli.formats.bvh import BvhLayout, _positions
from mdvae_cli.formats.bvh_rotations import channel_rotations
from mdvae_cli.formats.source import SourceMotion
from mdvae_cli.geometry.euler import rotmat_to_euler
from mdvae_cli.geometry.kinematics import forward_kinematics, joint_position, world_rotations
from mdvae_cli.geometry.rotations_np import (
    quat_continuous,
    quat_to_rotmat,
    rotmat_to_quat,
    rotmat_to_rotvec,
    rotvec_to_rotmat,
)
from mdvae_cli.motion.motion import Motion, slice_frames
from mdvae_cli.retarget.fit_shape import BodyJoints
from mdvae_cli.retarget.held_channels import constant_channels, hold_channels
from mdvae_cli.retarget.joint_map import JointMap
from mdvae_cli.retarget.steady import (
    STEADY_SECONDS,
    below_brief_turn,
    brief_jumps,
    miss_jitter,
    steady_halo,
    turn_reading,
)
from mdvae_cli.workers import map_in_order

_N = NUM_BODY_JOINTS
_SPINE = (0, 3, 6, 9, 12, 15)


def smpl_globals(motion: Motion, model: BodyJoints) -> tuple[np.ndarray, np.ndarray]:
    """World rotations (T, 22, 3, 3) and joint positions (T, 22, 3) of a motion's body."""
    parents = [int(p) for p in SMPL_PARENTS[:_N]]
    X = model.rest_joints(torch.as_tensor(np.asarray(motion.betas, dtype=np.float64)))[:_N]
    T = motion.num_frames
    L = _local_rotations(motion)
    X = X.numpy()
    G = np.empty((T, _N, 3, 3))
    P = np.empty((T, _N, 3))
    G[:, 0], P[:, 0] = L[:, 0], np.asarray(motion.trans, dtype=np.float64) + X[0]
    for j in range(1, _N):
        p = parents[j]
        G[:, j] = G[:, p] @ L[:, j]
        P[:, j] = P[:, p] + G[:, p] @ (X[j] - X[p])
    return G, P


def _local_rotations(motion: Motion) -> np.ndarray:
    """The body's local rotations, the root's first.  -> (T, 22, 3, 3)"""
    T = motion.num_frames
    body = np.reshape(motion.pose_body, (T, -1, 3))[:, : _N - 1]
    pose = np.concatenate([np.reshape(motion.root_orient, (T, 1, 3)), body], axis=1)
    return rotvec_to_rotmat(pose)


def _turned_globals(motion: Motion, M: np.ndarray) -> np.ndarray:
    """``M^T`` times the world rotations of :func:`smpl_globals` (the root's turned before
    the chain goes down), without the positions.  M: (3, 3) -> (T, 22, 3, 3)"""
    L = _local_rotations(motion)
    G = np.empty_like(L)
    G[:, 0] = M.T @ L[:, 0]
    for j in range(1, _N):
        G[:, j] = G[:, int(SMPL_PARENTS[j])] @ L[:, j]
    return G


def _pelvis(motion: Motion, model: BodyJoints) -> np.ndarray:
    """The pelvis joint's world position (T, 3), as :func:`smpl_globals` gives it."""
    X = model.rest_joints(torch.as_tensor(np.asarray(motion.betas, dtype=np.float64)))[0]
    return np.asarray(motion.trans, dtype=np.float64) + X.numpy()


def drivers(jmap: JointMap, num_joints: int) -> np.ndarray:
    """Per source joint, the SMPL joint whose change it follows (-1: none, keeps its channels).

    The pelvis drives the source pelvis; where several SMPL joints share a source joint (one
    source spine joint for three SMPL ones, an ankle without toes) the deepest one drives it;
    collars the source lacks drive nothing.  -> (J,) int
    """
    cands: dict[int, list[int]] = {}
    for j in range(_N):
        s = int(jmap.rot_source[j])
        side = {13: "left_collar", 14: "right_collar"}.get(j)
        if s < 0 or (side is not None and side not in jmap.anchor):
            continue
        cands.setdefault(s, []).append(j)
    out = np.full(num_joints, -1, dtype=np.int64)
    for s, js in cands.items():
        spine = [j for j in js if j in _SPINE]
        out[s] = 0 if 0 in js else max(spine or js)
    return out


class SmplChange(NamedTuple):
    """What cleaning did to the SMPL body, in the source file's axes (``M = rt.to_output``:
    source world -> SMPL output world): each body joint's world-space turn ``turn = M^T
    G_clean G_orig^T M`` and its world rotations ``before = M^T G_orig`` and ``after = M^T
    G_clean`` (T, 22, 3, 3 each), and the pelvis's move ``shift`` (T, 3) in file units;
    ``weight`` and ``brief``: ``steady.turn_reading`` of the turns, (T, 22) each."""

    turn: np.ndarray
    before: np.ndarray
    after: np.ndarray
    shift: np.ndarray
    weight: np.ndarray
    brief: np.ndarray


def smpl_change(
    rt, original: Motion, cleaned: Motion, body: BodyJoints, scale: float, frames=slice(None)
):
    """:class:`SmplChange` from ``original`` to ``cleaned`` (``scale``: metres per file unit).
    rt: the take's RetargetResult; frames: which of its frames the motions hold (default:
    all).

    The pelvis's move is the cleaned pelvis less the retargeted one, which is its target (the
    file's pelvis) plus the fit's own miss. The retarget fits each frame on its own, so on a
    noisy take that miss jitters with the noise of the joints around the pelvis (CMU 07_01 at
    120 Hz under 0.1 rad of rotation noise: 54 m/s^2 of acceleration on the height, against
    0.8 clean), and the move would write it into the root's position channels, which had none.
    Where the cleaning turned the body (any joint's ``steady.turn_reading`` weight), the miss
    is read smoothed over time (:data:`STEADY_SECONDS`), as the driven joints' offsets are."""
    M = np.asarray(rt.to_output)
    before, after = _turned_globals(original, M), _turned_globals(cleaned, M)
    turn = after @ np.swapaxes(before, -1, -2)
    fitted = _pelvis(original, body)
    shift = _pelvis(cleaned, body) - fitted
    weight, brief = turn_reading(turn, original.fps)
    shift += miss_jitter(fitted, rt.targets[frames, 0], weight.max(axis=1), original.fps)
    return SmplChange(turn, before, after, shift @ M / scale, weight, brief)


def driven_rotations(
    change: SmplChange, G: np.ndarray, drive: np.ndarray, fps: float
) -> np.ndarray:
    """The new world rotations (T, J, 3, 3) of the source joints the body drives (``drive``,
    :func:`drivers`; the others keep ``G``'s), from their world rotations ``G`` (T, J, 3, 3)
    and ``change`` (the take's frames at ``fps``).

    A driven joint turns as its driver did: ``turn @ G``, which is ``after @ Y`` with ``Y =
    before^T @ G`` its offset from the driver. The retarget that gave ``before`` fits each
    frame on its own, so on a noisy take ``Y`` jitters with the share of the noise the fit
    spread over neighbouring joints (a one-spine rig under 0.1 rad a frame: 13 % of the change
    came back, as jitter on the spine chain). Where the driver turned by
    :data:`STEADY_TURN_DEG` or more, ``Y`` is taken smoothed over time (:data:`STEADY_SECONDS`);
    below, the smoothing's step is scaled by the turn; where the cleaning left the driver
    alone (a turn under :data:`STEADY_FROM_DEG`), the joint is ``turn @ G`` exactly (its
    channels as they were). A ``Y`` that jumped on a frame its driver was turned alone (the
    retarget's miss, ``steady.brief_jumps``) is its neighbours' there, smoothed or not."""
    out = G.copy()
    js = np.flatnonzero(drive >= 0)
    ds = drive[js]
    turn, Gj = change.turn[:, ds], G[:, js]  # (T, n, 3, 3): every driven joint at once
    after = change.after[:, ds]
    R = turn @ Gj
    w = change.weight[:, ds]
    missed = brief_jumps(R, change.before[:, ds], after, Gj, change.brief[:, ds])
    if not w.any():
        out[:, js] = R
        return out
    Y = np.swapaxes(change.before[:, ds], -1, -2) @ Gj
    Y[missed[0], missed[1]] = missed[2]
    q = quat_continuous(rotmat_to_quat(Y))  # (T, n, 4), smoothed as sign-continuous quaternions
    steady = quat_to_rotmat(gaussian_smooth(q.reshape(len(q), -1), STEADY_SECONDS * fps)
                            .reshape(q.shape))  # fmt: skip
    full = w == 1
    R[full] = after[full] @ steady[full]
    part = (w > 0) & (w < 1)  # a small turn: the step towards the smoothed offset scaled by it
    if part.any():
        Yp = Y[part]
        step = rotmat_to_rotvec(np.swapaxes(Yp, -1, -2) @ steady[part])
        R[part] = after[part] @ Yp @ rotvec_to_rotmat(w[part][:, None] * step)
    out[:, js] = R
    return out


def pelvis_point(
    rt, change: SmplChange, anchor: np.ndarray, scale: float, fps: float, frames=slice(None)
):
    """Where the source pelvis joint goes (T, 3; file units and axes): the point the SMPL
    pelvis was fitted to moves by the pelvis's ``change.shift`` and turns with it, and the
    source pelvis joint (at ``anchor`` (T, 3) before) keeps its place relative to it, read in
    the retargeted pelvis's frame. That frame carries the fit's own miss of each frame's
    rotation (on a noisy take it jitters with the noise of the joints around it), so where
    the cleaning turned the body (any joint's ``steady.turn_reading`` weight) the joint's place in
    it is read smoothed over time (:data:`STEADY_SECONDS`), as the driven joints' offsets
    are: turned by the jitter instead, a pelvis joint 5 cm from the point shook the root (CMU
    05_09 at 120 Hz under 0.1 rad of noise: 41 m/s^2 on the height, 5 clean).  fps: the
    take's rate; frames: which of the take's frames ``change`` and ``anchor`` hold (default:
    all)."""
    target = ((rt.targets[frames, 0] + rt.drop) @ np.asarray(rt.to_output)) / scale
    arm = target - anchor
    out = target + change.shift - (change.turn[:, 0] @ arm[..., None])[..., 0]
    w = change.weight.max(axis=1)
    if w.any():  # the steady arm's difference, in the world (none where w is 0: exact)
        before, after = change.before[:, 0], change.after[:, 0]
        own = (np.swapaxes(before, -1, -2) @ arm[..., None])[..., 0]
        step = w[:, None] * (gaussian_smooth(own, STEADY_SECONDS * fps) - own)
        out -= (after @ step[..., None])[..., 0]
    return out


def file_frames(src: SourceMotion, layout: BvhLayout, data: np.ndarray, rotations=None):
    """Local rotations (T, J, 3, 3) and translations (T, J, 3; the root's is its position) of
    the file's own frames ``data`` (T, C), in file units. rotations: the local rotations of
    these frames, when at hand (the reader's), else made from their channels."""
    T, J = data.shape[0], src.num_joints
    L = channel_rotations(layout, data, J) if rotations is None else rotations
    t = np.tile(layout.offsets, (T, 1, 1))
    for j in range(J):
        cols = layout.joint_columns(j, "t")
        if j == 0:
            t[:, 0] = _positions(data, cols, np.zeros(3)) + layout.offsets[0]
        elif cols and j not in layout.world_channels:
            t[:, j] = _positions(data, cols, layout.offsets[j])
    return L, t


def file_pose(src: SourceMotion, layout: BvhLayout, data: np.ndarray, rotations=None):
    """:func:`file_frames` and their world rotations and positions: L, t, G, P (T, J, ...)."""
    L, t = file_frames(src, layout, data, rotations)
    G, P = forward_kinematics(L, t, src.parents)
    return L, t, G, P


def _carrier(src: SourceMotion, layout: BvhLayout, a: int) -> int:
    """The joint whose position channels move joint a: a itself when they move it, else the
    nearest ancestor with position channels (the root); -1 when none has any (a root with
    rotation channels alone: the take stays where its OFFSETs put it)."""
    j = a
    while j >= 0:
        if layout.joint_columns(j, "t") and (j == 0 or j in layout.moving):
            return j
        j = int(src.parents[j])
    return -1


def translation_dropped(src: SourceMotion, rt) -> bool:
    """Whether no channel of the BVH take ``src`` can carry the pelvis's move (a root with
    rotation channels alone): the way back leaves the take where its OFFSETs put it."""
    return _carrier(src, src.layout, int(rt.jmap.anchor["pelvis"])) < 0


def write_back_data(
    src: SourceMotion,
    rt,
    original: Motion,
    cleaned: Motion,
    body: BodyJoints,
    chunk: int = 2048,
    progress: Callable[[int, int], None] | None = None,
) -> np.ndarray:
    """The file's channel values (F, C) with the change from ``original`` to ``cleaned`` (SMPL
    motions of the same frames as ``src``, e.g. a retarget result's motion and its denoised
    version) carried onto the file's own skeleton.  rt: the :class:`RetargetResult` of
    ``src`` (its joint map and axes). Rows the reader skipped are kept as they were. Frames
    are carried ``chunk`` at a time (each frame on its own: the same result, flat memory);
    ``progress`` is called with (frames carried, frames) after each chunk."""
    layout: BvhLayout = src.layout
    if layout is None:
        raise InputError("this motion was not read from a BVH file; it cannot be written back")
    T = len(layout.rows)
    if original.num_frames != T or cleaned.num_frames != T:
        raise InputError(f"the SMPL motions have {cleaned.num_frames} frames, the file {T}")
    out = layout.data.copy()
    halo = steady_halo(src.fps)
    held = constant_channels(layout.data, layout.rows)  # as they came (``held_channels``)

    def rows_of(i: int) -> np.ndarray:
        stop = min(i + chunk, T)
        # each chunk with the context its smoothed offsets read (driven_rotations), cut off
        frames = slice(max(0, i - halo), min(T, stop + halo))
        part = (slice_frames(m, frames.start, frames.stop) for m in (original, cleaned))
        rows = _write_back_rows(src, rt, *part, body, frames, held)
        return rows[i - frames.start : stop - frames.start]

    starts = range(0, T, chunk)  # memory flat in the take's length; the chunks side by side
    for i, rows in zip(starts, map_in_order(rows_of, starts), strict=True):
        stop = min(i + chunk, T)
        out[layout.rows[i:stop]] = rows
        if progress is not None:
            progress(stop, T)
    return out


def _new_angles(layout: BvhLayout, j: int, L2: np.ndarray, data: np.ndarray, new: np.ndarray,
                held: np.ndarray) -> None:  # fmt: skip
    """Joint j's rotation channels for its new local rotations ``L2[:, j]`` into ``new``
    (n, C), nearest the file's ``data`` (n, C). A joint that cannot turn freely (fewer than
    three rotation channels) keeps its channels; channels ``held`` (C,) constant through the
    take stay as they came, the others solved for L2 (``held_channels``), and ``L2[:, j]``
    becomes what is written."""
    rot = layout.joint_columns(j, "r")
    axes = "".join(a for _, a in rot)
    if len(rot) != 3 or len(set(axes)) != 3:
        return
    cols = [col for col, _ in rot]
    near = np.deg2rad(data[:, cols])
    angles = rotmat_to_euler(L2[:, j], axes, near)
    keep = held[cols]
    if keep.any():
        angles, L2[:, j] = hold_channels(L2[:, j], axes, angles, keep, near[0])
    new[:, cols] = np.where(keep, data[:, cols], np.rad2deg(angles))


def _write_back_rows(src, rt, original: Motion, cleaned: Motion, body, frames: slice, held):
    """:func:`write_back_data` on the take's ``frames`` (``original`` and ``cleaned`` hold
    those frames alone); held: (C,) the channels constant through the whole take
    (``held_channels.constant_channels``). -> the file's channel values of those rows (n, C)"""
    layout: BvhLayout = src.layout
    data = layout.data[layout.rows[frames]]
    T = data.shape[0]
    scale = layout.metres_per_unit
    change = smpl_change(rt, original, cleaned, body, scale, frames)

    L, t = file_frames(src, layout, data)
    G = world_rotations(L, src.parents)  # the positions: of the joints asked for alone
    drive = drivers(rt.jmap, src.num_joints)
    G2 = driven_rotations(change, G, drive, src.fps)
    # down the chain: each joint's new local rotation (a driven joint's Euler angles, its held
    # channels as they came) and the world rotation that gives it (G2, written over)
    new = data.copy()
    L2 = np.empty_like(G2)
    for j in range(src.num_joints):
        p = int(src.parents[j])
        if drive[j] < 0 and p >= 0:
            L2[:, j] = L[:, j]  # not driven: its channels as they were, following its parent
            at, Lt = below_brief_turn(G2, G, change.brief, drive, p, j)
            if len(at):  # ... but where its parent was turned briefly and it stayed put
                L2t, rows = L2[at], new[at]
                L2t[:, j] = Lt
                _new_angles(layout, j, L2t, data[at], rows, held)
                L2[at], new[at] = L2t, rows
        else:
            L2[:, j] = G2[:, j] if p < 0 else np.swapaxes(G2[:, p], -1, -2) @ G2[:, j]
            _new_angles(layout, j, L2, data, new, held)
        G2[:, j] = L2[:, j] if p < 0 else G2[:, p] @ L2[:, j]

    # the pelvis point (the SMPL pelvis's target) moves by the SMPL pelvis's change and turns
    # with the pelvis; the channels that carry the source pelvis take up the difference
    a = int(rt.jmap.anchor["pelvis"])
    P_a = joint_position(G, t, src.parents, a)
    new_a = pelvis_point(rt, change, P_a, scale, src.fps, frames)
    c = _carrier(src, layout, a)
    t2 = t.copy()
    if c >= 0:  # else no channel can carry a translation: it is dropped, the root stays put
        Gp = np.broadcast_to(np.eye(3), (T, 3, 3)) if c == 0 else G2[:, src.parents[c]]
        t2[:, c] = t[:, c] + (np.swapaxes(Gp, -1, -2) @ (new_a - P_a)[..., None])[..., 0]

    for col, axis in layout.joint_columns(c, "t") if c >= 0 else ():
        k = "xyz".index(axis)
        new[:, col] = t2[:, c, k] - (layout.offsets[0, k] if c == 0 else 0.0)
    if layout.world_channels:
        _, P2 = forward_kinematics(L2, t2, src.parents)
        for j in layout.world_channels:
            P_j = joint_position(G, t, src.parents, j)
            for col, axis in layout.joint_columns(j, "t"):
                k = "xyz".index(axis)  # the file's value, moved as the joint moved
                new[:, col] = data[:, col] + P2[:, j, k] - P_j[:, k]
    return new
