"""The prior's training loss (paper Sec. 3.2): the negative ELBO per frame, with the decoder's
Gaussian width and the KL weight as settings, plus the body-model regulariser on joints,
markers and a spread of mesh vertices. Used by training (``train.train_prior``) and by
semi-amortised reconstruction (``train.reconstruct``)."""

from __future__ import annotations

import numpy as np
import torch

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.model.losses import gaussian_kl
from mdvae_cli.model.prior_model import PriorModel
from mdvae_cli.model.state import VELOCITY_DIMS, state_to_params
from mdvae_cli.train.corpus import WindowSet


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
    per_frame = betas[:, None].expand(B, T, betas.shape[-1]).reshape(B * T, -1)
    out = body(p.root_orient, p.pose_body, p.trans, per_frame, vertex_ids=vertex_ids)
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
    *,
    frames: torch.Tensor | None = None,
    velocity_dims: torch.Tensor | None = None,
) -> dict[str, torch.Tensor]:
    """Negative ELBO (per frame) + body regulariser for a batch.

    ``recon_w`` = 1 / sigma_x^2: the decoder's Gaussian is N(mu_x, sigma_x^2 I) in normalised
    units (1 = the paper's N(mu_x, I)); ``velocity_w`` scales that weight on the velocity
    columns (a wider variance there). ``recon`` is reported unweighted.

    ``forward`` is the (possibly DDP-wrapped) ``model.dvae``. The body term is evaluated on
    every ``frame_stride``-th frame from a random phase (an unbiased, cheaper estimate), or on
    the frame indices ``frames`` (T',) where given (a CUDA graph's step sets them before each
    replay). ``kl_w`` may be a 0-d device tensor, and ``velocity_dims`` the device tensor of
    :data:`VELOCITY_DIMS` (a captured step copies nothing from the host).
    Returns the terms and ``loss``.
    """
    norm = model.normalizer
    xn, x0n = norm.normalize(batch.x), norm.normalize(batch.x0)
    x_mean, _, post, prior = forward(xn, x0n)
    recon = 0.5 * ((xn - x_mean) ** 2).sum(-1).mean()
    kl = gaussian_kl(post.mean, post.logvar, prior.mean, prior.logvar).mean()
    if frames is None:
        phase = int(torch.randint(frame_stride, (1,))) if frame_stride > 1 else 0
        x_hat, x_gt = x_mean[:, phase::frame_stride], batch.x[:, phase::frame_stride]
    else:
        x_hat, x_gt = x_mean.index_select(1, frames), batch.x.index_select(1, frames)
    pts_hat = body_points(body, norm.denormalize(x_hat), batch.betas, vertex_ids)
    with torch.no_grad():
        pts_gt = body_points(body, x_gt, batch.betas, vertex_ids)
    body_mse = ((pts_hat - pts_gt) ** 2).sum(-1).mean() * 1e4  # cm^2
    if velocity_w != 1.0:
        dims = velocity_dims
        if dims is None:
            dims = torch.as_tensor(VELOCITY_DIMS, device=xn.device)
        sq = ((xn - x_mean) ** 2).index_select(-1, dims).sum(-1).mean()
        fit = recon + 0.5 * (velocity_w - 1.0) * sq
    else:
        fit = recon
    loss = recon_w * fit + kl_w * kl + body_w * body_mse
    return {"loss": loss, "recon": recon, "kl": kl, "body_cm2": body_mse}
