"""Rotation conversions and interpolation, pure torch.

Vocabulary: ``<src>_to_<dst>`` with

* ``rotvec``  axis-angle vector, shape ``(..., 3)``; its norm is the angle in radians.
* ``rotmat``  rotation matrix, shape ``(..., 3, 3)``, acting on column vectors.
* ``quat``    unit quaternion, shape ``(..., 4)``, **scalar first: (w, x, y, z)**.
* ``rot6d``   the first two columns of the rotation matrix, shape ``(..., 6)``
  laid out as ``[c0x, c0y, c0z, c1x, c1y, c1z]`` (Zhou et al. 2019).

Every function accepts arbitrary leading batch dimensions, float32 or float64, and is
differentiable with finite gradients at zero angle. Inputs are not validated here (these are
hot-path math functions); validation happens where data enters the program.
"""

from __future__ import annotations

import math

import torch

_SMALL = 1e-6


def angle_terms(theta2: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """sin(t)/t and (1-cos t)/t^2 from t^2, Taylor-expanded near zero.  theta2: (...,)"""
    small = theta2 < _SMALL
    safe2 = torch.where(small, torch.ones_like(theta2), theta2)
    theta = torch.sqrt(safe2)
    a = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24.0, (1.0 - torch.cos(theta)) / safe2)
    return a, b


def skew(v: torch.Tensor) -> torch.Tensor:
    """Cross-product matrix.  v: (..., 3) -> (..., 3, 3)"""
    x, y, z = v.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack([o, -z, y, z, o, -x, -y, x, o], dim=-1).reshape(*v.shape[:-1], 3, 3)


def rotvec_to_rotmat(rotvec: torch.Tensor) -> torch.Tensor:
    """Rodrigues' formula.  rotvec: (..., 3) -> (..., 3, 3)"""
    theta2 = (rotvec * rotvec).sum(-1)
    a, b = angle_terms(theta2)
    k = skew(rotvec)
    eye = torch.eye(3, dtype=rotvec.dtype, device=rotvec.device).expand(k.shape)
    return eye + a[..., None, None] * k + b[..., None, None] * (k @ k)


def rotvec_to_quat(rotvec: torch.Tensor) -> torch.Tensor:
    """rotvec: (..., 3) -> quat (..., 4), w >= 0"""
    theta2 = (rotvec * rotvec).sum(-1)
    small = theta2 < _SMALL
    theta = torch.sqrt(torch.where(small, torch.ones_like(theta2), theta2))
    half = 0.5 * torch.where(small, torch.zeros_like(theta), theta)
    scale = torch.where(small, 0.5 - theta2 / 48.0, torch.sin(half) / theta)
    w = torch.where(small, 1.0 - theta2 / 8.0, torch.cos(half))
    return torch.cat([w[..., None], rotvec * scale[..., None]], dim=-1)


def quat_to_rotvec(quat: torch.Tensor) -> torch.Tensor:
    """quat: (..., 4), any norm > 0 -> rotvec (..., 3) with angle in [0, pi]"""
    q = quat / quat.norm(dim=-1, keepdim=True)
    q = torch.where(q[..., :1] < 0, -q, q)
    w, v = q[..., 0], q[..., 1:]
    s2 = (v * v).sum(-1)
    small = s2 < _SMALL
    s = torch.sqrt(torch.where(small, torch.ones_like(s2), s2))
    angle = 2.0 * torch.atan2(s, w)
    # angle / s = 2 atan(x) / (w x) with x = s / w: for small s, 2/w * (1 - s^2 / (3 w^2))
    w_safe = torch.where(small, w.clamp_min(0.5), torch.ones_like(w))
    factor = torch.where(small, 2.0 / w_safe * (1.0 - s2 / (3.0 * w_safe**2)), angle / s)
    return v * factor[..., None]


