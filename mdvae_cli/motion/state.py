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


def finite_difference(p: torch.Tensor, fps: float, dim: int = -2) -> torch.Tensor:
    """Velocity along the time ``dim``.  p: (..., T, D) with T >= 2 -> (..., T, D)"""
    d = torch.diff(p, dim=dim) * fps
    first = d.narrow(dim, 0, 1)
    return torch.cat([first, d], dim=dim)


@dataclass
class BodyParams:
    """Body parameters of a sequence.  root_orient (..., T, 3), pose_body (..., T, 21, 3),
    trans (..., T, 3)."""

    root_orient: torch.Tensor
    pose_body: torch.Tensor
    trans: torch.Tensor


def params_to_state(params: BodyParams, fps: float) -> torch.Tensor:
    """Assemble the state.  -> x (..., T, 138)"""
    r, phi = params.trans, params.root_orient
    theta = params.pose_body.flatten(-2)
    return torch.cat(
        [r, finite_difference(r, fps), phi, finite_difference(phi, fps), theta,
         finite_difference(theta, fps)], dim=-1,
    )  # fmt: skip


def state_to_params(x: torch.Tensor) -> BodyParams:
    """Read the positional parts back.  x: (..., T, 138) -> BodyParams"""
    return BodyParams(
        root_orient=x[..., ROOT],
        pose_body=x[..., POSE].unflatten(-1, (NUM_BODY_JOINTS - 1, 3)),
        trans=x[..., TRANS],
    )
