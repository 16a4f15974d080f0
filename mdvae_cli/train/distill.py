"""Amortised refinement: teach the inference networks what latent refinement finds.

Regression mode reads each window's latents off the encoder in one pass; latent refinement
(``infer.refine``) then takes gradient steps on that window's own ELBO and lands markedly closer
to the clean motion (the encoder's amortisation gap, docs/model.md). Here, after the ELBO fit,
every noisy training window is refined (its own noisy observations only: still no clean data)
and the encoder and the initial-state predictor are trained to output those refined posterior
means directly: squared error between the states they decode to and the refined decoded
states (normalised units, velocities down-weighted), plus a small term on the latents
themselves and one that keeps the posterior log-variances at the encoder's (refinement holds
them there, and its steps read them through the KL: left free, they drift and refinement from
the new networks ends worse). Regression mode then gets much of refinement's accuracy at
regression mode's cost. The prior, the decoder and the noise predictor are not touched.
"""

from __future__ import annotations

import itertools
import math
import threading
from collections.abc import Callable, Iterator
from contextlib import closing
from dataclasses import asdict, dataclass

import torch

from mdvae_cli.errors import diverged
from mdvae_cli.infer.elbo_fit import batch_order
from mdvae_cli.infer.progress import stoppable
from mdvae_cli.infer.refine import RefinedPosterior, refine_posterior, window_batches
from mdvae_cli.infer.settings import RefineConfig
from mdvae_cli.infer.window_groups import WindowGroup
from mdvae_cli.model.config import require_int, require_number
from mdvae_cli.model.denoiser import Denoiser
from mdvae_cli.model.optim import checkpoint_in_eval, clipped_step, cosine_lr, set_lr
from mdvae_cli.model.state import VELOCITY_DIMS
from mdvae_cli.workers import map_in_order


@dataclass
class DistillConfig:
    """Settings of amortised refinement (``mdvae fit-dataset --distill-epochs``).

    epochs: passes over the windows (0 = off); lr, lr_final: Adam's learning rate, cosine-
    decayed; batch_size: windows per step; latent_weight: weight of the squared errors on the
    latent means and log-variances beside the one on the decoded states; velocity_weight:
    weight of the velocity columns in the latter (they are redundant with the positions);
    refine_steps: refinement steps that make each window's target (``RefineConfig`` defaults
    otherwise).
    """

    epochs: int = 0
    lr: float = 1e-3
    lr_final: float = 1e-4
    batch_size: int = 64
    latent_weight: float = 0.1
    velocity_weight: float = 0.1
    refine_steps: int = 50

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """InputError naming the first invalid setting (``--distill-...`` where it has one)."""
        require_int("--distill-epochs", self.epochs, 0)
        require_int("--distill-refine-steps", self.refine_steps, 1)
        require_int("distill batch_size", self.batch_size, 1)
        require_number("--distill-lr", self.lr, 0.0, open_low=True)
        require_number("distill lr_final", self.lr_final, 0.0, open_low=True)
        require_number("distill latent_weight", self.latent_weight, 0.0)
        require_number("distill velocity_weight", self.velocity_weight, 0.0)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class Targets:
    """Refined posterior of a group's windows.  z: (N, T, L) and x0: (N, 138) the means,
    normalised; z_logvar: (N, T, L) the log-variances (the encoder's before distillation)."""

    z: torch.Tensor
    x0: torch.Tensor
    z_logvar: torch.Tensor

    def __len__(self) -> int:
        return int(self.z.shape[0])


def refine_targets(
    denoiser: Denoiser,
    group: WindowGroup,
    steps: int,
    progress: Callable[[dict], None] | None = None,
    *,
    start: Targets | None = None,
    stop_requested: Callable[[], bool] | None = None,
    keep: Callable[[Callable[[], Targets]], None] | None = None,
    batch: int = RefineConfig.batch_windows,
    workers: int = 1,
) -> Targets:
    """Refine every window of ``group`` (its raw noisy states: ``make_windows(observations=
    True)``) for ``steps`` steps; ``progress`` gets {"step", "steps"} counted in windows.

    start: the targets of the group's first windows, made before (a stopped run): refinement
    goes on after them (each window's steps depend on that window alone). stop_requested():
    true after a batch ends the loop there, and the targets returned cover the group's first
    windows only. keep(so_far) is called after each batch but the last, ``so_far()`` giving
    the targets made so far (to save them now and then). batch: windows refined together;
    ``workers`` > 1: batches of ``batch // workers`` side by side, torch one thread in each
    (``infer.refine.window_batches``; the same targets).
    """
    if group.obs is None:
        raise ValueError("refinement targets need the raw states: make_windows(observations=True)")
    cfg = RefineConfig(steps=steps, batch_windows=batch)
    denoiser.eval()
    parts = [] if start is None else [(start.z, start.x0, start.z_logvar)]

    def so_far() -> Targets:
        return Targets(*(torch.cat(t) for t in zip(*parts, strict=True)))

    done = 0 if start is None else len(start)

    def refine(idx: torch.Tensor) -> tuple[torch.Tensor, RefinedPosterior]:
        g = group.batch(idx, with_y3d=False)
        joints = None if g.weight is None else g.weight[..., :22]
        with torch.no_grad():
            yn = denoiser.read_holes(g.yn, g.read_weight)
        return idx, refine_posterior(denoiser, yn, g.obs, joints, cfg, stoppable(None, stop))

    batches = [done + b for b in window_batches(len(group) - done, cfg, workers)]
    stop = threading.Event()  # set when the batches side by side are left (Ctrl-C)
    with closing(map_in_order(refine, batches, workers, stop)) as refined_batches:
        for idx, refined in refined_batches:
            parts.append((refined.z, refined.x0, refined.z_logvar))
            if progress is not None:
                progress({"step": int(idx[-1]) + 1, "steps": len(group)})
            if stop_requested is not None and stop_requested():
                break
            if keep is not None and int(idx[-1]) + 1 < len(group):
                keep(so_far)
    return so_far()


