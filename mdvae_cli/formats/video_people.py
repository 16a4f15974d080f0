"""Readers for the video-pipeline outputs that hold several people frame by frame or as a batch:
4D-Humans/PHALP (per-frame lists grouped by track id), ROMP/BEV (``sequence_results``) and
SLAHMR (tracks stacked along a first axis). See ``formats.video_formats`` for the others."""

from __future__ import annotations

from typing import Any

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.formats.video_layout import (
    array,
    cam_extras,
    frames_of,
    smpl_axis_angle,
    smpl_matrices,
    track_items,
    tracks_with_frames,
)
from mdvae_cli.formats.video_tracks import CAMERA_UP, RawTrack, rotvecs
from mdvae_cli.geometry.rotations_np import rotvec_to_rotmat


def read_phalp(data: dict, label: str) -> list[RawTrack]:
    """4D-Humans / PHALP ``demo_<video>.pkl``: {frame name: {time, tid, smpl [{global_orient
    (1, 3, 3), body_pose (23, 3, 3), betas}], camera [(3,)], ...}}, camera frame; frames are
    grouped into tracks by ``tid``."""
    per: dict[str, dict[str, list]] = {}
    for frame_id, f, i, tid in _entries(data):
        smpl = f["smpl"][i]
        t = per.setdefault(str(tid), {"root": [], "body": [], "betas": [], "cam": [], "frame": []})
        t["root"].append(np.asarray(smpl["global_orient"]).reshape(3, 3))
        t["body"].append(np.asarray(smpl["body_pose"]).reshape(23, 3, 3))
        t["betas"].append(np.asarray(smpl["betas"]).reshape(-1))
        t["cam"].append(np.asarray(f["camera"][i]).reshape(3))
        t["frame"].append(frame_id)
    if not per:
        raise InputError(f"{label}: no tracked person with SMPL parameters in the file")
    tracks = []
    for tid in sorted(per, key=lambda s: (len(s), s)):
        t = per[tid]
        mats = np.concatenate([np.stack(t["root"])[:, None], np.stack(t["body"])], axis=1)
        root, body, hands = smpl_matrices(mats, 24, "smpl", f"{label} track {tid}")
        cam = np.stack(t["cam"])
        tracks.append(
            RawTrack(
                root=root,
                body=body,
                transl=cam,
                betas=np.stack(t["betas"]),
                up=CAMERA_UP,
                model="smpl",
                label=tid,
                pose_extra=hands,
                frame_ids=np.asarray(t["frame"]),
                extras=cam_extras(root, cam),
                notes=["no world frame in the file: camera frame, level camera"],
            )
        )
    return tracks


def _entries(data: dict):
    """Every person entry of a PHALP result with SMPL parameters and a camera, frames in
    time order: (frame id, frame dict, index in its lists, track id)."""
    for frame_id, f in phalp_frames(data):
        for i, tid in enumerate(f.get("tid", [])):
            smpl = f.get("smpl", [None] * (i + 1))[i]
            if isinstance(smpl, dict) and i < len(f.get("camera", [])):
                yield frame_id, f, i, tid


def phalp_frames(data: dict) -> list[tuple[int, dict]]:
    """A PHALP result's frames in time order, each with the frame id its tracks' rows get:
    its ``time``, or its place in that order where it has none."""
    frames = sorted(data.items(), key=lambda kv: (_time(kv[1]), str(kv[0])))
    return [(_time(f) if _time(f) >= 0 else index, f)
            for index, (_, f) in enumerate(frames) if isinstance(f, dict)]  # fmt: skip


def phalp_entries(data: dict, label: str | None) -> list[tuple[dict, int]]:
    """The entries of one track of a PHALP result, in the order :func:`read_phalp` reads
    them (its rows): (frame dict, index in the frame's lists)."""
    return [(f, i) for _, f, i, tid in _entries(data) if label is None or str(tid) == label]


def _time(frame: Any) -> int:
    t = frame.get("time", -1) if isinstance(frame, dict) else -1
    try:
        return int(t)
    except (TypeError, ValueError):
        return -1


