"""The closed-form factors of latent refinement's ELBO (``infer.refine``): for fixed decoded
states, each group's noise precision (Gaussian per joint and window, or Student-t per frame),
and the slow per-joint rotation offset with its per-joint scale.

The decoded rotations are scored with a slow offset added, x_hat + B c: B holds the first few
cosines over the window (B (T, K), DCT-II) and every joint-axis has its own coefficients c, with
c_k ~ N(0, decay^{2k} s_g^2) and each joint's scale s_g^2 ~ IG (centred on offset_std). The offset
models what the learned prior cannot express (on clean held-out motion, refined latents alone
stop at ~2.3 cm V2V; with the offset, 0.7 cm), slow enough that white noise barely moves it.
For fixed latents the coefficients' Gaussian posterior and each joint's q(s_g^2) are closed form
(``ClosedFormFactors``); they are updated with the noise precisions before every step. The
output keeps the offset's posterior mean. With 0 steps the latents stay the encoder's and only
these closed-form factors are fitted: regression mode plus the offset (``mdvae denoise``'s default).

Pure tensor math; ``ClosedFormFactors`` holds one batch's factors between rounds of
coordinate ascent.
"""

from __future__ import annotations

import torch

from mdvae_cli.infer.settings import RefineConfig
from mdvae_cli.model.state import POSE, ROOT, TRANS


def noise_precision(
    sq: torch.Tensor, weight: torch.Tensor | None, a0: float, b0: float
) -> torch.Tensor:
    """E[1/v] under q(v) = IG(a0 + n/2, b0 + S/2) for each group of squared residuals.

    sq: (N, T, G, K) squared residuals; weight: (N, T, G) 1 = observed, 0 = missing, or None
    (all observed) -> (N, G) the expected precision of every window's group (K coordinates
    over T frames).
    """
    if weight is None:
        n, s = sq.shape[1] * sq.shape[3], sq.sum(dim=(1, 3))
    else:
        w = weight[..., None].expand_as(sq)
        n, s = w.sum(dim=(1, 3)), (sq * w).sum(dim=(1, 3))
    return (a0 + 0.5 * n) / (b0 + 0.5 * s)


def student_t_weights(sq: torch.Tensor, precision: torch.Tensor, dof: float) -> torch.Tensor:
    """EM weights of Student-t noise per frame and group: E[1/u] of each frame's scale u under
    its posterior, with y ~ N(x, v u I_3), u ~ IG(dof/2, dof/2).

    sq: (N, T, G) squared 3-D residual norms; precision: (N, G) E[1/v] -> (N, T, G) weights in
    (0, (dof + 3) / dof]: ~1 for frames the group's noise level explains, small for spikes.
    """
    return (dof + 3.0) / (dof + sq * precision[:, None])


# the residual groups, three state columns each (one noise variance and one offset scale per
# group and window): the root orientation and the 21 body joints (groups 0-21, pelvis first, as
# the joint masks), then the root translation (group 22)
GROUP_COLUMNS = torch.tensor(
    [*range(ROOT.start, ROOT.stop), *range(POSE.start, POSE.stop), *range(TRANS.start, TRANS.stop)]
)
NUM_ROTATIONS = 22
NUM_GROUPS = NUM_ROTATIONS + 1


#: the share of a window's frames a group must have observed for the offset to start from
#: a free fit of them (with 60 % of the joints missing at random the free fit followed the
#: noise: docs/model.md)
FREE_SHARE = 0.75


def per_group(rotation: float, translation: float, like: torch.Tensor) -> torch.Tensor:
    """A value per residual group: ``rotation`` for groups 0-21, ``translation`` for 22. -> (23,)"""
    out = like.new_full((NUM_GROUPS,), rotation)
    out[NUM_ROTATIONS] = translation
    return out


def offset_scales(cfg: RefineConfig, translation: bool = True) -> tuple[float, float]:
    """The scales the slow offsets' priors centre on: the rotations' (``offset_std``, rad)
    and, with ``translation``, the root translation's (``trans_offset_std``, m); 0 = none."""
    return cfg.offset_std, cfg.trans_offset_std if translation else 0.0


