"""Rotation conversions: known rotations, round trips, batch shapes, dtypes, gradients."""

import math

import pytest
import torch

from mdvae_cli.geometry import rotations as R

DTYPES = [torch.float32, torch.float64]
SHAPES = [(3,), (7, 3), (2, 5, 3)]


def tol(dtype):
    return 1e-5 if dtype == torch.float32 else 1e-10


def random_rotvecs(shape, dtype, max_angle=math.pi - 1e-3, seed=0):
    g = torch.Generator().manual_seed(seed)
    axis = torch.randn(shape, generator=g, dtype=dtype)
    axis = axis / axis.norm(dim=-1, keepdim=True)
    angle = torch.rand(shape[:-1], generator=g, dtype=dtype) * max_angle
    return axis * angle[..., None]


@pytest.mark.parametrize("dtype", DTYPES)
def test_known_rotation_90_about_z(dtype):
    r = torch.tensor([0.0, 0.0, math.pi / 2], dtype=dtype)
    m = R.rotvec_to_rotmat(r)
    expected = torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=dtype)
    torch.testing.assert_close(m, expected, atol=tol(dtype), rtol=0)
    q = R.rotvec_to_quat(r)
    s = math.sqrt(0.5)
    torch.testing.assert_close(q, torch.tensor([s, 0, 0, s], dtype=dtype), atol=tol(dtype), rtol=0)
    # x axis maps to y axis
    torch.testing.assert_close(
        m @ torch.tensor([1.0, 0, 0], dtype=dtype),
        torch.tensor([0.0, 1, 0], dtype=dtype),
        atol=tol(dtype),
        rtol=0,
    )


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", SHAPES)
def test_round_trips(dtype, shape):
    r = random_rotvecs(shape, dtype)
    m = R.rotvec_to_rotmat(r)
    assert m.shape == (*shape[:-1], 3, 3)
    torch.testing.assert_close(R.rotmat_to_rotvec(m), r, atol=100 * tol(dtype), rtol=0)
    torch.testing.assert_close(
        R.quat_to_rotvec(R.rotvec_to_quat(r)), r, atol=10 * tol(dtype), rtol=0
    )
    torch.testing.assert_close(
        R.quat_to_rotmat(R.rotmat_to_quat(m)), m, atol=10 * tol(dtype), rtol=0
    )
    torch.testing.assert_close(
        R.rot6d_to_rotmat(R.rotmat_to_rot6d(m)), m, atol=10 * tol(dtype), rtol=0
    )
    torch.testing.assert_close(
        R.rot6d_to_rotvec(R.rotvec_to_rot6d(r)), r, atol=100 * tol(dtype), rtol=0
    )
    # orthonormal with det +1
    eye = torch.eye(3, dtype=dtype).expand(m.shape)
    torch.testing.assert_close(m @ m.transpose(-1, -2), eye, atol=10 * tol(dtype), rtol=0)
    torch.testing.assert_close(
        torch.linalg.det(m), torch.ones(shape[:-1], dtype=dtype), atol=10 * tol(dtype), rtol=0
    )


def test_quaternion_scalar_first_and_product_matches_matrices():
    a, b = random_rotvecs((4, 3), torch.float64, seed=1), random_rotvecs((4, 3), torch.float64, 2)
    qa, qb = R.rotvec_to_quat(a), R.rotvec_to_quat(b)
    m = R.quat_to_rotmat(R.quat_multiply(qa, qb))
    torch.testing.assert_close(m, R.rotvec_to_rotmat(a) @ R.rotvec_to_rotmat(b))


@pytest.mark.parametrize("dtype", DTYPES)
def test_near_pi_is_stable(dtype):
    for angle in (math.pi - 1e-6, math.pi):
        r = torch.tensor(
            [[angle, 0.0, 0.0], [0.0, angle / math.sqrt(2), angle / math.sqrt(2)]], dtype=dtype
        )
        m = R.rotvec_to_rotmat(r)
        back = R.rotmat_to_rotvec(m)
        assert torch.isfinite(back).all()
        # the same rotation (axis sign may flip at exactly pi)
        torch.testing.assert_close(R.rotvec_to_rotmat(back), m, atol=1e-5, rtol=0)
        assert abs(back.norm(dim=-1) - angle).max() < 1e-3


@pytest.mark.parametrize("dtype", DTYPES)
def test_zero_angle_values_and_finite_gradients(dtype):
    r = torch.zeros(2, 3, dtype=dtype, requires_grad=True)
    m = R.rotvec_to_rotmat(r)
    torch.testing.assert_close(m, torch.eye(3, dtype=dtype).expand(2, 3, 3))
    (m.sum() + R.rotvec_to_quat(r).sum() + R.rotvec_to_rot6d(r).sum()).backward()
    assert torch.isfinite(r.grad).all()
    m2 = torch.eye(3, dtype=dtype, requires_grad=True)
    R.rotmat_to_rotvec(m2).sum().backward()
    assert torch.isfinite(m2.grad).all()
    q = torch.tensor([1.0, 0, 0, 0], dtype=dtype, requires_grad=True)
    R.quat_to_rotvec(q).sum().backward()
    assert torch.isfinite(q.grad).all()