def quat_to_rotmat(quat: torch.Tensor) -> torch.Tensor:
    """quat: (..., 4), any norm > 0 -> (..., 3, 3)"""
    q = quat / quat.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    m = [
        1 - 2 * (y * y + z * z),
        2 * (x * y - w * z),
        2 * (x * z + w * y),
        2 * (x * y + w * z),
        1 - 2 * (x * x + z * z),
        2 * (y * z - w * x),
        2 * (x * z - w * y),
        2 * (y * z + w * x),
        1 - 2 * (x * x + y * y),
    ]
    return torch.stack(m, dim=-1).reshape(*q.shape[:-1], 3, 3)


def rotmat_to_quat(rotmat: torch.Tensor) -> torch.Tensor:
    """Robust conversion: each of the four pivots gives a candidate, the largest pivot wins.

    rotmat: (..., 3, 3) -> quat (..., 4) with w >= 0
    """
    m = rotmat
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    pivots = torch.stack(
        [1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1
    )
    # each row is 4 * q_k * q for pivot k; dividing by 2*sqrt(pivot) gives q
    cand = torch.stack(
        [
            torch.stack([pivots[..., 0], m21 - m12, m02 - m20, m10 - m01], -1),
            torch.stack([m21 - m12, pivots[..., 1], m10 + m01, m02 + m20], -1),
            torch.stack([m02 - m20, m10 + m01, pivots[..., 2], m21 + m12], -1),
            torch.stack([m10 - m01, m20 + m02, m21 + m12, pivots[..., 3]], -1),
        ],
        dim=-2,
    )
    best = pivots.argmax(-1)
    chosen = torch.gather(cand, -2, best[..., None, None].expand(*best.shape, 1, 4))[..., 0, :]
    piv = torch.gather(pivots, -1, best[..., None]).clamp_min(1e-12)
    q = chosen / (2.0 * torch.sqrt(piv))
    q = q / q.norm(dim=-1, keepdim=True)
    return torch.where(q[..., :1] < 0, -q, q)


def rotmat_to_rotvec(rotmat: torch.Tensor) -> torch.Tensor:
    """rotmat: (..., 3, 3) -> rotvec (..., 3), angle in [0, pi]"""
    return quat_to_rotvec(rotmat_to_quat(rotmat))


def rotmat_to_rot6d(rotmat: torch.Tensor) -> torch.Tensor:
    """rotmat: (..., 3, 3) -> (..., 6), the first two columns"""
    return torch.cat([rotmat[..., :, 0], rotmat[..., :, 1]], dim=-1)


def rot6d_to_rotmat(rot6d: torch.Tensor) -> torch.Tensor:
    """Gram-Schmidt on the two columns.  rot6d: (..., 6) -> (..., 3, 3)"""
    a, b = rot6d[..., :3], rot6d[..., 3:]
    c0 = a / a.norm(dim=-1, keepdim=True).clamp_min(1e-8)
    b = b - (c0 * b).sum(-1, keepdim=True) * c0
    c1 = b / b.norm(dim=-1, keepdim=True).clamp_min(1e-8)
    c2 = torch.linalg.cross(c0, c1, dim=-1)
    return torch.stack([c0, c1, c2], dim=-1)


def rotvec_to_rot6d(rotvec: torch.Tensor) -> torch.Tensor:
    """rotvec: (..., 3) -> (..., 6)"""
    return rotmat_to_rot6d(rotvec_to_rotmat(rotvec))


def rot6d_to_rotvec(rot6d: torch.Tensor) -> torch.Tensor:
    """rot6d: (..., 6) -> (..., 3)"""
    return rotmat_to_rotvec(rot6d_to_rotmat(rot6d))


def quat_multiply(q1: torch.Tensor, q2: torch.Tensor) -> torch.Tensor:
    """Hamilton product q1 * q2 (apply q2 first).  (..., 4), (..., 4) -> (..., 4)"""
    w1, x1, y1, z1 = q1.unbind(-1)
    w2, x2, y2, z2 = q2.unbind(-1)
    return torch.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        dim=-1,
    )


