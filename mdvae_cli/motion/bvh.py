"""BVH motion files, and the skeleton + motion structure every mocap importer produces.

:class:`SourceMotion` is a BVH-shaped clip: joints with parents and rest offsets, per-frame local
rotations and a root trajectory, in metres. Both parsers (this module for BVH, ``asfamc`` for
Acclaim ASF/AMC) return it, and ``retarget`` turns it into an SMPL :class:`Motion`.

Conventions: every joint's rest frame is the world frame (offsets are world vectors in the rest
pose); global rotation ``G_j = G_parent @ R_j``; position ``p_j = p_parent + G_parent @ o_j``.
A BVH rotation with channels ``Zrotation Xrotation Yrotation`` is ``Rz @ Rx @ Ry`` (channels
listed outermost first).
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.motion.source import (
    CMU_UNIT,
    SourceMotion,
    check_angles,
    euler_to_rotmat,
    guess_length_unit,
    read_text,
    skeleton_height,
)

# --- BVH ---------------------------------------------------------------------------------------

_CHANNELS = {
    "xposition": ("t", "x"), "yposition": ("t", "y"), "zposition": ("t", "z"),
    "xrotation": ("r", "x"), "yrotation": ("r", "y"), "zrotation": ("r", "z"),
}  # fmt: skip

#: joint names that only the CMU "cmuconvert" BVH release has together
_CMUCONVERT_SIGNATURE = {"LHipJoint", "RHipJoint", "LowerBack", "LeftFingerBase"}


class _Tokens:
    def __init__(self, text: str, path: Path):
        self.items = re.sub(r"([{}])", r" \1 ", text).split()
        self.pos = 0
        self.path = path

    def next(self, what: str) -> str:
        if self.pos >= len(self.items):
            raise InputError(f"{self.path}: unexpected end of file (expected {what})")
        tok = self.items[self.pos]
        self.pos += 1
        return tok

    def expect(self, word: str) -> None:
        tok = self.next(repr(word))
        if tok.upper() != word.upper():
            raise InputError(f"{self.path}: malformed BVH: expected {word!r}, got {tok!r}")

    def number(self, what: str) -> float:
        tok = self.next(what)
        try:
            return float(tok)
        except ValueError:
            raise InputError(f"{self.path}: expected a number for {what}, got {tok!r}") from None


def _parse_hierarchy(tok: _Tokens):
    """-> names, parents, offsets (file units), channels [(joint, kind, axis)], end_site flags."""
    names: list[str] = []
    parents: list[int] = []
    offsets: list[tuple[float, float, float]] = []
    end_site: list[bool] = []
    channels: list[tuple[int, str, str]] = []

    def joint(parent: int, name: str, is_end: bool) -> None:
        index = len(names)
        names.append(name)
        parents.append(parent)
        end_site.append(is_end)
        tok.expect("{")
        tok.expect("OFFSET")
        offsets.append(tuple(tok.number(f"the OFFSET of {name}") for _ in range(3)))
        if not is_end:
            tok.expect("CHANNELS")
            count = tok.number(f"the channel count of {name}")
            if count != int(count) or not 0 <= count <= 6:
                raise InputError(f"{tok.path}: joint {name} has a bad channel count {count:g}")
            for _ in range(int(count)):
                ch = tok.next(f"a channel of {name}")
                if ch.lower() not in _CHANNELS:
                    raise InputError(f"{tok.path}: joint {name} has an unknown channel {ch!r}")
                channels.append((index, *_CHANNELS[ch.lower()]))
        while True:
            word = tok.next(f"'}}' closing {name}")
            if word == "}":
                return
            if is_end:
                raise InputError(f"{tok.path}: End Site of {names[parent]} has extra content")
            if word.upper() == "JOINT":
                joint(index, tok.next("a joint name"), False)
            elif word.upper() == "END":
                tok.expect("Site")
                joint(index, f"{name}_end", True)
            else:
                raise InputError(f"{tok.path}: unexpected {word!r} inside joint {name}")

    tok.expect("HIERARCHY")
    tok.expect("ROOT")
    joint(-1, tok.next("the root joint name"), False)
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise InputError(f"{tok.path}: joint name {dup!r} appears twice")
    return names, parents, np.array(offsets, dtype=np.float64), channels, end_site


def load_bvh(
    path: Path | str,
    scale: float | None = None,
    drop_first: bool | None = None,
    max_frames: int | None = None,
) -> SourceMotion:
    """Read a BVH file (``.bvh`` or ``.bvh.gz``) into a :class:`SourceMotion`.

    scale: metres per file unit; None guesses it from the skeleton's height (m, cm, mm, inches
        or CMU units) and uses CMU units for the cmuconvert release.
    drop_first: drop frame 0; None drops it for cmuconvert files (where it is an added T-pose).
    max_frames: read at most this many frames (after the drop), for quick looks and tests.

    Any channel order is accepted. Position channels on non-root joints replace the joint's
    offset (their mean over the clip; a note says when they move). Raises InputError with a
    one-line message for malformed files.
    """
    path = Path(path)
    text = read_text(path)
    split = re.search(r"^\s*MOTION\s*$", text, flags=re.MULTILINE | re.IGNORECASE)
    if not text.lstrip().upper().startswith("HIERARCHY"):
        raise InputError(f"{path}: not a BVH file (it does not start with HIERARCHY)")
    if split is None:
        raise InputError(f"{path}: no MOTION section")
    tok = _Tokens(text[: split.start()], path)
    names, parents, offsets, channels, end_site = _parse_hierarchy(tok)
    if tok.pos != len(tok.items):
        raise InputError(f"{path}: unexpected {tok.items[tok.pos]!r} after the root joint")

    motion = text[split.end() :]
    head = re.match(
        r"\s*Frames:\s*(\S+)\s+Frame\s+Time:\s*(\S+)", motion, flags=re.IGNORECASE
    )  # fmt: skip
    if head is None:
        raise InputError(f"{path}: MOTION section lacks 'Frames:' and 'Frame Time:' lines")
    try:
        n_frames, frame_time = int(head.group(1)), float(head.group(2))
    except ValueError:
        raise InputError(f"{path}: bad 'Frames:' or 'Frame Time:' value") from None
    if not (frame_time > 0 and math.isfinite(frame_time)):
        raise InputError(f"{path}: Frame Time must be > 0, got {head.group(2)}")
    C = len(channels)
    try:
        values = np.array(motion[head.end() :].split(), dtype=np.float64)
    except ValueError:
        raise InputError(f"{path}: non-numeric value in the motion data") from None
    if C == 0:
        raise InputError(f"{path}: the skeleton has no channels")
    if values.size % C:
        raise InputError(f"{path}: motion data has {values.size} values, not a multiple of "
                         f"the {C} channels (truncated or malformed line?)")  # fmt: skip
    found = values.size // C
    if found != n_frames:
        raise InputError(f"{path}: header says {n_frames} frames but the file holds {found}")
    if not np.all(np.isfinite(values)):
        raise InputError(f"{path}: motion data contains NaN or infinite values")
    data = values.reshape(found, C)

    notes: list[str] = []
    cmuconvert = _CMUCONVERT_SIGNATURE <= set(names)
    if drop_first is None:
        drop_first = cmuconvert
    if drop_first:
        data = data[1:]
    blank = ~np.any(data != 0.0, axis=1)  # every channel exactly 0: an exporter's empty frame
    if blank.all():
        raise InputError(f"{path}: every frame is blank (all channels 0)")
    first, last = int(np.argmin(blank)), len(blank) - int(np.argmin(blank[::-1]))
    if first or last < len(blank):
        notes.append(f"dropped {first + len(blank) - last} blank frame(s) at the start/end")
        data = data[first:last]
    if max_frames is not None:
        data = data[:max_frames]
    T = data.shape[0]
    if T < 1:
        raise InputError(f"{path}: no motion frames")

    info: dict = {"format": "bvh", "dropped_first_frame": bool(drop_first),
                  "cmuconvert": cmuconvert, "frames_in_file": n_frames}  # fmt: skip
    J = len(names)
    rest = offsets.copy()
    root_pos = np.zeros((T, 3)) + offsets[0]
    rotations = np.broadcast_to(np.eye(3), (T, J, 3, 3)).copy()
    for j in range(J):
        cols = [(c, kind, axis) for c, (jj, kind, axis) in enumerate(channels) if jj == j]
        rot = [(c, axis) for c, kind, axis in cols if kind == "r"]
        if rot:
            angles = np.deg2rad(data[:, [c for c, _ in rot]])
            check_angles(angles, f"joint {names[j]}", path)
            rotations[:, j] = euler_to_rotmat(angles, "".join(a for _, a in rot))
        for c, kind, axis in cols:
            if kind != "t":
                continue
            k = "xyz".index(axis)
            if j == 0:
                root_pos[:, k] = offsets[0, k] + data[:, c]
            else:
                rest[j, k] = data[:, c].mean()
                if np.ptp(data[:, c]) > 1e-3 * max(1.0, np.abs(data[:, c]).max()):
                    notes.append(f"joint {names[j]} has moving position channels; "
                                 "using their mean as its offset")  # fmt: skip

    height = skeleton_height(rest, np.array(parents))
    if scale is None:
        unit, scale = ("cmu", CMU_UNIT) if cmuconvert else guess_length_unit(height)
        info["unit"] = unit
    else:
        info["unit"] = f"{scale:g} m"
    info["metres_per_unit"] = float(scale)
    fps = 1.0 / frame_time
    if abs(fps - round(fps)) < 5e-3 * fps:
        fps = float(round(fps))
    info["fps_in_file"] = fps
    rest[0] = 0.0
    return SourceMotion(
        names=tuple(names),
        parents=np.array(parents, dtype=np.int64),
        offsets=rest * scale,
        rotations=rotations,
        root_positions=root_pos * scale,
        fps=fps,
        end_site=np.array(end_site, dtype=bool),
        info=info,
        notes=notes,
    ).check_distances(path)
