"""``mdvae export-mesh``: write one posed body mesh per frame."""

from __future__ import annotations

from pathlib import Path

import click
from rich.markup import escape

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.cli.batch import FileJob, emit_json, json_option, plan_jobs, print_notes, run_batch
from mdvae_cli.cli.common import (
    OutputPath,
    allow_pickle_option,
    body_model_option,
    console,
    handle_errors,
)
from mdvae_cli.cli.motion_input import INPUT_SUFFIXES, input_fps_option, one_track, track_option
from mdvae_cli.cli.takes import take_options, take_reading
from mdvae_cli.formats.registry import ReadOptions, read


@click.command("export-mesh")
@click.argument("inputs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "-o", "--out", type=OutputPath(path_type=Path), required=True,
    help="Output folder: frame_000000.<format>, ... (one sub-folder per file for several inputs).",
)  # fmt: skip
@click.option(
    "--format", "fmt", type=click.Choice(["ply", "obj"]), default="ply", show_default=True,
    help="Mesh file format.",
)  # fmt: skip
@click.option(
    "--every", type=click.IntRange(min=1), default=1, show_default=True,
    help="Write every N-th frame (files keep the source frame number).",
)  # fmt: skip
@click.option(
    "--frames", "span", default=None, metavar="START:STOP",
    help="Only these frames: 0-based, STOP not included (120:240, 120: or :240); files keep "
    "the source frame number.",
)  # fmt: skip
@take_options
@input_fps_option
@track_option("export this track (its id in the file)")
@body_model_option
@allow_pickle_option
@json_option
@handle_errors
def export_mesh(
    inputs, out, fmt, every, span, asf, joint_map_file, input_fps, track, body_model,
    allow_pickle, as_json,
) -> None:  # fmt: skip
    """Export the posed body mesh of each frame as .ply or .obj, in the motion's own world:
    metres, Z up (as AMASS; set the importer's up axis to Z).

    One input file writes into --out itself; several files or a folder write
    --out/<relative path without .npz>/frame_NNNNNN.<format>. Frame files of that
    format that an earlier export left there (a longer take) are removed, so a
    folder holds one sequence; other files are never touched.

    \b
    Examples:
      mdvae export-mesh walk.npz --out walk_meshes --format obj --every 2
      mdvae export-mesh take.npz --out shot_meshes --frames 120:240
    """
    from mdvae_cli.export import as_body_model, export_mesh_sequence, frame_span

    span = (0, None) if span is None else frame_span(span)  # refused before anything is read

    jobs = plan_jobs(inputs, out, INPUT_SUFFIXES, out_suffix=None)
    body = as_body_model(load_body_model(body_model))
    options = ReadOptions(allow_pickle=allow_pickle, body=body.data, fps=input_fps,
                          **take_reading(asf, joint_map_file))  # fmt: skip
    sources = tuple(job.source for job in jobs)

    def process(job: FileJob) -> dict[str, int]:
        motion = one_track(read(job.source, options), track)
        print_notes(job.relpath, motion.notes)
        written = export_mesh_sequence(motion, body, job.output, fmt, every=every, forbid=sources,
                                       span=span)  # fmt: skip
        return {"meshes": len(written)}

    report = run_batch(jobs, process, "export-mesh")
    if as_json:
        emit_json(report.to_dict())
    elif report.succeeded:
        meshes = sum(o.result["meshes"] for o in report.succeeded)
        where = jobs[0].output if len(jobs) == 1 else out
        console.print(f"wrote {meshes} {fmt} meshes to {escape(str(where))}")
    report.exit()


COMMANDS = [export_mesh]
