"""Load any motion file the tool reads: AMASS-style ``.npz`` and the output files of video pose
pipelines (WHAM, GVHMR, TRAM, 4D-Humans/PHALP, VIBE, PARE, HybrIK, ROMP/BEV, SLAHMR) and AIST++
pickles, each as upright Motions (z up, metres), one per person track.

    loaded = load_any("wham_output.pkl")              # format from the extension and contents
    loaded = load_any("take.pt", fmt="gvhmr", fps=25)  # name the format / frame rate
    for label, motion in loaded.tracks: ...            # label None for a one-person file
    motion = load_one("take.npz")                      # exactly one motion (else InputError)

Every command that reads motion (denoise, import, eval, add-noise, ...) goes through
:func:`load_any`. Pickles and torch files are read with the restricted unpickler
(``body.safe_data``): arrays, tensors and plain containers only, anything else refused in one
line. BVH and ASF/AMC are retargeted by ``mdvae import`` instead (they need a skeleton solve).
"""

from __future__ import annotations

import gzip
import io
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mdvae_cli.body.data import BodyModelData
from mdvae_cli.errors import InputError
from mdvae_cli.motion.motion import Motion, check_fps
from mdvae_cli.motion.npz_io import load_motion

#: every format name ``--format`` takes ("amass": AMASS-style .npz; the others are the readers
#: of ``motion.video_formats``, imported when needed: they need torch, listing them does not)
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
#: file names a folder is searched for (``.gz`` versions too)
MOTION_FILE_SUFFIXES = (".npz", ".pkl", ".pk", ".pt", ".pth", ".npy", ".pickle", ".joblib")
#: formats whose files come from a video pipeline (denoise picks its settings for video)
_MOCAP_FORMATS = ("amass", "aistpp")
#: npz keys that mark a downstream conversion of GVHMR output into an AMASS-style file
_GVHMR_NPZ_KEY = "smpl_params_incam_global_orient"


@dataclass
class LoadedFile:
    """What :func:`load_any` read from one file.

    path: the file; format: its format name (FORMATS, or "gvhmr-npz"); kind: "video" for a
    video pipeline's estimates, "mocap" otherwise (denoise settings follow it); tracks:
    ``(label, motion)`` per person, label None when the file holds one motion; notes: remarks
    about the file as a whole.
    """

    path: Path
    format: str
    kind: str
    tracks: list[tuple[str | None, Motion]]
    notes: list[str] = field(default_factory=list)

    def single(self) -> Motion:
        """The one motion of the file; InputError when it holds several tracks."""
        if len(self.tracks) != 1:
            labels = ", ".join(str(lab) for lab, _ in self.tracks)
            raise InputError(
                f"{self.path}: holds {len(self.tracks)} tracks ({labels}); pick one with --track ID"
            )
        return self.tracks[0][1]


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


def load_any(
    path: Path | str,
    fmt: str | None = None,
    *,
    fps: float | None = None,
    track: str | None = None,
    allow_pickle: bool = False,
    body: BodyModelData | None = None,
) -> LoadedFile:
    """Read a motion file of any supported format (module docstring).

    fmt: a FORMATS name (or alias) to skip detection; fps: the frame rate to use (video
    outputs store none: default 30; for other files it overrides the file's); track: keep only
    the track with this label; allow_pickle: AMASS npz files with pickled objects (runs their
    code: trusted files only); body: the body model whose rest pelvis places converted
    translations (default: the built-in body). Raises InputError (one line) for anything
    unreadable.
    """
    path = Path(path)
    name = format_name(fmt)
    if fps is not None:
        check_fps(float(fps), "--fps")
    if not path.exists():
        raise InputError(f"no such file: {path}")
    if path.is_dir():
        raise InputError(f"{path} is a folder, expected a motion file")
    kind = path.name.lower().removesuffix(".gz").rsplit(".", 1)[-1]
    if name is None and kind in ("bvh", "amc", "asf"):
        raise InputError(
            f"{path}: a .{kind} file; convert it first with `mdvae import {path} -o imported/`"
        )
    data = None
    if name is None and kind == "npz":
        keys = _npz_keys(path)
        data_npz = keys & {"sequence_results", "results", "cam_R", "track_mask"}
        name = None if data_npz else "amass"
    if name == "amass":
        return _load_amass(path, fps, track, allow_pickle)
    from mdvae_cli.body.data_files import load_data
    from mdvae_cli.motion.video_formats import detect

    data = load_data(path)
    name = name or detect(data)
    inner = data.item() if isinstance(data, np.ndarray) and data.dtype.hasobject else data
    if name is None and isinstance(inner, dict) and "world_cam_R" in inner:
        raise InputError(
            f"{path}: TRAM's camera file, not a motion: give the hps/hps_track_<k>.npy files "
            "(they read it from two folders up)"
        )
    if name is None:
        raise InputError(
            f"{path}: not a motion layout this tool knows (give --format: {', '.join(FORMATS)})"
        )
    return _load_video(path, name, data, fps, track, body)


def load_one(path: Path | str, fmt: str | None = None, **kwargs) -> Motion:
    """The one motion of a file (:func:`load_any`, then :meth:`LoadedFile.single`)."""
    return load_any(path, fmt, **kwargs).single()


def _npz_keys(path: Path) -> set[str]:
    """The array names of an npz (gzipped or not), without loading any of them."""
    try:
        if path.suffix.lower() == ".gz":
            with gzip.open(path, "rb") as fh:
                source = io.BytesIO(fh.read())
        else:
            source = path
        with zipfile.ZipFile(source) as zf:
            return {n.removesuffix(".npy") for n in zf.namelist()}
    except (OSError, EOFError, zlib.error, zipfile.BadZipFile):
        return set()  # load_motion says what is wrong with it


def _load_amass(path: Path, fps: float | None, track: str | None, allow_pickle: bool):
    motion = load_motion(path, allow_pickle=allow_pickle)
    if track is not None:
        raise InputError(f"{path}: --track applies to files of several people; this one holds one")
    fmt, kind, notes = "amass", "mocap", []
    if _GVHMR_NPZ_KEY in motion.extras:
        fmt, kind = "gvhmr-npz", "video"
        notes.append(
            "a GVHMR result converted to an AMASS-style file: SMPL-X body pose (the last "
            "6 'poses' columns are not SMPL hands)"
        )
    if fps is not None and abs(fps - motion.fps) > 1e-9:
        motion.notes.append(f"frame rate {fps:g} Hz (--fps), the file says {motion.fps:g}")
        motion.fps = float(fps)
    return LoadedFile(path, fmt, kind, [(None, motion)], notes)


def _load_video(path, name, data, fps, track, body) -> LoadedFile:
    from mdvae_cli.motion.video_formats import READERS, VIDEO_FPS, read_tram
    from mdvae_cli.motion.video_tracks import track_to_motion

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
    out = []
    for raw in raws:
        rate = fps if fps is not None else (raw.fps or VIDEO_FPS)
        motion = track_to_motion(raw, rate, body, str(path))
        if fps is None and raw.fps is None:
            motion.notes.append(f"no frame rate in the file: {VIDEO_FPS:g} fps assumed")
        motion.extras.setdefault("source_format", np.array(name))
        label = raw.label if len(raws) > 1 else None
        out.append((label, motion))
    kind = "mocap" if name in _MOCAP_FORMATS else "video"
    return LoadedFile(path, name, kind, out)
