"""``mdvae train-prior`` (what it shares with ``fit-dataset``: ``cli.train_shared``)."""

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
    StepReporter,
    StopAfterStep,
    apply_overrides,
    note_skipped_data,
    refuse_changes_on_resume,
    run_options,
    same_config,
    same_path,
    start_config,
    summary_dict,
)
from mdvae_cli.errors import InputError


@click.command("train-prior")
@click.argument("data", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "-o",
    "--out",
    "run_dir",
    required=True,
    type=OutputPath(path_type=Path),
    help="Run folder: config.json, best.npz/.json, last.npz/.json, log.jsonl.",
)
@click.option(
    "--split",
    "split_file",
    type=click.Path(path_type=Path),
    help="JSON split file {train: [...], val: [...]} of paths relative to it.",
)
@click.option(
    "--window",
    type=click.IntRange(min=1),
    help="Frames per training window at 30 Hz [default: 60].",
)
@click.option(
    "--stride",
    type=click.IntRange(min=1),
    help="Frames between window starts [default: 10].",
)
@click.option(
    "--batch-size",
    type=click.IntRange(min=1),
    help="Windows per step (per process) [default: 64].",
)
@click.option(
    "--epochs",
    type=click.IntRange(min=1),
    help="Passes over the training windows [default: 40].",
)
@click.option(
    "--lr",
    type=POSITIVE,
    help="Adam learning rate (> 0, cosine-decayed) [default: 1e-3].",
)
@click.option(
    "--lr-warmup",
    "lr_warmup_steps",
    type=click.IntRange(min=0),
    help="Steps of linear learning-rate warm-up before the cosine decay (0 = none; for large "
    "batches at a large --lr) [default: 0].",
)
@click.option(
    "--kl-warmup",
    "kl_warmup_steps",
    type=click.IntRange(min=0),
    help="KL warm-up steps (0 = none) [default: 1500].",
)
@click.option(
    "--kl-max",
    type=NON_NEGATIVE,
    help="Final KL weight after warm-up (>= 0; 1 = the ELBO) [default: 1].",
)
@click.option(
    "--body-weight",
    type=NON_NEGATIVE,
    help="Weight of the mesh/joint term, per cm² (>= 0; 0 = off) [default: 0.1].",
)
@click.option(
    "--recon-weight",
    type=POSITIVE,
    help="1/sigma_x^2 of the decoder Gaussian in normalised units (> 0; 1 = N(mu, I)); larger "
    "puts more information in the latents and reconstructs more exactly [default: 1].",
)
@click.option(
    "--velocity-weight",
    type=NON_NEGATIVE,
    help="Scales the reconstruction weight of the velocity columns (>= 0; they are redundant "
    "with the positions and noisy; the body term does not see them) [default: 1].",
)
@click.option(
    "--init-from",
    type=click.Path(path_type=Path, exists=True),
    help="Start from this prior checkpoint (weights and normaliser): fine-tuning.",
)
@click.option(
    "--velocity-std-scale",
    type=POSITIVE,
    help="Widen the velocities' normalisation scale by this factor (> 0), giving them less "
    "weight in the reconstruction [default: 1].",
)
@click.option(
    "--train-only",
    type=click.Choice(["all", "encoder", "prior"]),
    help="Train one network with --init-from, the other two frozen: 'encoder' keeps "
    "sampling unchanged (e.g. with a larger --recon-weight); 'prior' keeps the decoder and "
    "the encoder, fitting the prior network alone to the encoder's posteriors [default: all].",
)
@click.option("--latent-dim", type=click.IntRange(min=1), help="z_t width [default: 32].")
@click.option(
    "--hidden-dim",
    type=click.IntRange(min=1),
    help="Recurrent state width [default: 128].",
)
@click.option(
    "--decoder-z-skip/--no-decoder-z-skip",
    default=None,
    help="Decoder head reads z_t beside its recurrent state [default: on for new runs].",
)
@click.option(
    "--encoder-x-skip/--no-encoder-x-skip",
    default=None,
    help="Encoder head reads x_t beside the backward summary of x_{t:T} "
    "[default: on for new runs].",
)
@click.option(
    "--encoder-reads-decoder/--no-encoder-reads-decoder",
    default=None,
    help="Encoder also reads the decoder's state after z_{1:t-1} [default: on for new runs].",
)
@click.option(
    "--val-every",
    "val_every_epochs",
    type=click.IntRange(min=1),
    help="Validate and write checkpoints every this many epochs (and at the end) [default: 1].",
)
@click.option(
    "--cuda-graph/--no-cuda-graph",
    default=None,
    help="On a GPU, capture the training step once as a CUDA graph and replay it (the step "
    "is bound by kernel launches there); no effect on a CPU or under torchrun [default: on].",
)
@click.option(
    "--mirror-augment/--no-mirror-augment",
    default=None,
    help="Also train on the left-right mirror image of every training motion: twice the "
    "windows, a body prior closer to symmetric (validation stays unmirrored) [default: off].",
)
@click.option(
    "--speeds",
    type=str,
    metavar="LIST",
    help="Time-warp augmentation: also train on every motion played at these speeds, "
    "comma-separated (e.g. 0.8,1,1.25; each in 0.25-4; 1 = as captured) [default: 1].",
)
@click.option(
    "--data-fraction",
    type=click.FloatRange(min=0.0, max=1.0, min_open=True),
    help="Train on a seeded subset of whole training files holding this share of the "
    "frames (data-scaling runs) [default: 1].",
)
@click.option(
    "--val-split",
    "val_splits",
    multiple=True,
    help="Split-file list whose windows choose the best checkpoint; repeat for several "
    "(e.g. --val-split val --val-split unseen_val) [default: val].",
)
@click.option(
    "--resume",
    is_flag=True,
    help="Continue the run in the -o folder from its last.npz (where it stopped: the end of "
    "an epoch, or the step a first Ctrl-C / SIGTERM let it finish): with the same settings it "
    "ends with exactly the weights of an uninterrupted run (one process).",
)
@click.option(
    "--max-steps",
    type=click.IntRange(min=1),
    help="Stop once the run has taken this many steps in all, counting those before a "
    "--resume (smoke runs).",
)
@click.option(
    "--max-minutes",
    type=click.FloatRange(min=0.0, min_open=True),
    help="Stop after the first step that ends past this many minutes of wall time (a GPU "
    "lent for minutes): the run validates, saves, and --resume continues it exactly.",
)
@run_options
@body_model_option
@handle_errors
def train_prior(
    data, run_dir, split_file, config_file, resume, max_steps, max_minutes, threads, body_model,
    as_json, **overrides,
) -> None:  # fmt: skip
    """Train the Motion-DVAE prior on clean AMASS-layout motion files or folders.

    Motions are resampled to 30 Hz and cut into windows; the state normaliser is fitted on the
    training split. Works on CUDA when available, and distributed under
    `torchrun --nproc_per_node N -m mdvae_cli.cli.main train-prior ...` (DDP).

    \b
    Example:
      mdvae train-prior data/cmu_amass --split data/cmu_amass/split.json -o runs/prior
    """
    import torch

    from mdvae_cli.train.train_config import TrainConfig
    from mdvae_cli.train.train_prior import train_prior as run

    if threads is not None:
        torch.set_num_threads(threads)
    cfg = start_config(TrainConfig, run_dir, resume, config_file, data)
    if resume:  # the command as first run may be given again; a change is refused
        init_from = overrides["init_from"]
        now = {k for k, v in overrides.items() if v not in (None, ())}  # options given now
        same_file = config_file and same_config(TrainConfig, config_file, cfg, now)
        refuse_changes_on_resume({
            "--split": (split_file, split_file and same_path(split_file, cfg.split_file)),
            "--body-model": (body_model, body_model and same_path(body_model, cfg.body_model)),
            "--config": (config_file, same_file),
            "--init-from": (init_from, init_from and same_path(init_from, cfg.init_from)),
        })  # fmt: skip
    if not resume:
        cfg.data = [str(p) for p in data]
        if split_file is not None:
            cfg.split_file = str(split_file)
        if body_model is not None:
            cfg.body_model = str(body_model)
    note_skipped_data(cfg.data)  # what the trainer skips: broken links, other formats
    if overrides.get("init_from") is not None:
        overrides["init_from"] = str(overrides["init_from"])
    if overrides.get("speeds") is not None:
        overrides["speeds"] = parse_speeds(overrides["speeds"])
    overrides["val_splits"] = list(overrides["val_splits"]) or None
    apply_overrides(
        cfg,
        overrides,
        nested={
            "latent_dim": "model",
            "hidden_dim": "model",
            "decoder_z_skip": "model",
            "encoder_reads_decoder": "model",
            "encoder_x_skip": "model",
        },
        resume=resume,
    )
    with progress_bar() as progress, StopAfterStep() as stop:
        summary = run(
            cfg,
            run_dir,
            resume=resume,
            progress=StepReporter(progress, "training"),
            max_steps=max_steps,
            max_minutes=max_minutes,
            stop_requested=stop,
        )
    stop.raise_stop(summary.steps)
    if as_json:
        emit_json(summary_dict(summary))
        return
    best = summary.best_val_loss
    best_text = f"{best:.4f}" if math.isfinite(best) else "none (not finite)"
    which = "val" if summary.val_windows else "train"  # no validation windows: training loss
    console.print(
        f"trained {summary.steps} steps in {summary.seconds:.0f} s on {summary.train_windows} "
        f"windows; best {which} loss {best_text}; run in {summary.run_dir}"
    )


def parse_speeds(text: str) -> list[float]:
    """``--speeds 0.8,1,1.25`` -> [0.8, 1.0, 1.25]; InputError naming the option otherwise."""
    try:
        speeds = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        speeds = []
    if not speeds:
        raise InputError(
            f"--speeds must be comma-separated numbers such as 0.8,1,1.25, got {text!r}"
        )
    return speeds


COMMANDS = [train_prior]
