"""Read and write AMASS-style ``.npz`` motion files."""

from __future__ import annotations

import gzip
import io
import zipfile
import zlib
from pathlib import Path

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.fileio import write_atomic
from mdvae_cli.formats.npz_holes import (
    AS_READ,
    HOLES,
    fill_placeholders,
    read_holes,
    restore_holes,
)
from mdvae_cli.formats.npz_values import (
    ANGLE,
    BETA,
    DISTANCE,
    branch_reference,
    fps_array,
    frame_rate,
    gender_as_written,
    gender_text,
    joint_mask,
    like_stored,
    on_file_branches,
    real_array,
    safe_keys,
)
from mdvae_cli.motion.motion import POSE_WIDTHS, Motion, as_numpy, check_fps
from mdvae_cli.npz_archive import NpzArchive, write_npz

FPS_KEYS = ("mocap_framerate", "mocap_frame_rate")
_OWN_KEYS = {"poses", "trans", "betas", "gender", "joint_mask", *FPS_KEYS}

#: The split pose arrays of SMPL-H/SMPL-X ("stage-ii") files, each a copy of some columns of
#: ``poses``: key -> (columns, {poses width: first column}). root_orient and pose_body are the
#: body; the others slices of Motion.pose_extra (SMPL-X ``poses``: root, body, jaw, eyes, hands).
SPLIT_KEYS: dict[str, tuple[int, dict[int, int]]] = {
    "root_orient": (3, dict.fromkeys(POSE_WIDTHS, 0)),
    "pose_body": (63, dict.fromkeys(POSE_WIDTHS, 3)),
    "pose_jaw": (3, {165: 66}),
    "pose_eye": (6, {165: 69}),
    "pose_hand": (90, {165: 75, 156: 66}),
}
_BODY_SPLIT_KEYS = ("root_orient", "pose_body")
#: radians: a split array further than this from its ``poses`` columns disagrees with them
_SPLIT_TOL = 1e-5


