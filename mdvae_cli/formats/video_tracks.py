"""Per-person tracks of video-pipeline estimates -> upright Motions (z-up, metres, AMASS layout).

A pipeline reader (``formats.video_formats``) fills a :class:`RawTrack` with what the file holds,
in the file's own frame; :func:`track_to_motion` turns it into a :class:`Motion`:

* **frame**: every source frame is mapped to the AMASS convention (z up) by the smallest
  rotation that takes the source's up direction to +z. A y-up world (WHAM, GVHMR, TRAM, AIST++)
  becomes (x, y, z) -> (x, -z, y); a camera frame (OpenCV: x right, y down, z forward) with no
  world frame in the file is taken as a *level camera*: up is -y, so (x, y, z) -> (x, z, -y):
  the camera sits at the origin looking along +y, and a tilted camera leaves the body leaning
  by the camera's tilt. The root orientation is rotated with the frame, and the translation so
  that the pelvis stays on the body: pelvis = J0(betas) + transl (or the stored pelvis, for
  pipelines that store the pelvis), rotated, minus J0 again, with J0 the rest pelvis of the
  body model in use (the built-in one by default).
* **frames**: where ``frame_ids`` has gaps (a person not detected), the missing frames are
  filled by slerp / lerp between their neighbours and marked unobserved in ``joint_mask``;
  ``frame_ids`` in the output counts every frame.
* **layout**: ``poses`` holds root, the 21 body joints, then the model's other joints: SMPL's two
  hand joints (72 columns), SMPL-H's hands (156), SMPL-X's jaw, eyes and hands (165), or nothing
  (66) when the file has only the body; ``betas`` is the track's mean shape; extras keep
  per-frame pipeline arrays (camera-frame parameters, intrinsics) under documented names.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mdvae_cli.body.data import BodyModelData
from mdvae_cli.errors import InputError
from mdvae_cli.geometry.rotations_np import rotmat_to_rotvec, rotvec_to_rotmat
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.resample import interp_linear, interp_rotvec

#: source up directions
Y_UP = (0.0, 1.0, 0.0)
Z_UP = (0.0, 0.0, 1.0)
CAMERA_UP = (0.0, -1.0, 0.0)  # OpenCV camera: y points down
#: output ``gender`` per body model: pipelines use the neutral models
GENDER = "neutral"


@dataclass
class RawTrack:
    """One person's per-frame estimates as a pipeline stored them (its frame, its layout).

    label: the pipeline's track id (None for a file of one person); root: (T, 3, 3) root
    orientation; body: (T, 21, 3) axis-angles of the 21 body joints (SMPL order); transl:
    (T, 3) metres; transl_is_pelvis: whether ``transl`` is the pelvis position rather than the
    body model's translation; betas: (T, S) or (S,); up: the source frame's up direction;
    model: "smpl", "smplh", "smplx" or "body" (the pose layout written); pose_extra: (T, K)
    axis-angles after the body in that layout; frame_ids: (T,) video frame numbers or None
    (consecutive); observed: (T,) bool, False for frames the pipeline filled in itself (they
    are marked unobserved in ``joint_mask``), or None; missing: (T, 22) bool, True for the
    joints (pelvis: with the translation) the file holds NaN / inf for, their values here
    placeholders (``formats.video_holes``), or None; extras: per-frame (first dim T) or
    constant arrays to carry through;
    world: a ``(R (T, 3, 3), t (T, 3))`` camera-to-world transform applied before ``up`` (TRAM),
    or None; notes: remarks for the user; fps: the file's own frame rate, if it has one.
    """

    root: np.ndarray
    body: np.ndarray
    transl: np.ndarray
    betas: np.ndarray
    up: tuple[float, float, float]
    model: str = "smpl"
    label: str | None = None
    transl_is_pelvis: bool = False
    pose_extra: np.ndarray | None = None
    frame_ids: np.ndarray | None = None
    observed: np.ndarray | None = None
    missing: np.ndarray | None = None
    extras: dict[str, np.ndarray] = field(default_factory=dict)
    world: tuple[np.ndarray, np.ndarray] | None = None
    notes: list[str] = field(default_factory=list)
    fps: float | None = None
    #: files beside the result that it was read with (TRAM: its ``camera.npy``)
    side_files: tuple[Path, ...] = ()

    @property
    def num_frames(self) -> int:
        return int(self.root.shape[0])


def up_to_z(up: tuple[float, float, float] | np.ndarray) -> np.ndarray:
    """The smallest rotation taking the unit vector ``up`` to +z.  -> (3, 3)

    y-up -> R_x(+90 deg): (x, y, z) -> (x, -z, y); camera (-y up) -> R_x(-90 deg):
    (x, y, z) -> (x, z, -y); z-up -> identity.
    """
    u = np.asarray(up, dtype=np.float64)
    u = u / np.linalg.norm(u)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(u, z)
    s, c = np.linalg.norm(axis), float(u @ z)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        return np.diag([1.0, -1.0, -1.0])  # upside down: half a turn about x
    angle = np.arctan2(s, c)
    return rotvec_to_rotmat(axis / s * angle)


def pose_values(x, what: str, label: str) -> np.ndarray:
    """A pose array as float64, refused in one line when it is not real numbers, has no
    frames or holds no finite value at all (nothing to fill from). NaN / inf in some frames
    or joints are holes, kept as they are (``formats.video_holes``)."""
    a = np.asarray(x)
    if np.iscomplexobj(a):
        raise InputError(f"{label}: '{what}' holds complex numbers; poses must be real")
    if not (np.issubdtype(a.dtype, np.number) or a.dtype == bool):
        raise InputError(f"{label}: '{what}' is not numeric (dtype {a.dtype})")
    a = a.astype(np.float64)
    if a.ndim >= 1 and a.shape[0] == 0:
        raise InputError(f"{label}: '{what}' has no frames")
    if a.size and not np.isfinite(a).any():
        raise InputError(f"{label}: '{what}' holds NaN or infinite values{where_not_finite(a)}; "
                         "nothing observed to fill them from")  # fmt: skip
    return a


def where_not_finite(*arrays: np.ndarray) -> str:
    """Which rows (frames: the first axis) of equally long ``arrays`` hold a NaN or infinite
    value, in words for a message: " in 2 of 42 frames (rows 5, 6)"; "" for a 0-d array."""
    arrays = tuple(np.asarray(a) for a in arrays if np.ndim(a) >= 1)
    if not arrays or len({len(a) for a in arrays}) != 1:
        return ""
    bad = ~np.all([np.isfinite(a.reshape(len(a), -1)).all(1) for a in arrays], axis=0)
    rows = np.flatnonzero(bad)
    listed = ", ".join(map(str, rows[:5])) + (", ..." if len(rows) > 5 else "")
    return f" in {len(rows)} of {len(bad)} frame(s) (row{'s' * (len(rows) > 1)} {listed})"


def rotvecs(aa: np.ndarray, joints: int, what: str, label: str) -> np.ndarray:
    """Axis-angles of ``joints`` joints per frame from (T, joints * 3) or (T, joints, 3).
    -> (T, joints, 3) float64; InputError naming ``what`` otherwise."""
    a = pose_values(aa, what, label)
    if a.ndim < 2 or a[0].size != joints * 3:
        raise InputError(f"{label}: '{what}' has shape {a.shape}, expected (T, {joints * 3})")
    return a.reshape(a.shape[0], joints, 3)


def rotmats(m: np.ndarray, joints: int, what: str, label: str) -> np.ndarray:
    """Rotation matrices of ``joints`` joints per frame from (T, joints * 9) or
    (T, joints, 3, 3). -> (T, joints, 3, 3) float64; InputError otherwise."""
    a = pose_values(m, what, label)
    if a.ndim < 2 or a[0].size != joints * 9:
        raise InputError(f"{label}: '{what}' has shape {a.shape}, expected (T, {joints}, 3, 3)")
    a = a.reshape(a.shape[0], joints, 3, 3)
    det = np.linalg.det(np.where(np.isfinite(a), a, 0.0)) if a.size else np.ones(0)
    det[~np.isfinite(a).all(axis=(-2, -1))] = 1.0  # holes: filled later
    if np.any(np.abs(det - 1.0) > 0.5):  # drift is orthonormalised away; zeros are no rotation
        worst = float(det.reshape(-1)[np.argmax(np.abs(det - 1.0))])
        raise InputError(f"{label}: '{what}' holds matrices that are not rotations "
                         f"(determinant {worst:.3g}, a rotation's is 1)")  # fmt: skip
    return a


def matrices_to_rotvecs(m: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) (orthonormalised first: estimators' outputs drift) ->
    axis-angles (..., 3); NaN for a matrix with a NaN / inf (a hole)."""
    m = np.asarray(m, np.float64)
    ok = np.isfinite(m).all(axis=(-2, -1))
    u, _, vt = np.linalg.svd(np.where(ok[..., None, None], m, np.eye(3)))
    d = np.sign(np.linalg.det(u @ vt))
    u[..., :, -1] *= d[..., None]
    return np.where(ok[..., None], rotmat_to_rotvec(u @ vt), np.nan)


