"""A take's file read into a :class:`SourceMotion` on its own skeleton (``.bvh`` or ``.amc``,
``.gz`` too), its rest pose made to stand and its length unit checked: all numpy, so that a
file can be read while torch loads (:mod:`mdvae_cli.run.read_ahead`)."""

from __future__ import annotations

from pathlib import Path

from mdvae_cli.errors import InputError
from mdvae_cli.formats.asf import AsfSkeleton
from mdvae_cli.formats.asfamc import load_amc
from mdvae_cli.formats.bvh import load_bvh
from mdvae_cli.formats.source import SourceMotion
from mdvae_cli.motion.motion import check_fps
from mdvae_cli.retarget.joint_map import build_joint_map
from mdvae_cli.retarget.upright import stature_unit, upright_rest


def load_source(
    path: Path | str,
    skeleton: Path | str | AsfSkeleton | None = None,
    fps: float | None = None,
    scale: float | None = None,
    max_frames: int | None = None,
    joint_map: dict[str, str] | None = None,
) -> SourceMotion:
    """Read a ``.bvh`` or ``.amc`` file (``.gz`` too) into a :class:`SourceMotion`.

    skeleton: the ``.asf`` an AMC motion needs. fps: the true frame rate when the file's is
    wrong (AMC files have none: 120 is assumed). scale: metres per file unit. A rate outside
    FPS_RANGE (e.g. a BVH Frame Time of 120, a rate written as a frame time) is refused.
    joint_map: SMPL joint name -> source joint name, for joints the names do not reveal.
    A BVH rest pose that does not stand is replaced by the take's most upright frame, and a
    guessed length unit is checked against the body's stature from its bone lengths.
    """
    name = Path(path).name.lower().removesuffix(".gz")
    if name.endswith(".bvh"):
        src = load_bvh(path, scale=scale, max_frames=max_frames)
    elif name.endswith(".amc"):
        if skeleton is None:
            raise InputError(f"{path}: an AMC motion needs its ASF skeleton (pass --asf)")
        src = load_amc(path, skeleton, fps=fps, scale=scale, max_frames=max_frames)  # no rate
    else:
        raise InputError(f"{path}: not a .bvh or .amc file")
    if joint_map:
        src.info["joint_map"] = dict(joint_map)
    if fps is not None and abs(fps - src.fps) > 1e-9:
        src = src.with_fps(fps)
        src.notes.append(f"frame rate {src.info.get('fps_in_file'):g} in the file, {fps:g} used")
    check_fps(
        src.fps,
        str(path),
        swapped="is its Frame Time a frame rate?",
        remedy="give the rate with --fps (mdvae import: --source-fps)",
    )
    if src.info.get("format") == "bvh":
        try:
            jmap = build_joint_map(src)
        except InputError:
            return src  # the retarget says what is missing
        src = stature_unit(upright_rest(src, jmap), jmap)
    return src
