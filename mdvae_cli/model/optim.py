"""What the training loops share (prior, denoiser fit, distillation): the cosine learning-rate
schedule, one clipped gradient step, and checkpoints written in eval mode."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable

import torch


def cosine_lr(step: int, total: int, lr: float, lr_final: float) -> float:
    """The learning rate at ``step`` of ``total``: half a cosine from ``lr`` down to
    ``lr_final``."""
    frac = step / max(1, total)
    return lr_final + 0.5 * (lr - lr_final) * (1 + math.cos(math.pi * frac))


def warmup_cosine_lr(step: int, total: int, lr: float, lr_final: float, warmup: int) -> float:
    """:func:`cosine_lr` after a linear warm-up: ``lr * (step + 1) / warmup`` for the first
    ``warmup`` steps (large batches), then the cosine over the remaining steps. ``warmup`` 0
    is exactly :func:`cosine_lr`."""
    if step < warmup:
        return lr * (step + 1) / warmup
    return cosine_lr(step - warmup, total - warmup, lr, lr_final)


def set_lr(opt: torch.optim.Optimizer, lr: float) -> None:
    for group in opt.param_groups:
        group["lr"] = lr


def clipped_step(
    opt: torch.optim.Optimizer,
    loss: torch.Tensor,
    params: Iterable[torch.nn.Parameter],
    max_norm: float,
) -> None:
    """Backpropagate ``loss``, clip the gradients of ``params`` to ``max_norm`` and step."""
    opt.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(params, max_norm)
    opt.step()


def checkpoint_in_eval(
    module: torch.nn.Module, checkpoint: Callable[[int], None] | None, step: int, every: int
) -> None:
    """Call ``checkpoint(step)`` every ``every`` steps with ``module`` in eval mode (training
    mode restored afterwards)."""
    if checkpoint is not None and step % every == 0:
        module.eval()
        checkpoint(step)
        module.train()