def observation_residuals(x_hat: torch.Tensor, obs: torch.Tensor) -> torch.Tensor:
    """Residuals x_hat - obs of the parameters a file stores, one group per noise variance.

    x_hat, obs: (N, T, 138) states -> (N, T, 23, 3): root orientation, 21 body joints,
    translation
    """
    return (x_hat[..., GROUP_COLUMNS] - obs[..., GROUP_COLUMNS]).unflatten(-1, (NUM_GROUPS, 3))


#: the window length (frames at 30 Hz) ``RefineConfig.offset_terms`` is set for
FULL_WINDOW = 61


def offset_terms_for(num_frames: int, terms: int) -> int:
    """How many cosines a window of ``num_frames`` gets: ``terms`` for a full window, fewer
    for a shorter one so that the fastest cosine keeps the same frequency in Hz (the offset
    models *slow* discrepancy; ten cosines over 16 frames would follow the noise). At least
    one (a constant offset)."""
    if num_frames >= FULL_WINDOW:
        return terms
    return max(1, min(terms, round(terms * num_frames / FULL_WINDOW)))


def cosine_basis(num_frames: int, terms: int, like: torch.Tensor) -> torch.Tensor:
    """The first ``terms`` DCT-II cosines over a window -> (num_frames, terms); column 0 is 1."""
    t = (torch.arange(num_frames, dtype=like.dtype, device=like.device) + 0.5) / num_frames
    k = torch.arange(terms, dtype=like.dtype, device=like.device)
    return torch.cos(torch.pi * t[:, None] * k[None])


