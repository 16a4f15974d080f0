"""A mocap take (BVH, ASF/AMC) read for cleaning and written back on its own skeleton.

:func:`read_take` retargets the take onto the SMPL body at its own frame rate (one SMPL frame
per file frame) and keeps what writing it again needs; :func:`write_take` carries a cleaned
version of that SMPL motion back onto the file's skeleton (``retarget.way_back``) and writes it
in the file's own form.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from mdvae_cli.body.data import BodyModelData
from mdvae_cli.errors import InputError
from mdvae_cli.fileio import write_atomic
from mdvae_cli.formats.amc_write import write_amc
from mdvae_cli.formats.asf import AsfSkeleton, load_asf
from mdvae_cli.formats.bvh_rotations import let_go_of_rotations
from mdvae_cli.formats.bvh_write import write_bvh
from mdvae_cli.formats.source import SourceMotion
from mdvae_cli.motion import cmu
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.resample import resample_times
from mdvae_cli.retarget.fit_shape import BodyJoints, fit_betas, skeleton_key
from mdvae_cli.retarget.retarget import RetargetResult, import_motion
from mdvae_cli.retarget.source_file import load_source
from mdvae_cli.retarget.way_back import translation_dropped, write_back_data
from mdvae_cli.retarget.way_back_amc import write_back_amc
from mdvae_cli.workers import map_in_order

#: take suffixes (``.gz`` variants too); each is written back in its own form
TAKE_SUFFIXES = (".bvh", ".amc")


@dataclass
class Take:
    """A take as read: the source motion (with its file layout) and its retarget onto SMPL."""

    path: Path
    source: SourceMotion
    retarget: RetargetResult
    body: BodyJoints | None = None  #: the body it was retargeted onto
    skeleton_file: Path | None = None  #: an AMC take's .asf (found next to it, or --asf)
    #: (T, J) True where ``--missing`` named a source joint missing (``formats.missing``)
    missing: np.ndarray | None = None

    @property
    def motion(self) -> Motion:
        """The SMPL motion (AMASS layout, z up), one frame per file frame."""
        return self.retarget.motion


def read_take(
    path: Path | str,
    body: BodyJoints,
    skeleton: AsfSkeleton | Path | str | None = None,
    joint_map: dict[str, str] | None = None,
    scale: float | None = None,
    fps: float | None = None,
    betas: np.ndarray | None = None,
    source: SourceMotion | None = None,
    rate: float | None = None,
    settings=None,
    metadata: dict | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Take:
    """Read a BVH or AMC take and retarget it onto ``body`` at the take's own frame rate.

    skeleton: the ASF of an AMC take. joint_map: SMPL joint -> source joint names the
    skeleton's names do not reveal. scale: metres per file unit (default: guessed). fps: the
    take's true rate when its file is wrong. betas: the body shape (default: fitted).
    source: the take already read with :func:`load_source` (the other arguments but body and
    betas are then unused). rate: resample to this rate first (None: the take's own);
    settings: ``RetargetSettings``; metadata: kept with the motion (default: the file name);
    progress: (frames retargeted, frames) as the retarget goes.
    """
    path = Path(path)
    src = source or load_source(path, skeleton, fps=fps, scale=scale, joint_map=joint_map)
    kept = len(resample_times(src.num_frames, src.fps, rate)) if rate is not None else 2
    if src.num_frames >= 2 > kept:  # the take has frames enough: the rate leaves one
        raise InputError(
            f"{path}: {src.num_frames} frames at {src.fps:g} fps make 1 at {rate:g} fps; a "
            "motion needs at least 2 (import it at its own rate with --fps 0)"
        )
    if betas is None:
        try:
            betas = fit_betas(src, body)
        except InputError as exc:
            raise InputError(f"{path}: {exc}") from None
    try:
        meta = metadata if metadata is not None else {"file": path.name}
        rt = import_motion(src, body, fps=rate, betas=betas, settings=settings, metadata=meta,
                           progress=progress)  # fmt: skip
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
    if not np.isfinite(rt.mean_error):
        raise InputError(f"{path}: the retarget to the body gave non-finite values")
    # the way back makes the take's rotations again a chunk at a time: not held meanwhile
    return Take(path=path, source=let_go_of_rotations(src), retarget=rt, body=body)


def with_missing(take: Take, rules: tuple[str, ...]) -> Motion:
    """The take's motion with its holes marked in ``joint_mask`` and slerp / lerp placeholders
    in them (``motion.holes.with_holes``), and a note: the frames an AMC file lacks (missing
    frame numbers, ``formats.missing.file_gaps``) and what ``rules`` name
    (``formats.missing``); the take's own motion (kept for the way back) when there are none.
    A body joint is missing where the source joint it follows, or takes its rotation from, is.
    The file's missing frames read as the NaN rows of an npz would (``npz_holes.AS_READ``):
    ``--fill off`` and ``add-noise`` keep them as holes."""
    from mdvae_cli.formats.missing import file_gaps

    gaps = file_gaps(take.source)
    if not rules and gaps is None:
        return take.motion
    from mdvae_cli.formats.missing import describe, missing_channels
    from mdvae_cli.motion.holes import hole_count, with_holes

    found = None
    if rules:
        source, found = missing_channels(take.source, rules)
    else:
        source = np.zeros((take.source.num_frames, take.source.num_joints), bool)
    jmap = take.retarget.jmap
    named = source[:, jmap.attach] | source[:, jmap.rot_source]  # (T_file, 22)
    if gaps is not None:
        source[gaps] = True
    motion = take.motion
    at = slice(None)
    if len(named) != motion.num_frames:  # resampled: the nearest file frame
        at = np.rint(np.arange(motion.num_frames) * take.source.fps / motion.fps).astype(int)
        at = np.clip(at, 0, len(named) - 1)
    else:
        take.missing = source
    named = named[at]
    lost = np.zeros(len(named), bool) if gaps is None else gaps[at]
    note = None  # what the rules found
    if found is not None and named.any():
        note = describe(found, hole_count(~named)[0])
    elif found is not None:
        note = f"--missing {','.join(rules)}: no frame matched"
    if not named.any() and not lost.any():
        motion = motion.with_body()
        motion.notes.append(note)
        return motion
    out = with_holes(motion, ~(named | lost[:, None]), "slerp")
    if note is not None:
        out.notes.append(note)
    if lost.any() and take.missing is source:  # the file's own frames: its gaps as NaN rows
        from mdvae_cli.formats.npz_holes import AS_READ, with_nan_holes

        lacking = np.repeat(~lost[:, None], out.joint_mask.shape[1], axis=1)
        out.layout[AS_READ] = with_nan_holes(out, lacking).layout[AS_READ]
    return out


def _restore_missing(take: Take, data: np.ndarray | dict) -> None:
    """Put the file's own values back where ``take.missing`` is (``--fill off``), in place.
    data: a BVH's rows (F, C) or an AMC's bone values {bone: (F, n)}, every frame of the file."""
    layout = take.source.layout
    for j in np.flatnonzero(take.missing.any(axis=0)):
        at = layout.rows[take.missing[:, j]]
        if isinstance(data, dict):
            bone = take.source.names[j]
            if bone in data:
                data[bone][at] = layout.values[bone][at]
        else:
            cols = [c for c, (jj, _, _) in enumerate(layout.channels) if jj == j]
            data[np.ix_(at, cols)] = layout.data[np.ix_(at, cols)]


def write_take(
    take: Take, cleaned: Motion, out: Path | str, body: BodyJoints | None = None,
    forbid: tuple = (), progress: Callable[[int, int], None] | None = None,
) -> list[str]:  # fmt: skip
    """Write ``cleaned`` (the take's SMPL motion after cleaning) on the take's own skeleton,
    in the take's own form: a BVH take as BVH (``.bvh`` or ``.bvh.gz``; its Frame Time the
    rate the take was read at, when ``--fps`` gave another), an AMC take as AMC (``.amc`` or
    ``.amc.gz``; its ASF is unchanged; AMC holds no rate). body: default the one it was read with.
    An AMC take gets a copy of its ``.asf`` (found next to it, or given with --asf) next to
    its output when none of that name is there, so the output reads on its own. -> notes for the
    user (a move of the root the file has no channel for)."""
    out = Path(out)
    body = body if body is not None else take.body
    name = out.name.lower().removesuffix(".gz")
    form = take.source.info.get("format")
    as_read = cleaned.layout.get("holes") == "as read" and take.missing is not None
    if form not in ("bvh", "amc") or not name.endswith(f".{form}"):
        raise InputError(f"{out}: a {form} take is written back as .{form}, or as .npz")
    if form == "bvh":
        data = write_back_data(take.source, take.retarget, take.motion, cleaned, body,
                               progress=progress)  # fmt: skip
        if as_read:
            _restore_missing(take, data)
        if not np.isfinite(data).all():
            raise InputError(f"{take.path}: the way back gave non-finite values; nothing written")
        own = take.source.info.get("fps_in_file", take.source.fps)  # --fps: the rate used
        rate = None if abs(take.source.fps - own) <= 1e-9 * own else take.source.fps
        write_bvh(take.source.layout, data, out, forbid=forbid, fps=rate, rows_map=map_in_order)
        return (
            _dropped_move(take, cleaned) if translation_dropped(take.source, take.retarget) else []
        )
    try:
        values = write_back_amc(take.source, take.retarget, take.motion, cleaned, body)
    except InputError as exc:
        raise InputError(f"{take.path}: {exc}; nothing written") from None
    if as_read:
        _restore_missing(take, values)
    write_amc(take.source.layout, values, out, forbid=forbid, gaps=not as_read,
              drop=dropped_frames(take, cleaned))  # fmt: skip
    notes = _copy_skeleton(take.skeleton_file, out, forbid)
    if any(ch.startswith("t") for ch in take.source.layout.skeleton.root_order):
        return notes
    return notes + _dropped_move(take, cleaned)


def dropped_frames(take: Take, cleaned: Motion) -> np.ndarray | None:
    """(F,) bool, the frames of an AMC take's file that ``cleaned``, written with its holes as
    they came (``npz_holes.keep_holes``: ``add-noise``, ``--fill off``), misses whole (NaN in
    every body value: ``add-noise --drop-frames``): left out of the file, their numbers
    missing, the holes the AMC reader reads (``formats.amc_frames``). None: none, or a motion
    not one row per file frame. InputError for a take whose numbers step by more than 1 (one
    frame in k of a capture), where a missing number is no hole."""
    from mdvae_cli.formats.amc_frames import even_step
    from mdvae_cli.formats.npz_holes import AS_READ, HOLES, NUM_JOINTS

    as_read, layout = cleaned.layout.get(AS_READ), take.source.layout
    if cleaned.layout.get(HOLES) != "as read" or not as_read:
        return None
    if as_read["frames"] != len(layout.rows) or cleaned.num_frames != len(layout.rows):
        return None
    rows, cols, values = (np.asarray(a) for a in as_read["poses"])
    body = (cols < 3 * NUM_JOINTS) & ~np.isfinite(values.astype(float))
    nan = np.zeros((cleaned.num_frames, 3 * NUM_JOINTS), bool)
    nan[rows[body].astype(int), cols[body].astype(int)] = True
    whole = nan.all(axis=1)
    if not whole.any():
        return None
    whole_frames = [int(n) for n, cut in zip(layout.frames, _added(layout), strict=True) if not cut]
    if even_step(sorted(whole_frames)) > 1:
        raise InputError(f"{take.path}: its frame numbers step by more than 1 (one frame in k "
                         "of a capture), so a missing number is no hole; write .npz")  # fmt: skip
    drop = np.zeros(len(layout.frames), bool)
    drop[layout.rows[whole]] = True
    return drop


def _added(layout) -> np.ndarray:
    """(F,) bool, the frames an AMC layout added for missing numbers."""
    return np.zeros(len(layout.frames), bool) if layout.added is None else layout.added


def _copy_skeleton(asf: Path | None, out: Path, forbid: tuple) -> list[str]:
    """Copy a take's ``.asf`` next to its output ``out`` when none of its name is there; a
    note when another skeleton of that name is (left as it is). -> notes"""
    if asf is None:
        return []
    copy = out.parent / asf.name
    if not copy.exists():
        write_atomic(copy, lambda tmp: shutil.copyfile(asf, tmp), forbid=forbid)
        return []
    if copy.is_file() and copy.read_bytes() == asf.read_bytes():
        return []
    return [f"{copy} is not the take's skeleton {asf}: left as it is; read {out.name} with "
            f"--asf {asf}"]  # fmt: skip


#: a move of the root (m) under which no note is given when the file cannot carry it
_MOVE_NOTED = 1e-3


def _dropped_move(take: Take, cleaned: Motion) -> list[str]:
    """The note for a take whose root has no position channels, when the cleaning moved the
    pelvis (more than :data:`_MOVE_NOTED`): the move is not written."""
    moved = np.linalg.norm(np.asarray(cleaned.trans) - np.asarray(take.motion.trans), axis=-1)
    most = float(np.nanmax(moved, initial=0.0))
    if not most > _MOVE_NOTED:
        return []
    return [f"the file's root has no position channels: the cleaned motion's move of the hips "
            f"(up to {most * 100:.1f} cm) is not written, the take stays where the file "
            "puts it"]  # fmt: skip


def find_asf(path: Path) -> Path | None:
    """The skeleton next to an AMC file: ``<subject>.asf`` (CMU naming), else the folder's only
    ``.asf`` (``.asf.gz`` too); None when there is none or several."""
    path = Path(path)
    ids = cmu.trial_of(path)
    if ids is not None:
        for name in (f"{ids[0]}.asf", f"{ids[0]}.asf.gz"):
            if (path.parent / name).is_file():
                return path.parent / name
    found = asf_beside(path)
    return found[0] if len(found) == 1 else None


def asf_beside(path: Path) -> list[Path]:
    """The ``.asf`` (``.asf.gz``) files in the folder of ``path``, sorted by name."""
    return [
        p for p in sorted(Path(path).parent.iterdir())
        if p.is_file() and p.name.lower().removesuffix(".gz").endswith(".asf")
    ]  # fmt: skip


class TakeReader:
    """Reads takes for a command: the body's joints once, each ASF once, the body shape once
    per skeleton.

    body: the body model (None: the built-in one). asf: the skeleton of every AMC take (None:
    each one's found next to it). joint_map: SMPL joint -> source joint names. ahead: a
    ``run.read_ahead.ReadAhead`` that may already be reading a take's file (its
    :func:`load_source` call), or None.
    """

    def __init__(self, body: BodyModelData | None = None, asf: Path | None = None,
                 joint_map: dict[str, str] | None = None, ahead=None):  # fmt: skip
        self.body_data, self.asf, self.joint_map = body, asf, joint_map
        self.ahead = ahead
        self._body: BodyJoints | None = None
        self.skeletons: dict[Path, AsfSkeleton] = {}
        self.betas: dict[str, np.ndarray] = {}

    @property
    def body(self) -> BodyJoints:
        """The body's joints (built on first use)."""
        if self._body is None:
            from mdvae_cli.body.builtin import builtin_body_model

            data = self.body_data if self.body_data is not None else builtin_body_model()
            self._body = BodyJoints(data)
        return self._body

    def skeleton(
        self, path: Path, given: Path | None = None
    ) -> tuple[AsfSkeleton | None, Path | None]:
        """The parsed skeleton of a take (None for BVH) and its ``.asf`` file (``given``, the
        reader's, or the one found next to it; None for a BVH take)."""
        if not path.name.lower().removesuffix(".gz").endswith(".amc"):
            return None, None
        found = given or self.asf or find_asf(path)
        if found is None:
            beside = [p.name for p in asf_beside(path)]
            names = ", ".join(beside[:3]) + (", ..." if len(beside) > 3 else "")
            what = (f"{len(beside)} .asf skeletons next to it ({names}), none named for it"
                    if beside else "no .asf skeleton found next to it")  # fmt: skip
            raise InputError(f"{path}: {what}; pass --asf FILE")
        if found not in self.skeletons:
            self.skeletons[found] = load_asf(found)
        return self.skeletons[found], Path(found)

    def read(
        self,
        path: Path,
        fps: float | None = None,
        scale: float | None = None,
        rate: float | None = None,
        settings=None,
        metadata: dict | None = None,
        skeleton: Path | None = None,
        progress: Callable[[int, int], None] | None = None,
    ) -> Take:
        """Read one take and retarget it (:func:`read_take`); ``rate``: resample to this rate
        first (None: the take's own), with ``settings`` (``RetargetSettings``); metadata: kept
        with the motion, with the skeleton's key added; skeleton: this take's ``.asf``;
        progress: (frames retargeted, frames) as the retarget goes."""
        path = Path(path)
        skeleton, found = self.skeleton(path, skeleton)
        load = load_source if self.ahead is None else partial(self.ahead.call, load_source)
        src = load(path, skeleton, fps=fps, scale=scale, joint_map=self.joint_map)
        key = skeleton_key(src)
        if key not in self.betas:
            try:
                self.betas[key] = fit_betas(src, self.body)
            except InputError as exc:
                raise InputError(f"{path}: {exc}") from None
        if metadata is not None:
            metadata = {**metadata, "skeleton_key": key}
        take = read_take(path, self.body, betas=self.betas[key], source=src, rate=rate,
                         settings=settings, metadata=metadata, progress=progress)  # fmt: skip
        take.skeleton_file = found
        return take
