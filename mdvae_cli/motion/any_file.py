"""Read any motion file mdvae understands into a :class:`Motion`: one function, one table.

:func:`load_any_motion` picks a reader by the file's suffix (``.gz`` ignored) from READERS:
AMASS-style ``.npz`` directly, BVH and ASF/AMC retargeted onto the body model at their own rate
(as ``mdvae denoise`` reads takes). A new format is one more entry::

    READERS[".pkl"] = read_my_pickle  # (path, ReadOptions) -> Motion

Commands that only show or compare motions (``mdvae view``, ``mdvae plot``) read through here,
so every format added to the table works in all of them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from mdvae_cli.body.data import BodyModelData
from mdvae_cli.errors import InputError
from mdvae_cli.motion import cmu
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.npz_io import load_motion


@dataclass(frozen=True)
class ReadOptions:
    """What a reader may need besides the path.

    allow_pickle: read .npz files that hold pickled objects (only trusted files).
    body: the body model mocap (BVH, AMC) is retargeted onto; None = the built-in body.
    skeleton: the .asf an .amc motion needs; None = look next to the file (:func:`find_asf`).
    joint_map: SMPL joint -> the take's joint names its names do not reveal (``--joint-map``).
    fps: the rate BVH / AMC motions are resampled to; None keeps the take's own rate (one
        frame per file frame, as ``mdvae denoise`` reads takes).
    """

    allow_pickle: bool = False
    body: BodyModelData | None = None
    skeleton: Path | None = None
    joint_map: dict[str, str] | None = None
    fps: float | None = None


Reader = Callable[[Path, ReadOptions], Motion]


def _suffix(path: Path) -> str:
    """``take.BVH.gz`` -> ``.bvh``."""
    return Path(path.name.lower().removesuffix(".gz")).suffix


def find_asf(path: Path) -> Path | None:
    """The skeleton next to an AMC file: ``<subject>.asf`` (CMU naming), else the folder's only
    ``.asf`` (``.asf.gz`` too); None when there is none or several."""
    path = Path(path)
    ids = cmu.trial_of(path)
    if ids is not None:
        for name in (f"{ids[0]}.asf", f"{ids[0]}.asf.gz"):
            if (path.parent / name).is_file():
                return path.parent / name
    found = [p for p in sorted(path.parent.iterdir()) if p.is_file() and _suffix(p) == ".asf"]
    return found[0] if len(found) == 1 else None


def read_npz(path: Path, options: ReadOptions) -> Motion:
    """An AMASS-style .npz (:func:`~mdvae_cli.motion.npz_io.load_motion`), or a video
    pipeline's .npz (``motion.load_any`` tells them apart)."""
    return read_estimates(path, options)


def read_estimates(path: Path, options: ReadOptions) -> Motion:
    """Any file ``motion.load_any`` reads (AMASS .npz, video pipelines' pickles and torch
    files, AIST++): its one motion, or its first person track (said in the notes)."""
    from mdvae_cli.motion.load_any import load_any

    loaded = load_any(path, allow_pickle=options.allow_pickle)
    label, motion = loaded.tracks[0]
    notes = [*loaded.notes]
    if len(loaded.tracks) > 1:
        notes.append(f"{len(loaded.tracks)} people tracked: showing track {label}")
    motion.notes = [*motion.notes, *notes]
    return motion if options.fps is None else _resampled(motion, options.fps)


def _resampled(motion: Motion, fps: float) -> Motion:
    from mdvae_cli.motion.resample import resample_motion

    return resample_motion(motion, fps)


def read_mocap(path: Path, options: ReadOptions) -> Motion:
    """A BVH or AMC take, retargeted onto the body at its own frame rate as ``mdvae denoise``
    reads takes (:func:`~mdvae_cli.motion.take.read_take`; torch needed)."""
    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.motion.asf import load_asf
    from mdvae_cli.motion.fit_shape import BodyJoints
    from mdvae_cli.motion.resample import resample_motion
    from mdvae_cli.motion.take import read_take

    skeleton = None
    if _suffix(path) == ".amc":
        found = options.skeleton or find_asf(path)
        if found is None:
            raise InputError(f"{path}: no .asf skeleton found next to it; pass --asf FILE")
        skeleton = load_asf(found)
    body = BodyJoints(options.body if options.body is not None else load_body_model(None))
    take = read_take(path, body, skeleton=skeleton, joint_map=options.joint_map)
    motion = take.motion
    motion.notes.append(
        f"retargeted from {_suffix(path)[1:].upper()} onto the body "
        f"(mean joint error {1000 * take.retarget.mean_error:.1f} mm)"
    )
    return motion if options.fps is None else resample_motion(motion, options.fps)


#: suffix -> reader; extend it to read more formats everywhere load_any_motion is used
READERS: dict[str, Reader] = {
    ".npz": read_npz,
    ".bvh": read_mocap,
    ".amc": read_mocap,
    **{s: read_estimates for s in (".pkl", ".pk", ".pt", ".pth", ".npy", ".pickle", ".joblib")},
}


def readable_suffixes() -> tuple[str, ...]:
    """The suffixes :func:`load_any_motion` reads (each also ``.gz``-compressed)."""
    return tuple(READERS)


def load_any_motion(path: Path | str, options: ReadOptions | None = None) -> Motion:
    """Read a motion file of any format in READERS (chosen by suffix; ``.gz`` is ignored).

    A file of another suffix is tried as .npz, which answers with a one-line InputError when
    it is not one. Raises InputError for missing, unreadable or malformed files.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"no such file: {path}")
    if path.is_dir():
        raise InputError(f"{path} is a folder, expected a motion file")
    reader = READERS.get(_suffix(path), read_amass)
    return reader(path, options or ReadOptions())


def read_amass(path: Path, options: ReadOptions) -> Motion:
    """An AMASS-style .npz only (a file of an unknown suffix is tried as one)."""
    return load_motion(path, allow_pickle=options.allow_pickle)
