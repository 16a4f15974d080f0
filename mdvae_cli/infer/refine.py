"""Latent refinement: per-window inference by gradient steps on the ELBO (semi-amortised).

Regression mode reads each window's latents off the encoder in one pass; the encoder is an
amortised approximation, and on held-out motion its latents land ~3 cm (V2V) away from the best
the frozen decoder can express. Refinement starts from the encoder's answer and then treats each
window's posterior means as free variational parameters: a few Adam steps maximise the window's
ELBO under the frozen prior and decoder,

    sum_t E_q(v)[log N(obs_t | x_hat_t, v)] - KL(q(z_{1:T}) || p(z_{1:T} | x0)),

with x_hat = decoder(x0, z_{1:T}) (x0 optimised too), the posterior variances of z held at the
encoder's, and the observation noise v an Inverse-Gamma variance per group of coordinates, updated
in closed form after every step (coordinate ascent: q(v) = IG(a0 + n/2, b0 + S/2), S the sum of
squared residuals of the group, n its size; IG(a0, b0) the prior).

The decoded rotations are scored with a slow per-joint offset added, and the noise precisions
and the offset are closed form for fixed latents: ``infer.closed_form`` (updated before every
step). With 0 steps the latents stay the encoder's and only those factors are fitted
(``add_offset``): ``mdvae denoise``'s default.

The likelihood scores the file's own noisy parameters (joint rotations, root orientation,
translation) rather than 3D points: the noise of a mocap solve or of a pose estimator lives in the
joint rotations, and a rotation error moves every point below that joint at once, which a
per-point diagonal likelihood counts as many independent observations (it then fits the noise).
Each joint's variance is estimated from the window itself, so the noise level need not be known.

``train.reconstruct.refine_reconstruction`` does the same for a prior on clean windows, with the
prior run's own training loss (ELBO + body regulariser): semi-amortised reconstruction.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from mdvae_cli.infer.closed_form import ClosedFormFactors, add_offset
from mdvae_cli.infer.settings import RefineConfig
from mdvae_cli.model.denoiser import Denoiser
from mdvae_cli.model.losses import gaussian_kl


class Adam:
    """Adam (no weight decay) on a few tensors, written out: ``torch.optim``'s first optimiser
    imports ``torch._dynamo``, ~2 s on a 2-core CPU, longer than refining a whole clip.
    Same update as ``torch.optim.Adam`` with its defaults.  params: leaf tensors with grads."""

    def __init__(self, params: list[torch.Tensor], lr: float, betas=(0.9, 0.999), eps=1e-8):
        self.params, self.lr, self.betas, self.eps, self.t = params, lr, betas, eps, 0
        self.m = [torch.zeros_like(p) for p in params]
        self.v = [torch.zeros_like(p) for p in params]

    def zero_grad(self) -> None:
        for p in self.params:
            p.grad = None

    @torch.no_grad()
    def step(self) -> None:
        self.t += 1
        b1, b2 = self.betas
        c1, c2 = 1 - b1**self.t, 1 - b2**self.t
        for p, m, v in zip(self.params, self.m, self.v, strict=True):
            m.mul_(b1).add_(p.grad, alpha=1 - b1)
            v.mul_(b2).addcmul_(p.grad, p.grad, value=1 - b2)
            p.addcdiv_(m, (v / c2).sqrt_().add_(self.eps), value=-self.lr / c1)


def window_batches(count: int, cfg: RefineConfig, workers: int = 1) -> list[torch.Tensor]:
    """Batches of ``count`` windows' indices for refinement. One at a time (``workers`` 1, or
    no steps to take: regression mode's one pass gains nothing side by side):
    ``cfg.batch_windows`` windows each, the last the rest. Side by side: a multiple of
    ``workers`` batches of near-equal sizes, each of at most
    ``cfg.batch_windows // workers`` windows, so that the windows refined at once, and the
    memory, stay as one batch's. Each window's steps depend on that window alone: the batches
    change its result by no more than the products' rounding (on the shipped networks' 400
    windows of a 10-minute take, not at all)."""
    if count == 0:
        return []
    windows = torch.arange(count)
    if workers <= 1 or cfg.steps == 0:
        return list(windows.split(cfg.batch_windows))
    batches = -(-count // max(1, cfg.batch_windows // workers))
    return list(windows.tensor_split(min(count, -(-batches // workers) * workers)))


def refine_latents(
    denoiser: Denoiser,
    yn: torch.Tensor,
    obs: torch.Tensor,
    joint_weight: torch.Tensor | None,
    cfg: RefineConfig,
    progress: Callable[[dict], None] | None = None,
) -> torch.Tensor:
    """Refine one batch of windows; return the decoded states plus the slow offset.

    yn: (N, T+1, 138) what the encoder reads (normalised); obs: (N, T+1, 138) the noisy states
    the likelihood scores (state units, canonical frame); joint_weight: (N, T+1, 22) or None
    -> (N, T+1, 138) in state units. With ``cfg.steps`` = 0 the latents stay the encoder's and
    only the closed-form factors are fitted (``cfg.offset_iterations`` rounds): regression
    mode plus the offset, or regression mode itself when ``cfg.offset_std`` = 0.
    """
    if cfg.steps == 0:
        with torch.no_grad():
            start = denoiser.infer(yn, with_prior=False)
        return add_offset(start["x_hat"], obs, joint_weight, cfg)
    refined = refine_posterior(denoiser, yn, obs, joint_weight, cfg, progress)
    return refined.x_hat + refined.factors.offset


@dataclass
class RefinedPosterior:
    """What refinement ends with for a batch of windows.

    z: (N, T, L) and x0: (N, 138) the refined posterior means (normalised); z_logvar: (N, T, L)
    the posterior log-variances (the encoder's, held during refinement); x_hat: (N, T+1, 138)
    the decoded states (state units, without the offset); factors: the closed-form factors
    fitted to x_hat (``factors.offset`` is the slow offset).
    """

    z: torch.Tensor
    x0: torch.Tensor
    z_logvar: torch.Tensor
    x_hat: torch.Tensor
    factors: ClosedFormFactors


def refine_posterior(
    denoiser: Denoiser,
    yn: torch.Tensor,
    obs: torch.Tensor,
    joint_weight: torch.Tensor | None,
    cfg: RefineConfig,
    progress: Callable[[dict], None] | None = None,
) -> RefinedPosterior:
    """``cfg.steps`` Adam steps on each window's ELBO from the encoder's answer (shapes as in
    :func:`refine_latents`); the posterior means they reach, and what they decode to."""
    dvae, norm = denoiser.prior.dvae, denoiser.prior.normalizer
    N, T1 = yn.shape[:2]
    with torch.no_grad():
        start = denoiser.infer(yn, with_prior=False)
    z = start["q_z"].mean.clone().requires_grad_(True)
    z_logvar = start["q_z"].logvar
    x0 = start["q_x0"].mean.clone().requires_grad_(True)
    # the latents fit the translation here: a slow offset on it measured no better (model.md)
    factors = ClosedFormFactors(obs, joint_weight, cfg, translation=False)
    opt = Adam([z, x0], lr=cfg.lr)

    def decode() -> torch.Tensor:
        x_mean, _ = dvae.decoder(z, x0)
        return norm.denormalize(torch.cat([x0[:, None], x_mean], dim=1))

    for step in range(cfg.steps):
        x_hat = decode()
        factors.update(x_hat)
        p_z = dvae.prior(z, x0)
        kl = gaussian_kl(z, z_logvar, p_z.mean, p_z.logvar).sum()
        # a sum over windows (per frame): each window's gradient, and so its Adam steps, do
        # not depend on how many windows share the batch (Adam's epsilon is not scale-free)
        loss = (factors.reconstruction(x_hat) + kl) / T1
        opt.zero_grad()
        loss.backward()
        opt.step()
        if progress is not None:
            progress({"step": step + 1, "steps": cfg.steps, "loss": loss.item() / N})
    with torch.no_grad():
        x_hat = decode()
        factors.update(x_hat)
    return RefinedPosterior(z.detach(), x0.detach(), z_logvar, x_hat, factors)
