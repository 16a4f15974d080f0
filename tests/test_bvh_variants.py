"""BVH files as other exporters write them: names with spaces (3ds Max Biped), a root with
rotation channels alone, cp1252 / UTF-8 / BOM text, CR / LF / CR LF line endings, gzip
named in any case or not named at all. Each is read, and written back with its own header
byte for byte."""

from __future__ import annotations

import gzip

import numpy as np
import pytest

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.errors import InputError
from mdvae_cli.formats.bvh import load_bvh
from mdvae_cli.formats.source import read_text
from mdvae_cli.retarget.fit_shape import BodyJoints
from mdvae_cli.retarget.joint_map import build_joint_map
from mdvae_cli.retarget.take import read_take
from mdvae_cli.retarget.way_back import write_back_data
from tests.bad_input import files as F
from tests.conftest import run_cli

FRAMES = 24
#: the test rig's names as 3ds Max Biped writes them (spaces inside)
BIPED = {
    "Hips": "Bip01 Pelvis", "Spine": "Bip01 Spine", "Spine1": "Bip01 Spine1",
    "Neck": "Bip01 Neck", "Head": "Bip01 Head", "LeftShoulder": "Bip01 L Clavicle",
    "LeftArm": "Bip01 L UpperArm", "LeftForeArm": "Bip01 L Forearm", "LeftHand": "Bip01 L Hand",
    "LeftUpLeg": "Bip01 L Thigh", "LeftLeg": "Bip01 L Calf", "LeftFoot": "Bip01 L Foot",
    "LeftToeBase": "Bip01 L Toe0",
}  # fmt: skip
BIPED.update({k.replace("Left", "Right"): v.replace(" L ", " R ") for k, v in BIPED.items()
              if k.startswith("Left")})  # fmt: skip


def _rows(frames: int, channels: int) -> list[list[float]]:
    """Channel values of a small walk: the root at 95 cm moving along +z, a swing elsewhere."""
    rows = []
    for f in range(frames):
        values = np.zeros(channels)
        values[:3] = (0.0, 95.0, 3.0 * f)
        values[3:] = 5.0 * np.sin(0.3 * f + np.arange(channels - 3))
        rows.append(values)
    return rows


def take_text(names: dict | None = None, nl: str = "\n", root_position: bool = True) -> str:
    """The test rig (``F.bvh_hierarchy``) as BVH text, joints renamed by ``names``, lines
    ending in ``nl``; root_position False leaves the root its rotation channels alone."""
    hierarchy, channels = F.bvh_hierarchy()
    lines = hierarchy.splitlines()
    for old, new in (names or {}).items():
        lines = [ln.replace(f"JOINT {old}", f"JOINT {new}").replace(f"ROOT {old}", f"ROOT {new}")
                 if ln.strip().split()[-1] == old else ln for ln in lines]  # fmt: skip
    rows = _rows(FRAMES, channels)
    if not root_position:
        lines = [ln.replace("CHANNELS 6 Xposition Yposition Zposition", "CHANNELS 3", 1)
                 for ln in lines]  # fmt: skip
        rows = [r[3:] for r in rows]
    lines += ["MOTION", f"Frames: {FRAMES}", "Frame Time: 0.0333333"]
    lines += [" ".join(f"{v:.4f}" for v in r) for r in rows]
    return nl.join(lines) + nl


def header_of(data: bytes) -> bytes:
    """A BVH file's bytes through its MOTION line."""
    return data[: data.index(b"MOTION") + len(b"MOTION")]


@pytest.fixture(scope="module")
def joints():
    return BodyJoints(load_body_model(None))


# --- 1: names with spaces ----------------------------------------------------------------------


