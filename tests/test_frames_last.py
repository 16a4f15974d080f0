"""The frames-last 3x3 arithmetic the pose solve runs on (``geometry.frames_last``) agrees
with the frames-first functions it stands in for, and the numpy forward kinematics by tree
levels gives the joint-by-joint products bit for bit."""

import numpy as np
import torch

from mdvae_cli.body.data import SMPL_PARENTS
from mdvae_cli.geometry import frames_last as fl
from mdvae_cli.geometry.kinematics import (
    forward_kinematics,
    joint_position,
    tree_levels,
    world_rotations,
)
from mdvae_cli.geometry.rotations import rotmat_to_rotvec, rotvec_to_rotmat

PARENTS = [int(p) for p in SMPL_PARENTS[:22]]


def test_products_and_forward_kinematics_match_the_frames_first_ones():
    g = torch.Generator().manual_seed(3)
    T = 50
    A, B = (rotvec_to_rotmat(torch.randn(T, 4, 3, generator=g, dtype=torch.float64)) for _ in "ab")
    v = torch.randn(T, 4, 3, generator=g, dtype=torch.float64)
    Af, Bf, vf = A.permute(1, 2, 3, 0), B.permute(1, 2, 3, 0), v.permute(1, 2, 0)
    torch.testing.assert_close(fl.matmul3(Af, Bf).permute(3, 0, 1, 2), A @ B)
    torch.testing.assert_close(fl.matvec3(Af, vf).permute(2, 0, 1), (A @ v[..., None])[..., 0])
    At = A.transpose(-1, -2)
    torch.testing.assert_close(fl.matTvec3(Af, vf).permute(2, 0, 1), (At @ v[..., None])[..., 0])
    L = rotvec_to_rotmat(torch.randn(T, 22, 3, generator=g, dtype=torch.float64))
    bones = torch.randn(22, 3, generator=g, dtype=torch.float64)
    root = torch.randn(T, 3, generator=g, dtype=torch.float64)
    G, P = forward_kinematics(L, bones, PARENTS, root=root)
    Gf, Pf = fl.forward_kinematics(L.permute(1, 2, 3, 0).contiguous(), bones, PARENTS, root.T)
    torch.testing.assert_close(Gf.permute(3, 0, 1, 2), G)
    torch.testing.assert_close(Pf.permute(2, 0, 1), P)


def test_turns_frames_last_match_frames_first_also_past_half_a_turn():
    g = torch.Generator().manual_seed(4)
    v = torch.randn(40, 5, 3, generator=g, dtype=torch.float64)
    v[:10] *= 3.0 / v[:10].norm(dim=-1, keepdim=True)  # past 120 degrees: the exact fallback
    R = rotvec_to_rotmat(v)
    torch.testing.assert_close(fl.turn_matrix(v.permute(1, 2, 0), -2).permute(3, 0, 1, 2), R)
    got = fl.turn_vector(R.permute(1, 2, 3, 0), -2).permute(2, 0, 1)
    torch.testing.assert_close(got, fl.turn_vector(R), rtol=0, atol=0)
    torch.testing.assert_close(got, rotmat_to_rotvec(R), rtol=1e-6, atol=1e-9)


def test_numpy_forward_kinematics_by_levels_is_the_joint_by_joint_one():
    rng = np.random.default_rng(5)
    parents = [-1, 0, 1, 0, 3, 4, 1, 2, 6]
    assert tree_levels(tuple(parents)) == (([1, 3], [0, 0]), ([2, 4, 6], [1, 3, 1]),
                                           ([5, 7, 8], [4, 2, 6]))  # fmt: skip
    L = rotvec_to_rotmat(torch.as_tensor(rng.normal(size=(30, 9, 3)))).numpy()
    for offsets in (rng.normal(size=(9, 3)), rng.normal(size=(30, 9, 3))):
        for root in (None, rng.normal(size=(30, 3))):
            G, P = forward_kinematics(L, offsets, parents, root=root)
            rt = None if root is None else torch.as_tensor(root)
            _, Pt = forward_kinematics(torch.as_tensor(L), torch.as_tensor(offsets), parents, rt)
            Gw = [L[:, 0]]
            Pw = [offsets[..., 0, :] if root is None else root]
            for j in range(1, 9):
                p = parents[j]
                Gw.append(Gw[p] @ L[:, j])
                Pw.append(Pw[p] + (Gw[p] @ offsets[..., j, :, None])[..., 0])
            assert np.array_equal(G, np.stack(Gw, 1))
            assert np.array_equal(P, np.stack(np.broadcast_arrays(*Pw), 1))
            np.testing.assert_allclose(P, Pt.numpy(), atol=1e-12)


def test_world_rotations_and_one_joints_position_are_the_forward_kinematics_ones():
    rng = np.random.default_rng(6)
    parents = [-1, 0, 1, 0, 3, 4, 1, 2, 6]
    L = rotvec_to_rotmat(torch.as_tensor(rng.normal(size=(30, 9, 3)))).numpy()
    offsets = rng.normal(size=(30, 9, 3))
    G, P = forward_kinematics(L, offsets, parents)
    assert np.array_equal(world_rotations(L, parents), G)
    for j in range(9):
        np.testing.assert_allclose(joint_position(G, offsets, parents, j), P[:, j], atol=1e-12)
