"""``mdvae denoise``: regression mode by default, optimisation mode with ``--optimize N``."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import click

from mdvae_cli.cli.batch import (
    FileJob,
    emit_json,
    json_option,
    print_notes,
    run_batch,
    strip_gz,
)
from mdvae_cli.cli.common import (
    allow_pickle_option,
    body_model_option,
    console,
    handle_errors,
    progress_bar,
)
from mdvae_cli.cli.denoise_options import (
    denoise_options,
    fill_counts,
    fill_setting,
    fill_totals,
    fill_words,
)
from mdvae_cli.cli.motion_input import (
    motion_input_options,
    outputs_of,
    read_input,
    track_output,
)
from mdvae_cli.cli.takes import is_take, load_joint_map, plan_take_jobs
from mdvae_cli.errors import InputError


@click.command("denoise")
@click.argument("inputs", nargs=-1, required=True, type=click.Path(path_type=Path))
@denoise_options
@motion_input_options
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
    lam,
    input_kind,
    mirror,
    feet,
    fill,
    missing,
    floor,
    guard,
    blend,
    loop,
    mesh_dir,
    mesh_format,
    view_dir,
    window,
    overlap,
    asf,
    joint_map_file,
    input_format,
    input_fps,
    track,
    body_model,
    allow_pickle,
    as_json,
) -> None:
    """Remove noise from motion files with the learned Motion-DVAE prior.

    INPUTS are AMASS-style .npz files, BVH takes (.bvh, .bvh.gz), ASF/AMC takes (.amc,
    .amc.gz, with their .asf), the output files of video pose pipelines (WHAM, GVHMR, TRAM,
    4D-Humans/PHALP, VIBE, PARE, HybrIK, ROMP/BEV, SLAHMR: upright, z up, one output per
    person track) or folders of them (any length, any frame rate); .npz outputs keep the
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
    -o x.npz instead writes the cleaned body motion.

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
      mdvae denoise wham_output.pkl -o clean.npz
      mdvae denoise hmr4d_results.pt -o clean.npz --fps 25 --refine 50
      mdvae denoise take.npz -o clean.npz --mesh-dir meshes/ --mesh-format obj
      mdvae denoise takes/ -o clean/ --view pages/
    """
    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.body.skinning import BodyModel
    from mdvae_cli.cli.motion_input import on_floor
    from mdvae_cli.export import export_mesh_sequence
    from mdvae_cli.formats.npz_holes import keep_holes
    from mdvae_cli.formats.registry import ReadOptions
    from mdvae_cli.formats.registry import write as write_motion
    from mdvae_cli.infer.denoise import check_finite, check_length
    from mdvae_cli.infer.denoise_settings import DenoiseSettings, denoise, loops_of
    from mdvae_cli.infer.settings import OUTLIER_DOF
    from mdvae_cli.model.denoiser import load_denoiser
    from mdvae_cli.retarget.take import TakeReader

    if outliers and lam is not None and lam != OUTLIER_DOF:
        raise InputError(f"--outliers is --lam {OUTLIER_DOF:g}; give one of them")
    lam = OUTLIER_DOF if outliers else lam
    if lam and not (refine_steps or offset):
        raise InputError("--outliers / --lam weigh frames in the offset or --refine; "
                         "drop --no-offset or add --refine N")  # fmt: skip
    if not optimize_steps and (per_file or lr is not None):
        raise InputError(f"{'--per-file' if per_file else '--lr'} only applies with --optimize N")
    if mesh_format is not None and mesh_dir is None:
        raise InputError("--mesh-format only applies with --mesh-dir DIR")
    if mesh_dir is not None and Path(mesh_dir).exists() and not Path(mesh_dir).is_dir():
        raise InputError(f"--mesh-dir {mesh_dir} is a file; give a folder")
    if view_dir is not None and Path(view_dir).exists() and not Path(view_dir).is_dir():
        raise InputError(f"--view {view_dir} is a file; give a folder")
    lr = 3e-4 if lr is None else lr
    if overlap >= window:
        raise InputError(f"--overlap ({overlap}) must be smaller than --window ({window})")
    blend = not outliers if blend is None else blend  # --outliers weighs spikes itself
    base = DenoiseSettings(
        refine_steps=refine_steps, refine_lr=refine_lr, offset=offset, lam=lam,
        offset_std=refine_offset, trans_offset_std=trans_offset, blend=blend, guard=guard,
        feet=feet, loop=loop, mirror=mirror, optimize_steps=optimize_steps, lr=lr, seed=seed,
        window=window, overlap=overlap, fill=fill_setting(fill),
    )  # fmt: skip
    per_kind = lambda kind: replace(base, input_kind=kind)  # noqa: E731
    mesh_format = mesh_format or "ply"
    jobs = plan_take_jobs(inputs, out)
    sources = tuple(job.source for job in jobs)
    body_data = load_body_model(body_model)
    loaded: dict[Path, list] = {}  # source -> [(track label, motion, output)]
    kinds: dict[Path, str] = {}
    formats: dict[Path, str] = {}
    joint_map = load_joint_map(joint_map_file)
    if asf is not None and not Path(asf).is_file():
        raise InputError(f"no such skeleton file: {asf}")
    takes = TakeReader(body_data, asf, joint_map)
    options = ReadOptions(format=input_format, fps=input_fps, track=track,
                          allow_pickle=allow_pickle, body=body_data, missing=missing)  # fmt: skip
    read_takes: dict[Path, object] = {}  # source -> its take, for writing it back

    def read(job: FileJob) -> None:
        f = read_input(job.source, job.relpath, options, takes=takes)
        read_takes[job.source] = f.take
        items, short = [], []
        for label, motion, output in outputs_of(f, job.output):
            if floor:
                motion = on_floor(motion, body_data)
            try:
                check_length(motion)
            except InputError as exc:
                if len(f.tracks) == 1:
                    raise
                short.append(f"track {label}: {exc}")
                continue
            items.append((label, motion, output))
        if not items:
            raise InputError(f"every track is too short to denoise ({'; '.join(short)})")
        print_notes(job.relpath, [f"{s}; skipped" for s in short])
        kinds[job.source] = f.kind if input_kind == "auto" else input_kind
        formats[job.source] = f.format
        loaded[job.source] = items

    report = run_batch(jobs, read, "reading", quiet=True)
    good = [o.job for o in report.succeeded]
    if good:
        denoiser, _ = load_denoiser(denoiser_path)
        body = BodyModel(body_data)
    chosen: dict[str, tuple] = {}
    for kind in sorted({kinds[j.source] for j in good}):
        chosen[kind] = per_kind(kind).refine_row()
    for kind, (_, c) in chosen.items():
        if kind != "mocap" and not as_json:
            console.print(f"[dim]note: {kind} input: λ = {c['lam']:g}, offset scales "
                          f"{c['offset_std']:g} rad / {c['trans_offset_std']:g} m[/]")  # fmt: skip
    results: dict[tuple[Path, int], object] = {}
    timings: dict[Path, float] = {}
    fallbacks: dict[tuple[Path, int], list[list[float]]] = {}
    # the guard goes with the offset or refinement (--no-offset is the paper's mode untouched)
    guarding = {kind: guard and r is not None for kind, (r, _) in chosen.items()}  # for --json
    blends: dict[tuple[Path, int], object] = {}
    cycles: dict[tuple[Path, int], bool] = {}
    if good:
        for j in good:
            for i, (_, motion, _) in enumerate(loaded[j.source]):
                cycles[(j.source, i)] = loops_of([motion], base)[0]
                if loop is None and cycles[(j.source, i)] and not as_json:  # --json: "loop"
                    print_notes(j.relpath, [LOOP_NOTE])

    def run(group: list[FileJob], settings: DenoiseSettings) -> None:
        items = [(j, i) for j in group for i in range(len(loaded[j.source]))]
        keys = [(j.source, i) for j, i in items]
        motions = [loaded[j.source][i][1] for j, i in items]
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

            cleaned = denoise(
                motions,
                settings,
                denoiser,
                body,
                progress=tick,
                loops=None if loop is None else [loop] * len(motions),
                on_blend=lambda k, report: blends.__setitem__(keys[k], report),
                on_fallback=lambda k, a, b: fallbacks.setdefault(keys[k], []).append(
                    [round(a, 3), round(b, 3)]
                ),
            )
        seconds = time.perf_counter() - start
        frames = sum(m.num_frames for m in motions)
        for (j, i), m, src in zip(items, cleaned, motions, strict=True):
            results[(j.source, i)] = m
            timings[j.source] = timings.get(j.source, 0.0) + seconds * src.num_frames / max(
                frames, 1
            )

    for kind in chosen:
        of_kind = [j for j in good if kinds[j.source] == kind]
        for group in [[j] for j in of_kind] if per_file and optimize_steps else [of_kind]:
            run(group, per_kind(kind))

    def write(job: FileJob) -> dict:
        tracks = []
        for i, (label, source_motion, output) in enumerate(loaded[job.source]):
            motion = results[(job.source, i)]
            check_finite(motion)
            if mesh_dir is not None:  # first: a file whose meshes fail gets no .npz either
                sub = strip_gz(job.relpath).with_suffix("")  # as export-mesh names it
                target = Path(mesh_dir) / sub if len(jobs) > 1 else Path(mesh_dir)
                export_mesh_sequence(motion, body, track_output(target, label), mesh_format,
                                     forbid=sources)  # fmt: skip
            if fill == "off":  # an npz gets its NaN back, a take its own frames
                motion = keep_holes(motion)
            write_motion(motion, output, take=read_takes[job.source] if is_take(output) else None,
                  forbid=sources)  # fmt: skip
            if view_dir is not None:
                from mdvae_cli.view.page import write_before_after

                page = track_output(Path(view_dir) / strip_gz(job.relpath).with_suffix(".html"),
                                    label)  # fmt: skip
                write_before_after(source_motion, motion, job, page, body, forbid=sources)
            if not as_json:  # --json has them under "fallbacks"
                print_notes(job.relpath, [n for n in motion.notes if n.startswith("guard:")])
            stretches = fallbacks.get((job.source, i), [])
            duration = max((motion.num_frames - 1) / motion.fps, 1e-9)
            kept = blends.get((job.source, i))
            tracks.append({"track": label, "output": str(output), "frames": motion.num_frames,
                           "fallbacks": stretches,
                           "fallback_share": round(min(sum(b - a for a, b in stretches)
                                                       / duration, 1.0), 4),
                           "input_share": None if kept is None else round(kept.input_share, 4),
                           "spike_share": None if kept is None else round(kept.spike_share, 4),
                           "loop": cycles.get((job.source, i), False),
                           **fill_counts(source_motion, fill != "off")})  # fmt: skip
        return {
            "frames": sum(t["frames"] for t in tracks),
            "seconds": round(timings[job.source], 4),
            "format": formats[job.source],
            "input_kind": kinds[job.source],
            "fallbacks": [f for t in tracks for f in t["fallbacks"]],
            "fallback_share": _frame_mean(tracks, "fallback_share"),
            "input_share": _frame_mean(tracks, "input_share"),
            "loop": any(t["loop"] for t in tracks),
            **fill_totals(tracks),
            "tracks": tracks,
        }

    write_report = run_batch(good, write, "denoise", quiet=True)
    write_report.outcomes = report.failed + write_report.outcomes
    if len(jobs) > 1:
        write_report.print_summary("denoise")
    if as_json:
        first = next(iter(chosen.values()), (None, None))
        emit_json(
            {
                **write_report.to_dict(),
                "mode": _mode(optimize_steps, refine_steps, offset),
                "optimize_steps": optimize_steps,
                "refine_steps": refine_steps,
                "refine": first[0].to_dict() if first[0] else None,
                "settings": {kind: c[1] for kind, c in chosen.items()},
                "mirror": mirror,
                "feet": feet,
                "fill": fill_setting(fill),
                "guard": any(guarding.values()),
                "blend": blend and any(r is not None for r, _ in chosen.values()),
            }
        )
    elif write_report.succeeded:
        done = [o.result for o in write_report.succeeded]
        total = sum(r["frames"] for r in done)
        secs = sum(r["seconds"] for r in done)
        console.print(
            f"denoised {len(done)} file(s), {total} frames in {secs:.2f} s "
            f"({total / max(secs, 1e-9):,.0f} frames/s){_kept_words(done)}{fill_words(done)}"
        )
    write_report.exit()


def _frame_mean(items: list[dict], key: str) -> float | None:
    """The frame-weighted mean of ``key`` over tracks or files (None where none has it)."""
    have = [(t[key], t["frames"]) for t in items if t.get(key) is not None]
    if not have:
        return None
    return round(sum(v * n for v, n in have) / max(sum(n for _, n in have), 1), 4)


def _kept_words(done: list[dict]) -> str:
    """What the summary line says of the blend and the guard."""
    words = ""
    kept = _frame_mean(done, "input_share")
    if kept is not None:
        words += f"; kept as it came where its noise explains no change: {100 * kept:.0f} %"
    fell = _frame_mean(done, "fallback_share")
    if fell:
        words += f"; guard: {100 * fell:.1f} % of frames are the input smoothed"
    return words


def _mode(optimize_steps: int, refine_steps: int, offset: bool) -> str:
    """The ``--json`` "mode": what ran after the networks' one pass."""
    if optimize_steps:
        return "optimization"
    if refine_steps:
        return "refinement"
    return "regression+offset" if offset else "regression"


LOOP_NOTE = (
    "looks like a loop (its last frame meets its first): denoised as a cycle; --no-loop to "
    "treat it as a take"
)

COMMANDS = [denoise]