def test_biped_names_with_spaces_are_read_and_map_onto_the_body(tmp_path, joints):
    path = tmp_path / "biped.bvh"
    path.write_text(take_text(BIPED))
    plain = tmp_path / "plain.bvh"
    plain.write_text(take_text())
    src, ref = load_bvh(path), load_bvh(plain)
    assert len(src.names) == len(ref.names) == 26  # 21 joints, 5 End Sites
    assert src.names[:3] == ("Bip01 Pelvis", "Bip01 Spine", "Bip01 Spine1")
    assert "Bip01 L Thigh" in src.names and "Bip01 R Toe0" in src.names
    np.testing.assert_array_equal(src.rotations, ref.rotations)
    np.testing.assert_array_equal(src.offsets, ref.offsets)
    named = {k: src.names[v] for k, v in build_joint_map(src).anchor.items()}
    assert named["left_hip"] == "Bip01 L Thigh" and named["right_knee"] == "Bip01 R Calf"
    assert named["left_ankle"] == "Bip01 L Foot" and named["left_foot"] == "Bip01 L Toe0"
    assert named["left_wrist"] == "Bip01 L Hand" and named["head"] == "Bip01 Head"
    assert named["pelvis"] == "Bip01 Pelvis"
    a, b = (read_take(p, joints).retarget.mean_error for p in (path, plain))
    assert a == pytest.approx(b, abs=1e-9) and a < 0.01


def test_biped_names_keep_the_header_byte_for_byte(tmp_path):
    """The name is the rest of the line, stripped; a brace may follow it on the line."""
    text = take_text(BIPED).replace("ROOT Bip01 Pelvis\n{", "ROOT Bip01 Pelvis {")
    text = text.replace("JOINT Bip01 L Thigh\n", "JOINT Bip01 L Thigh \t \n")
    path = tmp_path / "biped.bvh"
    path.write_bytes(text.encode())
    names = load_bvh(path).names
    assert names[0] == "Bip01 Pelvis" and "Bip01 L Thigh" in names
    code, _, _ = run_cli("denoise", path, "-o", tmp_path / "out.bvh")
    assert code == 0
    out = (tmp_path / "out.bvh").read_bytes()
    assert header_of(out) == header_of(path.read_bytes())
    assert load_bvh(tmp_path / "out.bvh").names == names


def test_a_joint_name_on_the_next_line_still_reads(tmp_path):
    path = tmp_path / "a.bvh"
    path.write_text(take_text().replace("JOINT Spine\n", "JOINT\n  Spine\n"))
    assert load_bvh(path).names[:2] == ("Hips", "Spine")


# --- 2: a root with rotation channels alone ---------------------------------------------------


def test_a_root_without_position_channels_stays_where_its_offset_puts_it(tmp_path, joints):
    path = tmp_path / "rot_only.bvh"
    path.write_text(take_text(root_position=False))
    src = load_bvh(path)
    assert src.layout.joint_columns(0, "t") == [] and src.layout.data.shape[1] == 3 * 21
    np.testing.assert_allclose(src.root_positions, np.tile([0, 0.95, 0], (FRAMES, 1)), atol=1e-12)
    take = read_take(path, joints, source=src)
    motion = take.motion
    moved = motion.with_body(trans=np.asarray(motion.trans) + [0.5, 0.0, 0.2])
    # the translation has no channel to go to: the file comes back as it was
    same = write_back_data(take.source, take.retarget, motion, moved, joints)
    np.testing.assert_allclose(same, src.layout.data, atol=1e-6)
    turned = motion.with_body(pose_body=np.asarray(motion.pose_body) * 0.8)
    data = write_back_data(take.source, take.retarget, motion, turned, joints)
    assert data.shape == src.layout.data.shape and np.isfinite(data).all()
    assert np.abs(data - src.layout.data).max() > 0.5  # degrees: the joints did turn


