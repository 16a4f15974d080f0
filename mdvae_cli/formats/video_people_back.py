"""The write-back of the video pipelines whose files hold several people frame by frame or as a
batch (4D-Humans / PHALP, ROMP / BEV, SLAHMR): each cleaned track's rows put where the pipeline
keeps them (``formats.video_back`` writes the files; the readers: ``formats.video_people``)."""

from __future__ import annotations

import numpy as np

from mdvae_cli.formats.video_people import phalp_entries
from mdvae_cli.formats.video_rows import (
    Rows,
    crop_camera_follows,
    like,
    put_betas,
    put_body,
    put_matrices,
    put_root,
    put_transl,
    stacked,
)
from mdvae_cli.formats.video_tracks import RawTrack


def put_phalp(data: dict, raw: RawTrack, rows: Rows, notes: list[str]) -> None:
    """4D-Humans / PHALP: the track's rows are its entries in the frames taken in the
    reader's order (``video_people.read_phalp``); each entry's ``smpl`` and ``camera``, and
    ``camera_bbox`` (the crop camera ``camera`` is made from) following ``camera``."""
    entries = phalp_entries(data, raw.label)
    old = np.stack([np.asarray(f["camera"][i], np.float64).reshape(3) for f, i in entries])
    for row, (frame, i) in enumerate(entries):
        for key in ("camera", "camera_bbox"):
            if isinstance(frame.get(key), np.ndarray):  # shared with the file as read: a copy
                frame[key] = frame[key].copy()
        smpl = frame["smpl"][i]
        mats = np.concatenate([np.asarray(smpl["global_orient"]).reshape(1, 3, 3),
                               np.asarray(smpl["body_pose"]).reshape(23, 3, 3)])  # fmt: skip
        one = rows.at(slice(row, row + 1))
        new = put_matrices(mats[None], one)[0]
        dtype = np.asarray(smpl["body_pose"]).dtype
        smpl["global_orient"] = new[:1].reshape(np.shape(smpl["global_orient"])).astype(dtype)
        smpl["body_pose"] = new[1:].reshape(np.shape(smpl["body_pose"])).astype(dtype)
        frame["camera"][i] = put_transl(np.asarray(frame["camera"][i])[None], one)[0]
        betas = np.asarray(smpl["betas"])
        if betas.dtype.kind == "f" and not np.isfinite(betas).all():  # a hole's: the track's
            smpl["betas"] = put_betas(betas[None], one)[0]
    _crop_cameras(entries, old, rows, notes)
    kept = sorted({k for f in data.values() if isinstance(f, dict)
                   for k in ("3d_joints", "2d_joints") if k in f})  # fmt: skip
    if kept:
        notes.append(f"{', '.join(kept)} (the old pose's joints) kept as they came")


def _crop_cameras(entries: list, old: np.ndarray, rows: Rows, notes: list[str]) -> None:
    """The track's ``camera_bbox`` entries (PHALP's crop cameras ``[s, tx, ty]``, in its
    ``entries`` (frame, index)) made to give its cleaned ``camera`` from the one as read,
    ``old`` (R, 3) (``video_rows.crop_camera_follows``); a note where they cannot."""
    if not entries or not all(i < len(f.get("camera_bbox", ())) for f, i in entries):
        return
    new = np.stack([np.asarray(f["camera"][i], np.float64).reshape(3) for f, i in entries])
    bbox = np.stack([np.asarray(f["camera_bbox"][i]).reshape(3) for f, i in entries])
    cams = crop_camera_follows(bbox, old, new, rows.fill)
    if cams is None:
        if np.any(rows.shift != 0):
            notes.append("'camera_bbox' holds no crop camera of 'camera' (no positive scale "
                         "with a positive depth): kept as it came")  # fmt: skip
        return
    for (frame, i), cam in zip(entries, cams, strict=True):
        frame["camera_bbox"][i] = cam.reshape(np.shape(frame["camera_bbox"][i]))


def romp_track(data: dict, raw: RawTrack) -> dict:
    """The track's dict in a ROMP file's ``sequence_results`` (a dict in a 0-d object array)."""
    holder = data["sequence_results"]
    seq = holder.item() if isinstance(holder, np.ndarray) else holder
    return next(v for k, v in seq.items() if str(k) == raw.label)


def put_romp(data: dict, raw: RawTrack, rows: Rows, notes: list[str]) -> None:
    """ROMP / BEV: the track's per-frame entries in ``sequence_results`` (lists of arrays or
    arrays, kept as they were); ``cam_trans`` is the translation (``video_people.read_romp``)."""
    d = romp_track(data, raw)
    d["global_orient"] = like(d["global_orient"], put_root(stacked(d["global_orient"]), rows))
    d["body_pose"] = like(d["body_pose"], put_body(stacked(d["body_pose"]), rows))
    d["cam_trans"] = like(d["cam_trans"], put_transl(stacked(d["cam_trans"]), rows))
    d["smpl_betas"] = like(d["smpl_betas"], put_betas(stacked(d["smpl_betas"]), rows))
    made = sorted(k for k in d if k == "verts" or k.startswith(("j3d", "pj2d", "joints")))
    if made:
        notes.append(f"{', '.join(made)} (made from the old pose) kept as they came")
    if "results" in data:
        notes.append("'results' (the per-image estimates) kept as they came")


def put_slahmr(data: dict, raw: RawTrack, rows: Rows, notes: list[str]) -> None:
    """SLAHMR: track b of its (B, T, ...) arrays (a file of one track may lack the B axis)."""
    b, batched = int(raw.label), np.ndim(data["root_orient"]) == 3

    def put(key: str, fn) -> None:
        a = np.array(data[key], copy=True)
        if batched:
            a[b] = fn(a[b])
        else:
            a = fn(a)
        data[key] = a

    put("root_orient", lambda a: put_root(a, rows))
    put("pose_body", lambda a: put_body(a, rows))
    put("trans", lambda a: put_transl(a, rows))
