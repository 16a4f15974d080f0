"""The numpy rotations (``geometry.rotations_np``) against the torch ones they mirror: the same
values in float32 and float64 inputs, several batch shapes, round trips, zero angles and the
branch an axis-angle is on."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mdvae_cli.geometry import rotations as T
from mdvae_cli.geometry import rotations_np as N


def rotvecs(shape, seed=0, max_angle=np.pi) -> np.ndarray:
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=(*shape, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    return axis * rng.uniform(0, max_angle, size=(*shape, 1))


def torch_of(fn, x):
    return fn(torch.as_tensor(np.asarray(x, np.float64))).numpy()


@pytest.mark.parametrize("shape", [(), (7,), (4, 5), (2, 3, 6)])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_conversions_match_the_torch_ones(shape, dtype):
    r = rotvecs(shape, max_angle=0.99 * np.pi).astype(dtype)
    R = N.rotvec_to_rotmat(r)
    assert R.shape == (*shape, 3, 3) and R.dtype == np.float64
    np.testing.assert_allclose(R, torch_of(T.rotvec_to_rotmat, r), atol=1e-12)
    np.testing.assert_allclose(N.rotmat_to_quat(R), torch_of(T.rotmat_to_quat, R), atol=1e-12)
    np.testing.assert_allclose(N.rotmat_to_rotvec(R), torch_of(T.rotmat_to_rotvec, R), atol=1e-9)
    np.testing.assert_allclose(N.rotvec_to_quat(r), torch_of(T.rotvec_to_quat, r), atol=1e-12)
    np.testing.assert_allclose(N.rotmat_to_rotvec(R), r, atol=1e-6 if dtype == np.float32 else 1e-9)


def test_round_trips_and_zero_angle():
    r = np.concatenate([rotvecs((50,), seed=1), np.zeros((1, 3)), [[1e-10, 0.0, 0.0]]])
    np.testing.assert_allclose(N.quat_to_rotvec(N.rotvec_to_quat(r)), r, atol=1e-12)
    np.testing.assert_allclose(N.rotmat_to_rotvec(N.rotvec_to_rotmat(r)), r, atol=1e-9)
    assert np.array_equal(N.rotvec_to_rotmat(np.zeros(3)), np.eye(3))
    R = N.rotvec_to_rotmat(r)
    np.testing.assert_allclose(
        R @ R.swapaxes(-1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12
    )


def test_an_axis_angle_keeps_its_branch_through_the_quaternion():
    """Angles over pi: w < 0 in the quaternion, and the same axis-angle back."""
    r = rotvecs((20,), seed=2, max_angle=1.0) + 0.0
    long = r / np.linalg.norm(r, axis=-1, keepdims=True) * 4.0  # 4 rad about each axis
    q = N.rotvec_to_quat(long)
    assert (q[:, 0] < 0).all()
    np.testing.assert_allclose(N.quat_to_rotvec(q, keep_branch=True), long, atol=1e-12)
    # without keep_branch, as torch: the short way round
    np.testing.assert_allclose(N.quat_to_rotvec(q), torch_of(T.quat_to_rotvec, q), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(N.quat_to_rotvec(q), axis=-1), 2 * np.pi - 4.0)
    # the matrix forgets the branch: the short way round, 2 pi - 4 rad about the other side
    short = N.rotmat_to_rotvec(N.rotvec_to_rotmat(long))
    np.testing.assert_allclose(np.linalg.norm(short, axis=-1), 2 * np.pi - 4.0, atol=1e-9)


def test_quat_continuous_keeps_each_rotation_and_avoids_sign_jumps():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(50, 3, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    for first_positive in (False, True):
        c = N.quat_continuous(q, first_positive)
        assert np.allclose(np.abs(np.sum(c * q, -1)), 1.0)  # same rotations (q or -q)
        assert (np.sum(c[1:] * c[:-1], -1) >= 0).all()
    assert (N.quat_continuous(q, True)[0, :, 0] >= 0).all()
    assert np.array_equal(N.quat_continuous(q)[0], q[0])  # the first frame as it came
    assert N.quat_continuous(q[:0]).shape == (0, 3, 4)


def test_cross_is_numpys():
    a, b = rotvecs((6, 2), seed=3), rotvecs((6, 2), seed=4)
    np.testing.assert_allclose(N.cross(a, b), np.cross(a, b), atol=1e-15)


def test_forward_kinematics_of_a_known_chain_in_numpy_and_torch():
    from mdvae_cli.geometry.kinematics import forward_kinematics

    # root at (1, 0, 0) turned 90 degrees about z; a child 1 m along x; a grandchild 1 m along x
    L = N.rotvec_to_rotmat(np.array([[[0, 0, np.pi / 2], [0, 0, 0], [0, 0, 0]]]))  # (1, 3, 3, 3)
    offsets = np.array([[1.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0]])
    G, P = forward_kinematics(L, offsets, [-1, 0, 1])
    np.testing.assert_allclose(P[0], [[1, 0, 0], [1, 1, 0], [1, 2, 0]], atol=1e-12)
    np.testing.assert_allclose(G[0, 2], L[0, 0], atol=1e-12)
    # per-frame offsets, a root given apart, a batch of 4 frames; torch the same
    rng = np.random.default_rng(5)
    L = N.rotvec_to_rotmat(rotvecs((4, 5), seed=6))
    local = rng.normal(size=(4, 5, 3))
    root = rng.normal(size=(4, 3))
    parents = [-1, 0, 1, 1, 3]
    G, P = forward_kinematics(L, local, parents, root=root)
    assert G.shape == (4, 5, 3, 3) and P.shape == (4, 5, 3)
    np.testing.assert_allclose(P[:, 0], root)
    np.testing.assert_allclose(P[:, 4], P[:, 3] + (G[:, 3] @ local[:, 4, :, None])[..., 0])
    Gt, Pt = forward_kinematics(*(torch.as_tensor(a) for a in (L, local)), parents,
                                root=torch.as_tensor(root))  # fmt: skip
    np.testing.assert_allclose(Gt.numpy(), G, atol=1e-12)
    np.testing.assert_allclose(Pt.numpy(), P, atol=1e-12)


@pytest.mark.parametrize("axes", ["zxy", "xyz", "zyx", "yxz"])
def test_euler_angles_in_any_batch_shape(axes):
    from mdvae_cli.geometry.euler import euler_to_rotmat, rotmat_to_euler

    rng = np.random.default_rng(7)
    angles = rng.uniform(-1.2, 1.2, size=(4, 5, 3))
    R = euler_to_rotmat(angles, axes)
    unit = {a: np.eye(3)[i] for i, a in enumerate("xyz")}
    turns = [N.rotvec_to_rotmat(angles[..., k, None] * unit[a]) for k, a in enumerate(axes)]
    np.testing.assert_allclose(R, turns[0] @ turns[1] @ turns[2], atol=1e-12)
    np.testing.assert_allclose(rotmat_to_euler(R, axes, near=angles), angles, atol=1e-9)
    flat = rotmat_to_euler(R.reshape(-1, 3, 3), axes).reshape(angles.shape)
    np.testing.assert_allclose(rotmat_to_euler(R, axes), flat, atol=0)


def test_rotmat_between_turns_one_direction_into_the_other_the_short_way():
    rng = np.random.default_rng(8)
    u, v = rng.normal(size=(2, 6, 4, 3))
    R = N.rotmat_between(u, v)
    unit = v / np.linalg.norm(v, axis=-1, keepdims=True)
    np.testing.assert_allclose((R @ u[..., None])[..., 0] / np.linalg.norm(u, axis=-1)[..., None],
                               unit, atol=1e-12)  # fmt: skip
    angle = np.linalg.norm(N.rotmat_to_rotvec(R), axis=-1)
    between = np.arccos(np.clip((u * unit).sum(-1) / np.linalg.norm(u, axis=-1), -1, 1))
    np.testing.assert_allclose(angle, between, atol=1e-9)  # no longer than the angle between
    x = np.array([1.0, 0.0, 0.0])
    assert np.array_equal(N.rotmat_between(x, 2 * x), np.eye(3))
    half = N.rotmat_between(x, -x)  # opposite: half a turn about a perpendicular axis
    np.testing.assert_allclose(half @ x, -x, atol=1e-12)
    np.testing.assert_allclose(half @ half, np.eye(3), atol=1e-12)


@pytest.mark.parametrize("axes", ["yxz", "zxy"])
def test_euler_angles_near_gimbal_lock_stay_near_the_given_ones(axes):
    """A joint written at gimbal lock (its middle angle 90 degrees, as a rig's feet can be)
    and turned by a hundredth of a degree: the exact angles swing by tens of degrees, the ones
    solved near the given stay near them, with the rotation within a small fraction of a
    degree."""
    from mdvae_cli.geometry.euler import euler_to_rotmat, rotmat_to_euler

    rng = np.random.default_rng(3)
    T = 200
    given = np.stack([np.linspace(-0.4, 0.6, T), np.full(T, np.pi / 2), np.zeros(T)], -1)
    turn = N.rotvec_to_rotmat(rng.normal(0, np.radians(0.01), (T, 3)))
    R = turn @ euler_to_rotmat(given, axes)
    exact = rotmat_to_euler(R, axes)  # no angles to stay near: the exact decomposition
    held = rotmat_to_euler(R, axes, near=given)
    assert np.abs(np.diff(exact[:, 0])).max() > np.radians(5)  # the plain solution jumps
    assert np.abs(held - given).max() < np.radians(0.1)
    assert np.abs(np.diff(held, 2, axis=0)).max() < np.radians(0.1)
    err = N.rotmat_to_rotvec(np.swapaxes(euler_to_rotmat(held, axes), -1, -2) @ R)
    assert np.degrees(np.linalg.norm(err, axis=-1)).max() < 0.05


def test_quat_to_rotmat_inverts_rotmat_to_quat_and_matches_rotvec_to_rotmat():
    rng = np.random.default_rng(11)
    rotvec = rng.normal(0, 1.5, (6, 5, 3))
    R = N.rotvec_to_rotmat(rotvec)
    q = N.rotmat_to_quat(R)
    np.testing.assert_allclose(N.quat_to_rotmat(q), R, atol=1e-12)
    np.testing.assert_allclose(N.quat_to_rotmat(-3.0 * q), R, atol=1e-12)  # sign and scale
    np.testing.assert_allclose(N.quat_to_rotmat(N.rotvec_to_quat(rotvec)), R, atol=1e-12)


def test_angles_near_a_locked_input_for_a_rotation_away_from_lock_are_the_exact_ones():
    from mdvae_cli.geometry.euler import euler_to_rotmat, rotmat_to_euler

    near = np.array([[-1.74, np.radians(88.9), 1.65]])  # the file's frame at lock
    R = euler_to_rotmat(np.array([[-0.1, np.radians(78.0), 0.09]]), "zxy")  # the output's: not
    out = rotmat_to_euler(R, "zxy", near=near)
    np.testing.assert_allclose(euler_to_rotmat(out, "zxy"), R, atol=1e-12)


def test_quat_slerp_matches_the_torch_one_and_takes_the_short_way():
    q0 = N.rotvec_to_quat(rotvecs((6, 4), seed=1))
    q1 = N.rotvec_to_quat(rotvecs((6, 4), seed=2))
    q1[0, 0] = -q0[0, 0]  # one rotation given as both signs: no turn at all
    q1[1, 0] = q0[1, 0] + 1e-9  # nearly equal: the close branch
    t = np.random.default_rng(3).uniform(size=(6, 1))  # one weight a row, broadcast over joints
    got = N.quat_slerp(q0, q1, t)
    want = T.quat_slerp(torch.as_tensor(q0), torch.as_tensor(q1), torch.as_tensor(t).expand(6, 4))
    np.testing.assert_allclose(got, want.numpy(), atol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(got[0, 0] * q0[0, 0])), 1.0, atol=1e-12)
    np.testing.assert_allclose(N.quat_slerp(q0, q1, 0.0), q0, atol=1e-12)
    ends = N.quat_slerp(q0, q1, 1.0) * np.sign(np.sum(q0 * q1, axis=-1, keepdims=True))
    np.testing.assert_allclose(ends, q1, atol=1e-9)
    halfway = N.quat_to_rotmat(N.quat_slerp(q0[2:], q1[2:], 0.5))  # equal angles to both ends
    a0 = N.rotmat_to_rotvec(np.swapaxes(N.quat_to_rotmat(q0[2:]), -1, -2) @ halfway)
    a1 = N.rotmat_to_rotvec(np.swapaxes(halfway, -1, -2) @ N.quat_to_rotmat(q1[2:]))
    np.testing.assert_allclose(np.linalg.norm(a0, axis=-1), np.linalg.norm(a1, axis=-1), atol=1e-9)


@pytest.mark.parametrize("invert_a", [False, True])
def test_rotvec_product_is_the_torch_quaternion_product(invert_a):
    """b then a (a inverted first: b's turn away from a), angle in [0, pi], against the torch
    quaternions the blend used; angles near zero (the series) and past pi included."""
    a = np.concatenate([rotvecs((40, 3), seed=2, max_angle=2.5 * np.pi).reshape(-1, 3),
                        [[0.0, 0.0, 0.0], [1e-9, 0.0, 0.0], [0.3, -0.2, 0.1]]])  # fmt: skip
    b = np.concatenate([rotvecs((40, 3), seed=3, max_angle=2.5 * np.pi).reshape(-1, 3),
                        [[0.0, 0.0, 0.0], [0.0, 2e-9, 0.0], [0.3, -0.2, 0.1]]])  # fmt: skip
    qa = T.rotvec_to_quat(torch.as_tensor(a))
    if invert_a:
        qa = qa * torch.tensor([1.0, -1.0, -1.0, -1.0], dtype=torch.float64)
    want = T.quat_to_rotvec(T.quat_multiply(qa, T.rotvec_to_quat(torch.as_tensor(b)))).numpy()
    got = N.rotvec_product(a, b, invert_a=invert_a)
    np.testing.assert_allclose(got, want, atol=1e-12)
    assert np.linalg.norm(got, axis=-1).max() <= np.pi + 1e-12
    if invert_a:  # the same rotation's turn away from itself is none
        np.testing.assert_allclose(got[-1], 0.0, atol=1e-15)
    # shapes: any batch, and the rotation it gives is R(a) R(b)
    got2 = N.rotvec_product(a.reshape(-1, 1, 3), b.reshape(-1, 1, 3))
    assert got2.shape == (len(a), 1, 3)
    both = N.rotvec_to_rotmat(a) @ N.rotvec_to_rotmat(b)
    np.testing.assert_allclose(N.rotvec_to_rotmat(got2[:, 0]), both, atol=1e-12)
