"""Euler angles in numpy, float64, as mocap files write them: ``axes`` names the turns outermost
first, ``R = R_axes[0](a0) @ R_axes[1](a1) @ ...`` (BVH's channel order; an AMC's dofs reversed).
Every function takes arbitrary leading batch dimensions."""

from __future__ import annotations

import numpy as np


def euler_to_rotmat(angles: np.ndarray, axes: str) -> np.ndarray:
    """Product of axis rotations, outermost first: ``R_axes[0](a0) @ R_axes[1](a1) @ ...``.

    Built entry by entry: each turn mixes two columns of the product so far, and entries
    still exactly 0 or 1 (from the identity) cost nothing.
    angles: (..., K) radians; axes: K letters from "xyz" -> (..., 3, 3)
    """
    angles = np.asarray(angles, dtype=np.float64)
    shape = angles.shape[:-1]
    M: list[list] = [[1.0 if r == k else 0.0 for k in range(3)] for r in range(3)]
    for k, axis in enumerate(axes):
        c, s = np.cos(angles[..., k]), np.sin(angles[..., k])
        i = "xyz".index(axis)
        a, b = (i + 1) % 3, (i + 2) % 3
        for row in M:  # (M R)[:, a] = c M[:, a] + s M[:, b]; (M R)[:, b] = c M[:, b] - s M[:, a]
            row[a], row[b] = _mix(c, row[a], s, row[b]), _mix(c, row[b], -s, row[a])
    out = np.empty((*shape, 3, 3))
    for r in range(3):
        for k in range(3):
            out[..., r, k] = M[r][k]
    return out


def _mix(c: np.ndarray, x, s: np.ndarray, y):
    """``c * x + s * y`` where x and y are arrays or the exact constants 0.0 and 1.0."""
    terms = [t for t in (_times(c, x), _times(s, y)) if t is not None]
    if not terms:
        return 0.0
    return terms[0] if len(terms) == 1 else terms[0] + terms[1]


def _times(c: np.ndarray, x):
    """``c * x`` for x an array or the exact constants 0.0 (None: nothing) and 1.0."""
    if isinstance(x, float):
        return None if x == 0.0 else c if x == 1.0 else c * x
    return c * x


def rotmat_to_euler(R: np.ndarray, axes: str, near: np.ndarray | None = None) -> np.ndarray:
    """Angles (radians) with ``R = R_axes[0](a0) @ R_axes[1](a1) @ R_axes[2](a2)``, for three
    distinct axes.

    Of the two solutions, the one closest to ``near`` is returned, each angle moved by whole
    turns to lie nearest its ``near`` value (so a file's angles that run past 180 degrees, or
    sit at -180 rather than 180, come back as written). Near gimbal lock (:data:`LOCK_COS`),
    where the outer angles are ill-determined, angles solved near ``near`` are returned when
    they give ``R`` within :data:`LOCK_MISS_DEG`.

    R: (..., 3, 3); axes: e.g. "zxy"; near: (..., 3) radians or None  -> (..., 3)
    """
    R = np.asarray(R, dtype=np.float64)
    i, j, k = ("xyz".index(a) for a in axes)
    sign = 1.0 if (j - i) % 3 == 1 else -1.0  # cyclic order (xyz, yzx, zxy) or not
    s = np.clip(sign * R[..., i, k], -1.0, 1.0)
    b = np.arcsin(s)
    a = np.arctan2(-sign * R[..., j, k], R[..., k, k])
    c = np.arctan2(-sign * R[..., i, j], R[..., i, i])
    lock = np.sqrt(R[..., i, i] ** 2 + R[..., i, j] ** 2) < 1e-9  # gimbal lock: all in a
    if lock.any():
        c = np.where(lock, 0.0, c)
        a = np.where(lock, np.arctan2(sign * R[..., k, j], R[..., j, j]), a)
    one = np.stack([a, b, c], axis=-1)
    two = np.stack([a + np.pi, np.pi - b, c + np.pi], axis=-1)
    if near is None:
        return _wrap(one, np.zeros_like(one))
    one, two = _wrap(one, near), _wrap(two, near)
    pick = np.abs(two - near).sum(-1) < np.abs(one - near).sum(-1)
    out = np.where(pick[..., None], two, one)
    near = np.broadcast_to(np.asarray(near, dtype=np.float64), out.shape)
    locked = np.abs(np.cos(out[..., 1])) < LOCK_COS
    if locked.any():
        held = _held_near(R[locked], axes, near[locked])
        miss = np.swapaxes(euler_to_rotmat(held, axes), -1, -2) @ R[locked]
        cos_miss = (np.trace(miss, axis1=-2, axis2=-1) - 1.0) / 2.0
        good = cos_miss > np.cos(np.radians(LOCK_MISS_DEG))  # else the exact angles
        rows = out[locked]
        rows[good] = held[good]
        out[locked] = rows
    return out


#: near gimbal lock (the middle angle within about 1.1 degrees of +-90 degrees: its cosine
#: under this), the outer two angles are ill-determined: a turn of a hundredth of a degree can
#: move them by tens of degrees in opposite ways (a rig whose feet sit at 90 degrees wrote
#: channels jumping 36 degrees a frame). There the angles are solved near the given ones, and
#: kept when they give the rotation within LOCK_MISS_DEG.
LOCK_COS = 0.02
#: how much staying near the given angles weighs (per rad^2) against matching the rotation
#: (squared Frobenius distance) near gimbal lock
LOCK_PULL = 1e-2
#: angles solved near the given ones are kept only within this of the rotation (degrees)
LOCK_MISS_DEG = 1.0


def _held_near(R: np.ndarray, axes: str, near: np.ndarray, steps: int = 10) -> np.ndarray:
    """Angles (n, 3) for rotations R (n, 3, 3) near gimbal lock: the minimum of ``|R(angles) -
    R|^2 + LOCK_PULL |angles - near|^2``, by Gauss-Newton from ``near`` (n, 3)."""
    theta = near.copy()
    gens = []
    for axis in axes:
        K = np.zeros((3, 3))
        i = "xyz".index(axis)
        a, b = (i + 1) % 3, (i + 2) % 3
        K[b, a], K[a, b] = 1.0, -1.0
        gens.append(K)
    eye = np.eye(3)
    for _ in range(steps):
        R0, R1, R2 = (euler_to_rotmat(theta[:, k : k + 1], axes[k]) for k in range(3))
        F = R0 @ R1 @ R2
        J = np.stack([gens[0] @ F, R0 @ gens[1] @ R1 @ R2, F @ gens[2]], axis=-1)  # (n,3,3,3)
        J = J.reshape(-1, 9, 3)
        r = (F - R).reshape(-1, 9)
        H = np.swapaxes(J, -1, -2) @ J + LOCK_PULL * eye
        g = (np.swapaxes(J, -1, -2) @ r[..., None])[..., 0] + LOCK_PULL * (theta - near)
        theta = theta - np.linalg.solve(H, g[..., None])[..., 0]
    return theta


def _wrap(angles: np.ndarray, near: np.ndarray) -> np.ndarray:
    """angles moved by whole turns to lie within half a turn of near."""
    return angles + 2 * np.pi * np.round((near - angles) / (2 * np.pi))
