"""Loss terms: Gaussian KL, Inverse-Gamma expectations and KL, the ELBO pieces."""

from __future__ import annotations

import torch


def gaussian_kl(mean_q, logvar_q, mean_p, logvar_p) -> torch.Tensor:
    """KL(N(mean_q, e^logvar_q) || N(mean_p, e^logvar_p)) summed over the last dim.

    all: (..., L) -> (...)
    """
    return 0.5 * (
        logvar_p - logvar_q + (torch.exp(logvar_q) + (mean_q - mean_p) ** 2) / torch.exp(logvar_p)
        - 1.0
    ).sum(-1)  # fmt: skip


def inverse_gamma_expectations(alpha: torch.Tensor, beta: torch.Tensor):
    """E[1/v] and E[log v] for v ~ IG(alpha, beta).  (...), (...) -> (...), (...)"""
    return alpha / beta, torch.log(beta) - torch.digamma(alpha)


def inverse_gamma_kl(alpha, beta, alpha0: float, beta0: float) -> torch.Tensor:
    """KL(IG(alpha, beta) || IG(alpha0, beta0)), elementwise.  (...), (...) -> (...)

    Equal to the KL between the Gamma laws of 1/v, which has a closed form.
    """
    a0 = torch.as_tensor(alpha0, dtype=alpha.dtype, device=alpha.device)
    b0 = torch.as_tensor(beta0, dtype=alpha.dtype, device=alpha.device)
    return (
        (alpha - a0) * torch.digamma(alpha) - torch.lgamma(alpha) + torch.lgamma(a0)
        + a0 * (torch.log(beta) - torch.log(b0)) + alpha * (b0 - beta) / beta
    )  # fmt: skip


def kl_weight(step: int, warmup_steps: int) -> float:
    """Linear KL warm-up from 0 to 1 over ``warmup_steps``."""
    if warmup_steps <= 0:
        return 1.0
    return min(1.0, step / warmup_steps)
