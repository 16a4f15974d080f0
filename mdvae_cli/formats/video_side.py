"""The side files a video pipeline's result was read with, beside its written-back copy.

TRAM keeps a result's world in ``camera.npy`` two folders above ``hps/hps_track_<k>.npy``
(``video_formats.read_tram``). A cleaned track written back in TRAM's layout
(``<out>/hps/hps_track_<k>.npy``) gets a copy of that file at ``<out>/camera.npy`` when none
is there, so that TRAM's visualiser, and mdvae reading the output, put it in the same world
as the input; an output elsewhere gets a note saying where the file belongs.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from mdvae_cli.fileio import write_atomic


def side_files_copied(tracks, out: Path, forbid: tuple[Path, ...] = ()) -> list[str]:
    """Copy the side files of ``tracks`` (``(label, RawTrack, Motion)`` of a VideoDocument)
    beside ``out`` (the written-back file) as the module docstring says. -> notes."""
    notes: list[str] = []
    for side in dict.fromkeys(f for _, raw, _ in tracks for f in raw.side_files):
        target = out.parent.parent / side.name
        if target.exists():
            continue
        if out.parent.name.lower() != "hps":
            notes.append(f"its world came from {side}: TRAM (and mdvae, reading the output) "
                         f"looks for it at {target}")  # fmt: skip
            continue
        write_atomic(target, lambda tmp, src=side: shutil.copyfile(src, tmp), forbid=forbid)
        notes.append(f"{side.name} copied to {target} (the world the output is read in)")
    return notes
