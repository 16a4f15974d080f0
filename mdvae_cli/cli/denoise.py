"""``mdvae denoise``: regression mode by default, optimisation mode with ``--optimize N``.

A thin layer: options -> ``DenoiseSettings`` -> ``run.denoise_files`` (read, denoise, write)
-> notes, the summary line or ``--json``.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import click

from mdvae_cli.cli.batch import FileJob, emit_json, json_option, print_notes, run_batch, strip_gz
from mdvae_cli.cli.common import (
    allow_pickle_option,
    body_model_option,
    console,
    handle_errors,
    on_command_line,
    process_seconds,
    progress_bar,
)
from mdvae_cli.cli.denoise_options import denoise_options, fill_setting, fill_words
from mdvae_cli.cli.motion_input import motion_input_options
from mdvae_cli.cli.takes import load_joint_map, plan_take_jobs, read_ahead
from mdvae_cli.errors import InputError
from mdvae_cli.fileio import check_named_file

HELP = """Remove noise from motion files with the learned Motion-DVAE prior.

INPUTS are AMASS-style .npz files, BVH takes (.bvh, .bvh.gz), ASF/AMC takes (.amc,
.amc.gz, with their .asf), the output files of video pose pipelines (WHAM, GVHMR, TRAM,
4D-Humans/PHALP, VIBE, PARE, HybrIK, ROMP/BEV, SLAHMR: upright, z up) or folders of them
(any frame rate; any length from 0.17 s, 6 frames at 30 Hz: a shorter take is refused);
.npz outputs keep the
input's keys, frame rate, frame count, hands and extra arrays, with cleaned body pose,
root orientation and translation. A video pipeline's file gets the settings chosen for
video estimates (Student-t noise, see --lam); options override them. Works out of the box
with the shipped weights and the built-in body; pass --body-model for a real
SMPL/SMPL-H/SMPL-X file.

