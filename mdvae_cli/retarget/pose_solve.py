"""Solving SMPL joint rotations from a source skeleton's posed joint positions: rest-pose
corrections between the two skeletons, and the per-frame pose solve that
``retarget.retarget`` runs, a chunk of a take's frames at a time (:func:`solve_frames`)."""

from __future__ import annotations

import numpy as np
import torch

from mdvae_cli.body.data import NUM_BODY_JOINTS, SMPL_PARENTS
from mdvae_cli.formats.source import SourceMotion
from mdvae_cli.geometry.kinematics import forward_kinematics
from mdvae_cli.geometry.rotations import rotmat_to_rotvec, rotvec_to_rotmat
from mdvae_cli.geometry.rotations_np import rotmat_between
from mdvae_cli.retarget.joint_map import (
    JointMap,
)
from mdvae_cli.retarget.soles import _FEET

_N = NUM_BODY_JOINTS
_PARENTS = SMPL_PARENTS[:_N]


def rest_corrections(jmap: JointMap, src_rest: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Per SMPL joint, the rotation C_j with ``G_smpl = G_source @ C_j`` in the rest pose:
    it turns the body's rest bone direction onto the source's.  -> (22, 3, 3)"""
    Y = src_rest[jmap.attach] + jmap.offset
    parents = _PARENTS
    C = np.tile(np.eye(3), (_N, 1, 1))
    for j in range(_N):
        kids = [k for k in range(_N) if parents[k] == j]
        if len(kids) == 1:
            C[j] = rotmat_between(X[kids[0]] - X[j], Y[kids[0]] - Y[j])
    for j in range(_N):  # leaves continue their parent's correction
        if not any(parents[k] == j for k in range(_N)):
            C[j] = C[parents[j]]
    return C


def _ancestors(parents: list[int]) -> torch.Tensor:
    """(22, 22) bool: A[k, j] when j is k or one of its ancestors."""
    A = torch.zeros(_N, _N, dtype=torch.bool)
    for k in range(_N):
        j = k
        while j >= 0:
            A[k, j] = True
            j = parents[j]
    return A


def solve_pose(
    targets: torch.Tensor,
    L_init: torch.Tensor,
    X: torch.Tensor,
    parents: list[int],
    twist_weight: float = 0.02,
    iterations: int = 3,
    damping: float = 1e-6,
    chunk: int = 256,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Fit local rotations and the root to joint targets, all frames at once.

    Minimises ``sum_j |p_j - y_j|^2 + twist_weight^2 sum_j |log(L_init_j^T L_j)|^2`` (metres,
    radians) by damped Gauss-Newton. Parameters per frame: a world-frame rotation increment for
    each joint that has children (turning its subtree about it) and the root position; joints
    without children (feet, wrists, head) keep their start rotation, which positions cannot see.

    targets: (T, 22, 3); L_init: (T, 22, 3, 3); X: (22, 3) rest joints; -> L (T, 22, 3, 3),
    root position (T, 3)
    """
    if targets.shape[0] > chunk:  # frames are independent: small chunks stay in cache
        parts = [solve_pose(targets[i : i + chunk], L_init[i : i + chunk], X, parents,
                            twist_weight, iterations, damping, chunk)
                 for i in range(0, targets.shape[0], chunk)]  # fmt: skip
        return torch.cat([a for a, _ in parts]), torch.cat([b for _, b in parts])
    T = targets.shape[0]
    dt = targets.dtype
    bones = X.clone()
    bones[1:] = X[1:] - X[parents[1:]]
    active = [j for j in range(_N) if j in parents[1:]]
    n = len(active)
    lin = torch.float32  # the normal equations: float32 is plenty for a Gauss-Newton step
    A = _ancestors(parents)[:, active].to(lin)  # (22, n)
    L = L_init.clone()
    root = targets[:, 0].clone()
    w2 = twist_weight**2
    # the Jacobian (T, 66, 3n + 3): rows (joint k, axis a); columns (active joint j, axis b),
    # then the root's translation (identity blocks, set once)
    Jac = torch.zeros(T, 3 * _N, 3 * n + 3, dtype=lin)
    Jac[:, :, 3 * n :] = torch.eye(3, dtype=lin).repeat(_N, 1)
    Jr = Jac[:, :, : 3 * n].unflatten(2, (n, 3)).unflatten(1, (_N, 3))  # (T, 22, 3, n, 3) view
    diag = torch.full((3 * n + 3,), damping, dtype=lin)
    diag[: 3 * n] += w2
    for _ in range(iterations):
        G, p = forward_kinematics(L, bones, parents[:_N], root=root)  # (T, 22, 3, 3), (T, 22, 3)
        r = (p - targets).reshape(T, 3 * _N, 1).to(lin)
        pl = p.to(lin)
        diff = pl[:, :, None, :] - pl[:, None, active, :]  # (T, 22, n, 3): p_k - p_j
        _minus_skew_into(Jr, diff * A[None, :, :, None])  # d p_k / d omega_j, j above k
        JT = Jac.transpose(1, 2)
        H = torch.baddbmm(torch.diag(diag).expand(T, -1, -1), JT, Jac)
        g = (JT @ r)[..., 0]
        Ga = G[:, active]
        delta = rotmat_to_rotvec(L_init[:, active].transpose(-1, -2) @ L[:, active])
        g[:, : 3 * n] += w2 * (Ga @ delta[..., None])[..., 0].reshape(T, 3 * n).to(lin)
        chol, _ = torch.linalg.cholesky_ex(H)
        step = -torch.cholesky_solve(g[..., None], chol)[..., 0].to(dt)
        omega = step[:, : 3 * n].reshape(T, n, 3)
        local = (Ga.transpose(-1, -2) @ omega[..., None])[..., 0]
        L[:, active] = L[:, active] @ rotvec_to_rotmat(local)
        root = root + step[:, 3 * n :]
    return L, root


def _minus_skew_into(out: torch.Tensor, d: torch.Tensor) -> None:
    """Write ``-skew(d)`` (the cross product ``v -> v x d``) into ``out``, laid out as the
    Jacobian's rows and columns.  out: (T, K, 3, n, 3) [k, a, j, b]; d: (T, K, n, 3)"""
    x, y, z = d.unbind(-1)
    out[:, :, 0, :, 1], out[:, :, 0, :, 2] = z, -y
    out[:, :, 1, :, 0], out[:, :, 1, :, 2] = -z, x
    out[:, :, 2, :, 0], out[:, :, 2, :, 1] = y, -x


CHUNK_FRAMES = 4096  # frames solved at once (a multiple of solve_pose's own chunks)


def frame_chunks(num_frames: int, chunk: int = CHUNK_FRAMES) -> list[slice]:
    """A take's frames ``chunk`` at a time."""
    return [slice(i, min(i + chunk, num_frames)) for i in range(0, num_frames, chunk)]


def solve_frames(src: SourceMotion, frames: slice, jmap, C, X, parents, settings) -> tuple:
    """The pose solve on some of the take's frames (each frame is solved on its own, so a
    long take goes a chunk at a time in flat memory). -> (targets (n, 22, 3), root (n, 3),
    joints (n, 22, 3), the pelvis's world rotation (n, 3, 3), the ankles' and feet's
    (n, 4, 3, 3), pose_body (n, 21, 3))"""
    G_src, P_src = (torch.as_tensor(a) for a in src.forward_kinematics(frames))
    attach, offset = torch.as_tensor(jmap.attach), torch.as_tensor(jmap.offset)
    targets = P_src[:, attach] + (G_src[:, attach] @ offset[..., None])[..., 0]
    G0 = G_src[:, torch.as_tensor(jmap.rot_source)] @ C
    L0 = G0.clone()
    L0[:, 1:] = G0[:, parents[1:]].transpose(-1, -2) @ G0[:, 1:]
    del G_src, P_src, G0
    L, root = solve_pose(targets, L0, X, parents, settings.twist_weight, settings.iterations)
    bones = X.clone()
    bones[1:] = X[1:] - X[parents[1:]]
    G, p = forward_kinematics(L, bones, parents[:_N], root=root)
    return targets, root, p, G[:, 0], G[:, _FEET], rotmat_to_rotvec(L[:, 1:])
