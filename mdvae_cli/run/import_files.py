"""``mdvae import``'s work on one file, as a Python user can call it: a mocap take retargeted
onto the body (or a video pipeline's output read upright) and written as an AMASS-style .npz,
with a row of what came of it. (Apart from the command, so that loading the CLI does not load
torch: the retargeting solves need it, the rest of the CLI does not.)"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.errors import InputError
from mdvae_cli.formats.registry import TAKE_SUFFIXES, ReadOptions, read, suffix_of, write
from mdvae_cli.motion import cmu
from mdvae_cli.motion.corpus_plan import CorpusItem
from mdvae_cli.retarget.fit_shape import skeleton_key
from mdvae_cli.retarget.retarget import walking_speed
from mdvae_cli.retarget.take import TakeReader
from mdvae_cli.run.jobs import FileJob


class FileImporter:
    """Imports one file; keeps the body, parsed skeletons and betas fitted once per skeleton.
    Built once per process (each ``--jobs`` worker builds its own). ``on_notes(relpath,
    notes)``: what reading a file remarked (a padded shape, an assumed rate), if wanted."""

    def __init__(self, body_model, out: Path, fps, settings, source_fps, scale, asf,
                 input_format=None, track=None, joint_map=None, estimate_fps=None,
                 estimate_floor=None, missing=(), on_notes=None):  # fmt: skip
        self.takes = TakeReader(load_body_model(body_model), asf, joint_map)
        self.body = self.takes.body
        self.format, self.track = input_format, track
        self.out, self.fps, self.settings = out, fps, settings
        self.source_fps, self.scale = source_fps, scale
        # files that need no retarget (video estimates): their own frames and heights unless
        # --fps / --floor are given
        self.estimate_fps, self.estimate_floor = estimate_fps, estimate_floor
        self.on_notes = on_notes
        self.missing = missing  # --missing: holes of takes, marked in joint_mask

    def __call__(self, job: FileJob) -> dict:
        """Import one file -> its row. Small batched solves: one torch thread is fastest; the
        caller's thread count is as it was after."""
        before = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            return self._import(job)
        finally:
            torch.set_num_threads(before)

    def _import(self, job: FileJob) -> dict:
        item: CorpusItem | None = job.data
        is_take = suffix_of(job.source) in TAKE_SUFFIXES
        if item is None and not is_take:
            return self.import_estimates(job)
        meta: dict = {"file": job.relpath.as_posix()}
        if item is not None:
            donor = f"{cmu.DONOR_SUBJECT}.asf" if item.donor else None
            meta.update(subject=item.subject, trial=item.trial, split=item.split,
                        description=item.description, donor_skeleton=donor)  # fmt: skip
        options = ReadOptions(
            fps=item.fps if item else self.source_fps, body=self.body.data, scale=self.scale,
            skeleton=item.skeleton if item else None, resample=self.fps,
            retarget=self.settings, metadata=meta, missing=self.missing,
        )  # fmt: skip
        from mdvae_cli.motion.holes import hole_count, observed

        loaded = read(job.source, options, takes=self.takes)
        take, motion = loaded.take, loaded.single()  # with --missing: its holes marked
        if self.on_notes is not None:  # what reading the take remarked (a rest pose, sides)
            self.on_notes(job.relpath, list(dict.fromkeys([*loaded.notes, *motion.notes])))
        src, result = take.source, take.retarget
        key = skeleton_key(src)
        arrays = (motion.root_orient, motion.pose_body, motion.trans, motion.betas)
        if not all(np.isfinite(a).all() for a in arrays) or not np.isfinite(result.mean_error):
            hint = f" (is --scale {self.scale:g} metres per file unit right?)" if self.scale else ""
            raise InputError(
                f"{job.source}: the retarget to the body gave non-finite values{hint}; "
                "nothing written"
            )
        write(motion, job.output, forbid=(job.source,))
        out = job.output  # relative to the output folder, or the output file's own path
        out = out.relative_to(self.out) if out != self.out and out.is_relative_to(self.out) else out
        row = {
            "output": out.as_posix(),
            "format": item.kind if item else src.info["format"],
            "frames": motion.num_frames,
            "fps": motion.fps,
            "source_fps": src.fps,
            "retarget_error_mm": round(1000 * result.mean_error, 2),
            "retarget_error_direct_mm": round(1000 * result.direct_error, 2),
            "sole_height_mean_cm": round(100 * float(result.sole_height.mean()), 2),
            "floor_tilt_deg": round(result.floor_tilt_deg, 2),
            "speed_mps": round(walking_speed(motion.trans, motion.fps), 3),
            "skeleton_key": key,
            "missing_frames": hole_count(observed(motion))[0],  # --missing
        }
        if item is not None:
            row.update({k: meta[k] for k in ("subject", "trial", "split", "description")},
                       donor_skeleton=item.donor)  # fmt: skip
        return row

    def import_estimates(self, job: FileJob) -> dict:
        """A motion file that needs no retarget (a video pipeline's output, an AMASS-style
        file): read upright (``formats.registry``), one output per track, at the file's own
        frames and heights (as ``mdvae denoise`` reads it) unless ``--fps`` (resampled) or
        ``--floor plane|flat`` (the ground under the soles at z = 0) is given."""
        from mdvae_cli.motion.resample import resample_motion
        from mdvae_cli.run.tracks import on_floor, outputs_of

        options = ReadOptions(format=self.format, fps=self.source_fps, track=self.track,
                              body=self.body.data, missing=self.missing)  # fmt: skip
        loaded = read(job.source, options)
        if self.on_notes is not None:
            self.on_notes(job.relpath, loaded.notes)
            for label, motion in loaded.tracks:
                where = (
                    job.relpath
                    if label is None
                    else Path(f"{job.relpath.as_posix()} track {label}")
                )
                self.on_notes(where, motion.notes)
        frames, fps, outputs = 0, None, []
        for _, motion, output in outputs_of(loaded, job.output):
            source_fps = motion.fps
            if self.estimate_fps:
                motion = resample_motion(motion, self.estimate_fps)
            if self.estimate_floor in ("plane", "flat"):
                motion = on_floor(motion, self.body.data, self.settings.max_tilt)
            written = write(motion, output, forbid=(job.source,))
            if self.on_notes is not None:
                self.on_notes(job.relpath, written)  # what was left out (a GVHMR npz's internals)
            frames, fps = frames + motion.num_frames, motion.fps
            outputs.append(output.as_posix())
        return {
            "output": outputs[0] if len(outputs) == 1 else outputs,
            "format": loaded.format,
            "frames": frames,
            "fps": fps,
            "source_fps": source_fps,
            "retarget_error_mm": 0.0,
            "retarget_error_direct_mm": 0.0,
            "tracks": len(outputs),
        }
