"""A cleaned video track back in the rows and frame of the pipeline's file it was read from,
and the array layouts those rows are put into (``formats.video_back`` writes the files).

What changes is only what the cleaning changed: per row (a frame the file has) the root is
the cleaned one taken back to the file's frame (the inverse of
``video_tracks.track_to_motion``), the translation the file's own plus the cleaning's change
of the pelvis in that frame (the body model's rest pelvis, which the reading added, cancels),
the body joints the cleaned ones; every value the cleaning left alone is the file's own, bit
for bit. Camera-frame copies of a world-frame pose follow by the file's own per-frame camera.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.formats.npz_holes import HOLES
from mdvae_cli.formats.video_people import phalp_entries, phalp_frames
from mdvae_cli.formats.video_tracks import RawTrack, up_to_z
from mdvae_cli.geometry.rotations_np import rotmat_to_rotvec, rotvec_to_rotmat
from mdvae_cli.motion.motion import Motion


@dataclass
class Rows:
    """A cleaned track in the file's frame, one entry per row the file has for it.

    root: (R, 3, 3); body: (R, 21, 3) axis-angles; transl: (R, 3) in the file's meaning
    (model translation or pelvis); root_moved: (R,) rows whose root the cleaning changed;
    body_moved: (R, 21) joints it changed; shift: (R, 3) the translation's change."""

    root: np.ndarray
    body: np.ndarray
    transl: np.ndarray
    root_moved: np.ndarray
    body_moved: np.ndarray
    shift: np.ndarray


def file_rows(raw: RawTrack, before: Motion, after: Motion) -> Rows:
    """``after`` (the cleaned ``before``, which ``raw`` was read into) back in the file's rows
    and frame (module docstring). Frames where ``after`` is not finite (holes left unfilled)
    keep the file's values."""
    if after.num_frames != before.num_frames:
        raise InputError(
            f"the cleaned motion has {after.num_frames} frames, the file's track "
            f"{before.num_frames}: it cannot go back in the file's own form (write .npz)"
        )
    R = raw.num_frames
    ids = track_ids(raw).astype(np.int64)
    idx = ids - ids.min()
    ok = np.isfinite(after.root_orient[idx]).all(1) & np.isfinite(after.trans[idx]).all(1)
    root_moved = ok & np.any(after.root_orient[idx] != before.root_orient[idx], axis=1)
    moved_t = ok & np.any(after.trans[idx] != before.trans[idx], axis=1)
    to_file = up_to_z(raw.up).T  # (3, 3): z-up -> the file's frame
    if raw.world is not None:  # TRAM: the camera frame, the world being per row
        to_file = raw.world[0].transpose(0, 2, 1) @ to_file
    to_file = np.broadcast_to(to_file, (R, 3, 3))
    root = np.array(raw.root, dtype=np.float64)
    root[root_moved] = to_file[root_moved] @ rotvec_to_rotmat(after.root_orient[idx][root_moved])
    change = np.where(moved_t[:, None], after.trans[idx] - before.trans[idx], 0.0)
    shift = np.einsum("tij,tj->ti", to_file, change)
    a_body, b_body = after.pose_body[idx], before.pose_body[idx]
    body_moved = np.isfinite(a_body).all(2) & np.any(a_body != b_body, axis=2)
    body = np.where(body_moved[..., None], a_body, raw.body)
    transl = np.asarray(raw.transl, np.float64) + shift
    return Rows(root, body, transl, root_moved, body_moved, shift)


# --------------------------------------------------------------------------------------------
# putting rows into arrays of the file's layouts


def near(new: np.ndarray, old: np.ndarray) -> np.ndarray:
    """Of the axis-angles that give each rotation of ``new``, the one nearest the file's
    ``old`` (an angle near 180 degrees has two: a turn of 2 pi apart), so that a value
    the cleaning barely moved does not jump in the file.  (..., 3), (..., 3) -> (..., 3)"""
    new = np.asarray(new, np.float64)
    angle = np.linalg.norm(new, axis=-1, keepdims=True)
    axis = new / np.maximum(angle, 1e-12)
    options = [axis * (angle + k * 2 * np.pi) for k in (-1, 0, 1)]
    gaps = np.stack([np.linalg.norm(o - old, axis=-1) for o in options])
    return np.choose(gaps.argmin(0)[..., None], options)


