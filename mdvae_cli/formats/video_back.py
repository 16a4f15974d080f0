"""A video pipeline's result written back in its own form: the file as it was read, each
cleaned track's parameters put back where the pipeline keeps them, in its frame and layout.

What changes is only what the cleaning changed. For each row of a track (a frame the file
has), the root rotation is the cleaned one taken back to the file's frame (the inverse of
``video_tracks.track_to_motion``); the translation is the file's own plus the cleaning's
change of the pelvis, taken back to the file's frame (so the body model's rest pelvis, which
the reading added, cancels); each body joint the cleaning left as it was keeps the file's own
value, bit for bit, as does every row it left alone. Camera-frame copies of a world-frame pose
(WHAM's ``pose`` / ``trans``, GVHMR's ``smpl_params_incam``) follow by the file's own
per-frame camera: ``R_c = R_cam R_world^T`` from the file's two roots, the new camera root
``R_c R_world'`` and translation ``t_cam + R_c (t_world' - t_world)``. Arrays derived from
the old pose that would now contradict it (vertices, joints from the pose, network internals)
are left out with a note; the weak-perspective crop cameras a translation is made from
(TRAM's ``pred_cam``, PHALP's ``camera_bbox``) are solved for the new one
(``video_rows.crop_camera_follows``); the pipeline's other per-frame estimates (2D and 3D
keypoints it detected, boxes) stay as they came. Where the file holds NaN / inf (holes), the
filled values themselves go into every copy (``formats.video_holes``). Frames a WHAM,
VIBE / PARE, ROMP or PHALP track lacks (gaps in its frame ids) get a row each, filled by the
cleaning, its other arrays (betas, the camera its camera-frame copy follows, VIBE's
weak-perspective camera and boxes, PHALP's per-person entries in that frame) the nearest
row's (``video_gap_rows.gap_rows_added``, ``phalp_rows_added``).

    doc = loaded.document                        # formats.registry.read of a video file
    notes = write_video(doc, {label: cleaned}, Path("clean.pkl"))

The rows and the array layouts they go into: ``formats.video_rows``; the containers:
``formats.data_write``.
"""

from __future__ import annotations

import copy
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.formats.data_write import write_data
from mdvae_cli.formats.hybrik_holes import hybrik_rows_filled
from mdvae_cli.formats.video_gap_rows import gap_rows_added, phalp_rows_added
from mdvae_cli.formats.video_holes import scales_in_holes, weak_camera_in_holes
from mdvae_cli.formats.video_layout import track_items
from mdvae_cli.formats.video_people_back import put_phalp, put_romp, put_slahmr, romp_track
from mdvae_cli.formats.video_rows import (
    Rows,
    camera_follows,
    crop_camera_follows,
    file_rows,
    put_axis_angle,
    put_betas,
    put_body,
    put_matrices,
    put_root,
    put_transl,
    row_scales,
    six_d_follows,
    track_ids,
)
from mdvae_cli.formats.video_side import side_files_copied
from mdvae_cli.formats.video_tracks import RawTrack
from mdvae_cli.motion.motion import Motion

#: the container each format is written back in (formats not named: .npz only)
OWN_CONTAINER = {
    "wham": "joblib",
    "vibe": "joblib",
    "hybrik": "pickle",
    "aistpp": "pickle",
    "gvhmr": "torch",
    "tram": "npy",
    "phalp": "joblib-zlib",
    "romp": "npz",
    "slahmr": "npz",
}
#: formats whose contents are a flat dict of arrays: one that came as an ``.npz`` (AIST++
#: motion re-saved by ``np.savez``) goes back as one
FLAT_FORMATS = ("aistpp",)
#: the pickle containers, any of which a pickled format may come in and go back in
_PICKLES = ("pickle", "joblib", "joblib-zlib", "joblib-gzip")
#: the file names each container is written under (``.gz`` not: the pipelines do not read it)
CONTAINER_SUFFIXES = {
    "joblib": (".pkl", ".pk", ".pickle", ".joblib"),
    "joblib-zlib": (".pkl", ".pk", ".pickle", ".joblib"),
    "pickle": (".pkl", ".pk", ".pickle", ".joblib"),
    "torch": (".pt", ".pth"),
    "npy": (".npy",),
    "npz": (".npz",),
}


