"""Semi-amortised reconstruction of clean windows through a prior (``benchmarks/prior.py``).

The prior's encoder is an amortised approximation of the posterior; starting from its answer,
a few Adam steps per window on the prior run's own training loss (ELBO with the run's weights plus
the body regulariser), prior and decoder frozen, find latents that explain held-out motion better
at a lower KL: the gap between the two is the encoder's amortisation gap. The same step on noisy
data is ``infer.refine.refine_latents``.
"""

from __future__ import annotations

from contextlib import contextmanager

import torch

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.infer.refine import Adam
from mdvae_cli.model.dvae import Gaussian
from mdvae_cli.model.prior_model import PriorModel
from mdvae_cli.train.corpus import WindowSet
from mdvae_cli.train.prior_loss import prior_losses, spread_vertex_ids
from mdvae_cli.train.train_config import TrainConfig


@contextmanager
def frozen(module: torch.nn.Module):
    """Parameters of ``module`` without gradients for the duration (restored afterwards)."""
    params = list(module.parameters())
    flags = [p.requires_grad for p in params]
    for p in params:
        p.requires_grad_(False)
    try:
        yield module
    finally:
        for p, flag in zip(params, flags, strict=True):
            p.requires_grad_(flag)


def refine_reconstruction(
    prior: PriorModel,
    body: BodyModel,
    batch: WindowSet,
    train: TrainConfig | None,
    steps: int = 50,
    lr: float = 0.05,
) -> tuple[torch.Tensor, Gaussian]:
    """Semi-amortised reconstruction of clean windows with a prior run's own loss.

    Starts from the encoder's posterior means, then takes Adam steps on every window's
    training loss (ELBO with the run's reconstruction weights plus the body regulariser, all
    frames; prior and decoder frozen, the posterior variances held at the encoder's). Every
    window's steps depend on that window alone.

    batch: windows (x0 (B, D), x (B, T, D), betas); train: the run's TrainConfig (only read
    when ``steps`` > 0) -> decoded means (B, T, D), normalised, and the refined posterior
    (means (B, T, L), the encoder's log-variances). ``steps`` = 0: the encoder's answer.
    """
    norm, dvae = prior.normalizer, prior.dvae
    xn, x0n = norm.normalize(batch.x), norm.normalize(batch.x0)
    with torch.no_grad():
        x_mean, _, post, _ = dvae.encode_decode(xn, x0n, sample=False)
    if steps == 0:
        return x_mean, post
    if train is None:
        raise ValueError("refining a reconstruction needs the run's TrainConfig")
    z = post.mean.clone().requires_grad_(True)
    vertex_ids = spread_vertex_ids(body.v_template.shape[0], train.body_vertices).to(xn.device)

    def forward(_xn: torch.Tensor, x0: torch.Tensor):
        return dvae.decoder(z, x0)[0], z, Gaussian(z, post.logvar), dvae.prior(z, x0)

    opt = Adam([z], lr=lr)
    with frozen(dvae):
        for _ in range(steps):
            terms = prior_losses(
                prior, forward, batch, body, vertex_ids, 1.0, train.body_weight, 1,
                train.recon_weight, train.velocity_weight,
            )  # fmt: skip
            opt.zero_grad()
            (terms["loss"] * len(batch)).backward()
            opt.step()
        with torch.no_grad():
            x_mean = dvae.decoder(z, x0n)[0]
    return x_mean, Gaussian(z.detach(), post.logvar)
