"""Rows for the frames a video track skips (gaps in its frame ids), added to the pipeline's own
file when it is written back, each starting as a copy of the nearest row the file has and then
filled by the cleaning (``formats.video_back``; the rows themselves: ``formats.video_rows``)."""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace

import numpy as np

from mdvae_cli.formats.npz_holes import HOLES
from mdvae_cli.formats.video_people import phalp_entries, phalp_frames
from mdvae_cli.formats.video_rows import track_ids
from mdvae_cli.formats.video_tracks import RawTrack
from mdvae_cli.motion.motion import Motion


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
                  transl=np.asarray(raw.transl)[src], frame_ids=plan.ids,
                  missing=None if raw.missing is None else raw.missing[src])  # fmt: skip
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
