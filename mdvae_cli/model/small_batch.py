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

Weights are copied when the regressor is built; ``small_batch_regressor`` keeps one per
denoiser and rebuilds it when the weights change (optimisation mode fine-tunes them).
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np
import torch

from mdvae_cli.model.denoiser import Denoiser, line_start_weights


def _np(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().cpu().numpy(), dtype=np.float32)


def _silu(a: np.ndarray) -> np.ndarray:
    return a / (1.0 + np.exp(-a))


def gate_weights(w_ih, w_hh, b_ih, b_hh) -> tuple[np.ndarray, ...]:
    """A GRU's weights laid out for :func:`gru_update` (torch's gate order r, z, n).

    -> (W_i (I, 3H), b_i (3H,), W_h (H, 3H), b_hn (H,)): the reset and update columns negated,
    with both biases of those gates folded into b_i; b_hn is the hidden bias of the new gate
    (it sits inside the reset product, so it cannot be folded)."""
    H = w_hh.shape[1]
    sign = np.ones(3 * H, dtype=np.float32)
    sign[: 2 * H] = -1.0
    b_i = _np(b_ih).copy()
    b_i[: 2 * H] += _np(b_hh)[: 2 * H]
    c = np.ascontiguousarray  # row-major (in, out): the faster layout for x @ W on a vector
    return c(_np(w_ih).T * sign), b_i * sign, c(_np(w_hh).T * sign), _np(b_hh)[2 * H :].copy()


def gru_update(gi: np.ndarray, gh: np.ndarray, h: np.ndarray, b_hn: np.ndarray) -> np.ndarray:
    """One GRU step from the gate pre-activations of :func:`gate_weights`.

    gi = x W_i + b_i, gh = h W_h: (..., 3H) with the reset and update gates negated, so that
    sigmoid(a) = 1 / (1 + exp(gi + gh)) costs no negation; h: (..., H) -> (..., H)
    """
    H = h.shape[-1]
    ru = 1.0 / (1.0 + np.exp(gi[..., : 2 * H] + gh[..., : 2 * H]))  # reset, update gates
    n = np.tanh(gi[..., 2 * H :] + ru[..., :H] * (gh[..., 2 * H :] + b_hn))
    return n + ru[..., H:] * (h - n)


