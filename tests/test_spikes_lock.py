"""A one-frame spike in a leg joint of a clean take: filled, and the foot lock does not pull
the cleaned leg to where the spike put the foot (it read the input's feet as its reference)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.geometry.rotations_np import rotvec_to_rotmat
from mdvae_cli.infer.denoise_settings import DenoiseSettings, denoise
from mdvae_cli.infer.feet import FOOT_CHAIN, without_spikes
from mdvae_cli.infer.noise_blend import source_spikes

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between rotations given as axis-angles (..., 3) -> (...) degrees."""
    rel = np.swapaxes(rotvec_to_rotmat(a), -1, -2) @ rotvec_to_rotmat(b)
    cos = np.clip((np.trace(rel, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0)
    return np.degrees(np.arccos(cos))


def static_take_with_spike(joint: int, T: int = 90, at: int = 45):
    walk = load_motion(EXAMPLES / "walk.npz")
    still = walk.with_body(
        root_orient=np.repeat(walk.root_orient[:1], T, 0),
        pose_body=np.repeat(walk.pose_body[:1], T, 0),
        trans=np.repeat(walk.trans[:1], T, 0),
        pose_extra=np.repeat(walk.pose_extra[:1], T, 0),
    )
    spiky = still.with_body()
    spiky.pose_body = still.pose_body.copy()
    spiky.pose_body[at, joint - 1] += np.array([1.05, 0.0, 0.0])  # about 60 degrees
    return still, spiky


@pytest.mark.parametrize("joint", [2, 5, 8])  # right hip, knee, ankle
def test_a_leg_spike_in_a_still_take_comes_back_as_the_pose(joint):
    still, spiky = static_take_with_spike(joint)
    spikes = source_spikes(spiky, FOOT_CHAIN)
    assert np.argwhere(spikes).tolist() == [[45, joint]]
    assert not observed_at(without_spikes(spiky), 45, joint)
    (out,) = denoise([spiky], DenoiseSettings())  # the default: blend and foot lock
    err = angle_deg(out.joint_rotations, still.joint_rotations)  # (T, 22)
    assert err.max() < 1.0, np.unravel_index(err.argmax(), err.shape)


def observed_at(motion, t: int, j: int) -> bool:
    return motion.joint_mask is None or bool(motion.joint_mask[t, j])
