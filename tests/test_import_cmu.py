"""Mocap import: BVH and ASF/AMC parsers, retargeting onto SMPL, ``mdvae import``, CMU corpus.

Real-data tests read small excerpts of the CMU files in ``../shared/data/cmu`` (or
``$MDVAE_CMU_DATA``) and are skipped where that folder is absent; excerpts are written only to
``tmp_path``. Synthetic tests pin the conventions (Euler orders, ASF axes, units, axes) with
hand-computed answers.
"""

from __future__ import annotations

import gzip
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from mdvae_cli.body.data import SMPL_PARENTS
from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.cli.main import cli
from mdvae_cli.errors import InputError
from mdvae_cli.formats.asf import load_asf, parse_asf
from mdvae_cli.formats.asfamc import load_amc
from mdvae_cli.formats.bvh import load_bvh
from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.formats.source import CMU_UNIT
from mdvae_cli.geometry.euler import euler_to_rotmat
from mdvae_cli.geometry.rotations import rotmat_to_rotvec, rotvec_to_rotmat
from mdvae_cli.motion import cmu, corpus_plan
from mdvae_cli.retarget.retarget import (
    Y_UP_TO_Z_UP,
    BodyJoints,
    RetargetSettings,
    import_motion,
    load_source,
    walking_speed,
)

REPO = Path(__file__).resolve().parents[1]
CMU = Path(os.environ.get("MDVAE_CMU_DATA", REPO.parent / "shared" / "data" / "cmu"))
needs_cmu = pytest.mark.skipif(not (CMU / "asfamc").is_dir(), reason=f"no CMU data at {CMU}")


@pytest.fixture(scope="module")
def body_data():
    return load_body_model(None)


@pytest.fixture(scope="module")
def body(body_data):
    torch.set_num_threads(1)
    return BodyJoints(body_data)


def run(*args) -> tuple[int, str, str]:
    result = CliRunner().invoke(cli, ["import", *[str(a) for a in args]])
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout, result.stderr


def rot(axis: str, deg: float) -> np.ndarray:
    return euler_to_rotmat(np.deg2rad([[deg]]), axis)[0]


# --- excerpts of the shared files (written to tmp_path only) ----------------------------------


def read(path: Path) -> str:
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as fh:
        return fh.read()


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    with (gzip.open if path.suffix == ".gz" else open)(path, "wt") as fh:
        fh.write(text)
    return path


def amc_excerpt(src: Path, frames: int) -> str:
    lines = read(src).splitlines()
    starts = [i for i, ln in enumerate(lines) if ln.strip().isdigit()]
    end = starts[frames] if frames < len(starts) else len(lines)
    return "\n".join(lines[:end]) + "\n"


def bvh_excerpt(src: Path, frames: int) -> str:
    head, motion = read(src).split("MOTION", 1)
    rows = motion.strip().splitlines()
    return head + f"MOTION\nFrames: {frames}\n{rows[1]}\n" + "\n".join(rows[2 : 2 + frames]) + "\n"


# --- parsers: conventions ---------------------------------------------------------------------


def test_euler_product_is_listed_order():
    a = np.deg2rad([[30.0, -50.0, 70.0]])
    expected = rot("z", 30) @ rot("x", -50) @ rot("y", 70)
    assert np.allclose(euler_to_rotmat(a, "zxy")[0], expected)
    # a right-handed rotation about z by 90 deg takes x to y
    assert np.allclose(rot("z", 90) @ [1, 0, 0], [0, 1, 0])


