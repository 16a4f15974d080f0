"""Euler angles in numpy, float64, as mocap files write them: ``axes`` names the turns outermost
first, ``R = R_axes[0](a0) @ R_axes[1](a1) @ ...`` (BVH's channel order; an AMC's dofs reversed).
Every function takes arbitrary leading batch dimensions."""

from __future__ import annotations

import numpy as np


def euler_to_rotmat(angles: np.ndarray, axes: str) -> np.ndarray:
    """Product of axis rotations, outermost first: ``R_axes[0](a0) @ R_axes[1](a1) @ ...``.

    angles: (..., K) radians; axes: K letters from "xyz" -> (..., 3, 3)
    """
    angles = np.asarray(angles, dtype=np.float64)
    shape = angles.shape[:-1]
    out = np.broadcast_to(np.eye(3), (*shape, 3, 3)).copy()
    for k, axis in enumerate(axes):
        c, s = np.cos(angles[..., k]), np.sin(angles[..., k])
        R = np.zeros((*shape, 3, 3))
        i = "xyz".index(axis)
        a, b = (i + 1) % 3, (i + 2) % 3
        R[..., i, i] = 1.0
        R[..., a, a], R[..., a, b], R[..., b, a], R[..., b, b] = c, -s, s, c
        out = out @ R
    return out


def rotmat_to_euler(R: np.ndarray, axes: str, near: np.ndarray | None = None) -> np.ndarray:
    """Angles (radians) with ``R = R_axes[0](a0) @ R_axes[1](a1) @ R_axes[2](a2)``, for three
    distinct axes.

    Of the two solutions, the one closest to ``near`` is returned, each angle moved by whole
    turns to lie nearest its ``near`` value (so a file's angles that run past 180 degrees, or
    sit at -180 rather than 180, come back as written).

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
    return np.where(pick[..., None], two, one)


def _wrap(angles: np.ndarray, near: np.ndarray) -> np.ndarray:
    """angles moved by whole turns to lie within half a turn of near."""
    return angles + 2 * np.pi * np.round((near - angles) / (2 * np.pi))