def column_weights(velocity_weight: float, dim: int = 138) -> torch.Tensor:
    """(dim,) weights of the state columns in the distillation loss."""
    w = torch.ones(dim)
    w[torch.as_tensor(VELOCITY_DIMS)] = velocity_weight
    return w


def distill_loss(
    denoiser: Denoiser,
    yn: torch.Tensor,
    targets: Targets,
    col_weight: torch.Tensor,
    latent_weight: float,
) -> dict[str, torch.Tensor]:
    """Squared errors of the networks' posterior against the refined one, per window.

    yn: (B, T+1, 138) what the networks read; targets: B windows' refined posteriors;
    col_weight: (138,) -> {"loss", "state", "latent"} (means over windows and frames, sums over
    columns; "latent" = means and log-variances)
    """
    out = denoiser.infer(yn, with_prior=False)
    with torch.no_grad():
        x_mean, _ = denoiser.prior.dvae.decoder(targets.z, targets.x0)
        ref = torch.cat([targets.x0[:, None], x_mean], dim=1)
    state = (((out["x_hat_n"] - ref) ** 2) * col_weight).sum(-1).mean()
    q_z = out["q_z"]
    latent = ((q_z.mean - targets.z) ** 2 + (q_z.logvar - targets.z_logvar) ** 2).sum(-1).mean()
    return {"loss": state + latent_weight * latent, "state": state, "latent": latent}


def distill(
    denoiser: Denoiser,
    group: WindowGroup | list[WindowGroup],
    targets: Targets | list[Targets],
    cfg: DistillConfig,
    seed: int = 0,
    done: int = 0,
    progress: Callable[[dict], None] | None = None,
    checkpoint: Callable[[int], None] | None = None,
    checkpoint_every: int = 200,
    stop_requested: Callable[[], bool] | None = None,
) -> list[float]:
    """Train the encoder and the x0 predictor on ``targets`` for ``cfg.epochs`` passes.

    ``group`` and ``targets`` may be lists (windows of several lengths, e.g. full windows and
    short takes): batches then come from one group at a time, groups chosen in proportion to
    their sizes (``infer.elbo_fit.batch_order``); with one group, every epoch is a seeded
    permutation of its windows. ``done`` steps were taken before (resume: the learning-rate
    schedule and the batch order carry on where they were); ``checkpoint(step)`` is called every
    ``checkpoint_every`` steps with the number of distillation steps taken so far. Returns
    every step's loss; ``stop_requested()`` true after a step ends the loop there.
    """
    groups = group if isinstance(group, list) else [group]
    all_targets = targets if isinstance(targets, list) else [targets]
    for g, t in zip(groups, all_targets, strict=True):
        if len(t) != len(g):
            raise ValueError(f"{len(t)} targets for {len(g)} windows")
    size = sum(len(g) for g in groups)
    per_epoch = max(1, size // cfg.batch_size)
    total = per_epoch * cfg.epochs
    params = [*denoiser.encoder.parameters(), *denoiser.x0_predictor.parameters()]
    if denoiser.hole_reader is not None:
        params += list(denoiser.hole_reader.parameters())
    opt = torch.optim.Adam(params, lr=cfg.lr)
    device = params[0].device  # the windows and targets stay where they are, batches move
    col_weight = column_weights(cfg.velocity_weight, groups[0].yn.shape[-1]).to(device)
    order = _batches(groups, cfg.batch_size, per_epoch, seed)
    order = itertools.islice(order, done, total)
    denoiser.train()
    losses = []
    for step, (gi, idx) in enumerate(order, start=done):
        t = all_targets[gi]
        set_lr(opt, cosine_lr(step, total, cfg.lr, cfg.lr_final))
        batch = Targets(*(x[idx].to(device) for x in (t.z, t.x0, t.z_logvar)))
        read = groups[gi].read_weight
        yn = denoiser.read_holes(groups[gi].yn[idx].to(device), None if read is None else read[idx])
        terms = distill_loss(denoiser, yn, batch, col_weight, cfg.latent_weight)
        loss = terms["loss"].item()
        if not math.isfinite(loss):  # the weights are still the last good ones
            raise diverged("distillation", step + 1, f"loss {loss:g}", "--distill-lr")
        clipped_step(opt, terms["loss"], params, 5.0)
        losses.append(loss)
        if progress is not None:
            progress({"step": step + 1, "steps": total, **{k: v.item() for k, v in terms.items()}})
        checkpoint_in_eval(denoiser, checkpoint, step + 1, checkpoint_every)
        if stop_requested is not None and stop_requested():
            break
    denoiser.eval()
    return losses


def _batches(
    groups: list[WindowGroup], batch_size: int, per_epoch: int, seed: int
) -> Iterator[tuple[int, torch.Tensor]]:
    """The endless batch order of :func:`distill`: (group index, window indices)."""
    if len(groups) > 1:
        yield from batch_order([len(g) for g in groups], batch_size, seed)
        return
    for epoch in itertools.count():
        perm = torch.randperm(len(groups[0]), generator=torch.Generator().manual_seed(seed + epoch))
        for i in range(per_epoch):
            yield 0, perm[i * batch_size : (i + 1) * batch_size]
