"""``mdvae export-bvh``: an SMPL/AMASS .npz as a BVH file on the SMPL skeleton of its shape."""

from __future__ import annotations

from pathlib import Path

import click
from rich.markup import escape

from mdvae_cli.cli.batch import FileJob, emit_json, json_option, plan_jobs, print_notes, run_batch
from mdvae_cli.cli.common import (
    OutputPath,
    allow_pickle_option,
    body_model_option,
    console,
    handle_errors,
)
from mdvae_cli.cli.motion_input import input_fps_option, one_track, track_option
from mdvae_cli.cli.takes import take_options, take_reading


@click.command("export-bvh")
@click.argument("inputs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "-o", "--out", type=OutputPath(), required=True,
    help="Output .bvh (or .bvh.gz) for one input file, or a folder (inputs mirrored below it).",
)  # fmt: skip
@click.option(
    "--units", type=click.Choice(["cm", "m", "mm", "in"]), default="cm", show_default=True,
    help="Length unit of the file. MotionBuilder and Maya read BVH in cm; Blender reads one "
    "unit as one metre (import with Scale 0.01, or write --units m).",
)  # fmt: skip
@click.option(
    "--order", type=click.Choice(["ZXY", "XYZ", "ZYX", "YXZ", "YZX", "XZY"]), default="ZXY",
    show_default=True, help="Rotation channel order of every joint.",
)  # fmt: skip
@take_options
@input_fps_option
@track_option("export this track (its id in the file)")
@body_model_option
@allow_pickle_option
@json_option
@handle_errors
def export_bvh(
    inputs, out, units, order, asf, joint_map_file, input_fps, track, body_model, allow_pickle,
    as_json,
) -> None:  # fmt: skip
    """Write AMASS/SMPL .npz motions as BVH on the SMPL skeleton of their own body shape.

    The 22 body joints keep SMPL's names (pelvis, left_hip, ..., right_wrist) and their rest
    offsets from the body model and the file's betas, with End Sites at the hands, toes and
    head top. The file is Y up with the body facing +Z, as Blender's and MotionBuilder's BVH
    importers expect by default, at the motion's own frame rate. `mdvae import` reads it back
    to the same motion (within a millimetre).

    \b
    Examples:
      mdvae export-bvh walk.npz -o walk.bvh
      mdvae export-bvh walk.npz -o walk.bvh --units m      (Blender at Scale 1)
      mdvae export-bvh cleaned/ -o bvh/
    """
    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.cli.motion_input import INPUT_SUFFIXES
    from mdvae_cli.formats.registry import ReadOptions, read, write

    single = Path(str(out))
    if single.name.lower().endswith(".bvh.gz") and len(inputs) == 1 and Path(inputs[0]).is_file():
        jobs = [FileJob(Path(Path(inputs[0]).name), Path(inputs[0]), single)]
    else:
        jobs = plan_jobs(inputs, out, INPUT_SUFFIXES, out_suffix=".bvh",
                         rename=lambda rel: rel.with_suffix("").with_suffix(".bvh")
                         if rel.suffix.lower() == ".gz" else rel.with_suffix(".bvh"))  # fmt: skip
    body = load_body_model(body_model)
    options = ReadOptions(allow_pickle=allow_pickle, body=body, fps=input_fps,
                          **take_reading(asf, joint_map_file))  # fmt: skip
    sources = tuple(job.source for job in jobs)

    def process(job: FileJob) -> dict:
        motion = one_track(read(job.source, options), track)
        print_notes(job.relpath, motion.notes)
        write(motion, job.output, body=body, forbid=sources, bvh_units=units, bvh_order=order)
        return {"frames": motion.num_frames, "fps": motion.fps}

    report = run_batch(jobs, process, "export-bvh")
    if as_json:
        emit_json(report.to_dict())
    elif report.succeeded:
        where = jobs[0].output if len(jobs) == 1 else out
        console.print(f"wrote {len(report.succeeded)} BVH file(s) to {escape(str(where))}")
    report.exit()


COMMANDS = [export_bvh]
