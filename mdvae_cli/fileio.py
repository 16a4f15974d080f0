"""File-system helpers shared by every writer: atomic output, input discovery."""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import stat
from collections.abc import Callable, Iterable
from pathlib import Path

from mdvae_cli.errors import InputError


def write_atomic(path: Path, write: Callable[[Path], None], forbid: Iterable[Path] = ()) -> None:
    """Write a file by calling ``write(tmp)`` on a temporary name, then renaming it to ``path``.

    ``forbid`` lists input files: writing onto one of them is refused (inputs are never
    overwritten). The temporary keeps ``path``'s suffix so writers that look at it still work;
    ``write`` creates it. Its name is chosen before it exists, so an interrupt (Ctrl-C) at any
    moment leaves no temporary behind; folders made for ``path`` are removed again when the
    write fails (and they are still empty). A file-system failure (read-only folder, disk
    full) is one InputError naming ``path``.
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
    tmp = path.parent / f".{path.stem}.{secrets.token_hex(6)}{path.suffix}"
    made = [p for p in (path.parent, *path.parent.parents) if not p.exists()]
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write(tmp)
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):  # absent, or a read-only folder
            tmp.unlink()
        for folder in made:  # deepest first: only the folders made for it, if still empty
            with contextlib.suppress(OSError):
                folder.rmdir()
        if isinstance(exc, OSError):
            raise InputError(f"cannot write {path}: {exc.strerror or exc}") from None
        raise


def check_named_file(path: Path, what: str) -> None:
    """InputError unless ``path`` (a file an option names: "skeleton", "body model") is a
    regular file: a missing one is "no such WHAT file", a folder, FIFO or device said as such
    (before anything is opened: reading a FIFO would wait forever)."""
    if not os.path.lexists(path):
        raise InputError(f"no such {what} file: {path}")
    check_regular(path)


MOTION_SUFFIXES = (".npz",)


def check_regular(path: Path) -> None:
    """InputError unless ``path`` is a regular file: missing, a folder, a FIFO, a device or a
    socket are refused before anything is opened (reading a FIFO would wait forever)."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise InputError(f"no such file: {path}") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    if stat.S_ISDIR(mode):
        raise InputError(f"{path} is a folder, expected a file")
    if not stat.S_ISREG(mode):
        what = "a FIFO (named pipe)" if stat.S_ISFIFO(mode) else "a device or socket"
        raise InputError(f"{path} is {what}, not a file: give a regular file")


def expand_inputs(
    inputs: Iterable[Path],
    suffixes: tuple[str, ...] = MOTION_SUFFIXES,
    skip: Iterable[Path] = (),
    *,
    by_target: bool = False,
    notes: list[str] | None = None,
) -> list[tuple[Path, Path]]:
    """Expand files and folders into ``(file, relative_path)`` pairs, sorted.

    A folder contributes every file below it whose name ends in one of ``suffixes`` (any
    case, ``.gz`` variants included; hidden files and folders skipped), with its path relative
    to the folder; a file given directly contributes its own name. Each path found is its own
    item, a symlink too (``a/link.npz -> ../b/take.npz`` and ``b/take.npz`` are two items, two
    outputs); the same path named twice (or named and also inside a folder named) counts
    once. ``by_target``: paths to one file count once too (a training corpus: a take linked
    from two places is still one take). A broken symlink in a folder is skipped, with
    ``"<relative path>: a broken link (to <target>); skipped"`` appended to ``notes``. A folder
    in ``skip`` that lies inside a folder named is left out of it (e.g. the output folder kept
    inside the input folder: a second run must not read the first one's outputs). A missing
    path raises InputError.
    """
    skip = [Path(s).resolve() for s in skip]
    out: list[tuple[Path, Path]] = []
    for item in inputs:
        item = Path(item)
        if item.is_dir():
            root = item.resolve()
            inner = [s for s in skip if s != root and s.is_relative_to(root)]
            for f in sorted(item.rglob("*")):
                name = f.name.lower().removesuffix(".gz")
                rel = f.relative_to(item)
                if not name.endswith(suffixes) or any(p.startswith(".") for p in rel.parts):
                    continue
                if any(f.resolve().is_relative_to(s) for s in inner):
                    continue
                side = pipeline_side_file(f)
                if side is not None and f.is_file():
                    if notes is not None:
                        notes.append(f"{rel.as_posix()}: {side}, not a motion; skipped")
                elif f.is_file():
                    out.append((f, rel))
                elif f.is_symlink() and not f.exists():
                    if notes is not None:
                        notes.append(f"{rel.as_posix()}: {_broken_link(f)}; skipped")
        elif item.exists():
            check_regular(item)
            out.append((item, Path(item.name)))
        else:
            raise InputError(f"no such file or folder: {item}")
    unique, seen = [], set()
    for f, rel in out:
        key = f.resolve() if by_target else entry_of(f)
        if key not in seen:
            seen.add(key)
            unique.append((f, rel))
    return unique


#: the side files video pipelines write beside their results, by name: (what sits beside
#: them, the pipeline); a folder of results holds them, and they are not motions
SIDE_FILES = {
    ("camera.npy", "boxes.npy", "masks.npy", "tracks.npy"): ("hps", "TRAM"),
    ("tracking_results.pth", "slam_results.pth"): ("wham_output.pkl", "WHAM"),
}


def pipeline_side_file(path: Path) -> str | None:
    """What ``path`` is when it is a side file of a video pipeline's results (TRAM's
    ``camera.npy`` beside its ``hps/`` folder, WHAM's ``slam_results.pth`` beside its
    ``wham_output.pkl``), in words; None for any other file."""
    name = path.name.lower()
    for names, (beside, pipeline) in SIDE_FILES.items():
        if name in names and (path.parent / beside).exists():
            return f"{pipeline}'s {path.name} beside {beside}"
    return None


def entry_of(path: Path) -> Path:
    """The folder entry ``path`` names: its folder resolved, its own name kept (a symlink is
    an entry of its own, not the file it points to)."""
    path = Path(path).absolute()
    return path.parent.resolve() / path.name


def _broken_link(path: Path) -> str:
    """``a broken link (to TARGET)``, or ``a link that loops`` (``path`` is a symlink)."""
    try:
        target = os.readlink(path)
    except OSError:
        return "a broken link"
    try:
        path.resolve(strict=True)
    except RuntimeError:  # Python 3.11 raises this for a loop
        return "a link that loops"
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "a link that loops"
    return f"a broken link (to {target})"
