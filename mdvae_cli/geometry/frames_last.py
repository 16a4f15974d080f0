"""3x3 rotation arithmetic on torch tensors with the frames last: matrices (..., 3, 3, T),
vectors (..., 3, T). Every operation is a few elementwise passes over whole rows of frames;
torch's batched products of frames-first 3x3 matrices cost several times more (the pose
solve, ``retarget.pose_solve``, runs on these)."""

from __future__ import annotations

from collections.abc import Sequence

import torch

from mdvae_cli.geometry.rotations import angle_terms, rotmat_to_rotvec


def matmul3(A: torch.Tensor, B: torch.Tensor) -> torch.Tensor:
    """3x3 matrix products.  (..., 3, 3, T) x (..., 3, 3, T) -> (..., 3, 3, T)"""
    out = A[..., :, 0, None, :] * B[..., None, 0, :, :]
    out.addcmul_(A[..., :, 1, None, :], B[..., None, 1, :, :])
    return out.addcmul_(A[..., :, 2, None, :], B[..., None, 2, :, :])


def matvec3(A: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """``A @ v``.  A: (..., 3, 3, T); v: (..., 3, T) -> (..., 3, T)"""
    out = A[..., 0, :] * v[..., 0:1, :]
    out.addcmul_(A[..., 1, :], v[..., 1:2, :])
    return out.addcmul_(A[..., 2, :], v[..., 2:3, :])


def matTvec3(A: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """``A^T @ v``.  A: (..., 3, 3, T); v: (..., 3, T) -> (..., 3, T)"""
    out = A[..., 0, :, :] * v[..., 0:1, :]
    out.addcmul_(A[..., 1, :, :], v[..., 1:2, :])
    return out.addcmul_(A[..., 2, :, :], v[..., 2:3, :])


def forward_kinematics(
    L: torch.Tensor, bones: torch.Tensor, parents: Sequence[int], root: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """World rotations and positions of a joint tree (``geometry.kinematics``, frames last).

    L: (J, 3, 3, T) local rotations; bones: (J, 3) each joint's offset from its parent in the
    parent's frame; parents: (J,) every parent before its children; root: (3, T) the root's
    position. -> G (J, 3, 3, T), P (J, 3, T)"""
    G, P = torch.empty_like(L), L.new_empty(L.shape[0], 3, L.shape[-1])
    G[0], P[0] = L[0], root
    for j, b in enumerate(bones.tolist()[1:], start=1):
        Gp, Lj, p = G[parents[j]], L[j], parents[j]
        torch.mul(Gp[:, 0, None], Lj[None, 0], out=G[j])
        G[j].addcmul_(Gp[:, 1, None], Lj[None, 1]).addcmul_(Gp[:, 2, None], Lj[None, 2])
        torch.add(P[p], Gp[:, 0], alpha=b[0], out=P[j])
        P[j].add_(Gp[:, 1], alpha=b[1]).add_(Gp[:, 2], alpha=b[2])
    return G, P


def turn_matrix(v: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """``rotvec_to_rotmat`` written out entry by entry (Rodrigues: ``I + a K + b K^2`` with
    ``K^2 = v v^T - |v|^2 I``), without its skew matrices and their product. dim: the
    vectors' axis (-1: frames first, -2: frames last).
    (..., 3) -> (..., 3, 3) or (..., 3, T) -> (..., 3, 3, T)"""
    x, y, z = v.unbind(dim)
    xx, yy, zz = x * x, y * y, z * z
    a, b = angle_terms(xx + yy + zz)
    ax, ay, az = a * x, a * y, a * z
    bxy, bxz, byz = b * x * y, b * x * z, b * y * z
    m = [1 - b * (yy + zz), bxy - az, bxz + ay,
         bxy + az, 1 - b * (xx + zz), byz - ax,
         bxz - ay, byz + ax, 1 - b * (xx + yy)]  # fmt: skip
    return torch.stack(m, dim).unflatten(dim, (3, 3))


#: turns whose cosine is under this go by ``rotmat_to_rotvec`` (near a half turn the skew
#: part that :func:`turn_vector` reads the axis from vanishes)
HALF_TURN_COS = -0.5
_SMALL_SIN2 = 1e-12


def turn_vector(M: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """``rotmat_to_rotvec`` from the trace and the skew part, ``theta / (2 sin theta)`` times
    ``(M21 - M12, M02 - M20, M10 - M01)``; turns past 120 degrees (rare: a departure from the
    start) by ``rotmat_to_rotvec``. dim: the vectors' axis (-1: frames first, -2: last).
    (..., 3, 3) -> (..., 3) or (..., 3, 3, T) -> (..., 3, T)"""
    m = M.flatten(dim - 1, dim)
    e = [m.select(dim, k) for k in range(9)]
    v = torch.stack([e[7] - e[5], e[2] - e[6], e[3] - e[1]], dim)
    cos = 0.5 * (e[0] + e[4] + e[8] - 1.0)
    sin2 = 0.25 * (v * v).sum(dim)  # sin(theta)^2
    theta = torch.atan2(sin2.sqrt(), cos)
    small = sin2 < _SMALL_SIN2  # theta / sin(theta) = 1 + theta^2 / 6 + ...
    ratio = torch.where(small, 1.0 + theta * theta / 6.0, theta / sin2.sqrt().clamp_min(1e-30))
    out = 0.5 * ratio.unsqueeze(dim) * v
    far = cos < HALF_TURN_COS
    if far.any():
        frames_first = (M, out) if dim == -1 else (M.movedim(-1, -3), out.movedim(-1, -2))
        frames_first[1][far] = rotmat_to_rotvec(frames_first[0][far])
    return out
