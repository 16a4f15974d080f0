"""Acclaim motion files (``.amc``) on their ``.asf`` skeleton (``motion.asf``), as used by the
CMU mocap database.

Conventions (Acclaim, as CMU writes them):

* An AMC ``:DEGREES``/``:RADIANS`` line overrides the skeleton's angle unit.
* AMC values for ``dof rx ry rz`` form ``M = Rz Ry Rx`` (applied in the listed order), in the
  local frame: the bone's rotation in world-aligned axes is ``C M C^T``.

:func:`load_amc` returns a :class:`SourceMotion` whose joints are the root, every bone (placed at
the bone's start) and an ``<bone>_end`` tip for each leaf bone.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.motion.asf import (
    AsfSkeleton,
    axis_frame,
    load_asf,
)
from mdvae_cli.motion.source import (
    SourceMotion,
    check_angles,
    euler_to_rotmat,
    read_text,
)


def _read_amc_values(text: str, layout: dict[str, int], path: str):
    """Frame values per bone: {name: (T, n)}, the angle unit if the header says one, and
    notes on frames that lacked bones.

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
    values, notes = (_fast_amc(tokens, order, layout, block) if order else None), []
    if values is None:
        values, notes = _slow_amc(lines[start:], layout, path)
    return values, degrees, notes


def _is_int(tok: str) -> bool:
    return tok.isdigit()


def _fast_amc(tokens: list[str], order: list[str], layout: dict[str, int], block: int):
    if len(tokens) % block:
        return None
    T = len(tokens) // block
    col = 1
    values: dict[str, np.ndarray] = {}
    for bone in order:
        if tokens[col::block].count(bone) != T:
            return None
        n = layout[bone]
        try:
            cols = [np.array(tokens[col + 1 + i :: block], dtype=np.float64) for i in range(n)]
        except ValueError:
            return None
        values[bone] = np.stack(cols, axis=1) if n else np.zeros((T, 0))
        col += 1 + n
    if not all(t.isdigit() for t in tokens[0::block]):
        return None
    return values


def _slow_amc(
    lines: list[str], layout: dict[str, int], path: str
) -> tuple[dict[str, np.ndarray], list[str]]:
    """Frames read line by line; a bone a frame leaves out holds its previous value, and a last
    frame that lists fewer bones than the others (a file cut off mid-frame) is dropped."""
    frames: list[dict[str, list[float]]] = []
    for ln in lines:
        words = ln.split()
        if not words or words[0].startswith("#"):
            continue
        if len(words) == 1 and _is_int(words[0]):
            frames.append({})
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
    notes = []
    seen = set().union(*frames) if frames else set()
    if len(frames) > 1 and seen - set(frames[-1]):
        frames.pop()
        notes.append("the last frame lists fewer bones than the others (a cut-off file?): dropped")
    T = len(frames)
    out, held = {}, 0
    for bone, n in layout.items():
        arr = np.zeros((T, n))
        for t, fr in enumerate(frames):
            if bone in fr:
                arr[t] = fr[bone]
            elif bone in seen and t > 0:
                arr[t], held = arr[t - 1], held + 1
        out[bone] = arr
    if held:
        notes.append(f"{held} bone entries missing from their frames: the previous frame's held")
    return out, notes


def load_amc(
    path: Path | str,
    skeleton: AsfSkeleton | Path | str,
    fps: float = 120.0,
    scale: float | None = None,
    max_frames: int | None = None,
) -> SourceMotion:
    """Read an ``.amc`` (or ``.amc.gz``) motion on an ASF skeleton into a :class:`SourceMotion`.

    fps: AMC files do not store their rate; CMU's are 120 (60 for some subjects, see ``cmu``).
    scale: metres per file unit; None follows the ASF's ``:units length`` (Acclaim/CMU inches).
    max_frames: keep only the first frames (for quick looks and tests).
    """
    path = str(path)
    if not isinstance(skeleton, AsfSkeleton):
        skeleton = load_asf(skeleton)
    text = read_text(path)
    if text.lstrip().startswith(":version") or ":bonedata" in text[:20000]:
        raise InputError(f"{path}: this is an ASF skeleton, not an AMC motion")
    layout = {"root": len(skeleton.root_order)}
    layout.update({name: len(b.dofs) for name, b in skeleton.bones.items()})
    values, amc_degrees, amc_notes = _read_amc_values(text, layout, path)
    degrees = skeleton.degrees if amc_degrees is None else amc_degrees
    T = T_file = next(iter(values.values())).shape[0]
    if max_frames is not None:
        T = min(T, max_frames)
        values = {k: v[:T] for k, v in values.items()}
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
    root_angles = root_vals[:, [i for i, _ in r_cols[::-1]]] * to_rad
    check_angles(root_angles, "the root", path)
    M0 = euler_to_rotmat(root_angles, "".join(a for _, a in r_cols[::-1]))
    rotations.append(C0 @ M0 @ C0.T)

    for name in bone_order:
        bone = skeleton.bones[name]
        parent = parent_of[name]
        names.append(name)
        parents.append(index[parent])
        end_site.append(False)
        index[name] = len(names) - 1
        pb = skeleton.bones.get(parent)
        offsets.append(np.zeros(3) if pb is None else pb.direction * pb.length)
        r = [(i, d[1]) for i, d in enumerate(bone.dofs) if d.startswith("r")]
        if r:
            C = axis_frame(bone.axis, bone.axis_order, skeleton.degrees)
            vals = values[name][:, [i for i, _ in r[::-1]]] * to_rad
            check_angles(vals, f"bone {name}", path)
            M = euler_to_rotmat(vals, "".join(a for _, a in r[::-1]))
            rotations.append(C @ M @ C.T)
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
    info = {"format": "amc", "skeleton": Path(skeleton.path).name, "unit": unit,
            "metres_per_unit": float(metres), "fps_in_file": float(fps),
            "frames_in_file": int(T_file)}  # fmt: skip
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
    ).check_distances(path)
