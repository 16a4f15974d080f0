"""Solving SMPL joint rotations from a source skeleton's posed joint positions: rest-pose
corrections between the two skeletons, forward kinematics, and the per-frame pose solve that
``retarget.retarget`` runs."""

from __future__ import annotations

import numpy as np
import torch

from mdvae_cli.body.data import NUM_BODY_JOINTS, SMPL_PARENTS
from mdvae_cli.geometry.kinematics import forward_kinematics
from mdvae_cli.geometry.rotations import rotmat_to_rotvec, rotvec_to_rotmat, skew
from mdvae_cli.geometry.rotations_np import rotmat_between
from mdvae_cli.retarget.joint_map import (
    JointMap,
)

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
    Jt = torch.eye(3, dtype=lin).repeat(_N, 1).expand(T, 3 * _N, 3)
    diag = torch.full((3 * n + 3,), damping, dtype=lin)
    diag[: 3 * n] += w2
    for _ in range(iterations):
        G, p = forward_kinematics(L, bones, parents[:_N], root=root)  # (T, 22, 3, 3), (T, 22, 3)
        r = (p - targets).reshape(T, 3 * _N, 1).to(lin)
        pl = p.to(lin)
        diff = pl[:, :, None, :] - pl[:, None, active, :]  # (T, 22, n, 3): p_k - p_j
        Jr = -skew(diff) * A[None, :, :, None, None]  # (T, 22, n, 3, 3)
        Jr = Jr.permute(0, 1, 3, 2, 4).reshape(T, 3 * _N, 3 * n)
        Jac = torch.cat([Jr, Jt], dim=2)  # (T, 66, 3n + 3)
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
