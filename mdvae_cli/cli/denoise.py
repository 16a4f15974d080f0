"""``mdvae denoise``: regression mode by default, optimisation mode with ``--optimize N``."""

from __future__ import annotations

import copy
import time
from pathlib import Path

import click

from mdvae_cli.cli.batch import (
    FileJob,
    emit_json,
    json_option,
    plan_jobs,
    print_notes,
    run_batch,
    strip_gz,
)
from mdvae_cli.cli.common import (
    NON_NEGATIVE,
    POSITIVE,
    SEED,
    allow_pickle_option,
    body_model_option,
    console,
    handle_errors,
    progress_bar,
)
from mdvae_cli.errors import InputError


@click.command("denoise")
@click.argument("inputs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "-o",
    "--out",
    required=True,
    type=click.Path(),
    help="Output .npz (one input file) or folder (inputs mirrored below it).",
)
@click.option(
    "--denoiser",
    "denoiser_path",
    type=click.Path(path_type=Path),
    help="Denoiser checkpoint or fit-dataset folder (default: the shipped one).",
)
@click.option(
    "--optimize",
    "optimize_steps",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    help="Optimisation mode: first fine-tune the inference networks on these files "
    "for N steps (the paper uses 50); 0 = regression mode, one forward pass.",
)
@click.option(
    "--per-file",
    is_flag=True,
    help="With --optimize: adapt once per file instead of once to the whole set.",
)
@click.option(
    "--lr",
    type=POSITIVE,
    default=None,
    help="With --optimize: its learning rate (> 0) [default: 3e-4].",
)
@click.option(
    "--seed", type=SEED, default=0, show_default=True, help="With --optimize: its random seed."
)
@click.option(
    "--refine",
    "refine_steps",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    help="Then refine every window's latents for N gradient steps on its own ELBO, scoring "
    "the file's noisy joint rotations with a noise level estimated per joint (50 is a good "
    "value: markedly cleaner, about 15x slower than the default); 0 = off.",
)
@click.option(
    "--refine-lr",
    type=POSITIVE,
    default=0.1,
    show_default=True,
    help="Step size of --refine (> 0).",
)
@click.option(
    "--refine-offset",
    type=NON_NEGATIVE,
    default=0.03,
    show_default=True,
    help="The scale (rad) each joint's slow rotation offset (--offset, --refine) starts from "
    "in every window, then estimated from the file. 0 = no offset.",
)
@click.option(
    "--trans-offset",
    type=NON_NEGATIVE,
    default=0.03,
    show_default=True,
    help="The scale (m) the root translation's slow offset (--offset) starts from in every "
    "window: it keeps the file's path, from which the decoded one drifts by ~4 cm. 0 = no "
    "translation offset. (--refine fits the translation itself.)",
)
@click.option(
    "--offset/--no-offset",
    default=True,
    show_default=True,
    help="After the forward pass, fit a slow rotation offset per joint, and one for the root "
    "translation, to the file in closed form (no gradient steps): it follows slow motion the "
    "learned prior cannot express, so clean parts of a take come back almost unchanged, the "
    "body keeps the file's path, and the result is more accurate than a tuned filter, at "
    "~1.3x the time. --no-offset is the paper's plain regression mode. Part of --refine "
    "already.",
)
@click.option(
    "--outliers",
    is_flag=True,
    help="With --refine: model the noise as heavy-tailed (Student-t, 10 degrees of freedom) per "
    "frame and joint, so spikes (a swapped marker, a solver flip) are down-weighted where they "
    "happen instead of raising the whole joint's noise level: about 40 % lower error on takes "
    "with spikes, 1 % higher on evenly noisy ones (benchmarks/outliers.py).",
)
@click.option(
    "--mirror",
    is_flag=True,
    help="Also denoise each file's left-right mirror image and average the two results (the "
    "learned prior is not exactly mirror-symmetric): about 10 % lower error in regression "
    "mode without the offset, 1 % with it, 3 % with --refine, at about twice the time.",
)
@click.option(
    "--feet",
    type=click.Choice(["lock", "off"]),
    default="lock",
    show_default=True,
    help="lock: where a foot is down (a foot joint low and slow), hold it still on the floor "
    "with a small turn of the hip, knee and ankle, and lift a foot that dips under the floor; "
    "frames away from contacts are left exactly as denoised. On noisy test clips it cuts foot "
    "skate 4-5x and floor penetration by half at the same vertex error (docs/benchmarks.md). "
    "off: the feet as denoised.",
)
@click.option(
    "--mesh-dir",
    type=click.Path(path_type=Path),
    help="Also write the cleaned mesh sequence here (one input: into the folder itself; "
    "several: a subfolder per file).",
)
@click.option(
    "--mesh-format",
    type=click.Choice(["obj", "ply"]),
    default=None,
    help="Mesh file format for --mesh-dir [default: ply].",
)
@click.option(
    "--window",
    type=click.IntRange(min=8),
    default=60,
    show_default=True,
    help="Frames per window at 30 Hz (as trained).",
)
@click.option(
    "--overlap",
    type=click.IntRange(min=1),
    default=15,
    show_default=True,
    help="Frames shared by consecutive windows, cross-faded.",
)
@body_model_option
@allow_pickle_option
@json_option
@handle_errors
def denoise(
    inputs,
    out,
    denoiser_path,
    optimize_steps,
    per_file,
    lr,
    seed,
    refine_steps,
    refine_lr,
    refine_offset,
    trans_offset,
    offset,
    outliers,
    mirror,
    feet,
    mesh_dir,
    mesh_format,
    window,
    overlap,
    body_model,
    allow_pickle,
    as_json,
) -> None:
    """Remove noise from motion files with the learned Motion-DVAE prior.

    INPUTS are AMASS-style .npz files or folders (any length, any frame rate); outputs keep
    the input's keys, frame rate, frame count, hands and extra arrays, with cleaned body pose,
    root orientation and translation. Works out of the box with the shipped weights and the
    built-in body; pass --body-model for a real SMPL/SMPL-H/SMPL-X file.

    \b
    Examples:
      mdvae denoise noisy.npz -o clean.npz
      mdvae denoise noisy_dir/ -o clean_dir/ --optimize 50
      mdvae denoise noisy.npz -o clean.npz --no-offset
      mdvae denoise noisy.npz -o clean.npz --refine 50 --mirror
      mdvae denoise spiky.npz -o clean.npz --refine 50 --outliers
      mdvae denoise take.npz -o clean.npz --feet off
      mdvae denoise take.npz -o clean.npz --mesh-dir meshes/ --mesh-format obj
    """
    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.body.skinning import BodyModel
    from mdvae_cli.export import export_mesh_sequence
    from mdvae_cli.infer.denoise import check_finite, check_length, denoise_motions
    from mdvae_cli.infer.feet import FootLockConfig
    from mdvae_cli.infer.settings import OUTLIER_DOF, RefineConfig
    from mdvae_cli.model.denoiser import load_denoiser
    from mdvae_cli.motion.npz_io import load_motion, save_motion

    if overlap >= window:
        raise InputError(f"--overlap ({overlap}) must be smaller than --window ({window})")
    if outliers and not refine_steps:
        raise InputError("--outliers re-weights frames while refining: use it with --refine N")
    if not optimize_steps and (per_file or lr is not None):
        raise InputError(f"{'--per-file' if per_file else '--lr'} only applies with --optimize N")
    if mesh_format is not None and mesh_dir is None:
        raise InputError("--mesh-format only applies with --mesh-dir DIR")
    if mesh_dir is not None and Path(mesh_dir).exists() and not Path(mesh_dir).is_dir():
        raise InputError(f"--mesh-dir {mesh_dir} is a file; give a folder")
    lr = 3e-4 if lr is None else lr
    mesh_format = mesh_format or "ply"
    jobs = plan_jobs(inputs, out)
    sources = tuple(job.source for job in jobs)
    loaded: dict[Path, object] = {}

    def read(job: FileJob) -> None:
        motion = load_motion(job.source, allow_pickle=allow_pickle)
        check_length(motion)
        print_notes(job.relpath, motion.notes)
        loaded[job.source] = motion

    report = run_batch(jobs, read, "reading", quiet=True)
    good = [o.job for o in report.succeeded]
    if good:
        denoiser, _ = load_denoiser(denoiser_path)
        body = BodyModel(load_body_model(body_model))
    stride = window - overlap
    refine = None
    if refine_steps or offset:
        refine = RefineConfig(
            steps=refine_steps,
            lr=refine_lr,
            offset_std=refine_offset,
            trans_offset_std=trans_offset,
            outlier_dof=OUTLIER_DOF if outliers else 0.0,
        )
    results: dict[Path, object] = {}
    timings: dict[Path, float] = {}

    def run(group: list[FileJob]) -> None:
        model = copy.deepcopy(denoiser) if optimize_steps else denoiser
        start = time.perf_counter()
        with progress_bar(transient=True) as progress:
            tasks = {
                stage: progress.add_task(label, total=1, visible=False, info="")
                for stage, label in (("optimize", "optimising"), ("refine", "refining"))
            }

            def tick(info: dict) -> None:
                progress.update(
                    tasks[info["stage"]],
                    visible=True,
                    completed=info["step"],
                    total=info["steps"],
                    info=f"loss {info['loss']:.2f}",
                )

            cleaned = denoise_motions(
                [loaded[j.source] for j in group],
                model,
                body,
                window,
                stride,
                optimize_steps=optimize_steps,
                lr=lr,
                seed=seed,
                progress=tick,
                refine=refine,
                mirror=mirror,
                feet=FootLockConfig() if feet == "lock" else None,
            )
        seconds = time.perf_counter() - start
        frames = sum(loaded[j.source].num_frames for j in group)
        for j, m in zip(group, cleaned, strict=True):
            results[j.source] = m
            timings[j.source] = seconds * loaded[j.source].num_frames / max(frames, 1)

    if good:
        for group in [[j] for j in good] if per_file and optimize_steps else [good]:
            run(group)

    def write(job: FileJob) -> dict:
        motion = results[job.source]
        check_finite(motion)
        if mesh_dir is not None:  # first: a file whose meshes fail gets no .npz either
            sub = strip_gz(job.relpath).with_suffix("")  # as export-mesh names it
            target = Path(mesh_dir) / sub if len(jobs) > 1 else Path(mesh_dir)
            export_mesh_sequence(motion, body, target, mesh_format, forbid=sources)
        save_motion(motion, job.output, forbid=sources)
        return {"frames": motion.num_frames, "seconds": round(timings[job.source], 4)}

    write_report = run_batch(good, write, "denoise", quiet=True)
    write_report.outcomes = report.failed + write_report.outcomes
    if len(jobs) > 1:
        write_report.print_summary("denoise")
    if as_json:
        emit_json(
            {
                **write_report.to_dict(),
                "mode": "optimization" if optimize_steps else "regression",
                "optimize_steps": optimize_steps,
                "refine_steps": refine_steps,
                "refine": refine.to_dict() if refine else None,
                "mirror": mirror,
                "feet": feet,
            }
        )
    elif write_report.succeeded:
        total = sum(o.result["frames"] for o in write_report.succeeded)
        secs = sum(o.result["seconds"] for o in write_report.succeeded)
        console.print(
            f"denoised {len(write_report.succeeded)} file(s), {total} frames in "
            f"{secs:.2f} s ({total / max(secs, 1e-9):,.0f} frames/s)"
        )
    write_report.exit()


COMMANDS = [denoise]
