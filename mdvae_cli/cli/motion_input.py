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


def motion_input_options(fn: Callable) -> Callable:
    """``--format``, ``--fps`` and ``--track``: how to read the input files."""
    fn = click.option(
        "--track",
        default=None,
        metavar="ID",
        help="Files of several people: keep only this track (its id in the file). Default: "
        "every track, each written to <output>.track<ID>.npz.",
    )(fn)
    fn = click.option(
        "--fps",
        "input_fps",
        type=POSITIVE,
        default=None,
        help="Frame rate of the inputs. Video-pipeline outputs store none: 30 is assumed "
        "unless given; for other files it replaces the file's rate.",
    )(fn)
    return click.option(
        "--format",
        "input_format",
        type=format_choice(),
        default=None,
        help="Input format, when the file does not tell (default: from the extension and "
        "contents): " + FORMATS_HELP,
    )(fn)


def read_input(path: Path, relpath: Path, options: ReadOptions, takes=None) -> LoadedFile:
    """``formats.registry.read`` with the command's options, printing the file's notes.
    takes: a ``retarget.take.TakeReader`` shared over the command's files."""
    loaded = read(path, options, takes=takes)
    print_notes(relpath, loaded.notes)
    for label, motion in loaded.tracks:
        where = relpath if label is None else Path(f"{relpath.as_posix()} track {label}")
        print_notes(where, motion.notes)
    return loaded
