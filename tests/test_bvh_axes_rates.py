"""BVH takes keep their own up and their own rate: a take done lying or upside down imports as
it lies (``retarget/upright.py``), a y-up rest pose in a z-up scene still stands; a Frame Time
that is not a rounded 1/n keeps its rate (59.94), and ``--fps`` is the rate written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.formats.bvh import load_bvh, rate_of_frame_time
from mdvae_cli.formats.bvh_rotations import ChannelRotations, TurnedRotations
from mdvae_cli.formats.bvh_write import frame_time_text
from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.geometry.rotations_np import rotmat_to_rotvec, rotvec_to_rotmat
from mdvae_cli.motion.motion import slice_frames
from mdvae_cli.retarget.fit_shape import BodyJoints
from mdvae_cli.retarget.joint_map import build_joint_map
from mdvae_cli.retarget.retarget import RetargetSettings, import_motion, load_source
from mdvae_cli.retarget.smpl_bvh import smpl_bvh
from mdvae_cli.retarget.upright import rerest, to_smpl_axes
from mdvae_cli.retarget.way_back import smpl_globals
from tests.conftest import run_cli as run
from tests.test_bvh_out import write_rig

WALK = Path(__file__).resolve().parents[1] / "examples" / "walk.npz"


@pytest.fixture(scope="module")
def joints():
    return BodyJoints(load_body_model(None))


@pytest.mark.parametrize(("text", "fps"), [("0.0333333", 30.0), ("0.033333", 30.0),
    ("0.008333", 120.0), ("0.016666", 60.0), ("8.333333e-03", 120.0), ("0.04", 25.0),
    ("0.01668335", 59.94), ("0.00834168", 119.88), ("0.03", 33.33)])  # fmt: skip
def test_a_frame_time_is_snapped_only_when_it_prints_a_round_rate(text, fps):
    assert rate_of_frame_time(text) == fps


def test_a_new_rate_is_written_as_the_file_writes_its_frame_time():
    assert frame_time_text(60, "0.033333") == "0.016667"
    assert frame_time_text(60, "0.0333333") == "0.0166667"
    assert frame_time_text(120, "0.04") == "0.0083333"  # at least 5 significant digits
    assert frame_time_text(60, "3.333333e-02") == "1.666667e-02"


def test_a_59_94_take_imports_at_59_94(tmp_path):
    path = write_rig(tmp_path / "take.bvh", T=40)
    path.write_text(path.read_text().replace("Frame Time: 0.033333", "Frame Time: 0.01668335"))
    code, _, err = run("import", path, "-o", tmp_path / "x.npz", "--fps", 0)
    assert code == 0, err
    assert float(np.load(tmp_path / "x.npz")["mocap_framerate"]) == 59.94


@pytest.mark.parametrize("command", ["denoise", "add-noise"])
def test_fps_on_a_bvh_is_the_rate_written(tmp_path, command):
    path = write_rig(tmp_path / "take.bvh", T=40)
    out = tmp_path / "out.bvh"
    code, _, err = run(command, path, "-o", out, "--fps", 60)
    assert code == 0, err
    assert "Frame Time: 0.016667" in out.read_text()
    code, _, err = run(command, path, "-o", tmp_path / "same.bvh")
    assert code == 0 and "Frame Time: 0.033333" in (tmp_path / "same.bvh").read_text()


def turned(motion, joints, R: np.ndarray, pivot: np.ndarray):
    """The motion with its whole world turned by R (3, 3) about ``pivot`` (z-up metres; SMPL
    turns about its pelvis joint, at ``trans + X_pelvis``)."""
    root = rotmat_to_rotvec(R @ rotvec_to_rotmat(np.asarray(motion.root_orient)))
    X0 = smpl_globals(motion, joints)[1][:, 0] - np.asarray(motion.trans)
    trans = (np.asarray(motion.trans) + X0 - pivot) @ R.T + pivot - X0
    return motion.with_body(root_orient=root, trans=trans)


def round_trip(tmp_path, joints, motion):
    path = tmp_path / "take.bvh"
    path.write_text(smpl_bvh(motion, joints))
    src = load_source(path)
    rt = import_motion(src, joints, fps=None, settings=RetargetSettings(floor="none"))
    err = np.linalg.norm(smpl_globals(rt.motion, joints)[1] - smpl_globals(motion, joints)[1],
                         axis=-1)  # fmt: skip
    return rt, float(err.mean())


@pytest.mark.parametrize("degrees", [90.0, 180.0, -90.0])
def test_a_take_done_lying_or_upside_down_comes_back_as_it_lies(tmp_path, joints, degrees):
    walk = slice_frames(load_motion(WALK), 0, 60)
    a = np.radians(degrees)
    Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    lying = turned(walk, joints, Rx, np.asarray(walk.trans).mean(0))
    rt, err = round_trip(tmp_path, joints, lying)
    assert err < 0.002  # was 3.2 m (lying) and 6.4 m (upside down): turned upright
    notes = json.loads(str(rt.motion.extras["source"]))["notes"]
    assert any("kept as it lies" in n for n in notes)


def test_a_y_up_rest_pose_in_a_z_up_scene_still_stands(tmp_path, joints):
    """The body stands along the file's z on the floor through the origin (pybvh's
    bvh_test3): the world is turned, the rest pose by its own."""
    walk = slice_frames(load_motion(WALK), 0, 60)
    Rx = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # +90 about x: AMASS up -> -y
    rt, _ = round_trip(tmp_path, joints, turned(walk, joints, Rx, np.zeros(3)))
    P = smpl_globals(rt.motion, joints)[1]
    assert (P[:, 15, 2] - P[:, 0, 2]).min() > 0.4  # the head above the pelvis, z up
    notes = json.loads(str(rt.motion.extras["source"]))["notes"]
    assert not any("kept as it lies" in n for n in notes)


def test_turned_rotations_are_every_frames_turn_as_asked_for(tmp_path):
    """``left[j] R[t, j] right[j]^T`` of the frames asked for, however they are indexed,
    from an array or from a take's channels (made when asked, no array held)."""
    rng = np.random.default_rng(0)
    src = load_bvh(write_rig(tmp_path / "take.bvh", T=30))
    J = src.num_joints
    left, right = rotvec_to_rotmat(rng.normal(size=(2, J, 3)))
    assert isinstance(src.rotations, ChannelRotations)
    for base in (src.rotations, np.asarray(src.rotations)):
        lazy = TurnedRotations(base, left, right)
        whole = np.einsum("jab,tjbc,jdc->tjad", left, np.asarray(src.rotations), right)
        assert lazy.shape == whole.shape and len(lazy) == 30
        np.testing.assert_allclose(np.asarray(lazy), whole, atol=1e-12)
        for key in (slice(5, 17), 3, -1, np.array([0, 4, 2]), (slice(None), 1),
                    (slice(2, 9), 3, 0)):  # fmt: skip
            np.testing.assert_allclose(lazy[key], whole[key], atol=1e-12)


def test_a_take_turned_to_stand_holds_no_array_of_its_rotations(tmp_path, joints):
    """A z-up take (and a rest pose replaced by an upright frame) is turned as its frames are
    asked for: a long take's rotations are not held twice over."""
    walk = slice_frames(load_motion(WALK), 0, 60)
    Rx = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    path = tmp_path / "take.bvh"
    path.write_text(smpl_bvh(turned(walk, joints, Rx, np.zeros(3)), joints))
    src = load_source(path)
    turned_src, _ = to_smpl_axes(src, build_joint_map(src))
    assert isinstance(turned_src.rotations, TurnedRotations) and turned_src.num_frames == 60
    rested = rerest(src, 5)
    assert isinstance(rested.rotations, TurnedRotations)
    P0, P1 = src.forward_kinematics()[1], rested.forward_kinematics()[1]
    np.testing.assert_allclose(P1, P0, atol=1e-9)  # the same world positions, another rest
