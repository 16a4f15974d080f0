"""The hand-written fast paths of the BVH round trip give what the plain ones give: the motion
text (as numpy's savetxt writes it), Euler matrices, the pose solve's turn conversions, the
quaternion pivots, the motion parser."""

from __future__ import annotations

import io

import numpy as np
import pytest
import torch

from mdvae_cli.formats.bvh import _parse_floats
from mdvae_cli.formats.bvh_write import format_rows
from mdvae_cli.geometry import rotations_np
from mdvae_cli.geometry.euler import euler_to_rotmat
from mdvae_cli.geometry.frames_last import turn_matrix, turn_vector
from mdvae_cli.geometry.rotations import rotmat_to_rotvec, rotvec_to_rotmat


def _savetxt(data: np.ndarray) -> str:
    buf = io.StringIO()
    np.savetxt(buf, data, fmt="%.6f", delimiter=" ")
    return buf.getvalue()


@pytest.mark.parametrize("scale", [1e-7, 1e-3, 1.0, 50.0, 1e4, 9e7, 2e8])
def test_format_rows_writes_what_savetxt_writes(scale):
    data = np.random.default_rng(0).standard_normal((300, 9)) * scale
    assert format_rows(data) == _savetxt(data)


def test_format_rows_rounds_halves_signs_and_odd_values_as_savetxt():
    halves = ((np.arange(-3000, 3000) + 0.5) / 1e6).reshape(100, 60)
    odd = np.array([[0.0, -0.0, -1e-9, 5e-7, -5e-7, 1.5e-6, 9.9999995, -999.9999996, 1e6]])
    for data in (halves, odd, np.array([[1.0]]), np.array([[np.nan, np.inf, 1.0]])):
        assert format_rows(data) == _savetxt(data)
    assert format_rows(np.zeros((0, 4))) == ""


def test_euler_to_rotmat_is_the_product_of_its_axis_rotations():
    rng = np.random.default_rng(1)

    def axis(a, letter):
        c, s = np.cos(a), np.sin(a)
        i = "xyz".index(letter)
        R = np.zeros((*a.shape, 3, 3))
        j, k = (i + 1) % 3, (i + 2) % 3
        R[..., i, i], R[..., j, j], R[..., j, k], R[..., k, j], R[..., k, k] = 1, c, -s, s, c
        return R

    for axes in ("zxy", "xyz", "yzx", "zz", "x", "xzxy"):
        angles = 3 * rng.standard_normal((20, 2, len(axes)))
        want = np.broadcast_to(np.eye(3), (20, 2, 3, 3))
        for k, letter in enumerate(axes):
            want = want @ axis(angles[..., k], letter)
        np.testing.assert_allclose(euler_to_rotmat(angles, axes), want, atol=1e-15)
    np.testing.assert_array_equal(
        euler_to_rotmat(np.zeros((4, 0)), ""), np.tile(np.eye(3), (4, 1, 1))
    )


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_pose_solve_turns_match_the_rotation_conversions(dtype):
    g = torch.Generator().manual_seed(0)
    for scale in (1e-9, 1e-4, 0.1, 1.0, 3.0):
        v = (scale * torch.randn(500, 3, generator=g, dtype=torch.float64)).to(dtype)
        R = rotvec_to_rotmat(v)
        torch.testing.assert_close(turn_matrix(v), R)
        # the two agree (rotmat_to_rotvec through quaternions, turn_vector from the skew part)
        torch.testing.assert_close(turn_vector(R), rotmat_to_rotvec(R), rtol=1e-5, atol=1e-7)
    assert turn_vector(torch.eye(3, dtype=torch.float64)).abs().max() == 0


def test_rotmat_to_quat_takes_the_largest_pivot():
    rng = np.random.default_rng(2)
    R = rotations_np.rotvec_to_rotmat(2.5 * rng.standard_normal((400, 3)))
    q = rotations_np.rotmat_to_quat(R)
    np.testing.assert_allclose(rotations_np.quat_to_rotmat(q), R, atol=1e-13)
    assert (q[:, 0] >= 0).all()
    np.testing.assert_allclose(rotations_np.rotmat_to_quat(np.eye(3)), [1, 0, 0, 0])


def test_parse_floats_reads_what_split_reads():
    for text in ("", " \n\t ", "1 2\n3\t4 \r\n", " -0 .5 5. +3 nan inf 1e-3"):
        np.testing.assert_array_equal(_parse_floats(text), np.array(text.split(), dtype=float))
    with pytest.raises(ValueError):
        _parse_floats("1 2 x")