@dataclass
class VideoDocument:
    """A video pipeline's file as read: format name, its decoded contents (``data``), and
    per track the raw estimates (file frame), its label in ``LoadedFile.tracks`` and the
    motion read from it."""

    format: str
    data: Any
    tracks: list[tuple[str | None, RawTrack, Motion]] = field(default_factory=list)
    #: the pickle container the file came in (``data_files.pickled_container``), if one
    container: str | None = None

    @property
    def npz_born(self) -> bool:
        """Whether this file came as an ``.npz`` of a flat format (:data:`FLAT_FORMATS`)."""
        return self.container == "npz" and self.format in FLAT_FORMATS

    @property
    def writable(self) -> bool:
        """Whether mdvae writes this format back in its own form."""
        return self.format in OWN_CONTAINER

    def own_form(self) -> str:
        """The form this file is written back in, in words."""
        if not self.writable:
            return f"mdvae writes {self.format} results as .npz only"
        names = " / ".join(CONTAINER_SUFFIXES[OWN_CONTAINER[self.format]])
        return f"a {self.format} result is written back as {names}"

    def written_container(self, path: Path | str | None = None) -> str:
        """The container this file is written back in: the one it came in where the format
        is a pickle of some kind (a WHAM file saved compressed, or re-saved as a plain
        pickle, comes back so), or where it came as an ``.npz`` of a flat format and goes
        to one (``path``), else the format's own (OWN_CONTAINER)."""
        if self.npz_born and path is not None and Path(path).suffix.lower() == ".npz":
            return "npz"
        own = OWN_CONTAINER[self.format]
        if own in _PICKLES and self.container in _PICKLES:
            return self.container
        return own


def writes_back(doc: VideoDocument | None, path: Path | str) -> bool:
    """Whether ``path`` names ``doc``'s own form (a suffix of its container, not ``.gz``)."""
    if doc is None or not doc.writable:
        return False
    suffix = Path(path).suffix.lower()
    return suffix in CONTAINER_SUFFIXES[OWN_CONTAINER[doc.format]] or (
        suffix == ".npz" and doc.npz_born
    )


# --------------------------------------------------------------------------------------------
# each pipeline's layout (the readers in ``formats.video_formats`` / ``video_people``)

Putter = Callable[[Any, RawTrack, Rows, list[str]], None]


def _track_dict(data: dict, raw: RawTrack) -> dict:
    """The per-track dict of a file keyed by track id (WHAM, VIBE)."""
    for key, _ in track_items(data):
        if raw.label is None or key == raw.label:
            return next(v for k, v in data.items() if str(k) == key)
    raise InputError(f"no track {raw.label} in the file")  # the reader found it: not reached


def _drop(d: dict, keys: tuple[str, ...], why: str, notes: list[str]) -> None:
    gone = [k for k in keys if k in d]
    for k in gone:
        del d[k]
    if gone:
        notes.append(f"{', '.join(repr(k) for k in gone)} left out ({why})")


def put_wham(data: dict, raw: RawTrack, rows: Rows, notes: list[str]) -> None:
    d = _track_dict(data, raw)
    world = "pose_world" in d and "trans_world" in d
    pose, trans = ("pose_world", "trans_world") if world else ("pose", "trans")
    d[pose] = put_axis_angle(d[pose], rows)
    d[trans] = put_transl(d[trans], rows)
    if "betas" in d:
        d["betas"] = put_betas(d["betas"], rows)
    if world and "pose" in d and "trans" in d:
        old = np.asarray(d["pose"])
        cam_root, d["trans"] = camera_follows(old.reshape(len(old), -1)[:, :3], d["trans"],
                                              raw.root, rows)  # fmt: skip
        cam = put_axis_angle(old, rows)  # the body joints are the world pose's
        cam.reshape(len(cam), -1)[:, :3] = cam_root
        d["pose"] = cam
    _drop(d, ("verts",), "vertices of the old pose; any SMPL tool makes them from the new", notes)


def put_vibe(data: dict, raw: RawTrack, rows: Rows, notes: list[str]) -> None:
    d = _track_dict(data, raw)
    pose = np.asarray(d["pose"])
    d["pose"] = put_axis_angle(pose, rows) if pose[0].size == 72 else put_matrices(pose, rows)
    d["betas"] = put_betas(d["betas"], rows)
    if "orig_cam" in d and rows.fill:  # its NaN rows: the camera that places the filled pelvis
        d["orig_cam"] = weak_camera_in_holes(d["orig_cam"], rows.transl)
    if np.any(rows.shift != 0):
        notes.append("the file stores no translation: 'orig_cam' kept as it came")
    _drop(d, ("verts", "joints3d"), "made from the old pose", notes)