def rest_pelvis(body: BodyModelData, betas: np.ndarray) -> np.ndarray:
    """The body model's rest-pose pelvis for shape ``betas`` (extra coefficients dropped,
    missing ones zero).  betas: (S,) -> (3,)"""
    S = min(body.num_betas, betas.shape[-1])
    verts = body.v_template + body.shapedirs[..., :S] @ betas[:S]
    return body.J_regressor[0] @ verts


def track_to_motion(raw: RawTrack, fps: float, body: BodyModelData, source: str) -> Motion:
    """An upright Motion from one raw track (module docstring). ``source``: the file, for
    messages; ``fps``: the frame rate to record."""
    T = raw.num_frames
    if T < 1:
        raise InputError(f"{source}: track {raw.label} has no frames")
    arrays = [raw.root, raw.body, raw.transl, raw.betas]
    if raw.pose_extra is not None:
        arrays.append(raw.pose_extra)
    if not all(np.isfinite(a).all() for a in arrays):
        framed = [a for a in arrays if np.ndim(a) >= 1 and len(a) == T]
        who = "the track" if raw.label is None else f"track {raw.label}"
        raise InputError(f"{source}: {who} holds NaN or infinite values"
                         f"{where_not_finite(*framed)}")  # fmt: skip
    rows = np.asarray(raw.betas, dtype=np.float64)
    rows = rows.reshape(T, -1) if rows.ndim >= 2 and rows.shape[0] == T else rows.reshape(1, -1)
    betas = rows.mean(axis=0)
    notes = list(raw.notes)
    spread = float(np.ptp(rows, axis=0).max(initial=0.0))
    if spread > 0:
        notes.append(f"per-frame betas vary by up to {spread:.3g}: using their mean")
    J0 = rest_pelvis(body, betas)
    root = raw.root
    pelvis = raw.transl if raw.transl_is_pelvis else raw.transl + J0
    if raw.world is not None:
        Rw, tw = raw.world
        root = Rw @ root
        pelvis = np.einsum("tij,tj->ti", Rw, pelvis) + tw
    C = up_to_z(raw.up)
    root = rotmat_to_rotvec(C @ root)
    trans = pelvis @ C.T - J0
    pose_body = np.asarray(raw.body, dtype=np.float64)
    extra = np.zeros((T, 0)) if raw.pose_extra is None else np.asarray(raw.pose_extra, np.float64)
    extras = dict(raw.extras)
    mask = None
    if raw.observed is not None and not np.asarray(raw.observed).all():
        mask = np.repeat(np.asarray(raw.observed, dtype=bool).reshape(T, 1), 22, axis=1)
        notes.append(
            f"{int((~mask[:, 0]).sum())} frame(s) the pipeline filled in itself "
            "marked unobserved in joint_mask"
        )
    there = None if raw.missing is None else ~np.asarray(raw.missing, bool)  # (T, 22)
    if there is not None:
        mask = there if mask is None else mask & there
    if raw.frame_ids is not None:
        rows_mask = mask
        root, pose_body, trans, extra, extras, gaps, ids = _fill_gaps(
            raw.frame_ids, root, pose_body, trans, extra, extras, source, raw.label
        )
        if mask is not None:  # the file's holes and filled frames, where they land now
            rows = np.ones((len(ids), 22), bool) if gaps is None else gaps
            mask = _observed_at(raw.frame_ids, rows_mask, ids) & rows
            if there is not None:  # the frames a track skips are no NaN of the file's
                there = _observed_at(raw.frame_ids, there, ids) | ~rows
        else:
            mask = gaps
        extras["frame_ids"] = ids
        if gaps is not None:
            missing = int((~gaps[:, 0]).sum())
            notes.append(
                f"{missing} missing frame(s) filled by interpolation and marked "
                "unobserved in joint_mask"
            )
            if missing > len(ids) - missing:
                notes.append(
                    f"the track holds {len(ids) - missing} of the {len(ids)} frames its ids "
                    "span: most of what is written for it will be filled, not measured "
                    "(denoise --fill off keeps the frames it has)"
                )
    if _mean_up(root) < 0:
        notes.append("the body is upside down in this frame: is the file's frame (--format) right?")
    layout = {
        "fps_key": "mocap_framerate",
        "poses_dtype": "float32",
        "has_gender": True,
        "key_order": ["poses", "trans", "betas", "mocap_framerate", "gender"],
    }
    motion = Motion(
        root_orient=root,
        pose_body=pose_body,
        trans=trans,
        betas=betas,
        fps=float(fps),
        pose_extra=extra,
        gender=GENDER,
        joint_mask=mask,
        extras=extras,
        layout=layout,
        notes=notes,
    )
    if there is None or there.all():
        return motion
    from mdvae_cli.formats.npz_holes import HOLES, with_nan_holes

    marked = with_nan_holes(motion, there)  # an .npz written with --fill off: NaN back
    marked.layout.pop(HOLES)
    return marked


