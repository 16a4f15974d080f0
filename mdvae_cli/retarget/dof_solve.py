"""Angles of a chain of single-axis rotations that come closest to a wanted rotation.

An ASF bone turns about up to three fixed axes (its ``dof rx ry rz``, in the bone's own frame);
a run of bones turns about more. Written as one product of turns about fixed axes ``u_i``
(outermost first), ``A(theta) = Rot(u_1, theta_1) @ ... @ Rot(u_n, theta_n)``, the angles that
bring ``A`` closest to a wanted rotation ``R`` are those that leave the smallest residual turn
``A^T R`` (its angle; for one axis this is also the Frobenius-closest rotation). A chain that can
express every rotation (three independent axes) reaches ``R`` exactly; one that cannot (a knee
with ``dof rx``, a wrist with ``rx rz``) keeps the part of the turn its axes allow. Among equally
close answers (more than three axes) the one nearest the starting angles is taken.

Plain numpy; torch only for the rotation logarithm.
"""

from __future__ import annotations

import numpy as np
import torch

from mdvae_cli.geometry.rotations import rotmat_to_rotvec

#: weight of "stay near the starting angles" against the residual turn (rad^2 per rad^2)
NEAR_WEIGHT = 1e-8
#: largest change of any angle in one step, rad (keeps a step sane where axes nearly align)
MAX_STEP = 0.5


def axis_rotations(axes: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rodrigues: turns about unit axes.  axes: (n, 3); angles: (T, n) rad -> (T, n, 3, 3)"""
    K = np.zeros((len(axes), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -axes[:, 2], axes[:, 1], -axes[:, 0]
    K -= np.swapaxes(K, -1, -2)
    s, c = np.sin(angles)[..., None, None], np.cos(angles)[..., None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def chain_rotation(axes: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """``Rot(u_1, a_1) @ ... @ Rot(u_n, a_n)``.  axes: (n, 3); angles: (T, n) -> (T, 3, 3)"""
    out = np.broadcast_to(np.eye(3), (angles.shape[0], 3, 3)).copy()
    for R in np.moveaxis(axis_rotations(axes, angles), 1, 0):
        out = out @ R
    return out


def closest_angles(
    R: np.ndarray, axes: np.ndarray, start: np.ndarray, iterations: int = 60
) -> np.ndarray:
    """Angles of the chain ``axes`` whose product comes closest to ``R``, from ``start``.

    Gauss-Newton on the residual turn ``log(A^T R)``, weighted by :data:`NEAR_WEIGHT` towards
    ``start`` (which settles the angles the residual does not fix, and the branch: the answer
    is the one the angles reach by moving continuously from ``start``).

    R: (T, 3, 3); axes: (n, 3) unit vectors, outermost first; start: (T, n) rad -> (T, n) rad
    """
    axes = np.asarray(axes, dtype=np.float64)
    theta = np.array(start, dtype=np.float64, copy=True)
    T, n = theta.shape
    if n == 0:
        return theta
    eye = np.eye(n)
    for _ in range(iterations):
        Rs = axis_rotations(axes, theta)
        Q = np.broadcast_to(np.eye(3), (T, 3, 3)).copy()  # turns after axis i
        J = np.empty((T, 3, n))
        for i in range(n - 1, -1, -1):
            J[:, :, i] = np.swapaxes(Q, -1, -2) @ axes[i]  # body-frame derivative of A
            Q = Rs[:, i] @ Q
        r = rotmat_to_rotvec(torch.from_numpy(np.swapaxes(Q, -1, -2) @ R)).numpy()
        H = np.swapaxes(J, -1, -2) @ J + NEAR_WEIGHT * eye
        g = (np.swapaxes(J, -1, -2) @ r[..., None])[..., 0] - NEAR_WEIGHT * (theta - start)
        step = np.clip(np.linalg.solve(H, g[..., None])[..., 0], -MAX_STEP, MAX_STEP)
        theta += step
        if np.abs(step).max() < 1e-13:
            break
    return theta
