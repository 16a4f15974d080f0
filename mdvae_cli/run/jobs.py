"""One file's work in a command over many files: what the file-at-a-time runners take."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass
class FileJob:
    """One unit of work.

    relpath: the file's path relative to the folder it was found in (its name when given
        directly); used for display, mirroring and per-file seeds.
    source: the input file. output: where the result goes (None when nothing is written).
    data: anything else the command needs (e.g. the matching prediction file).
    missing: the input was named but does not exist (one of several: it fails alone).
    """

    relpath: Path
    source: Path
    output: Path | None = None
    data: Any = None
    missing: bool = False
