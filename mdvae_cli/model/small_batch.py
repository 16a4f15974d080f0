"""Regression mode for a handful of windows, in numpy.

``Denoiser.infer`` (torch) is the definition; this module computes the same posterior-mean
states for small batches, where the time goes to per-operation overhead rather than
arithmetic: the encoder is a 60-step sequential loop of two GRU cells and a head (about 20
tiny operations a step), and on a CPU one torch operation on a (1, 128) tensor costs 2-4x a
numpy one. A 2-second clip spends ~20 ms in that loop through torch and ~5 ms here.

Only the denoiser layout that ships is handled (encoder reads the decoder's state and x_t,
decoder head reads z_t, x0 predictor runs backward), on the CPU;
``SmallBatchRegressor.supports`` says whether a denoiser qualifies, and callers fall back to
torch otherwise. Tests pin the two paths
to each other.

Weights are copied when the regressor is built: build a new one after the denoiser changes
(optimisation mode fine-tunes it).
"""

from __future__ import annotations

import numpy as np
import torch

from mdvae_cli.model.denoiser import Denoiser, line_start_weights


def _np(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().cpu().numpy(), dtype=np.float32)


def _sigmoid(a: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-a))


def _silu(a: np.ndarray) -> np.ndarray:
    return a / (1.0 + np.exp(-a))


def gru_update(gi: np.ndarray, gh: np.ndarray, h: np.ndarray) -> np.ndarray:
    """One GRU step from its gate pre-activations (torch's gate order r, z, n).

    gi = x W_ih^T + b_ih, gh = h W_hh^T + b_hh: (B, 3H); h: (B, H) -> (B, H)
    """
    H = h.shape[-1]
    ru = _sigmoid(gi[:, : 2 * H] + gh[:, : 2 * H])  # reset and update gates together
    n = np.tanh(gi[:, 2 * H :] + ru[:, :H] * gh[:, 2 * H :])
    return n + ru[:, H:] * (h - n)


class _GRU:
    """A one-layer GRU's weights, transposed for ``x @ W``."""

    def __init__(self, w_ih, w_hh, b_ih, b_hh):
        self.w_ih, self.w_hh = _np(w_ih).T, _np(w_hh).T
        self.b_ih, self.b_hh = _np(b_ih), _np(b_hh)

    @classmethod
    def of(cls, rnn: torch.nn.GRU) -> _GRU:
        return cls(rnn.weight_ih_l0, rnn.weight_hh_l0, rnn.bias_ih_l0, rnn.bias_hh_l0)

    def run(self, x: np.ndarray, h: np.ndarray) -> np.ndarray:
        """Forward over time.  x: (B, T, I), h: (B, H) initial state -> states (B, T, H)"""
        gi = x @ self.w_ih + self.b_ih  # all input projections at once
        out = np.empty((*x.shape[:2], h.shape[-1]), dtype=np.float32)
        for t in range(x.shape[1]):
            h = gru_update(gi[:, t], h @ self.w_hh + self.b_hh, h)
            out[:, t] = h
        return out


class _Linear:
    def __init__(self, layer: torch.nn.Linear):
        self.w = _np(layer.weight).T
        self.b = _np(layer.bias)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return x @ self.w + self.b


