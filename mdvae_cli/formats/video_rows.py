"""A cleaned video track back in the rows and frame of the pipeline's file it was read from,
and the array layouts those rows are put into (``formats.video_back`` writes the files).

What changes is only what the cleaning changed: per row (a frame the file has) the root is
the cleaned one taken back to the file's frame (the inverse of
``video_tracks.track_to_motion``), the translation the file's own plus the cleaning's change
of the pelvis in that frame (the body model's rest pelvis, which the reading added, cancels),
the body joints the cleaned ones; every value the cleaning left alone is the file's own, bit
for bit. Camera-frame copies of a world-frame pose follow by the file's own per-frame camera.
Where the file holds NaN / inf (a hole, ``formats.video_holes``), the filled values themselves
are written (the placeholders the track was read with, moved by the cleaning), in every copy;
with ``--fill off`` those entries stay as they came.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.formats.npz_holes import HOLES
from mdvae_cli.formats.video_tracks import RawTrack, up_to_z
from mdvae_cli.geometry.rotations_np import rotmat_to_rotvec, rotvec_to_rotmat
from mdvae_cli.motion.motion import Motion


@dataclass
class Rows:
    """A cleaned track in the file's frame, one entry per row the file has for it.

    root: (R, 3, 3); body: (R, 21, 3) axis-angles; transl: (R, 3) in the file's meaning
    (model translation or pelvis); root_moved: (R,) rows whose root the cleaning changed;
    body_moved: (R, 21) joints it changed; shift: (R, 3) the translation's change; fill:
    whether entries the file holds no finite value for are written (False: ``--fill off``);
    extra: (R, K) the axis-angles after the body (hands), for such entries; missing: (R, 22)
    the joints the track was read with as holes (the pelvis: with the translation); betas:
    (S,) the track's shape, for per-frame shapes the file holds NaN / inf in."""

    root: np.ndarray
    body: np.ndarray
    transl: np.ndarray
    root_moved: np.ndarray
    body_moved: np.ndarray
    shift: np.ndarray
    fill: bool = True
    extra: np.ndarray | None = None
    missing: np.ndarray | None = None
    betas: np.ndarray | None = None

    def at(self, rows: slice) -> Rows:
        """These rows only."""
        extra = None if self.extra is None else self.extra[rows]
        missing = None if self.missing is None else self.missing[rows]
        return Rows(self.root[rows], self.body[rows], self.transl[rows], self.root_moved[rows],
                    self.body_moved[rows], self.shift[rows], self.fill, extra, missing,
                    self.betas)  # fmt: skip

    def holes(self, values: np.ndarray) -> np.ndarray:
        """Where ``values`` ((R, n, ...): n entries per row) hold a NaN / inf to be written
        over (none with ``fill`` False).  -> (R, n) bool"""
        v = np.asarray(values)
        if v.dtype.kind not in "fc" or not self.fill:
            return np.zeros(v.shape[:2], bool)
        return ~np.isfinite(v.reshape(*v.shape[:2], -1)).all(axis=-1)


def file_rows(raw: RawTrack, before: Motion, after: Motion) -> Rows:
    """``after`` (the cleaned ``before``, which ``raw`` was read into) back in the file's rows
    and frame (module docstring). Frames where ``after`` is not finite (holes left unfilled),
    and the file's holes when they stay (``--fill off``, ``add-noise``), keep the file's
    values."""
    if after.num_frames != before.num_frames:
        raise InputError(
            f"the cleaned motion has {after.num_frames} frames, the file's track "
            f"{before.num_frames}: it cannot go back in the file's own form (write .npz)"
        )
    R = raw.num_frames
    ids = track_ids(raw).astype(np.int64)
    idx = ids - ids.min()
    ok = np.isfinite(after.root_orient[idx]).all(1) & np.isfinite(after.trans[idx]).all(1)
    fill = after.layout.get(HOLES) != "as read"
    lost = np.zeros((R, 22), bool) if fill or raw.missing is None else raw.missing
    root_moved = ok & ~lost[:, 0] & np.any(after.root_orient[idx] != before.root_orient[idx], 1)
    moved_t = ok & ~lost[:, 0] & np.any(after.trans[idx] != before.trans[idx], axis=1)
    to_file = up_to_z(raw.up).T  # (3, 3): z-up -> the file's frame
    if raw.world is not None:  # TRAM: the camera frame, the world being per row
        to_file = raw.world[0].transpose(0, 2, 1) @ to_file
    to_file = np.broadcast_to(to_file, (R, 3, 3))
    root = np.array(raw.root, dtype=np.float64)
    root[root_moved] = to_file[root_moved] @ rotvec_to_rotmat(after.root_orient[idx][root_moved])
    change = np.where(moved_t[:, None], after.trans[idx] - before.trans[idx], 0.0)
    shift = np.einsum("tij,tj->ti", to_file, change)
    a_body, b_body = after.pose_body[idx], before.pose_body[idx]
    body_moved = np.isfinite(a_body).all(2) & ~lost[:, 1:] & np.any(a_body != b_body, axis=2)
    body = np.where(body_moved[..., None], a_body, raw.body)
    transl = np.asarray(raw.transl, np.float64) + shift
    extra = np.asarray(after.pose_extra, np.float64)[idx]
    betas = np.asarray(after.betas, np.float64).reshape(-1)
    return Rows(root, body, transl, root_moved, body_moved, shift, fill, extra, raw.missing, betas)


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
    hole = ~np.isfinite(gaps[1])  # the file holds no value there: the new one's own branch
    gaps = np.where(np.isfinite(gaps), gaps, np.inf)
    gaps[1][hole] = 0.0
    return np.choose(gaps.argmin(0)[..., None], options)


