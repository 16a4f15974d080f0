"""The learned fill: what a hole's cubic curve misses, read from the motion around it.

A hole's frames are first filled by a cubic Hermite curve (``motion.holes``, the end values
and velocities of the frames beside it). That curve knows nothing of how people move: a
second-long hole in a walk loses its step. The :class:`Infiller` reads a window of the filled
motion (heading-free: turned so its first frame faces +x, its first pelvis at the origin)
with the mask and the place of each frame in its hole, and gives each missing joint a
correction: a rotation on the right of the curve's (in the joint's own frame) and, where the
pelvis is missing, a translation in the window's heading frame. It is trained on the clean
corpus the prior learns from, with holes cut at random (``train.train_infiller``).

Pure torch. Shapes: B windows of L frames, 22 rotations (root orientation first, then the 21
body joints), axis-angle.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
from torch import nn

from mdvae_cli.geometry.rotations import (
    quat_multiply,
    quat_to_rotvec,
    rotmat_to_rot6d,
    rotvec_to_quat,
    rotvec_to_rotmat,
)

NUM_ROTATIONS = 22
#: per-frame input width: 22 rotations as 6D, translation (3), its velocity (3), mask (22),
#: place in the hole (1), hole length (1)
INPUT_WIDTH = NUM_ROTATIONS * 6 + 3 + 3 + NUM_ROTATIONS + 2
#: output: a rotation correction per joint (axis-angle) and a translation correction
OUTPUT_WIDTH = NUM_ROTATIONS * 3 + 3
#: metres of translation error that weigh as much as one radian of rotation error
TRANS_WEIGHT = 4.0
#: longest hole (frames at 30 Hz) the training saw; a longer one is scaled as this
LONGEST_HOLE = 60


@dataclass
class InfillerConfig:
    channels: int = 96
    dilations: tuple[int, ...] = (1, 2, 4, 8, 1, 2)
    kernel: int = 5
    window: int = 120  # frames at 30 Hz a window holds (hole and context)

    def to_dict(self) -> dict:
        return {**asdict(self), "dilations": list(self.dilations)}


class Infiller(nn.Module):
    """Dilated temporal convolutions with residual connections over a window (each frame sees
    about a second either side): features (B, L, INPUT_WIDTH) -> corrections
    (B, L, OUTPUT_WIDTH) (22 axis-angles, then a translation)."""

    def __init__(self, cfg: InfillerConfig | None = None):
        super().__init__()
        self.cfg = cfg or InfillerConfig()
        c, k = self.cfg.channels, self.cfg.kernel
        self.inp = nn.Conv1d(INPUT_WIDTH, c, 1)
        self.blocks = nn.ModuleList(
            nn.Conv1d(c, c, k, dilation=d, padding=d * (k // 2)) for d in self.cfg.dilations
        )
        self.out = nn.Conv1d(c, OUTPUT_WIDTH, 1)
        nn.init.zeros_(self.out.weight)  # starts as the curve itself
        nn.init.zeros_(self.out.bias)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        h = self.inp(features.transpose(1, 2))
        for conv in self.blocks:
            h = h + nn.functional.gelu(conv(h))
        return self.out(h).transpose(1, 2)


def heading(rotvec: torch.Tensor) -> torch.Tensor:
    """Yaw (rad, about +z) of the body's forward axis.  rotvec: (..., 3) -> (...)"""
    R = rotvec_to_rotmat(rotvec)
    return torch.atan2(R[..., 1, 2], R[..., 0, 2])


def yaw_quat(angle: torch.Tensor) -> torch.Tensor:
    """Quaternions (w, x, y, z) of turns about +z.  (...) -> (..., 4)"""
    half = 0.5 * angle
    zero = torch.zeros_like(half)
    return torch.stack([torch.cos(half), zero, zero, torch.sin(half)], dim=-1)


