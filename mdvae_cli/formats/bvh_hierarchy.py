"""A BVH file's HIERARCHY: joints, parents, OFFSETs and channels, read into plain lists.

A joint's name is the rest of its ``ROOT`` / ``JOINT`` line, stripped (3ds Max Biped names hold
spaces: ``JOINT Bip01 L Thigh``), up to a ``{`` on that line; lines may end in LF, CR LF or CR.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from mdvae_cli.errors import InputError

_CHANNELS = {
    "xposition": ("t", "x"), "yposition": ("t", "y"), "zposition": ("t", "z"),
    "xrotation": ("r", "x"), "yrotation": ("r", "y"), "zrotation": ("r", "z"),
}  # fmt: skip


#: joints deeper than this below the root: not a motion-capture skeleton (a finger tip of a
#: full-body rig is ~10 deep)
MAX_DEPTH = 1000


#: a line that opens a joint: its keyword, then its name, the rest of the line (3ds Max Biped
#: names hold spaces: ``JOINT Bip01 L Thigh``), up to a ``{`` on the same line
_JOINT_LINE = re.compile(r"^\s*(ROOT|JOINT)(?:\s+([^{]*?))?\s*(\{.*)?$", re.IGNORECASE)
#: any line ending: LF, CR LF, or CR alone (old Mac files)
_LINE_END = re.compile(r"\r\n|\r|\n")


def _words(text: str) -> list[str]:
    """A hierarchy's words, braces apart; a joint's name is one word, spaces and all."""
    items: list[str] = []
    for line in _LINE_END.split(text):
        m = _JOINT_LINE.match(line)
        if m and m.group(2):
            items += [m.group(1), m.group(2)]
            line = m.group(3) or ""
        items += re.sub(r"([{}])", r" \1 ", line).split()
    return items


class Tokens:
    """A hierarchy's words (:func:`_words`), taken one at a time; a word missing or not the
    one expected is a one-line InputError naming the file."""

    def __init__(self, text: str, path: Path):
        self.items = _words(text)
        self.pos = 0
        self.path = path

    def next(self, what: str) -> str:
        if self.pos >= len(self.items):
            raise InputError(f"{self.path}: unexpected end of the hierarchy (expected {what})")
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
            value = float(tok)
        except ValueError:
            raise InputError(f"{self.path}: expected a number for {what}, got {tok!r}") from None
        if not math.isfinite(value):
            raise InputError(f"{self.path}: {what} is not finite ({tok})")
        return value


def parse_hierarchy(tok: Tokens):
    """-> names, parents, offsets (file units), channels [(joint, kind, axis)], end_site flags.

    Read without recursion (a hierarchy's depth is the file's to choose); one deeper than
    MAX_DEPTH is refused."""
    names: list[str] = []
    parents: list[int] = []
    offsets: list[tuple[float, float, float]] = []
    end_site: list[bool] = []
    channels: list[tuple[int, str, str]] = []
    open_joints: list[int] = []  # the joints whose '}' is still to come, root first

    def begin(parent: int, name: str, is_end: bool) -> None:
        if len(open_joints) >= MAX_DEPTH:
            raise InputError(f"{tok.path}: the joint hierarchy is more than {MAX_DEPTH} joints "
                             "deep; not a motion-capture skeleton")  # fmt: skip
        index = len(names)
        names.append(name)
        parents.append(parent)
        end_site.append(is_end)
        tok.expect("{")
        tok.expect("OFFSET")
        offsets.append(tuple(tok.number(f"the OFFSET of {name}") for _ in range(3)))
        if not is_end:
            tok.expect("CHANNELS")
            word = tok.next(f"the channel count of {name}")
            try:
                count = float(word)
            except ValueError:
                count = -1.0
            if not (0 <= count <= 6 and count == int(count)):
                raise InputError(f"{tok.path}: joint {name} has a bad channel count {word}")
            for _ in range(int(count)):
                ch = tok.next(f"a channel of {name}")
                if ch.lower() not in _CHANNELS:
                    raise InputError(f"{tok.path}: joint {name} has an unknown channel {ch!r}")
                channels.append((index, *_CHANNELS[ch.lower()]))
        open_joints.append(index)

    tok.expect("HIERARCHY")
    tok.expect("ROOT")
    begin(-1, tok.next("the root joint name"), False)
    while open_joints:
        index = open_joints[-1]
        name = names[index]
        word = tok.next(f"'}}' closing {name}")
        if word == "}":
            open_joints.pop()
        elif end_site[index]:
            raise InputError(f"{tok.path}: End Site of {names[parents[index]]} has extra content")
        elif word.upper() == "JOINT":
            begin(index, tok.next("a joint name"), False)
        elif word.upper() == "END":
            tok.expect("Site")
            begin(index, f"{name}_end", True)
        else:
            raise InputError(f"{tok.path}: unexpected {word!r} inside joint {name}")
    seen: set[str] = set()
    for n in names:
        if n in seen:
            raise InputError(f"{tok.path}: joint name {n!r} appears twice")
        seen.add(n)
    return names, parents, np.array(offsets, dtype=np.float64), channels, end_site
