"""``mdvae fit-dataset``: unsupervised denoising learning on a folder of noisy files."""

from __future__ import annotations

import math
from pathlib import Path

import click

from mdvae_cli.cli.batch import emit_json
from mdvae_cli.cli.common import (
    NON_NEGATIVE,
    POSITIVE,
    OutputPath,
    body_model_option,
    console,
    handle_errors,
    progress_bar,
)
from mdvae_cli.cli.train_shared import (
    StopAfterStep,
    apply_overrides,
    note_skipped_data,
    refuse_changes_on_resume,
    run_options,
    same_path,
    start_config,
    summary_dict,
)
from mdvae_cli.errors import InputError


@click.command("fit-dataset")
@click.argument("noisy", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "-o",
    "--out",
    "out_dir",
    required=True,
    type=OutputPath(path_type=Path),
    help="Denoiser folder: config.json, denoiser.npz/.json, log.jsonl.",
)
@click.option(
    "--prior",
    "prior_path",
    type=click.Path(path_type=Path),
    help="Prior checkpoint or train-prior run folder (default: the shipped prior).",
)
@click.option(
    "--lam",
    type=POSITIVE,
    help="lambda of the IG(lam/2, lam/2) noise prior (> 0): large = "
    "Gaussian noise, small = heavy-tailed (outliers, video) [default: 10].",
)
@click.option(
    "--obs-unit",
    type=POSITIVE,
    help="Metres per observation unit (noise scale, > 0) [default: 0.08].",
)
@click.option(
    "--input-window",
    type=click.IntRange(min=0),
    help="Savitzky-Golay window (frames, odd; 0 = off) through which the inference networks "
    "read the noisy motion; the likelihood always scores the raw observations [default: 11].",
)
@click.option(
    "--window", type=click.IntRange(min=1), help="Frames per window at 30 Hz [default: 60]."
)
@click.option(
    "--stride",
    type=click.IntRange(min=1),
    help="Frames between window starts [default: 10].",
)
@click.option("--batch-size", type=click.IntRange(min=1), help="Windows per step [default: 64].")
@click.option(
    "--epochs",
    type=click.IntRange(min=0),
    help="Passes over the windows (0 = none, e.g. distillation only) [default: 8].",
)
@click.option(
    "--lr",
    type=POSITIVE,
    help="Adam learning rate (> 0), cosine-decayed to --lr-final [default: 3e-3].",
)
@click.option("--lr-final", type=NON_NEGATIVE, help="Final learning rate (>= 0) [default: 3e-4].")
@click.option(
    "--init-from",
    type=click.Path(path_type=Path, exists=True),
    help="Start from this denoiser (checkpoint or fit-dataset folder; its prior and settings "
    "come with it) instead of new networks on --prior.",
)
@click.option(
    "--distill-epochs",
    type=click.IntRange(min=0),
    help="After the ELBO epochs, passes of amortised refinement: every window is refined "
    "(--refine-style gradient steps on its own noisy data) and the networks learn to output "
    "the result in one pass; 0 = off [default: 0].",
)
@click.option(
    "--distill-lr",
    type=POSITIVE,
    help="Learning rate of --distill-epochs (> 0) [default: 1e-3].",
)
@click.option(
    "--distill-refine-steps",
    type=click.IntRange(min=1),
    help="Refinement steps per window for --distill-epochs' targets [default: 50].",
)
@click.option(
    "--mirror-augment/--no-mirror-augment",
    default=None,
    help="Also fit to the left-right mirror image of every noisy file: twice the windows "
    "(still no clean data) [default: off].",
)
@click.option(
    "--short-windows",
    metavar="LIST",
    help="Also fit to short takes: clips of these lengths (frames at 30 Hz, comma-separated, "
    "e.g. 6,10,16,30) cut from the noisy files, --short-share as many in all as full windows "
    "[default: none].",
)
@click.option(
    "--short-share",
    type=click.FloatRange(min=0.0, max=4.0, min_open=True),
    help="How many short takes, as a share of the full windows [default: 0.25].",
)
@click.option(
    "--holes",
    type=click.FloatRange(min=0.0, max=4.0),
    help="Also fit to copies of this share of the takes with random holes (frames and limbs "
    "missing; 1 = every take once more): the networks read where the holes are, the "
    "likelihood still scores the noisy frames hidden there, so they learn to fill them "
    "(`denoise` then writes their own frames in a noisy take's holes) [default: 0].",
)
@click.option(
    "--resume",
    is_flag=True,
    help="Continue the -o run from its denoiser.npz (saved every 200 ELBO steps). The ELBO "
    "fit then ends with exactly the networks of an uninterrupted run (resume.npz keeps Adam's "
    "state and the random draws); the distillation targets refined so far are kept (saved "
    "on a stop and every 5 minutes) and the rest refined; distillation restarts its Adam.",
)
@click.option(
    "--overwrite",
    is_flag=True,
    help="Start a new run in an -o folder that already holds a denoiser, replacing it "
    "(refused otherwise); its distillation targets are reused where the networks match.",
)
@click.option(
    "--max-steps",
    type=click.IntRange(min=1),
    help="Stop after this many ELBO steps in this invocation (a --resume counts afresh).",
)
@run_options
@body_model_option
@handle_errors
def fit_dataset(
    noisy,
    out_dir,
    prior_path,
    config_file,
    init_from,
    resume,
    overwrite,
    max_steps,
    threads,
    body_model,
    as_json,
    **overrides,
) -> None:
    """Fit the denoiser to noisy motion files, unsupervised (no clean data needed).

    Learns the encoder, initial-state predictor and noise predictor by maximising the ELBO of
    the noisy observations (22 joints + 43 markers) under the frozen prior (paper Sec. 4.2).
    The result denoises new files in one pass: `mdvae denoise --denoiser OUT ...`.

    With --distill-epochs, it then teaches the networks what latent refinement (`mdvae
    denoise --refine`) finds on each of these windows, so that the one pass lands closer to
    it (amortised refinement; still no clean data).

    \b
    Examples:
      mdvae fit-dataset noisy_takes/ -o runs/denoiser --epochs 20
      mdvae fit-dataset noisy_takes/ -o runs/denoiser_a --init-from runs/denoiser \\
          --epochs 0 --distill-epochs 6 --mirror-augment
    """
    import torch

    from mdvae_cli.train.fit_dataset import FitConfig
    from mdvae_cli.train.fit_dataset import fit_dataset as run

    if threads is not None:
        torch.set_num_threads(threads)
    cfg = start_config(FitConfig, out_dir, resume, config_file, noisy)
    if not resume:
        cfg.data = [str(p) for p in noisy]
        if prior_path is not None:
            cfg.prior = str(prior_path)
        if init_from is not None:
            cfg.init_from = str(init_from)
        if body_model is not None:
            cfg.body_model = str(body_model)
    note_skipped_data(cfg.data)  # what the trainer skips: broken links, other formats
    if overrides.get("short_windows") is not None:
        overrides["short_windows"] = parse_lengths(overrides["short_windows"])
    apply_overrides(
        cfg,
        overrides,
        nested={
            "lam": "denoiser",
            "obs_unit": "denoiser",
            "input_window": "denoiser",
            "distill_epochs": ("distill", "epochs"),
            "distill_lr": ("distill", "lr"),
            "distill_refine_steps": ("distill", "refine_steps"),
        },
        resume=resume,
    )
    paths = {"--prior": prior_path, "--init-from": init_from, "--body-model": body_model}
    _check_starting_point(cfg, overrides, paths, resume)
    with progress_bar() as progress, StopAfterStep() as stop:
        summary = run(cfg, out_dir, resume=resume, progress=FitReporter(progress),
                      max_steps=max_steps, overwrite=overwrite, stop_requested=stop)  # fmt: skip
    where: int | str = summary.steps
    if summary.distill_steps:
        where = f"{summary.steps} ELBO + {summary.distill_steps} distillation"
    elif summary.targets_left:  # the targets made so far are kept in the run folder too
        where = f"{summary.steps} ({summary.targets_left:,} windows' targets still to refine)"
    stop.raise_stop(where, "denoiser.npz")
    if as_json:
        emit_json(summary_dict(summary))
    else:
        _print_summary(summary, out_dir)


