"""Canonical frames and fixed-length windows of a motion, and their inverse (blending).

A window is canonicalised so that its first frame's pelvis sits above the world origin and
faces +x: the networks then see motion, not where in the room it happened. World is z-up
(AMASS); a body's forward direction is its model +z axis, as in SMPL.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from mdvae_cli.geometry.rotations import (
    rotmat_to_rotvec,
    rotvec_to_rotmat,
    rotvec_unwrap,
    rotvec_wrap,
)
from mdvae_cli.model.state import BodyParams


def rotation_about_z(yaw: torch.Tensor) -> torch.Tensor:
    """yaw: (...) radians -> (..., 3, 3)"""
    c, s = torch.cos(yaw), torch.sin(yaw)
    o, i = torch.zeros_like(yaw), torch.ones_like(yaw)
    return torch.stack([c, -s, o, s, c, o, o, o, i], dim=-1).reshape(*yaw.shape, 3, 3)


def heading(root_orient: torch.Tensor) -> torch.Tensor:
    """Yaw of the body's forward (model +z) axis in the world xy plane.  (..., 3) -> (...)"""
    forward = rotvec_to_rotmat(root_orient)[..., :, 2]
    return torch.atan2(forward[..., 1], forward[..., 0])


@dataclass
class CanonicalFrame:
    """The rigid move that canonicalised a window.  yaw: (B,), origin: (B, 3) with z = 0."""

    yaw: torch.Tensor
    origin: torch.Tensor


def canonical_frame(params: BodyParams, pelvis_rest: torch.Tensor) -> CanonicalFrame:
    """Each window's own canonical frame: frame 0's heading, and its pelvis on the floor.

    params: root_orient (B, T, 3), trans (B, T, 3); pelvis_rest: (B, 3)"""
    origin = params.trans[:, 0] + pelvis_rest
    origin = torch.cat([origin[:, :2], torch.zeros_like(origin[:, 2:])], dim=-1)
    return CanonicalFrame(yaw=heading(params.root_orient[:, 0]), origin=origin)


def canonicalize(
    params: BodyParams, pelvis_rest: torch.Tensor, frame: CanonicalFrame | None = None
) -> tuple[BodyParams, CanonicalFrame]:
    """Move windows so frame 0's pelvis is at x = y = 0, facing +x; unwrap axis-angles in time.

    params: root_orient (B, T, 3), pose_body (B, T, 21, 3), trans (B, T, 3);
    pelvis_rest: (B, 3) the rest-pose pelvis joint for each window's shape (the root rotates
    about it, so a rigid move changes ``trans`` by ``Rz (trans + pelvis) - pelvis``);
    frame: apply this move instead of the windows' own (e.g. another version of the same
    windows, so both land in one coordinate frame).
    """
    pelvis = params.trans + pelvis_rest[:, None]
    if frame is None:
        frame = canonical_frame(params, pelvis_rest)
    yaw, origin = frame.yaw, frame.origin
    Rz = rotation_about_z(-yaw)[:, None]
    R = Rz @ rotvec_to_rotmat(params.root_orient)
    new_pelvis = (Rz @ (pelvis - origin[:, None])[..., None])[..., 0]
    out = BodyParams(
        root_orient=rotvec_unwrap(rotmat_to_rotvec(R), dim=1),
        pose_body=rotvec_unwrap(params.pose_body, dim=1),
        trans=new_pelvis - pelvis_rest[:, None],
    )
    return out, frame


def uncanonicalize(
    params: BodyParams, frame: CanonicalFrame, pelvis_rest: torch.Tensor
) -> BodyParams:
    """Inverse of :func:`canonicalize` (axis-angles come back with angles in [0, pi])."""
    Rz = rotation_about_z(frame.yaw)[:, None]
    R = Rz @ rotvec_to_rotmat(params.root_orient)
    pelvis = params.trans + pelvis_rest[:, None]
    world = (Rz @ pelvis[..., None])[..., 0] + frame.origin[:, None]
    return BodyParams(
        root_orient=rotmat_to_rotvec(R),
        pose_body=rotvec_wrap(params.pose_body),
        trans=world - pelvis_rest[:, None],
    )


def window_starts(num_frames: int, length: int, stride: int) -> list[int]:
    """Start indices of windows of ``length`` frames every ``stride`` frames covering all frames.

    The last window is aligned to the end so no frame is left out; a motion shorter than
    ``length`` gets one window starting at 0 (the caller pads it).
    """
    if num_frames <= length:
        return [0]
    starts = list(range(0, num_frames - length + 1, stride))
    if starts[-1] != num_frames - length:
        starts.append(num_frames - length)
    return starts
