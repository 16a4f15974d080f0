"""Motion files that need no retarget: AMASS-style ``.npz`` and the outputs of video pose
pipelines (WHAM, GVHMR, TRAM, 4D-Humans/PHALP, VIBE, PARE, HybrIK, ROMP/BEV, SLAHMR) and AIST++
pickles, each read into upright Motions (z up, metres), one per person track.

``formats.registry.read`` calls these; pickles and torch files are read with the restricted
unpickler (``formats.safe_data``): arrays, tensors and plain containers only, anything else
refused in one line.
"""

from __future__ import annotations

import gzip
import io
import zipfile
import zlib
from pathlib import Path

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.formats.loaded import LoadedFile
from mdvae_cli.formats.npz_io import load_motion

#: every format name ``--format`` takes ("amass": AMASS-style .npz; the others are the readers
#: of ``formats.video_formats``, imported when needed: they need torch, listing them does not)
FORMATS = ("amass", "wham", "gvhmr", "tram", "phalp", "vibe", "hybrik", "romp", "slahmr", "aistpp")
#: other names ``--format`` accepts
ALIASES = {
    "pare": "vibe",
    "4dhumans": "phalp",
    "4d-humans": "phalp",
    "hmr2": "phalp",
    "bev": "romp",
    "hybrik-x": "hybrik",
    "aist++": "aistpp",
}
#: formats whose files come from a video pipeline (denoise picks its settings for video)
_MOCAP_FORMATS = ("amass", "aistpp")
#: npz keys that mark a downstream conversion of GVHMR output into an AMASS-style file
_GVHMR_NPZ_KEY = "smpl_params_incam_global_orient"


def format_name(fmt: str | None) -> str | None:
    """The canonical name of a ``--format`` value (aliases such as "pare", "bev" accepted);
    InputError for an unknown one."""
    if fmt is None:
        return None
    name = ALIASES.get(fmt.lower(), fmt.lower())
    if name not in FORMATS:
        known = ", ".join(sorted({*FORMATS, *ALIASES}))
        raise InputError(f"unknown --format {fmt!r} (known: {known})")
    return name


def read_npz_file(path: Path, name, fps, track, allow_pickle: bool, body) -> LoadedFile:
    """An ``.npz``: AMASS-style (``name`` "amass" or None), or a video pipeline's (SLAHMR,
    TRAM) or AIST++ motion saved as one: told apart by their keys when ``name`` is None."""
    if name is None:
        data_npz = _npz_keys(path) & {"sequence_results", "results", "cam_R", "track_mask",
                                      "smpl_poses"}  # fmt: skip
        name = None if data_npz else "amass"
    if name == "amass":
        return _load_amass(path, fps, track, allow_pickle)
    return read_data_file(path, name, fps, track, body)


def read_data_file(path: Path, name, fps, track, body) -> LoadedFile:
    """A video pipeline's output (or AIST++) of any container, its format ``name`` or (None)
    told from its contents."""
    from mdvae_cli.formats.data_files import load_data, pickled_container, read_bytes
    from mdvae_cli.formats.video_formats import detect

    raw_bytes = read_bytes(Path(path))
    data = load_data(path, raw_bytes)
    container = pickled_container(raw_bytes)
    if container is None and raw_bytes[:2] == b"PK" and _is_npz_name(path):
        container = "npz"  # an archive of arrays (AIST++ motion saved by np.savez)
    del raw_bytes
    name = name or detect(data)
    inner = data.item() if isinstance(data, np.ndarray) and data.dtype.hasobject else data
    if name is None and isinstance(inner, dict) and "world_cam_R" in inner:
        raise InputError(
            f"{path}: TRAM's camera file, not a motion: give the hps/hps_track_<k>.npy files "
            "(they read it from two folders up)"
        )
    if name is None:
        raise InputError(f"{path}: {_unknown_layout(inner)}")
    return _load_video(path, name, data, fps, track, body, container)


def _is_npz_name(path: Path | str) -> bool:
    """Whether a file's name ends in ``.npz`` (``.npz.gz`` too, any case)."""
    return Path(path).name.lower().removesuffix(".gz").endswith(".npz")


def _unknown_layout(data: object) -> str:
    """Why a data file is refused: SMPL arrays in a pickle (AMASS keys, or an SMPL parameter
    dump, whose up axis no key tells) said as such, with the way to an .npz; else the formats
    ``--format`` may name (AMASS-style files are .npz archives, never pickles)."""
    keys = set(map(str, data)) if isinstance(data, dict) else set()
    amass = "an AMASS-style .npz (poses, trans, betas, mocap_framerate; z up)"
    if "poses" in keys or {"root_orient", "pose_body"} <= keys:
        return f"AMASS-style arrays in a pickle: mdvae reads them as {amass}; save them so"
    if {"global_orient", "body_pose"} <= keys:
        return (
            "SMPL parameters ('global_orient', 'body_pose') in a layout mdvae does not know "
            f"(nor their up axis): save them as {amass}, poses = global_orient + body_pose"
        )
    video = ", ".join(f for f in FORMATS if f != "amass")
    return (
        f"not a motion layout this tool knows (if it is one of {video}: denoise, "
        "add-noise and import read it with --format)"
    )


