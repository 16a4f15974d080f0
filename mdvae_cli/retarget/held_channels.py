"""Rotation channels a take holds exactly constant, kept so on the way back.

A channel whose value is the same in every frame of a take (a hinge's unused axes, a video
estimate's feet with no rotation at all) is no noise to clean: nothing in the input moves it.
The way back writes it as it came, and the joint's other channels are solved for the rotation
the cleaning asked for (:func:`hold_channels`), so the joint stays as close to it as the held
channels allow.
"""

from __future__ import annotations

import numpy as np

from mdvae_cli.geometry.euler import euler_to_rotmat
from mdvae_cli.geometry.rotations_np import rotmat_to_rotvec

#: Gauss-Newton steps of the free channels' solve
STEPS = 6


#: a channel whose values spread less than this (degrees) holds one value: below the last
#: digit the way back writes (6 decimals), e.g. a video estimate's feet at 0 +- 1e-14
SPREAD = 1e-6


def constant_channels(data: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
    """Which columns of a take's channel values (F, C) hold one value in every frame (spread
    under :data:`SPREAD`; a take of one frame holds none); rows: (T,) the frames to read
    (None: all), gathered a block at a time (a copy of a 30-minute 120 Hz take's rows was
    120 MB at the way back's peak).  -> (C,) bool"""
    data = np.asarray(data)
    rows = np.arange(len(data)) if rows is None else np.asarray(rows)
    if len(rows) < 2:
        return np.zeros(data.shape[1], dtype=bool)
    low = np.full(data.shape[1], np.inf)
    high = np.full(data.shape[1], -np.inf)
    for i in range(0, len(rows), _BLOCK):
        part = data[rows[i : i + _BLOCK]]
        np.minimum(low, part.min(axis=0), out=low)  # NaN stays NaN: no constant channel
        np.maximum(high, part.max(axis=0), out=high)
    return high - low < SPREAD


#: frames gathered at a time by :func:`constant_channels`
_BLOCK = 8192


def angle_between(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """The angle (radians) of ``A^T B`` for rotations (..., 3, 3).  -> (...)"""
    cos = (np.einsum("...ij,...ij->...", A, B) - 1.0) / 2.0
    return np.arccos(np.clip(cos, -1.0, 1.0))


def hold_channels(
    R: np.ndarray, axes: str, angles: np.ndarray, held: np.ndarray, values: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Euler angles for the rotations ``R`` with the ``held`` channels at ``values``.

    R: (T, 3, 3) the rotations asked for; axes: three distinct letters (outermost first);
    angles: (T, 3) radians, the way back's own solution for R; held: (3,) bool; values: (3,)
    radians, the held channels' values. Per frame, of the way back's free channels as they
    are and those channels solved (Gauss-Newton from there on the angle to R), the one
    nearer R is kept.  -> (angles (T, 3), their rotations (T, 3, 3))
    """
    held = np.asarray(held, dtype=bool)
    start = np.array(angles, dtype=np.float64)
    start[:, held] = np.asarray(values, dtype=np.float64)[held]
    free = np.flatnonzero(~held)
    if not free.size:
        return start, euler_to_rotmat(start, axes)
    axis = np.eye(3)[["xyz".index(a) for a in axes]]  # (3, 3) each channel's axis
    theta = start.copy()
    for _ in range(STEPS):
        # R_theta turned by channel k by d is R_theta Exp(d S_k^T a_k), S_k: the turns after k
        cols = []
        for k in free:
            S = euler_to_rotmat(theta[:, k + 1 :], axes[k + 1 :]) if k < 2 else np.eye(3)
            cols.append(np.einsum("...ji,j->...i", S, axis[k]) if k < 2 else
                        np.broadcast_to(axis[k], (len(theta), 3)))  # fmt: skip
        J = np.stack(cols, axis=-1)  # (T, 3, n)
        e = rotmat_to_rotvec(np.swapaxes(euler_to_rotmat(theta, axes), -1, -2) @ R)
        JtJ = np.swapaxes(J, -1, -2) @ J + 1e-9 * np.eye(len(free))
        d = np.linalg.solve(JtJ, (np.swapaxes(J, -1, -2) @ e[..., None]))[..., 0]
        theta[:, free] += d
    A, B = euler_to_rotmat(start, axes), euler_to_rotmat(theta, axes)
    solved = angle_between(B, R) < angle_between(A, R)
    out = np.where(solved[:, None], theta, start)
    return out, np.where(solved[:, None, None], B, A)