class SmallBatchRegressor:
    """The denoiser's regression mode in numpy: yn (B, T+1, D) -> x_hat (B, T+1, D)."""

    @staticmethod
    def supports(denoiser: Denoiser) -> bool:
        enc, dec = denoiser.encoder, denoiser.prior.dvae.decoder
        return (
            enc.reads_decoder
            and enc.x_skip
            and dec.z_skip
            and not denoiser.x0_predictor.bidirectional
            and next(denoiser.parameters()).device.type == "cpu"
        )

    def __init__(self, denoiser: Denoiser):
        if not self.supports(denoiser):
            raise ValueError("this denoiser's layout has no numpy path; use Denoiser.infer")
        x0p, enc = denoiser.x0_predictor, denoiser.encoder
        dec = denoiser.prior.dvae.decoder
        norm = denoiser.prior.normalizer
        self.mean, self.std = _np(norm.mean), _np(norm.std)
        # x0 predictor: backward GRU summary + line-fit base, head residual
        self.x0_rnn = _GRU.of(x0p.rnn)
        self.x0_base_window = int(x0p.base_weights.shape[0])
        self.x0_head = (_Linear(x0p.head[0]), _Linear(x0p.head[2]))
        # encoder: backward GRU over x_{t:T}, then the sequential loop
        H = enc.cell.hidden_size
        self.H, self.L = H, enc.cell.input_size
        self.enc_backward = _GRU.of(enc.backward_rnn)
        self.enc_backward_init = _Linear(enc.backward_init[0])
        self.enc_init = _Linear(enc.init[0])
        first = enc.head[0]
        w = _np(first.weight)  # (M, H + 2H + D): columns [g_t | h_t, hd_t | x_t]
        self.head_g, self.head_x, self.head_b = w[:, :H].T, w[:, 3 * H :].T, _np(first.bias)
        # the head's output layer, latent means only (the log-variances are not needed)
        self.head_out_w = _np(enc.head[2].weight)[: self.L].T
        self.head_out_b = _np(enc.head[2].bias)[: self.L]
        # each step's products fused by the state they read (see encode_decode):
        # h_t @ [head | W_hh_enc], hd_{t-1} @ [head | W_hh_dec], z_t @ [W_ih_dec | W_ih_enc]
        cell, rnn = enc.cell, dec.rnn
        self.w_h = np.ascontiguousarray(
            np.concatenate([w[:, H : 2 * H].T, _np(cell.weight_hh).T], axis=1)
        )
        self.w_hd = np.ascontiguousarray(
            np.concatenate([w[:, 2 * H : 3 * H].T, _np(rnn.weight_hh_l0).T], axis=1)
        )
        self.w_z = np.ascontiguousarray(
            np.concatenate([_np(rnn.weight_ih_l0).T, _np(cell.weight_ih).T], axis=1)
        )
        self.b_z = np.concatenate([_np(rnn.bias_ih_l0), _np(cell.bias_ih)])
        self.b_hh_enc, self.b_hh_dec = _np(cell.bias_hh), _np(rnn.bias_hh_l0)
        # decoder: initial state and head on [hd_t, z_t]
        self.dec_init = _Linear(dec.init[0])
        self.dec_head = (_Linear(dec.head[0]), _Linear(dec.head[2]))

    def x0_mean(self, yn: np.ndarray) -> np.ndarray:
        """Posterior mean of normalised x0.  yn: (B, T+1, D) -> (B, D)"""
        B = yn.shape[0]
        h0 = np.zeros((B, self.x0_rnn.w_hh.shape[0]), dtype=np.float32)
        summary = self.x0_rnn.run(yn[:, ::-1], h0)[:, -1]
        n = min(self.x0_base_window, yn.shape[1])
        w = line_start_weights(n).numpy()
        base = np.einsum("k,bkd->bd", w, yn[:, :n]).astype(np.float32)
        first, last = self.x0_head
        out = last(_silu(first(np.concatenate([summary, base], axis=-1))))
        return base + out[:, : base.shape[-1]]

    def encode_decode(self, x: np.ndarray, x0: np.ndarray) -> np.ndarray:
        """Posterior-mean latents decoded.  x: (B, T, D), x0: (B, D) -> means (B, T, D)"""
        B, T, _ = x.shape
        g = self.enc_backward.run(x[:, ::-1], np.tanh(self.enc_backward_init(x0)))[:, ::-1]
        g_part = g @ self.head_g + x @ self.head_x + self.head_b  # (B, T, M)
        h = np.tanh(self.enc_init(x0))
        hd = np.tanh(self.dec_init(x0))
        H, M = self.H, self.head_g.shape[1]
        zs = np.empty((B, T, self.L), dtype=np.float32)
        hds = np.empty((B, T, self.H), dtype=np.float32)
        gi_enc = np.broadcast_to(self.b_z[3 * H :], (B, 3 * H))  # z_0 = 0
        gh_enc = h @ self.w_h[:, M:] + self.b_hh_enc
        for t in range(T):
            h = gru_update(gi_enc, gh_enc, h)
            h_part = h @ self.w_h  # head term of h_t, and W_hh_enc h_t for step t + 1
            hd_part = hd @ self.w_hd  # head term of hd_{t-1}, and W_hh_dec hd_{t-1}
            pre = g_part[:, t] + h_part[:, :M] + hd_part[:, :M]
            z = _silu(pre) @ self.head_out_w + self.head_out_b
            z_part = z @ self.w_z + self.b_z  # W_ih_dec z_t now, W_ih_enc z_t for step t + 1
            hd = gru_update(z_part[:, : 3 * H], hd_part[:, M:] + self.b_hh_dec, hd)
            gi_enc, gh_enc = z_part[:, 3 * H :], h_part[:, M:] + self.b_hh_enc
            zs[:, t] = z
            hds[:, t] = hd
        first, last = self.dec_head
        return x0[:, None] + last(_silu(first(np.concatenate([hds, zs], axis=-1))))

    def __call__(self, yn: np.ndarray) -> np.ndarray:
        """Denormalised posterior-mean states.  yn: (B, T+1, D) normalised -> (B, T+1, D)"""
        yn = np.asarray(yn, dtype=np.float32)
        x0 = self.x0_mean(yn)
        x_mean = self.encode_decode(yn[:, 1:], x0)
        x_hat_n = np.concatenate([x0[:, None], x_mean], axis=1)
        return x_hat_n * self.std + self.mean
