"""Per-dimension state normalisation with statistics from the training split."""

from __future__ import annotations

import torch
from torch import nn

from mdvae_cli.model.state import STATE_DIM


class Normalizer(nn.Module):
    """x_n = (x - mean) / std.  mean, std: (D,), stored in the checkpoint."""

    def __init__(self, dim: int = STATE_DIM):
        super().__init__()
        self.register_buffer("mean", torch.zeros(dim))
        self.register_buffer("std", torch.ones(dim))

    @torch.no_grad()
    def fit(self, *parts: torch.Tensor, min_std: float = 1e-2, chunk: int = 1 << 22) -> Normalizer:
        """Set statistics from samples: every row of every part.  parts: (..., D) each.

        Two passes over rows in chunks of ``chunk`` values, in float64 (mean, then the
        unbiased variance about it): the memory of one chunk, not of a float64 copy of the
        training set (98,000 windows would need 6.7 GB)."""
        D = parts[0].shape[-1]
        rows = [p.reshape(-1, D) for p in parts]
        step = max(1, chunk // D)
        pieces = lambda: (r[i : i + step].double() for r in rows for i in range(0, len(r), step))  # noqa: E731
        n = sum(len(r) for r in rows)
        mean = sum(p.sum(0) for p in pieces()) / n
        var = sum(((p - mean) ** 2).sum(0) for p in pieces()) / max(1, n - 1)
        self.mean.copy_(mean.to(self.mean.dtype))
        self.std.copy_(var.sqrt().clamp_min(min_std).to(self.std.dtype))
        return self

    @torch.no_grad()
    def scale_std(self, dims: list[int], factor: float) -> Normalizer:
        """Widen (factor > 1) the scale of some dimensions: under the decoder's N(mu, I) in
        normalised units this gives them a proportionally larger variance, i.e. less weight."""
        self.std[dims] *= factor
        return self

    def normalize(self, x: torch.Tensor) -> torch.Tensor:
        """(..., D) -> (..., D)"""
        return (x - self.mean) / self.std

    def denormalize(self, x: torch.Tensor) -> torch.Tensor:
        """(..., D) -> (..., D)"""
        return x * self.std + self.mean
