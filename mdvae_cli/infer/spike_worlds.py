"""A spike filled in one joint leaves the joints below it where the input had them.

The blend fills a spike joint by joint in local rotations (``infer.fill.fill_spikes``). A take
whose joints were solved frame by frame (a retarget's spine, a pelvis and the hips) often
jumps in one joint's local rotation while the joint below it jumps back: the world rotation
below stays steady. Filling the one local jump and keeping the other turns the steady part of
the body by the jump that was filled: one-frame pops of 5-12 degrees in the chest, neck and
arms where the input was smooth (CMU 01_08, through its ASF/AMC skeleton: 542 such frames over
the 22 joints, 85 over 8 degrees).

So each joint below a filled one takes the filled joint's world correction only in the share
its own world rotation carried the jump in the input: ``D_c = exp(lam u_c)``, with ``u_c`` the
correction that following its parent (and its own fill) would give it, and ``lam`` the share
of ``u_c`` that undoes the joint's own world jump away from its neighbours' midpoint
(:func:`followed_share`). A glitch in one joint's rotation (its children's worlds jump with
it) is filled below it as before; a jump its children undid leaves them as they came.

Pure numpy on one motion's local rotations (T, J, 3) axis-angle, the SMPL body's tree.
"""

from __future__ import annotations

import numpy as np

from mdvae_cli.body.data import SMPL_PARENTS
from mdvae_cli.geometry.kinematics import world_rotations
from mdvae_cli.geometry.rotations_np import (
    quat_slerp,
    quat_to_rotmat,
    rotmat_to_quat,
    rotmat_to_rotvec,
    rotvec_to_quat,
    rotvec_to_rotmat,
)


def _t(R: np.ndarray) -> np.ndarray:
    """Transpose of rotation matrices (..., 3, 3)."""
    return np.swapaxes(R, -1, -2)


def world_jumps(before: np.ndarray, now: np.ndarray, after: np.ndarray) -> np.ndarray:
    """Each rotation's turn away from the midpoint of the frames either side, in the world
    frame: ``log(G_now M^T)``, M the two neighbours' slerp midpoint.

    before, now, after: (..., 3, 3) -> (..., 3) rotation vectors"""
    mid = quat_slerp(rotmat_to_quat(before), rotmat_to_quat(after), 0.5)
    return rotmat_to_rotvec(now @ _t(quat_to_rotmat(mid)))


#: a correction over this (rad), or a jump over it in the joint's chain, is followed whole:
#: near half a turn a rotation vector's axis flips, and no share of it can be read (a
#: 179-degree glitch of a foot kept itself; a 150-degree glitch of a hip on the same frame as one
#: of its ankle left the ankle 70 degrees off)
READ_TURN_RAD = 0.5 * np.pi


#: a share within this of 0 or 1 is read as 0 or 1 (the rest stretched between): a joint's own
#: motion over its three frames moves its jump by a little; read as a share it kept a few
#: percent of a glitch it had followed whole (unseen_test, 0.3-rad spikes on 2 % of the
#: joint-frames: 0.1355 -> 0.1380 cm V2V without the edge, 0.1350 with it)
FOLLOW_EDGE = 0.2


def followed_share(u: np.ndarray, jump: np.ndarray) -> np.ndarray:
    """The share of a correction ``u`` that undoes a joint's own jump: the projection of
    ``-jump`` on ``u`` over ``|u|^2``, read to [0, 1] past :data:`FOLLOW_EDGE` (1 where
    ``u`` is nil, or over :data:`READ_TURN_RAD`).

    u, jump: (..., 3) rotation vectors -> (...)"""
    uu = (u * u).sum(-1)
    lam = -(u * jump).sum(-1) / np.maximum(uu, 1e-12)
    lam = np.clip((lam - FOLLOW_EDGE) / (1.0 - 2.0 * FOLLOW_EDGE), 0.0, 1.0)
    return np.where((uu < 1e-12) | (uu > READ_TURN_RAD**2), 1.0, lam)