def load_motion(path: Path | str, allow_pickle: bool = False, fps: float | None = None) -> Motion:
    """Read an AMASS-layout motion file (``fps``: the rate of a file that stores none).

    A ``.gz`` file (``take.npz.gz``, as folders are searched) is gunzipped first. Never
    executes pickled objects unless ``allow_pickle``: object arrays of plain data (numbers,
    strings, arrays, lists, dicts: AMASS SMPL-X's ``markers_latent_vids``) are built without
    running anything and carried through; any other is refused. Raises InputError with a one-line
    message for every malformed input (missing file, not an npz, corrupt archive or member,
    a member claiming more than it holds, missing or mis-shaped keys, complex, NaN/inf or
    corrupt-looking values, no frames, frame rate <= 0 or outside FPS_RANGE). Extra keys whose
    names are paths (``../x``) are renamed, with a warning among the notes.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"no such file: {path}")
    if path.is_dir():
        raise InputError(f"{path} is a folder, expected an .npz file")
    source = _gunzip(path) if path.suffix.lower() == ".gz" else path
    kind = path.name.lower().removesuffix(".gz").rsplit(".", 1)[-1]
    if kind in ("bvh", "amc", "asf") and not zipfile.is_zipfile(source):
        raise InputError(  # mocap a studio exported: the importer reads it
            f"{path}: a .{kind} file, not an .npz; convert it first with "
            f"`mdvae import {path} -o imported/`"
        )
    if isinstance(source, io.BytesIO):
        source.seek(0)
    limits = {"max_member": MAX_MEMBER, "max_total": MAX_TOTAL}
    with NpzArchive(source, path, "--allow-pickle", **limits) as npz:
        # in the archive's order; object arrays of plain data read without running anything
        data = {key: npz.read(key, allow_pickle, plain_data=True) for key in npz.keys}
        compressed = npz.compressed
    motion = motion_from_arrays(data, path, fps)
    motion.layout["compressed"] = compressed
    return motion


#: bytes one array of a motion file may take (a 10-minute SMPL-X take at 120 Hz: 57 MB)
MAX_MEMBER = 512 << 20
#: bytes all arrays of a motion file may take together (as much as a ``.npz.gz`` may unzip to)
MAX_TOTAL = 512 << 20
#: bytes a ``.npz.gz`` may expand to (a guard against decompression bombs)
MAX_GUNZIP = 512 << 20


def _gunzip(path: Path) -> io.BytesIO:
    """A ``.gz`` file's decompressed bytes; InputError when it is not gzip data or expands
    past MAX_GUNZIP (read in steps: the limit holds while reading)."""
    try:
        with gzip.open(path, "rb") as fh:
            raw = fh.read(MAX_GUNZIP + 1)
    except (OSError, EOFError, zlib.error) as exc:
        raise InputError(f"{path}: not a readable .gz file ({exc})") from None
    if len(raw) > MAX_GUNZIP:
        raise InputError(f"{path}: expands past {MAX_GUNZIP >> 20} MiB when unzipped; refused")
    return io.BytesIO(raw)


def motion_from_arrays(
    data: dict[str, np.ndarray], path: Path | str = "<arrays>", fps: float | None = None
) -> Motion:
    """Build a Motion from the arrays of an AMASS-layout file (see :func:`load_motion`); a
    file with no frame rate is read at ``fps`` (and written with it), else refused.

    ``poses`` is the source of truth for the pose; a file without it is read from its split
    arrays (``root_orient``, ``pose_body``, and ``pose_jaw``/``pose_eye``/``pose_hand`` when
    present, see SPLIT_KEYS). ``layout`` records what :func:`motion_to_arrays` needs to write
    the file back as it was: key order, dtypes and shapes, split arrays, compression.
    The values may be numpy arrays, numbers or torch tensors (read as their values).
    """
    path = Path(path)
    data = {key: as_numpy(value) for key, value in data.items()}
    notes: list[str] = []
    has_poses = "poses" in data
    if has_poses:
        poses = real_array("poses", data["poses"], path, ANGLE, holes=True)
    else:
        poses = _poses_from_split(data, path)
    if poses.ndim != 2 or poses.shape[1] not in POSE_WIDTHS:
        widths = "/".join(str(w) for w in POSE_WIDTHS)
        why = ""
        if poses.ndim == 3 and poses.shape[2] in POSE_WIDTHS:  # (B, T, W): B motions
            why = f": a batch of {poses.shape[0]}; save each motion (poses[i], trans[i]) as an .npz"
        raise InputError(f"{path}: 'poses' has shape {poses.shape}, expected (T, {widths}){why}")
    T = poses.shape[0]
    if T < 1:  # one frame is a pose: it can be evaluated, exported or sampled from
        raise InputError(f"{path}: the motion has no frames")
    split = _split_layout(data, poses, path, notes)

    if "trans" in data:
        trans = real_array("trans", data["trans"], path, DISTANCE, holes=True)
        if trans.shape != (T, 3):
            raise InputError(f"{path}: 'trans' has shape {trans.shape}, expected ({T}, 3)")
    else:
        trans = np.zeros((T, 3))
        notes.append("no 'trans' array: using zero translation")

    betas_rows = None
    if "betas" in data:
        betas = real_array("betas", data["betas"], path, BETA)
        if betas.ndim > 2 or (betas.ndim == 2 and betas.shape[0] not in (1, T)):
            raise InputError(f"{path}: 'betas' has shape {betas.shape}; expected (S,), (1, S) "
                             f"or one row per frame ({T}, S)")  # fmt: skip
        if betas.ndim == 2 and betas.shape[0] == T:  # one shape vector per frame
            betas_rows = data["betas"]
            spread = float(np.ptp(betas, axis=0).max(initial=0.0))
            if spread > 0:
                notes.append(
                    f"per-frame 'betas' {betas.shape} vary by up to {spread:.3g} over the frames: "
                    "using their mean"
                )
            betas = betas.mean(axis=0)
        else:
            betas = betas.reshape(-1)
    else:
        betas = np.zeros(10)
        notes.append("no 'betas' array: using the mean shape")

    fps_key = next((k for k in FPS_KEYS if k in data), None)
    if fps_key is None and fps is None:
        raise InputError(f"{path}: no frame rate ('mocap_framerate' or 'mocap_frame_rate'); "
                         "give it with --fps (import: --source-fps)")  # fmt: skip
    fps = float(fps) if fps_key is None else frame_rate(fps_key, data[fps_key], path)
    if not fps > 0:
        raise InputError(f"{path}: frame rate must be > 0, got {fps:g}")
    check_fps(fps, str(path), swapped=f"is {fps_key} a frame time?")

    gender, gender_bytes, gender_as_stored = ("neutral", False, "neutral")
    if "gender" in data:
        gender, gender_bytes, gender_as_stored = gender_text(data["gender"], path)

    mask = None
    if "joint_mask" in data:
        mask = joint_mask(data["joint_mask"], path)
        if mask.shape != (T, 22):
            raise InputError(f"{path}: 'joint_mask' has shape {mask.shape}, expected ({T}, 22)")
    trans_bad = ~np.isfinite(trans)
    branches = branch_reference(poses)  # NaN where the file has holes
    poses, trans, finite, as_read, note = read_holes(poses, trans, path, split=not has_poses)
    if finite is not None:
        mask = finite if mask is None else mask & finite
    if note:
        notes.append(note)

    data = safe_keys(data, notes)
    extras = {k: v for k, v in data.items() if k not in _OWN_KEYS and k not in split}
    own = [k for k in ("poses", "trans", "betas", fps_key, "gender", "joint_mask") if k in data]
    layout = {
        "fps_key": fps_key,
        "gender_bytes": gender_bytes,
        "gender_as_stored": gender_as_stored,
        "has_gender": "gender" in data,
        "has_poses": has_poses,
        "poses_dtype": str(data["poses"].dtype) if has_poses else str(poses.dtype),
        "key_order": list(data),
        "arrays": {k: (str(np.asarray(data[k]).dtype), np.shape(data[k])) for k in own},
        "split": split,
        "betas_rows": betas_rows,
        "absent": [k for k in ("trans", "betas") if k not in data],  # written once not zero
        "branches": branches,
    }
    if as_read is not None:
        layout[AS_READ] = as_read
    motion = Motion.from_poses(
        poses, trans, betas, fps, gender=gender, joint_mask=mask, extras=extras,
        layout=layout, notes=notes,
    )  # fmt: skip
    return motion if as_read is None else fill_placeholders(motion, trans_bad)


def _split_array(data: dict[str, np.ndarray], key: str, T: int) -> np.ndarray | None:
    """``data[key]`` as (T, columns) float64, or None when it is absent or not that shape."""
    columns = SPLIT_KEYS[key][0]
    if key not in data:
        return None
    arr = np.asarray(data[key])
    if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
        return None
    if arr.ndim < 2 or arr.shape[0] != T or arr.size != T * columns:
        return None
    return np.asarray(arr, dtype=np.float64).reshape(T, columns)


def _poses_from_split(data: dict[str, np.ndarray], path: Path) -> np.ndarray:
    """(T, W) ``poses`` put together from a file's split arrays (a file without ``poses``)."""
    if not all(k in data for k in _BODY_SPLIT_KEYS):
        raise InputError(
            f"{path}: no 'poses' array, nor 'root_orient' and 'pose_body' "
            f"(keys: {', '.join(sorted(data)) or 'none'})"
        )
    T = np.shape(data["root_orient"])[0] if np.ndim(data["root_orient"]) else 0
    for key in _BODY_SPLIT_KEYS:
        real_array(key, data[key], path, ANGLE, holes=True)
        if _split_array(data, key, T) is None:
            shape = np.shape(data[key])
            raise InputError(
                f"{path}: '{key}' has shape {shape}, expected ({T}, {SPLIT_KEYS[key][0]})"
            )
    for width in (165, 156, 66):  # the widest layout whose split arrays are all there
        keys = [k for k, (_, starts) in SPLIT_KEYS.items() if width in starts]
        parts = {k: _split_array(data, k, T) for k in keys}
        if all(p is not None for p in parts.values()):
            poses = np.zeros((T, width))
            for k, p in parts.items():
                start = SPLIT_KEYS[k][1][width]
                poses[:, start : start + p.shape[1]] = real_array(k, p, path, ANGLE, holes=True)
            return poses
    raise AssertionError("unreachable: width 66 needs only the body arrays")