def test_a_root_move_the_file_cannot_hold_is_noted(tmp_path, joints):
    from mdvae_cli.formats.registry import write

    path = tmp_path / "rot_only.bvh"
    path.write_text(take_text(root_position=False))
    take = read_take(path, joints, source=load_bvh(path))
    motion = take.motion
    moved = motion.with_body(trans=np.asarray(motion.trans) + [0.03, 0.0, 0.04])
    notes = write(moved, tmp_path / "moved.bvh", take=take)
    assert len(notes) == 1 and "no position channels" in notes[0] and "5.0 cm" in notes[0]
    assert write(motion, tmp_path / "same.bvh", take=take) == []  # nothing moved: no note
    full = tmp_path / "full.bvh"
    full.write_text(take_text())
    take = read_take(full, joints, source=load_bvh(full))
    moved = take.motion.with_body(trans=np.asarray(take.motion.trans) + [0.03, 0.0, 0.04])
    assert write(moved, tmp_path / "full_out.bvh", take=take) == []  # its root carries it


@pytest.mark.parametrize("command", [["denoise"], ["add-noise", "--seed", "3"]])
def test_a_root_without_position_channels_is_written_back_as_bvh(tmp_path, command):
    path = tmp_path / "rot_only.bvh"
    path.write_text(take_text(root_position=False))
    out = tmp_path / "out.bvh"
    code, stdout, stderr = run_cli(*command, path, "-o", out)
    assert code == 0, stdout + stderr
    assert header_of(out.read_bytes()) == header_of(path.read_bytes())
    back = load_bvh(out)
    assert back.layout.joint_columns(0, "t") == [] and back.num_frames == FRAMES
    np.testing.assert_allclose(back.root_positions, load_bvh(path).root_positions, atol=1e-12)


# --- 3: encodings -----------------------------------------------------------------------------


@pytest.mark.parametrize(("encoding", "bom", "read_as"), [
    ("cp1252", b"", "latin-1"), ("utf-8", b"", "utf-8"), ("utf-8", b"\xef\xbb\xbf", "utf-8-sig"),
])  # fmt: skip
def test_the_header_comes_back_in_the_files_own_encoding(tmp_path, encoding, bom, read_as):
    names = {"LeftShoulder": "ÉpauleGauche", "RightShoulder": "Épaule Droite"}
    path = tmp_path / "take.bvh"
    path.write_bytes(bom + take_text(names).encode(encoding))
    src = load_bvh(path)
    assert "ÉpauleGauche" in src.names and "Épaule Droite" in src.names
    assert src.layout.encoding == read_as
    code, _, _ = run_cli("denoise", path, "-o", tmp_path / "out.bvh")
    assert code == 0
    out = (tmp_path / "out.bvh").read_bytes()
    assert out.startswith(bom + b"HIERARCHY")
    assert header_of(out) == header_of(path.read_bytes())
    assert "ÉpauleGauche".encode(encoding) in out and b"\xef\xbf\xbd" not in out
    assert load_bvh(tmp_path / "out.bvh").names == src.names


def test_a_cp1252_bone_name_reads_alike_in_the_asf_and_the_amc(tmp_path):
    bones = [*F._ASF_BONES, ("lthümb", "lhand", (1, 0, 0), 1.0, "rx")]
    (tmp_path / "07.asf").write_bytes(F.asf_text(bones).encode("cp1252"))
    amc = tmp_path / "07_01.amc"
    amc.write_bytes(F.amc_text(48, bones).encode("cp1252"))
    code, stdout, stderr = run_cli("denoise", amc, "-o", tmp_path / "out" / "07_01.amc")
    assert code == 0, stdout + stderr
    out = (tmp_path / "out" / "07_01.amc").read_bytes()
    assert out.count(b"lth\xfcmb ") == 48
    source = amc.read_bytes()
    assert out[: out.index(b"\n1\n")] == source[: source.index(b"\n1\n")]


# --- 4: line endings --------------------------------------------------------------------------