def nearness(source: np.ndarray, denoised: np.ndarray, blended: np.ndarray) -> np.ndarray:
    """How near the input the blend came: 1 - angle(blended, source) / angle(denoised,
    source), clipped to [0, 1] (1 where the denoiser's output is the input).

    source, denoised, blended: (..., 3) axis-angles -> (...)"""
    src = _t(rotvec_to_rotmat(source))
    apart = np.linalg.norm(rotmat_to_rotvec(src @ rotvec_to_rotmat(denoised)), axis=-1)
    off = np.linalg.norm(rotmat_to_rotvec(src @ rotvec_to_rotmat(blended)), axis=-1)
    near = np.clip(1.0 - off / np.maximum(apart, 1e-12), 0.0, 1.0)
    return np.where(apart < 1e-6, 1.0, near)


def keep_worlds_below_spikes(
    source: np.ndarray,
    denoised: np.ndarray,
    filled: np.ndarray,
    spikes: np.ndarray,
    seen: np.ndarray | None = None,
) -> np.ndarray:
    """``filled`` (the blend of ``denoised`` with ``source``, its spikes filled) with each
    joint below a filled one turned by the fill only in the share its world rotation jumped
    with it in ``source``.

    source, denoised, filled: (T, J, 3) local axis-angles, the root first (the SMPL tree);
    spikes: (T, J) bool, the blend's; seen: (T, J) bool where the source has values (None:
    all), a joint whose chain misses one about a frame follows its parent as before. Without
    its spike, a joint would have come back as near its input as the blend brought it on the
    frames either side that are no spikes of it (:func:`nearness`: 1 on a clean take, where
    the joints below are given back their input's world rotation; 0 on a noisy one, where
    nothing changes). A joint that is no spike itself, and none of whose chain is a spike
    on the frames either side, is held in the same share where its input was steady in the
    world: its world change goes on as the blend made it on those frames
    (:func:`steady_worlds`), not as far as its filled parent's would-be blend (on a take
    whose pelvis the blend kept half of, a pelvis spike the spine had undone turned the
    spine by half of it for the frame). Inside a run of spikes in its chain (on both frames
    beside too) a joint follows the fill. A jump is read against the frames either side as a
    first pass leaves them: a spike there (spikes run two or three frames in a row on a
    jittery take) would otherwise read as a jump of the frame between. -> (T, J, 3)"""
    source, filled = np.asarray(source, np.float64), np.asarray(filled, np.float64)
    denoised = np.asarray(denoised, np.float64)
    T, J = spikes.shape
    frames = np.flatnonzero(spikes.any(axis=1))
    frames = frames[(frames >= 1) & (frames <= T - 2)]
    if not len(frames):
        return filled
    parents = [int(p) for p in SMPL_PARENTS[:J]]
    free = np.ones((len(frames), J), bool)  # the chain has values about the frame
    if seen is not None:
        free = seen[frames - 1] & seen[frames] & seen[frames + 1]
        for c in range(1, J):
            free[:, c] &= free[:, parents[c]]
    # inside a run of spikes in its chain (on the frames either side too) a joint follows:
    # a share read frame by frame along the run is no steady course
    chain = spikes.copy()
    for c in range(1, J):
        chain[:, c] |= chain[:, parents[c]]
    free &= ~(chain[frames - 1] & chain[frames + 1])
    # the blend had it not been a spike: the filled frame turned toward the input's as far
    # as the blend turned this joint toward its input on the frames either side
    beside = np.concatenate([frames - 1, frames + 1])
    valid = ~spikes[beside]
    near = nearness(source[beside], denoised[beside], filled[beside]) * valid
    n = len(frames)
    near = (near[:n] + near[n:]) / np.maximum(valid[:n].astype(float) + valid[n:], 1.0)
    toward = quat_slerp(rotvec_to_quat(filled[frames]), rotvec_to_quat(source[frames]), near)
    L_fill = rotvec_to_rotmat(filled[frames])
    L_kept = np.where(spikes[frames][..., None, None], quat_to_rotmat(toward), L_fill)
    G_kept = world_rotations(L_kept, parents)
    # a joint that is no spike, with none in its chain on the frames beside: as steady in the
    # world as the input had it, as far as the blend kept its input on the frames either side
    spiked_beside = chain[frames - 1] | chain[frames + 1]
    share = np.where(spikes[frames] | spiked_beside | ~free, 0.0, near)
    if share.any():
        steady = rotmat_to_quat(steady_worlds(source, filled, frames, parents))
        G_kept = quat_to_rotmat(quat_slerp(rotmat_to_quat(G_kept), steady, share))
    first = rotmat_to_rotvec(_kept_worlds(L_fill, G_kept, _jumps(source, frames), free, parents))
    # a second pass where a frame beside had a spike, read against that frame as the first
    # pass left it
    again = np.flatnonzero(spikes[frames - 1].any(axis=1) | spikes[frames + 1].any(axis=1))
    if len(again):
        at = frames[again]
        around = [_as_left(source, frames, first, at - 1), source[at],
                  _as_left(source, frames, first, at + 1)]  # fmt: skip
        jump = world_jumps(*world_rotations(rotvec_to_rotmat(np.stack(around)), parents))
        first[again] = rotmat_to_rotvec(
            _kept_worlds(L_fill[again], G_kept[again], jump, free[again], parents)
        )
    out = filled.copy()
    out[frames] = first
    return out


