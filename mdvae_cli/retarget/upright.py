"""Which way a source skeleton stands: up judged from the motion, a rest pose that can be read,
and the length unit from the body's stature.

Files disagree with their own rest pose: some rest poses lie sideways (each OFFSET along its
bone's local axis, so the rest skeleton is a line), some are y-up while the motion is z-up. The
functions here make a :class:`SourceMotion` that the retarget can read:

* :func:`motion_up` - the world's up axis from the posed frames (pelvis -> head);
* :func:`canonical_axes` - the rest pose's axes (read off the rest pose) and the world's: the
  rest pose's, or the motion's up where the file's own floor confirms it, both as signed axis
  permutations to SMPL's frame (:func:`to_smpl_axes` turns a take with them);
* :func:`rerest` / :func:`upright_rest` - a rest pose that is no T-pose nor upright is replaced
  by the most upright frame of the take (world positions unchanged);
* :func:`stature_unit` - for BVH files whose unit was guessed, the unit that gives the body a
  plausible stature from its bone lengths (legs and trunk), not from the rest pose's extent.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.formats.bvh_rotations import TurnedRotations
from mdvae_cli.formats.source import BVH_UNIT_GUESSES, SourceMotion, guess_length_unit
from mdvae_cli.retarget.joint_map import JointMap, canonical_rotation, canonicalise

#: hip -> knee -> ankle plus pelvis -> head along the spine on SMPL's mean body, whose
#: stature is 1.70 m (built-in body, measured once)
_CHAIN_AT_170 = 1.393

#: the stature units are judged against: below an adult's, because when two units are both
#: possible (inches and CMU units differ 2.2x) a 1.05 m child is likelier than a 2.3 m giant
_STATURE = 1.5

#: at most this many frames are looked at to judge up and choose a rest frame
_SAMPLE = 400


def _sample(T: int) -> np.ndarray:
    return np.unique(np.linspace(0, T - 1, min(T, _SAMPLE)).round().astype(int))


def _positions(src: SourceMotion, frames: np.ndarray) -> np.ndarray:
    """World joint positions of some frames.  -> (F, J, 3)"""
    local = None if src.local_positions is None else src.local_positions[frames]
    sub = replace(src, rotations=src.rotations[frames], root_positions=src.root_positions[frames],
                  local_positions=local, layout=None)  # fmt: skip
    return sub.forward_kinematics()[1]


def _body_axes(src: SourceMotion, jmap: JointMap) -> np.ndarray:
    """Unit pelvis -> head directions of the sampled frames (world axes).  -> (F, 3)"""
    P = _positions(src, _sample(src.num_frames))
    up = P[:, jmap.anchor["head"]] - P[:, jmap.anchor["pelvis"]]
    return up / np.maximum(np.linalg.norm(up, axis=1, keepdims=True), 1e-12)


def motion_up(src: SourceMotion, jmap: JointMap) -> np.ndarray:
    """Mean unit pelvis -> head direction over the take (world axes): where the body points
    on average, not by itself the world's up (a take may be done lying).  -> (3,)"""
    return _body_axes(src, jmap).mean(0)


#: a take stands along its rest pose's up when this share of its frames do (pelvis -> head
#: within 45 degrees of it): one that bends to the floor or lies down for the rest of it
_STANDS = 0.1


def _axes(up: np.ndarray, left: np.ndarray) -> np.ndarray | None:
    """Signed axis permutation with ``up`` -> +y and ``left`` -> +x (None if degenerate)."""
    iu = int(np.argmax(np.abs(up)))
    left = left.copy()
    left[iu] = 0.0
    il = int(np.argmax(np.abs(left)))
    if np.linalg.norm(left) < 1e-9 or il == iu or abs(up[iu]) < 1e-9:
        return None
    S = np.zeros((3, 3))
    S[1, iu] = np.sign(up[iu])
    S[0, il] = np.sign(left[il])
    S[2] = np.cross(S[0], S[1])
    return S