def _check_starting_point(cfg, overrides: dict, paths: dict, resume: bool) -> None:
    """InputError for options the run's starting point rules out: a prior or denoiser
    settings beside --init-from, and on --resume a path in ``paths`` (option -> path or None:
    --prior, --init-from, --body-model) other than the run's own."""
    if cfg.init_from is not None and paths["--prior"] is not None:
        raise InputError("--init-from brings its own prior: drop --prior")
    given = [f"--{k.replace('_', '-')}" for k in ("lam", "obs_unit", "input_window")
             if overrides.get(k) is not None]  # fmt: skip
    if cfg.init_from is not None and given:
        raise InputError(
            f"{', '.join(given)}: the denoiser --init-from starts from keeps its own settings"
        )
    if resume:
        saved = {"--prior": cfg.prior, "--init-from": cfg.init_from,
                 "--body-model": cfg.body_model}  # fmt: skip
        refuse_changes_on_resume(
            {k: (v, v is not None and same_path(v, saved[k])) for k, v in paths.items()}
        )


class FitReporter:
    """fit-dataset's progress: a bar per stage (fitting, refining targets, distilling), and
    off a terminal (batch jobs' logs) a line every 5 % of a stage."""

    LABELS = {"fit": "fitting", "targets": "refining targets", "distill": "distilling"}

    def __init__(self, progress):
        self.progress = progress
        self.tasks: dict[str, object] = {}
        self.logged: dict[str, int] = {}

    def __call__(self, info: dict) -> None:
        stage = info["stage"]
        label = self.LABELS[stage]
        if stage not in self.tasks:
            self.tasks[stage] = self.progress.add_task(label, total=info["steps"], info="")
        if stage == "fit":
            text = (
                f"loss {info['loss']:.2f} rec {info['rec']:.2f} "
                f"kl_z {info['kl_z']:.2f} err {info['err_cm']:.1f} cm"
            )
        elif stage == "distill":
            text = f"loss {info['loss']:.3f} state {info['state']:.3f}"
        else:
            text = "windows"
        self.progress.update(self.tasks[stage], total=info["steps"], completed=info["step"],
                             info=text)  # fmt: skip
        part = 20 * info["step"] // max(1, info["steps"])
        if not console.is_terminal and part > self.logged.get(stage, 0):
            self.logged[stage] = part
            console.print(f"{label} {info['step']}/{info['steps']} {text}")


def _print_summary(summary, out_dir) -> None:
    elbo = (
        f"loss {summary.first_loss:.3f} -> {summary.last_loss:.3f}"
        if not math.isnan(summary.first_loss)  # ELBO steps were taken in this run
        else "no ELBO steps in this run"
    )
    console.print(
        f"fitted {summary.steps} steps on {summary.windows} windows in {summary.seconds:.0f} s; "
        f"{elbo}; denoiser in {out_dir}"
    )
    if summary.distill_steps:
        console.print(
            f"amortised refinement: {summary.distill_steps} steps, loss "
            f"{summary.distill_first_loss:.3f} -> {summary.distill_last_loss:.3f}"
        )


def parse_lengths(text: str) -> list[int]:
    """``--short-windows 6,10,16`` -> [6, 10, 16]; InputError naming the option otherwise."""
    try:
        lengths = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        lengths = []
    if not lengths:
        raise InputError(f"--short-windows must be comma-separated frame counts such as 6,10,16, "
                         f"got {text!r}")  # fmt: skip
    return lengths


COMMANDS = [fit_dataset]
