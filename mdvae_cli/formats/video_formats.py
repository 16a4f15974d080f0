"""Readers for the output files of video pose pipelines: what each stores, as RawTracks.

Each reader takes the file's contents as plain containers (``formats.safe_data.load_data``) and
returns one :class:`RawTrack` per person, in the file's own frame; ``formats.video_tracks`` makes
them upright Motions. The keys, rotation forms and frames read are in docs/formats.md ("Video
pipelines"); the sources of each layout in ``video_formats.md`` of the shared data.

A detector per format looks at the keys only (:func:`detect`), so ``--format`` is needed only
for files these layouts do not tell apart.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.formats.video_layout import (
    array,
    cam_extras,
    framed,
    frames_of,
    smpl_axis_angle,
    smpl_matrices,
    stored_fps,
    track_items,
    tracks_with_frames,
)
from mdvae_cli.formats.video_people import read_phalp, read_romp, read_slahmr
from mdvae_cli.formats.video_tracks import (
    CAMERA_UP,
    Y_UP,
    RawTrack,
    rotvecs,
)
from mdvae_cli.geometry.rotations_np import rotvec_to_rotmat

#: frame rate of a video pipeline's output when the file does not say (none does)
VIDEO_FPS = 30.0
#: horizontal field of view assumed to place VIBE / PARE bodies from their weak-perspective
#: camera (they store no translation), degrees
WEAK_PERSPECTIVE_FOV = 60.0


# --------------------------------------------------------------------------------------------
# per-person dicts keyed by track id: WHAM, VIBE, PARE


def read_wham(data: dict, label: str) -> list[RawTrack]:
    """WHAM ``wham_output.pkl``: {track id: {pose, trans, pose_world, trans_world, betas,
    verts, frame_ids}}; the world frame (y up) when the track has it, else the camera's."""
    tracks = []
    items, empty = tracks_with_frames(track_items(data), "pose", label)
    for tid, d in items:
        where = f"{label} track {tid}"
        world = "pose_world" in d and "trans_world" in d
        key = "pose_world" if world else "pose"
        root, body, hands = smpl_axis_angle(array(d, key, where), key, where)
        T = len(root)
        transl = frames_of(array(d, "trans_world" if world else "trans", where), T, "trans", where)
        extras = {}
        if world and "pose" in d and "trans" in d:
            cam_root, _, _ = smpl_axis_angle(array(d, "pose", where), "pose", where)
            extras = cam_extras(cam_root, frames_of(array(d, "trans", where), T, "trans", where))
        notes = [] if world else ["no world frame in the file: camera frame, level camera"]
        if "verts" in d:
            notes.append("'verts' (made from the pose by any SMPL tool) not carried")
        tracks.append(
            RawTrack(
                root=root,
                body=body,
                transl=transl.reshape(T, 3),
                betas=array(d, "betas", where),
                up=Y_UP if world else CAMERA_UP,
                model="smpl",
                label=tid,
                pose_extra=hands,
                frame_ids=d.get("frame_ids"),
                extras=extras,
                notes=notes + stored_fps(d)[1],
                fps=stored_fps(d)[0],
            )
        )
    if empty:
        tracks[0].notes.append(empty)
    return tracks


def _weak_perspective_pelvis(cam: np.ndarray) -> np.ndarray:
    """VIBE/PARE ``orig_cam`` (T, 4) = [sx, sy, tx, ty] -> a pelvis position (T, 3): x, y from
    the camera's offsets, depth from its scale with WEAK_PERSPECTIVE_FOV."""
    focal_over_width = 0.5 / np.tan(np.radians(WEAK_PERSPECTIVE_FOV) / 2)
    sx = np.clip(cam[:, 0], 1e-3, None)
    return np.stack([cam[:, 2], cam[:, 3], 2 * focal_over_width / sx], axis=1)


def read_vibe(data: dict, label: str) -> list[RawTrack]:
    """VIBE / PARE ``*_output.pkl``: {person id: {pose (T, 72) axis-angle (VIBE) or
    (T, 24, 3, 3) matrices (PARE), betas, orig_cam, frame_ids, ...}}, camera frame, no
    translation (placed from the weak-perspective camera)."""
    tracks = []
    items, empty = tracks_with_frames(track_items(data), "pose", label)
    for tid, d in items:
        where = f"{label} track {tid}"
        pose = framed(array(d, "pose", where), "pose", where)
        if pose[0].size == 72:
            root, body, hands = smpl_axis_angle(pose, "pose", where)
        else:
            root, body, hands = smpl_matrices(pose, 24, "pose", where)
        T = len(root)
        fov = WEAK_PERSPECTIVE_FOV
        notes = [
            "no translation in the file: the pelvis is placed from the weak-perspective "
            f"camera 'orig_cam' assuming a {fov:g} degree field of view"
        ]
        if "orig_cam" in d:
            pelvis = _weak_perspective_pelvis(
                frames_of(array(d, "orig_cam", where), T, "orig_cam", where).reshape(T, -1)
            )
        else:
            pelvis, notes = np.zeros((T, 3)), ["no translation in the file: the pelvis stays put"]
        extras = {k: np.asarray(d[k], np.float32) for k in ("orig_cam", "bboxes") if k in d}
        tracks.append(
            RawTrack(
                root=root,
                body=body,
                transl=pelvis,
                betas=array(d, "betas", where),
                up=CAMERA_UP,
                model="smpl",
                label=tid,
                transl_is_pelvis=True,
                pose_extra=hands,
                frame_ids=d.get("frame_ids"),
                extras=extras,
                notes=notes + stored_fps(d)[1],
                fps=stored_fps(d)[0],
            )
        )
    if empty:
        tracks[0].notes.append(empty)
    return tracks


