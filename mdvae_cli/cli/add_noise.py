"""``mdvae add-noise``: make noisy test data with the Pose-NDF protocol, or with the errors of a
video pose estimator (``--preset video``)."""

from __future__ import annotations

from pathlib import Path

import click
from rich.markup import escape

from mdvae_cli.cli.batch import (
    FileJob,
    emit_json,
    json_option,
    no_clashes,
    print_notes,
    run_batch,
    strip_gz,
)
from mdvae_cli.cli.common import (
    FRACTION,
    NON_NEGATIVE,
    SEED,
    OutputPath,
    allow_pickle_option,
    console,
    handle_errors,
    on_command_line,
)
from mdvae_cli.cli.motion_input import motion_input_options, read_input
from mdvae_cli.cli.noise_holes import HOLES, drop_holes
from mdvae_cli.cli.takes import plan_take_jobs, take_options, take_reading
from mdvae_cli.errors import InputError
from mdvae_cli.formats.npz_holes import keep_holes
from mdvae_cli.formats.registry import (
    TAKE_SUFFIXES,
    VIDEO_SUFFIXES,
    ReadOptions,
    suffix_of,
    write,
)
from mdvae_cli.motion.noise import (
    PRESETS,
    NoiseSettings,
    add_pose_noise,
    add_video_noise,
    file_rng,
)
from mdvae_cli.run.tracks import outputs_of, own_output


def _parse_sets(values: tuple[str, ...]) -> dict[str, float]:
    """``--set name=value`` options -> {name: value}; InputError for a malformed one."""
    out = {}
    for item in values:
        name, eq, value = item.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            eq = ""
        if not eq or not name.strip():
            raise InputError(f"--set takes NAME=NUMBER, got {item!r}")
    return out


