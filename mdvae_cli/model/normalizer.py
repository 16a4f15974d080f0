"""Per-dimension state normalisation with statistics from the training split."""

from __future__ import annotations

import torch
from torch import nn

from mdvae_cli.motion.state import STATE_DIM


class Normalizer(nn.Module):
    """x_n = (x - mean) / std.  mean, std: (D,), stored in the checkpoint."""

    def __init__(self, dim: int = STATE_DIM):
        super().__init__()
        self.register_buffer("mean", torch.zeros(dim))
        self.register_buffer("std", torch.ones(dim))

    @torch.no_grad()
    def fit(self, x: torch.Tensor, min_std: float = 1e-2) -> Normalizer:
        """Set statistics from samples.  x: (..., D)"""
        flat = x.reshape(-1, x.shape[-1]).double()
        self.mean.copy_(flat.mean(0).to(self.mean.dtype))
        self.std.copy_(flat.std(0).clamp_min(min_std).to(self.std.dtype))
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
