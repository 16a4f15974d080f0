"""What the arrays of an AMASS-style ``.npz`` may hold: real, finite numbers within the limits of
a motion; one frame rate; one gender as text; key names that are safe to write back. And how
values are written back as the file stored them (frame rate, text, axis-angle branches).

Each check raises InputError with one line naming the file, the key and the problem; used by
:mod:`mdvae_cli.formats.npz_io`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.motion.motion import MAX_ANGLE_DEG, MAX_BETA, MAX_DISTANCE_M
from mdvae_cli.npz_archive import safe_key, safe_name


@dataclass(frozen=True)
class Limit:
    """The largest magnitude a key's values may have, and how a refusal words a value past it:
    ``value`` (e.g. "an angle of {} rad") and ``kind`` (e.g. "angles over 1745 rad")."""

    largest: float
    value: str
    kind: str


#: axis-angles (radians), as the BVH and ASF/AMC readers limit Euler angles
ANGLE = Limit(math.radians(MAX_ANGLE_DEG), "holds an angle of {:.3g} rad",
              f"angles over {math.radians(MAX_ANGLE_DEG):.0f} rad")  # fmt: skip
#: root translation (metres)
DISTANCE = Limit(MAX_DISTANCE_M, "reaches {:.3g} m", f"distances over {MAX_DISTANCE_M:g} m")
#: body shape coefficients (standard deviations)
BETA = Limit(MAX_BETA, "holds a shape coefficient of {:.3g}", f"coefficients over {MAX_BETA:g}")


def real_array(
    key: str, arr: np.ndarray, path: Path, limit: Limit | None = None, holes: bool = False
) -> np.ndarray:
    """``arr`` as float64; InputError when it is not real numbers (text, complex...), holds
    NaN or inf (unless ``holes``: they mark missing values, ``formats.npz_holes``), or holds a
    finite value past ``limit``."""
    arr = np.asarray(arr)
    if np.iscomplexobj(arr):
        raise InputError(f"{path}: '{key}' holds complex numbers; expected real numbers")
    if arr.dtype.kind not in "iuf":  # timedelta, datetime, text, bool, objects
        raise InputError(f"{path}: '{key}' is not numeric (dtype {arr.dtype})")
    arr = np.asarray(arr, dtype=np.float64)
    finite = np.isfinite(arr)
    if not holes and not finite.all():
        raise InputError(f"{path}: '{key}' contains NaN or infinite values")
    size = np.abs(arr[finite]) if holes else np.abs(arr)
    if limit is not None and size.size and size.max() > limit.largest:
        worst = float(size.max())
        raise InputError(f"{path}: '{key}' {limit.value.format(worst)}; the file is corrupt "
                         f"({limit.kind} are refused)")  # fmt: skip
    return arr


def frame_rate(key: str, value: np.ndarray, path: Path) -> float:
    """The one number of a frame-rate array (0-d or one element)."""
    value = np.asarray(value)
    if value.size != 1:
        what = "is empty" if value.size == 0 else f"holds {value.size} values"
        raise InputError(f"{path}: '{key}' {what}; expected one frame rate")
    return float(real_array(key, value, path).reshape(-1)[0])


def gender_text(value: np.ndarray, path: Path) -> tuple[str, bool, str]:
    """The one text a ``gender`` array holds (stripped), whether it was stored as bytes, and
    the text as stored (written back as it came while the gender is unchanged)."""
    value = np.asarray(value)
    if value.size != 1:
        what = "is empty" if value.size == 0 else f"holds {value.size} values; expected one"
        raise InputError(f"{path}: 'gender' {what} (e.g. 'female')")
    item = value.reshape(-1)[0]
    if isinstance(item, np.generic):
        item = item.item()
    if isinstance(item, bytes):
        text = item.decode("utf-8", "replace")
        return text.strip(), True, text
    if not isinstance(item, str):
        raise InputError(f"{path}: 'gender' is not text (dtype {value.dtype})")
    return item.strip(), False, item


def gender_as_written(gender: str, layout: dict) -> str | bytes:
    """What ``gender`` is written as: the text as stored (:func:`gender_text`, spaces and all)
    while it is unchanged, as bytes when it was bytes."""
    stored = str(layout.get("gender_as_stored", gender))
    text = stored if stored.strip() == gender else gender
    return text.encode() if layout.get("gender_bytes") else text


def joint_mask(value: np.ndarray, path: Path) -> np.ndarray:
    """A ``joint_mask`` as bool: true/false values, or numbers (non-zero = observed)."""
    mask = np.asarray(value)
    if mask.dtype.kind not in "biuf":
        raise InputError(f"{path}: 'joint_mask' is not true/false values (dtype {mask.dtype})")
    return mask if mask.dtype.kind == "b" else real_array("joint_mask", mask, path) != 0


def safe_keys(data: dict[str, np.ndarray], notes: list[str]) -> dict[str, np.ndarray]:
    """``data`` with every key that is a path (``../../x``, ``/abs/y``: unsafe as an archive
    member name, see :func:`~mdvae_cli.npz_archive.safe_key`) renamed in place, and a
    ``warning:`` note for each."""
    if all(safe_key(k) for k in data):
        return data
    taken = {k for k in data if safe_key(k)}
    out = {}
    for key, value in data.items():
        if not safe_key(key):
            new = safe_name(key, taken)
            taken.add(new)
            notes.append(f"warning: key {key!r} is a path, unsafe in an archive: written as "
                         f"{new!r}")  # fmt: skip
            key = new
        out[key] = value
    return out


#: radians: a file with a body axis-angle this long may write the other side of pi (a solver's
#: free axis-angles, a root turning through 180 degrees); its own branches are kept on writing
_NEAR_PI = 3.0


def branch_reference(poses: np.ndarray) -> np.ndarray | None:
    """The body axis-angles of a file as read, (T, 66), when any comes near or past pi (where
    a rewritten rotation could land on another branch than the file's); None otherwise."""
    body = np.asarray(poses[:, :66], dtype=np.float64).reshape(len(poses), -1, 3)
    with np.errstate(invalid="ignore"):
        near = np.linalg.norm(body, axis=-1) > _NEAR_PI
    return np.array(poses[:, :66], dtype=np.float64) if near.any() else None


def on_file_branches(poses: np.ndarray, reference: np.ndarray | None) -> np.ndarray:
    """``poses`` (T, W) with each body axis-angle on the branch nearest the file's own
    (``branch_reference``), the rotations unchanged; as it is without a reference of its
    frames."""
    if reference is None or reference.shape != (len(poses), 66):
        return poses
    from mdvae_cli.geometry.rotations_np import rotvec_nearest

    out = np.array(poses, dtype=np.float64)
    T = len(out)
    out[:, :66] = rotvec_nearest(
        out[:, :66].reshape(T, 22, 3), reference.reshape(T, 22, 3)
    ).reshape(T, 66)
    return out


def fps_array(fps: float, spec: tuple | None) -> np.ndarray:
    """The frame rate in the file's dtype (an integer one only for a whole rate) and shape."""
    out = np.array(fps)
    if spec is None:
        return out
    dtype = np.dtype(spec[0])
    if np.issubdtype(dtype, np.floating) or (
        np.issubdtype(dtype, np.integer) and float(fps).is_integer()
    ):
        out = out.astype(dtype)
    return out.reshape(spec[1]) if int(np.prod(spec[1])) == 1 else out


def like_stored(arr: np.ndarray, spec: tuple | None) -> np.ndarray:
    """A string array in the file's dtype and shape, where the text fits."""
    if spec is None:
        return arr
    dtype = np.dtype(spec[0])
    fits = dtype.kind == "O" or (dtype.kind == arr.dtype.kind and dtype.itemsize >= arr.itemsize)
    out = arr.astype(dtype) if fits else arr
    return out.reshape(spec[1]) if int(np.prod(spec[1])) == out.size else out
