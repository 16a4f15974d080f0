"""Acclaim skeleton (``.asf``) and motion (``.amc``) files, as used by the CMU mocap database.

Conventions (Acclaim, as CMU writes them):

* ``:units length L``: file lengths are inches times L, so metres = value * 0.0254 / L
  (CMU: L = 0.45, one unit = 5.644 cm). ``angle deg|rad``; an AMC ``:DEGREES``/``:RADIANS``
  line overrides it.
* A bone runs from its parent's tip along ``direction`` (world axes, rest pose) for ``length``.
* ``axis a b c XYZ`` gives the bone's local frame ``C = Rz(c) Ry(b) Rx(a)`` (X applied first).
* AMC values for ``dof rx ry rz`` form ``M = Rz Ry Rx`` (applied in the listed order), in the
  local frame: the bone's rotation in world-aligned axes is ``C M C^T``.

:func:`load_amc` returns a :class:`SourceMotion` whose joints are the root, every bone (placed at
the bone's start) and an ``<bone>_end`` tip for each leaf bone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.motion.bvh import (
    SourceMotion,
    check_angles,
    euler_to_rotmat,
    guess_length_unit,
    read_text,
    skeleton_height,
)

_DOF_NAMES = ("rx", "ry", "rz", "tx", "ty", "tz", "l")


@dataclass
class AsfBone:
    """One ASF bone.  direction (3,) unit vector, length in file units, axis (3,) degrees or
    radians as the file says, axis_order e.g. "XYZ", dofs e.g. ("rx", "ry", "rz")."""

    name: str
    direction: np.ndarray
    length: float
    axis: np.ndarray
    axis_order: str
    dofs: tuple[str, ...]


@dataclass
class AsfSkeleton:
    """A parsed ``.asf`` file.

    bones: name -> AsfBone (the root is not a bone); children: name -> child names, "root"
    included; root_order: the root's AMC channels, e.g. ("tx", "ty", "tz", "rx", "ry", "rz");
    root_axis_order, root_position (3,), root_orientation (3,): the ``:root`` section;
    length_unit: the ``:units length`` value (None if absent); degrees: angle unit.
    """

    name: str
    bones: dict[str, AsfBone]
    children: dict[str, list[str]]
    root_order: tuple[str, ...]
    root_axis_order: str
    root_position: np.ndarray
    root_orientation: np.ndarray
    length_unit: float | None
    degrees: bool
    path: str = ""
    notes: list[str] = field(default_factory=list)

    def order(self) -> list[str]:
        """Bone names, parents before children (depth first from the root)."""
        out: list[str] = []
        stack = list(reversed(self.children.get("root", [])))
        while stack:
            name = stack.pop()
            out.append(name)
            stack.extend(reversed(self.children.get(name, [])))
        return out

    def metres_per_unit(self) -> tuple[str, float]:
        if self.length_unit:
            return f"inch*{self.length_unit:g}", 0.0254 / self.length_unit
        return guess_length_unit(self._height())

    def _height(self) -> float:
        names = ["root", *self.order()]
        parents = np.array([-1] + [names.index(self._parent(n)) for n in names[1:]])
        offsets = np.zeros((len(names), 3))
        for i, n in enumerate(names[1:], start=1):
            p = self._parent(n)
            if p != "root":
                offsets[i] = self.bones[p].direction * self.bones[p].length
        return skeleton_height(offsets, parents)

    def _parent(self, name: str) -> str:
        return next(p for p, kids in self.children.items() if name in kids)


def _floats(values: list[str], what: str, path: str, count: int | None = None) -> np.ndarray:
    try:
        out = np.array([float(v) for v in values], dtype=np.float64)
    except ValueError:
        raise InputError(f"{path}: expected numbers for {what}, got {' '.join(values)!r}") from None
    if count is not None and out.size != count:
        raise InputError(f"{path}: {what} needs {count} numbers, got {out.size}")
    if not np.all(np.isfinite(out)):
        raise InputError(f"{path}: {what} is not finite")
    return out


def _axis_order(word: str, what: str, path: str) -> str:
    order = word.upper()
    if sorted(order) != ["X", "Y", "Z"]:
        raise InputError(f"{path}: bad axis order {word!r} for {what}")
    return order


def parse_asf(text: str, path: str = "<asf>") -> AsfSkeleton:
    """Parse the text of an ``.asf`` file; InputError on anything malformed."""
    lines = [ln.split("#", 1)[0].strip() for ln in text.splitlines()]
    lines = [ln for ln in lines if ln]
    sections: dict[str, list[str]] = {}
    current = None
    for ln in lines:
        if ln.startswith(":"):
            key, _, rest = ln[1:].partition(" ")
            current = key.lower()
            sections.setdefault(current, [])
            if rest.strip():
                sections[current].append(rest.strip())
        elif current is not None:
            sections[current].append(ln)
    for needed in ("root", "bonedata", "hierarchy"):
        if needed not in sections:
            raise InputError(f"{path}: not an ASF skeleton (no :{needed} section)")

    units = dict(_key_values(sections.get("units", []), path))
    length_unit = None
    if "length" in units:
        length_unit = float(_floats(units["length"][:1], "units length", path, 1)[0])
        if not length_unit > 0:
            raise InputError(f"{path}: :units length must be > 0")
    angle = units.get("angle", ["deg"])[0].lower()
    if angle not in ("deg", "rad"):
        raise InputError(f"{path}: unknown angle unit {angle!r}")

    root = dict(_key_values(sections["root"], path))
    root_order = tuple(w.lower() for w in root.get("order", ["TX", "TY", "TZ", "RX", "RY", "RZ"]))
    for ch in root_order:
        if ch not in _DOF_NAMES[:6]:
            raise InputError(f"{path}: unknown root channel {ch!r}")
    root_axis = _axis_order(root.get("axis", ["XYZ"])[0], "the root", path)
    position = _floats(root.get("position", ["0", "0", "0"]), "root position", path, 3)
    orientation = _floats(root.get("orientation", ["0", "0", "0"]), "root orientation", path, 3)

    bones: dict[str, AsfBone] = {}
    block: list[str] | None = None
    for ln in sections["bonedata"]:
        word = ln.split()[0].lower()
        if word == "begin":
            block = []
        elif word == "end":
            if block is None:
                raise InputError(f"{path}: 'end' without 'begin' in :bonedata")
            bone = _bone(block, path)
            if bone.name in bones or bone.name == "root":
                raise InputError(f"{path}: bone {bone.name!r} defined twice")
            bones[bone.name] = bone
            block = None
        elif block is None:
            raise InputError(f"{path}: text outside a begin/end block in :bonedata: {ln!r}")
        else:
            block.append(ln)
    if block is not None:
        raise InputError(f"{path}: unterminated bone block in :bonedata")
    if not bones:
        raise InputError(f"{path}: no bones in :bonedata")

    children: dict[str, list[str]] = {}
    seen = {"root"}
    for ln in sections["hierarchy"]:
        words = ln.split()
        if words[0].lower() in ("begin", "end"):
            continue
        parent, kids = words[0], words[1:]
        if parent not in seen:
            raise InputError(f"{path}: hierarchy names {parent!r} before it is attached")
        for kid in kids:
            if kid not in bones:
                raise InputError(f"{path}: hierarchy names an unknown bone {kid!r}")
            if kid in seen:
                raise InputError(f"{path}: bone {kid!r} has two parents")
            seen.add(kid)
        children.setdefault(parent, []).extend(kids)
    notes = []
    orphans = sorted(set(bones) - seen)
    if orphans:
        notes.append(f"bones not in the hierarchy, ignored: {', '.join(orphans)}")
    name = sections.get("name", ["?"])[0] if sections.get("name") else "?"
    return AsfSkeleton(
        name=name, bones=bones, children=children, root_order=root_order,
        root_axis_order=root_axis, root_position=position, root_orientation=orientation,
        length_unit=length_unit, degrees=(angle == "deg"), path=path, notes=notes,
    )  # fmt: skip


def _key_values(lines: list[str], path: str):
    for ln in lines:
        words = ln.split()
        yield words[0].lower(), words[1:]


def _bone(block: list[str], path: str) -> AsfBone:
    fields: dict[str, list[str]] = {}
    for ln in block:
        words = ln.split()
        key = words[0].lower()
        if not key.startswith("("):  # "(" lines continue 'limits'
            fields[key] = words[1:]
    name = fields.get("name", [None])[0]
    if not name:
        raise InputError(f"{path}: a bone block has no name")
    for needed in ("direction", "length"):
        if needed not in fields:
            raise InputError(f"{path}: bone {name} has no {needed}")
    direction = _floats(fields["direction"], f"the direction of {name}", path, 3)
    length = float(_floats(fields["length"][:1], f"the length of {name}", path, 1)[0])
    if length < 0:
        raise InputError(f"{path}: bone {name} has a negative length")
    norm = np.linalg.norm(direction)
    if norm < 1e-9:
        if length > 1e-9:
            raise InputError(f"{path}: bone {name} has a zero direction")
        direction = np.zeros(3)
    else:
        direction = direction / norm
    axis_words = fields.get("axis", ["0", "0", "0", "XYZ"])
    if len(axis_words) != 4:
        raise InputError(f"{path}: bone {name}: 'axis' needs three angles and an order")
    axis = _floats(axis_words[:3], f"the axis of {name}", path, 3)
    order = _axis_order(axis_words[3], name, path)
    dofs = tuple(d.lower() for d in fields.get("dof", []))
    for d in dofs:
        if d not in _DOF_NAMES:
            raise InputError(f"{path}: bone {name} has an unknown dof {d!r}")
    return AsfBone(name, direction, length, axis, order, dofs)


def load_asf(path: Path | str) -> AsfSkeleton:
    """Read an ``.asf`` (or ``.asf.gz``) skeleton file."""
    return parse_asf(read_text(path), str(path))


def _axis_frame(angles: np.ndarray, order: str, degrees: bool) -> np.ndarray:
    """C = R_last ... R_first for ASF ``axis`` angles given in application order.  -> (3, 3)"""
    a = np.deg2rad(angles) if degrees else np.asarray(angles, dtype=np.float64)
    by_axis = dict(zip("XYZ", a, strict=True))
    rev = order[::-1]
    return euler_to_rotmat(np.array([[by_axis[c] for c in rev]]), rev.lower())[0]


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
            raise InputError(f"{path}: AMC names bone {bone!r}, which the skeleton lacks")
        order.append(bone)
        k += 1 + layout[bone]
    block = 1 + sum(1 + layout[b] for b in order)
    values, notes = _fast_amc(tokens, order, layout, block), []
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
    C0 = _axis_frame(skeleton.root_orientation, skeleton.root_axis_order, skeleton.degrees)
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
            C = _axis_frame(bone.axis, bone.axis_order, skeleton.degrees)
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
