"""What the file commands share about reading motion: the ``--format``, ``--fps`` and ``--track``
options, the suffixes folders are searched for, and reading a file with its notes shown.

A file of several people (a WHAM or PHALP result with several tracks) gives one output per
track (``run.tracks.outputs_of``); ``--track ID`` keeps one track, written to the output
itself.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import click

from mdvae_cli.cli.batch import print_notes
from mdvae_cli.cli.common import POSITIVE
from mdvae_cli.formats.registry import (
    ALIASES,
    FORMATS,
    READ_SUFFIXES,
    LoadedFile,
    ReadOptions,
    read,
)

#: what folders are searched for by the commands that read any motion file
INPUT_SUFFIXES = READ_SUFFIXES


FORMATS_HELP = (
    "amass (AMASS-style .npz), a video pipeline's output (wham, gvhmr, tram, phalp, vibe/pare, "
    "hybrik, romp/bev, slahmr) or aistpp (docs/formats.md)."
)


def format_choice() -> click.Choice:
    """The ``--format`` values: every format name and alias, any case."""
    return click.Choice(sorted({*FORMATS, *ALIASES}), case_sensitive=False)


#: ``--fps``: the inputs' frame rate, for every command that reads motion files
input_fps_option = click.option(
    "--fps",
    "input_fps",
    type=POSITIVE,
    default=None,
    help="Frame rate of the inputs. Video-pipeline outputs store none: 30 is assumed "
    "unless given; for other files it replaces the file's rate (a BVH whose Frame Time "
    "holds a rate, say).",
)


def motion_input_options(fn: Callable) -> Callable:
    """``--format``, ``--fps`` and ``--track``: how to read the input files."""
    fn = click.option(
        "--track",
        default=None,
        metavar="ID",
        help="Files of several people: keep only this track (its id in the file). Default: "
        "every track, each written to <output>.track<ID>.npz.",
    )(fn)
    fn = input_fps_option(fn)
    return click.option(
        "--format",
        "input_format",
        type=format_choice(),
        default=None,
        help="Input format, when the file does not tell (default: from the extension and "
        "contents): " + FORMATS_HELP,
    )(fn)


def _missing_rules(ctx, param, value: str) -> tuple[str, ...]:
    """``--missing``'s text as rules (``formats.missing.parse_rules``)."""
    from mdvae_cli.errors import InputError
    from mdvae_cli.formats.missing import parse_rules

    try:
        return parse_rules(value)
    except InputError as exc:
        raise click.BadParameter(str(exc).removeprefix("--missing: ")) from None


#: ``--missing RULES``: the holes of BVH / AMC takes (``formats.missing``)
missing_option = click.option(
    "--missing",
    default="",
    metavar="RULES",
    callback=_missing_rules,
    help="BVH/AMC takes: which frames are holes, comma-separated (off by default): frozen = "
    "every channel of a joint exactly unchanged for 1/3 s or more (at least 5 frames) while "
    "other joints move, then a jump (a solver that held a lost marker's last value and caught "
    "up); zeros = a frame with every channel 0 (an exporter's empty frame). E.g. "
    "--missing frozen,zeros. They are marked in joint_mask (denoise fills them, see --fill).",
)


def read_input(
    path: Path, relpath: Path, options: ReadOptions, output: Path | None = None,
    holes: bool = False, takes=None,
) -> LoadedFile:  # fmt: skip
    """``formats.registry.read`` with the command's options, printing the file's notes.
    output: where the file goes (``holes``: written with holes), for the notes
    (``run.tracks.reader_notes``). takes: a ``retarget.take.TakeReader`` shared over the
    command's files."""
    from mdvae_cli.run.tracks import own_output, reader_notes

    loaded = read(path, options, takes=takes)
    own = output is not None and own_output(loaded, output, holes)[1]
    print_notes(relpath, loaded.notes)
    for label, motion in loaded.tracks:
        where = relpath if label is None else Path(f"{relpath.as_posix()} track {label}")
        print_notes(where, reader_notes(motion.notes, own))
    return loaded


def track_option(what: str, otherwise: str = "is refused") -> Callable:
    """``--track ID`` for the commands that take one motion of a file (eval, export-bvh,
    export-mesh, view, plot): ``what`` they do with it, and what they do ``otherwise`` with a
    file of several people."""
    return click.option(
        "--track", default=None, metavar="ID",
        help=f"Files of several people (WHAM, PHALP, ...): {what}. Default: a file of "
        f"several people {otherwise}.",
    )  # fmt: skip


def one_track(loaded, track: str | None):
    """The motion of a file read (``LoadedFile``) to score: its only one, or in a file of
    several people the track ``track`` names (a file of one person is scored whatever it
    names: a cleaned track's own .npz against its pipeline's file)."""
    if track is None or len(loaded.tracks) == 1:
        return loaded.single()
    for label, motion in loaded.tracks:
        if label == str(track):
            return motion
    from mdvae_cli.errors import InputError

    labels = ", ".join(str(lab) for lab, _ in loaded.tracks)
    raise InputError(f"{loaded.path}: no track {track!r} (tracks: {labels})")