def put_axis_angle(a: Any, rows: Rows) -> np.ndarray:
    """A copy of ``a`` ((R, >= 66) or (R, J, 3): root, then the 21 body joints, as
    axis-angles) with the moved root and joints of ``rows``; its dtype kept."""
    out = np.array(a, copy=True)
    R = out.shape[0]
    flat = out.reshape(R, -1)
    moved = rows.root_moved | rows.holes(flat[:, None, :3])[:, 0]
    flat[moved, :3] = near(rotmat_to_rotvec(rows.root[moved]), flat[moved, :3])
    body = flat[:, 3:66].reshape(R, 21, 3)
    moved = rows.body_moved | rows.holes(body)
    body[moved] = near(rows.body[moved], body[moved])
    flat[:, 3:66] = body.reshape(R, 63)
    _extra_in_holes(flat[:, 66:], rows)
    return flat.reshape(out.shape)


def _extra_in_holes(flat: np.ndarray, rows: Rows) -> None:
    """The hand axis-angles ``rows.extra`` (R, K) into the NaN / inf entries of ``flat`` (R,
    K) (in place), where they are the same columns."""
    if rows.extra is not None and flat.shape == rows.extra.shape:
        bad = ~np.isfinite(flat) & rows.fill
        flat[bad] = rows.extra[bad]


def put_matrices(a: Any, rows: Rows) -> np.ndarray:
    """A copy of ``a`` ((R, J * 9) or (R, J, 3, 3) rotation matrices, root first) with the
    moved root and joints of ``rows``; the other joints' matrices as they were."""
    out = np.array(a, copy=True)
    R = out.shape[0]
    m = out.reshape(R, -1, 3, 3)
    moved = rows.root_moved | rows.holes(m[:, :1])[:, 0]
    m[moved, 0] = rows.root[moved]
    body = m[:, 1:22]
    moved = rows.body_moved | rows.holes(body)
    body[moved] = rotvec_to_rotmat(rows.body[moved])
    m[:, 1:22] = body
    rest = m[:, 22:]
    if rows.extra is not None and rows.extra.shape == (R, 3 * rest.shape[1]):
        bad = rows.holes(rest)
        rest[bad] = rotvec_to_rotmat(rows.extra.reshape(R, -1, 3)[bad])
        m[:, 22:] = rest
    return m.reshape(out.shape)


def put_root(a: Any, rows: Rows) -> np.ndarray:
    """A copy of ``a`` ((R, 3) or (R, 1, 3) root axis-angles) with the moved roots."""
    out = np.array(a, copy=True)
    flat = out.reshape(out.shape[0], 3)
    moved = rows.root_moved | rows.holes(flat[:, None])[:, 0]
    flat[moved] = near(rotmat_to_rotvec(rows.root[moved]), flat[moved])
    return flat.reshape(out.shape)


def put_body(a: Any, rows: Rows) -> np.ndarray:
    """A copy of ``a`` ((R, >= 63) or (R, >= 21, 3) body axis-angles: the 21 body joints,
    then any others, e.g. SMPL's two hand joints, kept) with the moved joints."""
    out = np.array(a, copy=True)
    flat = out.reshape(out.shape[0], -1)
    body = flat[:, :63].reshape(-1, 21, 3)
    moved = rows.body_moved | rows.holes(body)
    body[moved] = near(rows.body[moved], body[moved])
    flat[:, :63] = body.reshape(-1, 63)
    _extra_in_holes(flat[:, 63:], rows)
    return flat.reshape(out.shape)


