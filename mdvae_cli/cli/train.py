"""``mdvae train-prior`` and ``mdvae fit-dataset``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import click

from mdvae_cli.cli.common import body_model_option, console, handle_errors, progress_bar
from mdvae_cli.errors import InputError


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
        if not console.is_terminal and info["step"] % 50 == 0:  # logs of batch jobs
            console.print(f"step {info['step']}/{total} ep {info['epoch'] + 1} {terms}")


def start_config(cls, run_dir: Path, resume: bool, config_file: Path | None):
    """The config to run: the run's own (resume), a given file, or the defaults."""
    if resume:
        path = Path(run_dir) / "config.json"
        if not path.exists():
            raise InputError(f"nothing to resume: {path} not found")
    else:
        path = config_file
    if path is None:
        return cls()
    try:
        return cls.from_dict(json.loads(Path(path).read_text()))
    except (OSError, ValueError, TypeError) as exc:
        raise InputError(f"config {path} is unreadable ({exc})") from None


def apply_overrides(
    cfg, overrides: dict, nested: dict[str, str | tuple[str, str]], resume: bool
) -> None:
    """Set the options given on the command line; ``nested`` maps an option to the sub-config
    holding it (same field name) or to (sub-config, field).

    On resume, options that would change the network's shape are refused.
    """
    for key, value in overrides.items():
        if value is None:
            continue
        where = nested.get(key)
        sub, name = (where, key) if where is None or isinstance(where, str) else where
        target = cfg if sub is None else getattr(cfg, sub)
        if resume and sub == "model" and getattr(target, name) != value:
            raise InputError(f"--{key.replace('_', '-')} cannot change when resuming a run")
        setattr(target, name, value)


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
@click.option("--kl-max", type=float, help="Final KL weight after warm-up (1 = the ELBO) [1].")
@click.option("--body-weight", type=float, help="Weight of the mesh/joint term, per cm² [0.1].")
@click.option(
    "--recon-weight",
    type=float,
    help="1/sigma_x^2 of the decoder Gaussian in normalised units (1 = N(mu, I)); larger "
    "puts more information in the latents and reconstructs more exactly [1].",
)
@click.option(
    "--velocity-weight",
    type=float,
    help="Scales the reconstruction weight of the velocity columns (they are redundant with "
    "the positions and noisy; the body term does not see them) [1].",
)
@click.option(
    "--init-from",
    type=click.Path(path_type=Path, exists=True),
    help="Start from this prior checkpoint (weights and normaliser): fine-tuning.",
)
@click.option(
    "--velocity-std-scale",
    type=float,
    help="Widen the velocities' normalisation scale by this factor, giving them less "
    "weight in the reconstruction [1].",
)
@click.option(
    "--train-only",
    type=click.Choice(["all", "encoder", "prior"]),
    help="Train one network with --init-from, the other two frozen: 'encoder' keeps "
    "sampling unchanged (e.g. with a larger --recon-weight); 'prior' keeps the decoder and "
    "the encoder, fitting the prior network alone to the encoder's posteriors [all].",
)
@click.option("--latent-dim", type=int, help="z_t width [32].")
@click.option("--hidden-dim", type=int, help="Recurrent state width [128].")
@click.option(
    "--decoder-z-skip/--no-decoder-z-skip",
    default=None,
    help="Decoder head reads z_t beside its recurrent state [on for new runs].",
)
@click.option(
    "--encoder-x-skip/--no-encoder-x-skip",
    default=None,
    help="Encoder head reads x_t beside the backward summary of x_{t:T} [on for new runs].",
)
@click.option(
    "--encoder-reads-decoder/--no-encoder-reads-decoder",
    default=None,
    help="Encoder also reads the decoder's state after z_{1:t-1} [on for new runs].",
)
@click.option(
    "--mirror-augment/--no-mirror-augment",
    default=None,
    help="Also train on the left-right mirror image of every training motion: twice the "
    "windows, a body prior closer to symmetric (validation stays unmirrored) [off].",
)
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
    cfg = start_config(TrainConfig, run_dir, resume, config_file)
    if not resume:
        cfg.data = [str(p) for p in data]
        if split_file is not None:
            cfg.split_file = str(split_file)
        if body_model is not None:
            cfg.body_model = str(body_model)
    if overrides.get("init_from") is not None:
        overrides["init_from"] = str(overrides["init_from"])
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