def rest_is_upright(src: SourceMotion, jmap: JointMap) -> bool:
    """Whether the rest pose stands: the legs point away from the head, the hips lie across."""
    rest = src.rest_positions()
    a = jmap.anchor
    up = rest[a["head"]] - rest[a["pelvis"]]
    across = rest[a["left_hip"]] - rest[a["right_hip"]]
    legs = sum(rest[a[f"{s}_ankle"]] - rest[a[f"{s}_hip"]] for s in ("left", "right"))

    def cos(u, v):
        return float(u @ v / max(np.linalg.norm(u) * np.linalg.norm(v), 1e-12))

    return cos(up, -legs) > 0.8 and abs(cos(up, across)) < 0.5


def ground_level(src: SourceMotion, jmap: JointMap, up: np.ndarray) -> float:
    """Where the body stands along the unit axis ``up``, from the world's origin: the median
    over frames of the lowest joint's height, in leg + trunk lengths (:func:`chain_length`)."""
    P = _positions(src, _sample(src.num_frames))
    return float(np.median((P @ up).min(axis=1))) / max(chain_length(src, jmap), 1e-12)


#: a body stands on the world's floor along an axis when its lowest joint is this close to
#: the origin's level (leg + trunk lengths, about 14 cm)
_ON_FLOOR = 0.1


def canonical_axes(src: SourceMotion, jmap: JointMap) -> tuple[np.ndarray, np.ndarray, str | None]:
    """(S_rest, S_motion, note): the signed axis permutations taking the rest pose's axes and
    the world's to SMPL's (up +y, the body's left +x), and a note when they disagree.

    Up is the rest pose's (the file's convention). The world stands on another axis only when
    the file's own world says so: the body, upright along that axis on average, stands there
    on the floor through the origin (its lowest joint within :data:`_ON_FLOOR` of the origin's
    level) - a y-up rest pose in a z-up scene (standing is likelier than lying when both fit).
    Otherwise a body that is not upright in the rest pose's axes (a take done lying, upside
    down) is kept as it lies, with a note; none when it stands along that up in a share
    :data:`_STANDS` of its frames (a take that bends to the floor or lies down)."""
    S_rest = canonical_rotation(src, jmap)
    up = motion_up(src, jmap)
    iu = int(np.argmax(np.abs(up)))
    if S_rest[1, iu] == np.sign(up[iu]):
        return S_rest, S_rest, None
    rest = src.rest_positions()
    left = rest[jmap.anchor["left_hip"]] - rest[jmap.anchor["right_hip"]]
    S_move = _axes(up, S_rest.T @ np.array([1.0, 0.0, 0.0]))
    if S_move is None:
        S_move = _axes(up, left)
    if S_move is None:
        raise InputError("cannot tell which way is up in the motion")
    if abs(ground_level(src, jmap, S_move[1])) <= _ON_FLOOR:
        return S_rest, S_move, None
    if np.mean(_body_axes(src, jmap) @ S_rest[1] > np.sqrt(0.5)) >= _STANDS:
        return S_rest, S_rest, None  # it stands up in its rest pose's axes part of the take

    def name(u: np.ndarray) -> str:
        k = int(np.argmax(np.abs(u)))
        return ("+" if u[k] > 0 else "-") + "xyz"[k]

    note = (f"the body is upright along {name(S_move[1])}, not along its rest pose's up "
            f"{name(S_rest[1])}: kept as it lies, not turned upright")  # fmt: skip
    return S_rest, S_rest, note


def to_smpl_axes(src: SourceMotion, jmap: JointMap) -> tuple[SourceMotion, np.ndarray]:
    """``src`` turned into SMPL's axes (:func:`canonical_axes`, with its note) and the world's
    turn S_motion (3, 3)."""
    S_rest, S_world, note = canonical_axes(src, jmap)
    out = canonicalise(src, S_rest, S_world)
    if note is not None:
        out = replace(out, info=dict(out.info), notes=[*out.notes, note])
    return out, S_world


