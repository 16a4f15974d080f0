"""The 43 virtual mocap markers, placed by an anatomical rule on any SMPL-frame mesh.

A marker is the mesh vertex nearest to a target point defined from the rest-pose joints: a point
between two joints (or at one joint) plus an offset in body directions. The body directions are
SMPL's canonical frame: **+x is the body's left, +y is up, +z is forward**, rest pose a T-pose
(arms along +-x, palms down). Offsets are metres for a body whose head joint sits 1.45 m above
its ankles (1.70 m tall) and are scaled by the actual size, so the rule fits any SMPL-family
mesh (built-in, SMPL-X, ...) without knowing its topology.

The set follows the layout of the common 41-marker full-body mocap set (head, C7, T10,
clavicle, sternum, shoulders, upper arms, lateral elbows, forearms, both sides of the wrists,
hands, front and back of the pelvis, thighs, lateral knees, shins, ankles, heels, toes, fifth
metatarsals) with the single asymmetric back marker replaced by a symmetric pair, plus the head
top: 43 markers. Left markers come first in each pair; right ones are exact mirrors.
"""

from __future__ import annotations

import numpy as np

from mdvae_cli.errors import InputError

# joint indices in SMPL order (see data.SMPL_JOINT_NAMES)
_PELVIS, _SPINE2, _SPINE3, _NECK, _HEAD = 0, 6, 9, 12, 15
_L_HIP, _L_KNEE, _L_ANKLE, _L_FOOT = 1, 4, 7, 10
_L_SHOULDER, _L_ELBOW, _L_WRIST = 16, 18, 20
_R_ANKLE = 8

#: SMPL left-joint index -> right-joint index (and back); centre joints map to themselves.
_MIRROR_JOINT = {1: 2, 4: 5, 7: 8, 10: 11, 13: 14, 16: 17, 18: 19, 20: 21}
_MIRROR_JOINT.update({r: l for l, r in list(_MIRROR_JOINT.items())})

#: Head-joint height above the ankles of the reference (1.70 m) body the offsets are made for.
_REFERENCE_SIZE = 1.45

# (name, joint a, joint b, t along a->b, offset (left, up, forward) in metres). Only the 22
# body joints are used: SMPL-H and SMPL-X number their joints past 21 differently.
# Names starting with "L" get a mirrored "R" twin; the others lie on the midline.
_CENTRE = (
    ("ARIEL", _HEAD, _HEAD, 0.0, (0.0, 0.20, 0.01)),
)  # fmt: skip
_HEAD_PAIRS = (
    ("LFHD", _HEAD, _HEAD, 0.0, (0.055, 0.11, 0.10)),
    ("LBHD", _HEAD, _HEAD, 0.0, (0.055, 0.09, -0.10)),
)  # fmt: skip
_TRUNK_CENTRE = (
    ("C7", _NECK, _NECK, 0.0, (0.0, 0.0, -0.08)),
    ("T10", _SPINE2, _SPINE2, 0.0, (0.0, 0.0, -0.13)),
    ("CLAV", _NECK, _NECK, 0.0, (0.0, -0.06, 0.09)),
    ("STRN", _SPINE3, _SPINE3, 0.0, (0.0, -0.01, 0.14)),
)  # fmt: skip
_TRUNK_PAIRS = (
    ("LBAC", _SPINE3, _SPINE3, 0.0, (0.08, 0.03, -0.14)),
)  # fmt: skip
_ARM = (
    ("LSHO", _L_SHOULDER, _L_SHOULDER, 0.0, (0.0, 0.08, 0.0)),
    ("LUPA", _L_SHOULDER, _L_ELBOW, 0.5, (0.0, 0.04, -0.05)),
    ("LELB", _L_ELBOW, _L_ELBOW, 0.0, (0.0, 0.05, -0.02)),
    ("LFRM", _L_ELBOW, _L_WRIST, 0.5, (0.0, 0.05, 0.0)),
    ("LWRA", _L_WRIST, _L_WRIST, 0.0, (0.0, 0.0, 0.05)),
    ("LWRB", _L_WRIST, _L_WRIST, 0.0, (0.0, 0.0, -0.05)),
    ("LFIN", _L_ELBOW, _L_WRIST, 1.34, (0.0, 0.03, 0.0)),  # back of the hand, near knuckles
)  # fmt: skip
_PELVIS_PAIRS = (
    ("LFWT", _PELVIS, _PELVIS, 0.0, (0.10, 0.06, 0.13)),
    ("LBWT", _PELVIS, _PELVIS, 0.0, (0.07, 0.07, -0.13)),
)  # fmt: skip
_LEG = (
    ("LTHI", _L_HIP, _L_KNEE, 0.5, (0.09, 0.0, 0.02)),
    ("LKNE", _L_KNEE, _L_KNEE, 0.0, (0.07, 0.0, 0.0)),
    ("LSHN", _L_KNEE, _L_ANKLE, 0.5, (0.04, 0.0, 0.05)),
    ("LANK", _L_ANKLE, _L_ANKLE, 0.0, (0.05, 0.0, 0.0)),
    ("LHEE", _L_ANKLE, _L_ANKLE, 0.0, (0.0, -0.03, -0.09)),
    ("LTOE", _L_FOOT, _L_FOOT, 0.0, (0.0, 0.03, 0.06)),
    ("LMT5", _L_FOOT, _L_FOOT, 0.0, (0.06, 0.0, -0.01)),
)  # fmt: skip