def shifted(
    a: Any, shift: np.ndarray, scale: float | np.ndarray = 1.0, holes: np.ndarray | None = None
) -> np.ndarray:
    """A copy of ``a`` (R rows of 3 numbers, any shape) moved by ``shift * scale`` (R, 3)
    where the shift is not zero; rows it leaves alone are the same bits. ``holes`` (R, 3):
    the values (times ``scale``) its rows with a NaN / inf get (None: they stay so)."""
    out = np.array(a, copy=True)
    flat = out.reshape(out.shape[0], 3)
    scale = np.reshape(scale, (-1, 1))
    moved = np.any(shift != 0, axis=1)
    flat[moved] = flat[moved] + (shift * scale)[moved].astype(flat.dtype)
    if holes is not None:
        bad = ~np.isfinite(flat).all(axis=1)
        flat[bad] = (holes * scale)[bad].astype(flat.dtype)
    return flat.reshape(out.shape)


def put_transl(a: Any, rows: Rows, scale: float | np.ndarray = 1.0) -> np.ndarray:
    """A copy of ``a`` (R rows of 3 numbers: the file's translation, ``rows.transl`` times
    ``scale``) moved by the cleaning, its NaN / inf rows the filled translation."""
    return shifted(a, rows.shift, scale, rows.transl if rows.fill else None)


def put_betas(a: Any, rows: Rows) -> np.ndarray:
    """A copy of per-frame shapes ``a`` ((R, S): R rows of betas) whose rows holding a NaN /
    inf are the track's shape (``rows.betas``; coefficients past it 0), unless holes stay;
    any other array as it came."""
    out = np.array(a, copy=True)
    if not rows.fill or out.ndim < 2 or out.shape[0] != len(rows.root) or out.dtype.kind != "f":
        return out
    flat = out.reshape(len(out), -1)
    bad = ~np.isfinite(flat).all(axis=1)
    shape = np.zeros(flat.shape[1])
    S = min(flat.shape[1], len(rows.betas))
    shape[:S] = rows.betas[:S]
    flat[bad] = shape.astype(flat.dtype)
    return flat.reshape(out.shape)


def row_scales(copy: Any, of: Any, rtol: float = 1e-4) -> np.ndarray | None:
    """The per-row factor that makes ``copy`` of ``of`` (R rows of 3 numbers each): ``copy
    = s * of`` row by row (HybrIK's ``transl_camsys``: its ``transl`` times 256 over the box
    width; ``pred_cam_root``: the same numbers), or None where some row is not such a
    multiple (then it is no copy); NaN for a row either holds a NaN / inf in (a hole: it tells
    nothing).  -> (R,)"""
    c = np.asarray(copy, np.float64)
    o = np.asarray(of, np.float64)
    if c.size != o.size or c.size % 3 or c.shape[:1] != o.shape[:1]:
        return None
    c, o = c.reshape(-1, 3), o.reshape(-1, 3)
    told = np.isfinite(c).all(axis=1) & np.isfinite(o).all(axis=1)
    c, o = np.where(told[:, None], c, 0.0), np.where(told[:, None], o, 0.0)
    norm2 = np.einsum("ti,ti->t", o, o)
    s = np.einsum("ti,ti->t", c, o) / np.maximum(norm2, 1e-30)
    err = np.linalg.norm(c - s[:, None] * o, axis=1)
    if not told.any() or np.any(err > rtol * np.linalg.norm(c, axis=1) + 1e-9):
        return None
    return np.where(told, s, np.nan)


