"""Forward kinematics of a joint tree: local rotations and offsets to global rotations and
positions, for numpy arrays and torch tensors alike (the skeletons of takes, the SMPL body's
joints in the retarget solves)."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from functools import lru_cache

import numpy as np


def forward_kinematics(local_rotmats, offsets, parents: Sequence[int], root=None):
    """Global rotations and positions of every joint.

    local_rotmats: (..., J, 3, 3) each joint's rotation in its parent's frame (the root's in
    the world); offsets: (..., J, 3) or (J, 3), each joint's place in its parent's frame (the
    root's: its world position, unless ``root`` (..., 3) gives it); parents: (J,) each joint's
    parent index, -1 for the root, every parent before its children. numpy arrays or torch
    tensors (all of one kind). -> global rotations (..., J, 3, 3), positions (..., J, 3)
    """
    start = offsets[..., 0, :] if root is None else root
    torch = sys.modules.get("torch")  # not loaded: no tensor was given (file readers stay lean)
    if torch is None or not isinstance(local_rotmats, torch.Tensor):
        return _numpy_levels(local_rotmats, np.asarray(offsets), parents, np.asarray(start))
    G = [local_rotmats[..., 0, :, :]]
    shape = G[0].shape[:-1]
    P = [start.expand(shape)]
    for j in range(1, len(parents)):
        p = parents[j]
        G.append(G[p] @ local_rotmats[..., j, :, :])
        P.append(P[p] + (G[p] @ offsets[..., j, :, None])[..., 0])
    return torch.stack(G, -3), torch.stack(P, -2)


@lru_cache(maxsize=64)
def tree_levels(parents: tuple[int, ...]) -> tuple[tuple[list[int], list[int]], ...]:
    """The joints below the root grouped by depth, the shallowest first: each level's joints
    and their parents (no joint of a level is another's ancestor). parents: (J,), every
    parent before its children."""
    depth = [0] * len(parents)
    levels: dict[int, tuple[list[int], list[int]]] = {}
    for j in range(1, len(parents)):
        depth[j] = depth[parents[j]] + 1
        joints, above = levels.setdefault(depth[j], ([], []))
        joints.append(j)
        above.append(parents[j])
    return tuple(levels[d] for d in sorted(levels))


def _numpy_levels(L: np.ndarray, offsets: np.ndarray, parents, start: np.ndarray):
    """:func:`forward_kinematics` of numpy arrays, a level of the tree at a time (the same
    products as joint by joint, in fewer calls).  -> (..., J, 3, 3), (..., J, 3)"""
    batch = L.shape[:-3]
    G = np.empty(L.shape, np.result_type(L))
    P = np.empty((*batch, L.shape[-3], 3), np.result_type(L, offsets, start))
    G[..., 0, :, :] = L[..., 0, :, :]
    P[..., 0, :] = start
    for joints, above in tree_levels(tuple(int(p) for p in parents)):
        Gp = G[..., above, :, :]
        G[..., joints, :, :] = Gp @ L[..., joints, :, :]
        P[..., joints, :] = P[..., above, :] + (Gp @ offsets[..., joints, :, None])[..., 0]
    return G, P


def world_rotations(L: np.ndarray, parents) -> np.ndarray:
    """The global rotations of :func:`forward_kinematics` (numpy, by tree levels: the same
    products) without the positions.  L: (..., J, 3, 3) -> (..., J, 3, 3)"""
    G = np.empty(L.shape, np.result_type(L))
    G[..., 0, :, :] = L[..., 0, :, :]
    for joints, above in tree_levels(tuple(int(p) for p in parents)):
        G[..., joints, :, :] = G[..., above, :, :] @ L[..., joints, :, :]
    return G


def joint_position(G: np.ndarray, offsets: np.ndarray, parents, j: int) -> np.ndarray:
    """One joint's position as :func:`forward_kinematics` gives it (the same sums, down the
    joint's own chain alone), from the global rotations ``G`` (..., J, 3, 3) and ``offsets``
    (..., J, 3) (the root's: its world position).  -> (..., 3)"""
    chain = [j]
    while parents[chain[-1]] >= 0:
        chain.append(int(parents[chain[-1]]))
    P = offsets[..., 0, :]
    for k in reversed(chain[:-1]):
        p = int(parents[k])
        P = P + (G[..., p, :, :] @ offsets[..., k, :, None])[..., 0]
    return P
