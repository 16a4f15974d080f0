"""What the video-pipeline readers share: typed access to a result's arrays and the SMPL
layouts they come in (``formats.video_formats``, ``formats.video_people``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.formats.video_tracks import matrices_to_rotvecs, rotmats, rotvecs
from mdvae_cli.geometry.rotations_np import rotvec_to_rotmat


def array(d: dict, key: str, label: str) -> np.ndarray:
    if key not in d:
        raise InputError(f"{label}: no '{key}' array")
    a = np.asarray(d[key])
    if not np.issubdtype(a.dtype, np.number):
        raise InputError(f"{label}: '{key}' is not numeric (dtype {a.dtype})")
    if np.iscomplexobj(a):
        raise InputError(f"{label}: '{key}' holds complex numbers; it must be real")
    return a


def framed(a: np.ndarray, key: str, label: str) -> np.ndarray:
    """``a`` when it has at least one frame (a leading axis of length > 0)."""
    if a.ndim == 0 or a.shape[0] == 0:
        raise InputError(f"{label}: '{key}' has no frames")
    return a


def frames_of(a: np.ndarray, T: int, key: str, label: str) -> np.ndarray:
    if a.shape[0] != T:
        raise InputError(f"{label}: '{key}' has {a.shape[0]} frames, the pose {T}")
    return a


def smpl_axis_angle(pose: np.ndarray, key: str, label: str) -> tuple:
    """(T, 72) SMPL axis-angles -> root (T, 3, 3), body (T, 21, 3), hands (T, 6)."""
    aa = rotvecs(pose, 24, key, label)
    return rotvec_to_rotmat(aa[:, 0]), aa[:, 1:22], aa[:, 22:].reshape(len(aa), 6)


def smpl_matrices(mats: np.ndarray, joints: int, key: str, label: str) -> tuple:
    """(T, J, 3, 3) rotation matrices, root first -> root (T, 3, 3), body (T, 21, 3), the
    remaining joints as axis-angles (T, 3 (J - 22))."""
    m = rotmats(mats, joints, key, label)
    aa = matrices_to_rotvecs(m[:, 1:])
    return m[:, 0], aa[:, :21], aa[:, 21:].reshape(len(m), -1)


def cam_extras(root: np.ndarray, transl: np.ndarray) -> dict[str, np.ndarray]:
    """The camera-frame root and translation as the pipeline estimated them (carried)."""
    return {
        "cam_root_orient": matrices_to_rotvecs(root).astype(np.float32),
        "cam_trans": np.asarray(transl, dtype=np.float32),
    }


def track_items(data: dict) -> list[tuple[str, dict]]:
    """(label, per-track dict) of a dict keyed by track id, sorted by id."""

    def order(k):
        return (0, int(k), "") if np.issubdtype(type(k), np.integer) else (1, 0, str(k))

    return [(str(k), v) for k, v in sorted(data.items(), key=lambda kv: order(kv[0]))]


def tracks_with_frames(items: list[tuple[str, dict]], key: str, label: str):
    """Of ``items`` (``track_items``), the tracks whose ``key`` has frames, and a note naming
    those it has none in, or that hold nothing (a tracker's empty track: skipped, written back
    as it came), or None. InputError when no track has frames, and when the file is not a
    dict of per-track dicts (another pipeline's file read with the wrong ``--format``)."""
    if not items:
        raise InputError(f"{label}: holds no tracks (an empty dict)")
    odd = [(t, d) for t, d in items if not isinstance(d, dict)]
    if odd:
        t, d = odd[0]
        raise InputError(f"{label}: not a dict of per-track dicts with '{key}' (entry {t!r} "
                         f"is of type {type(d).__name__}); check --format")  # fmt: skip
    empty = [t for t, d in items if not d or (key in d and np.size(d[key]) == 0)]
    if empty and len(empty) == len(items):
        raise InputError(f"{label}: every track is empty (no frames in '{key}')")
    kept = [(t, d) for t, d in items if t not in empty]
    note = (f"track(s) {', '.join(empty)} hold no frames: skipped (written back as they came)"
            if empty else None)  # fmt: skip
    return kept, note


#: the keys a frame rate may be stored under by the scripts that save or convert these files
#: (no pipeline writes one: docs/formats.md, "Frame rate")
FPS_KEYS = ("fps", "frame_rate", "framerate", "mocap_framerate", "mocap_frame_rate")


def stored_fps(d: Any) -> tuple[float | None, list[str]]:
    """The frame rate a result's dict stores under one of FPS_KEYS (a single positive
    number), and a note saying so; (None, []) when it stores none."""
    if not isinstance(d, dict):
        return None, []
    for key in FPS_KEYS:
        value = np.asarray(d.get(key, np.nan)) if key in d else None
        if value is None or value.size != 1 or value.dtype.kind not in "iuf":
            continue
        fps = float(value.reshape(-1)[0])
        if np.isfinite(fps) and fps > 0:
            return fps, [f"the file's '{key}' gives {fps:g} fps (--fps overrides it)"]
    return None, []