def crop_camera_follows(cam: Any, old: Any, new: Any, fill: bool = True) -> np.ndarray | None:
    """A weak-perspective crop camera ``cam`` (R, 3) = [s, tx, ty] per row (TRAM's
    ``pred_cam``, PHALP's ``camera_bbox``) made to give the translation ``new`` (R, 3) where it
    moved from ``old`` (R, 3), the one the pipeline made from it with the row's box and focal
    length f: ``Z = 2 f / (b s)``, ``X = tx + c_x Z``, ``Y = ty + c_y Z`` (c from the box's
    offset). K = s Z, c_x and c_y are read from each row's own numbers (interpolated from the
    rows beside it where the file holds none: a hole, when ``fill``) and the camera solved:
    ``s = K / Z'``, ``tx = X' - c_x Z'``, ``ty = Y' - c_y Z'``; other rows keep their bits.
    None when no row tells (s or Z not positive anywhere): no crop camera of ``old``."""
    from mdvae_cli.formats.video_holes import scales_in_holes

    out = np.array(cam, copy=True)
    flat = out.reshape(len(out), 3)
    c = flat.astype(np.float64)
    o = np.asarray(old, np.float64).reshape(-1, 3)
    n = np.asarray(new, np.float64).reshape(-1, 3)
    with np.errstate(invalid="ignore", divide="ignore"):
        told = np.isfinite(c).all(1) & np.isfinite(o).all(1) & (c[:, 0] > 0) & (o[:, 2] > 0)
        if not told.any():
            return None
        read = (c[:, 0] * o[:, 2], (o[:, 0] - c[:, 1]) / o[:, 2], (o[:, 1] - c[:, 2]) / o[:, 2])
        K, cx, cy = (scales_in_holes(np.where(told, v, np.nan)) for v in read)
        hole = ~np.isfinite(c).all(1) & fill
        moved = np.isfinite(n).all(1) & (n[:, 2] > 0) & (np.any(n != o, axis=1) | hole)
        solved = np.stack([K / n[:, 2], n[:, 0] - cx * n[:, 2], n[:, 1] - cy * n[:, 2]], 1)
    flat[moved] = solved[moved].astype(flat.dtype)
    return out


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
    ``tol``; joints either holds a NaN / inf for, holes, tell nothing): then it is no copy of
    them."""
    out = np.array(six, copy=True)
    R = out.shape[0] if out.ndim else 0
    o = np.asarray(old, np.float64).reshape(R, -1, 3, 3)
    n = np.asarray(new, np.float64).reshape(R, -1, 3, 3)
    if out.size != o.shape[1] * 6 * R:
        return None
    flat = out.reshape(R, -1, 6)
    told = np.isfinite(flat).all(-1) & np.isfinite(o).all(axis=(2, 3))
    if not told.any():
        return None
    if np.abs(from_six_d(flat[told].astype(np.float64)) - o[told]).max(initial=0.0) > tol:
        return None
    moved = np.any(n != o, axis=(2, 3)) & np.isfinite(n).all(axis=(2, 3))
    flat[moved] = six_d(n[moved]).astype(flat.dtype)
    return out


def camera_follows(
    cam_root: Any, cam_transl: Any, world_root: np.ndarray, rows: Rows
) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame copies of a world-frame pose moved as the world one was (module
    docstring): per row the file's camera ``R_c = R_cam R_world^T``, the new camera root
    ``R_c R_world'`` and translation ``t_cam + R_c (t_world' - t_world)``.

    Rows whose camera the file does not give (a NaN / inf in the copy, a hole in the world
    pose) get the camera interpolated from the others (``video_holes.camera_in_holes``) and
    the cleaned pose through it, unless holes stay (``--fill off``).

    cam_root: (R, 3) axis-angles; cam_transl: (R, 3); world_root: (R, 3, 3) the file's world
    roots as read -> the new camera root and translation, in their arrays' dtypes"""
    from mdvae_cli.formats.video_holes import camera_in_holes

    cam = np.array(cam_root, copy=True)
    flat = cam.reshape(cam.shape[0], 3)
    t_cam = np.asarray(cam_transl, np.float64).reshape(-1, 3)
    known = np.isfinite(flat).all(axis=1) & np.isfinite(t_cam).all(axis=1)
    if rows.missing is not None:
        known &= ~rows.missing[:, 0]
    if not known.any():
        return cam, np.array(cam_transl, copy=True)
    Rc, d = camera_in_holes(rotvec_to_rotmat(np.where(known[:, None], flat, 0.0)),
                            np.where(known[:, None], t_cam, 0.0), np.asarray(world_root),
                            rows.transl - rows.shift, known)  # fmt: skip
    moved = rows.root_moved | (~known & rows.fill)
    flat[moved] = near(rotmat_to_rotvec(Rc[moved] @ rows.root[moved]), flat[moved])
    shift = np.einsum("tij,tj->ti", Rc, np.where(known[:, None], rows.shift, 0.0))
    out = shifted(cam_transl, shift)
    placed = out.reshape(-1, 3)
    write = ~known & rows.fill
    placed[write] = (d + np.einsum("tij,tj->ti", Rc, rows.transl))[write].astype(placed.dtype)
    return flat.reshape(cam.shape), out


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


def track_ids(raw: RawTrack) -> np.ndarray:
    """A track's frame ids, one per row (consecutive from 0 when the file has none)."""
    if raw.frame_ids is None:
        return np.arange(raw.num_frames)
    return np.asarray(raw.frame_ids).reshape(-1)