def _npz_keys(path: Path) -> set[str]:
    """The array names of an npz (gzipped or not), without loading any of them; a gzipped one
    is expanded no further than MAX_DECOMPRESSED."""
    from mdvae_cli.formats.data_files import MAX_DECOMPRESSED

    try:
        if path.suffix.lower() == ".gz":
            with gzip.open(path, "rb") as fh:
                raw = fh.read(MAX_DECOMPRESSED + 1)
            if len(raw) > MAX_DECOMPRESSED:
                return set()  # load_motion refuses it
            source = io.BytesIO(raw)
        else:
            source = path
        with zipfile.ZipFile(source) as zf:
            return {n.removesuffix(".npy") for n in zf.namelist()}
    except (OSError, EOFError, zlib.error, zipfile.BadZipFile):
        return set()  # load_motion says what is wrong with it


def _load_amass(path: Path, fps: float | None, track: str | None, allow_pickle: bool):
    motion = load_motion(path, allow_pickle=allow_pickle, fps=fps)
    if track is not None:
        raise InputError(f"{path}: --track applies to files of several people; this one holds one")
    fmt, kind, notes = "amass", "mocap", []
    if _imported_from_video(motion):  # mdvae import's output of a video file: video settings
        kind = "video"
    if _GVHMR_NPZ_KEY in motion.extras:
        from mdvae_cli.formats.gvhmr_npz import remember_world

        fmt, kind = "gvhmr-npz", "video"
        remember_world(motion)  # its camera-frame copies follow the cleaning on writing
        notes.append(
            "a GVHMR result converted to an AMASS-style file: SMPL-X body pose (the last "
            "6 'poses' columns are not SMPL hands)"
        )
    if fps is not None and abs(fps - motion.fps) > 1e-9:
        motion.notes.append(f"frame rate {fps:g} Hz (--fps), the file says {motion.fps:g}")
        motion.fps = float(fps)
    return LoadedFile(path, fmt, kind, [(None, motion)], notes)


def _imported_from_video(motion) -> bool:
    """Whether an AMASS-style motion is ``mdvae import``'s output of a video pipeline's file:
    its ``source_format`` extra names a video format."""
    fmt = motion.extras.get("source_format")
    if not isinstance(fmt, np.ndarray) or fmt.ndim != 0 or fmt.dtype.kind not in "US":
        return False
    name = str(fmt.item() if fmt.dtype.kind == "U" else fmt.item().decode("utf-8", "replace"))
    return name in FORMATS and name not in _MOCAP_FORMATS


def _load_video(path, name, data, fps, track, body, container=None) -> LoadedFile:
    from mdvae_cli.formats.video_formats import READERS, VIDEO_FPS, read_tram
    from mdvae_cli.formats.video_holes import track_holes
    from mdvae_cli.formats.video_tracks import track_to_motion

    if isinstance(data, np.ndarray) and data.dtype.hasobject and data.ndim == 0:
        data = data.item()  # np.save of a dict
    if not isinstance(data, dict):
        raise InputError(f"{path}: holds a {type(data).__name__}, not a {name} result")
    reader = READERS[name][0]
    raws = read_tram(data, str(path), path) if name == "tram" else reader(data, str(path))
    if track is not None:
        labels = [r.label for r in raws]
        raws = [r for r in raws if r.label == str(track) or (len(raws) == 1 and r.label is None)]
        if not raws:
            raise InputError(f"{path}: no track {track!r} (tracks: {', '.join(map(str, labels))})")
    if body is None:
        from mdvae_cli.body.builtin import builtin_body_model

        body = builtin_body_model()
    from mdvae_cli.formats.video_back import VideoDocument

    out, document = [], VideoDocument(name, data, container=container)
    for raw in raws:
        raw = track_holes(raw, str(path))  # NaN / inf: holes with placeholders, as in an npz
        rate = fps if fps is not None else (raw.fps or VIDEO_FPS)
        motion = track_to_motion(raw, rate, body, str(path))
        if fps is None and raw.fps is None:
            motion.notes.append(f"no frame rate in the file: {VIDEO_FPS:g} fps assumed")
        motion.extras.setdefault("source_format", np.array(name))
        label = raw.label if len(raws) > 1 else None
        out.append((label, motion))
        document.tracks.append((label, raw, motion))
    kind = "mocap" if name in _MOCAP_FORMATS else "video"
    return LoadedFile(path, name, kind, out, document=document)