class _GRU:
    """A one-layer GRU's weights in the layout of :func:`gate_weights`."""

    def __init__(self, w_ih, w_hh, b_ih, b_hh):
        self.w_i, self.b_i, self.w_h, self.b_hn = gate_weights(w_ih, w_hh, b_ih, b_hh)

    @classmethod
    def of(cls, rnn: torch.nn.GRU) -> _GRU:
        return cls(rnn.weight_ih_l0, rnn.weight_hh_l0, rnn.bias_ih_l0, rnn.bias_hh_l0)

    def run(self, x: np.ndarray, h: np.ndarray) -> np.ndarray:
        """Forward over time.  x: (..., T, I), h: (..., H) initial state -> states (..., T, H)
        (a single sequence may drop the batch axis: numpy's per-call cost is lower on vectors)."""
        gi = x @ self.w_i + self.b_i  # all input projections at once
        out = np.empty((*x.shape[:-1], h.shape[-1]), dtype=np.float32)
        for t in range(x.shape[-2]):
            h = gru_update(gi[..., t, :], h @ self.w_h, h, self.b_hn)
            out[..., t, :] = h
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
        # the head's first layer, negated (see encode_decode): columns [g_t | h_t, hd_t | x_t]
        w = -_np(enc.head[0].weight)
        self.head_g, self.head_x, self.head_b = w[:, :H].T, w[:, 3 * H :].T, -_np(enc.head[0].bias)
        # the head's output layer, latent means only (the log-variances are not needed)
        self.head_out_w = np.ascontiguousarray(-_np(enc.head[2].weight)[: self.L].T)
        self.head_out_b = _np(enc.head[2].bias)[: self.L]
        cell, rnn = enc.cell, dec.rnn
        enc_i, self.enc_bi, enc_h, self.enc_bhn = gate_weights(
            cell.weight_ih, cell.weight_hh, cell.bias_ih, cell.bias_hh
        )
        dec_i, dec_bi, dec_h, self.dec_bhn = gate_weights(
            rnn.weight_ih_l0, rnn.weight_hh_l0, rnn.bias_ih_l0, rnn.bias_hh_l0
        )
        # the loop carries the pair (hd_{t-1}, h_t) as one array and multiplies it by one stacked
        # weight (see encode_decode): [head term | W_h] for the decoder state and the encoder's
        self.w_pair = np.ascontiguousarray(
            np.stack(
                [
                    np.concatenate([w[:, 2 * H : 3 * H].T, dec_h], axis=-1),
                    np.concatenate([w[:, H : 2 * H].T, enc_h], axis=-1),
                ]
            )
        )  # (2, H, M + 3H)
        self.b_hn_pair = np.stack([self.dec_bhn, self.enc_bhn])  # (2, H)
        self.enc_h = enc_h
        # z_t @ [W_i dec | W_i enc]: the gate inputs of both halves of the pair at once
        self.w_z = np.ascontiguousarray(np.concatenate([dec_i, enc_i], axis=-1))
        self.b_z = np.concatenate([dec_bi, self.enc_bi])
        # decoder: initial state and head on [hd_t, z_t]
        self.dec_init = _Linear(dec.init[0])
        self.dec_head = (_Linear(dec.head[0]), _Linear(dec.head[2]))

    def x0_mean(self, yn: np.ndarray) -> np.ndarray:
        """Posterior mean of normalised x0.  yn: (..., T+1, D) -> (..., D)"""
        h0 = np.zeros((*yn.shape[:-2], self.x0_rnn.w_h.shape[0]), dtype=np.float32)
        summary = self.x0_rnn.run(yn[..., ::-1, :], h0)[..., -1, :]
        n = min(self.x0_base_window, yn.shape[-2])
        w = line_start_weights(n).numpy()
        base = np.einsum("k,...kd->...d", w, yn[..., :n, :]).astype(np.float32)
        first, last = self.x0_head
        out = last(_silu(first(np.concatenate([summary, base], axis=-1))))
        return base + out[..., : base.shape[-1]]

    def encode_decode(self, x: np.ndarray, x0: np.ndarray) -> np.ndarray:
        """Posterior-mean latents decoded.  x: (..., T, D), x0: (..., D) -> means (..., T, D)

        Step t reads the encoder state h_t and the decoder state hd_{t-1} to give z_t; from z_t
        both advance: hd_t (decoder) and h_{t+1} (encoder). The loop therefore carries the
        pair (hd_{t-1}, h_t) as one (..., 2, H) array, and each step is one stacked product,
        the head, and one GRU update of both halves. The encoder head's pre-activation is
        computed negated (its weights are stored so), for silu(a) = -(-a / (1 + exp(-a)))
        without a negation per step; the output layer's weights carry the sign back."""
        T = x.shape[-2]
        back = self.enc_backward.run(x[..., ::-1, :], np.tanh(self.enc_backward_init(x0)))
        g_part = back[..., ::-1, :] @ self.head_g + x @ self.head_x + self.head_b  # (..., T, M)
        H, M = self.H, self.head_g.shape[1]
        h0 = np.tanh(self.enc_init(x0))
        h1 = gru_update(self.enc_bi, h0 @ self.enc_h, h0, self.enc_bhn)  # z_0 = 0
        pair = np.stack([np.tanh(self.dec_init(x0)), h1], axis=-2)  # (hd_0, h_1)
        zs = np.empty((*x.shape[:-1], self.L), dtype=np.float32)
        hds = np.empty((*x.shape[:-1], H), dtype=np.float32)
        for t in range(T):
            prod = (pair[..., None, :] @ self.w_pair)[..., 0, :]  # (..., 2, M + 3H)
            neg = g_part[..., t, :] + prod[..., 0, :M] + prod[..., 1, :M]  # -(pre-activation)
            z = (neg / (1.0 + np.exp(neg))) @ self.head_out_w + self.head_out_b
            gates_in = (z @ self.w_z + self.b_z).reshape(*z.shape[:-1], 2, 3 * H)
            pair = gru_update(gates_in, prod[..., M:], pair, self.b_hn_pair)  # (hd_t, h_{t+1})
            zs[..., t, :] = z
            hds[..., t, :] = pair[..., 0, :]
        first, last = self.dec_head
        return x0[..., None, :] + last(_silu(first(np.concatenate([hds, zs], axis=-1))))

    def states(self, yn: np.ndarray) -> np.ndarray:
        """Denormalised posterior-mean states.  yn: (..., T+1, D) normalised -> (..., T+1, D)

        A gate's exp may overflow on a wild input: inf gives the gate's limit (0 or 1), as
        torch's sigmoid does, so numpy is not let warn of it."""
        with np.errstate(over="ignore"):
            x0 = self.x0_mean(yn)
            x_mean = self.encode_decode(yn[..., 1:, :], x0)
        x_hat_n = np.concatenate([x0[..., None, :], x_mean], axis=-2)
        return x_hat_n * self.std + self.mean

    def __call__(self, yn: np.ndarray) -> np.ndarray:
        """Denormalised posterior-mean states.  yn: (B, T+1, D) normalised -> (B, T+1, D)"""
        yn = np.asarray(yn, dtype=np.float32)
        if yn.shape[0] == 1:  # one window: vectors, not (1, n) rows, cost less per operation
            return self.states(yn[0])[None]
        return self.states(yn)


def small_batch_regressor(denoiser: Denoiser) -> SmallBatchRegressor:
    """The denoiser's numpy regressor, built on first use and kept on the denoiser until its
    weights change (a lone clip would otherwise spend ~1 ms copying weights).

    A change is seen through each parameter's and buffer's storage and torch version counter,
    which every in-place update moves (optimiser steps, ``load_state_dict``, ``copy_``), and a
    copy of the denoiser has storage of its own. The tensors are listed once (walking the
    module tree costs about as much as the copy it saves). Writes through ``tensor.data`` bypass
    the counter, and replacing a sub-module or parameter is not seen: build a
    ``SmallBatchRegressor`` directly after those.
    """
    cached = getattr(denoiser, "_small_batch_regressor", None)
    if cached is None:
        tensors = [*denoiser.parameters(), *denoiser.buffers()]
    else:
        tensors = cached[0]
    key = [(t.data_ptr(), t._version) for t in tensors]
    if cached is None or cached[1] != key:
        cached = (tensors, key, SmallBatchRegressor(denoiser))
        denoiser._small_batch_regressor = cached
    return cached[2]


@contextmanager
def threads_for(num_windows: int, small: int):
    """Run a handful of windows on one CPU thread: for tiny batches, thread synchronisation
    costs more than it saves (a 2-second clip: 21 ms on one thread, 28 ms on two)."""
    before = torch.get_num_threads()
    if num_windows <= small and before > 1:
        torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)
