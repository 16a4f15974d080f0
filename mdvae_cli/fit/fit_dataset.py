"""Unsupervised denoising learning (paper Sec. 4.2) and optimisation mode.

The same loop serves ``mdvae fit-dataset`` (many noisy files, many epochs, checkpoints) and
``mdvae denoise --optimize N`` (a few iterations on the very windows being cleaned).
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
from mdvae_cli.errors import InputError
from mdvae_cli.fileio import expand_inputs
from mdvae_cli.fit.checkpoint import load_checkpoint, save_checkpoint
from mdvae_cli.fit.data import MODEL_FPS
from mdvae_cli.fit.train_prior import pick_device
from mdvae_cli.fit.window_groups import WindowGroup, make_windows
from mdvae_cli.model.config import ModelConfig
from mdvae_cli.model.denoiser import Denoiser, DenoiserConfig
from mdvae_cli.model.prior_model import PriorModel, load_prior, model_tensors
from mdvae_cli.motion.npz_io import load_motion
from mdvae_cli.motion.resample import resample_motion
from mdvae_cli.weights import default_weights


@dataclass
class FitConfig:
    """Settings of an unsupervised denoising-learning run (saved as ``config.json``)."""

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
    denoiser: DenoiserConfig = field(default_factory=DenoiserConfig)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["denoiser"] = self.denoiser.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> FitConfig:
        d = dict(d)
        d["denoiser"] = DenoiserConfig.from_dict(d.get("denoiser", {}))
        return cls(**d)


def concat_groups(groups: list[WindowGroup], length: int) -> WindowGroup | None:
    """The group of windows of exactly ``length`` frames (training uses full windows only)."""
    same = [g for g in groups if g.yn.shape[1] == length]
    return same[0] if same else None


def fit_denoiser(
    denoiser: Denoiser,
    groups: list[WindowGroup],
    body: BodyModel,
    steps: int,
    lr: float,
    batch_size: int = 64,
    seed: int = 0,
    progress: Callable[[dict], None] | None = None,
    device: torch.device | None = None,
    lr_final: float | None = None,
    checkpoint: Callable[[int], None] | None = None,
    checkpoint_every: int = 200,
    sample_generator: torch.Generator | None = None,
) -> list[float]:
    """Maximise the ELBO over phi, gamma, omega for ``steps`` Adam steps on ``groups``.

    Batches cycle through a seeded permutation of all windows (each group separately, larger
    groups visited in proportion). With ``lr_final`` the learning rate decays from ``lr`` to it
    on a cosine; ``checkpoint(step)`` is called every ``checkpoint_every`` steps. One-frame
    windows (x0 alone) have nothing to fit and are left out. Returns the loss of every step.
    The ELBO's Monte-Carlo draws come from ``sample_generator`` (None: torch's global
    generator, which ``mdvae fit-dataset`` seeds).
    """
    device = device or torch.device("cpu")
    groups = [g for g in groups if g.moves]
    if not groups:
        return []
    opt = torch.optim.Adam(denoiser.trainable_parameters(), lr=lr)
    gen = torch.Generator().manual_seed(seed)
    sizes = torch.tensor([len(g) for g in groups], dtype=torch.float)
    perms = [torch.randperm(len(g), generator=gen) for g in groups]
    cursors = [0] * len(groups)
    denoiser.train()
    losses = []
    for step in range(steps):
        gi = int(torch.multinomial(sizes, 1, generator=gen)) if len(groups) > 1 else 0
        g = groups[gi]
        if cursors[gi] >= len(g):
            perms[gi] = torch.randperm(len(g), generator=gen)
            cursors[gi] = 0
        idx = perms[gi][cursors[gi] : cursors[gi] + batch_size]
        cursors[gi] += batch_size
        b = g.batch(idx)
        if lr_final is not None:
            frac = step / max(1, steps)
            for group in opt.param_groups:
                group["lr"] = lr_final + 0.5 * (lr - lr_final) * (1 + math.cos(math.pi * frac))
        w = None if b.weight is None else b.weight.to(device)
        terms = denoiser.elbo(
            b.yn.to(device), b.y3d.to(device), b.betas.to(device), body, w,
            generator=sample_generator,
        )  # fmt: skip
        opt.zero_grad(set_to_none=True)
        terms["loss"].backward()
        torch.nn.utils.clip_grad_norm_(denoiser.trainable_parameters(), 5.0)
        opt.step()
        losses.append(terms["loss"].item())
        if progress is not None:
            progress({"step": step + 1, "steps": steps, **{k: v.item() for k, v in terms.items()}})
        if checkpoint is not None and (step + 1) % checkpoint_every == 0:
            denoiser.eval()
            checkpoint(step + 1)
            denoiser.train()
    denoiser.eval()
    return losses


def save_denoiser(path: Path, denoiser: Denoiser, meta: dict) -> None:
    tensors = model_tensors(denoiser.prior, "prior/")
    for name in ("encoder", "x0_predictor", "noise_predictor"):
        tensors.update(model_tensors(getattr(denoiser, name), f"{name}/"))
    meta = {
        **meta,
        "model_config": denoiser.prior.cfg.to_dict(),
        "denoiser_config": denoiser.cfg.to_dict(),
        "kind": "mdvae-denoiser",
    }
    save_checkpoint(Path(path), tensors, meta)


def load_denoiser(path: Path | str | None = None) -> tuple[Denoiser, dict]:
    """Load a denoiser checkpoint (file, or a fit-dataset folder's ``denoiser.npz``); None
    loads the weights shipped with the package."""
    path = default_weights("denoiser") if path is None else Path(path)
    if path.is_dir():
        path = path / "denoiser.npz"
    tensors, meta = load_checkpoint(path)
    if meta.get("kind") != "mdvae-denoiser":
        raise InputError(f"{path} is not a denoiser checkpoint (train one with fit-dataset)")
    prior = PriorModel(ModelConfig.from_dict(meta["model_config"]))
    denoiser = Denoiser(prior, DenoiserConfig.from_dict(meta["denoiser_config"]))
    for prefix, module in (
        ("prior/", denoiser.prior),
        ("encoder/", denoiser.encoder),
        ("x0_predictor/", denoiser.x0_predictor),
        ("noise_predictor/", denoiser.noise_predictor),
    ):
        state = {k[len(prefix) :]: v for k, v in tensors.items() if k.startswith(prefix)}
        try:
            module.load_state_dict(state)
        except RuntimeError as exc:
            raise InputError(f"{path}: weights do not match its config ({exc})") from None
    return denoiser.eval(), meta


def load_noisy_windows(
    files: list[Path], denoiser: Denoiser, body: BodyModel, window: int, stride: int
) -> list[WindowGroup]:
    motions = [resample_motion(load_motion(f), MODEL_FPS) for f in files]
    groups = make_windows(motions, denoiser, body, window, stride)
    full = concat_groups(groups, window + 1)
    if full is None:
        raise InputError(f"no noisy motion of at least {window + 1} frames at 30 Hz found")
    return [full]


@dataclass
class FitSummary:
    out_dir: str
    steps: int
    first_loss: float
    last_loss: float
    seconds: float
    windows: int


def fit_dataset(
    cfg: FitConfig,
    out_dir: Path,
    resume: bool = False,
    progress: Callable[[dict], None] | None = None,
    max_steps: int | None = None,
) -> FitSummary:
    """Fit the inference networks to noisy files (no clean data) and save ``denoiser.npz``.

    Starts from a prior (``cfg.prior``, default the shipped one) or, with ``resume``, from the
    denoiser already in ``out_dir``.
    """
    start = time.time()
    out_dir = Path(out_dir)
    device = pick_device(cfg.device)
    torch.manual_seed(cfg.seed)
    if resume:
        denoiser, meta = load_denoiser(out_dir / "denoiser.npz")
        done = int(meta.get("steps", 0))
    else:
        prior, _ = load_prior(cfg.prior if cfg.prior else default_weights("prior"))
        denoiser, done = Denoiser(prior, cfg.denoiser), 0
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2) + "\n")
    body = BodyModel(load_body_model(cfg.body_model))
    files = [f for f, _ in expand_inputs([Path(p) for p in cfg.data])]
    if not files:
        raise InputError("no noisy .npz files found in the given paths")
    groups = load_noisy_windows(files, denoiser, body, cfg.window, cfg.stride)
    total = math.ceil(len(groups[0]) / cfg.batch_size) * cfg.epochs
    steps = max(0, total - done)
    if max_steps is not None:
        steps = min(steps, max_steps)
    denoiser.to(device)
    body.to(device)

    def save(step: int) -> None:
        meta = {"fit_config": cfg.to_dict(), "steps": done + step}
        save_denoiser(out_dir / "denoiser.npz", denoiser, meta)

    losses = fit_denoiser(
        denoiser,
        groups,
        body,
        steps,
        cfg.lr,
        cfg.batch_size,
        seed=cfg.seed + done,
        progress=progress,
        device=device,
        lr_final=cfg.lr_final,
        checkpoint=save,
    )
    denoiser.cpu()
    meta = {
        "fit_config": cfg.to_dict(),
        "steps": done + steps,
        "final_loss": losses[-1] if losses else None,
    }
    save_denoiser(out_dir / "denoiser.npz", denoiser, meta)
    with open(out_dir / "log.jsonl", "a") as fh:
        fh.write(
            json.dumps(
                {
                    "steps": done + steps,
                    "losses": losses[:: max(1, len(losses) // 200)],
                    "seconds": time.time() - start,
                }
            )
            + "\n"
        )
    return FitSummary(
        str(out_dir),
        done + steps,
        losses[0] if losses else math.nan,
        losses[-1] if losses else math.nan,
        time.time() - start,
        len(groups[0]),
    )