def _observed_at(src_ids, observed, ids: np.ndarray) -> np.ndarray:
    """(T', 22) the pipeline's ``observed`` (T,) flags (or (T, 22) per joint) moved onto the
    consecutive frame ids ``ids`` (T',) as :func:`_fill_gaps` orders them (the first of
    repeated ids kept); False for frames absent from ``src_ids``."""
    src = np.asarray(src_ids).reshape(-1).astype(np.int64)
    first, at = np.unique(src, return_index=True)
    flags = np.asarray(observed, bool)
    flags = flags if flags.ndim == 2 else np.repeat(flags.reshape(-1, 1), 22, axis=1)
    seen = np.zeros((len(ids), 22), bool)
    seen[first - ids[0]] = flags[at]
    return seen


def _mean_up(root_orient: np.ndarray) -> float:
    """Mean z of the pelvis's up axis (the rest body's +y) over the frames."""
    return float(rotvec_to_rotmat(root_orient)[:, 2, 1].mean())


def _frame_ids(ids, source, label) -> np.ndarray:
    """(T,) int64 frame numbers; InputError for ids that are not finite whole numbers."""
    ids = np.asarray(ids).reshape(-1)
    if ids.dtype.kind not in "iuf" or ids.size == 0:
        raise InputError(f"{source}: track {label}: frame ids of type {ids.dtype} (expected "
                         "whole numbers)")  # fmt: skip
    if ids.dtype.kind == "f":
        if not np.isfinite(ids).all() or np.any(ids != np.round(ids)):
            raise InputError(f"{source}: track {label}: frame ids that are NaN, infinite or "
                             "not whole numbers")  # fmt: skip
        if np.abs(ids).max() > 2**53:
            raise InputError(f"{source}: track {label}: frame ids beyond any video's length")
    return ids.astype(np.int64)