def turn_xy(v: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Vectors turned by ``angle`` about +z.  v: (B, L, 3), angle: (B,) -> (B, L, 3)"""
    c, s = torch.cos(angle)[:, None], torch.sin(angle)[:, None]
    x, y = v[..., 0], v[..., 1]
    return torch.stack([c * x - s * y, s * x + c * y, v[..., 2]], dim=-1)


def canonical(
    rot: torch.Tensor, trans: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A window turned so its first frame faces the same way every time, its first pelvis
    over the origin.

    rot: (B, L, 22, 3), trans: (B, L, 3) -> (rot, trans, the yaw taken off (B,))"""
    yaw = heading(rot[:, 0, 0]) - 0.5 * math.pi
    q_root = quat_multiply(yaw_quat(-yaw)[:, None], rotvec_to_quat(rot[:, :, 0]))
    rot = torch.cat([quat_to_rotvec(q_root)[:, :, None], rot[:, :, 1:]], dim=2)
    origin = trans[:, :1] * torch.tensor([1.0, 1.0, 0.0], dtype=trans.dtype)
    return rot, turn_xy(trans - origin, -yaw), yaw


def features(
    rot: torch.Tensor,
    trans: torch.Tensor,
    mask: torch.Tensor,
    place: torch.Tensor,
    length: torch.Tensor,
) -> torch.Tensor:
    """The infiller's input for canonical windows.

    rot: (B, L, 22, 3) the curve-filled rotations; trans: (B, L, 3); mask: (B, L, 22) 1 =
    observed; place: (B, L) 0..1 through the frame's hole (0 outside); length: (B, L) its hole's
    length over :data:`LONGEST_HOLE` (0 outside) -> (B, L, INPUT_WIDTH)"""
    B, L = rot.shape[:2]
    six = rotmat_to_rot6d(rotvec_to_rotmat(rot)).reshape(B, L, -1)
    vel = torch.cat([torch.zeros_like(trans[:, :1]), trans[:, 1:] - trans[:, :-1]], dim=1)
    return torch.cat(
        [six, trans, 30.0 * vel, mask, place[..., None], length[..., None]], dim=-1
    ).float()


def apply_corrections(
    rot: torch.Tensor, trans: torch.Tensor, corrections: torch.Tensor, yaw: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """World rotations and translation with the corrections put on (rotations on the right,
    in each joint's frame; the translation turned back to the world's heading).

    rot: (B, L, 22, 3), trans: (B, L, 3) world; corrections: (B, L, OUTPUT_WIDTH); yaw: (B,)"""
    B, L = rot.shape[:2]
    dq = rotvec_to_quat(corrections[..., : 3 * NUM_ROTATIONS].reshape(B, L, NUM_ROTATIONS, 3))
    q = quat_multiply(rotvec_to_quat(rot), dq.to(rot.dtype))
    dt = turn_xy(corrections[..., 3 * NUM_ROTATIONS :].to(trans.dtype), yaw)
    return quat_to_rotvec(q), trans + dt


def target_corrections(
    rot_fill: torch.Tensor,
    trans_fill: torch.Tensor,
    rot_true: torch.Tensor,
    trans_true: torch.Tensor,
) -> torch.Tensor:
    """What the corrections should be (canonical windows): the rotation taking each curve
    rotation to the true one (on the right) and the translation difference.
    (B, L, 22, 3) x2, (B, L, 3) x2 -> (B, L, OUTPUT_WIDTH)"""
    q_fill_inv = rotvec_to_quat(rot_fill) * torch.tensor(
        [1.0, -1.0, -1.0, -1.0], dtype=rot_fill.dtype
    )
    dr = quat_to_rotvec(quat_multiply(q_fill_inv, rotvec_to_quat(rot_true)))
    B, L = rot_fill.shape[:2]
    return torch.cat([dr.reshape(B, L, -1), trans_true - trans_fill], dim=-1)


def infill_loss(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean squared error on the missing entries: rotations where their joint is missing, the
    translation (x TRANS_WEIGHT) where the pelvis is.  (B, L, OUT) x2, mask (B, L, 22) -> ()"""
    B, L = mask.shape[:2]
    miss = 1.0 - mask
    err_r = ((pred[..., :-3] - target[..., :-3]) ** 2).reshape(B, L, NUM_ROTATIONS, 3).sum(-1)
    err_t = TRANS_WEIGHT**2 * ((pred[..., -3:] - target[..., -3:]) ** 2).sum(-1)
    n = miss.sum() + miss[..., 0].sum()
    return ((err_r * miss).sum() + (err_t * miss[..., 0]).sum()) / n.clamp_min(1.0)


def load_infiller(path=None) -> Infiller:
    """The learned fill's weights (None: those shipped with the package)."""
    from pathlib import Path

    from mdvae_cli.errors import InputError
    from mdvae_cli.model.checkpoint import load_checkpoint, load_weights
    from mdvae_cli.weights import default_weights

    path = default_weights("infiller") if path is None else Path(path)
    tensors, meta = load_checkpoint(path)
    if meta.get("kind") != "infiller":
        raise InputError(f"{path} is not a learned-fill checkpoint")
    cfg = meta["config"]
    model = Infiller(InfillerConfig(**{**cfg, "dilations": tuple(cfg["dilations"])}))
    load_weights(model, tensors, path)
    return model.eval()
