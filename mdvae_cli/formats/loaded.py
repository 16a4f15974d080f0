"""What reading one motion file gives: :class:`LoadedFile` (``formats.registry.read``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mdvae_cli.errors import InputError
from mdvae_cli.motion.motion import Motion


@dataclass
class LoadedFile:
    """What :func:`read` read from one file.

    path: the file; format: its format name (FORMATS, "gvhmr-npz", "bvh" or "amc"); kind:
    "video" for a video pipeline's estimates, "mocap" otherwise (denoise settings follow it);
    tracks: ``(label, motion)`` per person, label None when the file holds one motion; notes:
    remarks about the file as a whole; take: a BVH/AMC take as read (``retarget.take.Take``),
    for writing it back on its own skeleton; document: a video pipeline's file as read
    (``formats.video_back.VideoDocument``), for writing it back in its own form.
    """

    path: Path
    format: str
    kind: str
    tracks: list[tuple[str | None, Motion]]
    notes: list[str] = field(default_factory=list)
    take: Any = None
    document: Any = None

    def single(self) -> Motion:
        """The one motion of the file; InputError when it holds several tracks."""
        if len(self.tracks) != 1:
            labels = ", ".join(str(lab) for lab, _ in self.tracks)
            raise InputError(
                f"{self.path}: holds {len(self.tracks)} tracks ({labels}); pick one with --track ID"
            )
        return self.tracks[0][1]
