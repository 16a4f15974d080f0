"""Read and write AMASS-style ``.npz`` motion files."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.fileio import write_atomic
from mdvae_cli.motion.motion import POSE_WIDTHS, Motion

FPS_KEYS = ("mocap_framerate", "mocap_frame_rate")
_OWN_KEYS = {"poses", "trans", "betas", "gender", "joint_mask", *FPS_KEYS}


def _decode_gender(value: np.ndarray) -> tuple[str, bool]:
    item = value.item() if value.ndim == 0 else value.reshape(-1)[0]
    if isinstance(item, bytes):
        return item.decode("utf-8", "replace").strip(), True
    return str(item).strip(), False


def _finite(name: str, arr: np.ndarray, path: Path) -> np.ndarray:
    if not np.issubdtype(arr.dtype, np.number):
        raise InputError(f"{path}: '{name}' is not numeric (dtype {arr.dtype})")
    arr = np.asarray(arr, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{path}: '{name}' contains NaN or infinite values")
    return arr


def load_motion(path: Path | str, allow_pickle: bool = False) -> Motion:
    """Read an AMASS-layout motion file.

    Never executes pickled objects unless ``allow_pickle``. Raises InputError with a one-line
    message for every malformed input (missing file, not an npz, corrupt archive, missing or
    mis-shaped keys, NaN/inf, fewer than 2 frames, frame rate <= 0).
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"no such file: {path}")
    if path.is_dir():
        raise InputError(f"{path} is a folder, expected an .npz file")
    if not zipfile.is_zipfile(path):
        kind = path.name.lower().removesuffix(".gz").rsplit(".", 1)[-1]
        if kind in ("bvh", "amc", "asf"):  # mocap a studio exported: the importer reads it
            raise InputError(
                f"{path}: a .{kind} file, not an .npz; convert it first with "
                f"`mdvae import {path} -o imported/`"
            )
        raise InputError(f"{path}: not an .npz archive")
    try:
        with np.load(path, allow_pickle=allow_pickle) as npz:
            data = {k: npz[k] for k in npz.files}
    except InputError:
        raise
    except (zipfile.BadZipFile, EOFError, OSError) as exc:
        raise InputError(f"{path}: not a readable .npz archive ({exc})") from None
    except ValueError as exc:
        if "pickle" in str(exc):
            raise InputError(
                f"{path}: holds pickled objects; re-run with --allow-pickle if you trust it"
            ) from None
        raise InputError(f"{path}: not a readable .npz archive ({exc})") from None
    except Exception as exc:  # zlib errors, truncated members, ...
        raise InputError(f"{path}: corrupt .npz archive ({type(exc).__name__}: {exc})") from None
    return motion_from_arrays(data, path)


def motion_from_arrays(data: dict[str, np.ndarray], path: Path | str = "<arrays>") -> Motion:
    """Build a Motion from the arrays of an AMASS-layout file (see :func:`load_motion`)."""
    path = Path(path)
    notes: list[str] = []
    if "poses" not in data:
        raise InputError(f"{path}: no 'poses' array (keys: {', '.join(sorted(data)) or 'none'})")
    poses = _finite("poses", data["poses"], path)
    if poses.ndim != 2 or poses.shape[1] not in POSE_WIDTHS:
        widths = "/".join(str(w) for w in POSE_WIDTHS)
        raise InputError(f"{path}: 'poses' has shape {poses.shape}, expected (T, {widths})")
    T = poses.shape[0]
    if T < 2:
        raise InputError(f"{path}: motion has {T} frame(s); at least 2 are needed")

    if "trans" in data:
        trans = _finite("trans", data["trans"], path)
        if trans.shape != (T, 3):
            raise InputError(f"{path}: 'trans' has shape {trans.shape}, expected ({T}, 3)")
    else:
        trans = np.zeros((T, 3))
        notes.append("no 'trans' array: using zero translation")

    if "betas" in data:
        betas = _finite("betas", data["betas"], path).reshape(-1)
    else:
        betas = np.zeros(10)
        notes.append("no 'betas' array: using the mean shape")

    fps_key = next((k for k in FPS_KEYS if k in data), None)
    if fps_key is None:
        raise InputError(f"{path}: no frame rate ('mocap_framerate' or 'mocap_frame_rate')")
    fps = float(_finite(fps_key, np.asarray(data[fps_key]), path).reshape(-1)[0])
    if not fps > 0:
        raise InputError(f"{path}: frame rate must be > 0, got {fps:g}")

    gender, gender_bytes = ("neutral", False)
    if "gender" in data:
        gender, gender_bytes = _decode_gender(np.asarray(data["gender"]))

    mask = None
    if "joint_mask" in data:
        mask = np.asarray(data["joint_mask"]).astype(bool)
        if mask.shape != (T, 22):
            raise InputError(f"{path}: 'joint_mask' has shape {mask.shape}, expected ({T}, 22)")

    extras = {k: v for k, v in data.items() if k not in _OWN_KEYS}
    layout = {"fps_key": fps_key, "gender_bytes": gender_bytes, "has_gender": "gender" in data,
              "poses_dtype": str(data["poses"].dtype)}  # fmt: skip
    return Motion.from_poses(
        poses, trans, betas, fps, gender=gender, joint_mask=mask, extras=extras,
        layout=layout, notes=notes,
    )  # fmt: skip


def motion_to_arrays(motion: Motion) -> dict[str, np.ndarray]:
    """The arrays to write for a Motion, in the layout it was read with."""
    layout = motion.layout
    dtype = np.dtype(str(layout.get("poses_dtype", "float64")))
    if not np.issubdtype(dtype, np.floating):
        dtype = np.dtype("float64")
    out: dict[str, np.ndarray] = dict(motion.extras)
    out["poses"] = motion.poses.astype(dtype)
    out["trans"] = motion.trans.astype(dtype)
    out["betas"] = np.asarray(motion.betas, dtype=dtype)
    out[str(layout.get("fps_key", "mocap_framerate"))] = np.array(motion.fps)
    if layout.get("has_gender", True):
        g = motion.gender.encode() if layout.get("gender_bytes") else motion.gender
        out["gender"] = np.array(g)
    if motion.joint_mask is not None:
        out["joint_mask"] = motion.joint_mask.astype(bool)
    return out


def save_motion(motion: Motion, path: Path | str, forbid: tuple[Path, ...] = ()) -> None:
    """Write ``motion`` to ``path`` atomically (temporary file + rename), never onto ``forbid``."""
    arrays = motion_to_arrays(motion)

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)

    write_atomic(Path(path), write, forbid=forbid)
