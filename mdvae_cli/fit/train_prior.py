"""Train the Motion-DVAE prior (paper Sec. 3.2): ELBO with KL warm-up + body-model regulariser."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch.nn.parallel import DistributedDataParallel

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError
from mdvae_cli.fit.checkpoint import (
    load_checkpoint,
    optimizer_from_tensors,
    optimizer_to_tensors,
    save_checkpoint,
)
from mdvae_cli.fit.data import WindowSet, load_windows, select_files
from mdvae_cli.fit.distributed import (
    gather_strings,
    init_distributed,
    parameter_digest,
    shutdown_distributed,
)
from mdvae_cli.fit.schedule import clipped_step, cosine_lr, set_lr
from mdvae_cli.model.config import ModelConfig
from mdvae_cli.model.losses import gaussian_kl, kl_weight
from mdvae_cli.model.prior_model import PriorModel, load_prior, model_tensors, widen_state
from mdvae_cli.motion.state import VELOCITY_DIMS, state_to_params


@dataclass
class TrainConfig:
    """Everything that defines a prior training run (saved as ``config.json``)."""

    data: list[str] = field(default_factory=list)
    split_file: str | None = None
    window: int = 60
    stride: int = 10
    batch_size: int = 64
    epochs: int = 40
    lr: float = 1e-3
    lr_final: float = 1e-4
    kl_warmup_steps: int = 1500
    kl_max: float = 1.0
    recon_weight: float = 1.0
    velocity_weight: float = 1.0
    body_weight: float = 0.1
    body_vertices: int = 256
    body_frame_stride: int = 4
    velocity_std_scale: float = 1.0
    grad_clip: float = 5.0
    seed: int = 0
    body_model: str | None = None
    device: str = "auto"
    max_val_windows: int = 512
    init_from: str | None = None
    #: "all" trains prior, decoder and encoder; "encoder" keeps the generative model (prior and
    #: decoder, hence sampling) fixed and trains only the inference network, e.g. under a
    #: sharper reconstruction weight (closing the amortisation gap of a trained prior)
    train_only: str = "all"
    #: also train on every training motion's left-right mirror image (twice the windows)
    mirror_augment: bool = False
    model: ModelConfig = field(default_factory=ModelConfig)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["model"] = self.model.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        d = dict(d)
        d["model"] = ModelConfig.from_dict(d.get("model", {}))
        return cls(**d)


def pick_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def spread_vertex_ids(num_vertices: int, count: int) -> torch.Tensor:
    """``count`` vertex ids spread evenly over the mesh (deterministic).  -> (count,)"""
    count = min(count, num_vertices)
    return torch.as_tensor(np.linspace(0, num_vertices - 1, count).round().astype(np.int64))


def body_points(
    body: BodyModel, x: torch.Tensor, betas: torch.Tensor, vertex_ids: torch.Tensor
) -> torch.Tensor:
    """Joints, markers and some vertices of states.  x: (B, T, 138), betas: (B, S) ->
    (B, T, P, 3) in metres."""
    B, T = x.shape[:2]
    p = state_to_params(x.reshape(B * T, -1))
    out = body(
        p.root_orient, p.pose_body, p.trans, betas.repeat_interleave(T, 0), vertex_ids=vertex_ids
    )
    pts = torch.cat([out.joints, out.markers, out.vertices], dim=1)
    return pts.reshape(B, T, -1, 3)


def prior_losses(
    model: PriorModel,
    forward,
    batch: WindowSet,
    body: BodyModel,
    vertex_ids: torch.Tensor,
    kl_w: float,
    body_w: float,
    frame_stride: int = 1,
    recon_w: float = 1.0,
    velocity_w: float = 1.0,
) -> dict[str, torch.Tensor]:
    """Negative ELBO (per frame) + body regulariser for a batch.

    ``recon_w`` = 1 / sigma_x^2: the decoder's Gaussian is N(mu_x, sigma_x^2 I) in normalised
    units (1 = the paper's N(mu_x, I)); ``velocity_w`` scales that weight on the velocity
    columns (a wider variance there). ``recon`` is reported unweighted.

    ``forward`` is the (possibly DDP-wrapped) ``model.dvae``. The body term is evaluated on
    every ``frame_stride``-th frame from a random phase (an unbiased, cheaper estimate).
    Returns the terms and ``loss``.
    """
    norm = model.normalizer
    xn, x0n = norm.normalize(batch.x), norm.normalize(batch.x0)
    x_mean, _, post, prior = forward(xn, x0n)
    recon = 0.5 * ((xn - x_mean) ** 2).sum(-1).mean()
    kl = gaussian_kl(post.mean, post.logvar, prior.mean, prior.logvar).mean()
    phase = int(torch.randint(frame_stride, (1,))) if frame_stride > 1 else 0
    frames = slice(phase, None, frame_stride)
    pts_hat = body_points(body, norm.denormalize(x_mean[:, frames]), batch.betas, vertex_ids)
    with torch.no_grad():
        pts_gt = body_points(body, batch.x[:, frames], batch.betas, vertex_ids)
    body_mse = ((pts_hat - pts_gt) ** 2).sum(-1).mean() * 1e4  # cm^2
    if velocity_w != 1.0:
        dims = torch.as_tensor(VELOCITY_DIMS, device=xn.device)
        sq = ((xn - x_mean) ** 2)[..., dims].sum(-1).mean()
        fit = recon + 0.5 * (velocity_w - 1.0) * sq
    else:
        fit = recon
    loss = recon_w * fit + kl_w * kl + body_w * body_mse
    return {"loss": loss, "recon": recon, "kl": kl, "body_cm2": body_mse}


@torch.no_grad()
def evaluate(
    model: PriorModel,
    data: WindowSet,
    body: BodyModel,
    vertex_ids,
    cfg: TrainConfig,
    device,
    batch_size: int = 128,
) -> dict[str, float]:
    """Validation: the full-weight loss terms with a fixed noise seed."""
    model.eval()
    torch_state = torch.random.get_rng_state()
    torch.manual_seed(1234)
    totals: dict[str, float] = {}
    n = 0
    for i in range(0, len(data), batch_size):
        batch = data.subset(torch.arange(i, min(i + batch_size, len(data))))
        batch = WindowSet(*(t.to(device) for t in (batch.x0, batch.x, batch.betas)))
        terms = prior_losses(
            model,
            model.dvae,
            batch,
            body,
            vertex_ids,
            1.0,
            cfg.body_weight,
            1,
            cfg.recon_weight,
            cfg.velocity_weight,
        )
        for k, v in terms.items():
            totals[k] = totals.get(k, 0.0) + float(v) * len(batch)
        n += len(batch)
    torch.random.set_rng_state(torch_state)
    model.train()
    return {k: v / n for k, v in totals.items()}


@dataclass
class TrainSummary:
    run_dir: str
    epochs: int
    steps: int
    best_val_loss: float
    seconds: float
    train_windows: int
    val_windows: int
    rank_digests: list[str]


def _save(run_dir: Path, name: str, model, opt, meta: dict) -> None:
    tensors = model_tensors(model)
    if opt is not None:
        t, groups = optimizer_to_tensors(opt)
        tensors.update(t)
        meta = {**meta, "optimizer": groups}
    save_checkpoint(run_dir / f"{name}.npz", tensors, meta)


TRAINABLE = ("all", "encoder", "prior")


def trainable_parameters(model: PriorModel, which: str) -> list[torch.nn.Parameter]:
    """The parameters a run trains: all networks, or one of them with the other two frozen
    ("encoder": sampling unchanged; "prior": the decoder and the posterior unchanged, the
    prior network alone fitted to the encoder's posteriors by the KL term)."""
    if which not in TRAINABLE:
        raise InputError(f"train_only must be one of {', '.join(TRAINABLE)}, got {which!r}")
    if which == "all":
        return list(model.dvae.parameters())
    trained = getattr(model.dvae, which)
    for module in (model.dvae.prior, model.dvae.decoder, model.dvae.encoder):
        module.requires_grad_(module is trained)
    return list(trained.parameters())


def init_from_prior(model: PriorModel, path: Path) -> None:
    """Start from a trained prior (fine-tuning): its weights *and* its normaliser."""
    source, _ = load_prior(path)
    try:
        model.load_state_dict(widen_state(source.state_dict(), model.state_dict()))
    except ValueError as exc:
        raise InputError(f"--init-from {path}: {exc}") from None


def train_prior(
    cfg: TrainConfig,
    run_dir: Path,
    resume: bool = False,
    progress: Callable[[dict], None] | None = None,
    max_steps: int | None = None,
) -> TrainSummary:
    """Train (or resume) a prior into ``run_dir``; works alone or under torchrun (DDP).

    ``progress`` receives a dict after every step (epoch, step, steps_per_epoch, loss terms)
    and after every epoch (with ``val``). ``max_steps`` stops early (tests).
    """
    start = time.time()
    run_dir = Path(run_dir)
    device = pick_device(cfg.device)
    dist = init_distributed(device)
    if device.type == "cuda" and dist.enabled:
        device = torch.device("cuda", dist.local_rank)
    try:
        torch.manual_seed(cfg.seed)
        body = BodyModel(load_body_model(cfg.body_model)).to(device)
        vertex_ids = spread_vertex_ids(body.v_template.shape[0], cfg.body_vertices).to(device)
        split = Path(cfg.split_file) if cfg.split_file else None
        data = [Path(p) for p in cfg.data]
        train_files = select_files(data, split, "train")
        val_files = select_files(data, split, "val")
        if not train_files:
            raise InputError("no training files found (check the data paths and split file)")
        cpu_body = BodyModel(body.data)
        train = load_windows(
            train_files, cpu_body, cfg.window, cfg.stride, mirror=cfg.mirror_augment
        )
        val = load_windows(val_files, cpu_body, cfg.window, cfg.window) if val_files else None
        if val is not None and len(val) > cfg.max_val_windows:
            pick = torch.linspace(0, len(val) - 1, cfg.max_val_windows).long()
            val = val.subset(pick)

        model = PriorModel(cfg.model)
        model.normalizer.fit(torch.cat([train.x0[:, None], train.x], dim=1))
        model.normalizer.scale_std(VELOCITY_DIMS, cfg.velocity_std_scale)
        if cfg.init_from and not resume:
            init_from_prior(model, Path(cfg.init_from))
        model.to(device)
        opt = torch.optim.Adam(trainable_parameters(model, cfg.train_only), lr=cfg.lr)
        steps_per_epoch = max(1, len(train) // (cfg.batch_size * dist.world_size))
        total_steps = steps_per_epoch * cfg.epochs
        first_epoch, step, best = 0, 0, math.inf
        if resume:
            tensors, meta = load_checkpoint(run_dir / "last.npz")
            model.load_state_dict({k[6:]: v for k, v in tensors.items() if k.startswith("model/")})
            opt.load_state_dict(optimizer_from_tensors(tensors, meta["optimizer"]))
            first_epoch, step, best = meta["epoch"] + 1, meta["step"], meta["best_val_loss"]
        if dist.is_main:
            run_dir.mkdir(parents=True, exist_ok=True)
            (run_dir / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2) + "\n")
        forward = DistributedDataParallel(model.dvae) if dist.enabled else model.dvae
        meta_base = {
            "model_config": cfg.model.to_dict(),
            "train_config": cfg.to_dict(),
            "body_model": body.data.name or body.data.kind,
        }
        model.train()
        epoch = first_epoch - 1
        for epoch in range(first_epoch, cfg.epochs):
            gen = torch.Generator().manual_seed(cfg.seed * 1000 + epoch)
            perm = torch.randperm(len(train), generator=gen)
            mine = perm[dist.rank :: dist.world_size]
            for i in range(steps_per_epoch):
                idx = mine[i * cfg.batch_size : (i + 1) * cfg.batch_size]
                b = train.subset(idx)
                batch = WindowSet(b.x0.to(device), b.x.to(device), b.betas.to(device))
                set_lr(opt, cosine_lr(step, total_steps, cfg.lr, cfg.lr_final))
                kl_w = cfg.kl_max * kl_weight(step, cfg.kl_warmup_steps)
                terms = prior_losses(
                    model,
                    forward,
                    batch,
                    body,
                    vertex_ids,
                    kl_w,
                    cfg.body_weight,
                    cfg.body_frame_stride,
                    cfg.recon_weight,
                    cfg.velocity_weight,
                )
                clipped_step(opt, terms["loss"], model.dvae.parameters(), cfg.grad_clip)
                step += 1
                if progress is not None and dist.is_main:
                    progress(
                        {
                            "epoch": epoch,
                            "step": step,
                            "steps_per_epoch": steps_per_epoch,
                            "epochs": cfg.epochs,
                            "kl_w": kl_w,
                            **{k: v.item() for k, v in terms.items()},
                        }
                    )
                if max_steps is not None and step >= max_steps:
                    break
            if dist.is_main:
                val_terms = evaluate(model, val, body, vertex_ids, cfg, device) if val else {}
                val_loss = val_terms.get("loss", terms["loss"].item())
                meta = {
                    **meta_base,
                    "epoch": epoch,
                    "step": step,
                    "val": val_terms,
                    "best_val_loss": min(best, val_loss),
                }
                if val_loss < best:
                    best = val_loss
                    _save(run_dir, "best", model, None, meta)
                _save(run_dir, "last", model, opt, meta)
                with open(run_dir / "log.jsonl", "a") as fh:
                    fh.write(
                        json.dumps(
                            {
                                "epoch": epoch,
                                "step": step,
                                "val": val_terms,
                                "train_loss": terms["loss"].item(),
                                "seconds": time.time() - start,
                            }
                        )
                        + "\n"
                    )
                if progress is not None:
                    progress({"epoch": epoch, "step": step, "val": val_terms, "epoch_end": True})
            if max_steps is not None and step >= max_steps:
                break
        digests = gather_strings(dist, parameter_digest(model))
        summary = TrainSummary(
            str(run_dir),
            epoch + 1,
            step,
            best,
            time.time() - start,
            len(train),
            len(val) if val else 0,
            digests,
        )
        if dist.is_main:
            (run_dir / "summary.json").write_text(json.dumps(asdict(summary), indent=2) + "\n")
        return summary
    finally:
        shutdown_distributed(dist)
