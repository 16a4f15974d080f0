"""Acclaim skeleton files (``.asf``), as used by the CMU mocap database.

Conventions (Acclaim, as CMU writes them):

* ``:units length L``: file lengths are inches times L, so metres = value * 0.0254 / L
  (CMU: L = 0.45, one unit = 5.644 cm). ``angle deg|rad``.
* A bone runs from its parent's tip along ``direction`` (world axes, rest pose) for ``length``.
* ``axis a b c XYZ`` gives the bone's local frame ``C = Rz(c) Ry(b) Rx(a)`` (X applied first).

The motions that move such a skeleton are read by :mod:`mdvae_cli.formats.asfamc`."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.formats.source import (
    guess_length_unit,
    read_text,
    skeleton_height,
)
from mdvae_cli.geometry.euler import euler_to_rotmat
from mdvae_cli.motion.motion import MAX_DISTANCE_M

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
        index = {n: i for i, n in enumerate(names)}
        parent = {kid: p for p, kids in self.children.items() for kid in kids}
        parents = np.array([-1] + [index[parent[n]] for n in names[1:]])
        offsets = np.zeros((len(names), 3))
        for i, n in enumerate(names[1:], start=1):
            p = parent[n]
            if p != "root":
                offsets[i] = self.bones[p].direction * self.bones[p].length
        return skeleton_height(offsets, parents)


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

    units = _units(sections.get("units", []))
    length_unit = None
    if "length" in units:
        length_unit = float(_floats(units["length"][:1], "units length", path, 1)[0])
        if not length_unit > 0:
            raise InputError(f"{path}: :units length must be > 0")
    angle = _first(units.get("angle", ["deg"]), ":units angle", path).lower()
    if angle not in ("deg", "rad"):
        raise InputError(f"{path}: unknown angle unit {angle!r}")

    root = dict(_key_values(sections["root"], path))
    root_order = tuple(w.lower() for w in root.get("order", ["TX", "TY", "TZ", "RX", "RY", "RZ"]))
    for ch in root_order:
        if ch not in _DOF_NAMES[:6]:
            raise InputError(f"{path}: unknown root channel {ch!r}")
    root_axis = _axis_order(
        _first(root.get("axis", ["XYZ"]), "the root's axis", path), "the root", path
    )
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
    metres = 0.0254 / length_unit if length_unit else 1.0  # unknown units: taken as metres
    for bone in bones.values():
        if bone.length * metres > MAX_DISTANCE_M:
            raise InputError(f"{path}: bone {bone.name} is {bone.length * metres:.3g} m long; "
                             "the file is corrupt")  # fmt: skip

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


def _units(lines: list[str]) -> dict[str, list[str]]:
    """The ``:units`` section, a value per line or all on one (``mass 1.0 length 0.45 angle
    deg``): unit name -> [value] ([] for a name with none)."""
    out: dict[str, list[str]] = {}
    for words in (ln.split() for ln in lines):
        out.update((words[i].lower(), words[i + 1 : i + 2]) for i in range(0, len(words), 2))
    return out


def _first(values: list[str], what: str, path: str) -> str:
    """The first of a field's values; InputError when the field has none."""
    if not values:
        raise InputError(f"{path}: {what} has no value")
    return values[0]


def _bone(block: list[str], path: str) -> AsfBone:
    fields: dict[str, list[str]] = {}
    for ln in block:
        words = ln.split()
        key = words[0].lower()
        if not key.startswith("("):  # "(" lines continue 'limits'
            fields[key] = words[1:]
    name = (fields.get("name") or [None])[0]
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
    """Read an ``.asf`` (or ``.asf.gz``) skeleton file. Bytes that are not UTF-8 (a cp1252
    bone name) are kept as the AMC reader keeps them ("surrogateescape"), so that the names
    of the two files agree."""
    return parse_asf(read_text(path, errors="surrogateescape"), str(path))


def axis_frame(angles: np.ndarray, order: str, degrees: bool) -> np.ndarray:
    """C = R_last ... R_first for ASF ``axis`` angles given in application order.  -> (3, 3)"""
    a = np.deg2rad(angles) if degrees else np.asarray(angles, dtype=np.float64)
    by_axis = dict(zip("XYZ", a, strict=True))
    rev = order[::-1]
    return euler_to_rotmat(np.array([[by_axis[c] for c in rev]]), rev.lower())[0]
