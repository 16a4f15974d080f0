"""Joint names as studio tools and game engines write them map onto the same SMPL joints as the
test rig's Mixamo-style names: OptiTrack Motive, Daz Genesis 3/8, Blender Rigify deform bones,
Maya AdvancedSkeleton (``Head_M``), VRoid (``J_Bip_C_Head``), 3ds Max CAT (``Base HumanLCalf``,
``CATRigLLeg2``), and a prefix every joint carries (``mixamorig_``, ``mixamorig`` before a
capital, Maya HumanIK's ``Character1_``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mdvae_cli.formats.bvh import load_bvh
from mdvae_cli.retarget.joint_map import build_joint_map, shared_prefix
from tests.bad_input import files as F
from tests.conftest import one_error_line, run_cli

_BASE = ("Hips", "Spine", "Spine1", "Neck", "Head", "Shoulder", "Arm", "ForeArm", "Hand", "UpLeg",
         "Leg", "Foot", "ToeBase")  # fmt: skip

#: per convention, the test rig's names in _BASE order ("{s}" is the side as the rig writes it)
CONVENTIONS = {
    "optitrack": (("Hip", "Ab", "Chest", "Neck", "Head", "{s}Shoulder", "{s}UArm", "{s}FArm",
                   "{s}Hand", "{s}Thigh", "{s}Shin", "{s}Foot", "{s}Toe"), ("L", "R")),
    "daz_genesis8": (("hip", "abdomenLower", "chestUpper", "neckLower", "head", "{s}Collar",
                      "{s}ShldrBend", "{s}ForearmBend", "{s}Hand", "{s}ThighBend", "{s}Shin",
                      "{s}Foot", "{s}Toe"), ("l", "r")),
    "rigify_def": (("DEF-spine", "DEF-spine.001", "DEF-spine.003", "DEF-spine.004",
                    "DEF-spine.006", "DEF-shoulder.{s}", "DEF-upper_arm.{s}", "DEF-forearm.{s}",
                    "DEF-hand.{s}", "DEF-thigh.{s}", "DEF-shin.{s}", "DEF-foot.{s}",
                    "DEF-toe.{s}"), ("L", "R")),
    "advanced_skeleton": (("Root_M", "Spine1_M", "Chest_M", "Neck_M", "Head_M", "Scapula_{s}",
                           "Shoulder_{s}", "Elbow_{s}", "Wrist_{s}", "Hip_{s}", "Knee_{s}",
                           "Ankle_{s}", "Toes_{s}"), ("L", "R")),
    "vroid": (("J_Bip_C_Hips", "J_Bip_C_Spine", "J_Bip_C_Chest", "J_Bip_C_Neck", "J_Bip_C_Head",
               "J_Bip_{s}_Shoulder", "J_Bip_{s}_UpperArm", "J_Bip_{s}_LowerArm", "J_Bip_{s}_Hand",
               "J_Bip_{s}_UpperLeg", "J_Bip_{s}_LowerLeg", "J_Bip_{s}_Foot", "J_Bip_{s}_ToeBase"),
              ("L", "R")),
    # 3ds Max CAT: <rig name><limb><bone>; the Base Human preset's bones, and a rig built from
    # scratch ("CATRig": hubs, limbs LLeg / LArm with numbered bones, Ankle, Palm, Digit11)
    "cat_base_human": (("Base HumanPelvis", "Base HumanSpine1", "Base HumanRibcage",
                        "Base HumanNeck", "Base HumanHead", "Base Human{s}Collarbone",
                        "Base Human{s}Upperarm", "Base Human{s}Forearm", "Base Human{s}Palm",
                        "Base Human{s}Thigh", "Base Human{s}Calf", "Base Human{s}Foot",
                        "Base Human{s}Toe"), ("L", "R")),
    "cat_segments": (("CharPelvis", "CharSpine1", "CharRibcage", "CharNeck1", "CharHead",
                      "Char{s}Collarbone", "Char{s}Upperarm1", "Char{s}Forearm1", "Char{s}Palm",
                      "Char{s}Thigh1", "Char{s}Calf1", "Char{s}Foot", "Char{s}Toe0"),
                     ("L", "R")),
    "cat_from_scratch": (("CATRigHub001", "CATRigSpine1", "CATRigHub002", "CATRigSpine2",
                          "CATRigHub003", "CATRig{s}ArmCollarbone", "CATRig{s}Arm1",
                          "CATRig{s}Arm2", "CATRig{s}ArmPalm", "CATRig{s}Leg1", "CATRig{s}Leg2",
                          "CATRig{s}LegAnkle", "CATRig{s}LegDigit11"), ("L", "R")),
}  # fmt: skip
for _prefix, _key in (("mixamorig_", "mixamo_underscore"), ("mixamorig", "mixamo_no_colon"),
                      ("Character1_", "humanik_character1")):  # fmt: skip
    _names = tuple(_prefix + ("{s}" if i >= 5 else "") + b for i, b in enumerate(_BASE))
    CONVENTIONS[_key] = (_names, ("Left", "Right"))


def _renamed(convention: str) -> dict[str, str]:
    """The test rig's joint name -> the convention's."""
    names, sides = CONVENTIONS[convention]
    out = {}
    for i, (base, new) in enumerate(zip(_BASE, names, strict=True)):
        if i < 5:
            out[base] = new
            continue
        for side, s in zip(("Left", "Right"), sides, strict=True):
            out[side + base] = new.format(s=s)
    return out


def _take(tmp_path, convention: str | None):
    rig = [(_renamed(convention).get(n, n) if convention else n,
            (_renamed(convention).get(p, p) if convention else p) if p else None, off)
           for n, p, off in F._BVH_RIG]  # fmt: skip
    text = F.bvh_text().replace(F.bvh_hierarchy()[0], F.bvh_hierarchy(rig)[0])
    path = tmp_path / f"{convention or 'plain'}.bvh"
    path.write_text(text)
    return path


@pytest.mark.parametrize("convention", sorted(CONVENTIONS))
def test_each_convention_maps_every_joint_as_the_plain_names_do(tmp_path, convention):
    plain = build_joint_map(load_bvh(_take(tmp_path, None)))
    src = load_bvh(_take(tmp_path, convention))
    jmap = build_joint_map(src)
    assert jmap.anchor == plain.anchor
    np.testing.assert_array_equal(jmap.attach, plain.attach)
    np.testing.assert_array_equal(jmap.rot_source, plain.rot_source)
    named = {k: src.names[v] for k, v in jmap.anchor.items()}
    want = _renamed(convention)
    assert named["left_hip"] == want["LeftUpLeg"] and named["right_hip"] == want["RightUpLeg"]
    assert (
        named["left_shoulder"] == want["LeftArm"] and named["left_collar"] == want["LeftShoulder"]
    )
    assert named["right_elbow"] == want["RightForeArm"] and named["head"] == want["Head"]


def test_the_shared_prefix_stops_where_a_name_begins():
    assert shared_prefix(["mixamorigHips", "mixamorigLeftUpLeg", "mixamorigSpine"]) == "mixamorig"
    assert shared_prefix(["Reference", "Character1_Hips", "Character1_Spine"]) == "Character1_"
    # names that merely start alike keep their words
    assert shared_prefix(["Hips", "HipsTwist", "Head"]) == ""
    assert shared_prefix(["LeftUpLeg", "LeftLeg", "LeftFoot"]) == ""
    assert shared_prefix(["L_UpLeg", "L_Leg", "L_Foot"]) == ""
    assert shared_prefix(["Bip01", "Bip01 Pelvis", "Bip01 Spine"]) == "Bip01 "


def test_a_prefixed_mixamo_take_imports_as_the_plain_one(tmp_path):
    runs = []
    for convention in (None, "mixamo_underscore"):
        out = tmp_path / f"{convention}.npz"
        code, stdout, stderr = run_cli("import", _take(tmp_path, convention), "-o", out)
        assert code == 0, stdout + stderr
        runs.append(np.load(out))
    np.testing.assert_allclose(runs[0]["poses"], runs[1]["poses"], atol=1e-6)
    np.testing.assert_allclose(runs[0]["trans"], runs[1]["trans"], atol=1e-6)


def test_an_unknown_rig_names_its_own_joints_and_a_joint_map_file_fixes_it(tmp_path):
    # bones numbered as made: nothing known after the shared "Rig " prefix but the head
    order = ("UpLeg", "Leg", "Foot", "ToeBase", "Arm", "ForeArm", "Hand", "Shoulder")
    bones = {f"{side}{b}": f"Bone{10 * k + i:02d}" for k, side in enumerate(("Left", "Right"))
             for i, b in enumerate(order)}  # fmt: skip
    rig = [("Rig " + bones.get(n, n), p and "Rig " + bones.get(p, p), off)
           for n, p, off in F._BVH_RIG]  # fmt: skip
    path = tmp_path / "bones.bvh"
    path.write_text(F.bvh_text().replace(F.bvh_hierarchy()[0], F.bvh_hierarchy(rig)[0]))
    code, out, err = run_cli("import", path, "-o", tmp_path / "x.npz")
    line = one_error_line(code, out, err)
    assert "no joint found for left_hip, right_hip, left_knee" in line and "head" not in line
    assert "--joint-map" in line and "Rig Head, Rig Bone07" in line
    smpl = ("hip", "knee", "ankle", "foot", "shoulder", "elbow", "wrist", "collar")
    jmap = {f"{side}_{k}": f"Rig Bone{10 * s + i:02d}" for i, k in enumerate(smpl)
            for s, side in enumerate(("left", "right"))}  # fmt: skip
    (tmp_path / "map.json").write_text(json.dumps(jmap))
    npz = tmp_path / "bones.npz"
    code, out, err = run_cli("import", path, "-o", npz, "--joint-map", tmp_path / "map.json")
    assert code == 0, out + err
    plain = tmp_path / "plain.npz"
    assert run_cli("import", _take(tmp_path, None), "-o", plain)[0] == 0
    np.testing.assert_allclose(np.load(npz)["poses"], np.load(plain)["poses"], atol=1e-6)


def test_a_cat_rig_imports_as_the_plain_one_without_a_joint_map(tmp_path):
    """Before: "no joint found for left_hip, ... name them in a --joint-map FILE.json"."""
    plain = tmp_path / "plain.npz"
    assert run_cli("import", _take(tmp_path, None), "-o", plain)[0] == 0
    for convention in ("cat_base_human", "cat_from_scratch"):
        npz = tmp_path / f"{convention}.npz"
        code, out, err = run_cli("import", _take(tmp_path, convention), "-o", npz)
        assert code == 0, out + err
        np.testing.assert_allclose(np.load(npz)["poses"], np.load(plain)["poses"], atol=1e-6)
        np.testing.assert_allclose(np.load(npz)["trans"], np.load(plain)["trans"], atol=1e-6)


def _mirrored(tmp_path, toes: bool = True):
    """The test rig with Left and Right exchanged in every name (toes dropped unless toes)."""
    swap = {n: n.replace("Left", "#").replace("Right", "Left").replace("#", "Right")
            for n, _, _ in F._BVH_RIG}  # fmt: skip
    rig = [(swap[n], p and swap[p], off) for n, p, off in F._BVH_RIG]
    plain = list(F._BVH_RIG)
    if not toes:
        rig = [r for r in rig if "Toe" not in r[0]]
        plain = [r for r in plain if "Toe" not in r[0]]
    hier, channels = F.bvh_hierarchy(rig)
    rows = []
    for f in range(24):  # a walk-like swing: knees (channel 3 of LeftLeg/RightLeg) bend forward
        values = np.zeros(channels)
        values[:3] = (0.0, 95.0, 3.0 * f)
        rows.append(values)
    names = [r[0] for r in plain]
    for f, values in enumerate(rows):
        for side in ("Left", "Right"):
            col = 6 + 3 * (names.index(side + "Leg") - 1) + 1  # Xrotation (ZXY order)
            values[col] = 30.0 + 20.0 * np.sin(0.4 * f)
    text = "MOTION\nFrames: 24\nFrame Time: 0.0333333\n"
    text += "\n".join(" ".join(f"{v:.4f}" for v in r) for r in rows) + "\n"
    out = []
    for name, r in (("mirrored", rig), ("plain", plain)):
        path = tmp_path / f"{name}{'' if toes else '_no_toes'}.bvh"
        path.write_text(F.bvh_hierarchy(r)[0] + text)
        out.append(path)
    return out


@pytest.mark.parametrize("toes", [True, False])
def test_a_rig_named_mirror_wise_is_mapped_by_its_body_not_its_names(tmp_path, toes):
    mirrored, plain = _mirrored(tmp_path, toes)
    src = load_bvh(mirrored)
    named = {k: src.names[v] for k, v in build_joint_map(src).anchor.items()}
    # the joints named Right* sit on the body's left (+x, the side its knees say)
    assert named["left_hip"] == "RightUpLeg" and named["left_knee"] == "RightLeg"
    assert named["left_wrist"] == "RightHand" and named["right_shoulder"] == "LeftArm"
    assert any("sides exchanged" in n for n in src.notes)
    runs = []
    for path in (mirrored, plain):
        npz = tmp_path / (path.stem + ".npz")
        code, _, stderr = run_cli("import", path, "-o", npz)
        assert code == 0
        assert ("sides exchanged" in stderr) == (path == mirrored)  # the import says so
        runs.append(np.load(npz)["poses"])
    np.testing.assert_allclose(runs[0], runs[1], atol=1e-6)


def test_a_joint_map_naming_sides_is_taken_as_given(tmp_path):
    mirrored, _ = _mirrored(tmp_path)
    src = load_bvh(mirrored)
    src.info["joint_map"] = {"left_hip": "LeftUpLeg"}
    assert build_joint_map(src).anchor["left_hip"] == src.names.index("LeftUpLeg")
