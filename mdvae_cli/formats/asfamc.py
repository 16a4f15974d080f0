"""Acclaim motion files (``.amc``) on their ``.asf`` skeleton (``formats.asf``), as used by the
CMU mocap database.

Conventions (Acclaim, as CMU writes them):

* An AMC ``:DEGREES``/``:RADIANS`` line overrides the skeleton's angle unit.
* AMC values for ``dof rx ry rz`` form ``M = Rz Ry Rx`` (applied in the listed order), in the
  local frame: the bone's rotation in world-aligned axes is ``C M C^T``.

:func:`load_amc` returns a :class:`SourceMotion` whose joints are the root, every bone (placed at
the bone's start) and an ``<bone>_end`` tip for each leaf bone. It keeps the file's
:class:`AmcLayout` (header, frame numbers, each frame's bones and values as written) so that
``formats.amc_write`` can write the take again on its own skeleton.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.formats.amc_frames import apply_plan, arrange_frames
from mdvae_cli.formats.asf import (
    AsfSkeleton,
    axis_frame,
    load_asf,
)
from mdvae_cli.formats.source import (
    SourceMotion,
    check_angles,
    read_text,
)
from mdvae_cli.geometry.euler import euler_to_rotmat


@dataclass
class AmcLayout:
    """What it takes to write an AMC file again on its own skeleton.

    header: the text before the first frame number, verbatim (``:FULLY-SPECIFIED``,
    ``:DEGREES``, comments). frames: (F,) frame numbers as written. bones: (F,) the bones each
    frame lists, in its order. values: bone -> (F, n) every frame as read (a frame that leaves
    a bone out holds its previous value); tokens: bone -> (F, n) those values as written
    (object array of str; None where the frame left the bone out). rows: (T,) the frames the
    SourceMotion holds (a cut-off last frame, or frames past ``max_frames``, are written back
    unchanged). degrees: the angle unit of the values. skeleton: the ASF. metres_per_unit:
    the scale the SourceMotion is in. added: (F,) bool, True for a frame the file lacks (a
    missing frame number, ``formats.amc_frames``; its values are placeholders, its tokens ""
    and its number ``str``); None: none.

    The frames are in the order of their numbers, a row for each number missing inside the
    take; a cut-off last frame comes last.
    """

    header: str
    frames: list[str]
    bones: list[tuple[str, ...]]
    values: dict[str, np.ndarray]
    tokens: dict[str, np.ndarray]
    rows: np.ndarray
    degrees: bool
    skeleton: AsfSkeleton
    metres_per_unit: float
    newline: str = "\n"
    added: np.ndarray | None = None

    def gaps(self) -> np.ndarray:
        """(T,) bool, True for the frames of the SourceMotion the file lacks (holes)."""
        F = len(self.frames)
        added = np.zeros(F, bool) if self.added is None else np.asarray(self.added, bool)
        return added[self.rows]

    def dofs(self, name: str) -> tuple[str, ...]:
        """The AMC channels of ``name`` ("root" or a bone), e.g. ("rx", "rz")."""
        sk = self.skeleton
        return sk.root_order if name == "root" else sk.bones[name].dofs

    def frame(self, name: str) -> np.ndarray:
        """The local frame C of ``name`` (its ``axis``; the root's ``orientation``).  (3, 3)"""
        sk = self.skeleton
        if name == "root":
            return axis_frame(sk.root_orientation, sk.root_axis_order, sk.degrees)
        bone = sk.bones[name]
        return axis_frame(bone.axis, bone.axis_order, sk.degrees)


def rotation_columns(dofs: tuple[str, ...]) -> list[tuple[int, str]]:
    """(column, axis) of the rotation channels among ``dofs``, in listed order."""
    return [(i, d[1]) for i, d in enumerate(dofs) if d.startswith("r")]


def dof_rotation(C: np.ndarray, radians: np.ndarray, axes: str) -> np.ndarray:
    """A bone's rotation in world-aligned axes, ``C M C^T``, with ``M`` the turns about its
    ``axes`` (listed order, first applied first: ``rx ry rz`` -> ``Rz Ry Rx``).
    C: (3, 3); radians: (T, k) in listed order -> (T, 3, 3)"""
    M = euler_to_rotmat(radians[:, ::-1], axes[::-1])
    return C @ M @ C.T


def _read_amc_values(text: str, layout: dict[str, int], path: str):
    """Frame values per bone: {name: (T, n)}, the angle unit if the header says one, notes on
    frames that lacked bones, the :class:`AmcLayout` fields (header, frames, bones,
    tokens, frames read) and the step of the frame numbers (``amc_frames.even_step``).

    A fast path handles files whose frames all list the same bones in the same order (CMU);
    other files go through a line-by-line reader.
    """
    lines = text.splitlines()
    degrees = None
    start = 0
    for i, ln in enumerate(lines):
        s = ln.strip()
        if not s or s.startswith("#"):
            continue
        if s.startswith(":"):
            word = s[1:].split()[0].upper() if len(s) > 1 else ""
            if word == "DEGREES":
                degrees = True
            elif word == "RADIANS":
                degrees = False
            continue
        start = i
        break
    else:
        raise InputError(f"{path}: no motion frames in the AMC file")
    newline = "\r\n" if "\r\n" in text[:4096] else "\n"
    header = "".join(ln + newline for ln in lines[:start])
    body = "\n".join(lines[start:])
    tokens = body.split()
    if not tokens or not _is_int(tokens[0]):
        raise InputError(f"{path}: AMC data must start with a frame number, got {tokens[:1]}")
    # the first frame's bone order gives the candidate block layout
    order: list[str] = []
    k = 1
    while k < len(tokens) and not _is_int(tokens[k]):
        bone = tokens[k]
        if bone not in layout:
            order = []  # a value where a bone was expected: the line reader says where
            break
        order.append(bone)
        k += 1 + layout[bone]
    block = 1 + sum(1 + layout[b] for b in order)
    fast, notes = (_fast_amc(tokens, order, layout, block) if order else None), []
    if fast is None:
        values, notes, kept = _slow_amc(lines[start:], layout, path)
    else:
        values, kept = fast
    numbers, listed, written, T = kept
    plan = arrange_frames(numbers, T, path, _number_lines(lines, start))
    if plan.changed:
        values, written, listed = apply_plan(plan, values, written, listed)
        numbers, T = plan.numbers, plan.T
    notes += plan.notes
    kept = (header, newline, numbers, listed, written, plan.added, T)
    return values, degrees, notes, kept, plan.step


def _number_lines(lines: list[str], start: int):
    """file frame -> "line N" of its number (the lines that hold a number alone, counted once
    asked: only messages need them), or "frame K" when frames do not sit on lines of their
    own."""
    found: list[int] = []

    def line_of(k: int) -> str:
        if not found:
            found.extend(i + 1 for i in range(start, len(lines)) if lines[i].strip().isdigit())
        return f"line {found[k]}" if k < len(found) else f"frame {k + 1}"

    return line_of


def _is_int(tok: str) -> bool:
    """Whether ``tok`` is a frame number (ASCII digits: ``"²".isdigit()`` is True too)."""
    return tok.isascii() and tok.isdigit()


def _fast_amc(tokens: list[str], order: list[str], layout: dict[str, int], block: int):
    if len(tokens) % block:
        return None
    T = len(tokens) // block
    col = 1
    values: dict[str, np.ndarray] = {}
    written: dict[str, np.ndarray] = {}
    for bone in order:
        if tokens[col::block].count(bone) != T:
            return None
        n = layout[bone]
        written[bone] = np.empty((T, n), dtype=object)
        for i in range(n):
            written[bone][:, i] = tokens[col + 1 + i :: block]
        try:
            values[bone] = written[bone].astype(np.float64)
        except ValueError:
            return None
        col += 1 + n
    frames = tokens[0::block]
    if not all(_is_int(t) for t in frames):
        return None
    return values, (frames, [tuple(order)] * T, written, T)


def _slow_amc(lines: list[str], layout: dict[str, int], path: str):
    """Frames read line by line; a bone a frame leaves out holds its previous value, and a last
    frame that lists fewer bones than the others (a file cut off mid-frame) is dropped (kept in
    the layout, to be written back as it was).
    -> values {bone: (T, n)}, notes, (frame numbers, bones per frame, tokens, T)"""
    frames: list[dict[str, list[float]]] = []
    numbers: list[str] = []
    listed: list[dict[str, list[str]]] = []
    for ln in lines:
        words = ln.split()
        if not words or words[0].startswith("#"):
            continue
        if len(words) == 1 and _is_int(words[0]):
            frames.append({})
            numbers.append(words[0])
            listed.append({})
            continue
        if not frames:
            raise InputError(f"{path}: AMC data before the first frame number")
        bone, vals = words[0], words[1:]
        if bone not in layout:
            raise InputError(f"{path}: AMC names bone {bone!r}, which the skeleton lacks")
        if len(vals) != layout[bone]:
            raise InputError(f"{path}: AMC frame {len(frames)}: bone {bone} has {len(vals)} "
                             f"values, the skeleton gives it {layout[bone]}")  # fmt: skip
        try:
            frames[-1][bone] = [float(v) for v in vals]
        except ValueError:
            raise InputError(f"{path}: non-numeric AMC value in frame {len(frames)}") from None
        listed[-1][bone] = vals
    notes = []
    seen = set().union(*frames) if frames else set()
    T = len(frames)
    if T > 1 and seen - set(frames[-1]):
        T -= 1
        notes.append("the last frame lists fewer bones than the others (a cut-off file?): dropped")
    out, written, held = {}, {}, 0
    for bone, n in layout.items():
        arr = np.zeros((len(frames), n))
        tok = np.full((len(frames), n), None, dtype=object)
        for t, fr in enumerate(frames):
            if bone in fr:
                arr[t], tok[t] = fr[bone], listed[t][bone]
            elif bone in seen and t > 0:
                arr[t], held = arr[t - 1], held + (t < T)
        out[bone], written[bone] = arr, tok
    if held:
        notes.append(f"{held} bone entries missing from their frames: the previous frame's held")
    bones = [tuple(fr) for fr in listed]
    return out, notes, (numbers, bones, written, T)


def load_amc(
    path: Path | str,
    skeleton: AsfSkeleton | Path | str,
    fps: float | None = None,
    scale: float | None = None,
    max_frames: int | None = None,
) -> SourceMotion:
    """Read an ``.amc`` (or ``.amc.gz``) motion on an ASF skeleton into a :class:`SourceMotion`.

    fps: AMC files do not store their rate; CMU's are 120 (60 for some subjects, see ``cmu``).
        None assumes 120, or 120 / k for frames numbered every k-th (``1 3 5 ...``).
    scale: metres per file unit; None follows the ASF's ``:units length`` (Acclaim/CMU inches).
    max_frames: keep only the first frames (for quick looks and tests).
    """
    path = str(path)
    if not isinstance(skeleton, AsfSkeleton):
        skeleton = load_asf(skeleton)
    text = read_text(path, errors="surrogateescape")  # the header is written back as it was
    if text.lstrip().startswith(":version") or ":bonedata" in text[:20000]:
        raise InputError(f"{path}: this is an ASF skeleton, not an AMC motion")
    layout = {"root": len(skeleton.root_order)}
    layout.update({name: len(b.dofs) for name, b in skeleton.bones.items()})
    file_values, amc_degrees, amc_notes, kept, step = _read_amc_values(text, layout, path)
    assumed = fps is None
    fps = 120.0 / step if assumed else fps
    if step > 1:
        rate = f"{fps:g} fps" + (f" (120 / {step} assumed)" if assumed else "")
        amc_notes.append(f"frame numbers step by {step} throughout ({', '.join(kept[2][:3])}, "
                         f"...): one frame in {step} of a capture, read as consecutive frames "
                         f"at {rate}, not as holes")  # fmt: skip
    if not any(kept[3]):  # the bones each frame lists: none in any frame
        raise InputError(f"{path}: frame numbers but no bone lines: the AMC holds no motion")
    degrees = skeleton.degrees if amc_degrees is None else amc_degrees
    T = T_file = kept[-1]
    if max_frames is not None:
        T = min(T, max_frames)
    values = {k: v[:T] for k, v in file_values.items()}
    if T < 1:
        raise InputError(f"{path}: no motion frames")
    for bone, v in values.items():
        if not np.all(np.isfinite(v)):
            raise InputError(f"{path}: bone {bone} has NaN or infinite values")
    to_rad = math.pi / 180.0 if degrees else 1.0
    unit, metres = skeleton.metres_per_unit() if scale is None else (f"{scale:g} m", scale)

    bone_order = skeleton.order()
    names = ["root"]
    parents = [-1]
    offsets = [np.zeros(3)]
    end_site = [False]
    rotations = []
    index = {"root": 0}
    parent_of = {kid: p for p, kids in skeleton.children.items() for kid in kids}

    for name, n in layout.items():  # bones the AMC never mentions stay at rest
        values.setdefault(name, np.zeros((T, n)))
    root_vals = values["root"]
    t_cols = {ch[1]: i for i, ch in enumerate(skeleton.root_order) if ch.startswith("t")}
    r_cols = [(i, ch[1]) for i, ch in enumerate(skeleton.root_order) if ch.startswith("r")]
    root_pos = np.tile(skeleton.root_position, (T, 1))
    for axis, i in t_cols.items():
        root_pos[:, "xyz".index(axis)] += root_vals[:, i]
    C0 = axis_frame(skeleton.root_orientation, skeleton.root_axis_order, skeleton.degrees)
    root_angles = root_vals[:, [i for i, _ in r_cols]] * to_rad
    check_angles(root_angles, "the root", path)
    rotations.append(dof_rotation(C0, root_angles, "".join(a for _, a in r_cols)))

    for name in bone_order:
        bone = skeleton.bones[name]
        parent = parent_of[name]
        names.append(name)
        parents.append(index[parent])
        end_site.append(False)
        index[name] = len(names) - 1
        pb = skeleton.bones.get(parent)
        offsets.append(np.zeros(3) if pb is None else pb.direction * pb.length)
        r = rotation_columns(bone.dofs)
        if r:
            C = axis_frame(bone.axis, bone.axis_order, skeleton.degrees)
            vals = values[name][:, [i for i, _ in r]] * to_rad
            check_angles(vals, f"bone {name}", path)
            rotations.append(dof_rotation(C, vals, "".join(a for _, a in r)))
        else:
            rotations.append(np.broadcast_to(np.eye(3), (T, 3, 3)))
        if not skeleton.children.get(name):
            names.append(f"{name}_end")
            parents.append(index[name])
            end_site.append(True)
            offsets.append(bone.direction * bone.length)
            rotations.append(np.broadcast_to(np.eye(3), (T, 3, 3)))
    notes = list(skeleton.notes) + amc_notes
    if any(d in ("tx", "ty", "tz", "l") for b in skeleton.bones.values() for d in b.dofs):
        notes.append("translation/length dofs on bones are ignored")
    gaps = int(kept[5][:T_file].sum())  # frames the file lacks
    info = {"format": "amc", "skeleton": Path(skeleton.path).name, "unit": unit,
            "metres_per_unit": float(metres), "fps_in_file": float(fps),
            "frames_in_file": int(T_file) - gaps, "degrees": bool(degrees)}  # fmt: skip
    if gaps:
        info["missing_frames"] = gaps
    header, newline, frames, listed, tokens, added, _ = kept
    amc = AmcLayout(header=header, frames=list(frames), bones=listed, values=file_values,
                    tokens=tokens, rows=np.arange(T), degrees=bool(degrees), skeleton=skeleton,
                    metres_per_unit=float(metres), newline=newline, added=added)  # fmt: skip
    return SourceMotion(
        names=tuple(names),
        parents=np.array(parents, dtype=np.int64),
        offsets=np.array(offsets) * metres,
        rotations=np.stack(rotations, axis=1),
        root_positions=root_pos * metres,
        fps=float(fps),
        end_site=np.array(end_site, dtype=bool),
        info=info,
        notes=notes,
        layout=amc,
    ).check_distances(path)
