"""How a source skeleton reads as SMPL: the joint map, the canonical axes, the attached points.

* :func:`build_joint_map` finds, by name, the source joints for the SMPL joints with a clear
  anatomical counterpart (*direct* joints: hips, knees, ankles, toe bases, shoulders, elbows,
  wrists) and the anchors (pelvis, head, collars) the others hang from; a rig named
  mirror-wise gets its sides exchanged (:mod:`mdvae_cli.retarget.sides`).
* :func:`canonical_rotation` / :func:`canonicalise` turn the source world (a signed axis
  permutation read off the rest pose) so that up is +y, the body's left +x and forward +z,
  SMPL's own frame.
* :func:`attach_offsets` places the *attached* SMPL joints (pelvis, spine1-3, neck, head,
  collars the source lacks): a fixed offset in the frame of a source joint, taken from the
  body's rest pose once its shape is known.

Plain numpy, no torch and no files: used by :mod:`mdvae_cli.retarget.fit_shape` and
:mod:`mdvae_cli.retarget.retarget`.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field, replace

import numpy as np

from mdvae_cli.body.data import NUM_BODY_JOINTS, SMPL_JOINT_NAMES
from mdvae_cli.errors import InputError
from mdvae_cli.formats.bvh_rotations import TurnedRotations
from mdvae_cli.formats.source import SourceMotion
from mdvae_cli.retarget.rig_heads import cat_head, neck_end
from mdvae_cli.retarget.sides import exchange_sides, named_sides_mirrored

_N = NUM_BODY_JOINTS
_IDX = {name: i for i, name in enumerate(SMPL_JOINT_NAMES)}

#: source joint names (normalised: lower case, no namespace, no ``_ - . space``) per SMPL joint;
#: the first that exists wins. Left side only; the right is derived. 3ds Max CAT names a bone
#: <rig><limb><bone><segment> with the side glued on: its Base Human preset ``LThigh1``,
#: ``LCalf``, ``LFoot``, ``LToe0``, ``LCollarbone``, ``LUpperarm1``, ``LForearm1``, ``LPalm``; a
#: rig built from scratch ``LLeg1``, ``LLeg2``, ``LLegAnkle``, ``LLegDigit11``,
#: ``LArmCollarbone``, ``LArm1``, ``LArm2``, ``LArmPalm`` (the rig's name, a prefix every bone
#: shares, is cut by :func:`shared_prefix`; its head hub: ``rig_heads.cat_head``)
_ALIASES: dict[str, tuple[str, ...]] = {
    "pelvis": ("root", "hips", "pelvis", "hip"),
    "left_hip": ("lfemur", "leftupleg", "leftthigh", "lefthip", "lthigh", "lhip", "leftupperleg",
                 "lupleg", "leftfemur", "lthighbend", "lthigh1", "lleg1"),
    "left_knee": ("ltibia", "leftleg", "leftshin", "leftknee", "lshin", "lknee", "leftlowerleg",
                  "leftloleg", "leftlowleg", "leftcalf", "lcalf", "lcalf1", "lleg2"),
    "left_ankle": ("leftankle", "lankle", "lfoot", "leftfoot", "llegankle"),
    "left_foot": ("ltoes", "lefttoebase", "lefttoe", "lefttoes", "ltoe", "leftforefoot",
                  "leftball", "lefttoe0", "leftfoot", "ltoe0", "ltoe01", "ltoe1", "llegdigit11"),
    "left_shoulder": ("lhumerus", "leftarm", "leftupperarm", "leftuparm", "lshldr", "lshldrbend",
                      "luarm", "lshoulder", "leftshoulder", "lupperarm", "lupperarm1", "larm1"),
    "left_collar": ("lclavicle", "leftshoulder", "leftcollar", "lcollar", "leftclavicle",
                    "lclav", "lshoulder", "leftscapula", "lcollarbone", "larmcollarbone"),
    "left_elbow": ("lradius", "leftforearm", "leftlowerarm", "leftelbow", "lforearm", "lelbow",
                   "leftloarm", "leftlowarm", "lforearmbend", "lfarm", "lforearm1", "larm2"),
    "left_wrist": ("lhand", "leftwrist", "lefthand", "lwrist", "lpalm", "larmpalm"),
    "head": ("head", "neck1", "spine006"),
}  # fmt: skip

#: rig prefixes that carry no anatomy (SMPL's FBX rig, 3ds Max Biped, Character Creator,
#: Blender Rigify's deform bones, VRoid)
_PREFIXES = re.compile(r"^(?:[fm]_avg_|smpl_|bip\d*[\s_]|cc_base_|def-|j_bip_)", re.IGNORECASE)
#: a side written apart from the name: ``L_Hip``, ``Hand_L``, ``hand.l``, ``Left Arm``
_SIDE_FIRST = re.compile(r"^(l|r|left|right)[\s_.\-]+(.+)$", re.IGNORECASE)
_SIDE_LAST = re.compile(r"^(.+?)[\s_.\-]+(l|r|left|right)$", re.IGNORECASE)
#: a centre-line mark written apart: VRoid's ``J_Bip_C_Head``, AdvancedSkeleton's ``Head_M``
_CENTRE = re.compile(r"^(?:c|m)[\s_.\-]+(.+)$|^(.+?)[\s_.\-]+(?:c|m)$", re.IGNORECASE)

_REQUIRED = ("pelvis", "left_hip", "left_knee", "left_ankle", "left_shoulder", "left_elbow",
             "left_wrist", "head")  # fmt: skip
_DIRECT = ("left_hip", "left_knee", "left_ankle", "left_foot", "left_shoulder", "left_elbow",
           "left_wrist")  # fmt: skip
_SPINE = ("spine1", "spine2", "spine3", "neck", "head")


def _sides(name: str) -> list[str]:
    return [name, "right" + name[4:]] if name.startswith("left") else [name]


def _right_alias(alias: str) -> str:
    if alias.startswith("left"):
        return "right" + alias[4:]
    if alias[0] == "l":
        return "r" + alias[1:]
    return alias


def normalise_name(name: str) -> str:
    """``mixamorig:Left_Up-Leg`` -> ``leftupleg``; ``f_avg_L_Hip`` -> ``lefthip``;
    ``UpLeg_L`` -> ``leftupleg`` (a side written apart becomes a ``left``/``right`` prefix)."""
    name = _PREFIXES.sub("", re.split(r"[:|]", name)[-1].strip())
    side = ""
    for pattern, s, rest in ((_SIDE_FIRST, 1, 2), (_SIDE_LAST, 2, 1)):
        m = pattern.match(name)
        if m:
            side = "left" if m.group(s).lower().startswith("l") else "right"
            name = m.group(rest)
            break
    else:
        m = _CENTRE.match(name)
        name = (m.group(1) or m.group(2)) if m else name
    return side + re.sub(r"[\s_.\-]", "", name).lower()


def shared_prefix(names: list[str]) -> str:
    """The prefix a rig puts on every joint name (``Character1_``, ``mixamorig_``, ``mixamorig``
    before a capital), a root named otherwise allowed; "" when there is none."""
    for group in (names, names[1:]):
        p = os.path.commonprefix(group) if len(group) >= 2 else ""
        for k in range(len(p), 2, -1):
            if p[k - 1] in " _:|.-" or (
                not p[k - 1].isupper() and all(n[k : k + 1].isupper() for n in group)
            ):
                side = re.fullmatch(r"(?i)(l|r|left|right)[\s_.:|\-]*", p[:k])
                return "" if side else p[:k]
    return ""


@dataclass
class JointMap:
    """How the 22 SMPL body joints read a source skeleton.  Indices are source joint indices.

    anchor: SMPL joint name -> source joint found by name (direct joints, pelvis, head, collars).
    attach: (22,) source joint carrying each SMPL joint's target; offset: (22, 3) the target's
    offset in that joint's frame (zero for direct joints; set by :func:`attach_offsets`).
    rot_source: (22,) source joint whose global rotation starts each SMPL joint's rotation.
    direct: (22,) bool. chain: source joints from the pelvis to the head anchor.
    """

    anchor: dict[str, int]
    attach: np.ndarray
    rot_source: np.ndarray
    direct: np.ndarray
    chain: list[int]
    offset: np.ndarray = field(default_factory=lambda: np.zeros((_N, 3)))

    def describe(self, names: tuple[str, ...]) -> dict[str, str]:
        """SMPL joint -> the source joint it follows (``~`` marks an attached point)."""
        return {
            SMPL_JOINT_NAMES[j]: ("" if self.direct[j] else "~") + names[self.attach[j]]
            for j in range(_N)
        }


def _path(parents: np.ndarray, a: int, b: int) -> list[int]:
    """Source joints from ancestor a down to b (both included); [] if a is not an ancestor."""
    out = [b]
    while out[-1] != a:
        p = int(parents[out[-1]])
        if p < 0:
            return []
        out.append(p)
    return out[::-1]


#: every SMPL joint a user's --joint-map may name (the spine is placed by heights)
MAP_KEYS = tuple(n for smpl in _ALIASES for n in _sides(smpl)) + ("left_foot", "right_foot")


def _common_ancestor(parents: np.ndarray, joints: list[int]) -> int:
    """The deepest joint that is an ancestor of (or equal to) every joint in ``joints``."""
    paths = []
    for j in joints:
        chain = [j]
        while parents[chain[-1]] >= 0:
            chain.append(int(parents[chain[-1]]))
        paths.append(chain[::-1])
    common = 0
    for level in zip(*paths, strict=False):
        if len(set(level)) > 1:
            break
        common = level[0]
    return int(common)


def _user_anchors(src: SourceMotion, given: dict) -> dict[str, int]:
    """The --joint-map entries as source joint indices; InputError for unknown names."""
    out: dict[str, int] = {}
    by_norm = {normalise_name(n): i for i, n in enumerate(src.names)}
    for smpl, name in given.items():
        if smpl not in MAP_KEYS:
            raise InputError(f"joint map: {smpl!r} is not an SMPL joint it can use (one of "
                             f"{', '.join(sorted(set(MAP_KEYS)))})")  # fmt: skip
        if name in src.names:
            out[smpl] = src.names.index(name)
        elif normalise_name(str(name)) in by_norm:
            out[smpl] = by_norm[normalise_name(str(name))]
        else:
            raise InputError(f"joint map: {smpl} -> {name!r}, but the skeleton has no joint "
                             f"{name!r}")  # fmt: skip
    return out


def _find_anchors(src: SourceMotion) -> dict[str, int]:
    """SMPL joint name -> source joint, by name (a --joint-map kept in ``src.info["joint_map"]``
    first); InputError naming every required joint that is missing."""
    norm: dict[str, int] = {}
    helpers = [i for i, n in enumerate(src.names) if n.startswith("__")]  # MakeHuman's helpers
    cut = len(shared_prefix([n for n, e in zip(src.names, src.end_site, strict=True) if not e]))
    for i in [i for i in range(len(src.names)) if i not in helpers] + helpers:
        if not src.end_site[i]:
            norm.setdefault(normalise_name(src.names[i][cut:] or src.names[i]), i)
    anchor = _user_anchors(src, src.info.get("joint_map") or {})
    for smpl, aliases in _ALIASES.items():
        for side, name in zip(("l", "r"), _sides(smpl), strict=False):
            if name in anchor or smpl == "pelvis":
                continue
            names = aliases if side == "l" else tuple(_right_alias(a) for a in aliases)
            taken = set(anchor.values())
            hit = next((norm[a] for a in names if a in norm and norm[a] not in taken), None)
            if hit is not None:
                anchor[name] = hit
    if "head" not in anchor:  # a rig that names none: a CAT rig's hub, a neck's end
        head = cat_head(src, norm, anchor)
        head = neck_end(src, norm) if head is None else head
        if head is not None:
            anchor["head"] = head
    missing = [n for smpl in _REQUIRED[1:] for n in _sides(smpl) if n not in anchor]
    if missing:
        joints = [n for n, end in zip(src.names, src.end_site, strict=True) if not end]
        few = len(missing) > 6  # over half of the 13 limb and head joints: no body at all?
        raise InputError(
            f"cannot map the skeleton onto SMPL: no joint found for {', '.join(missing)} "
            f"(joints: {', '.join(joints[:12])}{', ...' * (len(joints) > 12)}); name them in "
            f'a --joint-map FILE.json, e.g. {{"{missing[0]}": "<joint name>"}}'
            f"{'; a hand, a face or a prop is no body to retarget' * few}"
        )
    if "pelvis" not in (src.info.get("joint_map") or {}):
        # the pelvis is where the legs and the spine part: names alone mislead (MakeHuman's
        # Hips carry only the legs; the SMPL rig's root sits under the pelvis)
        legs_and_head = [anchor["left_hip"], anchor["right_hip"], anchor["head"]]
        anchor["pelvis"] = _common_ancestor(src.parents, legs_and_head)
    return anchor


def _through_zero_offsets(src: SourceMotion, j: int) -> int:
    """Follow zero-length, non-thumb children down from j (cmuconvert's hands start so)."""
    while True:
        kids = [
            k
            for k in np.flatnonzero(src.parents == j)
            if not src.end_site[k]
            and np.linalg.norm(src.offsets[k]) < 1e-6
            and "thumb" not in src.names[k].lower()
        ]
        if not kids:
            return int(j)
        j = kids[0]


def build_joint_map(src: SourceMotion) -> JointMap:
    """Find the SMPL joints in ``src`` by name (CMU ASF, CMU/MotionBuilder/Mixamo BVH, ...).

    Spine joints (and collars the source lacks) are left for :func:`attach_offsets`, which
    places them once the body's shape is known. Raises InputError naming the first SMPL joint
    that cannot be found.
    """
    anchor = _find_anchors(src)
    given = src.info.get("joint_map") or {}
    if not any(k.startswith(("left_", "right_")) for k in given) and named_sides_mirrored(
        src, anchor
    ):
        anchor = exchange_sides(anchor)
        note = "the joints named left are the body's right (knees and toes say so): sides exchanged"
        if note not in src.notes:
            src.notes.append(note)
    parents = src.parents
    chain = _path(parents, anchor["pelvis"], anchor["head"])
    if not chain:
        raise InputError("cannot map the skeleton onto SMPL: the head is not below the pelvis")
    attach = np.full(_N, -1, dtype=np.int64)
    rot = np.full(_N, -1, dtype=np.int64)
    direct = np.zeros(_N, dtype=bool)
    for smpl in _DIRECT:
        for name in _sides(smpl):
            if name in anchor:
                attach[_IDX[name]] = anchor[name]
                direct[_IDX[name]] = True
    if src.info.get("cmuconvert"):
        # cmuconvert drops CMU's wrist segment: its hand joint sits ~9 cm short of the wrist,
        # so the body's wrist becomes a point further along the forearm (attach_offsets)
        direct[[_IDX["left_wrist"], _IDX["right_wrist"]]] = False
    attach[0] = rot[0] = anchor["pelvis"]
    for side in ("left", "right"):
        if f"{side}_foot" not in anchor:  # no toes: a point in the ankle's frame
            attach[_IDX[f"{side}_foot"]] = anchor[f"{side}_ankle"]
        collar = anchor.get(f"{side}_collar")
        path = _path(parents, collar, anchor[f"{side}_shoulder"]) if collar is not None else []
        if len(path) >= 2:
            attach[_IDX[f"{side}_collar"]], rot[_IDX[f"{side}_collar"]] = collar, path[-2]
        # rotation sources: the last source joint before the next anchor down the limb
        for a, b in (("hip", "knee"), ("knee", "ankle"), ("ankle", "foot"),
                     ("shoulder", "elbow"), ("elbow", "wrist")):  # fmt: skip
            ja, jb = anchor[f"{side}_{a}"], anchor.get(f"{side}_{b}")
            path = _path(parents, ja, jb) if jb is not None else []
            rot[_IDX[f"{side}_{a}"]] = path[-2] if len(path) >= 2 else ja
        for leaf in ("foot", "wrist"):  # leaves: their own frame (past zero-length joints)
            j = _IDX[f"{side}_{leaf}"]
            rot[j] = _through_zero_offsets(src, attach[j])
    return JointMap(anchor=anchor, attach=attach, rot_source=rot, direct=direct, chain=chain)


def canonical_rotation(src: SourceMotion, jmap: JointMap) -> np.ndarray:
    """The signed axis permutation S (det +1) taking the source world to SMPL's: up +y, the
    body's left +x, forward +z, read off the rest pose.  -> (3, 3)"""
    rest = src.rest_positions()
    up = rest[jmap.anchor["head"]] - rest[jmap.anchor["pelvis"]]
    left = rest[jmap.anchor["left_hip"]] - rest[jmap.anchor["right_hip"]]
    iu = int(np.argmax(np.abs(up)))
    left = left.copy()
    left[iu] = 0.0
    il = int(np.argmax(np.abs(left)))
    if np.linalg.norm(left) < 1e-9 or il == iu:
        raise InputError("cannot tell left from right in the source rest pose")
    S = np.zeros((3, 3))
    S[1, iu] = np.sign(up[iu])
    S[0, il] = np.sign(left[il])
    S[2] = np.cross(S[0], S[1])
    return S


def canonicalise(src: SourceMotion, S: np.ndarray, S_motion: np.ndarray | None = None):
    """``src`` expressed in the world turned by S (positions S p, rotations S R S^T).

    S_motion: the world's own turn when it differs from the rest pose's S (a y-up rest pose in
    a z-up take): the rest pose (offsets, joint rest frames) turns by S, the world (root
    position and rotation) by S_motion.  -> SourceMotion
    """
    S_motion = S if S_motion is None else S_motion
    if np.allclose(S, np.eye(3)) and np.allclose(S_motion, np.eye(3)):
        return src
    turn = np.repeat(S[None], src.num_joints, axis=0)  # the root's on its left: the world's
    rot = TurnedRotations(src.rotations, np.concatenate([S_motion[None], turn[1:]]), turn)
    local = None if src.local_positions is None else src.local_positions @ S.T
    return replace(src, offsets=src.offsets @ S.T, root_positions=src.root_positions @ S_motion.T,
                   rotations=rot, info=dict(src.info), notes=list(src.notes),
                   local_positions=local)  # fmt: skip


def _last_below(heights: np.ndarray, chain: list[int], h: float) -> int:
    """The last chain joint whose rest height is at most h (the first joint if none is)."""
    below = [c for c, hc in zip(chain, heights, strict=True) if hc <= h + 1e-3]
    return below[-1] if below else chain[0]


def attach_offsets(src: SourceMotion, jmap: JointMap, rest_joints: np.ndarray) -> JointMap:
    """Place the attached (non-direct) SMPL joints on the source skeleton.

    The body's rest joints ``rest_joints`` (J, 3) are moved so that its hip centre meets the
    source's; spine joints and missing collars then ride on the last source spine joint below
    them, and every attached joint keeps its rest offset from its carrier.  Fills in
    ``attach``, ``rot_source`` and ``offset`` of a copy of ``jmap``.
    """
    rest = src.rest_positions()
    X = np.asarray(rest_joints)[:_N]
    hips = (rest[jmap.anchor["left_hip"]] + rest[jmap.anchor["right_hip"]]) / 2
    X = X + (hips - (X[1] + X[2]) / 2)
    chain = jmap.chain
    heights = rest[chain, 1]
    attach, rot = jmap.attach.copy(), jmap.rot_source.copy()
    for name, child in zip(_SPINE, ("spine2", "spine3", "neck", "head", None), strict=True):
        j = _IDX[name]
        attach[j] = _last_below(heights, chain, X[j, 1])
        if child is None:
            rot[j] = _through_zero_offsets(src, jmap.anchor["head"])
        else:
            rot[j] = _last_below(heights, chain, (X[j, 1] + X[_IDX[child], 1]) / 2)
    for side in ("left", "right"):  # collars the source lacks ride on the spine
        j = _IDX[f"{side}_collar"]
        if attach[j] < 0:
            attach[j] = rot[j] = _last_below(heights, chain, X[j, 1])
    offset = np.where(jmap.direct[:, None], 0.0, X - rest[attach])
    for side in ("left", "right"):
        j, e = _IDX[f"{side}_wrist"], _IDX[f"{side}_elbow"]
        if not jmap.direct[j]:  # further along the source forearm, to the body's forearm length
            d = rest[attach[j]] - rest[attach[e]]
            n = np.linalg.norm(d)
            offset[j] = d / n * (np.linalg.norm(X[j] - X[e]) - n)
    return JointMap(anchor=dict(jmap.anchor), attach=attach, rot_source=rot,
                    direct=jmap.direct.copy(), chain=list(chain), offset=offset)  # fmt: skip