def steady_worlds(
    source: np.ndarray, filled: np.ndarray, frames: np.ndarray, parents
) -> np.ndarray:
    """Each joint's world rotation in ``source`` at ``frames``, turned by the midpoint (slerp)
    of the turns ``filled`` gave its world rotation on the frames either side: where the input
    was steady in the world, the blend's change carried on smoothly, with no jump of its own.

    source, filled: (T, J, 3) local axis-angles; frames: (n,) in 1 .. T - 2 -> (n, J, 3, 3)"""
    around = np.stack([source[frames - 1], source[frames], source[frames + 1]])
    G_src = world_rotations(rotvec_to_rotmat(around), parents)
    G_fill = world_rotations(rotvec_to_rotmat(np.stack([filled[frames - 1], filled[frames + 1]])),
                             parents)  # fmt: skip
    turns = rotmat_to_quat(G_fill @ _t(G_src[[0, 2]]))
    return quat_to_rotmat(quat_slerp(turns[0], turns[1], 0.5)) @ G_src[1]


def _as_left(source: np.ndarray, frames: np.ndarray, first: np.ndarray, at: np.ndarray):
    """The rotations of frames ``at``: the first pass's (``first`` (n, J, 3), of ``frames``)
    where it changed them, else the source's.  -> (m, J, 3)"""
    k = np.clip(np.searchsorted(frames, at), 0, len(frames) - 1)
    return np.where((frames[k] == at)[:, None, None], first[k], source[at])


def _jumps(source: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """:func:`world_jumps` of every joint at ``frames`` (n,) of ``source`` (T, J, 3).
    -> (n, J, 3)"""
    around = np.stack([source[frames - 1], source[frames], source[frames + 1]])
    parents = [int(p) for p in SMPL_PARENTS[: source.shape[1]]]
    return world_jumps(*world_rotations(rotvec_to_rotmat(around), parents))


def _kept_worlds(L_fill, G_kept, jump, free, parents) -> np.ndarray:
    """Down the tree: each joint turned by its parent's correction in the share it followed
    its parent's jump (:func:`followed_share`; wholly where ``free`` is False).

    L_fill: (n, J, 3, 3) the filled local rotations; G_kept: (n, J, 3, 3) the world rotations
    without the spikes' fill; jump: (n, J, 3) each joint's world jump in the input; free: (n,
    J) bool -> the local rotations (n, J, 3, 3)"""
    # a chain that jumped over READ_TURN_RAD (a glitch, not a solve's jitter) follows
    free = free & (np.linalg.norm(jump, axis=-1) <= READ_TURN_RAD)
    for c in range(1, len(parents)):
        free[:, c] &= free[:, parents[c]]
    G_out = np.empty_like(L_fill)
    L_out = L_fill.copy()
    G_out[:, 0] = L_fill[:, 0]
    for c in range(1, len(parents)):
        p = parents[c]
        u = rotmat_to_rotvec(G_out[:, p] @ L_fill[:, c] @ _t(G_kept[:, c]))
        lam = np.where(free[:, c], followed_share(u, jump[:, c]), 1.0)
        G_out[:, c] = rotvec_to_rotmat(lam[:, None] * u) @ G_kept[:, c]
        L_out[:, c] = _t(G_out[:, p]) @ G_out[:, c]
    return L_out