def _mirror(spec: tuple) -> tuple:
    name, a, b, t, (x, y, z) = spec
    return ("R" + name[1:], _MIRROR_JOINT.get(a, a), _MIRROR_JOINT.get(b, b), t, (-x, y, z))


def _pairs(specs: tuple) -> list[tuple]:
    return [s for spec in specs for s in (spec, _mirror(spec))]


def _side_blocks(specs: tuple) -> list[tuple]:
    return list(specs) + [_mirror(s) for s in specs]


#: Marker rules in output order.
_MARKER_SPECS: tuple[tuple, ...] = tuple(
    list(_CENTRE)
    + _pairs(_HEAD_PAIRS)
    + list(_TRUNK_CENTRE)
    + _pairs(_TRUNK_PAIRS)
    + _side_blocks(_ARM)
    + _pairs(_PELVIS_PAIRS)
    + _side_blocks(_LEG)
)

#: The 43 marker names, in the order of :func:`place_markers`'s output.
MARKER_NAMES: tuple[str, ...] = tuple(spec[0] for spec in _MARKER_SPECS)

#: For each marker, the index of its left/right mirror twin (itself on the midline).
MARKER_MIRROR: tuple[int, ...] = tuple(
    MARKER_NAMES.index(("R" + n[1:]) if n[0] == "L" else ("L" + n[1:]) if n[0] == "R" else n)
    if n[0] in "LR"
    else i
    for i, n in enumerate(MARKER_NAMES)
)


def _size(joints: np.ndarray) -> float:
    """Height of the head joint above the ankles."""
    return float(joints[_HEAD, 1] - 0.5 * (joints[_L_ANKLE, 1] + joints[_R_ANKLE, 1]))


def marker_targets(joints: np.ndarray) -> np.ndarray:
    """Target points the markers snap to.  joints: (J >= 22, 3) rest joints -> (43, 3)"""
    joints = np.asarray(joints, dtype=np.float64)
    scale = _size(joints) / _REFERENCE_SIZE
    targets = np.empty((len(_MARKER_SPECS), 3))
    for i, (_, a, b, t, offset) in enumerate(_MARKER_SPECS):
        targets[i] = (1.0 - t) * joints[a] + t * joints[b] + scale * np.asarray(offset)
    return targets


def place_markers(vertices: np.ndarray, joints: np.ndarray) -> np.ndarray:
    """Pick the 43 marker vertices of a rest-pose mesh in SMPL's canonical frame.

    vertices: (V, 3) rest-pose vertices; joints: (J >= 22, 3) rest joints whose first 22 follow
    SMPL's order (SMPL, SMPL-H, SMPL-X and the built-in body all qualify).
    Returns (43,) int64 vertex ids, ordered as :data:`MARKER_NAMES`.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    joints = np.asarray(joints, dtype=np.float64)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) == 0:
        raise InputError(f"marker placement needs (V, 3) vertices, got {vertices.shape}")
    if joints.ndim != 2 or joints.shape[1] != 3 or len(joints) < 22:
        raise InputError(f"marker placement needs (J >= 22, 3) SMPL joints, got {joints.shape}")
    if not _size(joints) > 0:
        raise InputError("marker placement: head is not above the ankles (not SMPL's y-up frame)")
    targets = marker_targets(joints)
    d2 = ((targets[:, None, :] - vertices[None, :, :]) ** 2).sum(-1)
    return np.argmin(d2, axis=1).astype(np.int64)