# --------------------------------------------------------------------------------------------
# one person per file: HybrIK, GVHMR, TRAM, AIST++


def read_hybrik(data: dict, label: str) -> list[RawTrack]:
    """HybrIK ``res.pk``: pred_thetas (T, 24*9) rotation matrices (HybrIK-X: 55 SMPL-X joints),
    pred_betas, transl = the pelvis in the camera frame (metres)."""
    thetas = framed(array(data, "pred_thetas", label), "pred_thetas", label)
    joints = thetas[0].size // 9
    if joints not in (24, 55) or thetas[0].size != joints * 9:
        raise InputError(
            f"{label}: 'pred_thetas' has shape {thetas.shape}, expected (T, 216) "
            "(SMPL) or (T, 495) (SMPL-X)"
        )
    root, body, rest = smpl_matrices(thetas, joints, "pred_thetas", label)
    T = len(root)
    key = "transl" if "transl" in data else "pred_cam_root"
    transl = frames_of(array(data, key, label), T, key, label).reshape(T, 3)
    extras = cam_extras(root, transl)
    for k in ("img_path", "bbox"):
        if k in data and np.shape(data[k])[:1] == (T,):
            extras[k] = np.asarray(data[k])
    return [
        RawTrack(
            root=root,
            body=body,
            transl=transl,
            betas=array(data, "pred_betas", label),
            up=CAMERA_UP,
            model="smpl" if joints == 24 else "smplx",
            transl_is_pelvis=True,
            pose_extra=rest,
            extras=extras,
            notes=["no world frame in the file: camera frame, level camera"] + stored_fps(data)[1],
            fps=stored_fps(data)[0],
        )
    ]


def read_gvhmr(data: dict, label: str) -> list[RawTrack]:
    """GVHMR ``hmr4d_results.pt``: smpl_params_global {global_orient, body_pose (T, 63),
    betas, transl} in the gravity-view world (y up); smpl_params_incam the same in the camera
    frame; K_fullimg intrinsics. SMPL-X body, no hands."""
    glob = data.get("smpl_params_global")
    world = isinstance(glob, dict)
    params = glob if world else data.get("smpl_params_incam")
    if not isinstance(params, dict):
        raise InputError(f"{label}: no 'smpl_params_global' or 'smpl_params_incam'")
    where = f"{label} smpl_params_{'global' if world else 'incam'}"
    root = rotvec_to_rotmat(
        rotvecs(array(params, "global_orient", where), 1, "global_orient", where)[:, 0]
    )
    T = len(root)
    body = frames_of(
        rotvecs(array(params, "body_pose", where), 21, "body_pose", where), T, "body_pose", where
    )
    transl = frames_of(array(params, "transl", where), T, "transl", where).reshape(T, 3)
    extras: dict[str, np.ndarray] = {"surface_model_type": np.array("smplx")}
    incam = data.get("smpl_params_incam")
    if world and isinstance(incam, dict) and "global_orient" in incam and "transl" in incam:
        cam_root = rotvec_to_rotmat(
            rotvecs(array(incam, "global_orient", label), 1, "global_orient", label)[:, 0]
        )
        extras.update(cam_extras(cam_root, np.asarray(incam["transl"]).reshape(-1, 3)))
    if "K_fullimg" in data and np.shape(data["K_fullimg"])[:1] == (T,):
        extras["cam_K"] = np.asarray(data["K_fullimg"], np.float32)
    notes = ["SMPL-X body (no hands in the file): poses holds the root and 21 body joints"]
    if "net_outputs" in data:
        notes.append("'net_outputs' (network internals) not carried")
    return [
        RawTrack(
            root=root,
            body=body,
            transl=transl,
            betas=array(params, "betas", where),
            up=Y_UP if world else CAMERA_UP,
            model="body",
            extras=extras,
            notes=notes + stored_fps(data)[1],
            fps=stored_fps(data)[0],
        )
    ]


