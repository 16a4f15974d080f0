"""``add-noise --drop-frames / --drop-joints``: holes for benchmark takes, written as NaN."""

from __future__ import annotations

import re
from pathlib import Path

import click
import numpy as np

from mdvae_cli.cli.batch import print_notes
from mdvae_cli.errors import InputError
from mdvae_cli.motion.motion import Motion


class HoleSpec(click.ParamType):
    """``LENGTH[xCOUNT]`` -> (length, count): COUNT holes of LENGTH frames (COUNT default 1)."""

    name = "LENGTH[xCOUNT]"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        found = re.fullmatch(r"\s*(\d+)\s*(?:[xX*]\s*(\d+))?\s*", str(value))
        if not found or int(found[1]) < 1 or int(found[2] or 1) < 1:
            self.fail(f"expected LENGTH[xCOUNT] with whole numbers >= 1 (e.g. 15x2), got {value!r}")
        return int(found[1]), int(found[2] or 1)


HOLES = HoleSpec()


def hole_mask(
    num_frames: int,
    frames: tuple[int, int] | None,
    joints: tuple[int, int] | None,
    rng: np.random.Generator,
) -> tuple[np.ndarray, int]:
    """(T, 22) mask (False = dropped) of ``frames`` = (length, count) whole-frame holes and
    ``joints`` = (length, count) one-limb holes (``motion.holes.frame_holes`` /
    ``limb_holes``), and how many of the holes asked for did not fit into the take."""
    from mdvae_cli.motion.holes import frame_holes, limb_holes

    mask = np.ones((num_frames, 22), bool)
    short = 0
    for spec, make in ((frames, frame_holes), (joints, limb_holes)):
        if spec is None:
            continue
        length, count = spec
        part = make(num_frames, length, count, rng)
        made = _runs(part)
        short += count - made
        mask &= part
    return mask, short


def _runs(mask: np.ndarray) -> int:
    """Stretches of consecutive frames with a joint missing in a (T, 22) mask."""
    hole = (~mask).any(axis=1).astype(np.int8)
    return int((np.diff(np.concatenate([[0], hole])) == 1).sum())


def drop_holes(
    motion: Motion,
    frames: tuple[int, int] | None,
    joints: tuple[int, int] | None,
    rng: np.random.Generator,
    relpath: Path | None = None,
) -> tuple[Motion, dict]:
    """``motion`` with the holes of :func:`hole_mask` to be written as NaN, and
    {"dropped_frames", "dropped_joints"} (frames with a joint dropped, (frame, joint)
    entries); {} when neither is asked for. The input's own holes (NaN in an npz) are written
    back as they came either way. InputError when no hole fits; a note when some do not."""
    from mdvae_cli.formats.npz_holes import AS_READ, keep_holes, with_nan_holes

    if motion.layout.get(AS_READ):  # the input's own holes (its NaN) stay holes
        motion = keep_holes(motion)
    if frames is None and joints is None:
        return motion, {}
    from mdvae_cli.motion.holes import hole_count

    mask, short = hole_mask(motion.num_frames, frames, joints, rng)
    if mask.all():
        longest = max(spec[0] for spec in (frames, joints) if spec is not None)
        raise InputError(
            f"{motion.num_frames} frames hold no hole of {longest} frames (each keeps 2 "
            "observed frames at either end); give a shorter LENGTH"
        )
    if short:
        print_notes(relpath or Path("input"), [f"{short} hole(s) did not fit into the take"])
    dropped_frames, dropped_joints = hole_count(mask)
    return with_nan_holes(motion, mask), {
        "dropped_frames": dropped_frames,
        "dropped_joints": dropped_joints,
    }