def rerest(src: SourceMotion, frame: int) -> SourceMotion:
    """The same motion on a rest pose equal to frame ``frame``'s pose (every joint's rest frame
    becomes its world frame there; world positions and rotations of the take unchanged)."""
    local = None if src.local_positions is None else src.local_positions[frame : frame + 1]
    one = replace(src, rotations=src.rotations[frame : frame + 1],
                  root_positions=src.root_positions[frame : frame + 1], local_positions=local,
                  layout=None)  # fmt: skip
    B = one.forward_kinematics()[0][0]  # (J, 3, 3)
    parents = src.parents
    Bp = B[np.maximum(parents, 0)]
    Bp[0] = np.eye(3)
    offsets = np.einsum("jab,jb->ja", Bp, src.offsets)
    rot = TurnedRotations(src.rotations, Bp, B)
    moving = None
    if src.local_positions is not None:
        moving = np.einsum("jab,tjb->tja", Bp, src.local_positions)
    return replace(src, offsets=offsets, rotations=rot, local_positions=moving,
                   info=dict(src.info), notes=list(src.notes))  # fmt: skip


def _rest_frame(src: SourceMotion, jmap: JointMap) -> int:
    """The frame whose legs are straightest below an upright trunk."""
    frames = _sample(src.num_frames)
    P = _positions(src, frames)
    a = jmap.anchor
    up = motion_up(src, jmap)
    up = up / max(np.linalg.norm(up), 1e-12)
    score = np.zeros(len(frames))
    for s in ("left", "right"):
        leg = P[:, a[f"{s}_hip"]] - P[:, a[f"{s}_ankle"]]
        score += leg @ up / np.maximum(np.linalg.norm(leg, axis=1), 1e-12)
    trunk = P[:, a["head"]] - P[:, a["pelvis"]]
    score += trunk @ up / np.maximum(np.linalg.norm(trunk, axis=1), 1e-12)
    return int(frames[int(np.argmax(score))])


def upright_rest(src: SourceMotion, jmap: JointMap) -> SourceMotion:
    """``src`` unchanged when its rest pose stands, else re-rested on its most upright frame
    (with a note)."""
    if rest_is_upright(src, jmap):
        return src
    frame = _rest_frame(src, jmap)
    out = rerest(src, frame)
    out.notes.append(f"the rest pose does not stand upright; frame {frame} used as the rest pose")
    return out


def chain_length(src: SourceMotion, jmap: JointMap) -> float:
    """Mean leg (hip -> knee -> ankle) plus the spine path (pelvis -> head), in src units."""
    rest = src.rest_positions()
    a = jmap.anchor

    def path(top: int, bottom: int) -> float:
        total, j = 0.0, bottom
        while j != top and j >= 0:
            total += float(np.linalg.norm(src.offsets[j]))
            j = int(src.parents[j])
        return total

    legs = [
        np.linalg.norm(rest[a[f"{s}_knee"]] - rest[a[f"{s}_hip"]])
        + np.linalg.norm(rest[a[f"{s}_ankle"]] - rest[a[f"{s}_knee"]])
        for s in ("left", "right")
    ]
    return float(np.mean(legs)) + path(a["pelvis"], a["head"])


def stature_unit(src: SourceMotion, jmap: JointMap) -> SourceMotion:
    """For a BVH file whose unit was guessed from its rest pose's extent, the unit that gives
    its body a plausible stature (closest to 1.5 m) from bone lengths instead; ``src`` rescaled when
    that differs (with a note)."""
    if src.info.get("format") != "bvh" or not src.info.get("unit_guessed"):
        return src
    scale = src.info["metres_per_unit"]
    unit, new = guess_length_unit(chain_length(src, jmap) / scale, BVH_UNIT_GUESSES,
                                  target=_CHAIN_AT_170 * _STATURE / 1.7)  # fmt: skip
    if unit == src.info.get("unit"):
        return src
    k = new / scale
    info = {**src.info, "unit": unit, "metres_per_unit": float(new)}
    if src.layout is not None:
        src.layout.metres_per_unit = float(new)
    local = None if src.local_positions is None else src.local_positions * k
    out = replace(src, offsets=src.offsets * k, root_positions=src.root_positions * k,
                  local_positions=local, info=info, notes=list(src.notes))  # fmt: skip
    out.notes.append(f"length unit {unit} (from the body's bone lengths)")
    return out
