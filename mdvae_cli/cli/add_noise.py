"""``mdvae add-noise``: make noisy test data with the Pose-NDF protocol."""

from __future__ import annotations

from pathlib import Path

import click

from mdvae_cli.cli.batch import (
    FileJob,
    emit_json,
    json_option,
    plan_jobs,
    print_notes,
    run_batch,
)
from mdvae_cli.cli.common import FRACTION, NON_NEGATIVE, SEED, allow_pickle_option, handle_errors
from mdvae_cli.motion.noise import NoiseSettings, add_pose_noise, file_rng
from mdvae_cli.motion.npz_io import load_motion, save_motion


@click.command("add-noise")
@click.argument("inputs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "-o", "--out", type=click.Path(), required=True,
    help="Output .npz (one input file) or folder (inputs mirrored below it).",
)  # fmt: skip
@click.option(
    "--sigma", type=NON_NEGATIVE, default=0.15, show_default=True,
    help="Std of the Gaussian noise on the body joints' axis-angles, radians "
    "(>= 0; the paper uses 0.1, 0.15, 0.2).",
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
    "--spike-frac", type=FRACTION, default=0.0, show_default=True,
    help="Probability that a (frame, body joint) entry gets a spike (an outlier such as a "
    "swapped marker or a solver flip), on top of --sigma (0 to 1).",
)  # fmt: skip
@click.option(
    "--spike-rad", type=NON_NEGATIVE, default=1.0, show_default=True, metavar="RADIANS",
    help="Std of a spike per axis-angle component (with --spike-frac).",
)  # fmt: skip
@allow_pickle_option
@json_option
@handle_errors
def add_noise(
    inputs, out, sigma, seed, joint_noise, drop_frac, spike_frac, spike_rad, allow_pickle, as_json
) -> None:
    """Add Pose-NDF-style noise to motion files.

    Adds zero-mean Gaussian noise of std --sigma (radians) to the axis-angle of the 21 body
    joints only; root orientation, translation (unless --joint-noise) and hands are left as
    they are. INPUTS are .npz files or folders; folders are mirrored under --out.

    \b
    Examples:
      mdvae add-noise --sigma 0.1 clean.npz -o noisy.npz
      mdvae add-noise --sigma 0.2 --seed 3 amass_test/ -o noisy_test/
      mdvae add-noise --sigma 0.05 --spike-frac 0.02 --spike-rad 1 clean.npz -o spiky.npz
    """
    settings = NoiseSettings(sigma, joint_noise, drop_frac, spike_frac, spike_rad).validate()
    jobs = plan_jobs(inputs, out)
    sources = tuple(job.source for job in jobs)

    def process(job: FileJob) -> None:
        motion = load_motion(job.source, allow_pickle=allow_pickle)
        print_notes(job.relpath, motion.notes)
        noisy = add_pose_noise(
            motion,
            settings.sigma,
            file_rng(seed, job.relpath),
            trans_sigma=settings.trans_sigma,
            drop_frac=settings.drop_frac,
            spike_frac=settings.spike_frac,
            spike_rad=settings.spike_rad,
        )
        save_motion(noisy, job.output, forbid=sources)

    report = run_batch(jobs, process, "add-noise")
    if as_json:
        emit_json(report.to_dict())
    report.exit()


COMMANDS = [add_noise]