def _split_layout(
    data: dict[str, np.ndarray], poses: np.ndarray, path: Path, notes: list[str]
) -> dict[str, dict[str, object]]:
    """The split arrays of ``data`` that mirror columns of ``poses``: {key: start, dtype, shape}.

    These are rewritten from the motion on save. ``poses`` wins where they disagree: a body
    array (root_orient, pose_body) that differs is noted and rewritten; a hand, jaw or eye
    array that differs (another column layout) is noted and kept as it is, as an extra.
    """
    T, width = poses.shape
    split: dict[str, dict[str, object]] = {}
    for key, (columns, starts) in SPLIT_KEYS.items():
        arr = _split_array(data, key, T)
        start = starts.get(width)
        if arr is None or start is None:
            continue
        cols = f"poses[:, {start}:{start + columns}]"
        with np.errstate(invalid="ignore"):
            diff = np.abs(arr - poses[:, start : start + columns])
        diff[np.isnan(diff) & (arr == poses[:, start : start + columns])] = 0.0  # inf == inf
        diff[np.isnan(arr) & np.isnan(poses[:, start : start + columns])] = 0.0
        worst = float(diff.max()) if np.all(np.isfinite(diff)) else float("inf")
        if worst > _SPLIT_TOL and key not in _BODY_SPLIT_KEYS:
            notes.append(f"'{key}' differs from {cols} by up to {worst:.3g}: kept as it is")
            continue
        if worst > _SPLIT_TOL:
            notes.append(
                f"'{key}' differs from {cols} by up to {worst:.3g} rad: "
                f"'poses' is used, and '{key}' is rewritten from it"
            )
        split[key] = {
            "start": start,
            "dtype": str(np.asarray(data[key]).dtype),
            "shape": np.shape(data[key]),
        }
    return split


