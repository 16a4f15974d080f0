"""NaN / inf in a video pipeline's track (a frame the estimator failed on, a joint it lost) read
as holes, the way an AMASS ``.npz``'s are (``formats.npz_holes``), and what the write-back
needs to put the filled values into every copy the file keeps of such a frame.

Reading (:func:`track_holes`): the track's pose and translation, in the file's own frame, go
through the npz path's reading of holes (``npz_holes.read_holes``: a joint with a NaN / inf is
missing, a frame whose translation has one is missing whole; a joint never observed, or no
frame observed, is refused) and get its placeholders (``npz_holes.fill_placeholders``: slerp /
lerp from the observed frames; hand and face columns linearly). They are put in the file's
frame, before the track is stood up, so that the write-back (``formats.video_rows``) reads
the same placeholders the cleaning was handed: there the file's rows hold NaN, and it writes
the cleaned values themselves, not their change. Per-frame betas with NaN rows take the mean
of the others.

Writing: the cameras of a camera-frame copy (WHAM's ``pose`` / ``trans``, GVHMR's
``smpl_params_incam``) in frames the file holds no camera for are interpolated from the frames
it does (:func:`camera_in_holes`), and so are HybrIK's per-frame scales of its translation
copies (:func:`scales_in_holes`); VIBE / PARE's weak-perspective camera in such a frame is the
one that places the filled pelvis (:func:`weak_camera_in_holes`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.formats.video_tracks import RawTrack, matrices_to_rotvecs
from mdvae_cli.geometry.rotations_np import rotvec_to_rotmat


def track_holes(raw: RawTrack, source: str) -> RawTrack:
    """``raw`` with finite placeholders where it holds NaN / inf and ``missing`` (T, 22) set
    (module docstring), and the npz path's note; ``raw`` itself when every value is finite.
    InputError (one line) when nothing is observed to fill a hole from."""
    from mdvae_cli.formats.npz_holes import AS_READ, check_holes, fill_placeholders, read_holes
    from mdvae_cli.motion.holes import finite_mask
    from mdvae_cli.motion.motion import Motion

    who = source if raw.label is None else f"{source} track {raw.label}"
    raw = _betas_filled(raw, who)
    T = raw.num_frames
    root = np.asarray(raw.root, np.float64)
    extra = np.zeros((T, 0)) if raw.pose_extra is None else np.asarray(raw.pose_extra, float)
    body = np.asarray(raw.body, float).reshape(T, 63)
    poses = np.concatenate([matrices_to_rotvecs(root), body, extra.reshape(T, -1)], axis=1)
    trans = np.asarray(raw.transl, np.float64).reshape(T, 3)
    if np.isfinite(poses).all() and np.isfinite(trans).all():
        return raw
    mask = finite_mask(poses, trans)
    check_holes(mask, who, key="pose" if not np.isfinite(poses[:, :66]).all() else "translation")
    zeroed, trans0, mask, as_read, note = read_holes(poses, trans, who)
    held = Motion.from_poses(zeroed, trans0, np.zeros(10), 30.0, joint_mask=mask,
                             layout={AS_READ: as_read})  # fmt: skip
    filled = fill_placeholders(held, ~np.isfinite(trans))
    lost = np.zeros((T, 22), bool) if mask is None else ~mask
    root = root.copy()
    root[lost[:, 0]] = rotvec_to_rotmat(filled.root_orient[lost[:, 0]])
    body = np.where(lost[:, 1:, None], filled.pose_body, np.asarray(raw.body, float))
    transl = np.where(np.isfinite(trans).all(1, keepdims=True), trans, filled.trans)
    return replace(
        raw,
        root=root,
        body=body,
        transl=transl,
        pose_extra=None if raw.pose_extra is None else filled.pose_extra,
        missing=None if mask is None else lost,
        notes=[*raw.notes, note] if note else list(raw.notes),
    )


def _betas_filled(raw: RawTrack, who: str) -> RawTrack:
    """``raw`` with the NaN / inf rows of its per-frame betas (T, S) the mean of the others;
    InputError when no row (or a single shape) is finite."""
    betas = np.asarray(raw.betas, np.float64)
    if np.isfinite(betas).all():
        return raw
    T = raw.num_frames
    if betas.ndim < 2 or betas.shape[0] != T:
        raise InputError(f"{who}: the shape (betas) holds NaN or infinite values")
    rows = betas.reshape(T, -1)
    ok = np.isfinite(rows).all(axis=1)
    if not ok.any():
        raise InputError(f"{who}: the shape (betas) holds NaN or infinite values in every frame")
    rows = np.where(ok[:, None], rows, rows[ok].mean(axis=0))
    return replace(raw, betas=rows.reshape(betas.shape))


def _rows_at(known: np.ndarray) -> np.ndarray:
    """Fractional positions among the ``known`` (R,) rows of every row (the ends held), for
    ``motion.resample`` interpolation.  -> (R,)"""
    return np.interp(np.arange(len(known)), np.flatnonzero(known), np.arange(int(known.sum())))


def camera_in_holes(
    cam_root: np.ndarray, cam_transl: np.ndarray, world_root: np.ndarray,
    world_transl: np.ndarray, known: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The camera (world to camera) of every row of a camera-frame copy of a world-frame
    track, interpolated where the file holds none: ``R_c = R_cam R_world^T`` and ``d = t_cam -
    R_c t_world`` (so that ``t_cam = d + R_c t_world`` for any world translation) in the
    ``known`` rows, slerp / lerp between them in the others.

    cam_root, world_root: (R, 3, 3); cam_transl, world_transl: (R, 3); known: (R,) bool with
    at least one True -> R_c (R, 3, 3), d (R, 3)"""
    from mdvae_cli.motion.resample import interp_linear, interp_rotvec

    Rc = cam_root @ np.transpose(world_root, (0, 2, 1))
    d = cam_transl - np.einsum("tij,tj->ti", Rc, world_transl)
    if known.all():
        return Rc, d
    at = _rows_at(known)
    Rc = rotvec_to_rotmat(interp_rotvec(matrices_to_rotvecs(Rc[known]), at))
    return Rc, interp_linear(d[known], at)


