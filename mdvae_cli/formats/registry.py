"""The one front door for motion files: :func:`read` any file mdvae understands, :func:`write`
a motion in any form mdvae writes.

    loaded = read("wham_output.pkl")                             # format from name and contents
    loaded = read("take.pt", ReadOptions(format="gvhmr", fps=25))  # name the format / frame rate
    for label, motion in loaded.tracks: ...                      # label None for a one-person file
    motion = read("take.bvh").single()                           # exactly one motion
    write(cleaned, "clean.bvh", take=loaded.take)                # a take back on its own skeleton
    write(cleaned, "clean.pkl", document=loaded.document)        # a WHAM file back as WHAM's

What each suffix is (``.gz`` ignored):

* ``.npz``: AMASS-style (``formats.npz_io``), or a video pipeline's (SLAHMR, TRAM) told apart by
  its keys;
* ``.bvh``, ``.amc``: a mocap take, retarget onto the body at its own rate
  (``retarget.take``; torch is loaded then); :attr:`LoadedFile.take` keeps what writing it
  back on its own skeleton needs;
* pickles, joblib, torch files and ``.npy`` (VIDEO_SUFFIXES): a video pipeline's output or
  AIST++, read without running code (``formats.data_files``) and turned upright
  (``formats.estimates``); :attr:`LoadedFile.document` keeps what writing the file back in
  its own form needs (``formats.video_back``);
* FBX, C3D, videos (UNSUPPORTED): refused in one line that says what to do instead.

Every command that reads or writes motion (denoise, eval, view, plot, import, export-bvh,
add-noise, export-mesh) goes through here. Failures are one-line :class:`InputError` s that name
the file.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mdvae_cli.body.data import BodyModelData
from mdvae_cli.errors import InputError
from mdvae_cli.fileio import check_regular
from mdvae_cli.formats.estimates import (
    ALIASES,
    FORMATS,
    format_name,
    read_data_file,
    read_npz_file,
)
from mdvae_cli.formats.loaded import LoadedFile
from mdvae_cli.motion.motion import Motion, check_fps

if TYPE_CHECKING:
    from mdvae_cli.retarget.take import Take, TakeReader

__all__ = ["ALIASES", "FORMATS", "LoadedFile", "format_name"]

#: the outputs of video pipelines (and AIST++): containers read by ``formats.data_files``
VIDEO_SUFFIXES = (".pkl", ".pk", ".pt", ".pth", ".npy", ".pickle", ".joblib")
#: mocap takes: retargeted on reading, written back on their own skeleton
TAKE_SUFFIXES = (".bvh", ".amc")
#: every suffix :func:`read` takes (each also ``.gz``-compressed)
READ_SUFFIXES = (".npz", *VIDEO_SUFFIXES, *TAKE_SUFFIXES)
#: every suffix :func:`write` writes
WRITE_SUFFIXES = (".npz", ".bvh", ".amc")

#: formats mdvae does not read or write, and the way forward for each
UNSUPPORTED = {
    ".fbx": "FBX is not supported: export the take as BVH (Blender, Maya and MotionBuilder all "
    "export .bvh) and give that",
    ".c3d": "C3D marker files are not supported: solve the markers onto a skeleton first (MoSh++ "
    "gives AMASS .npz; Vicon, Motive and Qualisys export BVH) and give that",
    ".trc": "TRC marker files are not supported: solve the markers onto a skeleton first (e.g. "
    "OpenSim, MoSh++) and give a BVH or AMASS .npz",
    ".asf": "an ASF is a skeleton, not a motion: give its .amc takes (the .asf is found next to "
    "them, or pass --asf)",
    ".glb": "glTF is not supported: export the animation as BVH and give that",
    ".gltf": "glTF is not supported: export the animation as BVH and give that",
    ".usd": "USD is not supported: export the animation as BVH and give that",
    **{
        s: "a video, not a motion file: run a video pose pipeline on it first (WHAM, GVHMR, "
        "TRAM, 4D-Humans, ...) and give its output file"
        for s in (".mp4", ".mov", ".avi", ".mkv", ".webm")
    },
}


def suffix_of(path: Path | str) -> str:
    """``take.BVH.gz`` -> ``.bvh``."""
    return Path(Path(path).name.lower().removesuffix(".gz")).suffix


@dataclass(frozen=True)
class ReadOptions:
    """What reading a file may need besides its path (every field optional).

    format: a FORMATS name (or alias) to skip detection (``--format``). fps: the input's frame
    rate (``--fps``: video outputs store none, 30 assumed; for other files it replaces the
    file's). track: keep only this person track. allow_pickle: AMASS npz files with pickled
    objects (runs their code: trusted files only). body: the body model takes are retargeted
    onto and video translations placed on (None: the built-in body). skeleton: the ``.asf``
    of AMC takes (None: looked for next to each). joint_map: SMPL joint -> the take's joint
    names its names do not reveal. scale: metres per take file unit (None: guessed).
    resample: a rate every motion read is resampled to (None keeps each file's own; a take
    is resampled before its retarget). retarget: the take retarget's ``RetargetSettings``
    (None: the defaults). metadata: kept with a take's motion (default: its file name).
    progress: called with (frames retargeted, frames) while a take is retargeted.
    missing: the rules that mark holes in a BVH / AMC take (``formats.missing``: "frozen",
    "zeros"; none by default).
    """

    format: str | None = None
    fps: float | None = None
    track: str | None = None
    allow_pickle: bool = False
    body: BodyModelData | None = None
    skeleton: Path | None = None
    joint_map: dict[str, str] | None = None
    scale: float | None = None
    resample: float | None = None
    retarget: Any = None
    metadata: dict | None = None
    progress: Callable[[int, int], None] | None = None
    missing: tuple[str, ...] = ()


def unsupported(path: Path | str) -> str | None:
    """Why ``path``'s format is not read or written (with the way forward), or None."""
    return UNSUPPORTED.get(suffix_of(path))


def read(
    path: Path | str, options: ReadOptions | None = None, *, takes: TakeReader | None = None
) -> LoadedFile:
    """Read a motion file of any supported format (module docstring).

    takes: a ``retarget.take.TakeReader`` shared over a command's files (the body's joints,
    each ASF and each skeleton's body shape solved once); None makes one for this file.
    Raises InputError (one line, naming the file) for anything unreadable.
    """
    path = Path(path)
    options = options or ReadOptions()
    name = format_name(options.format)
    if options.fps is not None:
        check_fps(float(options.fps), "--fps")
    check_regular(path)
    kind = suffix_of(path)
    why = unsupported(path)
    if why is not None and name is None:
        raise InputError(f"{path}: {why}")
    if name == "amass" and kind != ".npz":
        raise InputError(f"{path}: --format amass reads AMASS-style .npz files only")
    if name is None and kind in TAKE_SUFFIXES:
        loaded = _read_take(path, options, takes)
    elif name is None and kind == ".npz" or name == "amass":
        loaded = read_npz_file(path, name, options.fps, options.track, options.allow_pickle,
                               options.body)  # fmt: skip
    else:
        loaded = read_data_file(path, name, options.fps, options.track, options.body)
    if options.missing and loaded.take is None:
        npz = loaded.format in ("amass", "gvhmr-npz")
        nan = " (an npz marks its holes as NaN rows)" if npz else ""
        loaded.notes.append(f"--missing applies to BVH and AMC takes{nan}; ignored")
    if options.resample is not None and loaded.take is None:
        from mdvae_cli.motion.resample import resample_motion

        loaded.tracks = [(lab, resample_motion(m, options.resample)) for lab, m in loaded.tracks]
    return loaded


def _read_take(path: Path, options: ReadOptions, takes: TakeReader | None) -> LoadedFile:
    from mdvae_cli.retarget.take import TakeReader, with_missing

    if options.track is not None:
        raise InputError(f"{path}: --track applies to files of several people; a take holds one")
    reader = takes or TakeReader(options.body, options.skeleton, options.joint_map)
    take = reader.read(path, fps=options.fps, scale=options.scale, rate=options.resample,
                       settings=options.retarget, metadata=options.metadata,
                       skeleton=options.skeleton, progress=options.progress)  # fmt: skip
    fmt = suffix_of(path)[1:]
    return LoadedFile(path, fmt, "mocap", [(None, with_missing(take, options.missing))], take=take)


def write(
    item: Motion | LoadedFile,
    path: Path | str,
    *,
    take: Take | None = None,
    document: Any = None,
    body: BodyModelData | None = None,
    forbid: tuple[Path, ...] = (),
    bvh_units: str = "cm",
    bvh_order: str = "ZXY",
    progress: Callable[[int, int], None] | None = None,
) -> list[str]:
    """Write a motion (atomically; never over a path in ``forbid``) in the form ``path`` names.
    -> notes for the user about what was written (a video pipeline's form: what was left out).

    ``.npz``: AMASS-style (``formats.npz_io``), or with the ``document`` of a ROMP / SLAHMR
    file (whose own file is an ``.npz``) that file's layout. ``.bvh`` / ``.amc`` (``.gz``
    too) with ``take`` (or a LoadedFile read from a take): on the take's own skeleton, in its
    own form; ``.bvh`` without one: on the SMPL skeleton of the motion's shape (``bvh_units``,
    ``bvh_order``; ``body`` None: the built-in body). A video pipeline's form (``.pkl``,
    ``.pt``, ...) with ``document`` (``LoadedFile.document``): the file it was read from, its
    tracks put back (``formats.video_back``); a LoadedFile's tracks are written there
    together. InputError for any other form, saying what to do. progress: (frames carried
    back, frames) while a BVH take's way back goes.
    """
    path = Path(path)
    kind = suffix_of(path)
    if isinstance(item, LoadedFile):
        take = take if take is not None else item.take
        document = document if document is not None else item.document
        if _video_form(kind, document, path):
            return _write_video(document, dict(item.tracks), path, forbid)
        item = item.single()
    if _video_form(kind, document, path):
        labels = [label for label, _, _ in document.tracks]
        if len(labels) != 1:
            raise InputError(f"cannot write {path}: the file holds {len(labels)} tracks; give "
                             "them all (a LoadedFile)")  # fmt: skip
        return _write_video(document, {labels[0]: item}, path, forbid)
    check_writable(item, path)
    if kind == ".npz":
        from mdvae_cli.formats.gvhmr_npz import camera_follows_world
        from mdvae_cli.formats.npz_io import save_motion

        item, notes = camera_follows_world(item)  # a GVHMR npz's camera-frame copies
        save_motion(item, path, forbid=forbid)
        return notes
    if kind in TAKE_SUFFIXES and take is not None:
        from mdvae_cli.retarget.take import write_take

        return write_take(take, item, path, forbid=forbid, progress=progress)
    if kind == ".bvh":
        from mdvae_cli.formats.bvh_write import write_text
        from mdvae_cli.retarget.fit_shape import BodyJoints
        from mdvae_cli.retarget.smpl_bvh import smpl_bvh

        joints = BodyJoints(body if body is not None else _builtin())
        write_text(path, smpl_bvh(item, joints, bvh_units, bvh_order), forbid=forbid)
        return []
    if kind == ".amc":
        raise InputError(f"cannot write {path}: AMC is written only for an AMC take (on its own "
                         "skeleton); write .npz or .bvh")  # fmt: skip
    if kind in VIDEO_SUFFIXES:
        raise InputError(f"cannot write {path}: a video pipeline's file is written only back "
                         "from the file it was read from; write .npz")  # fmt: skip
    raise InputError(
        f"cannot write {path}: mdvae writes .npz and .bvh (and takes back as .amc); Blender, "
        "Maya and MotionBuilder import BVH and save it as FBX"
    )


def _video_form(kind: str, document: Any, path: Path) -> bool:
    """Whether ``path`` goes out as ``document``'s video pipeline file: a pipeline's suffix,
    or ``.npz`` for a pipeline whose own file is one (ROMP, SLAHMR)."""
    if document is None:
        return False
    if kind in VIDEO_SUFFIXES:
        return True
    from mdvae_cli.formats.video_back import writes_back

    return kind == ".npz" and writes_back(document, path)


def _write_video(document: Any, tracks: dict, path: Path, forbid: tuple[Path, ...]) -> list[str]:
    from mdvae_cli.formats.video_back import write_video, writes_back

    if not writes_back(document, path):
        raise InputError(f"cannot write {path}: {document.own_form()}; write .npz")
    for motion in tracks.values():
        check_writable(motion, path, holes=True)
    return write_video(document, tracks, path, forbid=forbid)


def check_writable(motion: Motion, path: Path, holes: bool = False) -> None:
    """InputError when ``motion`` holds values no motion file may (NaN, angles or distances
    past the readers' limits): nothing is written that mdvae would refuse to read back.
    holes: NaN allowed (frames a video pipeline's file keeps as they came)."""
    from mdvae_cli.formats.npz_values import ANGLE, DISTANCE

    # named in the user's words: the file written may call them 'poses', channels, 'smpl'...
    for what, arr, limit in (("the root rotation", motion.root_orient, ANGLE),
                             ("a body-joint rotation", motion.pose_body, ANGLE),
                             ("the root translation", motion.trans, DISTANCE)):  # fmt: skip
        arr = np.asarray(arr, dtype=np.float64)
        if holes:
            arr = arr[np.isfinite(arr)]
        if not np.isfinite(arr).all():
            raise InputError(f"cannot write {path}: {what} holds NaN or infinite values; "
                             "nothing written")  # fmt: skip
        if arr.size and np.abs(arr).max() > limit.largest:
            worst = limit.value.format(float(np.abs(arr).max()))
            raise InputError(f"cannot write {path}: {what} {worst} ({limit.kind} are "
                             "refused on reading; nothing written)")  # fmt: skip


def _builtin() -> Any:
    from mdvae_cli.body.builtin import builtin_body_model

    return builtin_body_model()