def _fill_gaps(ids, root, pose_body, trans, extra, extras, source, label):
    """Make frames consecutive: sort by frame id, drop repeated ids, fill gaps (module
    docstring). -> root, pose_body, trans, extra, extras, mask ((T', 22) or None), ids (T',)"""
    ids = _frame_ids(ids, source, label)
    T = root.shape[0]
    if ids.shape[0] != T:
        raise InputError(f"{source}: track {label}: {ids.shape[0]} frame ids for {T} frames")
    order = np.argsort(ids, kind="stable")
    keep = order[np.concatenate([[True], np.diff(ids[order]) > 0])]
    if 2 * len(keep) < T:
        raise InputError(f"{source}: track {label}: {T} frames but only {len(keep)} distinct "
                         "frame ids; the ids are not frame numbers")  # fmt: skip
    if len(keep) < T:  # the rows would be read as one and written back mixed
        a, b = order[np.flatnonzero(np.diff(ids[order]) == 0)[0] :][:2]
        raise InputError(f"{source}: track {label}: frame id {ids[a]} is listed twice (rows "
                         f"{a} and {b}); a track lists each frame once")  # fmt: skip
    ids = ids[keep]
    span = int(ids[-1]) - int(ids[0]) + 1  # checked before the frames are allocated
    if span > 20 * len(ids) + 1000:
        raise InputError(
            f"{source}: track {label}: frame ids {ids[0]}..{ids[-1]} for {len(ids)} frames"
        )
    full = np.arange(ids[0], ids[-1] + 1)
    if len(keep) == T and len(full) == T and np.all(keep == np.arange(T)):
        return root, pose_body, trans, extra, extras, None, ids
    pos = np.interp(full, ids, np.arange(len(ids)))
    observed = np.isin(full, ids)

    def fill_rot(a):
        return interp_rotvec(a[keep], pos)

    def fill_lin(a):
        return interp_linear(np.asarray(a[keep], dtype=np.float64), pos)

    root = fill_rot(root)
    pose_body = fill_rot(pose_body)
    trans = fill_lin(trans)
    extra = fill_lin(extra) if extra.shape[1] else np.zeros((len(full), 0))
    out = {}
    for k, v in extras.items():
        if v.ndim >= 1 and v.shape[0] == T and np.issubdtype(v.dtype, np.number):
            out[k] = (
                fill_lin(v).astype(v.dtype)
                if v.dtype.kind == "f"
                else v[keep][np.clip(np.searchsorted(ids, full, side="right") - 1, 0, len(ids) - 1)]
            )
        else:
            out[k] = v
    mask = np.repeat(observed[:, None], 22, axis=1)
    return root, pose_body, trans, extra, out, (None if observed.all() else mask), full
