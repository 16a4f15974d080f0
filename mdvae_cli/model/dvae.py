"""Motion-DVAE (paper Sec. 3.2): prior, decoder and encoder networks.

All tensors here live in the *normalised canonical* state space (see ``Normalizer``):
x0: (B, D) initial state, x: (B, T, D) states x_1..x_T, z: (B, T, L) latents.

* prior    p(z_t | z_{1:t-1}, x0) = N(mu, sigma): forward GRU over past latents, h_0 = f(x0).
* decoder  p(x_t | z_{1:t}, x0) = N(mu_x, sigma_x^2 I): forward GRU over latents, h_0 = g(x0),
  head on [h_t, z_t]; it never sees past x (cheap sampling, no posterior collapse).
* encoder  q(z_t | z_{1:t-1}, x_{t:T}, x0): backward GRU over x_{t:T} combined with a forward
  GRU over the sampled z_{1:t-1}, h_0 = e(x0), and (``encoder_reads_decoder``) the decoder's own
  state after z_{1:t-1}, so it sees what the decoder still needs to be told.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import nn

from mdvae_cli.model.config import ModelConfig
from mdvae_cli.model.recurrent import encoder_loop

#: windows at most for the encoder's loop to run as one function with its backward written out
#: (``recurrent.encoder_loop``) when a gradient is to come, on a CPU: on two cores its forward
#: and backward at batch 64 took 91 ms against autograd's 103, at 128 the same, at 256 328
#: against 281 (its whole-window buffers, fresh memory each step, fault in page by page:
#: ``recurrent``). Larger batches, GPUs (where the step is captured as a CUDA graph; the
#: function there untried) and inference (no gradient: the recorded loop's forward alone took
#: 27 ms at 64 windows against the function's 37-44) step as written below.
FUSED_MAX_BATCH = 96


def mlp(d_in: int, d_hidden: int, d_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(d_in, d_hidden), nn.SiLU(), nn.Linear(d_hidden, d_out))


@dataclass
class Gaussian:
    """Diagonal Gaussian.  mean, logvar: (..., L)"""

    mean: torch.Tensor
    logvar: torch.Tensor

    def sample(self, generator: torch.Generator | None = None) -> torch.Tensor:
        eps = torch.randn(
            self.mean.shape, generator=generator, dtype=self.mean.dtype, device=self.mean.device
        )
        return self.mean + torch.exp(0.5 * self.logvar) * eps


class Prior(nn.Module):
    """p(z_t | z_{1:t-1}, x0)."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.init = nn.Sequential(nn.Linear(cfg.state_dim, cfg.hidden_dim), nn.Tanh())
        self.rnn = nn.GRU(cfg.latent_dim, cfg.hidden_dim, batch_first=True)
        self.head = mlp(cfg.hidden_dim, cfg.mlp_dim, 2 * cfg.latent_dim)

    def forward(self, z: torch.Tensor, x0: torch.Tensor) -> Gaussian:
        """All T prior distributions given latents (teacher forcing).

        z: (B, T, L) -> Gaussian with (B, T, L) parameters; step t sees z_{1:t-1}.
        """
        z_past = torch.cat([torch.zeros_like(z[:, :1]), z[:, :-1]], dim=1)
        h, _ = self.rnn(z_past, self.init(x0)[None])
        mean, logvar = self.head(h).chunk(2, dim=-1)
        return Gaussian(mean, logvar.clamp(-12.0, 6.0))

    def step(self, z_prev: torch.Tensor, h: torch.Tensor) -> tuple[Gaussian, torch.Tensor]:
        """One step for sampling.  z_prev: (B, L), h: (1, B, H)"""
        out, h = self.rnn(z_prev[:, None], h)
        mean, logvar = self.head(out[:, 0]).chunk(2, dim=-1)
        return Gaussian(mean, logvar.clamp(-12.0, 6.0)), h