BVH_TWO_JOINTS = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Yrotation Xrotation Zrotation
  JOINT Arm
  {
    OFFSET 10 0 0
    CHANNELS 3 Xrotation Zrotation Yrotation
    End Site
    {
      OFFSET 0 5 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.0333333
1 2 3 90 0 0 0 90 0
1 2 3 0 0 0 0 0 0
"""


def test_bvh_channel_order_and_forward_kinematics(tmp_path):
    src = load_bvh(write(tmp_path / "arm.bvh", BVH_TWO_JOINTS), scale=0.01)
    assert src.names == ("Hips", "Arm", "Arm_end") and list(src.end_site) == [0, 0, 1]
    assert src.fps == 30.0 and src.num_frames == 2
    _, P = src.forward_kinematics()
    # Ry(90) takes x to -z; the arm's Rz(90) then turns the tip (0,5,0) to (-5,0,0) -> (0,0,5)
    assert np.allclose(P[0], [[0.01, 0.02, 0.03], [0.01, 0.02, -0.07], [0.01, 0.02, -0.02]])
    assert np.allclose(P[1, 2], [0.11, 0.07, 0.03])


def test_bvh_blank_frames_dropped_and_gzip(tmp_path):
    text = BVH_TWO_JOINTS.replace("Frames: 2", "Frames: 3").replace(
        "1 2 3 90", "0 0 0 0 0 0 0 0 0\n1 2 3 90"
    )
    src = load_bvh(write(tmp_path / "arm.bvh.gz", text), scale=1.0)
    assert src.num_frames == 2 and any("blank" in n for n in src.notes)
    assert np.allclose(src.root_positions[0], [1, 2, 3])


@pytest.mark.parametrize(
    "old, new, message",
    [
        ("HIERARCHY", "HIERARCHX", "not a BVH file"),
        ("MOTION", "MOTIONS", "no MOTION section"),
        ("Xrotation Zrotation", "Xrotation Wrotation", "unknown channel"),
        ("Frames: 2", "Frames: 3", "header says 3 frames"),
        ("1 2 3 0 0", "1 2 x 0 0", "non-numeric"),
        ("1 2 3 0 0 0 0 0 0", "1 2 3 0 0 0 0 0", "not a multiple"),
        ("Frame Time: 0.0333333", "Frame Time: 0", "Frame Time must be > 0"),
        ("Frame Time: 0.0333333\n", "", "lacks its 'Frame Time:' line (after 'Frames:')"),
        ("Frames: 2\n", "", "lacks its 'Frames:' line (before 'Frame Time:')"),
        ("Frames: 2\nFrame Time: 0.0333333\n", "", "lacks 'Frames:' and 'Frame Time:' lines"),
        ("1 2 3 0 0 0 0 0 0", "1 2 3 0 0 0 0 nan 0", "(first at frame 2, Arm Zrotation)"),
        ("    OFFSET 0 5 0\n", "", "expected 'OFFSET'"),
        ("1 2 3 0 0 0 0 0 0", "1 2 3 0 0 0 0 1e30 0", "joint Arm holds an angle of 1e+30 degrees"),
        ("1 2 3 0 0 0 0 0 0", "1 2 3 0 0 0 0 200000 0", "angles over 100000 degrees are refused"),
        ("1 2 3 0 0 0 0 0 0", "1e30 2 3 0 0 0 0 0 0", "the root position reaches 1e+29 m"),
        ("OFFSET 10 0 0", "OFFSET 1e30 0 0", "a bone reaches 1e+27 m"),
    ],
)
def test_bvh_malformed_files_give_one_line_errors(tmp_path, old, new, message):
    path = write(tmp_path / "bad.bvh", BVH_TWO_JOINTS.replace(old, new, 1))
    with pytest.raises(InputError) as err:
        load_bvh(path)
    text = str(err.value)
    assert message in text and str(path) in text and "\n" not in text


def test_bvh_frame_time_that_is_a_frame_rate_is_refused_unless_overridden(tmp_path):
    """A Frame Time of 120 (a rate written as a frame time) would be resampled to 30 Hz into
    hours of frames: refused as the .npz reader refuses such a rate; --source-fps overrides."""
    path = write(tmp_path / "arm.bvh", BVH_TWO_JOINTS.replace("0.0333333", "120"))
    with pytest.raises(InputError) as err:
        load_source(path)
    assert str(err.value) == (
        f"{path}: frame rate 0.00833333 Hz is implausible (1 to 10000 Hz); is its Frame Time a "
        "frame rate? (1/0.00833333 = 120 Hz); give the rate with --fps (mdvae import: "
        "--source-fps)"
    )
    assert load_source(path, fps=120.0).fps == 120.0
    code, out, err = run(path, "-o", tmp_path / "o.npz")
    assert code == 1 and "is its Frame Time a frame rate?" in err and not out
    assert not (tmp_path / "o.npz").exists()


ASF = """:version 1.10
:units
  length 1.0
  angle deg
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name b1
     direction 1 0 0
     length 10
     axis 0 0 90 XYZ
    dof rx
    limits (-180 180)
  end
  begin
     id 2
     name b2
     direction 0 1 0
     length 5
     axis 0 0 0 XYZ
  end
:hierarchy
  begin
    root b1
    b1 b2
  end
"""

AMC = """:FULLY-SPECIFIED
:DEGREES
1
root 0 0 0 0 0 0
b1 90
2
root 1 0 0 0 0 0
b1 0
"""


def test_asf_axis_frame_and_units(tmp_path):
    sk = write(tmp_path / "s.asf", ASF)
    src = load_amc(write(tmp_path / "s_01.amc", AMC), sk)
    assert src.names == ("root", "b1", "b2", "b2_end")
    _, P = src.forward_kinematics()
    u = 0.0254  # :units length 1.0 -> inches
    # b1's axis is Rz(90): its rx dof turns about world y, taking the bone (10,0,0) to (0,0,-10)
    assert np.allclose(P[0], np.array([[0, 0, 0], [0, 0, 0], [0, 0, -10], [0, 5, -10]]) * u)
    assert np.allclose(P[1, 3], np.array([11, 5, 0]) * u)


def test_amc_bones_in_any_order_and_errors(tmp_path):
    sk = load_asf(write(tmp_path / "s.asf", ASF))
    shuffled = AMC.replace("2\nroot 1 0 0 0 0 0\nb1 0", "2\nb1 0\nroot 1 0 0 0 0 0")
    a = load_amc(write(tmp_path / "a.amc", AMC), sk)
    b = load_amc(write(tmp_path / "b.amc", shuffled), sk)
    assert np.allclose(a.rotations, b.rotations) and np.allclose(a.root_positions, b.root_positions)
    for bad, message in [
        (AMC.replace("b1 90", "b9 90"), "lacks"),
        (AMC.replace("b1 90", "b1 90 4"), "has 2 values"),
        (ASF, "not an AMC motion"),
        (AMC.replace("b1 90", "b1 x"), "non-numeric"),
        (AMC.replace("b1 90", "b1 1e30"), "bone b1 holds an angle of 1e\\+30 degrees"),
        (AMC.replace("root 1 0 0 0 0 0", "root 1 0 0 1e30 0 0"), "the root holds an angle"),
        (AMC.replace("root 1 0 0", "root 1e30 0 0"), "the root position reaches"),
    ]:
        with pytest.raises(InputError, match=message):
            load_amc(write(tmp_path / "bad.amc", bad), sk)
    with pytest.raises(InputError, match="unknown bone"):
        parse_asf(ASF.replace("b1 b2\n", "b1 b3\n"))


def test_amc_cut_off_mid_frame_drops_that_frame_and_gaps_hold(tmp_path):
    sk = load_asf(write(tmp_path / "s.asf", ASF))
    cut = AMC + "3\nroot 2 0 0 0 0 0\n"  # the file ends before frame 3's b1
    m = load_amc(write(tmp_path / "cut.amc", cut), sk)
    full = load_amc(write(tmp_path / "a.amc", AMC), sk)
    assert m.rotations.shape == full.rotations.shape  # two frames, not three
    assert any("cut-off" in n for n in m.notes)
    gap = (
        AMC.replace("2\nroot 1 0 0 0 0 0\nb1 0", "2\nroot 1 0 0 0 0 0")
        + "3\nroot 2 0 0 0 0 0\nb1 0\n"
    )
    g = load_amc(write(tmp_path / "gap.amc", gap), sk)
    assert g.rotations.shape[0] == 3 and np.allclose(g.rotations[1], g.rotations[0])
    assert any("previous frame's held" in n for n in g.notes)


@needs_cmu
def test_cmu_units_and_cmuconvert_first_frame():
    sk = load_asf(CMU / "asfamc/07/07.asf")
    src = load_amc(CMU / "asfamc/07/07_01.amc.gz", sk, max_frames=30)
    assert src.num_frames == 30 and src.info["frames_in_file"] == 316
    tibia = src.index("ltibia")
    assert np.linalg.norm(src.offsets[tibia]) == pytest.approx(6.92462 * CMU_UNIT)
    assert np.allclose(src.root_positions[0], np.array([8.87208, 15.7511, -31.7081]) * CMU_UNIT)
    bvh = load_bvh(CMU / "bvh/07_02.bvh.gz", max_frames=20)
    assert bvh.info["cmuconvert"] and bvh.info["dropped_first_frame"] and bvh.fps == 120.0
    assert bvh.info["unit"] == "cmu" and bvh.num_frames == 20
    assert np.allclose(bvh.root_positions[0], np.array([7.4882, 15.9816, -35.4705]) * CMU_UNIT)


# --- retargeting ------------------------------------------------------------------------------

NAMES = ("Hips", "LeftUpLeg", "RightUpLeg", "Spine", "LeftLeg", "RightLeg", "Spine1", "LeftFoot",
         "RightFoot", "Spine2", "LeftToeBase", "RightToeBase", "Neck", "LeftShoulder",
         "RightShoulder", "Head", "LeftArm", "RightArm", "LeftForeArm", "RightForeArm",
         "LeftHand", "RightHand")  # fmt: skip


def zxy_angles(R: np.ndarray) -> np.ndarray:
    """Degrees (z, x, y) with R = Rz Rx Ry (independent of the parser's code)."""
    x = np.arcsin(np.clip(R[..., 2, 1], -1, 1))
    y = np.arctan2(-R[..., 2, 0], R[..., 2, 2])
    z = np.arctan2(-R[..., 0, 1], R[..., 1, 1])
    return np.degrees(np.stack([z, x, y], -1))


def test_synthetic_z_up_bvh_in_cm_round_trips(tmp_path, body, body_data):
    """An SMPL-shaped skeleton with Mixamo names, written z-up in centimetres: the importer
    must find the axes and units and give back the same joints and poses."""
    T, rng = 40, np.random.default_rng(1)
    t = np.arange(T)[:, None, None] / 30.0
    pose = 0.35 * np.sin(2 * np.pi * rng.uniform(0.2, 1.0, (1, 22, 3)) * t
                         + rng.uniform(0, 6, (1, 22, 3)))  # fmt: skip
    pose[:, 0] = [0.1, 0.4, 0.0] * np.sin(t[:, 0] * [1.0, 0.7, 1.0])
    trans = np.concatenate([0.5 * t[:, 0], 0.02 * np.sin(6 * t[:, 0]), 0.9 + 0 * t[:, 0]], 1)
    L = rotvec_to_rotmat(torch.as_tensor(pose)).numpy()  # (T, 22, 3, 3), y-up
    X = body.rest_joints(torch.zeros(body.num_betas, dtype=torch.float64)).numpy()[:22]
    Q = Y_UP_TO_Z_UP
    par = SMPL_PARENTS[:22]
    out, order = ["HIERARCHY"], []

    def emit(j: int, depth: int) -> None:
        order.append(j)  # channels are listed in hierarchy order
        pad = "  " * depth
        off = Q @ (X[j] - X[par[j]]) * 100 if j else np.zeros(3)
        out.append(f"{pad}{'ROOT' if j == 0 else 'JOINT'} {NAMES[j]}\n{pad}{{")
        out.append(f"{pad}  OFFSET {off[0]:.6f} {off[1]:.6f} {off[2]:.6f}")
        chans = "6 Xposition Yposition Zposition" if j == 0 else "3"
        out.append(f"{pad}  CHANNELS {chans} Zrotation Xrotation Yrotation")
        kids = [k for k in range(22) if par[k] == j]
        for k in kids:
            emit(k, depth + 1)
        if not kids:
            out.append(f"{pad}  End Site\n{pad}  {{\n{pad}    OFFSET 0 0 3\n{pad}  }}")
        out.append(f"{pad}}}")

    emit(0, 0)
    pelvis = (trans + X[0]) @ Q.T * 100  # the root joint's position, z-up cm
    angles = zxy_angles(Q @ L @ Q.T)  # local rotations in the z-up world
    rows = np.concatenate([pelvis, angles[:, order].reshape(T, -1)], 1)
    out += ["MOTION", f"Frames: {T}", "Frame Time: 0.0333333"]
    out += [" ".join(f"{v:.6f}" for v in row) for row in rows]
    src = load_bvh(write(tmp_path / "synthetic.bvh", "\n".join(out) + "\n"))
    assert src.info["unit"] == "cm"

    res = import_motion(src, body, fps=30.0, settings=RetargetSettings(floor="none"))
    assert res.mean_error < 1e-3
    assert np.abs(res.betas).max() < 0.05
    truth = BodyModel(body_data, dtype=torch.float64)(
        torch.as_tensor(pose[:, 0]), torch.as_tensor(pose[:, 1:]), torch.as_tensor(trans)
    ).joints.numpy() @ Q.T  # fmt: skip
    assert np.abs(res.joints - truth).max() < 2e-3
    got = rotvec_to_rotmat(torch.as_tensor(res.motion.pose_body)).numpy()
    diff = rotmat_to_rotvec(torch.as_tensor(np.swapaxes(got, -1, -2) @ L[:, 1:])).norm(dim=-1)
    assert float(diff.max()) < 0.02


def _excerpt(kind: str, name: str, frames: int | None = None):
    if kind == "bvh":
        return load_bvh(CMU / f"bvh/{name}.bvh.gz", max_frames=frames)
    subject = name.split("_")[0]
    asf = CMU / f"asfamc/{subject}/{subject}.asf"
    path = CMU / f"asfamc/{subject}/{name}.amc.gz"
    if not path.exists():
        asf = CMU / f"asfamc/{cmu.DONOR_SUBJECT}/{cmu.DONOR_SUBJECT}.asf"
        path = CMU / f"asfamc_noasf/{subject}/{name}.amc.gz"
    return load_amc(path, asf, fps=cmu.capture_fps(subject), max_frames=frames)


@needs_cmu
@pytest.mark.parametrize(
    "kind, name, frames, limit_mm",
    [("amc", "07_01", None, 8.0), ("bvh", "07_02", None, 8.0), ("amc", "01_01", 480, 10.0),
     ("bvh", "05_06", 480, 12.0), ("amc", "91_06", None, 14.0), ("amc", "79_08", 240, 12.0)],
)  # fmt: skip
def test_retarget_error_is_pinned(body, kind, name, frames, limit_mm):
    res = import_motion(_excerpt(kind, name, frames), body)
    assert 1000 * res.mean_error < limit_mm  # the issue asks for <= 20 mm
    assert 1000 * res.direct_error < limit_mm
    assert res.joint_error.max() < 0.05


@needs_cmu
@pytest.mark.parametrize("kind, name", [("amc", "07_01"), ("bvh", "07_02"), ("amc", "02_01")])
def test_walking_units_axes_and_frame_rate(tmp_path, body, body_data, kind, name):
    res = import_motion(_excerpt(kind, name), body)
    m = res.motion
    assert m.fps == 30.0 and m.gender == "neutral"
    assert abs(res.sole_height.mean()) < 0.03  # feet touch the floor (z = 0)
    assert abs(np.percentile(res.sole_height, 5)) < 0.01
    assert 1.0 < walking_speed(m.trans, m.fps) < 2.0
    head_up = res.joints[:, 15, 2] - res.joints[:, 0, 2]
    assert head_up.min() > 0.35  # z is up
    assert np.ptp(m.trans[:, 2]) < 0.12  # walking stays level
    # the saved file reproduces the joints through the body model (trans / root conventions)
    from mdvae_cli.formats.npz_io import save_motion

    save_motion(m, tmp_path / "m.npz")
    back = load_motion(tmp_path / "m.npz")
    assert back.poses.shape == (m.num_frames, 156)
    joints = BodyModel(body_data, dtype=torch.float64)(
        torch.as_tensor(back.root_orient), torch.as_tensor(back.pose_body),
        torch.as_tensor(back.trans), torch.as_tensor(back.betas),
    ).joints.numpy()  # fmt: skip
    assert np.abs(joints - res.joints).max() < 1e-3
    record = json.loads(str(back.extras["source"]))
    assert record["format"] == kind and record["joint_map"]["left_knee"] in ("ltibia", "LeftLeg")


@needs_cmu
def test_sixty_hz_subjects_are_slowed_down(body):
    assert cmu.capture_fps("79") == 60.0 and cmu.capture_fps("07") == 120.0
    path, asf = CMU / "asfamc/79/79_08.amc.gz", CMU / "asfamc/79/79.asf"
    as_written = import_motion(load_source(path, asf, fps=None), body)
    as_captured = import_motion(load_source(path, asf, fps=60.0), body)
    assert as_captured.motion.num_frames == 2 * as_written.motion.num_frames - 1
    assert as_captured.motion.duration == pytest.approx(2 * as_written.motion.duration)


# --- the command ------------------------------------------------------------------------------


@needs_cmu
def test_cli_amc_with_skeleton_input_json(tmp_path):
    code, out, err = run(CMU / "asfamc/07/07.asf", CMU / "asfamc/07/07_01.amc.gz",
                         "-o", tmp_path / "out", "--json")  # fmt: skip
    assert code == 0, err
    data = json.loads(out)
    assert data["succeeded"] == 1 and data["failed"] == 0
    row = data["files"][0]["result"]
    assert row["frames"] == 79 and row["retarget_error_mm"] < 8.0 and row["format"] == "amc"
    assert data["by_format"]["amc"]["files"] == 1 and data["retarget_error_mm"] < 8.0
    m = load_motion(tmp_path / "out/07_01.npz")
    assert m.fps == 30.0 and m.num_frames == 79


@needs_cmu
def test_cli_mirrors_folders_and_reports_failures(tmp_path, hash_tree):
    src = tmp_path / "in"
    write(src / "good.bvh.gz", bvh_excerpt(CMU / "bvh/07_02.bvh.gz", 60))
    write(src / "sub/bad.bvh", "HIERARCHY\nROOT Hips\n{\n")
    write(src / "sub/lonely_01.amc", "1\nroot 0 0 0 0 0 0\n")
    before = hash_tree(src)
    code, out, err = run(src, "-o", tmp_path / "out", "--fps", 0)
    assert code == 1
    assert (tmp_path / "out/good.npz").is_file()
    assert not (tmp_path / "out/sub").exists()
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert len(lines) == 2 and "bad.bvh" in err and "pass --asf" in err
    assert hash_tree(src) == before
    m = load_motion(tmp_path / "out/good.npz")
    assert m.fps == 120.0 and m.num_frames == 59  # frame 0 of a cmuconvert file is dropped


@needs_cmu
def test_cli_cmu_corpus_split_duplicates_donor_and_60hz(tmp_path):
    root = tmp_path / "cmu"
    for subject, trial in (("07", "01"), ("02", "01"), (cmu.DONOR_SUBJECT, "01"), ("79", "08")):
        folder = CMU / "asfamc" / subject
        write(root / f"asfamc/{subject}/{subject}.asf", read(folder / f"{subject}.asf"))
        text = amc_excerpt(folder / f"{subject}_{trial}.amc.gz", 40)
        write(root / f"asfamc/{subject}/{subject}_{trial}.amc.gz", text)
    write(root / "bvh/07_02.bvh.gz", bvh_excerpt(CMU / "bvh/07_02.bvh.gz", 40))
    dup = amc_excerpt(CMU / "asfamc_noasf/91/91_06.amc.gz", 40)
    write(root / "asfamc_noasf/91/91_06.amc.gz", dup)
    write(root / "asfamc_noasf/105/105_06.amc.gz", dup)
    write(root / "asfamc_noasf/02/02_99.amc.gz", amc_excerpt(CMU / "asfamc/02/02_02.amc.gz", 30))
    spec = write(tmp_path / "split.json", '{"val_subjects": ["02"], "test_subjects": ["07"]}')
    out = tmp_path / "corpus"
    code, stdout, err = run(root, "-o", out, "--cmu-corpus", "--split", spec, "--json")
    assert code == 0, err
    split = json.loads((out / "split.json").read_text())
    assert split["splits"] == {
        "train": ["asfamc/118/118_01.npz", "asfamc/79/79_08.npz", "asfamc_noasf/91/91_06.npz"],
        "val": ["asfamc/02/02_01.npz"],
        "test": ["asfamc/07/07_01.npz", "bvh/07_02.npz"],
        "unseen_val": [],
        "unseen_test": [],
    }
    assert split["donor_skeleton"] == ["asfamc_noasf/91/91_06.npz"]
    assert split["subjects"]["test"] == ["07"]
    for rel in [p for paths in split["splits"].values() for p in paths]:
        assert load_motion(out / rel).fps == 30.0
    summary = json.loads(stdout)
    assert summary == json.loads((out / "summary.json").read_text()) | {
        "elapsed_s": summary["elapsed_s"]
    }
    reasons = {s["file"]: s["reason"] for s in summary["skipped"]}
    assert reasons["asfamc_noasf/105/105_06.amc.gz"].startswith("duplicate of")
    assert "held-out" in reasons["asfamc_noasf/02/02_99.amc.gz"]
    rows = {f["file"]: f["result"] for f in summary["files"]}
    assert rows["asfamc/79/79_08.amc.gz"]["source_fps"] == 60.0
    assert rows["asfamc/79/79_08.amc.gz"]["frames"] == 20  # 40 frames at 60 Hz -> 30 Hz
    assert rows["asfamc_noasf/91/91_06.amc.gz"]["donor_skeleton"] is True
    assert summary["retarget_error_mm"] < 12.0 and summary["splits"]["val"]["files"] == 1


@needs_cmu
def test_cli_corpus_of_two_folders_holds_unseen_kinds_and_hdm05_out(tmp_path):
    """CMU (with a trial stored in two formats) and an HDM05-style folder in one build: unseen
    splits by subject and actor, HDM05 never in train, each folder mirrored under its name."""
    root = tmp_path / "cmu"
    for subject, trial in (("07", "01"), ("02", "01")):
        folder = CMU / "asfamc" / subject
        write(root / f"asfamc/{subject}/{subject}.asf", read(folder / f"{subject}.asf"))
        text = amc_excerpt(folder / f"{subject}_{trial}.amc.gz", 40)
        write(root / f"asfamc/{subject}/{subject}_{trial}.amc.gz", text)
    write(root / "bvh/07_02.bvh.gz", bvh_excerpt(CMU / "bvh/07_02.bvh.gz", 40))
    daz = bvh_excerpt(CMU / "bvh_daz/12_01.bvh.gz", 40)
    write(root / "bvh_daz/12_01.bvh.gz", daz)
    write(root / "bvh_daz/07_01.bvh.gz", daz)  # the same trial as asfamc/07/07_01
    hdm = tmp_path / "hdm05"
    for actor in ("bd", "dg"):  # CMU's skeleton and motion under HDM05's names
        write(hdm / f"{actor}/{actor}.asf", read(CMU / "asfamc/02/02.asf"))
        text = amc_excerpt(CMU / "asfamc/02/02_01.amc.gz", 40)
        write(hdm / f"{actor}/HDM_{actor}_kickLFront1Reps_001_120.amc.gz", text)
    spec = write(tmp_path / "split.json", json.dumps({
        "val_subjects": ["02"], "test_subjects": [], "unseen_val_subjects": ["hdm05:bd"],
        "unseen_test_subjects": ["12"]}))  # fmt: skip
    out = tmp_path / "corpus"
    code, stdout, err = run(root, hdm, "-o", out, "--corpus", "--split", spec, "--json")
    assert code == 0, err
    split = json.loads((out / "split.json").read_text())
    assert split["splits"] == {
        "train": ["cmu/asfamc/07/07_01.npz", "cmu/bvh/07_02.npz"],
        "val": ["cmu/asfamc/02/02_01.npz"],
        "test": [],
        "unseen_val": ["hdm05/bd/HDM_bd_kickLFront1Reps_001_120.npz"],
        "unseen_test": ["cmu/bvh_daz/12_01.npz"],
    }
    assert split["subjects"]["unseen_val"] == ["hdm05:bd"]
    assert split["unseen_test_subjects"] == ["12"]
    summary = json.loads(stdout)
    reasons = {s["file"]: s["reason"] for s in summary["skipped"]}
    assert reasons["cmu/bvh_daz/07_01.bvh.gz"] == (
        "trial 07_01 already taken from asfamc/07/07_01.amc.gz"
    )
    assert "test data only" in reasons["hdm05/dg/HDM_dg_kickLFront1Reps_001_120.amc.gz"]
    assert summary["splits"]["unseen_val"]["minutes"] == round(10 / 30 / 60, 2)
    rows = {f["file"]: f["result"] for f in summary["files"]}
    assert rows["cmu/bvh_daz/12_01.bvh.gz"]["retarget_error_mm"] < 15.0


def test_split_files_refuse_a_subject_in_two_splits(tmp_path):
    spec = {"val_subjects": ["06"], "test_subjects": ["02"], "unseen_test_subjects": ["06"]}
    path = write(tmp_path / "s.json", json.dumps(spec))
    with pytest.raises(InputError, match="subject 06 is in both val and unseen_test"):
        corpus_plan.load_split_spec(path)
    path.write_text(json.dumps({"val_subjects": [], "test_subjects": [], "unseen_val_subjects": 5}))
    with pytest.raises(InputError, match="unseen_val_subjects must be a list of strings"):
        corpus_plan.load_split_spec(path)


def test_cli_rejects_bad_options(tmp_path):
    code, out, err = run(tmp_path, "-o", tmp_path / "o", "--split", tmp_path / "s.json")
    assert code == 1 and "error: --split only goes with --corpus" in err
    for bad, why in ((-1, "-1 is not >= 0"), ("inf", "'inf' is not a finite number")):
        code, out, err = run(tmp_path, "-o", tmp_path / "o", "--fps", bad)
        assert code == 1 and f"Invalid value for '--fps': {why}" in out + err
    for option, rate in (("--fps", "0.5"), ("--source-fps", "20000")):
        code, out, err = run(tmp_path, "-o", tmp_path / "o", option, rate)
        assert code == 1 and f"error: {option}: frame rate {rate} Hz is implausible" in err
    assert not (tmp_path / "o").exists()


# --- the split --------------------------------------------------------------------------------


def test_split_file_matches_code_and_holds_out_walkers():
    spec = corpus_plan.load_split_spec(REPO / "weights_recipe/cmu_split.json")
    assert spec.val == cmu.VAL_SUBJECTS and spec.test == cmu.TEST_SUBJECTS
    assert not set(spec.val) & set(spec.test)
    if not (CMU / "manifest.csv").is_file():
        return
    own = {p.name for p in (CMU / "asfamc").iterdir()}
    manifest = cmu.read_manifest(CMU).items()
    walks = {t.split("_")[0] for t, d in manifest if "walk" in d or cmu.is_walking(t, d)}
    for subject in (*spec.val, *spec.test):
        assert subject in own and subject in walks


@pytest.mark.slow
@needs_cmu
def test_whole_corpus_meets_the_issue(tmp_path):
    """The full build (minutes): mean error <= 2 cm, walking feet on the floor, 1-2 m/s."""
    code, stdout, err = run(CMU, "-o", tmp_path / "c", "--cmu-corpus", "--json", "-j", 2)
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["retarget_error_mm"] <= 20.0
    assert all(row["retarget_error_mm"] <= 20.0 for row in summary["by_format"].values())
    walk = summary["walking"]
    assert walk["files"] >= 10
    for check in walk["trials"].values():
        assert abs(check["sole_height_mean_cm"]) <= 3.0
    assert 0.9 <= walk["speed_mps"]["min"] and walk["speed_mps"]["max"] <= 2.0
    assert math.isclose(sum(s["files"] for s in summary["splits"].values()), summary["succeeded"])


@needs_cmu
def test_cli_import_never_writes_a_non_finite_retarget(tmp_path, monkeypatch):
    # a retarget that comes out non-finite (e.g. a wildly wrong --scale) is one error line and
    # no file, not a NaN motion with exit 0
    import mdvae_cli.retarget.take as worker  # the take reader the registry calls

    real = worker.import_motion

    def broken(*args, **kwargs):
        result = real(*args, **kwargs)
        result.motion.trans[:] = np.nan
        return result

    monkeypatch.setattr(worker, "import_motion", broken)
    out = tmp_path / "walk.npz"
    code, _, err = run(CMU / "asfamc/07/07.asf", CMU / "asfamc/07/07_01.amc.gz", "-o", out)
    assert code == 1 and "non-finite values" in err and "Traceback" not in err
    assert not out.exists()


@needs_cmu
def test_cli_single_file_import_json_names_its_output(tmp_path):
    out = tmp_path / "walk.npz"
    code, stdout, err = run(CMU / "asfamc/07/07.asf", CMU / "asfamc/07/07_01.amc.gz", "-o", out,
                            "--json")  # fmt: skip
    assert code == 0, err
    assert json.loads(stdout)["files"][0]["result"]["output"] == out.as_posix()
