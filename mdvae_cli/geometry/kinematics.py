"""Forward kinematics of a joint tree: local rotations and offsets to global rotations and
positions, for numpy arrays and torch tensors alike (the skeletons of takes, the SMPL body's
joints in the retarget solves)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch


def forward_kinematics(local_rotmats, offsets, parents: Sequence[int], root=None):
    """Global rotations and positions of every joint.

    local_rotmats: (..., J, 3, 3) each joint's rotation in its parent's frame (the root's in
    the world); offsets: (..., J, 3) or (J, 3), each joint's place in its parent's frame (the
    root's: its world position, unless ``root`` (..., 3) gives it); parents: (J,) each joint's
    parent index, -1 for the root, every parent before its children. numpy arrays or torch
    tensors (all of one kind). -> global rotations (..., J, 3, 3), positions (..., J, 3)
    """
    is_torch = isinstance(local_rotmats, torch.Tensor)
    G = [local_rotmats[..., 0, :, :]]
    start = offsets[..., 0, :] if root is None else root
    shape = G[0].shape[:-1]
    P = [start.expand(shape) if is_torch else np.broadcast_to(start, shape)]
    for j in range(1, len(parents)):
        p = parents[j]
        G.append(G[p] @ local_rotmats[..., j, :, :])
        P.append(P[p] + (G[p] @ offsets[..., j, :, None])[..., 0])
    stack = torch.stack if is_torch else np.stack
    return stack(G, -3), stack(P, -2)
