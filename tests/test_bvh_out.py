"""BVH in, BVH out: takes written back on their own skeleton, export-bvh, other rigs' names."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.cli.main import cli
from mdvae_cli.errors import InputError
from mdvae_cli.formats.bvh import load_bvh
from mdvae_cli.formats.bvh_rotations import (
    ChannelRotations,
    channel_rotations,
    let_go_of_rotations,
)
from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.geometry.euler import euler_to_rotmat, rotmat_to_euler
from mdvae_cli.retarget.fit_shape import BodyJoints
from mdvae_cli.retarget.joint_map import build_joint_map, normalise_name
from mdvae_cli.retarget.retarget import load_source
from mdvae_cli.retarget.take import read_take
from mdvae_cli.retarget.way_back import file_pose, smpl_globals, write_back_data

REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "data"

# name, parent, offset (cm, z up, facing -y), rotation channel order
_RIG = [
    ("Root", None, (0, 0, 0), "zxy"),
    ("Spine_A", "Root", (0, 0, 10), "xyz"),
    ("Spine_B", "Spine_A", (0, 0, 15), "yzx"),
    ("Spine_C", "Spine_B", (0, 0, 15), "zxy"),
    ("Neck", "Spine_C", (0, 0, 12), "zxy"),
    ("Head", "Neck", (0, 0, 10), "zyx"),
    ("Shoulder_L", "Spine_C", (4, 0, 10), "xzy"),
    ("UpperArm_L", "Shoulder_L", (14, 0, 0), "zxy"),
    ("LowerArm_L", "UpperArm_L", (28, 0, 0), "xyz"),
    ("Hand_L", "LowerArm_L", (25, 0, 0), "zxy"),
    ("Index1_L", "Hand_L", (9, 0, 0), "zxy"),
    ("Index2_L", "Index1_L", (4, 0, 0), "zxy"),
    ("Shoulder_R", "Spine_C", (-4, 0, 10), "xzy"),
    ("UpperArm_R", "Shoulder_R", (-14, 0, 0), "zxy"),
    ("LowerArm_R", "UpperArm_R", (-28, 0, 0), "xyz"),
    ("Hand_R", "LowerArm_R", (-25, 0, 0), "zxy"),
    ("Index1_R", "Hand_R", (-9, 0, 0), "zxy"),
    ("Thigh_L", "Root", (9, 0, -6), "zxy"),
    ("Calf_L", "Thigh_L", (0, 0, -42), "yxz"),
    ("Foot_L", "Calf_L", (0, 0, -42), "zxy"),
    ("Toe_L", "Foot_L", (0, -14, -6), "zxy"),
    ("Thigh_R", "Root", (-9, 0, -6), "zxy"),
    ("Calf_R", "Thigh_R", (0, 0, -42), "yxz"),
    ("Foot_R", "Calf_R", (0, 0, -42), "zxy"),
    ("Toe_R", "Foot_R", (0, -14, -6), "zxy"),
]


def _angles(T: int, fps: float, seed: int) -> np.ndarray:
    """(T, J, 3) degrees: a walk-like swing of legs and arms, small sway elsewhere."""
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None] / fps
    out = 3.0 * np.sin(2 * np.pi * (0.5 * t[:, :, None] + rng.uniform(0, 1, (1, len(_RIG), 3))))
    swing = 25.0 * np.sin(2 * np.pi * 1.0 * t[:, 0])
    names = [r[0] for r in _RIG]
    for side, sign in (("L", 1), ("R", -1)):
        out[:, names.index(f"Thigh_{side}"), 1] = sign * swing  # about x (z, x, y order)
        out[:, names.index(f"Calf_{side}"), 1] = 20 + 15 * np.sin(2 * np.pi * t[:, 0])
        out[:, names.index(f"UpperArm_{side}"), 0] = sign * 70.0  # arms down from the T-pose
    return out


def write_rig(path: Path, T: int = 90, fps: float = 30.0, seed: int = 0, names=None) -> Path:
    """A z-up, cm, mixed-order BVH with fingers and three spine joints, walking along -y."""
    names = names or [r[0] for r in _RIG]
    lines = ["HIERARCHY"]
    kids = {r[0]: [k for k in _RIG if k[1] == r[0]] for r in _RIG}

    def block(r, depth):
        pad = "  " * depth
        i = _RIG.index(r)
        lines.append(f"{pad}{'ROOT' if r[1] is None else 'JOINT'} {names[i]}")
        lines.append(pad + "{")
        lines.append(f"{pad}  OFFSET {' '.join(str(v) for v in r[2])}")
        pos = "Xposition Yposition Zposition " if r[1] is None else ""
        rot = " ".join(f"{a.upper()}rotation" for a in r[3])
        lines.append(f"{pad}  CHANNELS {6 if r[1] is None else 3} {pos}{rot}")
        for k in kids[r[0]]:
            block(k, depth + 1)
        if not kids[r[0]]:
            lines.extend([f"{pad}  End Site", pad + "  {", f"{pad}    OFFSET 0 0 3", pad + "  }"])
        lines.append(pad + "}")

    block(_RIG[0], 0)
    ang = _angles(T, fps, seed)
    t = np.arange(T) / fps
    root = np.stack([np.zeros(T), -110.0 * t, 94.0 + 1.5 * np.sin(4 * np.pi * t)], axis=1)
    order = []

    def walk(r):
        order.append(_RIG.index(r))
        for k in kids[r[0]]:
            walk(k)

    walk(_RIG[0])
    rows = [np.concatenate([root[f]] + [ang[f, j] for j in order]) for f in range(T)]
    text = "\n".join(lines) + f"\nMOTION\nFrames: {T}\nFrame Time: {1 / fps:.6f}\n"
    text += "\n".join(" ".join(f"{v:.4f}" for v in row) for row in rows) + "\n"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def joints():
    return BodyJoints(load_body_model(None))


def test_euler_angles_round_trip_every_order():
    rng = np.random.default_rng(1)
    for axes in map("".join, itertools.permutations("xyz")):
        ang = rng.uniform(-3, 3, (200, 3))
        ang[:, 1] = rng.uniform(-1.5, 1.5, 200)
        R = euler_to_rotmat(ang, axes)
        back = rotmat_to_euler(R, axes, near=ang + 0.05)
        np.testing.assert_allclose(back, ang, atol=1e-9)
        # far from the file's angles: another solution, same rotation
        other = rotmat_to_euler(R, axes, near=ang + np.pi)
        np.testing.assert_allclose(euler_to_rotmat(other, axes), R, atol=1e-9)


def test_side_and_prefix_names():
    assert normalise_name("f_avg_L_Hip") == "lefthip"
    assert normalise_name("UpLeg_L") == "leftupleg"
    assert normalise_name("mixamorig:RightForeArm") == "rightforearm"
    assert normalise_name("Bip01 R Thigh") == "rightthigh"
    assert normalise_name("lfemur") == "lfemur"  # ASF names keep their own spelling


def test_generated_rig_maps_and_stands_up(tmp_path, joints):
    src = load_source(write_rig(tmp_path / "take.bvh"))
    assert src.info["unit"] == "cm"
    jmap = build_joint_map(src)
    named = {k: src.names[v] for k, v in jmap.anchor.items()}
    assert named["pelvis"] == "Root" and named["left_hip"] == "Thigh_L"
    assert named["left_wrist"] == "Hand_L" and named["right_foot"] == "Toe_R"
    take = read_take(tmp_path / "take.bvh", joints, source=src)
    P = smpl_globals(take.motion, joints)[1]
    # z up: the head is above the pelvis; the body's left (+x in the file) stays +x-ish
    assert (P[:, 15, 2] - P[:, 0, 2]).min() > 0.4
    assert take.retarget.mean_error < 0.01


def test_way_back_without_change_gives_the_file_back(tmp_path, joints):
    path = write_rig(tmp_path / "take.bvh")
    take = read_take(path, joints)
    data = write_back_data(take.source, take.retarget, take.motion, take.motion, joints)
    np.testing.assert_allclose(data, take.source.layout.data, atol=1e-6)


def test_way_back_in_chunks_is_the_way_back_in_one_piece(tmp_path, joints):
    """Frames are carried back a chunk at a time (flat memory on long takes): the same file
    as in one piece, whatever the chunk."""
    path = write_rig(tmp_path / "take.bvh")
    take = read_take(path, joints)
    cleaned = take.motion.with_body(pose_body=take.motion.pose_body * 0.9)
    args = (take.source, take.retarget, take.motion, cleaned, joints)
    whole = write_back_data(*args, chunk=10_000)
    for chunk in (1, 7, 64):
        np.testing.assert_allclose(write_back_data(*args, chunk=chunk), whole, atol=1e-9)


def test_the_way_back_makes_the_file_pose_from_the_channels_as_from_the_readers_rotations(
    tmp_path, joints
):
    """The way back's file pose made from the channels again is the one from the rotations
    the reader gives the take."""
    path = write_rig(tmp_path / "take.bvh")
    src = load_source(path)
    layout = src.layout
    take = read_take(path, joints, source=src)
    data = layout.data[layout.rows]
    again = file_pose(take.source, layout, data)
    given = file_pose(take.source, layout, data, np.asarray(src.rotations))
    for a, b in zip(again, given, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-12)


@pytest.mark.parametrize("drop_first", [False, True])
def test_a_take_makes_its_rotations_from_its_channels_when_asked(tmp_path, joints, drop_first):
    """The reader holds no array of a take's local rotations (373 MB on a 30-minute 120 Hz
    take) and makes them from the channels of the frames asked for: the same values bit for
    bit as from all the rows at once, however they are indexed (a dropped first row
    included); a retarget keeps them so."""
    path = write_rig(tmp_path / "take.bvh", T=40)
    src = load_bvh(path, drop_first=drop_first)
    lazy = src.rotations
    assert isinstance(lazy, ChannelRotations) and let_go_of_rotations(src) is src
    layout = src.layout
    held = channel_rotations(layout, layout.data[layout.rows], src.num_joints)
    assert lazy.shape == held.shape and len(lazy) == len(held) == 40 - drop_first
    np.testing.assert_array_equal(np.asarray(lazy), held)
    for key in (slice(5, 17), 3, -1, np.array([0, 4, 2]), (slice(None), 1),
                (slice(2, 9), 3, 0)):  # fmt: skip
        np.testing.assert_array_equal(lazy[key], held[key])
    take = read_take(path, joints)
    assert isinstance(take.source.rotations, ChannelRotations)
    assert take.source.num_frames == take.motion.num_frames == 40


def _change(take, data):
    layout = take.source.layout
    L0, _, _, P0 = file_pose(take.source, layout, layout.data)
    L1, _, _, P1 = file_pose(take.source, layout, data)
    R = np.swapaxes(L0, -1, -2) @ L1
    deg = np.degrees(np.arccos(np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1, 1)))
    return float(np.median(deg)), float(np.linalg.norm(P1 - P0, axis=-1).mean() * 10)  # cm->mm


def test_denoise_bvh_writes_the_take_back_on_its_own_skeleton(tmp_path, joints):
    path = write_rig(tmp_path / "take.bvh")
    out = tmp_path / "clean.bvh"
    r = CliRunner().invoke(cli, ["denoise", str(path), "-o", str(out)])
    assert r.exit_code == 0, r.output
    before, after = path.read_text(), out.read_text()
    assert after.split("MOTION")[0] == before.split("MOTION")[0]  # hierarchy verbatim
    assert "Frames: 90" in after and "Frame Time: 0.033333" in after
    src, clean = load_bvh(path), load_bvh(out)
    fingers = [src.index(n) for n in ("Index1_L", "Index2_L", "Index1_R")]
    np.testing.assert_allclose(clean.rotations[:, fingers], src.rotations[:, fingers], atol=1e-5)
    take = read_take(path, joints)
    rot_deg, pos_mm = _change(take, clean.layout.data)
    # the way back alone changes nothing (test above); what remains is the denoiser's own
    # change to this synthetic sine-wave walk (real takes: benchmarks/bvh_roundtrip.py)
    assert rot_deg <= 1.0 and pos_mm <= 12.0, (rot_deg, pos_mm)


def test_noisy_bvh_comes_back_closer(tmp_path, joints):
    path = write_rig(tmp_path / "take.bvh")
    take = read_take(path, joints)
    src = take.source
    rng = np.random.default_rng(3)
    noisy = src.layout.data.copy()
    rot_cols = [c for c, (j, k, _) in enumerate(src.layout.channels) if k == "r"]
    noisy[:, rot_cols] += rng.normal(0, 4.0, (noisy.shape[0], len(rot_cols)))
    head = path.read_text().split("MOTION")[0]
    noisy_path = tmp_path / "noisy.bvh"
    rows = "\n".join(" ".join(f"{v:.5f}" for v in row) for row in noisy)
    noisy_path.write_text(head + "MOTION\nFrames: 90\nFrame Time: 0.033333\n" + rows)
    out = tmp_path / "out.bvh"
    r = CliRunner().invoke(cli, ["denoise", str(noisy_path), "-o", str(out)])
    assert r.exit_code == 0, r.output
    _, P_clean = file_pose(src, src.layout, src.layout.data)[2:]
    body_joints = [src.index(n) for n in ("Thigh_L", "Calf_L", "Foot_L", "UpperArm_R",
                                          "LowerArm_R", "Hand_R", "Head")]  # fmt: skip
    err = {}
    for name, data in (("noisy", noisy), ("out", load_bvh(out).layout.data)):
        P = file_pose(src, src.layout, data)[3]
        err[name] = np.linalg.norm(P - P_clean, axis=-1)[:, body_joints].mean()
    assert err["out"] < 0.8 * err["noisy"], err


def test_unmapped_rig_names_the_joints_and_takes_a_joint_map(tmp_path):
    names = [r[0] for r in _RIG]
    odd = [n.replace("Thigh", "Femur_bone").replace("Calf", "Tib") for n in names]
    path = write_rig(tmp_path / "odd.bvh", names=odd)
    r = CliRunner().invoke(cli, ["denoise", str(path), "-o", str(tmp_path / "x.bvh")])
    assert r.exit_code == 1
    line = [ln for ln in r.output.splitlines() if "error" in ln]
    assert len(line) == 1 and "left_hip" in line[0] and "left_knee" in line[0]
    assert "--joint-map" in line[0]
    mapping = {"left_hip": "Femur_bone_L", "right_hip": "Femur_bone_R", "left_knee": "Tib_L",
               "right_knee": "Tib_R"}  # fmt: skip
    (tmp_path / "map.json").write_text(json.dumps(mapping))
    r = CliRunner().invoke(cli, ["denoise", str(path), "-o", str(tmp_path / "x.bvh"),
                                 "--joint-map", str(tmp_path / "map.json")])  # fmt: skip
    assert r.exit_code == 0, r.output
    assert load_bvh(tmp_path / "x.bvh").names == load_bvh(path).names
    with pytest.raises(InputError, match="no joint 'Nope'"):
        build_joint_map(load_source(path, joint_map={"left_hip": "Nope"}))


def mixed_folder(folder: Path, make_motion_file, T: int) -> Path:
    """A folder holding a BVH take (take.bvh) and an npz motion (walk.npz) of T frames."""
    folder.mkdir()
    write_rig(folder / "take.bvh", T=T)
    make_motion_file(folder / "walk.npz", T=T)
    return folder


def test_mixed_folder_each_in_its_own_form(tmp_path, make_motion_file):
    folder = mixed_folder(tmp_path / "in", make_motion_file, 40)
    r = CliRunner().invoke(cli, ["denoise", str(folder), "-o", str(tmp_path / "out")])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "out" / "take.bvh").is_file() and (tmp_path / "out" / "walk.npz").is_file()
    npz_in = str(folder / "walk.npz")
    r = CliRunner().invoke(cli, ["denoise", npz_in, "-o", str(tmp_path / "w.bvh")])
    assert r.exit_code == 1 and "export-bvh" in r.output


def test_export_bvh_imports_back_within_a_millimetre(tmp_path, joints):
    npz = REPO / "examples" / "walk.npz"
    bvh = tmp_path / "walk.bvh"
    r = CliRunner().invoke(cli, ["export-bvh", str(npz), "-o", str(bvh)])
    assert r.exit_code == 0, r.output
    text = bvh.read_text()
    assert "ROOT pelvis" in text and "JOINT left_knee" in text and "End Site" in text
    src = load_bvh(bvh)
    assert src.info["unit"] == "cm"
    back = tmp_path / "back.npz"
    r = CliRunner().invoke(cli, ["import", str(bvh), "-o", str(back), "--fps", "0",
                                 "--floor", "none"])  # fmt: skip
    assert r.exit_code == 0, r.output
    a, b = load_motion(npz), load_motion(back)
    err = np.linalg.norm(smpl_globals(a, joints)[1] - smpl_globals(b, joints)[1], axis=-1)
    assert err.mean() < 0.001, err.mean()


_REAL = sorted((REAL / "real" / "bvh").glob("*/*.bvh.gz")) + sorted(
    (REAL / "animated_drawings").glob("*.bvh.gz")
)


@pytest.mark.skipif(not _REAL, reason="no real BVH files in ../shared/data")
@pytest.mark.parametrize("path", _REAL, ids=lambda p: p.name.removesuffix(".bvh.gz"))
def test_real_rigs_import_upright_and_write_back_exactly(path, joints):
    src = load_source(path, max_frames=40)
    take = read_take(path, joints, source=src)
    P = smpl_globals(take.motion, joints)[1]
    up = P[:, 15] - P[:, 0]
    assert (up[:, 2] / np.linalg.norm(up, axis=1)).mean() > 0.6  # upright (lying: 0; a lean: 0.8)
    left = P[:, 1] - P[:, 2]  # left hip minus right hip, facing: forward = up x left
    knee = (P[:, 4] + P[:, 5]) / 2 - (P[:, 1] + P[:, 2]) / 2
    assert np.linalg.norm(left, axis=1).mean() > 0.05 and np.isfinite(knee).all()
    data = write_back_data(take.source, take.retarget, take.motion, take.motion, joints)
    rows = take.source.layout.rows
    np.testing.assert_allclose(data[rows], take.source.layout.data[rows], atol=1e-4)


def test_add_noise_gives_a_take_back_noisy_on_its_own_skeleton(tmp_path, joints):
    path = write_rig(tmp_path / "take.bvh")
    out = tmp_path / "noisy.bvh"
    r = CliRunner().invoke(cli, ["add-noise", "--sigma", "0.1", str(path), "-o", str(out)])
    assert r.exit_code == 0, r.output
    before, after = path.read_text(), out.read_text()
    assert after.split("MOTION")[0] == before.split("MOTION")[0]  # hierarchy verbatim
    src, noisy = load_bvh(path), load_bvh(out)
    assert noisy.num_frames == src.num_frames == 90
    # the root's channels and the joints the body does not drive keep their values (the
    # root's position within 10 micrometres: the way back reads the retarget's miss of the
    # pelvis along its course where the body was turned, and this clean take's miss wavers
    # by a few micrometres about it)
    root_cols = [c for c, (j, _, _) in enumerate(src.layout.channels) if j == 0]
    np.testing.assert_allclose(noisy.layout.data[:, root_cols], src.layout.data[:, root_cols],
                               atol=1e-3)  # fmt: skip
    fingers = [src.index(n) for n in ("Index1_L", "Index2_L", "Index1_R")]
    np.testing.assert_allclose(noisy.rotations[:, fingers], src.rotations[:, fingers], atol=1e-5)
    # the body's joints carry noise of about 0.1 rad (5.7 degrees an axis): 0.17 rad a joint
    rot_deg, pos_mm = _change(read_take(path, joints), noisy.layout.data)
    print(f"median joint change {rot_deg:.2f} deg, mean position change {pos_mm:.1f} mm")
    assert 3.0 < rot_deg < 15.0 and pos_mm > 20.0, (rot_deg, pos_mm)


def test_add_noise_with_holes_writes_takes_as_npz(tmp_path, make_motion_file):
    folder = mixed_folder(tmp_path / "in", make_motion_file, 60)
    r = CliRunner().invoke(cli, ["add-noise", str(folder), "-o", str(tmp_path / "out")])
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["take.bvh", "walk.npz"]
    holes = ["--drop-frames", "10"]
    r = CliRunner().invoke(cli, ["add-noise", str(folder), "-o", str(tmp_path / "h"), *holes])
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in (tmp_path / "h").iterdir()) == ["take.npz", "walk.npz"]
    assert np.isnan(np.load(tmp_path / "h" / "take.npz")["poses"]).any()
    # a take named as the output cannot hold them: refused in one line, nothing written
    named = tmp_path / "x.bvh"
    r = CliRunner().invoke(cli, ["add-noise", str(folder / "take.bvh"), "-o", str(named), *holes])
    errors = [ln for ln in r.output.splitlines() if ln.startswith("error")]
    assert r.exit_code != 0 and len(errors) == 1 and ".npz" in errors[0], r.output
    assert not named.exists()
    r = CliRunner().invoke(cli, ["add-noise", str(folder / "walk.npz"), "-o", str(named)])
    assert r.exit_code != 0 and "export-bvh" in r.output and not named.exists()


def test_driven_joints_read_their_offset_smoothed_where_the_cleaning_turned_them():
    from mdvae_cli.geometry.rotations_np import rotmat_to_rotvec, rotvec_to_rotmat
    from mdvae_cli.retarget.steady import STEADY_FROM_DEG, turn_reading
    from mdvae_cli.retarget.way_back import SmplChange, driven_rotations

    rng = np.random.default_rng(5)
    T, fps = 240, 120.0
    t = np.arange(T)[:, None] / fps
    before = rotvec_to_rotmat(np.concatenate([0.5 * np.sin(t), 0.3 * np.cos(2 * t), t], 1))
    # the source joint's offset from its driver: a steady one, and per-frame jitter that the
    # retarget's frame-by-frame fit leaves in it on a noisy take
    jitter = rotvec_to_rotmat(rng.normal(0, 0.02, (T, 3)))
    G = (before @ rotvec_to_rotmat(np.array([0.2, -0.1, 0.3])) @ jitter)[:, None]
    drive = np.array([0])

    def run(turn_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        turn = rotvec_to_rotmat(np.tile([0.0, 0.0, np.radians(turn_deg)], (T, 1)))
        after = turn @ before
        turns = turn[:, None]
        change = SmplChange(turns, before[:, None], after[:, None], np.zeros((T, 3)),
                            *turn_reading(turns, fps))  # fmt: skip
        return driven_rotations(change, G, drive, fps)[:, 0], after, turn

    # left alone (a turn under the floor): the turn alone, exactly
    out, _, turn = run(0.5 * STEADY_FROM_DEG)
    np.testing.assert_array_equal(out, turn @ G[:, 0])
    # turned: the offset from the driver comes out smooth, and still near the one it had
    out, after, _ = run(5.0)
    offset = rotmat_to_rotvec(np.swapaxes(after, -1, -2) @ out)
    given = rotmat_to_rotvec(np.swapaxes(before, -1, -2) @ G[:, 0])
    rough = lambda r: np.abs(np.diff(r, 2, axis=0)).mean()  # noqa: E731
    assert rough(offset) < 0.3 * rough(given), (rough(offset), rough(given))
    assert np.abs(offset - [0.2, -0.1, 0.3]).mean() < np.abs(given - [0.2, -0.1, 0.3]).mean()


def test_a_windows_bvh_comes_back_with_its_crlf_line_ends(tmp_path):
    """A BVH whose lines end in CR LF is written back with CR LF on every line (not its
    header's CR LF and LF under MOTION), the values as from the same file with LF."""
    from mdvae_cli.formats.registry import read, write

    lf = write_rig(tmp_path / "take.bvh", T=40)
    crlf = tmp_path / "take_crlf.bvh"
    crlf.write_bytes(lf.read_bytes().replace(b"\n", b"\r\n"))
    for src in (lf, crlf):
        loaded = read(src)
        m = loaded.single()
        turned = m.with_body(m.root_orient, m.pose_body * 0.9, m.trans)
        write(turned, src.with_name(src.stem + "_out.bvh"), take=loaded.take)
    out_lf, out_crlf = (p.with_name(p.stem + "_out.bvh").read_bytes() for p in (lf, crlf))
    assert out_crlf.count(b"\n") == out_crlf.count(b"\r\n") > 40
    assert b"\r" not in out_lf
    assert out_crlf.replace(b"\r\n", b"\n") == out_lf


def test_a_gz_output_keeps_its_own_name_inside(tmp_path):
    """gzip keeps a name in its header (``gunzip -N`` restores it): the output's, not the
    hidden temporary file's that the atomic write made first."""
    import gzip

    from mdvae_cli.formats.bvh_write import write_text

    out = tmp_path / "clean.bvh.gz"
    write_text(out, ["HIERARCHY\n", "MOTION\n"])
    raw = out.read_bytes()
    assert raw[3] & 0x08  # FNAME: a zero-terminated name after the 10-byte header
    assert raw[10 : raw.index(b"\0", 10)] == b"clean.bvh"
    assert gzip.decompress(raw) == b"HIERARCHY\nMOTION\n"
    assert [p.name for p in tmp_path.iterdir()] == ["clean.bvh.gz"]