class Decoder(nn.Module):
    """mu_theta_x(z_{1:t}, x0): the mean of p(x_t | z_{1:t}, x0)."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.z_skip = cfg.decoder_z_skip
        self.init = nn.Sequential(nn.Linear(cfg.state_dim, cfg.hidden_dim), nn.Tanh())
        self.rnn = nn.GRU(cfg.latent_dim, cfg.hidden_dim, batch_first=True)
        head_in = cfg.hidden_dim + (cfg.latent_dim if self.z_skip else 0)
        self.head = mlp(head_in, cfg.mlp_dim, cfg.state_dim)

    def forward(self, z: torch.Tensor, x0: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """z: (B, T, L), x0: (B, D) -> mean states (B, T, D) and hidden states (B, T, H).

        The mean is a residual on x0, so an untrained decoder already stays near the start;
        with ``decoder_z_skip`` the head reads [h_t, z_t] (the usual DVAE generation head).
        """
        h, _ = self.rnn(z, self.init(x0)[None])
        return self.output(h, z, x0), h

    def output(self, h: torch.Tensor, z: torch.Tensor, x0: torch.Tensor) -> torch.Tensor:
        """The mean from recurrent states.  h: (B, T, H), z: (B, T, L), x0: (B, D) -> (B, T, D)"""
        head_in = torch.cat([h, z], dim=-1) if self.z_skip else h
        return x0[:, None] + self.head(head_in)


class Encoder(nn.Module):
    """q_phi(z_t | z_{1:t-1}, x_{t:T}, x0)."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        H = cfg.hidden_dim
        self.reads_decoder = cfg.encoder_reads_decoder
        self.x_skip = cfg.encoder_x_skip
        self.backward_rnn = nn.GRU(cfg.state_dim, H, batch_first=True)
        self.backward_init = nn.Sequential(nn.Linear(cfg.state_dim, H), nn.Tanh())
        self.init = nn.Sequential(nn.Linear(cfg.state_dim, H), nn.Tanh())
        self.cell = nn.GRUCell(cfg.latent_dim, H)
        # head input [g_t, h_t, (decoder state), (x_t)]: older layouts are a prefix of this one
        width = (3 if self.reads_decoder else 2) * H + (cfg.state_dim if self.x_skip else 0)
        self.head = mlp(width, cfg.mlp_dim, 2 * cfg.latent_dim)

    def forward(
        self,
        x: torch.Tensor,
        x0: torch.Tensor,
        sample: bool = True,
        generator: torch.Generator | None = None,
        decoder: Decoder | None = None,
        decoder_states: bool = False,
    ):
        """Sample (or take the mean of) z_1..z_T sequentially.

        x: (B, T, D), x0: (B, D) -> z (B, T, L) and the posteriors (B, T, L), plus, with
        ``decoder_states``, the decoder's recurrent states h_1..h_T (B, T, H) it stepped along.
        ``decoder`` is required when the encoder reads the decoder's state: it is stepped along
        (its weights are used, not changed).
        """
        if self.reads_decoder and decoder is None:
            raise ValueError("this encoder reads the decoder's state: pass decoder=")
        g, _ = self.backward_rnn(x.flip(1), self.backward_init(x0)[None])
        g = g.flip(1)  # g_t summarises x_{t:T}
        # the head's first layer on [g_t, h_t, hd_t, x_t]: the g_t and x_t parts for all t at once
        first, rest = self.head[0], self.head[1:]
        H = g.shape[-1]
        S = (2 if self.reads_decoder else 1) * H
        g_part = nn.functional.linear(g, first.weight[:, :H], first.bias)
        if self.x_skip:
            g_part = g_part + nn.functional.linear(x, first.weight[:, H + S :])
        if (self.reads_decoder and torch.is_grad_enabled() and x.device.type == "cpu"
                and x.shape[0] <= FUSED_MAX_BATCH):  # fmt: skip
            eps = None
            if sample:
                B, T = x.shape[:2]
                eps = torch.randn((T, B, self.cell.input_size), generator=generator,
                                  dtype=x.dtype, device=x.device).transpose(0, 1)  # fmt: skip
            z, mean, logvar, hds = encoder_loop(self.cell, first.weight[:, H : H + S], rest[-1],
                                                decoder.rnn, g_part, self.init(x0),
                                                decoder.init(x0), eps)  # fmt: skip
            posterior = Gaussian(mean, logvar)
            return (z, posterior, hds) if decoder_states else (z, posterior)
        steps = EncoderSteps(self.cell, first.weight[:, H : H + S], decoder)
        h, hd = self.init(x0), (decoder.init(x0) if self.reads_decoder else None)
        zs, means, logvars, hds = [], [], [], []
        # one view per frame: indexing g_part[:, t] in the loop costs a full-size gradient each
        for t, g_t in enumerate(g_part.unbind(1)):
            h = steps.encoder_state(h)
            pre = g_t + steps.state_part(h, hd)
            mean, logvar = rest(pre).chunk(2, dim=-1)
            logvar = logvar.clamp(-12.0, 6.0)
            if sample:
                eps = torch.randn(
                    mean.shape, generator=generator, dtype=mean.dtype, device=mean.device
                )
                z = mean + torch.exp(0.5 * logvar) * eps
            else:
                z = mean
            hd = steps.take_latent(z, hd, last=t == x.shape[1] - 1)
            if hd is not None:
                hds.append(hd)
            zs.append(z)
            means.append(mean)
            logvars.append(logvar)
        stack = lambda v: torch.stack(v, dim=1)  # noqa: E731
        if decoder_states:
            return stack(zs), Gaussian(stack(means), stack(logvars)), stack(hds)
        return stack(zs), Gaussian(stack(means), stack(logvars))