def motion_to_arrays(motion: Motion, holes: bool = True) -> dict[str, np.ndarray]:
    """The arrays to write for a Motion, in the layout it was read with.

    Every key read is written back with its dtype, shape and place in the key order (keys the
    file did not have, e.g. a new ``joint_mask``, come last); split pose arrays are rewritten
    from the motion's pose, so they agree with ``poses``. holes: the file's NaN back in its
    holes when the motion is marked so (``formats.npz_holes.keep_holes``).
    """
    layout = motion.layout
    specs: dict = layout.get("arrays") or {}
    T = motion.num_frames
    poses_dtype = _float_dtype(layout.get("poses_dtype"), np.dtype("float64"))

    def float_dtype(key: str) -> np.dtype:
        return _float_dtype(specs[key][0] if key in specs else None, poses_dtype)

    out: dict[str, np.ndarray] = dict(motion.extras)
    poses, trans = on_file_branches(motion.poses, layout.get("branches")), motion.trans.copy()
    if holes:
        restore_holes(poses, trans, layout)
    if layout.get("has_poses", True):
        out["poses"] = poses.astype(poses_dtype)
    for key, spec in (layout.get("split") or {}).items():
        columns = SPLIT_KEYS[key][0]
        start = int(spec["start"])
        shape = (T, *tuple(spec["shape"])[1:])
        out[key] = poses[:, start : start + columns].reshape(shape).astype(spec["dtype"])
    out["trans"] = trans.astype(float_dtype("trans"))
    out["betas"] = _betas_array(motion, specs.get("betas"), float_dtype("betas"))
    for key in layout.get("absent") or ():  # a file without them stays so while they are 0
        if not np.any(out[key]):
            del out[key]
    fps_key = str(layout.get("fps_key") or "mocap_framerate")  # a file without one: added
    out[fps_key] = fps_array(motion.fps, specs.get(fps_key))
    if layout.get("has_gender", True):
        g = gender_as_written(motion.gender, layout)
        out["gender"] = like_stored(np.array(g), specs.get("gender"))
    if motion.joint_mask is not None:
        mask = motion.joint_mask.astype(bool)
        spec = specs.get("joint_mask")
        out["joint_mask"] = mask if spec is None else mask.astype(spec[0])

    order = [k for k in layout.get("key_order") or () if k in out]
    return {k: out[k] for k in [*order, *(k for k in out if k not in order)]}


def _float_dtype(name: object, default: np.dtype) -> np.dtype:
    """``name`` as a dtype when it is a floating one, else ``default`` (never round to ints)."""
    if name is None:
        return default
    dtype = np.dtype(str(name))
    return dtype if np.issubdtype(dtype, np.floating) else default


def _betas_array(motion: Motion, spec: tuple | None, dtype: np.dtype) -> np.ndarray:
    """``betas`` in the file's shape: per frame (T, S) when it was, else its own shape."""
    betas = np.asarray(motion.betas, dtype=np.float64)
    rows = motion.layout.get("betas_rows")
    if rows is not None:  # per frame: the file's rows while the shape and frames are unchanged
        rows = np.asarray(rows)
        unchanged = rows.shape[0] == motion.num_frames and rows.shape[1] == betas.size
        if unchanged and np.allclose(rows.astype(np.float64).mean(axis=0), betas, atol=1e-6):
            return rows.astype(dtype)
        return np.tile(betas, (motion.num_frames, 1)).astype(dtype)
    if spec is not None and int(np.prod(spec[1])) == betas.size:
        betas = betas.reshape(spec[1])
    return betas.astype(dtype)


def save_motion(motion: Motion, path: Path | str, forbid: tuple[Path, ...] = ()) -> None:
    """Write ``motion`` to ``path`` atomically (temporary file + rename), never onto ``forbid``.

    The archive is compressed when the file the motion was read from was. A motion whose
    pose, translation or shape is not finite in the file's dtypes (e.g. 1e300 in float32) is
    refused: it could not be read back.
    """
    with np.errstate(over="ignore", invalid="ignore"):  # the check below says it in one line
        arrays = motion_to_arrays(motion, holes=False)
    for key in ("poses", "trans", "betas", *SPLIT_KEYS):
        if key in arrays and not np.isfinite(arrays[key]).all():
            raise InputError(
                f"cannot write {path}: its '{key}' is not finite as {arrays[key].dtype} "
                "(values too large); nothing written"
            )
    if motion.layout.get(HOLES):  # the file's NaN back in its holes (--fill off)
        arrays = motion_to_arrays(motion)
    compress = bool(motion.layout.get("compressed"))

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            write_npz(fh, arrays, compress)

    write_atomic(Path(path), write, forbid=forbid)
