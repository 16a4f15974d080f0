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
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation
from pathlib import Path

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.formats.bvh_hierarchy import Tokens, parse_hierarchy
from mdvae_cli.formats.bvh_rotations import ChannelRotations
from mdvae_cli.formats.bvh_write import line_ending
from mdvae_cli.formats.source import (
    BVH_UNIT_GUESSES,
    CMU_UNIT,
    SourceMotion,
    check_angles,
    guess_length_unit,
    read_text_encoded,
    skeleton_height,
)

# --- BVH ---------------------------------------------------------------------------------------

#: joint names that only the CMU "cmuconvert" BVH release has together
_CMUCONVERT_SIGNATURE = {"LHipJoint", "RHipJoint", "LowerBack", "LeftFingerBase"}


def _is_added_pose(channels, row) -> bool:
    """Whether a frame is a pose set by hand, as the cmuconvert release's added T-pose frame 0
    (every rotation a whole number of degrees: 0, -21, 8, ...), not a captured one.

    channels: (C,) (joint, kind, axis); row: (C,) one frame's values.
    """
    angles = np.array([v for (_, kind, _), v in zip(channels, row, strict=True) if kind == "r"])
    return bool(np.all(np.abs(angles - np.round(angles)) < 1e-6))


@dataclass
class BvhLayout:
    """What it takes to write a BVH file again on its own skeleton.

    header: the file's text up to and including the ``MOTION`` line and its line ending,
    verbatim (hierarchy, names, offsets, channel layout). channels: (joint, kind "t"/"r",
    axis) per column.
    data: (F, C) every frame of the file as read. rows: (T,) the file rows the SourceMotion's
    frames came from (a dropped first frame or blank frames are written back unchanged).
    frame_time: the ``Frame Time`` as written. offsets: (J, 3) the OFFSETs, file units.
    metres_per_unit: the scale the SourceMotion is in. world_channels: joints whose position
    channels hold world positions (ignored on reading, rewritten on writing).
    moving: joints other than the root whose position channels move the joint.
    encoding: the one the file's bytes were read with
    (``source.decode_text``: ``"utf-8"``, ``"utf-8-sig"`` or ``"latin-1"``), to write its
    header back byte for byte. labels: the ``Frames:`` and ``Frame Time:`` words as the file
    spells them, with the spaces or tab after them (``"frame time:\t"``).
    """

    header: str
    channels: list[tuple[int, str, str]]
    data: np.ndarray
    rows: np.ndarray
    frame_time: str
    offsets: np.ndarray
    metres_per_unit: float
    world_channels: tuple[int, ...] = ()
    moving: tuple[int, ...] = ()
    encoding: str = "utf-8"
    labels: tuple[str, str] = ("Frames: ", "Frame Time: ")

    def joint_columns(self, j: int, kind: str) -> list[tuple[int, str]]:
        """(column, axis) of joint j's channels of one kind ("t" or "r"), in file order."""
        return [(c, axis) for c, (jj, k, axis) in enumerate(self.channels) if jj == j and k == kind]


def _positions(data, cols, offset) -> np.ndarray:
    """A joint's translation per frame: its OFFSET with each position channel replacing its
    component.  -> (T, 3)"""
    t = np.tile(offset, (data.shape[0], 1))
    for c, axis in cols:
        t[:, "xyz".index(axis)] = data[:, c]
    return t