@click.command("add-noise")
@click.argument("inputs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "-o", "--out", type=OutputPath(), required=True,
    help="Output file (one input file: .npz, or .bvh / .amc for a take of that form) or "
    "folder (inputs mirrored below it, each in its own form).",
)  # fmt: skip
@click.option(
    "--preset", type=click.Choice(sorted(PRESETS)), default=None,
    help="Noise of a kind instead of the Pose-NDF protocol: 'video' = what monocular video "
    "pose estimators get wrong (slow per-joint bias, jitter, left/right leg swaps, turned "
    "roots, spikes, depth jitter; docs/model.md). Change its parameters with --set.",
)  # fmt: skip
@click.option(
    "--set", "sets", multiple=True, metavar="NAME=VALUE",
    help="With --preset: set one of its parameters, e.g. --set pose_slow=0.05 --set "
    "swap_rate=0 (names: pose_white, pose_slow, root_white, root_slow, depth_white, "
    "depth_slow, lateral_white, lateral_slow, swap_rate, turn_rate, swap_frames, spike_frac, "
    "spike_rad, slow_time).",
)  # fmt: skip
@click.option(
    "--sigma", type=NON_NEGATIVE, default=None,
    help="Std of the Gaussian noise on the body joints' axis-angles, radians "
    "(>= 0; the paper uses 0.1, 0.15, 0.2). [default: 0.15]",
)  # fmt: skip
@click.option(
    "--seed", type=SEED, default=0, show_default=True,
    help="Random seed; each file's noise depends only on it and the file's relative path.",
)  # fmt: skip
@click.option(
    "--joint-noise", "joint_noise", type=NON_NEGATIVE, default=0.0, show_default=True,
    metavar="METRES",
    help="Std of Gaussian per-frame jitter on the root translation, per axis; moves every "
    "joint of a frame by the same offset.",
)  # fmt: skip
@click.option(
    "--drop-frac", type=FRACTION, default=0.0, show_default=True,
    help="Fraction of (frame, joint) entries to mark missing in a 'joint_mask' array "
    "(0 to 1; poses are not changed).",
)  # fmt: skip
@click.option(
    "--drop-frames", type=HOLES, default=None, metavar="LENGTH[xCOUNT]",
    help="Make holes: COUNT (default 1) stretches of LENGTH frames missing whole, written as "
    "NaN in poses and trans (as a tracker that lost the person; mdvae denoise fills them); "
    "in an AMC take as frame numbers left out, the holes its reader reads.",
)  # fmt: skip
@click.option(
    "--drop-joints", type=HOLES, default=None, metavar="LENGTH[xCOUNT]",
    help="Make holes: COUNT (default 1) stretches of LENGTH frames with one limb (an arm or a "
    "leg, drawn) missing, written as NaN (as an optical system that lost its markers).",
)  # fmt: skip
@click.option(
    "--spike-frac", type=FRACTION, default=0.0, show_default=True,
    help="Probability that a (frame, body joint) entry gets a spike (an outlier such as a "
    "swapped marker or a solver flip), on top of --sigma (0 to 1).",
)  # fmt: skip
@click.option(
    "--spike-rad", type=NON_NEGATIVE, default=1.0, show_default=True, metavar="RADIANS",
    help="Std of a spike per axis-angle component (with --spike-frac).",
)  # fmt: skip
@motion_input_options
@take_options
@allow_pickle_option
@json_option
@handle_errors
def add_noise(
    inputs, out, preset, sets, sigma, seed, joint_noise, drop_frac, drop_frames, drop_joints,
    spike_frac, spike_rad, input_format, input_fps, track, asf, joint_map_file, allow_pickle,
    as_json,
) -> None:  # fmt: skip
    """Add Pose-NDF-style noise to motion files.

    Adds zero-mean Gaussian noise of std --sigma (radians) to the axis-angle of the 21 body
    joints only; root orientation, translation (unless --joint-noise) and hands are left as
    they are. With --preset video, the errors of a video pose estimator instead. INPUTS are
    motion files (AMASS .npz, video-pipeline outputs, BVH and ASF/AMC takes) or folders;
    folders are mirrored under --out. A take comes back in its own form, on its own skeleton
    (the noise put on its joints' rotations through the body it is read onto), and a video
    pipeline's file as the pipeline wrote it, unless holes are asked for: written as .npz,
    but an AMC take with --drop-frames alone (the frames' numbers left out).

    \b
    Examples:
      mdvae add-noise --sigma 0.1 clean.npz -o noisy.npz
      mdvae add-noise --sigma 0.2 --seed 3 amass_test/ -o noisy_test/
      mdvae add-noise --sigma 0.05 --spike-frac 0.02 --spike-rad 1 clean.npz -o spiky.npz
      mdvae add-noise --preset video clean.npz -o video_like.npz
      mdvae add-noise --preset video --set swap_rate=0 clean_dir/ -o noisy_dir/
      mdvae add-noise --sigma 0.05 --drop-frames 15x2 --drop-joints 30 clean.npz -o holes.npz
      mdvae add-noise --sigma 0.1 take.bvh -o noisy_take.bvh
    """
    video = _video_noise(preset, sets, sigma, joint_noise, drop_frac, spike_frac)
    sigma = 0.15 if sigma is None else sigma
    settings = NoiseSettings(sigma, joint_noise, drop_frac, spike_frac, spike_rad).validate()
    jobs = plan_take_jobs(inputs, out)
    holes = drop_frac > 0 or drop_frames is not None or drop_joints is not None
    partial = drop_frac > 0 or drop_joints is not None  # holes not of whole frames
    jobs = takes_as_npz(jobs, Path(out), partial) if holes else jobs  # NaN: in an .npz
    sources = tuple(job.source for job in jobs)
    read_options = ReadOptions(format=input_format, fps=input_fps, track=track,
                               allow_pickle=allow_pickle,
                               **take_reading(asf, joint_map_file))  # fmt: skip

    def process(job: FileJob) -> dict:
        loaded = read_input(job.source, job.relpath, read_options, job.output, holes)
        frames, outputs, dropped, noisy_tracks = 0, [], {}, []
        target, own, why = own_output(loaded, job.output, holes)
        if why is not None:
            print_notes(job.relpath, [why])
        for label, motion, output in outputs_of(loaded, target, holes):
            name = job.relpath if label is None else f"{job.relpath.as_posix()}#track{label}"
            noisy = make_noisy(motion, file_rng(seed, name), video, settings)
            holes_rng = file_rng(seed, f"{name}#holes")  # the noise's own stream unchanged
            noisy, made = drop_holes(noisy, drop_frames, drop_joints, holes_rng, job.relpath)
            if own:  # the file's rows, noisy: its gaps stay gaps (no rows made up for them)
                noisy_tracks.append((label, keep_holes(noisy)))
            else:
                print_notes(job.relpath, write(noisy, output, take=loaded.take, forbid=sources))
                outputs.append(str(output))
            frames += noisy.num_frames
            dropped = {k: dropped.get(k, 0) + v for k, v in made.items()}
        if own:  # the pipeline's file back in its own form, every track in it
            loaded.tracks = noisy_tracks
            print_notes(job.relpath, write(loaded, target, forbid=sources))
            outputs.append(str(target))
        return {"frames": frames, "outputs": outputs, **dropped}

    report = run_batch(jobs, process, "add-noise")
    if as_json:
        emit_json(report.to_dict())
    elif report.succeeded:
        total = sum(o.result["frames"] for o in report.succeeded)
        where = escape(str(jobs[0].output if len(jobs) == 1 else out))
        console.print(f"wrote {len(report.succeeded)} noisy file(s), {total} frames, to {where}")
    report.exit()


