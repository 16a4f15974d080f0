"""Holes in an AMASS-style ``.npz``: NaN or infinite values in ``poses`` / ``trans`` (a solver
that lost a joint, a tracker that lost the person) read as missing joints, and written back.

Reading (:func:`read_holes`): a body joint whose axis-angle holds a NaN / inf in a frame is
missing there, and so is every joint of a frame whose ``trans`` holds one (the root
translation follows the pelvis). The motion gets ``joint_mask`` False there and finite
placeholders (``motion.holes.fill_gaps``: slerp / lerp from the observed frames); hand, jaw and
eye columns that are not finite are interpolated linearly (they are carried through, not
denoised). A joint missing in every frame, or every frame missing, is refused: there is
nothing to fill it from. The file's own values in the holes (NaN, inf, and the finite values
of a frame whose translation is missing) are kept in ``layout["as_read"]``.

Writing: a motion marked with :func:`keep_holes` (``mdvae denoise --fill off``) gets the file's
NaN / inf back in the entries where it had them (:func:`restore_holes`); otherwise holes are
written as the motion holds them (filled).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mdvae_cli.body.data import SMPL_JOINT_NAMES
from mdvae_cli.errors import InputError
from mdvae_cli.motion.motion import Motion

NUM_JOINTS = 22
#: ``layout`` key: the file's non-finite entries {"poses": (rows, cols, values), "trans": ...}
AS_READ = "as_read"
#: ``layout`` key: "as read" = write the file's non-finite values back in its holes
HOLES = "holes"


def check_holes(
    mask: np.ndarray, path: Path | str, split: bool = False, key: str = "poses"
) -> None:
    """InputError when a (T, 22) mask of finite joints leaves nothing to fill from: every
    frame missing, or a joint missing in every frame. split: the file stores the pose as
    ``root_orient`` / ``pose_body`` (named in the message instead of ``poses``)."""
    T = mask.shape[0]
    if not mask.any():
        raise InputError(
            f"{path}: '{key}' contains NaN or infinite values in every frame; nothing observed "
            "to fill it from"
        )
    never = np.flatnonzero(~mask.any(axis=0))
    if len(never):
        j = int(never[0])
        name = ("root_orient" if j == 0 else "pose_body") if split else key
        more = f" (and {len(never) - 1} more joint(s))" if len(never) > 1 else ""
        raise InputError(
            f"{path}: '{name}' contains NaN or infinite values for joint {j} "
            f"({SMPL_JOINT_NAMES[j]}) in all {T} frames{more}; a joint never observed cannot "
            "be filled"
        )


def read_holes(
    poses: np.ndarray, trans: np.ndarray, path: Path | str, split: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, dict | None, str | None]:
    """The finite-value mask of a file's pose and translation, and finite stand-ins.

    poses: (T, W) float64, may hold NaN / inf; trans: (T, 3) likewise. Returns (poses, trans)
    with non-finite entries set to 0 (the caller fills them, :func:`fill_placeholders`), the
    (T, 22) mask of observed joints (None when every body value is finite), the file's
    non-finite entries (for :func:`restore_holes`) and a note saying how many frames and joints
    miss. A hand / face column with no value in any frame (a tracker without hands) is at rest,
    0. InputError: see :func:`check_holes`.
    """
    bad_p, bad_t = ~np.isfinite(poses), ~np.isfinite(trans)
    if not bad_p.any() and not bad_t.any():
        return poses, trans, None, None, None
    from mdvae_cli.motion.holes import finite_mask, hole_count  # torch: only for holes

    mask = finite_mask(poses, trans)
    body = not mask.all()  # holes in the body: else only in hand / face columns
    if body:
        check_holes(mask, path, split, "poses" if bad_p[:, : 3 * NUM_JOINTS].any() else "trans")
    extra = int(bad_p[:, 3 * NUM_JOINTS :].any(axis=0).sum())
    never = int(bad_p[:, 3 * NUM_JOINTS :].all(axis=0).sum())  # a tracker without hands
    holes_p = bad_p.copy()  # the file's values in every hole, finite or not
    holes_p[:, : 3 * NUM_JOINTS] |= np.repeat(~mask, 3, axis=1)
    holes_t = bad_t | ~mask[:, :1]
    as_read = {
        "poses": (*np.nonzero(holes_p), poses[holes_p]),
        "trans": (*np.nonzero(holes_t), trans[holes_t]),
        "frames": len(poses),
    }
    frames, entries = hole_count(mask)
    T = len(mask)
    whole = int((~mask).all(axis=1).sum())
    notes = [
        f"NaN or infinite values in {frames} of {T} frame(s) ({whole} whole, {entries} joint "
        "entries): marked missing in joint_mask, placeholders interpolated"
    ] if body else []  # fmt: skip
    if extra > never:
        what = "" if body else "NaN or infinite values in "
        notes.append(f"{what}{extra - never} hand/face column(s) interpolated")
    if never:
        notes.append(f"{never} hand/face column(s) NaN or infinite in every frame: at rest (0)")
    note = "; ".join(notes)
    return (
        np.where(bad_p, 0.0, poses),
        np.where(bad_t, 0.0, trans),
        mask if body else None,
        as_read,
        note,
    )


def fill_placeholders(motion: Motion, trans_bad: np.ndarray) -> Motion:
    """``motion`` (its holes marked in ``joint_mask``, their values 0) with finite
    placeholders: slerp / lerp over the holes (``motion.holes.fill_gaps``); the file's own
    translation kept in frames where only the pose missed; hand / face columns that were not
    finite interpolated linearly. trans_bad: (T, 3) bool, the translation's non-finite
    entries."""
    from mdvae_cli.motion.holes import fill_gaps

    as_read = motion.layout.get(AS_READ) or {}
    rows, cols, _ = as_read.get("poses", ((), (), ()))
    rows, cols = np.asarray(rows, int), np.asarray(cols, int)
    extra = np.zeros_like(motion.pose_extra, dtype=bool)
    hand = cols >= 3 * NUM_JOINTS
    extra[rows[hand], cols[hand] - 3 * NUM_JOINTS] = True
    trans = motion.trans.copy()
    filled = fill_gaps(motion, "slerp")
    keep = ~trans_bad.any(axis=1)
    filled.trans[keep] = trans[keep]
    if extra.any():
        filled.pose_extra = interp_columns(motion.pose_extra, extra)
    return filled


def interp_columns(values: np.ndarray, bad: np.ndarray) -> np.ndarray:
    """(T, K) values with the entries where ``bad`` interpolated linearly column by column
    (the ends held)."""
    out = np.array(values, dtype=np.float64)
    frames = np.arange(len(out))
    for c in np.flatnonzero(bad.any(axis=0)):
        ok = ~bad[:, c]
        out[~ok, c] = np.interp(frames[~ok], frames[ok], out[ok, c]) if ok.any() else 0.0
    return out


def keep_holes(motion: Motion) -> Motion:
    """``motion`` marked to be written with its holes as they came (``--fill off``): an npz
    gets the file's NaN / inf back where it had them, a BVH / AMC take its own frames."""
    out = motion.with_body()
    out.layout[HOLES] = "as read"
    return out


