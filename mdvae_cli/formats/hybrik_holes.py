"""HybrIK's other per-frame arrays in the rows a hole filled (issue 32: a row the file holds
NaN / inf in; ``formats.video_holes``): each array gets values there, so that a filled row is
as complete as the rows around it, but for an array no row of which is finite (left NaN).

The cleaning writes the pose (``pred_thetas``), shape (``pred_betas``) and translations
(``transl``, ``pred_cam_root``, ``transl_camsys``); per array, in the rows it holds a
non-finite value in (with ``--fill off``, none: the holes stay as they came):

* joints made from the pose, placed by the filled one: ``pred_xyz_24_struct`` (the SMPL
  joints of ``pred_thetas`` and the shape, root-relative, over 2.2 m) and ``pred_xyz_29`` (the
  network's 29 joints the pose is solved from: SMPL's 24 then head top, middle fingers, big
  toes) along their kinematic chains (:data:`PARENTS_29`): each joint is its parent plus its
  offset in the parent's frame (the file's pose rotated into it), that offset interpolated
  linearly from the rows the array holds (the bones of the shape, as the network saw them),
  turned by the filled pose's world rotations (:func:`chained_joints`). On the real HybrIK
  file the struct joints are the chain of its own pose: a bone's offset in its parent's frame
  moves by 0.0026 (m / 2.2) at most over 135 frames (its per-frame shapes). ``pred_xyz_17``
  (Human3.6M joints made from the vertices): each joint follows the struct joint nearest it on
  average, its offset in that joint's frame interpolated likewise (:func:`anchored_joints`).
* the network's other outputs, no function of the pose: ``pred_uvd`` (image-plane joints),
  ``pred_scores`` (confidences), ``pred_camera``, ``pred_phi`` (twist angles, as written:
  not unit vectors) and the detector's ``bbox``, interpolated linearly from the rows beside
  the hole (a hole at an end: the nearest row's values) (:func:`interpolated_rows`).
"""

from __future__ import annotations

import numpy as np

from mdvae_cli.body.data import SMPL_PARENTS
from mdvae_cli.formats.npz_holes import interp_columns

#: HybrIK's 29 joints: SMPL's 24, then head top (on the head), left / right middle finger
#: (on the hands), left / right big toe (on the feet)
PARENTS_29 = tuple(int(p) for p in SMPL_PARENTS[:24]) + (15, 22, 23, 10, 11)
#: arrays of joints placed along their chain by the filled pose
CHAINED = {"pred_xyz_24_struct": PARENTS_29[:24], "pred_xyz_29": PARENTS_29}
#: arrays of joints each following the struct joint nearest it (interpolated in a file
#: without struct joints)
ANCHORED = ("pred_xyz_17",)
#: the network's outputs that are no function of the pose, interpolated
INTERPOLATED = ("pred_uvd", "pred_scores", "pred_camera", "pred_phi", "bbox")


def _bad_rows(values: np.ndarray) -> np.ndarray:
    """(R,) rows of ``values`` (R, ...) holding a non-finite number."""
    return ~np.isfinite(values.reshape(len(values), -1)).all(axis=1)


def _interp(values: np.ndarray, known: np.ndarray) -> np.ndarray:
    """``values`` (R, ...) with the rows not ``known`` (R,) interpolated linearly from those
    that are (ends held)."""
    flat = np.reshape(values, (len(values), -1))
    bad = np.repeat(~known[:, None], flat.shape[1], axis=1)
    return interp_columns(flat, bad).reshape(np.shape(values))


def interpolated_rows(values: np.ndarray) -> np.ndarray:
    """A copy of ``values`` (R, ...) whose rows holding a non-finite number are interpolated
    linearly from the finite ones (ends held), in its dtype; as it came when every row is
    finite, or none."""
    bad = _bad_rows(np.asarray(values, dtype=np.float64))
    if not bad.any() or bad.all():
        return np.array(values, copy=True)
    return _interp(values, ~bad).astype(np.asarray(values).dtype)


def chained_joints(
    joints: np.ndarray, parents: tuple[int, ...], old: np.ndarray, new: np.ndarray
) -> np.ndarray:
    """Joints (R, J, 3) with their non-finite rows placed along the chain ``parents`` (J,;
    each parent one of SMPL's 24) by the world rotations ``new`` (R, 24, 3, 3): the root
    interpolated, each other joint its parent plus its offset in the parent's frame, read in
    the rows where the joints and the file's rotations ``old`` (R, 24, 3, 3) are finite and
    interpolated. -> (R, J, 3), the finite rows as they came."""
    x = np.asarray(joints, dtype=np.float64)
    fill = _bad_rows(x)
    known = ~fill & ~_bad_rows(old)
    if not fill.any() or not known.any():
        return np.array(joints, copy=True)
    out = x.copy()
    out[fill, 0] = _interp(x[:, 0], known)[fill]
    for j in range(1, len(parents)):
        p = parents[j]
        offset = np.zeros((len(x), 3))
        offset[known] = np.einsum("rji,rj->ri", old[known, p], x[known, j] - x[known, p])
        offset = _interp(offset, known)[fill]
        out[fill, j] = out[fill, p] + np.einsum("rij,rj->ri", new[fill, p], offset)
    return out.astype(np.asarray(joints).dtype)


