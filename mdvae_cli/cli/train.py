"""``mdvae train-prior`` and ``mdvae fit-dataset``."""

from __future__ import annotations

import json
from pathlib import Path

import click

from mdvae_cli.cli.common import body_model_option, console, handle_errors, progress_bar
from mdvae_cli.errors import InputError, NotAvailableError


class StepReporter:
    """Feeds training progress dicts into a rich progress bar."""

    def __init__(self, progress, label: str):
        self.progress = progress
        self.label = label
        self.task = None

    def __call__(self, info: dict) -> None:
        if info.get("epoch_end"):
            val = info.get("val") or {}
            text = "  ".join(f"{k} {v:.3f}" for k, v in val.items())
            console.print(f"epoch {info['epoch'] + 1}: val {text}")
            return
        total = info["steps_per_epoch"] * info["epochs"]
        if self.task is None:
            self.task = self.progress.add_task(self.label, total=total, info="")
        terms = "  ".join(
            f"{k} {info[k]:.3f}" for k in ("loss", "recon", "kl", "body_cm2") if k in info
        )
        self.progress.update(
            self.task, completed=info["step"], info=f"ep {info['epoch'] + 1} {terms}"
        )


@click.command("train-prior")
@click.argument("data", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "-o",
    "--out",
    "run_dir",
    required=True,
    type=click.Path(path_type=Path),
    help="Run folder: config.json, best.npz/.json, last.npz/.json, log.jsonl.",
)
@click.option(
    "--split",
    "split_file",
    type=click.Path(path_type=Path),
    help="JSON split file {train: [...], val: [...]} of paths relative to it.",
)
@click.option(
    "--config",
    "config_file",
    type=click.Path(path_type=Path, exists=True),
    help="A config.json to start from; options given here override it.",
)
@click.option("--window", type=int, help="Frames per training window at 30 Hz [60].")
@click.option("--stride", type=int, help="Frames between window starts [10].")
@click.option("--batch-size", type=int, help="Windows per step (per process) [64].")
@click.option("--epochs", type=int, help="Passes over the training windows [40].")
@click.option("--lr", type=float, help="Adam learning rate (cosine-decayed) [1e-3].")
@click.option("--kl-warmup", "kl_warmup_steps", type=int, help="KL warm-up steps [1500].")
@click.option("--body-weight", type=float, help="Weight of the mesh/joint regulariser (per cm²) [0.1].")
@click.option("--latent-dim", type=int, help="z_t width [32].")
@click.option("--hidden-dim", type=int, help="Recurrent state width [256].")
@click.option("--seed", type=int, help="Random seed [0].")
@click.option("--device", help="cpu, cuda, cuda:N or auto [auto].")
@click.option("--resume", is_flag=True, help="Continue the run in RUN_DIR from last.npz.")
@click.option(
    "--max-steps", type=int, default=None, help="Stop after this many steps (smoke runs)."
)
@click.option("--threads", type=int, default=None, help="CPU threads for torch.")
@body_model_option
@handle_errors
def train_prior(
    data, run_dir, split_file, config_file, resume, max_steps, threads, body_model, **overrides
) -> None:
    """Train the Motion-DVAE prior on clean AMASS-layout motion files or folders.

    Motions are resampled to 30 Hz and cut into windows; the state normaliser is fitted on the
    training split. Works on CUDA when available, and distributed under
    `torchrun --nproc_per_node N -m mdvae_cli.cli.main train-prior ...` (DDP).

    \b
    Example:
      mdvae train-prior data/cmu_amass --split data/cmu_amass/split.json -o runs/prior
    """
    import torch

    from mdvae_cli.fit.train_prior import TrainConfig
    from mdvae_cli.fit.train_prior import train_prior as run

    if threads:
        torch.set_num_threads(threads)
    if resume:
        cfg_path = run_dir / "config.json"
        if not cfg_path.exists():
            raise InputError(f"nothing to resume: {cfg_path} not found")
        cfg = TrainConfig.from_dict(json.loads(cfg_path.read_text()))
    elif config_file is not None:
        cfg = TrainConfig.from_dict(json.loads(Path(config_file).read_text()))
    else:
        cfg = TrainConfig()
    if not resume:
        cfg.data = [str(p) for p in data]
        if split_file is not None:
            cfg.split_file = str(split_file)
        if body_model is not None:
            cfg.body_model = str(body_model)
        for key, value in overrides.items():
            if value is None:
                continue
            if key in ("latent_dim", "hidden_dim"):
                setattr(cfg.model, key, value)
            else:
                setattr(cfg, key, value)
    with progress_bar() as progress:
        summary = run(
            cfg,
            run_dir,
            resume=resume,
            progress=StepReporter(progress, "training"),
            max_steps=max_steps,
        )
    console.print(
        f"trained {summary.steps} steps in {summary.seconds:.0f} s on {summary.train_windows} "
        f"windows; best val loss {summary.best_val_loss:.4f}; run in {summary.run_dir}"
    )


@click.command("fit-dataset", context_settings={"ignore_unknown_options": True})
@click.argument("args", nargs=-1, type=click.UNPROCESSED)
@handle_errors
def fit_dataset(args) -> None:
    """Fit the denoiser to a folder of noisy files, unsupervised (not yet available)."""
    raise NotAvailableError("fit-dataset is not yet available in this version")


COMMANDS = [train_prior, fit_dataset]