def read_romp(data: dict, label: str) -> list[RawTrack]:
    """ROMP / BEV ``video_results.npz``: sequence_results {track id: {frame_id, global_orient
    (3,), body_pose (69,), smpl_betas (10 or 11,), cam_trans (3,), ...} per frame}."""
    seq = data.get("sequence_results")
    seq = seq.item() if isinstance(seq, np.ndarray) and seq.dtype.hasobject else seq
    if not isinstance(seq, dict) or not seq:
        raise InputError(
            f"{label}: no tracks in 'sequence_results' (a per-frame ROMP result "
            "holds one frame: use the video_results.npz of a video run)"
        )
    tracks = []
    items, empty = tracks_with_frames(track_items(seq), "global_orient", label)
    for tid, d in items:
        where = f"{label} track {tid}"
        pose = np.concatenate(
            [np.stack(d["global_orient"]).reshape(-1, 3), np.stack(d["body_pose"]).reshape(-1, 69)],
            axis=1,
        )
        root, body, hands = smpl_axis_angle(pose, "body_pose", where)
        T = len(root)
        cam = frames_of(
            np.stack(d["cam_trans"]).reshape(-1, 3).astype(np.float64), T, "cam_trans", where
        )
        betas = np.stack(d["smpl_betas"]).reshape(T, -1)[:, :10]
        tracks.append(
            RawTrack(
                root=root,
                body=body,
                transl=cam,
                betas=betas,
                up=CAMERA_UP,
                model="smpl",
                label=tid,
                pose_extra=hands,
                frame_ids=np.asarray(d.get("frame_id", np.arange(T))),
                extras=cam_extras(root, cam),
                notes=["no world frame in the file: camera frame, level camera"],
            )
        )
    if empty:
        tracks[0].notes.append(empty)
    return tracks


def read_slahmr(data: dict, label: str) -> list[RawTrack]:
    """SLAHMR ``*_world_results.npz``: trans, root_orient (B, T, 3), pose_body (B, T, 63),
    betas (B, 16), pose_hand (B, T, 90) optional, track_mask (B, T), floor_plane; the SLAM
    world, whose up is the floor's normal (signed by the bodies)."""
    ro = array(data, "root_orient", label)
    if ro.ndim == 2:  # a single track without the batch axis
        data = {k: (np.asarray(v)[None] if np.ndim(v) >= 1 else v) for k, v in data.items()}
        ro = ro[None]
    B, T = ro.shape[:2]
    up = _floor_up(data, ro)
    hands = data.get("pose_hand", data.get("hand_pose"))
    tracks = []
    for b in range(B):
        where = f"{label} track {b}"
        body = rotvecs(array(data, "pose_body", label)[b], 21, "pose_body", where)
        extra = None if hands is None else np.asarray(hands[b], np.float64).reshape(T, -1)
        observed = None
        if "track_mask" in data:
            observed = np.asarray(data["track_mask"][b]).astype(bool).reshape(T)
        tracks.append(
            RawTrack(
                root=rotvec_to_rotmat(ro[b].astype(np.float64)),
                body=body,
                transl=array(data, "trans", label)[b].reshape(T, 3),
                betas=array(data, "betas", label)[b],
                up=up,
                model="smplh" if extra is not None and extra.shape[1] == 90 else "body",
                label=str(b),
                pose_extra=extra,
                observed=observed,
            )
        )
    return tracks


def _floor_up(data: dict, root_orient: np.ndarray) -> tuple[float, float, float]:
    """SLAHMR's up: the floor plane's normal, signed to agree with the bodies' mean up. The
    plane is SLAHMR's 3-vector (its normal times its distance) or a plane's (a, b, c, d), one
    or one per track (the first is taken)."""
    rv = root_orient.reshape(-1, 3).astype(np.float64)
    body_up = rotvec_to_rotmat(rv[np.isfinite(rv).all(1)])[:, :, 1].mean(0)  # holes: not read
    plane = np.asarray(data.get("floor_plane", CAMERA_UP), np.float64)
    if plane.ndim == 0 or plane.size == 0 or plane.shape[-1] not in (3, 4):
        raise InputError(f"'floor_plane' has shape {plane.shape}: expected (3,) (a normal) or "
                         "(4,) (a, b, c, d), one per track or one for all")  # fmt: skip
    n = plane.reshape(-1, plane.shape[-1])[0, :3]
    n = n / max(np.linalg.norm(n), 1e-9) if np.linalg.norm(n) > 1e-9 else np.array(CAMERA_UP)
    return tuple(n if n @ body_up >= 0 else -n)