def test_gradcheck_rodrigues_small_and_large_angles():
    for scale in (1e-5, 1.0):
        r = (random_rotvecs((3, 3), torch.float64, seed=3) * scale).requires_grad_()
        assert torch.autograd.gradcheck(R.rotvec_to_rotmat, (r,))


def test_slerp_endpoints_midpoint_and_constant_speed():
    r0 = torch.tensor([0.0, 0.0, 0.0], dtype=torch.float64)
    r1 = torch.tensor([0.0, 0.0, 2.0], dtype=torch.float64)
    torch.testing.assert_close(R.rotvec_slerp(r0, r1, 0.0), r0)
    torch.testing.assert_close(R.rotvec_slerp(r0, r1, 1.0), r1)
    ts = torch.linspace(0, 1, 11, dtype=torch.float64)
    out = R.rotvec_slerp(r0.expand(11, 3), r1.expand(11, 3), ts)
    torch.testing.assert_close(out[:, 2], 2.0 * ts)
    # shorter arc: from +170 deg to -170 deg goes through 180, not through 0
    a = torch.tensor([0.0, 0.0, math.radians(170)], dtype=torch.float64)
    b = torch.tensor([0.0, 0.0, math.radians(-170)], dtype=torch.float64)
    mid = R.rotvec_slerp(a, b, 0.5)
    assert abs(mid.norm() - math.pi) < 1e-6


def test_unwrap_removes_2pi_jumps():
    angle = torch.linspace(0, 1.8 * math.pi, 60, dtype=torch.float64)
    truth = torch.stack([torch.zeros_like(angle), torch.zeros_like(angle), angle], -1)
    wrapped = R.rotmat_to_rotvec(R.rotvec_to_rotmat(truth))
    assert (wrapped[1:] - wrapped[:-1]).norm(dim=-1).max() > 3.0  # a jump exists
    un = R.rotvec_unwrap(wrapped)
    torch.testing.assert_close(un, truth, atol=1e-8, rtol=0)
    torch.testing.assert_close(R.rotvec_to_rotmat(un), R.rotvec_to_rotmat(wrapped))
    # batched along dim 1
    un_b = R.rotvec_unwrap(wrapped[None].expand(2, -1, -1), dim=1)
    torch.testing.assert_close(un_b[1], truth, atol=1e-8, rtol=0)


def test_wrap_brings_angles_into_0_pi_and_keeps_the_rotation():
    torch.manual_seed(0)
    r = torch.randn(2000, 3, dtype=torch.float64) * 4.0  # angles up to ~4 pi
    w = R.rotvec_wrap(r)
    assert float(w.norm(dim=-1).max()) <= math.pi + 1e-12
    torch.testing.assert_close(R.rotvec_to_rotmat(w), R.rotvec_to_rotmat(r), atol=1e-12, rtol=0)
    small = r[r.norm(dim=-1) < 3.0]
    assert torch.equal(R.rotvec_wrap(small), small)  # already in range: untouched
    # an angle of 3 pi / 2 about +z is pi / 2 about -z
    got = R.rotvec_wrap(torch.tensor([0.0, 0.0, 1.5 * math.pi], dtype=torch.float64))
    torch.testing.assert_close(got, torch.tensor([0.0, 0.0, -0.5 * math.pi], dtype=torch.float64))
    # undoes unwrap
    seq = R.rotvec_unwrap(R.rotmat_to_rotvec(R.rotvec_to_rotmat(r[:50])))
    torch.testing.assert_close(R.rotvec_to_rotmat(R.rotvec_wrap(seq)), R.rotvec_to_rotmat(r[:50]))


def test_quat_to_rotvec_small_angles_match_the_exact_angle():
    """Below the small-angle switch the series must agree with 2 atan2(s, w) / s to float64
    rounding (it once had the wrong second-order term: 5e-7 relative at the switch)."""
    angles = torch.tensor([1e-9, 1e-6, 1e-4, 1e-3, 1.9e-3, 1.99e-3], dtype=torch.float64)
    axis = torch.nn.functional.normalize(torch.tensor([0.3, -0.5, 0.8], dtype=torch.float64), dim=0)
    q = torch.cat([torch.cos(angles / 2)[:, None], torch.sin(angles / 2)[:, None] * axis], dim=1)
    assert ((q[:, 1:] ** 2).sum(-1) < 1e-6).all()  # every one on the series' side
    got = R.quat_to_rotvec(q)
    assert torch.allclose(got.norm(dim=-1), angles, rtol=1e-12, atol=0)
    assert torch.allclose(got / got.norm(dim=-1, keepdim=True), axis.expand(6, 3), atol=1e-12)
