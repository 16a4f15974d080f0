"""The ELBO fit of the inference networks (paper Sec. 4.2), prior and decoder frozen: the loop
``mdvae fit-dataset`` runs over many noisy files and ``mdvae denoise --optimize N`` over the very
windows being cleaned.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterator

import torch

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import diverged
from mdvae_cli.infer.window_groups import WindowGroup
from mdvae_cli.model.denoiser import Denoiser
from mdvae_cli.model.optim import checkpoint_in_eval, clipped_step, cosine_lr, set_lr


def batch_order(
    lengths: list[int], batch_size: int, seed: int
) -> Iterator[tuple[int, torch.Tensor]]:
    """The batches an ELBO fit visits, step after step: (group index, window indices).

    Batches cycle through a seeded permutation of each group's windows, groups chosen in
    proportion to their sizes. The same seed gives the same endless sequence, so a resumed
    run skips the batches already taken and carries on with the very next one."""
    gen = torch.Generator().manual_seed(seed)
    sizes = torch.tensor(lengths, dtype=torch.float)
    perms = [torch.randperm(n, generator=gen) for n in lengths]
    cursors = [0] * len(lengths)
    while True:
        gi = int(torch.multinomial(sizes, 1, generator=gen)) if len(lengths) > 1 else 0
        if cursors[gi] >= lengths[gi]:
            perms[gi] = torch.randperm(lengths[gi], generator=gen)
            cursors[gi] = 0
        yield gi, perms[gi][cursors[gi] : cursors[gi] + batch_size]
        cursors[gi] += batch_size


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
    first_step: int = 0,
    total_steps: int | None = None,
    optimizer: torch.optim.Optimizer | None = None,
    stop_requested: Callable[[], bool] | None = None,
) -> list[float]:
    """Maximise the ELBO over phi, gamma, omega for ``steps`` Adam steps on ``groups``.

    Batches follow :func:`batch_order`. With ``lr_final`` the learning rate decays from ``lr``
    to it on a cosine over ``total_steps`` (default ``steps``); ``first_step`` steps of that
    schedule and of the batch order were taken before (a resumed run, whose ``optimizer``
    carries Adam's state; default a new Adam). ``checkpoint(step)`` is called every
    ``checkpoint_every`` steps, ``step`` counted from the start of the run. One-frame windows
    (x0 alone) have nothing to fit and are left out. Returns the loss of every step; a loss
    that is not finite raises InputError before its step is taken.
    The ELBO's Monte-Carlo draws come from ``sample_generator`` (None: torch's global
    generator, which ``mdvae fit-dataset`` seeds). ``stop_requested()`` true after a step (a
    Ctrl-C the command caught) ends the loop there: fewer losses than ``steps``.
    """
    device = device or torch.device("cpu")
    groups = [g for g in groups if g.moves]
    if not groups:
        return []
    opt = optimizer or torch.optim.Adam(denoiser.trainable_parameters(), lr=lr)
    total = steps + first_step if total_steps is None else total_steps
    order = batch_order([len(g) for g in groups], batch_size, seed)
    order = itertools.islice(order, first_step, first_step + steps)
    denoiser.train()
    losses = []
    for step, (gi, idx) in enumerate(order, start=first_step):
        b = groups[gi].batch(idx)
        if lr_final is not None:
            set_lr(opt, cosine_lr(step, total, lr, lr_final))
        w = None if b.weight is None else b.weight.to(device)
        seen = None if b.seen is None else b.seen.to(device)
        terms = denoiser.elbo(
            b.yn.to(device), b.y3d.to(device), b.betas.to(device), body, w,
            generator=sample_generator, seen=seen,
        )  # fmt: skip
        loss = terms["loss"].item()
        if not math.isfinite(loss):  # the weights are still the last good ones
            raise diverged("training", step + 1, f"loss {loss:g}")
        clipped_step(opt, terms["loss"], denoiser.trainable_parameters(), 5.0)
        losses.append(loss)
        if progress is not None:
            done = step + 1 - first_step
            progress({"step": done, "steps": steps, **{k: v.item() for k, v in terms.items()}})
        checkpoint_in_eval(denoiser, checkpoint, step + 1, checkpoint_every)
        if stop_requested is not None and stop_requested():
            break
    denoiser.eval()
    return losses
