"""The paper's state vector x = [r, dr, phi, dphi, Theta, dTheta] (138 values per frame).

Velocities are finite differences in units per second: backward differences
``(p[t] - p[t-1]) * fps`` for t >= 1, and the forward difference for t = 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from mdvae_cli.body.data import NUM_BODY_JOINTS

STATE_DIM = 138
#: slices of the state vector, named as in the paper (Eq. 1)
TRANS = slice(0, 3)  # r
TRANS_VEL = slice(3, 6)  # r dot
ROOT = slice(6, 9)  # phi
ROOT_VEL = slice(9, 12)  # phi dot
POSE = slice(12, 75)  # Theta
POSE_VEL = slice(75, 138)  # Theta dot
#: the velocity columns of the state (r dot, phi dot, Theta dot)
VELOCITY_DIMS = [
    *range(TRANS_VEL.start, TRANS_VEL.stop),
    *range(ROOT_VEL.start, ROOT_VEL.stop),
    *range(POSE_VEL.start, POSE_VEL.stop),
]


def finite_difference(p: torch.Tensor, fps: float, dim: int = -2) -> torch.Tensor:
    """Velocity along the time ``dim``.  p: (..., T, D) -> (..., T, D); a single frame has
    velocity 0."""
    if p.shape[dim] < 2:
        return torch.zeros_like(p)
    d = torch.diff(p, dim=dim) * fps
    first = d.narrow(dim, 0, 1)
    return torch.cat([first, d], dim=dim)


def smoothed_difference(p: torch.Tensor, fps: float, window: int, dim: int = -2) -> torch.Tensor:
    """Velocity by a local least-squares line over ``window`` frames (a Savitzky-Golay first
    derivative), for noisy observations where plain differences amplify the noise.

    The ends are extended by odd reflection (2 p[0] - p[k]), which keeps linear trends, so a
    constant-velocity motion gets its exact velocity everywhere.
    p: (..., T, D) -> (..., T, D); ``window`` odd >= 3 (1 gives :func:`finite_difference`).
    """
    if window <= 1:
        return finite_difference(p, fps, dim)
    h = window // 2
    x = p.movedim(dim, -1)  # (..., D, T)
    T = x.shape[-1]
    k = torch.arange(1, h + 1, device=p.device)
    idx_lo = k.clamp(max=T - 1).flip(0)
    idx_hi = (T - 1 - k).clamp(min=0)
    lo = 2 * x[..., :1] - x[..., idx_lo]
    hi = 2 * x[..., -1:] - x[..., idx_hi]
    padded = torch.cat([lo, x, hi], dim=-1)
    taps = torch.arange(-h, h + 1, dtype=p.dtype, device=p.device)
    weights = taps / (taps**2).sum()
    v = (padded.unfold(-1, window, 1) * weights).sum(-1) * fps
    return v.movedim(-1, dim)


@dataclass
class BodyParams:
    """Body parameters of a sequence.  root_orient (..., T, 3), pose_body (..., T, 21, 3),
    trans (..., T, 3)."""

    root_orient: torch.Tensor
    pose_body: torch.Tensor
    trans: torch.Tensor


def params_to_state(params: BodyParams, fps: float, velocity_window: int = 1) -> torch.Tensor:
    """Assemble the state.  -> x (..., T, 138)

    ``velocity_window`` > 1 takes velocities by :func:`smoothed_difference` (noisy inputs).
    """
    r, phi = params.trans, params.root_orient
    theta = params.pose_body.flatten(-2)
    vel = lambda p: smoothed_difference(p, fps, velocity_window)  # noqa: E731
    return torch.cat([r, vel(r), phi, vel(phi), theta, vel(theta)], dim=-1)


def state_to_params(x: torch.Tensor) -> BodyParams:
    """Read the positional parts back.  x: (..., T, 138) -> BodyParams"""
    return BodyParams(
        root_orient=x[..., ROOT],
        pose_body=x[..., POSE].unflatten(-1, (NUM_BODY_JOINTS - 1, 3)),
        trans=x[..., TRANS],
    )