def anchored_joints(
    joints: np.ndarray, struct: np.ndarray, old: np.ndarray, new: np.ndarray
) -> np.ndarray:
    """Joints (R, K, 3) with their non-finite rows placed on the struct joints ``struct``
    (R, 24, 3; finite in every row): each follows the struct joint nearest it on average in
    the rows where it and the file's rotations ``old`` (R, 24, 3, 3) are finite, its offset
    in that joint's frame interpolated and turned by ``new`` (R, 24, 3, 3). -> (R, K, 3)"""
    x = np.asarray(joints, dtype=np.float64)
    fill = _bad_rows(x)
    known = ~fill & ~_bad_rows(old)
    if not fill.any() or not known.any():
        return np.array(joints, copy=True)
    s = np.asarray(struct, dtype=np.float64)
    distance = np.linalg.norm(x[known][:, :, None] - s[known][:, None], axis=-1).mean(axis=0)
    out = x.copy()
    for k, a in enumerate(distance.argmin(axis=1)):  # (K,) the struct joint nearest each
        offset = np.zeros((len(x), 3))
        offset[known] = np.einsum("rji,rj->ri", old[known, a], x[known, k] - s[known, a])
        offset = _interp(offset, known)[fill]
        out[fill, k] = s[fill, a] + np.einsum("rij,rj->ri", new[fill, a], offset)
    return out.astype(np.asarray(joints).dtype)


def hybrik_rows_filled(data: dict, old_thetas: np.ndarray) -> list[str]:
    """Fill, in place, HybrIK's arrays (module docstring) in the rows they hold a non-finite
    value in, ``data["pred_thetas"]`` being the written (filled) pose and ``old_thetas`` the
    file's (R, 216 or 24 x 3 x 3). -> a note naming the arrays filled, or none."""
    from mdvae_cli.geometry.kinematics import world_rotations  # torch: loaded by then

    R, smpl = len(old_thetas), PARENTS_29[:24]
    with np.errstate(invalid="ignore", over="ignore"):  # the file's NaN / inf rows stay so
        old = world_rotations(np.asarray(old_thetas, dtype=np.float64).reshape(R, 24, 3, 3), smpl)
    new = world_rotations(np.asarray(data["pred_thetas"], dtype=np.float64).reshape(R, 24, 3, 3),
                          smpl)  # fmt: skip
    filled = []
    for key, parents in CHAINED.items():
        if _fillable(data, key, R, len(parents)):
            shape = np.shape(data[key])
            x = np.reshape(data[key], (R, len(parents), 3))
            data[key] = chained_joints(x, parents, old, new).reshape(shape)
            filled.append(key)
    struct = data.get("pred_xyz_24_struct")
    placed = struct is not None and np.size(struct) == R * 72 and not _bad_rows(struct).any()
    for key in ANCHORED:
        if _fillable(data, key, R) and np.size(data[key]) % (3 * R) == 0:
            x = np.reshape(data[key], (R, -1, 3))
            if placed:  # else (no struct joints to follow): interpolated
                x = anchored_joints(x, np.reshape(struct, (R, 24, 3)), old, new)
            data[key] = interpolated_rows(x).reshape(np.shape(data[key]))
            filled.append(key)
    for key in INTERPOLATED:
        if _fillable(data, key, R):
            data[key] = interpolated_rows(np.asarray(data[key]))
            filled.append(key)
    if not filled:
        return []
    return [f"{', '.join(filled)} in the rows filled: the joints placed by the filled pose, "
            "the network's other outputs interpolated from the rows beside them"]  # fmt: skip


def _fillable(data: dict, key: str, R: int, joints: int | None = None) -> bool:
    """Whether ``data[key]`` is a float array of R rows (``joints`` x 3 values a row where
    given) with a non-finite row and a finite one."""
    a = data.get(key)
    if not isinstance(a, np.ndarray) or a.dtype.kind != "f" or len(a) != R:
        return False
    if joints is not None and a.size != R * joints * 3:
        return False
    bad = _bad_rows(a)
    return bool(bad.any() and not bad.all())