def put_axis_angle(a: Any, rows: Rows) -> np.ndarray:
    """A copy of ``a`` ((R, >= 66) or (R, J, 3): root, then the 21 body joints, as
    axis-angles) with the moved root and joints of ``rows``; its dtype kept."""
    out = np.array(a, copy=True)
    R = out.shape[0]
    flat = out.reshape(R, -1)
    moved = rows.root_moved
    flat[moved, :3] = near(rotmat_to_rotvec(rows.root[moved]), flat[moved, :3])
    body = flat[:, 3:66].reshape(R, 21, 3)
    body[rows.body_moved] = near(rows.body[rows.body_moved], body[rows.body_moved])
    flat[:, 3:66] = body.reshape(R, 63)
    return flat.reshape(out.shape)


def put_matrices(a: Any, rows: Rows) -> np.ndarray:
    """A copy of ``a`` ((R, J * 9) or (R, J, 3, 3) rotation matrices, root first) with the
    moved root and joints of ``rows``; the other joints' matrices as they were."""
    out = np.array(a, copy=True)
    R = out.shape[0]
    m = out.reshape(R, -1, 3, 3)
    m[rows.root_moved, 0] = rows.root[rows.root_moved]
    body = m[:, 1:22]
    body[rows.body_moved] = rotvec_to_rotmat(rows.body[rows.body_moved])
    m[:, 1:22] = body
    return m.reshape(out.shape)


def put_root(a: Any, rows: Rows) -> np.ndarray:
    """A copy of ``a`` ((R, 3) or (R, 1, 3) root axis-angles) with the moved roots."""
    out = np.array(a, copy=True)
    flat = out.reshape(out.shape[0], 3)
    moved = rows.root_moved
    flat[moved] = near(rotmat_to_rotvec(rows.root[moved]), flat[moved])
    return flat.reshape(out.shape)


def put_body(a: Any, rows: Rows) -> np.ndarray:
    """A copy of ``a`` ((R, >= 63) or (R, >= 21, 3) body axis-angles: the 21 body joints,
    then any others, e.g. SMPL's two hand joints, kept) with the moved joints."""
    out = np.array(a, copy=True)
    flat = out.reshape(out.shape[0], -1)
    body = flat[:, :63].reshape(-1, 21, 3)
    body[rows.body_moved] = near(rows.body[rows.body_moved], body[rows.body_moved])
    flat[:, :63] = body.reshape(-1, 63)
    return flat.reshape(out.shape)


def shifted(a: Any, shift: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """A copy of ``a`` (R rows of 3 numbers, any shape) moved by ``shift * scale`` (R, 3)
    where the shift is not zero; rows it leaves alone are the same bits."""
    out = np.array(a, copy=True)
    flat = out.reshape(out.shape[0], 3)
    moved = np.any(shift != 0, axis=1)
    flat[moved] = flat[moved] + (shift[moved] * scale).astype(flat.dtype)
    return flat.reshape(out.shape)


def row_scales(copy: Any, of: Any, rtol: float = 1e-4) -> np.ndarray | None:
    """The per-row factor that makes ``copy`` of ``of`` (R rows of 3 numbers each): ``copy
    = s * of`` row by row (HybrIK's ``transl_camsys``: its ``transl`` times 256 over the box
    width; ``pred_cam_root``: the same numbers), or None where some row is not such a
    multiple (then it is no copy).  -> (R,)"""
    c = np.asarray(copy, np.float64)
    o = np.asarray(of, np.float64)
    if c.size != o.size or c.size % 3 or c.shape[:1] != o.shape[:1]:
        return None
    c, o = c.reshape(-1, 3), o.reshape(-1, 3)
    norm2 = np.einsum("ti,ti->t", o, o)
    s = np.einsum("ti,ti->t", c, o) / np.maximum(norm2, 1e-30)
    err = np.linalg.norm(c - s[:, None] * o, axis=1)
    if not np.all(np.isfinite(s)) or np.any(err > rtol * np.linalg.norm(c, axis=1) + 1e-9):
        return None
    return s


def six_d(mats: np.ndarray) -> np.ndarray:
    """Rotation matrices as HMR 2.0's 6D numbers (TRAM's ``pred_pose``): the first column,
    then the second.  (..., 3, 3) -> (..., 6)"""
    return np.concatenate([mats[..., :, 0], mats[..., :, 1]], axis=-1)


def from_six_d(x: np.ndarray) -> np.ndarray:
    """HMR 2.0's 6D numbers as rotation matrices (Gram-Schmidt on the two columns, the third
    their cross product).  (..., 6) -> (..., 3, 3)"""
    a1, a2 = x[..., :3], x[..., 3:]
    b1 = a1 / np.maximum(np.linalg.norm(a1, axis=-1, keepdims=True), 1e-12)
    b2 = a2 - np.sum(b1 * a2, axis=-1, keepdims=True) * b1
    b2 = b2 / np.maximum(np.linalg.norm(b2, axis=-1, keepdims=True), 1e-12)
    return np.stack([b1, b2, np.cross(b1, b2)], axis=-1)


def six_d_follows(six: Any, old: Any, new: Any, tol: float = 1e-3) -> np.ndarray | None:
    """A 6D copy (``six`` (R, J * 6): TRAM's ``pred_pose``) of rotation matrices (``old``
    (R, J * 9 or J, 3, 3)) with the joints whose matrix ``new`` changed written from it; the
    others keep their numbers, bit for bit. None when ``six`` does not give ``old`` (within
    ``tol``): then it is no copy of them."""
    out = np.array(six, copy=True)
    R = out.shape[0] if out.ndim else 0
    o = np.asarray(old, np.float64).reshape(R, -1, 3, 3)
    n = np.asarray(new, np.float64).reshape(R, -1, 3, 3)
    if out.size != o.shape[1] * 6 * R or not np.all(np.isfinite(out)):
        return None
    flat = out.reshape(R, -1, 6)
    if np.abs(from_six_d(flat.astype(np.float64)) - o).max(initial=0.0) > tol:
        return None
    moved = np.any(n != o, axis=(2, 3))
    flat[moved] = six_d(n[moved]).astype(flat.dtype)
    return out


def camera_follows(
    cam_root: Any, cam_transl: Any, world_root: np.ndarray, rows: Rows
) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame copies of a world-frame pose moved as the world one was (module
    docstring): per row the file's camera ``R_c = R_cam R_world^T``, the new camera root
    ``R_c R_world'`` and translation ``t_cam + R_c (t_world' - t_world)``.

    cam_root: (R, 3) axis-angles; cam_transl: (R, 3); world_root: (R, 3, 3) the file's world
    roots as read -> the new camera root and translation, in their arrays' dtypes"""
    cam = np.array(cam_root, copy=True)
    flat = cam.reshape(cam.shape[0], 3)
    Rc = rotvec_to_rotmat(flat.astype(np.float64)) @ np.asarray(world_root).transpose(0, 2, 1)
    moved = rows.root_moved
    flat[moved] = near(rotmat_to_rotvec(Rc[moved] @ rows.root[moved]), flat[moved])
    shift = np.einsum("tij,tj->ti", Rc, rows.shift)
    return flat.reshape(cam.shape), shifted(cam_transl, shift)


