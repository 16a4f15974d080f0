"""``mdvae export-mesh``: write one posed body mesh per frame."""

from __future__ import annotations

from pathlib import Path

import click

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.cli.batch import FileJob, emit_json, json_option, plan_jobs, print_notes, run_batch
from mdvae_cli.cli.common import (
    OutputPath,
    allow_pickle_option,
    body_model_option,
    console,
    handle_errors,
)
from mdvae_cli.cli.motion_input import INPUT_SUFFIXES
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
@body_model_option
@allow_pickle_option
@json_option
@handle_errors
def export_mesh(inputs, out, fmt, every, body_model, allow_pickle, as_json) -> None:
    """Export the posed body mesh of each frame as .ply or .obj.

    One input file writes into --out itself; several files or a folder write
    --out/<relative path without .npz>/frame_NNNNNN.<format>. Frame files of that
    format that an earlier export left there (a longer take) are removed, so a
    folder holds one sequence; other files are never touched.

    \b
    Example:
      mdvae export-mesh walk.npz --out walk_meshes --format obj --every 2
    """
    from mdvae_cli.export import as_body_model, export_mesh_sequence

    jobs = plan_jobs(inputs, out, INPUT_SUFFIXES, out_suffix=None)
    body = as_body_model(load_body_model(body_model))
    options = ReadOptions(allow_pickle=allow_pickle, body=body.data)
    sources = tuple(job.source for job in jobs)

    def process(job: FileJob) -> dict[str, int]:
        motion = read(job.source, options).single()
        print_notes(job.relpath, motion.notes)
        written = export_mesh_sequence(motion, body, job.output, fmt, every=every, forbid=sources)
        return {"meshes": len(written)}

    report = run_batch(jobs, process, "export-mesh")
    if as_json:
        emit_json(report.to_dict())
    elif report.succeeded:
        meshes = sum(o.result["meshes"] for o in report.succeeded)
        where = jobs[0].output if len(jobs) == 1 else out
        console.print(f"wrote {meshes} {fmt} meshes to {where}")
    report.exit()


COMMANDS = [export_mesh]