def put_hybrik(data: dict, raw: RawTrack, rows: Rows, notes: list[str]) -> None:
    old_thetas = data["pred_thetas"]
    data["pred_thetas"] = put_matrices(old_thetas, rows)
    data["pred_betas"] = put_betas(data["pred_betas"], rows)
    key = "transl" if "transl" in data else "pred_cam_root"
    for twin in ("transl_camsys", "pred_cam_root"):  # copies of transl, scaled per frame
        scale = None if twin == key or twin not in data else row_scales(data[twin], data[key])
        if scale is not None:  # rows a hole leaves without one: as the rows beside them
            data[twin] = put_transl(data[twin], rows, scales_in_holes(scale))
        elif twin != key and twin in data and np.any(rows.shift != 0):
            notes.append(f"'{twin}' is no per-frame multiple of '{key}': kept as it came")
    data[key] = put_transl(data[key], rows)
    kept = [k for k in ("pred_xyz_29", "pred_xyz_17", "pred_xyz_24_struct", "pred_uvd")
            if k in data]  # fmt: skip
    # the rows a hole filled: every other array too (formats.hybrik_holes)
    filled = hybrik_rows_filled(data, old_thetas) if rows.fill else []
    if kept:
        notes.append(f"{', '.join(kept)} (the network's own joints) kept as they came"
                     + (" in the rows the file holds" if filled else ""))  # fmt: skip
    notes += filled


def put_aistpp(data: dict, raw: RawTrack, rows: Rows, notes: list[str]) -> None:
    scale = float(np.asarray(data.get("smpl_scaling", 1.0)).reshape(-1)[0])
    data["smpl_poses"] = put_axis_angle(data["smpl_poses"], rows)
    data["smpl_trans"] = put_transl(data["smpl_trans"], rows, scale)


def put_gvhmr(data: dict, raw: RawTrack, rows: Rows, notes: list[str]) -> None:
    world = isinstance(data.get("smpl_params_global"), dict)
    params = data["smpl_params_global" if world else "smpl_params_incam"]
    params["global_orient"] = put_root(params["global_orient"], rows)
    params["body_pose"] = put_body(params["body_pose"], rows)
    params["transl"] = put_transl(params["transl"], rows)
    for part in (params, data.get("smpl_params_incam")):
        if isinstance(part, dict) and "betas" in part:
            part["betas"] = put_betas(part["betas"], rows)
    incam = data.get("smpl_params_incam")
    if world and isinstance(incam, dict) and {"global_orient", "transl"} <= set(incam):
        if "body_pose" in incam:
            incam["body_pose"] = put_body(incam["body_pose"], rows)
        incam["global_orient"], incam["transl"] = camera_follows(
            incam["global_orient"], incam["transl"], raw.root, rows
        )
    _drop(data, ("net_outputs",), "the network's internals for the old pose", notes)


def put_tram(data: dict, raw: RawTrack, rows: Rows, notes: list[str]) -> None:
    """TRAM: ``pred_rotmat``, ``pred_trans``; ``pred_pose`` (the same rotations in 6D)
    follows ``pred_rotmat`` where it is a copy of it, ``pred_cam`` (the weak-perspective crop
    camera ``pred_trans`` is made from) ``pred_trans`` (``video_rows.crop_camera_follows``)."""
    old, trans = data["pred_rotmat"], data["pred_trans"]
    data["pred_rotmat"] = put_matrices(old, rows)
    data["pred_trans"] = put_transl(trans, rows)
    data["pred_shape"] = put_betas(data["pred_shape"], rows)
    if "pred_cam" in data:  # the crop camera pred_trans is made from: solved for the new one
        cam = crop_camera_follows(data["pred_cam"], trans, data["pred_trans"], rows.fill)
        if cam is not None:
            data["pred_cam"] = cam
        elif np.any(rows.shift != 0):
            notes.append("'pred_cam' holds no crop camera of 'pred_trans' (no positive scale "
                         "with a positive depth): kept as it came")  # fmt: skip
    if "pred_pose" in data:
        six = six_d_follows(data["pred_pose"], old, data["pred_rotmat"])
        if six is not None:
            data["pred_pose"] = six
        else:
            notes.append("'pred_pose' (6D rotations, not of 'pred_rotmat') kept as it came")


PUTTERS: dict[str, Putter] = {
    "wham": put_wham,
    "vibe": put_vibe,
    "hybrik": put_hybrik,
    "aistpp": put_aistpp,
    "gvhmr": put_gvhmr,
    "tram": put_tram,
    "phalp": put_phalp,
    "romp": put_romp,
    "slahmr": put_slahmr,
}


