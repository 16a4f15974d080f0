"""Whether a rig's "left" joints are the body's left: read off its motion, not its names.

A rig named mirror-wise (the joints named ``Left...`` on the body's right, as some video-to-BVH
tools and hand-made rigs write them) still fits the body to a few millimetres, but as a body
walking backwards on knees that bend the wrong way. Knees bend forward and toes point forward,
so in the frame the names give (left from the named hips, up from pelvis to head, forward =
left x up) a mirrored rig's knees and toes point backwards.

Plain numpy, no torch and no files: used by :mod:`mdvae_cli.retarget.joint_map`.
"""

from __future__ import annotations

import numpy as np

from mdvae_cli.formats.source import SourceMotion

#: frames looked at (evenly spread over the take)
_FRAMES = 240
#: votes that exchange the sides: toes below _TOES_BACK (a mean cosine) while the knees do not
#: bulge forward by _KNEES_FORWARD, or without toes, knees below _KNEES_BACK (the knee's mean
#: forward bulge over the leg's length; a walk's bent knee: about +0.05)
_TOES_BACK, _KNEES_FORWARD, _KNEES_BACK = -0.3, 0.01, -0.05


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def side_votes(P: np.ndarray, anchor: dict[str, int]) -> tuple[float | None, float]:
    """How far the toes and knees point forward in the named frame.

    P: (T, J, 3) joint positions; anchor: SMPL joint name -> joint. -> (toes: mean cosine of
    the ankle->toe direction with forward, None without toe joints; knees: mean forward bulge
    of the knee off the hip-ankle line over the leg's length)"""
    up = _unit(P[:, anchor["head"]] - P[:, anchor["pelvis"]])
    left = P[:, anchor["left_hip"]] - P[:, anchor["right_hip"]]
    forward = _unit(np.cross(left, up))
    toes, knees = [], []
    for s in ("left", "right"):
        hip, knee, ankle = (P[:, anchor[f"{s}_{k}"]] for k in ("hip", "knee", "ankle"))
        leg = np.linalg.norm(ankle - hip, axis=-1) + 1e-12
        knees.append(((knee - (hip + ankle) / 2) * forward).sum(-1) / leg)
        if f"{s}_foot" in anchor and anchor[f"{s}_foot"] != anchor[f"{s}_ankle"]:
            toes.append((_unit(P[:, anchor[f"{s}_foot"]] - ankle) * forward).sum(-1))
    return (float(np.mean(toes)) if toes else None), float(np.mean(knees))


def named_sides_mirrored(src: SourceMotion, anchor: dict[str, int]) -> bool:
    """True when the joints named left are the body's right (toes and knees point backwards).

    Toes decide when the rig has them (the knees must not say forward); without toes, the
    knees alone. A take too still to tell keeps its names."""
    step = max(1, src.num_frames // _FRAMES)
    _, P = src.forward_kinematics(slice(None, None, step))
    toes, knees = side_votes(np.asarray(P), anchor)
    if toes is not None:
        return toes < _TOES_BACK and knees < _KNEES_FORWARD
    return knees < _KNEES_BACK


def exchange_sides(anchor: dict[str, int]) -> dict[str, int]:
    """``left_*`` <-> ``right_*`` anchors; others as they were."""
    out = {}
    for name, j in anchor.items():
        if name.startswith("left_"):
            name = "right_" + name[5:]
        elif name.startswith("right_"):
            name = "left_" + name[6:]
        out[name] = j
    return out