A BVH take comes back as BVH on its own skeleton: same hierarchy, joint names, offsets,
channel order, frame time and frame count; fingers, toes and other joints the body does
not cover keep their motion. (It is retargeted onto the body at its own frame rate,
cleaned there, and each of its joints turns as its body joint did.) An AMC take comes back
as AMC on its .asf the same way: same header, frame numbers, bones and dofs, angle unit
and length unit; a bone with fewer than three rotation dofs (a knee's rx) takes the
closest turn its dofs allow. Its .asf is copied next to the output when none is there.
A video pipeline's file (WHAM, GVHMR, HybrIK, VIBE/PARE, TRAM, 4D-Humans, AIST++, ROMP/BEV,
SLAHMR) comes back as the pipeline wrote it: same container, keys, dtypes and other tracks,
its tracks' parameters cleaned (camera-frame copies follow), what the cleaning left alone
bit for bit; arrays made from the old pose (WHAM's verts) are left out, with a note. -o
x.npz instead writes the cleaned body motion (one output per person track), except for
ROMP and SLAHMR, whose own file is an .npz: mdvae import makes their AMASS-style .npz.

\b
Examples:
  mdvae denoise noisy.npz -o clean.npz
  mdvae denoise take.bvh -o clean.bvh
  mdvae denoise 07_01.amc -o clean/07_01.amc   (its 07.asf next to it, or --asf)
  mdvae denoise takes/ -o clean/            (BVH, AMC and npz, each in its own form)
  mdvae denoise noisy_dir/ -o clean_dir/ --optimize 50
  mdvae denoise noisy.npz -o clean.npz --no-offset
  mdvae denoise noisy.npz -o clean.npz --refine 50 --mirror
  mdvae denoise spiky.npz -o clean.npz --refine 50 --outliers
  mdvae denoise take.npz -o clean.npz --feet off
  mdvae denoise wham_output.pkl -o clean.pkl   (or -o clean.npz: AMASS-style)
  mdvae denoise hmr4d_results.pt -o clean.pt --fps 25 --refine 50
  mdvae denoise take.npz -o clean.npz --mesh-dir meshes/ --mesh-format obj
  mdvae denoise takes/ -o clean/ --view pages/
"""


@click.command("denoise", help=HELP)
@click.argument("inputs", nargs=-1, required=True, type=click.Path(path_type=Path))
@denoise_options
@motion_input_options
@body_model_option
@allow_pickle_option
@json_option
@handle_errors
def denoise(
    inputs, out, denoiser_path, optimize_steps, per_file, lr, seed, refine_steps, refine_lr,
    refine_offset, trans_offset, smooth, offset, outliers, lam, input_kind, mirror, feet, fill,
    missing, floor, guard, blend, loop, mesh_dir, mesh_format, view_dir, window, overlap, asf,
    joint_map_file, input_format, input_fps, track, body_model, allow_pickle, as_json,
) -> None:  # fmt: skip
    started = time.perf_counter()  # where the system cannot tell when the process started
    ahead = read_ahead(inputs, input_fps, joint_map_file, input_format)  # before torch loads
    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.body.skinning import BodyModel
    from mdvae_cli.formats.registry import ReadOptions
    from mdvae_cli.model.denoiser import load_denoiser
    from mdvae_cli.retarget.take import TakeReader
    from mdvae_cli.run.denoise_files import denoise_files, kind_rows, read_file

    settings = _settings(
        refine_steps=refine_steps, refine_lr=refine_lr, offset=offset, lam=lam, outliers=outliers,
        offset_std=refine_offset, trans_offset_std=trans_offset, blend=blend, guard=guard,
        feet=feet, loop=loop, mirror=mirror, optimize_steps=optimize_steps, lr=lr, seed=seed,
        window=window, overlap=overlap, per_file=per_file, fill=fill_setting(fill),
        smooth_s=smooth,
    )  # fmt: skip
    _check_outputs(mesh_dir, mesh_format, view_dir, asf)
    jobs = plan_take_jobs(inputs, out)
    body_data = load_body_model(body_model)
    takes = TakeReader(body_data, asf, load_joint_map(joint_map_file), ahead=ahead)
    options = ReadOptions(format=input_format, fps=input_fps, track=track,
                          allow_pickle=allow_pickle, body=body_data, missing=missing)  # fmt: skip
    runs: dict[Path, object] = {}  # source -> its FileRun

    def read(job: FileJob, tell) -> None:  # tell: the progress inside a long take
        run = read_file(job.source, job.output, replace(options, progress=tell), takes=takes,
                        floor=floor, input_kind=input_kind)  # fmt: skip
        runs[job.source] = run
        if settings.loop:
            run.notes += _not_loops(run)
        for label, note in run.notes:
            where = job.relpath if label is None else f"{job.relpath.as_posix()} track {label}"
            print_notes(Path(where), [note])

    report = run_batch(jobs, read, "reading", quiet=True, within=True)
    good = [o.job for o in report.succeeded]
    _note_unused(asf, joint_map_file, [runs[j.source] for j in good])
    chosen = kind_rows([runs[j.source] for j in good], settings)
    if good:
        _print_kind_notes(chosen)  # on stderr, --json or not: the JSON alone is on stdout
        denoiser, _ = load_denoiser(denoiser_path)
        body = BodyModel(body_data)
        with progress_bar(transient=True) as progress:
            denoise_files([runs[j.source] for j in good], settings, denoiser, body,
                          per_file=per_file, progress=_ticker(progress))  # fmt: skip
        if settings.loop is None:  # --json: "loop", and the note in "notes"
            for job in good:
                if any(t.loop for t in runs[job.source].tracks):
                    print_notes(job.relpath, [LOOP_NOTE])
                    runs[job.source].notes.append((None, LOOP_NOTE))
    write = _writer(runs, jobs, body if good else None, mesh_dir, mesh_format, view_dir)
    write_report = run_batch(good, write, "denoise", quiet=True, within=True)
    write_report.outcomes = report.failed + write_report.outcomes
    if len(jobs) > 1:
        write_report.print_summary("denoise")
    waited = process_seconds(started)  # what the user waited, start-up included
    if as_json:
        emit_json({**write_report.to_dict(), **_json_head(settings, chosen), "seconds": waited})
    elif write_report.succeeded:
        _print_summary([o.result for o in write_report.succeeded], waited)
    write_report.exit()


def _settings(outliers: bool, lr, per_file: bool, blend, **fields):
    """The command's options as a ``DenoiseSettings``; InputError for options that need
    another or contradict one."""
    from mdvae_cli.infer.denoise_settings import DenoiseSettings
    from mdvae_cli.infer.settings import OUTLIER_DOF

    lam = fields.pop("lam")
    if outliers and lam is not None and lam != OUTLIER_DOF:
        raise InputError(f"--outliers is --lam {OUTLIER_DOF:g}; give one of them")
    lam = OUTLIER_DOF if outliers else lam
    if lam and not (fields["refine_steps"] or fields["offset"]):
        raise InputError("--outliers / --lam weigh frames in the offset or --refine; "
                         "drop --no-offset or add --refine N")  # fmt: skip
    if not fields["optimize_steps"] and (per_file or lr is not None):
        raise InputError(f"{'--per-file' if per_file else '--lr'} only applies with --optimize N")
    if fields["overlap"] >= fields["window"]:
        raise InputError(
            f"--overlap ({fields['overlap']}) must be smaller than --window ({fields['window']})"
        )
    _check_pairs(fields, blend)
    blend = not outliers if blend is None else blend  # --outliers weighs spikes itself
    return DenoiseSettings(lam=lam, lr=3e-4 if lr is None else lr, blend=blend, **fields)


def _check_pairs(fields: dict, blend) -> None:
    """InputError for an option that would do nothing beside the others given (refused, not
    silently ignored): the offset's and the blend's options in the paper's plain mode
    (--no-offset), --no-offset or --trans-offset with --refine (which fits both itself),
    --refine-lr without --refine, --seed without --optimize."""
    refine = fields["refine_steps"]
    if refine and not fields["offset"]:
        raise InputError("--refine already fits the offset; drop --no-offset "
                         "(--refine-offset 0 for no rotation offset)")  # fmt: skip
    if not (refine or fields["offset"]):
        for name, on in (("--blend", blend), ("--guard", fields["guard"]),
                         ("--refine-offset", fields["offset_std"] is not None),
                         ("--trans-offset", fields["trans_offset_std"] is not None),
                         ("--smooth", fields["smooth_s"] is not None)):  # fmt: skip
            if on:
                raise InputError(f"{name} goes with the offset or --refine; drop --no-offset "
                                 f"(the paper's plain regression mode) or {name}")  # fmt: skip
    if refine and fields["trans_offset_std"] is not None:
        raise InputError("--trans-offset is the offset's alone: --refine fits the translation "
                         "itself; drop one of them")  # fmt: skip
    needs = (("--refine-lr", "refine_lr", refine, "--refine N"),
             ("--seed", "seed", fields["optimize_steps"], "--optimize N"))  # fmt: skip
    for option, param, needed, flag in needs:
        if not needed and on_command_line(param):
            raise InputError(f"{option} only applies with {flag}")


def _check_outputs(mesh_dir, mesh_format, view_dir, asf) -> None:
    """InputError for --mesh-format without --mesh-dir, a file where a folder is wanted, or
    a missing --asf: before anything is read."""
    if mesh_format is not None and mesh_dir is None:
        raise InputError("--mesh-format only applies with --mesh-dir DIR")
    if mesh_dir is not None and Path(mesh_dir).exists() and not Path(mesh_dir).is_dir():
        raise InputError(f"--mesh-dir {mesh_dir} is a file; give a folder")
    if view_dir is not None and Path(view_dir).exists() and not Path(view_dir).is_dir():
        raise InputError(f"--view {view_dir} is a file; give a folder")
    if asf is not None:
        check_named_file(Path(asf), "skeleton")


def _note_unused(asf, joint_map_file, runs: list) -> None:
    """A note for --asf or --joint-map when none of the inputs read (``runs``) is a take it
    applies to (as --missing says of each file it does not apply to)."""
    for option, given, applies, what in (
        ("--asf", asf, any(r.format == "amc" for r in runs), "AMC takes"),
        ("--joint-map", joint_map_file, any(r.take is not None for r in runs), "BVH/AMC takes"),
    ):
        if runs and given is not None and not applies:
            console.print(f"[dim]note: {option} applies to {what}, and no input is one; "
                          "ignored[/]", soft_wrap=True)  # fmt: skip


def _print_kind_notes(chosen: dict) -> None:
    """The settings row of every input kind but mocap."""
    for kind, (_, c) in chosen.items():
        if kind != "mocap":
            smooth = (f", smoothed over up to {c['smooth_s']:g} s as far as it reads noisy"
                      if c.get("smooth_s") else "")  # fmt: skip
            console.print(f"[dim]note: {kind} input: λ = {c['lam']:g}, offset scales "
                          f"{c['offset_std']:g} rad / {c['trans_offset_std']:g} m"
                          f"{smooth}[/]")  # fmt: skip


def _ticker(progress):
    """A ``progress`` callback for ``denoise_files``: one bar per stage, shown once it runs."""
    tasks = {
        stage: progress.add_task(label, total=1, visible=False, info="")
        for stage, label in (
            ("optimize", "optimising"),
            ("refine", "refining"),
            ("denoise", "denoising"),
        )
    }

    def tick(info: dict) -> None:  # "denoise": a phase of the whole (a long take's progress)
        words = f"loss {info['loss']:.2f}" if "loss" in info else info["phase"]
        progress.update(tasks[info["stage"]], visible=True, completed=info["step"],
                        total=info["steps"], info=words)  # fmt: skip

    return tick


def _writer(runs: dict, jobs: list[FileJob], body, mesh_dir, mesh_format, view_dir):
    """The per-file step of writing: ``write_file`` with the file's mesh folder and page."""
    from mdvae_cli.run.denoise_files import write_file

    sources = tuple(job.source for job in jobs)

    def write(job: FileJob, tell):  # tell: the progress inside a long take's way back
        stem = strip_gz(job.relpath).with_suffix("")  # as export-mesh names it
        meshes = None
        if mesh_dir is not None:
            meshes = Path(mesh_dir) / stem if len(jobs) > 1 else Path(mesh_dir)
        page = None if view_dir is None else Path(view_dir) / stem.with_suffix(".html")
        run = write_file(runs[job.source], body, forbid=sources, mesh_dir=meshes,
                         mesh_format=mesh_format or "ply", page=page,
                         progress=tell)  # fmt: skip
        for track in run.tracks:  # --json has them under "fallbacks" and "notes" too
            print_notes(job.relpath, [n for n in track.cleaned.notes if n.startswith("guard:")])
        print_notes(job.relpath, run.written)
        return run

    return write


def _json_head(settings, chosen: dict) -> dict:
    """What ``--json`` says of the run besides its files."""
    first = next(iter(chosen.values()), (None, None))[0]
    return {
        "mode": settings.mode,
        "optimize_steps": settings.optimize_steps,
        "refine_steps": settings.refine_steps,
        "refine": first.to_dict() if first else None,
        "settings": {kind: row for kind, (_, row) in chosen.items()},
        "mirror": settings.mirror,
        "feet": settings.feet,
        "fill": settings.fill,
        # the guard and the blend go with the offset or refinement (--no-offset: the paper's mode)
        "guard": settings.guard and any(r is not None for r, _ in chosen.values()),
        "blend": settings.blend and any(r is not None for r, _ in chosen.values()),
    }


def _print_summary(done: list, secs: float) -> None:
    """``denoised N file(s), F frames in S s (R frames/s)`` (S: the command's seconds, its
    start-up included; each file's own are in --json) and what the blend and guard did."""
    from mdvae_cli.run.denoise_files import frame_mean

    rows = [run.to_dict() for run in done]
    total = sum(r["frames"] for r in rows)
    words = ""
    kept = frame_mean(rows, "input_share")
    if kept is not None:
        words += f"; kept as it came where its noise explains no change: {100 * kept:.0f} %"
    fell = frame_mean(rows, "fallback_share")
    if fell:
        words += f"; guard: {100 * fell:.1f} % of frames are the input smoothed"
    console.print(
        f"denoised {len(done)} file(s), {total} frames in {secs:.2f} s "
        f"({total / max(secs, 1e-9):,.0f} frames/s){words}{fill_words(rows)}"
    )


def _not_loops(run) -> list[tuple[str | None, str]]:
    """``--loop``'s note on each track of ``run`` whose ends do not meet (``infer.loop``)."""
    from mdvae_cli.infer.loop import which_loop

    ends_meet = which_loop([t.motion for t in run.tracks])
    return [(t.label, NOT_LOOP_NOTE) for t, ok in zip(run.tracks, ends_meet, strict=True) if not ok]


NOT_LOOP_NOTE = (
    "--loop: its last frame does not meet its first (not a loop): denoised as a cycle anyway, "
    "its ends drawn together"
)
LOOP_NOTE = (
    "looks like a loop (its last frame meets its first): denoised as a cycle; --no-loop to "
    "treat it as a take"
)

COMMANDS = [denoise]
