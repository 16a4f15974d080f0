"""File-system helpers shared by every writer: atomic output, input discovery."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path

from mdvae_cli.errors import InputError


def write_atomic(path: Path, write: Callable[[Path], None], forbid: Iterable[Path] = ()) -> None:
    """Write a file by calling ``write(tmp)`` on a temporary name, then renaming it to ``path``.

    ``forbid`` lists input files: writing onto one of them is refused (inputs are never
    overwritten). The temporary keeps ``path``'s suffix so writers that look at it still work.
    """
    path = Path(path)
    target = path.resolve()
    for p in forbid:
        if Path(p).exists() and Path(p).resolve() == target:
            raise InputError(f"refusing to overwrite the input file {p}")
    if path.is_dir():
        raise InputError(f"cannot write {path}: it is a folder; give a file name")
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise InputError(f"cannot write {path}: {parent} is a file, not a folder")
            break
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~_current_umask())  # mkstemp makes 0600; outputs get the usual mode
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


MOTION_SUFFIXES = (".npz",)


def expand_inputs(
    inputs: Iterable[Path], suffixes: tuple[str, ...] = MOTION_SUFFIXES
) -> list[tuple[Path, Path]]:
    """Expand files and folders into ``(file, relative_path)`` pairs, sorted.

    A folder contributes every file below it whose name ends in one of ``suffixes`` (any
    case, ``.gz`` variants included; hidden files and folders skipped), with its path relative
    to the folder; a file given directly contributes its own name. A file named twice (or
    also inside a folder named) counts once. A missing path raises InputError.
    """
    out: list[tuple[Path, Path]] = []
    for item in inputs:
        item = Path(item)
        if item.is_dir():
            for f in sorted(item.rglob("*")):
                name = f.name.lower().removesuffix(".gz")
                hidden = any(part.startswith(".") for part in f.relative_to(item).parts)
                if f.is_file() and name.endswith(suffixes) and not hidden:
                    out.append((f, f.relative_to(item)))
        elif item.exists():
            out.append((item, Path(item.name)))
        else:
            raise InputError(f"no such file or folder: {item}")
    unique, seen = [], set()
    for f, rel in out:
        key = f.resolve()
        if key not in seen:
            seen.add(key)
            unique.append((f, rel))
    return unique