@pytest.mark.parametrize("nl", ["\r", "\r\n"])
def test_every_line_ending_reads_and_comes_back(tmp_path, nl):
    unix, other = tmp_path / "lf.bvh", tmp_path / "other.bvh"
    unix.write_bytes(take_text().encode())
    other.write_bytes(take_text(nl=nl).encode())
    a, b = load_bvh(unix), load_bvh(other)
    assert b.names == a.names and b.layout.header == a.layout.header.replace("\n", nl)
    np.testing.assert_array_equal(b.layout.data, a.layout.data)
    outs = []
    for path in (unix, other):
        code, _, _ = run_cli("denoise", path, "-o", tmp_path / f"out_{path.name}")
        assert code == 0
        outs.append((tmp_path / f"out_{path.name}").read_bytes())
    lines = len(take_text().splitlines())
    assert outs[1].count(nl.encode()) == lines and outs[1].count(b"\n") == nl.count("\n") * lines
    assert header_of(outs[1]) == header_of(other.read_bytes())
    assert outs[1].replace(nl.encode(), b"\n") == outs[0]  # the same values, own line ends


# --- 5: gzip ----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["a.bvh.GZ", "c.Bvh.Gz", "b.BVH.gz", "gzipped_as_plain.bvh"])
def test_gzip_is_read_whatever_the_case_of_its_suffix_or_without_one(tmp_path, name):
    plain = tmp_path / "plain.bvh"
    plain.write_text(take_text())
    path = tmp_path / name
    path.write_bytes(F.gz(take_text()))
    np.testing.assert_array_equal(load_bvh(path).layout.data, load_bvh(plain).layout.data)
    out = tmp_path / "out.bvh.GZ"
    code, _, _ = run_cli("denoise", path, "-o", out)
    assert code == 0
    data = out.read_bytes()
    assert data[:2] == b"\x1f\x8b"  # compressed: the name ends in .gz, in any case
    assert header_of(gzip.decompress(data)) == header_of(plain.read_bytes())


def test_an_upper_case_amc_gz_is_read(tmp_path):
    (tmp_path / "07.asf").write_text(F.asf_text())
    (tmp_path / "07_01.AMC.GZ").write_bytes(F.gz(F.amc_text(12)))
    (tmp_path / "07_02.amc").write_text(F.amc_text(12))
    code, stdout, stderr = run_cli("import", tmp_path / "07_01.AMC.GZ", tmp_path / "07_02.amc",
                                   "-o", tmp_path / "out", "--fps", "0")  # fmt: skip
    assert code == 0, stdout + stderr
    a, b = (np.load(tmp_path / "out" / f"07_0{i}.npz") for i in (1, 2))
    np.testing.assert_array_equal(a["poses"], b["poses"])
    assert a["poses"].shape[0] == 12


def test_a_gz_name_on_text_that_is_not_gzip_is_refused(tmp_path):
    path = tmp_path / "a.bvh.GZ"
    path.write_text(take_text())
    with pytest.raises(InputError, match=r"not a readable \.gz file"):
        read_text(path)


def test_gzip_magic_in_a_file_named_bvh_reads_as_its_text(tmp_path):
    path = tmp_path / "a.bvh"
    path.write_bytes(F.gz("HIERARCHY\n"))
    assert read_text(path) == "HIERARCHY\n"


def test_the_frames_and_frame_time_lines_come_back_as_the_file_spells_them(tmp_path):
    text = take_text().replace("Frames: ", "frames:\t").replace("Frame Time: ", "FRAME TIME:  ")
    path = tmp_path / "spelled.bvh"
    path.write_text(text)
    code, _, err = run_cli("denoise", path, "-o", tmp_path / "out.bvh")
    assert code == 0, err
    lines = (tmp_path / "out.bvh").read_text().splitlines()
    at = lines.index("MOTION")
    assert lines[at + 1 : at + 3] == [f"frames:\t{FRAMES}", "FRAME TIME:  0.0333333"]
    code, _, err = run_cli("denoise", path, "-o", tmp_path / "out60.bvh", "--fps", 60)
    assert code == 0, err
    assert "FRAME TIME:  0.0166667" in (tmp_path / "out60.bvh").read_text()