def gru_update(gi: torch.Tensor, gh: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
    """One GRU update from its two projections (PyTorch's equations, gates in r, z, n order).

    gi = W_i x + b_i, gh = W_h h + b_h: (B, 3H); h: (B, H) -> h' (B, H)
    """
    i_r, i_z, i_n = gi.chunk(3, dim=-1)
    h_r, h_z, h_n = gh.chunk(3, dim=-1)
    r = torch.sigmoid(i_r + h_r)
    u = torch.sigmoid(i_z + h_z)
    n = torch.tanh(i_n + r * h_n)
    return n + u * (h - n)


class EncoderSteps:
    """The encoder's sequential loop with its matrix products fused: each step multiplies
    each of its three changing vectors (h_t, hd_{t-1}, z_t) once, by the weights of every
    network that reads it, instead of six separate products (same equations as
    ``nn.GRUCell`` / ``torch.gru_cell``; the order of the products differs, so results
    agree to float rounding).

    ``cell``: the encoder's GRUCell over z_{t-1}; ``w_state``: (M, H) or (M, 2H), the head's
    first-layer columns for [h_t] or [h_t, hd_t]; ``decoder``: the decoder whose GRU the
    encoder steps along, or None.
    """

    def __init__(self, cell: nn.GRUCell, w_state: torch.Tensor, decoder: Decoder | None):
        H = cell.hidden_size
        self.M = w_state.shape[0]
        self.G = 3 * H
        self.reads_decoder = w_state.shape[1] == 2 * H
        # h_t -> [state columns | the encoder cell's hidden projection for step t+1]
        self.w_h = torch.cat([w_state[:, :H], cell.weight_hh], dim=0)
        self.b_h = torch.cat([cell.bias_hh.new_zeros(self.M), cell.bias_hh])
        self.cell = cell
        self.gi = cell.bias_ih.expand(1, -1)  # z_0 = 0: the input projection is its bias
        self.gh = None
        if self.reads_decoder:
            rnn = decoder.rnn
            # hd_{t-1} -> [the decoder GRU's hidden projection | state columns]
            self.w_hd = torch.cat([rnn.weight_hh_l0, w_state[:, H:]], dim=0)
            self.b_hd = torch.cat([rnn.bias_hh_l0, rnn.bias_hh_l0.new_zeros(self.M)])
            # z_t -> [the decoder GRU's input projection | the encoder cell's, for step t+1]
            self.w_z = torch.cat([rnn.weight_ih_l0, cell.weight_ih], dim=0)
            self.b_z = torch.cat([rnn.bias_ih_l0, cell.bias_ih])
            self.hd_proj = None

    def encoder_state(self, h: torch.Tensor) -> torch.Tensor:
        """h_{t-1} (B, H) -> h_t, from z_{t-1}'s projection kept by the previous step."""
        if self.gh is None:  # first step: h_0's projection
            self.gh = nn.functional.linear(h, self.cell.weight_hh, self.cell.bias_hh)
        h_new = gru_update(self.gi, self.gh, h)
        both = torch.addmm(self.b_h, h_new, self.w_h.t())
        self.state_h, self.gh = both[:, : self.M], both[:, self.M :]
        return h_new

    def state_part(self, h: torch.Tensor, hd: torch.Tensor | None) -> torch.Tensor:
        """The head's first layer on [h_t, hd_{t-1}] (B, M); h_t's part is already made."""
        if hd is None:
            return self.state_h
        both = torch.addmm(self.b_hd, hd, self.w_hd.t())
        self.hd_proj = both[:, : self.G]
        return self.state_h + both[:, self.G :]

    def take_latent(self, z: torch.Tensor, hd: torch.Tensor | None, last: bool):
        """Feed z_t (B, L): the decoder's state hd_t (or None), and the encoder cell's input
        projection for step t+1 (skipped after the last step)."""
        if hd is None:
            if not last:
                self.gi = nn.functional.linear(z, self.cell.weight_ih, self.cell.bias_ih)
            return None
        both = torch.addmm(self.b_z, z, self.w_z.t())
        self.gi = both[:, self.G :]
        return gru_update(both[:, : self.G], self.hd_proj, hd)


class MotionDVAE(nn.Module):
    """The generative model (prior + decoder) and its inference network (encoder)."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg
        self.prior = Prior(cfg)
        self.decoder = Decoder(cfg)
        self.encoder = Encoder(cfg)

    def forward(
        self,
        x: torch.Tensor,
        x0: torch.Tensor,
        sample: bool = True,
        generator: torch.Generator | None = None,
    ):
        """Encode then decode.  x: (B, T, D), x0: (B, D) ->
        (x_mean (B, T, D), z (B, T, L), posterior, prior)."""
        x_mean, z, posterior, _ = self.encode_decode(x, x0, sample, generator)
        return x_mean, z, posterior, self.prior(z, x0)

    def encode_decode(
        self,
        x: torch.Tensor,
        x0: torch.Tensor,
        sample: bool = True,
        generator: torch.Generator | None = None,
        encoder: Encoder | None = None,
    ):
        """z ~ q(z | x, x0) (or its mean) and the decoder's means.  x: (B, T, D), x0: (B, D) ->
        (x_mean (B, T, D), z (B, T, L), posterior, decoder states h (B, T, H)).

        ``encoder`` replaces the model's own (the denoiser's fine-tuned copy). An encoder that
        steps the decoder along hands over its states, so the decoder's GRU is not run twice.
        """
        encoder = self.encoder if encoder is None else encoder
        if encoder.reads_decoder:
            z, posterior, h = encoder(
                x, x0, sample, generator, decoder=self.decoder, decoder_states=True
            )
            return self.decoder.output(h, z, x0), z, posterior, h
        z, posterior = encoder(x, x0, sample=sample, generator=generator)
        x_mean, h = self.decoder(z, x0)
        return x_mean, z, posterior, h

    @torch.no_grad()
    def sample(
        self,
        x0: torch.Tensor,
        num_frames: int,
        generator: torch.Generator | None = None,
        temperature: float = 1.0,
        particles: int = 1,
        log_weight: Callable[[torch.Tensor, torch.Tensor], torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """Generate x_1..x_T from the prior alone.  x0: (B, D) -> (B, T, D) decoder means.

        ``temperature`` scales the prior's standard deviations (1 = exact prior samples;
        below 1 trades diversity for smoother, more typical motion).

        With ``log_weight`` (a constraint on the motion, e.g. feet above the floor) the sample
        approximates the prior conditioned on it, p(x | x0) prod_t exp(log_weight(x_t, x_{t-1})):
        a particle filter runs ``particles`` prior samples side by side, weights each frame by
        log_weight (decoded states and the frame before, each (B, M, D), x_0 = x0 -> (B, M)),
        resamples the particles when the weights degenerate, and returns one particle drawn by
        its weight. A constraint that never binds leaves exact prior samples.
        """
        log_scale = math.log(max(temperature, 1e-6))
        if log_weight is not None:
            return self._sample_conditioned(
                x0, num_frames, generator, log_scale, max(particles, 1), log_weight
            )
        h_prior = self.prior.init(x0)[None]
        z_prev = x0.new_zeros(x0.shape[0], self.cfg.latent_dim)
        zs = []
        for _ in range(num_frames):
            dist, h_prior = self.prior.step(z_prev, h_prior)
            z_prev = Gaussian(dist.mean, dist.logvar + 2.0 * log_scale).sample(generator)
            zs.append(z_prev)
        x_mean, _ = self.decoder(torch.stack(zs, dim=1), x0)
        return x_mean

    def _sample_conditioned(
        self,
        x0: torch.Tensor,
        num_frames: int,
        generator: torch.Generator | None,
        log_scale: float,
        M: int,
        log_weight: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    ) -> torch.Tensor:
        """:meth:`sample` under a constraint: a bootstrap particle filter with M particles per
        sample, each an exact prior draw (prior standard deviations times exp(log_scale)),
        weighted by the constraint and resampled when the weights degenerate.
        x0: (B, D) -> (B, T, D)"""
        B = x0.shape[0]
        h_prior = self.prior.init(x0)[None]
        z_prev = x0.new_zeros(B, self.cfg.latent_dim)
        rep = lambda t, dim=0: t.repeat_interleave(M, dim=dim)  # noqa: E731
        x0_m, h_prior = rep(x0), rep(h_prior, dim=1)
        h_dec, z_prev = rep(self.decoder.init(x0)[None], dim=1), rep(z_prev)
        logw = x0.new_zeros(B, M)
        base = (torch.arange(B, device=x0.device) * M)[:, None]
        # frame t as drawn, and which particle each survivor of frame t's resampling came from
        xs: list[torch.Tensor] = []
        parents: list[torch.Tensor | None] = []
        prev = x0_m
        for _ in range(num_frames):
            dist, h_prior = self.prior.step(z_prev, h_prior)
            z_prev = Gaussian(dist.mean, dist.logvar + 2.0 * log_scale).sample(generator)
            out, h_dec = self.decoder.rnn(z_prev[:, None], h_dec)
            x = self.decoder.output(out, z_prev[:, None], x0_m)[:, 0]  # (B*M, D)
            xs.append(x)
            logw = logw + log_weight(x.unflatten(0, (B, M)), prev.unflatten(0, (B, M)))
            w = torch.softmax(logw, dim=1)
            pick = None
            if (1.0 / (w**2).sum(dim=1)).min() < 0.5 * M:  # effective sample size
                pick = base + torch.multinomial(w, M, replacement=True, generator=generator)
                pick = pick.flatten()
                h_prior, h_dec, z_prev, x = h_prior[:, pick], h_dec[:, pick], z_prev[pick], x[pick]
                logw = torch.zeros_like(logw)
            parents.append(pick)
            prev = x
        w = torch.softmax(logw, dim=1)
        idx = base[:, 0] + torch.multinomial(w, 1, generator=generator)[:, 0]
        path = []
        for x, pick in zip(reversed(xs), reversed(parents), strict=True):  # trace back
            idx = idx if pick is None else pick[idx]
            path.append(x[idx])
        return torch.stack(path[::-1], dim=1)