def quat_slerp(q0: torch.Tensor, q1: torch.Tensor, t: torch.Tensor | float) -> torch.Tensor:
    """Spherical linear interpolation along the shorter arc.

    q0, q1: (..., 4) unit quaternions; t: scalar or (...) in [0, 1] -> (..., 4)
    """
    t = torch.as_tensor(t, dtype=q0.dtype, device=q0.device)
    dot = (q0 * q1).sum(-1, keepdim=True)
    q1 = torch.where(dot < 0, -q1, q1)
    # the angle between the quaternions, accurate also when they are nearly equal
    omega = 2.0 * torch.atan2((q1 - q0).norm(dim=-1), (q1 + q0).norm(dim=-1))
    close = omega < 1e-6
    sin_omega = torch.where(close, torch.ones_like(omega), torch.sin(omega))
    w0 = torch.where(close, 1.0 - t, torch.sin((1.0 - t) * omega) / sin_omega)
    w1 = torch.where(close, t, torch.sin(t * omega) / sin_omega)
    q = w0[..., None] * q0 + w1[..., None] * q1
    return q / q.norm(dim=-1, keepdim=True)


def rotvec_slerp(r0: torch.Tensor, r1: torch.Tensor, t: torch.Tensor | float) -> torch.Tensor:
    """Slerp between axis-angle rotations.  r0, r1: (..., 3); t: scalar or (...) -> (..., 3)"""
    return quat_to_rotvec(quat_slerp(rotvec_to_quat(r0), rotvec_to_quat(r1), t))


def rotvec_wrap(rotvec: torch.Tensor) -> torch.Tensor:
    """The same rotations with angles in [0, pi] (undoes :func:`rotvec_unwrap`).

    An angle theta > pi about axis a is the angle theta - 2 pi k in (-pi, pi] about a.
    rotvec: (..., 3) -> (..., 3)
    """
    theta = rotvec.norm(dim=-1, keepdim=True)
    wrapped = theta - 2.0 * math.pi * torch.round(theta / (2.0 * math.pi))  # in [-pi, pi]
    return torch.where(theta > math.pi, rotvec * (wrapped / theta.clamp_min(1.0)), rotvec)


def rotvec_unwrap(
    rotvec: torch.Tensor, dim: int = 0, quats: torch.Tensor | None = None
) -> torch.Tensor:
    """Make an axis-angle sequence continuous along ``dim`` (vectorised).

    Axis-angle jumps by nearly 2*pi when a joint turns past pi, which finite differences and
    networks see as a huge velocity. We convert to quaternions, flip signs so that consecutive
    quaternions lie in the same hemisphere, and convert back allowing angles in [0, 2*pi]:
    the result is continuous for sequences that turn less than a further half turn from the
    first frame's representation, which covers any short window of human motion.

    rotvec: (..., T, ..., 3); quats: their quaternions (rotvec_to_quat), when at hand -> same
    shape, same rotations
    """
    r = rotvec.movedim(dim, 0)
    q = rotvec_to_quat(r) if quats is None else quats.movedim(dim, 0)
    if q.shape[0] > 1:
        dots = (q[1:] * q[:-1]).sum(-1, keepdim=True)
        steps = torch.where(dots < 0, -torch.ones_like(dots), torch.ones_like(dots))
        sign = torch.cat([torch.ones_like(steps[:1]), torch.cumprod(steps, dim=0)], dim=0)
        q = q * sign
    w, v = q[..., :1], q[..., 1:]
    s = v.norm(dim=-1, keepdim=True)
    small = s < 1e-6
    angle = 2.0 * torch.atan2(s, w)
    factor = torch.where(
        small, 2.0 / w.abs().clamp_min(0.5) * torch.sign(w), angle / s.clamp_min(1e-6)
    )
    # near angle 2*pi (w ~ -1) with tiny s the rotation is the identity turned once: keep it exact
    out = torch.where(small & (w < 0), r, v * factor)
    return out.movedim(0, dim)