def write_video(
    doc: VideoDocument,
    cleaned: dict[str | None, Motion],
    path: Path | str,
    forbid: tuple[Path, ...] = (),
) -> list[str]:
    """Write ``doc``'s file to ``path`` in its own form (module docstring), each track of
    ``cleaned`` (label -> cleaned motion, labels as in ``LoadedFile.tracks``) put back; tracks
    not in it are written as they came. -> notes for the user (what was left out or kept).
    InputError for a format mdvae does not write back (write .npz)."""
    if not doc.writable:
        raise InputError(f"cannot write {path}: mdvae writes {doc.format} results as .npz only")
    data = containers_copied(doc.data)
    notes: list[str] = []
    for label, raw, before in doc.tracks:
        after = cleaned.get(label)
        if after is None:
            continue
        which = "" if label is None else f"track {label}: "
        if doc.format in ROWS_ADDED:
            raw, before, added = ROWS_ADDED[doc.format](data, raw, before, after)
            if added:
                notes.append(f"{which}{added} frame(s) missing from the file's frame ids added "
                             "as rows, filled (each other array of such a row, its camera "
                             "too, as the nearest frame the file has)")  # fmt: skip
        rows = file_rows(raw, before, after)
        PUTTERS[doc.format](data, raw, rows, notes)
        gaps = before.num_frames - len(np.unique(track_ids(raw)))
        if gaps > 0:
            holder = ("an .npz output holds them filled" if OWN_CONTAINER[doc.format] != "npz"
                      else "the AMASS-style .npz of `mdvae import` holds them for denoise to "
                      "fill")  # fmt: skip
            notes.append(
                f"{which}{gaps} frame(s) missing from the file's frame ids are not "
                f"written (the file has no rows for them; {holder})"
            )
    skipped = [str(lab) for lab, _, _ in doc.tracks if lab not in cleaned]
    if skipped:
        notes.append(f"track(s) {', '.join(skipped)} written as they came")
    if doc.format == "wham" and not isinstance(data, defaultdict):
        data = defaultdict(dict, data)  # as WHAM writes it
    write_data(data, Path(path), doc.written_container(path), forbid=forbid)
    notes += side_files_copied(doc.tracks, Path(path), forbid)
    return list(dict.fromkeys(notes))


#: ``(data, track, before, after) -> (track, before, rows added)``: rows for the frames missing
#: from a track's frame ids, filled (``video_gap_rows.gap_rows_added``)
RowsAdded = Callable[[Any, RawTrack, Motion, Motion], tuple[RawTrack, Motion, int]]


def _rows_in_dict(getter: Callable[[Any, RawTrack], dict], ids_key: str, leave=()) -> RowsAdded:
    """Rows added to a track that is a dict of per-row arrays or lists (``getter`` finds it
    in the file): ``ids_key`` its frame ids; ``leave`` the arrays left as they are (the
    putter leaves them out: not worth growing)."""
    return lambda data, raw, before, after: gap_rows_added(getter(data, raw), raw, before,
                                                           after, ids_key, leave)  # fmt: skip


#: formats whose tracks get rows for the frames missing from their frame ids
ROWS_ADDED: dict[str, RowsAdded] = {
    "wham": _rows_in_dict(_track_dict, "frame_ids", ("verts",)),
    "vibe": _rows_in_dict(_track_dict, "frame_ids", ("verts", "joints3d")),
    "romp": _rows_in_dict(romp_track, "frame_id"),
    "phalp": phalp_rows_added,
}


def containers_copied(obj: Any) -> Any:
    """``obj`` with its dicts, lists and boxed objects (0-d object arrays) copied at every
    depth and its other arrays shared: what the putters change they replace, never write
    into, so a file's large arrays (WHAM's vertices) are not held twice."""
    if isinstance(obj, dict):
        out = copy.copy(obj)  # keeps the dict's type (OrderedDict, defaultdict)
        for k, v in obj.items():
            out[k] = containers_copied(v)
        return out
    if isinstance(obj, list):
        return [containers_copied(v) for v in obj]
    if isinstance(obj, np.ndarray) and obj.dtype.hasobject and obj.ndim == 0:
        box = np.empty((), dtype=object)  # np.savez's boxed dict (ROMP): opened too
        box[()] = containers_copied(obj.item())
        return box
    return obj