def offset_coefficients(
    residual: torch.Tensor,
    precision: torch.Tensor,
    weight: torch.Tensor,
    basis: torch.Tensor,
    prior_precision: torch.Tensor | float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Gaussian posterior of the slow offset's coefficients c in obs = x_hat + B c + noise.

    residual: (N, T, G, 3) x_hat - obs; precision: (N, G) noise precision per group;
    weight: (N, T, G) 1 = observed, or None (every frame observed); basis: (T, K) orthogonal
    cosines; prior_precision: 1/s^2 of c ~ N(0, s^2), a number or (N, G, K) -> mean
    (N, G, 3, K) and marginal variance (N, G, K) of c. With missing frames the cosines are no
    longer orthogonal over the frames that remain, and the K coefficients of a group are solved
    together (a K x K system per group; solving them one by one double-counts); with every
    frame observed the system is diagonal and solved as such.
    """
    if weight is None:
        diag = precision[..., None] * (basis**2).sum(0) + prior_precision  # (N, G, K)
        rhs = -torch.einsum("tk,ntgc->ngck", basis, residual) * precision[..., None, None]
        return rhs / diag[:, :, None], 1.0 / diag
    T, K = basis.shape
    # two-operand products (a 3-operand einsum here took 10x as long on the CPU)
    outer = (basis[:, :, None] * basis[:, None, :]).reshape(T, K * K)
    gram = (weight.transpose(1, 2) @ outer).unflatten(-1, (K, K)) * precision[..., None, None]
    if not torch.is_tensor(prior_precision):
        prior_precision = gram.new_full(gram.shape[:-1], prior_precision)
    gram = gram + torch.diag_embed(prior_precision)
    weighted = weight[..., None] * residual
    rhs = -torch.einsum("tk,ntgc->ngkc", basis, weighted) * precision[..., None, None]
    chol = torch.linalg.cholesky(gram)  # (N, G, K, K)
    mean = torch.cholesky_solve(rhs, chol).transpose(-1, -2)  # (N, G, 3, K)
    var = torch.cholesky_inverse(chol).diagonal(dim1=-2, dim2=-1)
    return mean, var


def offset_precision(
    mean: torch.Tensor, var: torch.Tensor, relative: torch.Tensor, a0: float, b0: float
) -> torch.Tensor:
    """E[1/s^2] of each group's offset scale under q(s^2) = IG(a0 + n/2, b0 + S/2), where
    c_k ~ N(0, s^2 / relative_k) and S = sum_k relative_k E[|c_k|^2].

    mean: (N, G, 3, K), var: (N, G, K) the coefficients' posterior; relative: (K,) each
    coefficient's prior precision relative to the group's -> (N, G); n = 3K.
    """
    second_moment = (mean**2 + var[:, :, None, :]) * relative  # (N, G, 3, K)
    sq = second_moment.permute(0, 3, 1, 2)  # as (N, "T" = K, G, 3) for noise_precision
    return noise_precision(sq, sq.new_ones(sq.shape[:3]), a0, b0)


def offset_states(coef: torch.Tensor, basis: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """The offset B c as state columns.  coef: (N, 23, 3, K) per residual group, basis: (T, K),
    like: (N, T, 138) -> (N, T, 138), zero outside the groups' columns."""
    out = torch.zeros_like(like)
    out[..., GROUP_COLUMNS] = torch.einsum("tk,ngck->ntgc", basis, coef).flatten(-2)
    return out


def group_weights(joint_weight: torch.Tensor | None) -> torch.Tensor | None:
    """Observation weights per residual group from the per-joint mask.

    joint_weight: (N, T, 22) (pelvis first) -> (N, T, 23): the root orientation and the
    translation follow the pelvis. None (all observed) stays None (the solvers' all-observed
    case).
    """
    if joint_weight is None:
        return None
    return torch.cat([joint_weight[..., :NUM_ROTATIONS], joint_weight[..., :1]], dim=-1)


class ClosedFormFactors:
    """The factors of a batch's refinement ELBO that are closed form for fixed latents: each
    group's noise precision E[1/v], the slow offset's coefficients and each group's offset
    precision E[1/s_g^2]. ``update(x_hat)`` is one round of coordinate ascent on them. All
    23 residual groups (22 rotations, the translation) are solved together, each with its own
    noise unit and offset scale; a group whose scale is 0 gets no offset.

    obs: (N, T, 138) the noisy states; joint_weight: (N, T, 22) or None; ``translation``:
    whether the translation gets a slow offset too (``cfg.trans_offset_std``).
    """

    def __init__(
        self,
        obs: torch.Tensor,
        joint_weight: torch.Tensor | None,
        cfg: RefineConfig,
        translation: bool = True,
    ):
        N, T = obs.shape[:2]
        self.obs, self.cfg = obs, cfg
        self.mask = group_weights(joint_weight)  # (N, T, 23): 1 = observed; None = all
        self.weights = self.mask  # what the solvers read: the mask, x Student-t weights
        self.units = per_group(cfg.rot_unit, cfg.trans_unit, obs)  # (23,)
        terms = offset_terms_for(T, cfg.offset_terms)
        self.basis = cosine_basis(T, terms, obs)
        k = torch.arange(terms, dtype=obs.dtype, device=obs.device)
        self.relative = cfg.offset_decay ** (-2.0 * k)  # prior precision of cosine k, relative
        self.offset = torch.zeros_like(obs)
        self.started = False
        self.precision: torch.Tensor | None = None  # E[1/v]: (N, 23)
        self.offset_std = per_group(*offset_scales(cfg, translation), obs)  # (23,)
        self.has_offset = self.offset_std > 0  # (23,)
        scale = torch.where(self.has_offset, self.offset_std, torch.ones_like(self.offset_std))
        self.offset_precision = (1.0 / scale**2).expand(N, -1).clone()  # E[1/s_g^2]: (N, 23)

    def start(self, x_hat: torch.Tensor) -> None:
        """Where coordinate ascent starts: the slow cosines fitted to the residual by least
        squares (next to no shrinkage), and the per-group offset scales that fit implies.

        From a zero offset the first noise estimate holds the whole slow discrepancy, the
        offset is shrunk hard, and it creeps up over 10 or more rounds; from here 3 rounds
        land where 100 from zero do (docs/model.md). With missing frames the fit reads the
        observed ones, in each window and group that has at least 4 of them per cosine and
        :data:`FREE_SHARE` of its frames; where a free fit would follow the noise — fewer
        observed frames than that (a short motion, a window much in a hole, joints missing
        at random), or outliers (``cfg.outlier_dof`` > 0) — the offset starts from zero (a
        5-frame hole in a window once started the whole window from zero: on an unseen dance
        whose one pass is 40 cm off, the window stayed 40 cm off). x_hat: (N, T, 138).
        """
        self.started = True
        T, K = self.basis.shape
        if not bool(self.has_offset.any()) or T < 4 * K or self.cfg.outlier_dof != 0:
            return
        res = observation_residuals(x_hat.detach(), self.obs)
        unit = res.new_ones(res.shape[0], NUM_GROUPS)
        coef, var = offset_coefficients(res, unit, self.mask, self.basis, 1e-3 * self.relative)
        if self.mask is not None:  # (N, 23): enough frames observed for a free fit
            coef = coef * (self.mask.sum(1) >= max(4 * K, FREE_SHARE * T))[..., None, None]
        self._set_offset(coef, torch.zeros_like(var))

    def update(self, x_hat: torch.Tensor) -> None:
        """Noise precisions, then the offset's coefficients, then each group's offset scale,
        for the decoded states x_hat (N, T, 138) (no gradients kept). The first call begins
        with :meth:`start`."""
        cfg, a0 = self.cfg, self.cfg.lam / 2
        x_hat = x_hat.detach()
        if not self.started:
            self.start(x_hat)
        res = observation_residuals(x_hat, self.obs)
        r = res + self.offset[..., GROUP_COLUMNS].unflatten(-1, (NUM_GROUPS, 3))
        b0 = a0 * self.units**2
        if cfg.outlier_dof > 0:
            self._reweight(r, a0, b0)
        else:
            self.precision = noise_precision(r**2, self.mask, a0, b0)
        if not bool(self.has_offset.any()):
            return
        prior = self.offset_precision[..., None] * self.relative  # (N, 23, K)
        coef, var = offset_coefficients(res, self.precision, self.weights, self.basis, prior)
        self._set_offset(coef, var)

    def _set_offset(self, coef: torch.Tensor, var: torch.Tensor) -> None:
        """Keep the coefficients' posterior (mean (N, 23, 3, K), variance (N, 23, K)) of the
        groups that have an offset: the offset states, and each group's E[1/s_g^2]."""
        s0 = self.cfg.offset_lam / 2
        coef = coef * self.has_offset[:, None, None]
        precision = offset_precision(coef, var, self.relative, s0, s0 * self.offset_std**2)
        self.offset_precision = torch.where(self.has_offset, precision, self.offset_precision)
        self.offset = offset_states(coef, self.basis, self.obs)

    def _reweight(self, r: torch.Tensor, a0: float, b0: torch.Tensor) -> None:
        """Student-t noise (``cfg.outlier_dof`` > 0): each frame's weight from the group's last
        noise precision, then the precision from the weighted residuals; ``self.weights``
        becomes mask x weight, which every solver and the ELBO read. r: (N, T, 23, 3)."""
        sq = (r**2).sum(-1)  # (N, T, 23)
        mask = self.mask if self.mask is not None else torch.ones_like(sq)
        weight = torch.ones_like(sq)
        if self.precision is not None:
            weight = student_t_weights(sq, self.precision, self.cfg.outlier_dof)
        n, s = 3.0 * mask.sum(1), (mask * weight * sq).sum(1)
        self.precision = (a0 + 0.5 * n) / (b0 + 0.5 * s)
        self.weights = mask * weight

    def reconstruction(self, x_hat: torch.Tensor) -> torch.Tensor:
        """The ELBO's expected negative log-likelihood (up to constants), summed: a scalar."""
        r = observation_residuals(x_hat + self.offset, self.obs)
        w = self.precision[:, None]
        if self.weights is not None:
            w = self.weights * w
        return 0.5 * (r**2 * w[..., None]).sum()


@torch.no_grad()
def add_offset(
    x_hat: torch.Tensor, obs: torch.Tensor, joint_weight: torch.Tensor | None, cfg: RefineConfig
) -> torch.Tensor:
    """Decoded states plus the slow offset fitted to the observations in closed form with the
    latents held (``cfg.offset_iterations`` rounds; none when both offset scales are 0).

    x_hat, obs: (N, T+1, 138) state units; joint_weight: (N, T+1, 22) or None -> (N, T+1, 138)
    """
    factors = ClosedFormFactors(obs, joint_weight, cfg)
    for _ in range(cfg.offset_iterations if any(offset_scales(cfg)) else 0):
        factors.update(x_hat)
    return x_hat + factors.offset
