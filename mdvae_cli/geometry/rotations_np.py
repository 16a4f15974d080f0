"""Rotation conversions in numpy, float64: the vocabulary of :mod:`.rotations` (``rotvec``,
``rotmat``, ``quat`` scalar first (w, x, y, z)) for the code that works on numpy arrays (the foot
lock, filters, file readers), where a round trip through torch costs more than the math.

Every function takes arbitrary leading batch dimensions. Branches, as in torch:
:func:`rotmat_to_rotvec` and :func:`quat_to_rotvec` give angles in [0, pi];
:func:`rotvec_to_quat` keeps an axis-angle's branch in the quaternion's sign (w < 0 for angles in
(pi, 3 pi)), which ``quat_to_rotvec(q, keep_branch=True)`` reads back (angles in [0, 2 pi)).
"""

from __future__ import annotations

import numpy as np


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product over the last axis (numpy's ``cross`` costs more on small arrays)."""
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx], axis=-1)


def rotvec_to_rotmat(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues' formula.  (..., 3) -> (..., 3, 3)"""
    rotvec = np.asarray(rotvec, dtype=np.float64)
    theta = np.sqrt((rotvec * rotvec).sum(-1))
    small = theta < 1e-8
    x, y, z = np.moveaxis(rotvec / np.where(small, 1.0, theta)[..., None], -1, 0)
    sin, cos = np.where(small, 0.0, np.sin(theta)), np.where(small, 1.0, np.cos(theta))
    c1 = 1 - cos
    xs, ys, zs = x * sin, y * sin, z * sin
    xy, xz, yz = x * y * c1, x * z * c1, y * z * c1
    R = np.empty((*rotvec.shape[:-1], 3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 0, 2] = cos + x * x * c1, xy - zs, xz + ys
    R[..., 1, 0], R[..., 1, 1], R[..., 1, 2] = xy + zs, cos + y * y * c1, yz - xs
    R[..., 2, 0], R[..., 2, 1], R[..., 2, 2] = xz - ys, yz + xs, cos + z * z * c1
    return R


def rotmat_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The smallest rotation turning direction ``u`` into direction ``v`` (any lengths), about
    their common normal; where they are opposite, half a turn about an axis perpendicular to
    ``u``; the identity where either is zero.  (..., 3) x 2 -> (..., 3, 3)"""
    u, v = np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64)
    axis = cross(u, v)
    sin = np.linalg.norm(axis, axis=-1, keepdims=True)
    cos = (u * v).sum(-1, keepdims=True)
    scale = np.linalg.norm(u, axis=-1, keepdims=True) * np.linalg.norm(v, axis=-1, keepdims=True)
    opposite = (sin <= 1e-9 * scale) & (cos < 0)
    if opposite.any():
        other = np.eye(3)[np.abs(u).argmin(-1)]  # the axis u is least along
        perp = cross(u, other)
        axis = np.where(opposite, perp, axis)
        sin = np.where(opposite, np.linalg.norm(perp, axis=-1, keepdims=True), sin)
    angle = np.arctan2(np.where(opposite, 0.0, sin), cos)
    return rotvec_to_rotmat(axis / np.maximum(sin, 1e-12) * angle)


def rotmat_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternions with w >= 0, through the largest of the four pivots (as
    ``rotations.rotmat_to_quat``).  (..., 3, 3) -> (..., 4)"""
    m = np.asarray(R, dtype=np.float64)
    shape = m.shape[:-2]
    # the nine entries each a whole array of its own (strided columns cost a third more)
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = m.reshape(-1, 9).T.copy()
    p0, p1 = 1 + m00 + m11 + m22, 1 + m00 - m11 - m22
    p2, p3 = 1 - m00 + m11 - m22, 1 - m00 - m11 + m22
    a, b, c = m21 - m12, m02 - m20, m10 - m01
    d, e, f = m10 + m01, m02 + m20, m21 + m12
    rows = ((p0, a, b, c), (a, p1, d, e), (b, d, p2, f), (c, e, f, p3))  # row k: 4 q_k q
    best = np.argmax(np.stack([p0, p1, p2, p3]), axis=0)
    q = np.empty((4, len(best)))
    for i in range(4):  # each component from the best pivot's row
        np.choose(best, [row[i] for row in rows], out=q[i])
    q *= np.where(q[0] < 0, -1.0, 1.0) / np.sqrt((q * q).sum(0))
    return q.T.reshape(*shape, 4)


def quat_to_rotmat(quat: np.ndarray) -> np.ndarray:
    """Rotation matrices of quaternions (scalar first; normalised here).  (..., 4) -> (..., 3, 3)"""
    q = np.asarray(quat, dtype=np.float64)
    w, x, y, z = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    out = np.empty((*q.shape[:-1], 3, 3))
    out[..., 0, 0] = 1 - 2 * (y * y + z * z)
    out[..., 0, 1] = 2 * (x * y - w * z)
    out[..., 0, 2] = 2 * (x * z + w * y)
    out[..., 1, 0] = 2 * (x * y + w * z)
    out[..., 1, 1] = 1 - 2 * (x * x + z * z)
    out[..., 1, 2] = 2 * (y * z - w * x)
    out[..., 2, 0] = 2 * (x * z - w * y)
    out[..., 2, 1] = 2 * (y * z + w * x)
    out[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return out


def quat_slerp(q0: np.ndarray, q1: np.ndarray, t: np.ndarray | float) -> np.ndarray:
    """Spherical linear interpolation along the shorter arc (as ``rotations.quat_slerp``).

    q0, q1: (..., 4) unit quaternions; t: scalar or (...) in [0, 1] -> (..., 4)"""
    q0, q1 = np.asarray(q0, dtype=np.float64), np.asarray(q1, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    q1 = np.where(np.sum(q0 * q1, axis=-1, keepdims=True) < 0, -q1, q1)
    # the angle between the quaternions, accurate also when they are nearly equal
    omega = 2.0 * np.arctan2(np.linalg.norm(q1 - q0, axis=-1), np.linalg.norm(q1 + q0, axis=-1))
    close = omega < 1e-6
    sin_omega = np.where(close, 1.0, np.sin(omega))
    w0 = np.where(close, 1.0 - t, np.sin((1.0 - t) * omega) / sin_omega)
    w1 = np.where(close, t, np.sin(t * omega) / sin_omega)
    q = w0[..., None] * q0 + w1[..., None] * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def rotmat_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Axis-angles with angles in [0, pi].  (..., 3, 3) -> (..., 3)"""
    return quat_to_rotvec(rotmat_to_quat(R))


def rotvec_to_quat(rotvec: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 4) scalar first. w = cos(angle / 2) keeps the branch: w < 0 for angles
    in (pi, 3 pi)."""
    rotvec = np.asarray(rotvec, dtype=np.float64)
    theta = np.linalg.norm(rotvec, axis=-1, keepdims=True)
    half = 0.5 * theta
    scale = 0.5 * np.sinc(half / np.pi)  # sin(half) / theta, exact at 0
    return np.concatenate([np.cos(half), rotvec * scale], axis=-1)


def quat_to_rotvec(quat: np.ndarray, keep_branch: bool = False) -> np.ndarray:
    """Unit quaternions (..., 4) -> (..., 3), angles in [0, pi] (``q`` and ``-q`` alike).

    keep_branch: the angle 2 atan2(|v|, w) in [0, 2 pi) instead: q and -q give the two
    branches (angle a about n, or 2 pi - a about -n). A quaternion close to -1 is then the
    identity seen from the far branch, whose axis is undefined, so it is read as +1.
    """
    quat = np.asarray(quat, dtype=np.float64)
    if keep_branch:
        far = (quat[..., :1] < 0) & (np.linalg.norm(quat[..., 1:], axis=-1, keepdims=True) < 1e-6)
    else:
        far = quat[..., :1] < 0
    q = np.where(far, -quat, quat)
    w, v = q[..., 0], q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    angle = 2.0 * np.arctan2(s, w)
    factor = np.where(s > 0, angle / np.where(s > 0, s, 1.0), 2.0 / np.where(s > 0, 1.0, w))
    return v * factor[..., None]


def _quat_parts(rotvec: np.ndarray) -> tuple[np.ndarray, ...]:
    """:func:`rotvec_to_quat`'s (w, x, y, z), each (...) on its own (the series of the torch
    one, ``rotations.rotvec_to_quat``, for angles under 1e-6).  (..., 3) -> 4 x (...)"""
    x, y, z = rotvec[..., 0], rotvec[..., 1], rotvec[..., 2]
    theta2 = x * x + y * y + z * z
    small = theta2 < 1e-12
    theta = np.sqrt(np.where(small, 1.0, theta2))
    scale = np.where(small, 0.5 - theta2 / 48.0, np.sin(0.5 * theta) / theta)
    w = np.where(small, 1.0 - theta2 / 8.0, np.cos(0.5 * theta))
    return w, x * scale, y * scale, z * scale


def rotvec_product(a: np.ndarray, b: np.ndarray, invert_a: bool = False) -> np.ndarray:
    """The axis-angle of the rotation ``b`` then ``a`` (``a`` inverted first when
    ``invert_a``: b's turn away from a), angle in [0, pi]: ``quat_to_rotvec(quat_multiply(
    rotvec_to_quat(a), rotvec_to_quat(b)))`` with each quaternion component a whole array
    of its own, not a strided column (twice as fast on a long take's joints).
    a, b: (..., 3) -> (..., 3)"""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    w1, x1, y1, z1 = _quat_parts(a)
    if invert_a:
        x1, y1, z1 = -x1, -y1, -z1
    w2, x2, y2, z2 = _quat_parts(b)
    w = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2
    x = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2
    y = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2
    z = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2
    sign = np.where(w < 0, -1.0, 1.0) / np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w * sign, x * sign, y * sign, z * sign
    s2 = x * x + y * y + z * z
    small = s2 < 1e-12
    s = np.sqrt(np.where(small, 1.0, s2))
    # angle / s = 2 atan2(s, w) / s; for small s its series 2/w (1 - s^2 / (3 w^2))
    w_safe = np.where(small, np.maximum(w, 0.5), 1.0)
    factor = np.where(small, 2.0 / w_safe * (1.0 - s2 / (3.0 * w_safe**2)),
                      2.0 * np.arctan2(s, w) / s)  # fmt: skip
    return np.stack([x * factor, y * factor, z * factor], axis=-1)


def quat_continuous(quat: np.ndarray, first_positive: bool = False) -> np.ndarray:
    """Signs flipped so that each quaternion lies in the hemisphere of the one before it along
    axis 0 (q and -q are one rotation); ``first_positive``: the first frame with w >= 0 too.
    (T, ..., 4) -> (T, ..., 4)"""
    q = np.asarray(quat, dtype=np.float64)
    if len(q) == 0:
        return q.copy()
    steps = np.where(np.sum(q[1:] * q[:-1], axis=-1) < 0, -1.0, 1.0)
    first = (
        np.where(q[:1, ..., 0] < 0, -1.0, 1.0) if first_positive else np.ones_like(q[:1, ..., 0])
    )
    flips = np.cumprod(np.concatenate([first, steps], axis=0), axis=0)
    return q * flips[..., None]


def rotvec_nearest(rotvec: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Each axis-angle rewritten as the one of its rotation nearest ``reference``.

    The axis-angles of one rotation are ``n (a + 2 pi k)`` for integer k (``k = -1`` is the
    flip to ``-n (2 pi - a)``); the k whose vector lies nearest the reference is taken, so
    that a motion comes back on the branches its file used (a solver's root past pi). Entries
    with no axis (angle ~0) or a NaN reference are kept.  (..., 3), (..., 3) -> (..., 3)
    """
    rotvec = np.asarray(rotvec, dtype=np.float64)
    with np.errstate(invalid="ignore"):  # a hole's NaN rows stay NaN, quietly
        angle = np.linalg.norm(rotvec, axis=-1, keepdims=True)
        has_axis = angle > 1e-8
        axis = rotvec / np.where(has_axis, angle, 1.0)
        along = np.sum(np.asarray(reference, dtype=np.float64) * axis, axis=-1, keepdims=True)
        turns = np.round((along - angle) / (2.0 * np.pi))
    keep = ~has_axis | ~np.isfinite(turns) | (turns == 0)
    return np.where(keep, rotvec, axis * (angle + 2.0 * np.pi * np.where(keep, 0.0, turns)))