def make_noisy(motion, rng, video, settings: NoiseSettings):
    """``motion`` with the ``--preset``'s video noise (``video``), else Pose-NDF noise."""
    if video is not None:
        return add_video_noise(motion, video, rng)
    return add_pose_noise(motion, settings.sigma, rng, trans_sigma=settings.trans_sigma,
                          drop_frac=settings.drop_frac, spike_frac=settings.spike_frac,
                          spike_rad=settings.spike_rad)  # fmt: skip


def takes_as_npz(jobs: list[FileJob], out: Path, partial: bool = True) -> list[FileJob]:
    """``jobs`` with each BVH / AMC output, and each video pipeline's, written as .npz
    instead: holes are NaN, which none of those forms can hold; but an AMC take's when the
    holes are whole frames alone (not ``partial``: ``--drop-frames``), which it holds as frame
    numbers left out (``formats.amc_frames``). InputError when such an output is the one
    named by ``-o``."""
    keep = () if partial else (".amc",)
    fixed = []
    for job in jobs:
        kind = None if job.output is None else suffix_of(job.output)
        if kind in (*TAKE_SUFFIXES, *VIDEO_SUFFIXES) and kind not in keep:
            if job.output == out:
                amc = " (AMC holds frames missing whole: --drop-frames alone)" * (kind == ".amc")
                raise InputError(
                    f"cannot write {out}: holes (--drop-frac, --drop-frames, --drop-joints) are "
                    f"written as NaN, which {kind[1:].upper()} cannot hold{amc}; name an .npz "
                    "output"
                )  # fmt: skip
            job = FileJob(job.relpath, job.source, strip_gz(job.output).with_suffix(".npz"))
        fixed.append(job)
    return no_clashes(fixed)


def _video_noise(preset, sets, sigma, joint_noise, drop_frac, spike_frac):
    """The ``--preset`` noise with its ``--set`` changes (None without a preset); InputError
    for the options a preset sets itself, --set without one, and --spike-rad without
    --spike-frac."""
    if preset is None:
        if sets:
            raise InputError("--set changes the parameters of a --preset; give --preset too")
        if not spike_frac and on_command_line("spike_rad"):
            raise InputError("--spike-rad only applies with --spike-frac F (the spikes it sizes)")
        return None
    options = {"--sigma": sigma, "--joint-noise": joint_noise, "--drop-frac": drop_frac,
               "--spike-frac": spike_frac}  # fmt: skip
    given = [name for name, value in options.items() if value]
    given += ["--spike-rad"] * on_command_line("spike_rad")
    if given:
        raise InputError(f"--preset {preset} sets every noise itself; change its "
                         f"parameters with --set instead of {', '.join(given)}")  # fmt: skip
    return PRESETS[preset].with_overrides(_parse_sets(sets))


COMMANDS = [add_noise]