def read_tram(data: dict, label: str, path: Path | None = None) -> list[RawTrack]:
    """TRAM ``hps/hps_track_<k>.npy``: pred_rotmat (T, 24, 3, 3), pred_shape, pred_trans
    (T, 1, 3) camera frame, frame (T,); with ``../camera.npy`` (world_cam_R, world_cam_T per
    video frame) the body is put in TRAM's gravity-aligned world (y up)."""
    root, body, hands = smpl_matrices(array(data, "pred_rotmat", label), 24, "pred_rotmat", label)
    T = len(root)
    transl = frames_of(array(data, "pred_trans", label), T, "pred_trans", label).reshape(T, 3)
    frames = np.asarray(data["frame"]).astype(np.int64).reshape(-1) if "frame" in data else None
    world, notes = None, []
    camera = None if path is None else path.parent.parent / "camera.npy"
    if camera is not None and camera.is_file() and frames is not None:
        from mdvae_cli.formats.data_files import load_data

        cam = load_data(camera)
        cam = cam.item() if isinstance(cam, np.ndarray) and cam.dtype.hasobject else cam
        if isinstance(cam, dict) and "world_cam_R" in cam and "world_cam_T" in cam:
            Rw, tw = np.asarray(cam["world_cam_R"], np.float64), np.asarray(cam["world_cam_T"])
            if frames.max(initial=-1) >= len(Rw):
                raise InputError(f"{label}: frame {frames.max()} beyond {camera}'s {len(Rw)}")
            world = (Rw[frames], np.asarray(tw, np.float64).reshape(-1, 3)[frames])
            notes.append(f"world frame from {camera.name} (world_cam_R, world_cam_T)")
    if world is None:
        notes.append("no camera.npy beside hps/: camera frame, level camera")
    return [
        RawTrack(
            root=root,
            body=body,
            transl=transl,
            betas=array(data, "pred_shape", label),
            up=Y_UP if world is not None else CAMERA_UP,
            model="smpl",
            pose_extra=hands,
            frame_ids=frames,
            extras=cam_extras(root, transl),
            world=world,
            notes=notes + stored_fps(data)[1],
            fps=stored_fps(data)[0],
            side_files=() if world is None else (camera,),
        )
    ]


def read_aistpp(data: dict, label: str) -> list[RawTrack]:
    """AIST++ motion pickle: smpl_poses (T, 72), smpl_trans (T, 3) scaled by smpl_scaling, y up,
    exactly 60 fps."""
    root, body, hands = smpl_axis_angle(array(data, "smpl_poses", label), "smpl_poses", label)
    T = len(root)
    scale = float(np.asarray(data.get("smpl_scaling", 1.0)).reshape(-1)[0])
    if not scale > 0:
        raise InputError(f"{label}: 'smpl_scaling' must be > 0, got {scale:g}")
    trans = frames_of(array(data, "smpl_trans", label), T, "smpl_trans", label) / scale
    return [
        RawTrack(
            root=root,
            body=body,
            transl=trans.reshape(T, 3),
            betas=np.zeros(10),
            up=Y_UP,
            model="smpl",
            pose_extra=hands,
            fps=60.0,
            extras={"smpl_scaling": np.asarray(data.get("smpl_scaling", [1.0]), np.float32)},
            notes=["no betas in AIST++: the mean shape"],
        )
    ]


# --------------------------------------------------------------------------------------------
# dispatch


Reader = Callable[[dict, str], list[RawTrack]]

#: format name -> (reader, what it looks like, the pipeline)
READERS: dict[str, tuple[Reader, str]] = {
    "wham": (read_wham, "WHAM wham_output.pkl"),
    "gvhmr": (read_gvhmr, "GVHMR hmr4d_results.pt"),
    "tram": (read_tram, "TRAM hps/hps_track_<k>.npy"),
    "phalp": (read_phalp, "4D-Humans / PHALP demo_<video>.pkl"),
    "vibe": (read_vibe, "VIBE vibe_output.pkl or PARE pare_output.pkl"),
    "hybrik": (read_hybrik, "HybrIK res.pk"),
    "romp": (read_romp, "ROMP / BEV video_results.npz"),
    "slahmr": (read_slahmr, "SLAHMR <seq>_<iter>_world_results.npz"),
    "aistpp": (read_aistpp, "AIST++ motion .pkl"),
}


def detect(data: Any) -> str | None:
    """The format of a file's contents, from its keys; None when no layout matches."""
    if isinstance(data, np.ndarray) and data.dtype.hasobject and data.ndim == 0:
        data = data.item()
    if not isinstance(data, dict) or not data:
        return None
    keys = set(map(str, data))
    if "smpl_params_global" in keys or "smpl_params_incam" in keys:
        return "gvhmr"
    if "pred_thetas" in keys:
        return "hybrik"
    if "smpl_poses" in keys:
        return "aistpp"
    if "pred_rotmat" in keys and "pred_trans" in keys:
        return "tram"
    if "sequence_results" in keys or keys == {"results"}:
        return "romp"
    if {"root_orient", "pose_body", "trans"} <= keys and np.ndim(data["root_orient"]) == 3:
        return "slahmr"
    values = [v for v in data.values() if isinstance(v, dict)]
    if len(values) != len(data):
        return None
    first = set(map(str, next((v for v in values if v), values[0])))  # an empty track: the next
    if "pose" in first and ({"trans", "pose_world", "trans_world"} & first):
        return "wham"
    if "pose" in first and ("orig_cam" in first or "pred_cam" in first):
        return "vibe"
    if "smpl" in first and "tid" in first:
        return "phalp"
    return None