@click.command("fit-dataset")
@click.argument("noisy", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "-o",
    "--out",
    "out_dir",
    required=True,
    type=click.Path(path_type=Path),
    help="Denoiser folder: config.json, denoiser.npz/.json, log.jsonl.",
)
@click.option(
    "--prior",
    "prior_path",
    type=click.Path(path_type=Path),
    help="Prior checkpoint or train-prior run folder (default: the shipped prior).",
)
@click.option(
    "--config",
    "config_file",
    type=click.Path(path_type=Path, exists=True),
    help="A config.json to start from; options given here override it.",
)
@click.option(
    "--lam",
    type=float,
    help="lambda of the IG(lam/2, lam/2) noise prior: large = "
    "Gaussian noise, small = heavy-tailed (outliers, video) [10].",
)
@click.option("--obs-unit", type=float, help="Metres per observation unit (noise scale) [0.08].")
@click.option(
    "--input-window",
    type=int,
    help="Savitzky-Golay window (frames, odd; 0 = off) through which the inference networks "
    "read the noisy motion; the likelihood always scores the raw observations [11].",
)
@click.option("--window", type=int, help="Frames per window at 30 Hz [60].")
@click.option("--stride", type=int, help="Frames between window starts [10].")
@click.option("--batch-size", type=int, help="Windows per step [64].")
@click.option("--epochs", type=int, help="Passes over the windows [8].")
@click.option("--lr", type=float, help="Adam learning rate, cosine-decayed to --lr-final [3e-3].")
@click.option("--lr-final", type=float, help="Final learning rate [3e-4].")
@click.option("--seed", type=int, help="Random seed [0].")
@click.option("--device", help="cpu, cuda, cuda:N or auto [auto].")
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
    "the result in one pass; 0 = off [0].",
)
@click.option("--distill-lr", type=float, help="Learning rate of --distill-epochs [1e-3].")
@click.option(
    "--distill-refine-steps",
    type=click.IntRange(min=1),
    help="Refinement steps per window for --distill-epochs' targets [50].",
)
@click.option(
    "--mirror-augment/--no-mirror-augment",
    default=None,
    help="Also fit to the left-right mirror image of every noisy file: twice the windows "
    "(still no clean data) [off].",
)
@click.option("--resume", is_flag=True, help="Continue from OUT/denoiser.npz.")
@click.option("--max-steps", type=int, default=None, help="Stop after this many ELBO steps.")
@click.option("--threads", type=int, default=None, help="CPU threads for torch.")
@body_model_option
@handle_errors
def fit_dataset(
    noisy,
    out_dir,
    prior_path,
    config_file,
    init_from,
    resume,
    max_steps,
    threads,
    body_model,
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

    from mdvae_cli.fit.fit_dataset import FitConfig
    from mdvae_cli.fit.fit_dataset import fit_dataset as run

    if threads:
        torch.set_num_threads(threads)
    cfg = start_config(FitConfig, out_dir, resume, config_file)
    if not resume:
        cfg.data = [str(p) for p in noisy]
        if prior_path is not None:
            cfg.prior = str(prior_path)
        if init_from is not None:
            cfg.init_from = str(init_from)
        if body_model is not None:
            cfg.body_model = str(body_model)
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
    if cfg.init_from is not None and prior_path is not None:
        raise InputError("--init-from brings its own prior: drop --prior")
    with progress_bar() as progress:
        tasks: dict[str, object] = {}
        labels = {"fit": "fitting", "targets": "refining targets", "distill": "distilling"}
        logged: dict[str, int] = {}

        def tick(info: dict) -> None:
            stage = info["stage"]
            if stage not in tasks:
                tasks[stage] = progress.add_task(labels[stage], total=info["steps"], info="")
            if stage == "fit":
                text = (
                    f"loss {info['loss']:.2f} rec {info['rec']:.2f} "
                    f"kl_z {info['kl_z']:.2f} err {info['err_cm']:.1f} cm"
                )
            elif stage == "distill":
                text = f"loss {info['loss']:.3f} state {info['state']:.3f}"
            else:
                text = "windows"
            progress.update(tasks[stage], total=info["steps"], completed=info["step"], info=text)
            part = 20 * info["step"] // max(1, info["steps"])
            if not console.is_terminal and part > logged.get(stage, 0):  # batch jobs' logs
                logged[stage] = part  # a line every 5 % of a stage
                console.print(f"{labels[stage]} {info['step']}/{info['steps']} {text}")

        summary = run(cfg, out_dir, resume=resume, progress=tick, max_steps=max_steps)
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


COMMANDS = [train_prior, fit_dataset]