def stacked(per_frame: Any) -> np.ndarray:
    """A per-frame list of arrays (or an array) as one array (R, ...)."""
    return np.stack(per_frame) if isinstance(per_frame, list | tuple) else np.asarray(per_frame)


def like(old: Any, new: np.ndarray) -> Any:
    """``new`` (R, ...) in ``old``'s form: a list of per-frame arrays of its entries' dtype
    and shape, or an array of its dtype and shape."""
    if isinstance(old, list | tuple):
        return type(old)(np.asarray(n).astype(np.asarray(o).dtype).reshape(np.shape(o))
                         for o, n in zip(old, new, strict=True))  # fmt: skip
    return np.asarray(new).astype(np.asarray(old).dtype).reshape(np.shape(old))


@dataclass(frozen=True)
class GapRows:
    """Where a track gets rows for the frames missing from its frame ids: ``frames`` (n,) the
    track's frames (from its first frame id) that have a row after, the file's own and the
    added ones, in frame order; ``nearest`` (n,) the frame each of them copies (itself for a
    row the file has); ``src`` (n,) the file's row each copies; ``ids`` (n,) their frame ids;
    ``added``: how many rows are new."""

    frames: np.ndarray
    nearest: np.ndarray
    src: np.ndarray
    ids: np.ndarray
    added: int


def gap_rows(
    raw: RawTrack, before: Motion, after: Motion, allowed: np.ndarray | None = None
) -> GapRows | None:
    """The rows a track gets for the frames missing from its frame ids that ``after`` fills
    (finite there) and ``allowed`` (T,) permits (None: all), each a copy of the nearest row
    the file has; None when there are none, or for a motion whose holes are to stay as they
    came (``npz_holes.keep_holes``: --fill off)."""
    ids = track_ids(raw).astype(np.int64)
    first, T = int(ids.min()), before.num_frames
    present = np.zeros(T, bool)
    present[ids - first] = True
    add = ~present & np.isfinite(after.root_orient).all(1) & np.isfinite(after.trans).all(1)
    if allowed is not None:
        add &= allowed
    if not add.any() or after.layout.get(HOLES) == "as read":
        return None
    have = np.flatnonzero(present)
    frames = np.flatnonzero(present | add)
    lo = have[np.clip(np.searchsorted(have, frames) - 1, 0, len(have) - 1)]
    hi = have[np.clip(np.searchsorted(have, frames), 0, len(have) - 1)]
    nearest = np.where(frames - lo <= hi - frames, lo, hi)
    row_of = np.zeros(T, np.int64)
    row_of[ids - first] = np.arange(len(ids))
    return GapRows(frames, nearest, row_of[nearest], frames + first, int(add.sum()))