def scales_in_holes(scales: np.ndarray) -> np.ndarray:
    """(R,) per-row scales with NaN where a row told none, those interpolated linearly from
    the others (ends held); all NaN stays so."""
    ok = np.isfinite(scales)
    if ok.all() or not ok.any():
        return scales
    return np.interp(np.arange(len(scales)), np.flatnonzero(ok), scales[ok])


def weak_camera_in_holes(orig_cam, pelvis: np.ndarray) -> np.ndarray:
    """A copy of VIBE / PARE's ``orig_cam`` (R, 4) = [sx, sy, tx, ty] whose rows with a NaN /
    inf place ``pelvis`` (R, 3) as the reader reads them (``video_formats``'s weak-perspective
    pelvis, inverted): tx, ty its x, y, sx from its depth, sy at the other rows' sy / sx."""
    from mdvae_cli.formats.video_formats import WEAK_PERSPECTIVE_FOV

    out = np.array(orig_cam, copy=True)
    cam = out.reshape(len(out), -1)
    bad = ~np.isfinite(cam).all(axis=1)
    if not bad.any() or cam.shape[1] != 4:
        return out
    focal_over_width = 0.5 / np.tan(np.radians(WEAK_PERSPECTIVE_FOV) / 2)
    sx = 2 * focal_over_width / np.maximum(pelvis[:, 2], 1e-6)
    ratio = scales_in_holes(np.where(bad, np.nan, cam[:, 1] / np.where(bad, 1.0, cam[:, 0])))
    ratio = np.where(np.isfinite(ratio), ratio, 1.0)
    new = np.stack([sx, sx * ratio, pelvis[:, 0], pelvis[:, 1]], axis=1)
    cam[bad] = new[bad].astype(cam.dtype)
    return out