def restore_holes(poses: np.ndarray, trans: np.ndarray, layout: dict) -> None:
    """Put a file's values in its holes (its NaN / inf) back into ``poses`` (T, W) and
    ``trans`` (T, 3), in place, when the motion was marked with :func:`keep_holes` and has
    the file's frames."""
    as_read = layout.get(AS_READ)
    if layout.get(HOLES) != "as read" or not as_read or as_read["frames"] != len(poses):
        return
    for arr, key in ((poses, "poses"), (trans, "trans")):
        rows, cols, values = as_read[key]
        if len(rows) and cols.max() < arr.shape[1]:
            arr[rows, cols] = values


def with_nan_holes(motion: Motion, mask: np.ndarray) -> Motion:
    """``motion`` to be written with NaN where ``mask`` (T, 22) is False (``add-noise
    --drop-frames / --drop-joints``): a missing joint's three ``poses`` columns, the
    translation of a frame whose pelvis is missing, and the hand / face columns of a frame
    missing whole. Its values and ``joint_mask`` are unchanged; an ``.npz`` written from it
    holds the NaN (:func:`restore_holes`) and the file's own holes it was read with, and reads
    back with both."""
    mask = np.asarray(mask, bool)
    out = motion.with_body()
    T, W = motion.num_frames, motion.poses.shape[1]
    bad_p = np.zeros((T, W), bool)
    bad_p[:, : 3 * NUM_JOINTS] = np.repeat(~mask, 3, axis=1)
    bad_p[:, 3 * NUM_JOINTS :] = (~mask).all(axis=1, keepdims=True)
    bad_t = np.repeat(~mask[:, :1], 3, axis=1)
    before = motion.layout.get(AS_READ) or {}
    as_read: dict = {"frames": T}
    for key, bad in (("poses", bad_p), ("trans", bad_t)):
        rows, cols = np.nonzero(bad)
        old = before.get(key, ((), (), ()))  # the file's own holes first: the new NaN win
        values = np.concatenate([np.asarray(old[2], float), np.full(len(rows), np.nan)])
        as_read[key] = (
            np.concatenate([np.asarray(old[0], int), rows]),
            np.concatenate([np.asarray(old[1], int), cols]),
            values,
        )
    out.layout[AS_READ] = as_read
    out.layout[HOLES] = "as read"
    return out