def with_gap_rows(raw: RawTrack, before: Motion, plan: GapRows) -> tuple[RawTrack, Motion]:
    """The track and ``before`` as the file's rows read once ``plan``'s rows are in: each new
    row the nearest row's values, so that :func:`file_rows` puts the cleaned pose into it as
    into a row the cleaning moved."""
    src, frames, nearest = plan.src, plan.frames, plan.nearest
    raw = replace(raw, root=raw.root[src], body=raw.body[src],
                  transl=np.asarray(raw.transl)[src], frame_ids=plan.ids)  # fmt: skip
    ro, pb, tr = (np.array(a, copy=True) for a in (before.root_orient, before.pose_body,
                                                   before.trans))  # fmt: skip
    ro[frames], pb[frames], tr[frames] = ro[nearest], pb[nearest], tr[nearest]
    return raw, before.with_body(root_orient=ro, pose_body=pb, trans=tr)


def gap_rows_added(
    d: dict,
    raw: RawTrack,
    before: Motion,
    after: Motion,
    ids_key: str = "frame_ids",
    leave: tuple[str, ...] = (),
) -> tuple[RawTrack, Motion, int]:
    """A track's dict (``d``, changed in place: its per-row arrays replaced) with a row for
    each frame missing from its frame ids that ``after`` fills (:func:`gap_rows`), in frame
    order, each starting as a copy of the nearest row the file has (its betas, its camera).
    ``ids_key``: the dict's frame ids (an array or a list, kept so); arrays named in ``leave``
    stay as they are (the putter leaves them out); a per-frame list stays a list. -> (the
    track, ``before`` as the file's rows now read (:func:`with_gap_rows`), rows added)"""
    rows = len(track_ids(raw))
    plan = gap_rows(raw, before, after)
    if plan is None:
        return raw, before, 0
    for key, value in list(d.items()):
        if key in (*leave, ids_key) or np.ndim(value) < 1 or len(value) != rows:
            continue
        d[key] = type(value)(value[i] for i in plan.src) if isinstance(value, list) else (
            np.asarray(value)[plan.src])  # fmt: skip
    old_ids = d[ids_key]
    d[ids_key] = ([type(old_ids[0])(i) for i in plan.ids] if isinstance(old_ids, list)
                  else plan.ids.astype(np.asarray(old_ids).dtype))  # fmt: skip
    return (*with_gap_rows(raw, before, plan), plan.added)


def phalp_rows_added(
    data: dict, raw: RawTrack, before: Motion, after: Motion
) -> tuple[RawTrack, Motion, int]:
    """A 4D-Humans / PHALP result (``data``, changed in place) with an entry of the track for
    each frame it is missing from that the file has and the cleaning fills: in that frame's
    per-person lists (those as long as its ``tid``; all of them in a frame with nobody), a
    copy of the track's entry in the nearest frame it has. -> as :func:`gap_rows_added`"""
    frames = dict(phalp_frames(data))
    first = int(track_ids(raw).min())
    allowed = np.isin(np.arange(before.num_frames) + first, list(frames))
    plan = gap_rows(raw, before, after, allowed)
    if plan is None:
        return raw, before, 0
    entries = phalp_entries(data, raw.label)  # the file's rows: (frame, place in its lists)
    new = plan.frames != plan.nearest
    for frame_id, src in zip(plan.ids[new], plan.src[new], strict=True):
        into, (have, i) = frames[int(frame_id)], entries[src]
        people, theirs = len(into.get("tid", [])), len(have["tid"])
        for key, value in have.items():
            if not isinstance(value, list | np.ndarray) or len(value) != theirs:
                continue
            if key not in into and people == 0:
                into[key] = []
            there = into.get(key)
            if isinstance(there, list) and len(there) == people:
                there.append(copy.deepcopy(value[i]))
            elif isinstance(there, np.ndarray) and len(there) == people:
                into[key] = np.concatenate([there, np.asarray(value)[i : i + 1]])
    return (*with_gap_rows(raw, before, plan), plan.added)


def track_ids(raw: RawTrack) -> np.ndarray:
    """A track's frame ids, one per row (consecutive from 0 when the file has none)."""
    if raw.frame_ids is None:
        return np.arange(raw.num_frames)
    return np.asarray(raw.frame_ids).reshape(-1)