def _split_positions(names, parents, offsets, layout, data, rotations, root_pos, notes):
    """Sort the non-root joints with position channels: fixed (their value becomes the
    offset), world positions (written by some exporters; ignored) or moving local ones
    (kept per frame).  -> rest offsets (J, 3), local positions (T, J, 3) or None

    Joints' world poses are made only when a joint's position channels move (most files have
    none, and on a 30-minute 120 Hz take they would be 600 MB), and then only down to the
    deepest such joint's parent."""
    rest = offsets.copy()
    J, T = len(names), data.shape[0]
    varying: dict[int, np.ndarray] = {}
    for j in range(1, J):
        cols = layout.joint_columns(j, "t")
        if cols:
            t = _positions(data, cols, offsets[j])
            if np.ptp(t, axis=0).max() <= 1e-3 * max(1.0, np.abs(t).max()):
                rest[j] = t.mean(0)
            else:
                varying[j] = t
    if not varying:
        return rest, None
    rotations = np.asarray(rotations)
    local = np.tile(rest, (T, 1, 1))
    G = np.empty((T, max(varying), 3, 3))
    P = np.empty((T, max(varying), 3))
    world, moving = [], []
    for j in range(max(varying) + 1):
        p = parents[j]
        if j in varying:
            t = varying[j]
            at_offset = P[:, p] + G[:, p] @ offsets[j]
            far = np.median(np.linalg.norm(t - offsets[j], axis=1))
            off_world = np.median(np.linalg.norm(t - at_offset, axis=1))
            if far > 0.5 * max(np.linalg.norm(offsets[j]), 1e-9) and off_world < 0.2 * far:
                world.append(j)
                notes.append(f"joint {names[j]}'s position channels hold world positions; "
                             "its OFFSET is used")  # fmt: skip
            else:
                moving.append(j)
                local[:, j] = t
        if j < G.shape[1]:
            G[:, j] = rotations[:, j] if p < 0 else G[:, p] @ rotations[:, j]
            P[:, j] = root_pos if p < 0 else P[:, p] + (G[:, p] @ local[:, j, :, None])[..., 0]
    layout.world_channels, layout.moving = tuple(world), tuple(moving)
    return rest, (local if moving else None)


_SPACE = re.compile(r"\s")
#: the MOTION line, whatever the line endings (LF, CR LF, CR alone)
_MOTION_LINE = re.compile(r"(?:\A|(?<=[\r\n]))[ \t]*MOTION[ \t]*(?=[\r\n]|\Z)", re.IGNORECASE)
#: characters of motion data parsed at a time
_CHUNK = 4 << 20


