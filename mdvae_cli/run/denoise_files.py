"""``mdvae denoise`` on files, end to end, as a Python user can call it: read each file (every
person track), denoise the files with one :class:`DenoiseSettings` per input kind, write each
output in its form (npz, or a take on its own skeleton), with meshes and a before/after page
when asked. Nothing is printed: notes and results come back in :class:`FileRun`.

    runs = [read_file(Path("take.bvh"), Path("clean.bvh"), ReadOptions(body=body_data))]
    denoise_files(runs, DenoiseSettings(), denoiser, BodyModel(body_data))
    write_file(runs[0], body)
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError
from mdvae_cli.formats.registry import ReadOptions, read
from mdvae_cli.infer.denoise import check_finite, check_length
from mdvae_cli.infer.denoise_settings import DenoiseSettings, denoise, loops_of
from mdvae_cli.infer.noise_blend import BlendReport
from mdvae_cli.infer.settings import RefineConfig
from mdvae_cli.model.denoiser import Denoiser
from mdvae_cli.motion.motion import Motion
from mdvae_cli.run.tracks import on_floor, outputs_of, own_output, reader_notes, track_output

#: the output forms written back as a take on its own skeleton
TAKE_OUTPUTS = (".bvh", ".amc")


@dataclass
class TrackRun:
    """One person track of a file: ``motion`` as read (on the floor with ``floor``), where it
    goes, and once denoised ``cleaned``, whether it ran as a cycle (``loop``), the guard's
    fallback stretches ``[start s, end s]``, the blend's report and the Gaussian (seconds)
    its result was smoothed with (``smoothed_s``; the video row's, as far as it reads noisy)."""

    label: str | None
    motion: Motion
    output: Path
    cleaned: Motion | None = None
    loop: bool = False
    fallbacks: list[list[float]] = field(default_factory=list)
    blend: BlendReport | None = None
    smoothed_s: float = 0.0
    filled: bool = True
    meshes: Path | None = None  # where --mesh-dir wrote its meshes
    page: Path | None = None  # where --view wrote its before/after page

    def to_dict(self) -> dict[str, Any]:
        """What ``--json`` says of the track."""
        motion = self.cleaned if self.cleaned is not None else self.motion
        duration = max((motion.num_frames - 1) / motion.fps, 1e-9)
        fell = sum(b - a for a, b in self.fallbacks) / duration
        kept = self.blend
        return {
            "track": self.label,
            "output": str(self.output),
            "frames": motion.num_frames,
            "fallbacks": self.fallbacks,
            "fallback_share": round(min(fell, 1.0), 4),
            "input_share": None if kept is None else round(kept.input_share, 4),
            "spike_share": None if kept is None else round(kept.spike_share, 4),
            # frames where a joint jumped away and back, filled (the blend's spikes)
            "spike_frames": 0 if kept is None else round(kept.spike_share * motion.num_frames),
            "smoothed_s": round(self.smoothed_s, 4),
            "loop": self.loop,
            **fill_counts(self.motion, self.filled),
            **{k: str(v) for k, v in (("meshes", self.meshes), ("page", self.page)) if v},
        }


@dataclass
class FileRun:
    """One input file of a denoise run.

    format: the file's format name; input_kind: the settings row it is denoised with
    ("mocap" or "video"); take: a BVH/AMC take as read (written back on its own skeleton);
    document: a video pipeline's file as read, when it goes back in its own form (all its
    tracks into one output); notes: ``(track label or None, remark)`` made while reading, in
    order, and ``written``: those made while writing; seconds: the time
    the user waited for it: its reading (:func:`read_file`), its share of the denoising time
    (by frames) and its writing (:func:`write_file`).
    """

    source: Path
    format: str
    input_kind: str
    tracks: list[TrackRun]
    take: Any = None
    document: Any = None
    notes: list[tuple[str | None, str]] = field(default_factory=list)
    written: list[str] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def frames(self) -> int:
        return sum((t.motion if t.cleaned is None else t.cleaned).num_frames for t in self.tracks)

    def to_dict(self) -> dict[str, Any]:
        """What ``--json`` says of the file (``notes``: what reading and writing it remarked,
        as the console says them)."""
        tracks = [t.to_dict() for t in self.tracks]
        return {
            "frames": sum(t["frames"] for t in tracks),
            "seconds": round(self.seconds, 4),
            "format": self.format,
            "input_kind": self.input_kind,
            "fallbacks": [f for t in tracks for f in t["fallbacks"]],
            "fallback_share": frame_mean(tracks, "fallback_share"),
            "input_share": frame_mean(tracks, "input_share"),
            "loop": any(t["loop"] for t in tracks),
            **fill_totals(tracks),
            "tracks": tracks,
            "notes": [n if lab is None else f"track {lab}: {n}" for lab, n in self.notes]
            + self.written,
        }


def fill_counts(source: Motion, fill: bool) -> dict:
    """What the fill did to one motion: {"filled_frames": frames with a joint filled,
    "filled_joints": (frame, joint) entries filled}, both 0 with the fill off, and
    "unfilled_frames": the frames left with holes (fill off), else 0."""
    from mdvae_cli.motion.holes import hole_count, observed

    frames, entries = hole_count(observed(source)) if source.joint_mask is not None else (0, 0)
    if fill:
        return {"filled_frames": frames, "filled_joints": entries, "unfilled_frames": 0}
    return {"filled_frames": 0, "filled_joints": 0, "unfilled_frames": frames}


def fill_totals(items: Sequence[dict]) -> dict:
    """:func:`fill_counts` and the filled spikes (``spike_frames``) summed over tracks or
    files."""
    keys = ("filled_frames", "filled_joints", "unfilled_frames", "spike_frames")
    return {k: sum(int(t.get(k) or 0) for t in items) for k in keys}


def frame_mean(items: Sequence[dict], key: str) -> float | None:
    """The frame-weighted mean of ``key`` over tracks or files (None where none has it)."""
    have = [(t[key], t["frames"]) for t in items if t.get(key) is not None]
    if not have:
        return None
    return round(sum(v * n for v, n in have) / max(sum(n for _, n in have), 1), 4)


def read_file(
    source: Path,
    output: Path,
    options: ReadOptions,
    *,
    takes=None,
    floor: bool = False,
    input_kind: str = "auto",
) -> FileRun:
    """Read ``source`` for denoising into ``output`` (each track to its own output).

    takes: a ``retarget.take.TakeReader`` shared over the run's files; floor: put each track
    on the floor first (``options.body`` is the body, None the built-in one); input_kind:
    "auto" takes the file's own kind. A track too short to denoise is skipped with a note in
    a file of several; InputError when none is left. ``options.progress``: (frames
    retargeted, frames) while a take is read.
    """
    start = time.perf_counter()
    loaded = read(source, options, takes=takes)
    notes: list[tuple[str | None, str]] = [(None, n) for n in loaded.notes]
    output, own, why = own_output(loaded, output)
    if why is not None:
        notes.append((None, why))
    tracks, short = [], []
    for label, motion, out in outputs_of(loaded, output):
        notes += [(label, n) for n in reader_notes(motion.notes, own)]
        if floor:
            motion = on_floor(motion, _body_data(options))
            notes.append((label, motion.notes[-1]))
        try:
            check_length(motion)
        except InputError as exc:
            if len(loaded.tracks) == 1:
                raise
            short.append(f"track {label}: {exc}")
            continue
        tracks.append(TrackRun(label, motion, out))
    if not tracks:
        raise InputError(f"every track is too short to denoise ({'; '.join(short)})")
    notes += [(None, f"{s}; skipped") for s in short]
    kind = loaded.kind if input_kind == "auto" else input_kind
    run = FileRun(source, loaded.format, kind, tracks, take=loaded.take,
                  document=loaded.document if own else None, notes=notes)  # fmt: skip
    run.seconds = time.perf_counter() - start  # the time the user waited, reading included
    return run


def _body_data(options: ReadOptions):
    if options.body is not None:
        return options.body
    from mdvae_cli.body.formats import load_body_model

    return load_body_model(None)


def settings_for(base: DenoiseSettings, kind: str) -> DenoiseSettings:
    """``base`` for files of one input kind ("mocap" or "video")."""
    return replace(base, input_kind=kind)


def kind_rows(
    runs: Sequence[FileRun], base: DenoiseSettings
) -> dict[str, tuple[RefineConfig | None, dict]]:
    """Each input kind among ``runs`` (sorted) with its refinement settings and settings row."""
    return {k: settings_for(base, k).refine_row() for k in sorted({r.input_kind for r in runs})}


def mark_loops(runs: Sequence[FileRun], base: DenoiseSettings) -> None:
    """Set each track's ``loop``: the setting, or whether its ends meet."""
    tracks = [track for run in runs for track in run.tracks]
    for track, loop in zip(tracks, loops_of([t.motion for t in tracks], base), strict=True):
        track.loop = loop


def denoise_files(
    runs: Sequence[FileRun],
    base: DenoiseSettings,
    denoiser: Denoiser,
    body: BodyModel,
    *,
    per_file: bool = False,
    progress: Callable[[dict], None] | None = None,
) -> None:
    """Denoise every track of ``runs``, the files of each input kind together (one file at a
    time with ``per_file`` in optimisation mode), filling each track's ``cleaned``,
    ``fallbacks`` and ``blend`` and each file's ``seconds``. ``progress``: see
    ``infer.denoise.denoise_motions``."""
    mark_loops(runs, base)
    for kind in kind_rows(runs, base):
        of_kind = [r for r in runs if r.input_kind == kind]
        alone = per_file and base.optimize_steps
        for group in [[r] for r in of_kind] if alone else [of_kind]:
            _denoise_group(group, settings_for(base, kind), denoiser, body, progress)


def _denoise_group(group, settings, denoiser, body, progress) -> None:
    tracks = [(run, t) for run in group for t in run.tracks]
    motions = [t.motion for _, t in tracks]

    def fell_back(k: int, a: float, b: float) -> None:
        tracks[k][1].fallbacks.append([round(a, 3), round(b, 3)])

    def blended(k: int, report: BlendReport) -> None:
        tracks[k][1].blend = report

    def smoothed(k: int, seconds: float) -> None:
        tracks[k][1].smoothed_s = seconds

    start = time.perf_counter()
    loops = None if settings.loop is None else [settings.loop] * len(motions)
    cleaned = denoise(motions, settings, denoiser, body, progress=progress, loops=loops,
                      on_blend=blended, on_fallback=fell_back, on_smooth=smoothed)  # fmt: skip
    seconds = time.perf_counter() - start
    frames = max(sum(m.num_frames for m in motions), 1)
    for (run, track), motion in zip(tracks, cleaned, strict=True):
        track.cleaned, track.filled = motion, settings.fill != "off"
        run.seconds += seconds * track.motion.num_frames / frames


def write_file(
    run: FileRun,
    body: BodyModel,
    *,
    forbid: Sequence[Path] = (),
    mesh_dir: Path | None = None,
    mesh_format: str = "ply",
    page: Path | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> FileRun:
    """Write each denoised track of ``run`` to its output (never onto a file in ``forbid``):
    an ``.npz``, a ``.bvh``/``.amc`` output of a take on the take's own skeleton, or a video
    pipeline's file in its own form, all its tracks into one (notes in ``run.written``). With
    ``mesh_dir``, the track's meshes first (a track whose meshes fail gets no output either);
    with ``page``, a before/after page there (``<stem>.track<ID>.html`` per track).
    InputError for a result that is not finite. ``progress``: (frames carried back, frames)
    while a BVH take is written back. The time it takes is added to ``run.seconds``."""
    from mdvae_cli.formats.loaded import LoadedFile
    from mdvae_cli.formats.registry import write

    start = time.perf_counter()
    together = []  # (label, motion) of a file going back in its own form
    for track in run.tracks:
        motion = track.cleaned
        if motion is None:
            raise InputError(f"{run.source}: not denoised yet")
        check_finite(motion)
        if mesh_dir is not None:
            from mdvae_cli.export import export_mesh_sequence

            target = track_output(Path(mesh_dir), track.label)
            export_mesh_sequence(motion, body, target, mesh_format, forbid=forbid)
            track.meshes = target
        if not track.filled:  # an npz gets its NaN back, a take its own frames
            from mdvae_cli.formats.npz_holes import keep_holes

            motion = keep_holes(motion)
        is_take = track.output.name.lower().removesuffix(".gz").endswith(TAKE_OUTPUTS)
        take = run.take if is_take else None
        if run.document is not None:
            together.append((track.label, motion))
        else:
            run.written += write(motion, track.output, take=take, forbid=forbid,
                                 progress=progress)  # fmt: skip
        if page is not None:
            from mdvae_cli.view.page import write_before_after

            where = track_output(Path(page), track.label)
            write_before_after(track.motion, motion, run.source, track.output, where, body,
                               forbid=forbid)  # fmt: skip
            track.page = where
    if together:
        cleaned = LoadedFile(run.source, run.format, run.input_kind, together,
                             document=run.document)  # fmt: skip
        run.written = write(cleaned, run.tracks[0].output, forbid=forbid)
    run.seconds += time.perf_counter() - start  # writing included
    return run
