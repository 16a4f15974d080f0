"""Unsupervised denoising learning on a set of noisy files (paper Sec. 4.2): ``mdvae
fit-dataset``'s run — its settings, starting point, checkpoints, resume and amortised
refinement. The ELBO loop itself is ``infer.elbo_fit`` (shared with ``mdvae denoise --optimize``).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError, diverged
from mdvae_cli.fileio import expand_inputs
from mdvae_cli.infer.elbo_fit import fit_denoiser
from mdvae_cli.model.checkpoint import load_checkpoint, save_checkpoint
from mdvae_cli.model.config import (
    check_config_keys,
    require_bool,
    require_int,
    require_number,
    require_seed,
)
from mdvae_cli.model.denoiser import Denoiser, DenoiserConfig, load_denoiser, save_denoiser
from mdvae_cli.model.prior_model import load_prior
from mdvae_cli.train.corpus import outside
from mdvae_cli.train.distill import DistillConfig, distill
from mdvae_cli.train.distill_targets import distill_targets, windows_left
from mdvae_cli.train.guards import (
    check_device,
    check_run_folder,
    checkpoint_to_resume,
    pick_device,
    refuse_to_overwrite,
    weights_are_finite,
)
from mdvae_cli.train.noisy_windows import load_noisy_windows
from mdvae_cli.train.run_state import (
    optimizer_from_tensors,
    optimizer_to_tensors,
    restore_rng,
    rng_tensors,
    seeded_run,
)
from mdvae_cli.weights import default_weights


@dataclass
class FitConfig:
    """Settings of an unsupervised denoising-learning run (saved as ``config.json``).

    ``epochs`` of ELBO fitting (paper Sec. 4.2), then ``distill.epochs`` of amortised
    refinement (``train.distill``; 0 = off). ``init_from``: start from this denoiser's networks
    (checkpoint or fit-dataset folder; its prior and denoiser settings come with it) instead
    of new ones on ``prior``. ``mirror_augment``: also fit to every file's left-right mirror
    image (twice the windows). ``short_windows``: also fit to short takes — clips of these
    lengths (frames at 30 Hz, x0 included) cut from the noisy files, ``short_share`` as many
    in all as there are full windows (split evenly over the lengths): the networks then learn
    what a take of a few frames looks like instead of meeting it for the first time at
    denoising (docs/model.md, "Short takes"). ``holes``: also fit to copies of this share
    of the takes with random holes (whole frames and limbs missing; 1 = every take once more),
    and let the networks read where the holes are (``DenoiserConfig.reads_holes``): they read
    placeholders there while the likelihood still scores the noisy frames hidden, so filling
    the holes is what they are fitted to (``train.noisy_windows``).
    """

    data: list[str] = field(default_factory=list)
    prior: str | None = None
    window: int = 60
    stride: int = 10
    batch_size: int = 64
    epochs: int = 8
    lr: float = 3e-3
    lr_final: float = 3e-4
    seed: int = 0
    body_model: str | None = None
    device: str = "auto"
    init_from: str | None = None
    mirror_augment: bool = False
    short_windows: list[int] = field(default_factory=list)
    short_share: float = 0.25
    holes: float = 0.0
    denoiser: DenoiserConfig = field(default_factory=DenoiserConfig)
    distill: DistillConfig = field(default_factory=DistillConfig)

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """InputError naming the first invalid setting (its ``mdvae fit-dataset`` option).
        Run again after changing fields. ``epochs`` may be 0 (distillation only)."""
        for name, low in (("window", 1), ("stride", 1), ("batch_size", 1), ("epochs", 0)):
            require_int(f"--{name.replace('_', '-')}", getattr(self, name), low)
        require_bool("--mirror-augment", self.mirror_augment)
        if not isinstance(self.short_windows, (list, tuple)):
            raise InputError(
                f"--short-windows must be a list of lengths, got {self.short_windows!r}"
            )
        for n in self.short_windows:
            require_int("--short-windows", n, 2)
            if n > self.window:
                raise InputError(f"--short-windows {n} is not shorter than --window {self.window}")
        require_number("--short-share", self.short_share, 0.0, 4.0, open_low=True)
        require_number("--holes", self.holes, 0.0, 4.0)
        require_seed("--seed", self.seed)
        require_number("--lr", self.lr, 0.0, open_low=True)
        require_number("--lr-final", self.lr_final, 0.0)
        check_device(self.device)
        self.denoiser.validate()
        self.distill.validate()

    def to_dict(self) -> dict:
        d = asdict(self)
        d["denoiser"] = self.denoiser.to_dict()
        d["distill"] = self.distill.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict, legacy: bool = True, source: str = "config") -> FitConfig:
        """Settings from a JSON object; as :meth:`TrainConfig.from_dict` (unknown keys, values
        of the wrong kind or out of range are InputErrors starting with ``source``)."""
        check_config_keys(cls, d, source, nested=not legacy)
        d = dict(d)
        try:
            d["denoiser"] = DenoiserConfig.from_dict(d.get("denoiser", {}), legacy)
            d["distill"] = DistillConfig(**d.get("distill", {}))
            return cls(**d)
        except (ValueError, TypeError) as exc:
            raise InputError(f"{source} is unreadable ({exc})") from None


@dataclass
class FitSummary:
    out_dir: str
    steps: int
    first_loss: float
    last_loss: float
    seconds: float
    windows: int
    distill_steps: int = 0
    distill_first_loss: float = math.nan
    distill_last_loss: float = math.nan
    #: whether a stop asked for (``stop_requested``) ended the run
    interrupted: bool = False
    #: windows whose distillation targets are still to be made (a run stopped making them)
    targets_left: int = 0


#: Adam's state and the random generators' where the ELBO fit stands (fit-dataset --resume)
RESUME_FILE = "resume.npz"


@seeded_run  # with cfg.seed; the caller's random streams (CPU, GPUs) as they were
def fit_dataset(
    cfg: FitConfig,
    out_dir: Path,
    resume: bool = False,
    progress: Callable[[dict], None] | None = None,
    max_steps: int | None = None,
    overwrite: bool = False,
    stop_requested: Callable[[], bool] | None = None,
) -> FitSummary:
    """Fit the inference networks to noisy files (no clean data) and save ``denoiser.npz``.

    Starts from a prior (``cfg.prior``, default the shipped one), from another denoiser
    (``cfg.init_from``) or, with ``resume``, from the denoiser already in ``out_dir``. Then
    ``cfg.epochs`` of ELBO steps and ``cfg.distill.epochs`` of amortised refinement, whose
    targets are kept in ``out_dir`` (``distill_targets.npz``) for a resumed run. ``progress``
    gets every step's dict with "stage": "fit", "targets" or "distill". ``max_steps`` caps
    the ELBO steps (tests; 0 = none). A new run (not ``resume``) into a folder that holds a
    denoiser is refused unless ``overwrite`` (distillation targets there made from the same
    networks are reused). ``stop_requested()`` true after a step (a Ctrl-C the command
    caught) saves where the run stands and ends it (``interrupted``): ``resume`` continues it,
    the ELBO fit exactly. ``cfg`` is validated here (fields may have changed since
    it was made). A loss or weights that stop being finite end the run with InputError, and
    such weights are never saved.
    """
    cfg.validate()
    if max_steps is not None:
        require_int("max_steps", max_steps, 0)
    start = time.time()
    out_dir = Path(out_dir)
    if resume and overwrite:
        raise InputError(
            "--resume continues the run in the folder, --overwrite replaces it: give one"
        )
    if not resume:  # a denoiser there: --overwrite replaces it; a prior's run: never
        refuse_to_overwrite(out_dir, "fit-dataset", "--overwrite", replace=overwrite)
    check_run_folder(out_dir)
    device = pick_device(cfg.device)
    denoiser, done, distilled, history = _starting_point(cfg, out_dir, resume)
    if cfg.holes > 0:
        denoiser.add_hole_reader()
    body = BodyModel(load_body_model(cfg.body_model))
    data = [Path(p) for p in cfg.data]
    files = outside([f for f, _ in expand_inputs(data, by_target=True)], out_dir)
    if not files:
        raise InputError("no noisy .npz files found in the given paths")
    groups = load_noisy_windows(
        files, denoiser, body, cfg.window, cfg.stride, cfg.mirror_augment,
        tuple(cfg.short_windows), cfg.short_share, cfg.seed, cfg.holes,
    )  # fmt: skip
    out_dir.mkdir(parents=True, exist_ok=True)  # the inputs are good: the run folder is made
    (out_dir / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2) + "\n")
    total = math.ceil(sum(len(g) for g in groups) / cfg.batch_size) * cfg.epochs
    steps = max(0, total - done)
    if max_steps is not None:
        steps = min(steps, max_steps)
    if steps > 0:  # new ELBO steps: any distillation so far was of other networks
        distilled = 0
    denoiser.to(device)
    body.to(device)
    opt = torch.optim.Adam(denoiser.trainable_parameters(), lr=cfg.lr)
    if resume and steps > 0:
        _resume_state(out_dir / RESUME_FILE, done, opt, device)

    def save(elbo_steps: int, distill_steps: int, **extra) -> None:
        if not weights_are_finite(denoiser):
            what, step = (
                ("distillation", distill_steps) if distill_steps else ("training", elbo_steps)
            )
            raise diverged(what, step, "weights not finite")
        meta = {
            "fit_config": cfg.to_dict(),
            "steps": elbo_steps,
            "distill_steps": distill_steps,
            **({"started_from": history} if history else {}),
            **extra,
        }
        denoiser.cpu()
        save_denoiser(out_dir / "denoiser.npz", denoiser, meta)
        denoiser.to(device)
        if not distill_steps:  # where the ELBO fit stands, for --resume
            tensors, groups = optimizer_to_tensors(opt)
            state = {"kind": "mdvae-fit-resume", "steps": elbo_steps, "optimizer": groups}
            save_checkpoint(out_dir / RESUME_FILE, {**tensors, **rng_tensors(device)}, state)

    losses = fit_denoiser(
        denoiser,
        groups,
        body,
        steps,
        cfg.lr,
        cfg.batch_size,
        seed=cfg.seed,
        progress=_staged(progress, "fit"),
        device=device,
        lr_final=cfg.lr_final,
        checkpoint=lambda step: save(step, 0),
        first_step=done,
        total_steps=total,
        optimizer=opt,
        stop_requested=stop_requested,
    )
    done += len(losses) if losses else steps  # fewer when stopped
    last = {"final_loss": losses[-1]} if losses else {}
    save(done, distilled, **last)
    asked = stop_requested or (lambda: False)
    d_losses, left = [], 0
    if cfg.distill.epochs > 0 and not asked():
        targets = distill_targets(
            denoiser, groups, cfg.distill.refine_steps, out_dir, steps > 0, distilled > 0,
            _staged(progress, "targets"), asked,
        )  # fmt: skip
        left = windows_left(targets, groups)  # > 0: stopped while making them
        if left == 0 and not asked():
            d_losses = distill(
                denoiser, groups if len(groups) > 1 else groups[0],
                targets if len(groups) > 1 else targets[0], cfg.distill, cfg.seed, distilled,
                _staged(progress, "distill"), lambda step: save(done, step),
                stop_requested=asked,
            )  # fmt: skip
            distilled += len(d_losses)
            if d_losses:
                save(done, distilled, **last, final_distill_loss=d_losses[-1])
    denoiser.cpu()
    with open(out_dir / "log.jsonl", "a") as fh:
        record = {
            "steps": done,
            "losses": losses[:: max(1, len(losses) // 200)],
            "distill_steps": distilled,
            "distill_losses": d_losses[:: max(1, len(d_losses) // 200)],
            "seconds": time.time() - start,
            **({"interrupted": True} if asked() else {}),
        }
        fh.write(json.dumps(record) + "\n")
    return FitSummary(
        str(out_dir),
        done,
        losses[0] if losses else math.nan,
        losses[-1] if losses else math.nan,
        time.time() - start,
        sum(len(g) for g in groups),
        distilled,
        d_losses[0] if d_losses else math.nan,
        d_losses[-1] if d_losses else math.nan,
        bool(asked()),
        left,
    )


def _resume_state(path: Path, steps: int, opt: torch.optim.Optimizer, device) -> None:
    """Load Adam's state and the generators' saved with the denoiser after ``steps`` ELBO
    steps, so that the resumed fit takes the steps the whole run would have taken. A run
    saved without them (older versions) resumes with a new Adam."""
    if not path.exists():
        return
    tensors, meta = load_checkpoint(path)
    if meta.get("kind") != "mdvae-fit-resume" or meta.get("steps") != steps:
        return  # not the state of the denoiser being resumed
    opt.load_state_dict(optimizer_from_tensors(tensors, meta["optimizer"]))
    restore_rng(tensors, device)


def _starting_point(cfg: FitConfig, out_dir: Path, resume: bool) -> tuple[Denoiser, int, int, dict]:
    """The denoiser a run starts from, the ELBO and distillation steps it has taken, and what
    the networks had been through before the run (``init_from``: its path and record)."""
    if resume:
        denoiser, meta = load_denoiser(
            checkpoint_to_resume(out_dir, "denoiser.npz"), keep_rng=False
        )
        steps, distilled = int(meta.get("steps", 0)), int(meta.get("distill_steps", 0))
        return denoiser, steps, distilled, meta.get("started_from", {})
    if cfg.init_from:
        denoiser, meta = load_denoiser(cfg.init_from, keep_rng=False)
        cfg.denoiser = denoiser.cfg
        keep = ("fit_config", "steps", "distill_steps", "started_from")
        return denoiser, 0, 0, {"path": cfg.init_from, **{k: meta[k] for k in keep if k in meta}}
    prior, _ = load_prior(cfg.prior if cfg.prior else default_weights("prior"), keep_rng=False)
    return Denoiser(prior, cfg.denoiser), 0, 0, {}


def _staged(progress: Callable[[dict], None] | None, stage: str) -> Callable[[dict], None] | None:
    """A progress callback that labels the stage."""
    if progress is None:
        return None
    return lambda info: progress({**info, "stage": stage})