def _numbers(text: str, start: int, expect: int) -> tuple[np.ndarray, int]:
    """The first ``expect`` whitespace-separated numbers of ``text[start:]`` and how many it
    holds, parsed ``_CHUNK`` characters at a time into one array (a list of every word at
    once took up to 60 bytes a number: 2.9 GB for a 230 MB take). ValueError for a word that
    is no number."""
    expect = max(0, min(expect, (len(text) - start) // 2 + 1))  # a number and a space each
    out, count = np.empty(expect), 0
    while start < len(text):
        cut = _SPACE.search(text, start + _CHUNK)
        end = cut.start() if cut else len(text)
        part = _parse_floats(text[start:end])
        room = max(0, min(part.size, expect - count))
        out[count : count + room] = part[:room]
        count, start = count + part.size, end
    return out[: min(count, expect)], count


def _parse_floats(text: str) -> np.ndarray:
    """The whitespace-separated numbers of ``text`` (numpy's C parser: no list of words);
    ValueError for a word that is no number."""
    if not text.strip():  # numpy reads a text of nothing but whitespace as [-1]
        return np.empty(0)
    return np.fromstring(text, sep=" ")


def rate_of_frame_time(text: str) -> float:
    """The frame rate a ``Frame Time`` as written means: ``1 / Frame Time``, or the whole rate
    n when the text is 1/n printed to its own digits (rounded or cut off: ``0.0333333`` and
    ``0.008333`` are 30 and 120, ``0.01668335`` is 59.94, not 60) within 0.5 % of n; other
    rates of 1 Hz or more to as many significant digits as the Frame Time has (at least 4)."""
    seconds = float(text)
    fps = 1.0 / seconds
    n = round(fps)
    try:
        digits = Decimal(text.strip()).as_tuple()
        last = 10.0**digits.exponent  # one unit in the last digit written
    except (InvalidOperation, TypeError):
        return fps
    if n >= 1 and abs(fps - n) < 5e-3 * fps and abs(seconds - 1.0 / n) <= last * (1 + 1e-9):
        return float(n)
    if fps < 1.0:  # no frame rate (refused by the reader's callers): as written
        return fps
    return float(f"{fps:.{max(len(digits.digits), 4)}g}")  # as many digits as the file gave


def _missing_motion_lines(text: str, start: int) -> str:
    """What a MOTION section whose first lines are not ``Frames:`` then ``Frame Time:`` lacks,
    in words (the first 200 characters after ``start`` read)."""
    lines = text[start : start + 200].lstrip().splitlines()[:2]
    frames = bool(lines) and lines[0].strip().lower().startswith("frames:")
    time_line = re.compile(r"\s*frame\s+time:", re.IGNORECASE)
    timed = any(time_line.match(line) for line in lines)
    if frames and not timed:
        return "MOTION section lacks its 'Frame Time:' line (after 'Frames:')"
    if timed and not frames:
        return "MOTION section lacks its 'Frames:' line (before 'Frame Time:')"
    return "MOTION section lacks 'Frames:' and 'Frame Time:' lines"


def load_bvh(
    path: Path | str,
    scale: float | None = None,
    drop_first: bool | None = None,
    max_frames: int | None = None,
) -> SourceMotion:
    """Read a BVH file (``.bvh`` or ``.bvh.gz``) into a :class:`SourceMotion`.

    scale: metres per file unit; None guesses it from the skeleton's height (m, cm, mm, inches
        or CMU units) and uses CMU units for the cmuconvert release.
    drop_first: drop frame 0; None drops it for cmuconvert files whose frame 0 is the T-pose
        that release adds (a take trimmed or resampled on that rig keeps its frame 0).
    max_frames: read at most this many frames (after the drop), for quick looks and tests.

    The file may be gzipped (by name, any case, or by its first bytes), UTF-8 or not (read as
    latin-1: ``layout.encoding`` says which) and end its lines in LF, CR LF or CR; joint names
    may hold spaces (``formats.bvh_hierarchy``). Any channel order is accepted. Position
    channels on non-root joints replace the joint's offset (their mean over the clip; a note
    says when they move). Raises InputError with a one-line message for malformed files.
    """
    path = Path(path)
    text, encoding = read_text_encoded(path)
    split = _MOTION_LINE.search(text)
    if not text.lstrip().upper().startswith("HIERARCHY"):
        raise InputError(f"{path}: not a BVH file (it does not start with HIERARCHY)")
    if split is None:
        raise InputError(f"{path}: no MOTION section")
    tok = Tokens(text[: split.start()], path)
    names, parents, offsets, channels, end_site = parse_hierarchy(tok)
    if tok.pos != len(tok.items):
        raise InputError(f"{path}: unexpected {tok.items[tok.pos]!r} after the root joint")

    # matched and parsed in place: a copy of a long take's motion text is as large as the file
    head = re.compile(r"\s*(Frames:[ \t]*)(\S+)\s+(Frame\s+Time:[ \t]*)(\S+)", re.IGNORECASE).match(
        text, split.end()
    )
    if head is None:
        raise InputError(f"{path}: {_missing_motion_lines(text, split.end())}")
    try:
        n_frames, frame_time = int(head.group(2)), float(head.group(4))
    except ValueError:
        raise InputError(f"{path}: bad 'Frames:' or 'Frame Time:' value") from None
    if not (frame_time > 0 and math.isfinite(frame_time)):
        raise InputError(f"{path}: Frame Time must be > 0, got {head.group(4)}")
    C = len(channels)
    if C == 0:
        raise InputError(f"{path}: the skeleton has no channels")
    try:
        values, count = _numbers(text, head.end(), n_frames * C)
    except ValueError:
        raise InputError(f"{path}: non-numeric value in the motion data") from None
    header = text[: split.end()].rstrip() + line_ending(text[: split.end()])
    frame_text, labels = head.group(4), (head.group(1), head.group(3))
    del text, head, split  # the matches hold the text too
    if count % C:
        raise InputError(f"{path}: motion data has {count} values, not a multiple of "
                         f"the {C} channels (truncated or malformed line?)")  # fmt: skip
    found = count // C
    if found != n_frames:
        raise InputError(f"{path}: header says {n_frames} frames but the file holds {found}")
    data = values.reshape(found, C)
    if not np.all(np.isfinite(values)):
        t, c = np.argwhere(~np.isfinite(data))[0]
        joint, kind, axis = channels[c]
        what = f"{axis.upper()}{'rotation' if kind == 'r' else 'position'}"
        raise InputError(
            f"{path}: motion data holds NaN or infinite values (first at frame {t + 1}, "
            f"{names[joint]} {what}); BVH has no missing values: a stretch written as its "
            "joint's last good values (1/3 s or more) or a frame of zeros is read as a hole "
            "with --missing frozen,zeros"
        )
    layout = BvhLayout(header=header, channels=channels, data=data,
                       rows=np.arange(found), frame_time=frame_text, offsets=offsets,
                       metres_per_unit=1.0, encoding=encoding, labels=labels)  # fmt: skip

    notes: list[str] = []
    cmuconvert = _CMUCONVERT_SIGNATURE <= set(names)
    if drop_first is None:
        drop_first = cmuconvert and _is_added_pose(channels, data[0])
    rows = layout.rows
    if drop_first:
        data, rows = data[1:], rows[1:]
    if data.shape[0] == 0:
        raise InputError(f"{path}: no motion frames")
    blank = ~np.any(data != 0.0, axis=1)  # every channel exactly 0: an exporter's empty frame
    if blank.all():
        raise InputError(f"{path}: every frame is blank (all channels 0)")
    first, last = int(np.argmin(blank)), len(blank) - int(np.argmin(blank[::-1]))
    if first or last < len(blank):
        notes.append(f"dropped {first + len(blank) - last} blank frame(s) at the start/end")
        data, rows = data[first:last], rows[first:last]
    if max_frames is not None:
        data, rows = data[:max_frames], rows[:max_frames]
    layout.rows = rows
    T = data.shape[0]
    if T < 1:
        raise InputError(f"{path}: no motion frames")

    info: dict = {"format": "bvh", "dropped_first_frame": bool(drop_first),
                  "cmuconvert": cmuconvert, "frames_in_file": n_frames}  # fmt: skip
    J = len(names)
    root_pos = _positions(data, layout.joint_columns(0, "t"), np.zeros(3)) + offsets[0]
    for j in range(J):
        rot = layout.joint_columns(j, "r")
        if rot:
            check_angles(np.deg2rad(data[:, [c for c, _ in rot]]), f"joint {names[j]}", path)
    # made from the channels a chunk of frames at a time when asked (the retarget's solve,
    # the way back): held whole, a 30-minute 120 Hz take's were 342 MB at the peak
    rotations = ChannelRotations(layout, J)
    rest, local = _split_positions(names, parents, offsets, layout, data, rotations, root_pos,
                                   notes)  # fmt: skip
    for j in layout.moving:
        notes.append(f"joint {names[j]} has moving position channels (kept per frame)")

    height = skeleton_height(rest, np.array(parents))
    if scale is None:
        guess = guess_length_unit(height, BVH_UNIT_GUESSES)
        unit, scale = ("cmu", CMU_UNIT) if cmuconvert else guess
        info["unit"] = unit
        info["unit_guessed"] = not cmuconvert
    else:
        info["unit"] = f"{scale:g} m"
    info["metres_per_unit"] = layout.metres_per_unit = float(scale)
    fps = info["fps_in_file"] = rate_of_frame_time(frame_text)
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
        local_positions=None if local is None else local * scale,
        layout=layout,
    ).check_distances(path)
