"""A mocap take (BVH, ASF/AMC) read for cleaning and written back on its own skeleton.

:func:`read_take` retargets the take onto the SMPL body at its own frame rate (one SMPL frame
per file frame) and keeps what writing it again needs; :func:`write_take` carries a cleaned
version of that SMPL motion back onto the file's skeleton (``motion.way_back``) and writes it
in the file's own form.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.motion.amc_write import write_amc
from mdvae_cli.motion.asf import AsfSkeleton
from mdvae_cli.motion.bvh_write import write_bvh
from mdvae_cli.motion.fit_shape import BodyJoints, fit_betas
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.retarget import RetargetResult, import_motion, load_source
from mdvae_cli.motion.source import SourceMotion
from mdvae_cli.motion.way_back import write_back_data
from mdvae_cli.motion.way_back_amc import write_back_amc

#: take suffixes (``.gz`` variants too); each is written back in its own form
TAKE_SUFFIXES = (".bvh", ".amc")


@dataclass
class Take:
    """A take as read: the source motion (with its file layout) and its retarget onto SMPL."""

    path: Path
    source: SourceMotion
    retarget: RetargetResult

    @property
    def motion(self) -> Motion:
        """The SMPL motion (AMASS layout, z up), one frame per file frame."""
        return self.retarget.motion


def read_take(
    path: Path | str,
    body: BodyJoints,
    skeleton: AsfSkeleton | Path | str | None = None,
    joint_map: dict[str, str] | None = None,
    scale: float | None = None,
    fps: float | None = None,
    betas: np.ndarray | None = None,
    source: SourceMotion | None = None,
) -> Take:
    """Read a BVH or AMC take and retarget it onto ``body`` at the take's own frame rate.

    skeleton: the ASF of an AMC take. joint_map: SMPL joint -> source joint names the
    skeleton's names do not reveal. scale: metres per file unit (default: guessed). fps: the
    take's true rate when its file is wrong. betas: the body shape (default: fitted).
    source: the take already read with :func:`load_source` (the other arguments but body and
    betas are then unused).
    """
    path = Path(path)
    src = source or load_source(path, skeleton, fps=fps, scale=scale, joint_map=joint_map)
    if betas is None:
        try:
            betas = fit_betas(src, body)
        except InputError as exc:
            raise InputError(f"{path}: {exc}") from None
    try:
        rt = import_motion(src, body, fps=None, betas=betas, metadata={"file": path.name})
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
    if not np.isfinite(rt.mean_error):
        raise InputError(f"{path}: the retarget to the body gave non-finite values")
    return Take(path=path, source=src, retarget=rt)


def write_take(
    take: Take, cleaned: Motion, out: Path | str, body: BodyJoints, forbid: tuple = ()
) -> None:
    """Write ``cleaned`` (the take's SMPL motion after cleaning) on the take's own skeleton,
    in the take's own form: a BVH take as BVH (``.bvh`` or ``.bvh.gz``), an AMC take as AMC
    (``.amc`` or ``.amc.gz``; its ASF is unchanged)."""
    out = Path(out)
    name = out.name.lower().removesuffix(".gz")
    form = take.source.info.get("format")
    if form not in ("bvh", "amc") or not name.endswith(f".{form}"):
        raise InputError(f"{out}: a {form} take is written back as .{form}, or as .npz")
    if form == "bvh":
        data = write_back_data(take.source, take.retarget, take.motion, cleaned, body)
        if not np.isfinite(data).all():
            raise InputError(f"{take.path}: the way back gave non-finite values; nothing written")
        write_bvh(take.source.layout, data, out, forbid=forbid)
        return
    try:
        values = write_back_amc(take.source, take.retarget, take.motion, cleaned, body)
    except InputError as exc:
        raise InputError(f"{take.path}: {exc}; nothing written") from None
    write_amc(take.source.layout, values, out, forbid=forbid)
