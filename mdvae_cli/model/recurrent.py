"""The encoder's sequential loop as one autograd function, its backward through time written out.

The encoder (paper Sec. 3.2, ``q(z_t | z_{1:t-1}, x_{t:T}, x0)``, in the layout that reads the
decoder's state) steps two GRU cells and a head along the window, one frame after the other.
Recorded operation by operation, autograd keeps ~40 small operations a frame and replays each
one's backward with its own bookkeeping. Here the forward runs without recording and keeps what
the backward needs; the backward forms the gates' derivative factors for all frames at once,
walks the frames back in ~20 operations each, and makes each weight's gradient with one
product over all frames. Same equations as ``nn.GRUCell`` (gates in r, z, n order); results
agree with autograd's to float rounding (``tests/test_recurrent.py``). On two CPU cores, at
batch 64 (60 frames), the whole encoder's forward and backward take 91 ms against 103 recorded by
autograd; its small products (64 rows) already run near the cores' rate, so that is what there
was to gain. At 128 windows the two are even and at 256 this is slower (328 against 281 ms):
its whole-window buffers are fresh memory every step, which glibc maps anew above its mmap
threshold (32 MB at most) and the first writes fault in page by page (with
``MALLOC_MMAP_THRESHOLD_=1000000000`` it is 248 against 276 ms there). For the same reason its
forward alone is slower than the loop run without recording. So the encoder runs it on a CPU
for small batches, and only when a gradient is to come (``dvae.FUSED_MAX_BATCH``). (The same
for a plain GRU layer was slower than ``nn.GRU``.)

One frame t of the encoder, with ``h`` its state, ``hd`` the decoder's, ``G = 3H``:

* ``h_t = gru(gi_t, gh_t, h_{t-1})``: ``gi_t`` is z_{t-1}'s input projection (the bias for
  t = 1), ``gh_t`` h_{t-1}'s hidden projection;
* ``[s_t | gh_{t+1}] = W_h h_t + b_h`` and ``[hp_t | s'_t] = W_hd hd_{t-1} + b_hd``;
* ``pre_t = g_t + s_t + s'_t``, ``[mean_t | raw_t] = W_out silu(pre_t) + b_out``,
  ``logvar_t = clamp(raw_t, -12, 6)``, ``z_t = mean_t + exp(logvar_t / 2) eps_t`` (or the
  mean);
* ``[gd_t | gi_{t+1}] = W_z z_t + b_z`` and ``hd_t = gru(gd_t, hp_t, hd_{t-1})``.
"""

from __future__ import annotations

import torch
from torch import nn

#: the clamp on the latents' log-variances (as the prior's)
LOGVAR_RANGE = (-12.0, 6.0)


def _gru(gi: torch.Tensor, gh: torch.Tensor, h: torch.Tensor, ru: torch.Tensor, n: torch.Tensor,
         out: torch.Tensor) -> None:  # fmt: skip
    """One GRU update from its two projections, written into the buffers given (a window's
    frame each: no copies later).  gi, gh: (B, 3H); h: (B, H) -> out: h' (B, H), with what its
    backward needs: ru, the r and u gates (B, 2H), and n, the candidate (B, H)."""
    H = h.shape[-1]
    torch.add(gi[:, : 2 * H], gh[:, : 2 * H], out=ru).sigmoid_()
    torch.addcmul(gi[:, 2 * H :], ru[:, :H], gh[:, 2 * H :], out=n).tanh_()
    torch.sub(h, n, out=out).mul_(ru[:, H:]).add_(n)


def _gru_factors(ru: torch.Tensor, n: torch.Tensor, hn: torch.Tensor, h_prev: torch.Tensor):
    """A GRU's derivative factors for every frame at once (T, B, H each): with dh the gradient
    of h', the n gate's pre-activation gets dh k_n, u's dh k_u, r's (dh k_n) k_r, h dh u, and
    the hidden projection's n part (dh k_n) r.  ru: (T, B, 2H); n, hn (the hidden projection's
    n part), h_prev: (T, B, H)"""
    H = n.shape[-1]
    r, u = ru[..., :H], ru[..., H:]
    k_n = (1 - u) * (1 - n * n)
    k_u = (h_prev - n) * u * (1 - u)
    k_r = hn * r * (1 - r)
    return k_n, k_u, k_r, u, r


def _gru_back(dh, t, factors, d_gi, d_gh):
    """Frame t of a GRU's backward: dh (B, H) the gradient of h'; writes the gradients of gi
    and gh into ``d_gi``, ``d_gh`` (B, 3H views) and returns h's share (B, H)."""
    k_n, k_u, k_r, u, r = factors
    H = dh.shape[-1]
    dn = torch.mul(dh, k_n[t], out=d_gi[:, 2 * H :])
    torch.mul(dh, k_u[t], out=d_gi[:, H : 2 * H])
    torch.mul(dn, k_r[t], out=d_gi[:, :H])
    d_gh[:, : 2 * H].copy_(d_gi[:, : 2 * H])
    torch.mul(dn, r[t], out=d_gh[:, 2 * H :])
    return dh * u[t]


class EncoderLoop(torch.autograd.Function):
    """``apply(g_part, eps, h0, hd0, gi0, gh0, w_h, b_h, w_hd, b_hd, w_z, b_z, w_out, b_out,
    keep_for_backward)`` -> z, mean, logvar (B, T, L) and the decoder's states hd_1..hd_T
    (B, T, H); ``keep_for_backward`` False (no gradient to come) saves nothing for a backward.

    g_part: (B, T, M) the head's first layer on what does not recur ([g_t, x_t], with its
    bias); eps: (B, T, L) the samples' noise, or None for the means; h0, hd0: (B, H); gi0:
    (1, 3H) or (B, 3H) and gh0: (B, 3H) the encoder cell's first projections; w_h: (M + 3H, H),
    b_h: (M + 3H,); w_hd: (3H + M, H), b_hd; w_z: (6H, L), b_z; w_out: (2L, M), b_out.
    """

    @staticmethod
    def forward(ctx, g_part, eps, h0, hd0, gi0, gh0, w_h, b_h, w_hd, b_hd, w_z, b_z, w_out,
                b_out, keep_for_backward=True):  # fmt: skip
        B, T, M = g_part.shape
        H, L = h0.shape[-1], w_z.shape[-1]
        G = 3 * H
        lo, hi = LOGVAR_RANGE
        f = {"dtype": g_part.dtype, "device": g_part.device}
        # every frame's results straight into whole-window buffers, time first: the states
        # with their starts (T + 1), each product ([s | gh'], [hp | s'], [gd | gi']), the gates,
        # the head's sigmoid and SiLU, its output, the latents
        hs, hds = torch.empty(T + 1, B, H, **f), torch.empty(T + 1, B, H, **f)
        hs[0], hds[0] = h0, hd0
        both, both2 = torch.empty(T, B, M + G, **f), torch.empty(T, B, G + M, **f)
        both3 = torch.empty(T, B, 2 * G, **f)
        ru, rud = torch.empty(T, B, 2 * H, **f), torch.empty(T, B, 2 * H, **f)
        n, nd = torch.empty(T, B, H, **f), torch.empty(T, B, H, **f)
        sig, a = torch.empty(T, B, M, **f), torch.empty(T, B, M, **f)
        out, z = torch.empty(T, B, 2 * L, **f), torch.empty(T, B, L, **f)
        pre = torch.empty(B, M, **f)
        gi, gh = gi0.expand(B, G), gh0
        for t in range(T):
            _gru(gi, gh, hs[t], ru[t], n[t], hs[t + 1])
            torch.addmm(b_h, hs[t + 1], w_h.t(), out=both[t])
            torch.addmm(b_hd, hds[t], w_hd.t(), out=both2[t])
            torch.add(g_part[:, t], both[t, :, :M], out=pre).add_(both2[t, :, G:])
            torch.mul(pre, torch.sigmoid(pre, out=sig[t]), out=a[t])
            torch.addmm(b_out, a[t], w_out.t(), out=out[t])
            if eps is None:
                z[t] = out[t, :, :L]
            else:
                std = out[t, :, L:].clamp(lo, hi).mul_(0.5).exp_()
                torch.addcmul(out[t, :, :L], std, eps[:, t], out=z[t])
            torch.addmm(b_z, z[t], w_z.t(), out=both3[t])
            _gru(both3[t, :, :G], both2[t, :, :G], hds[t], rud[t], nd[t], hds[t + 1])
            gi, gh = both3[t, :, G:], both[t, :, M:]
        if keep_for_backward:
            # the hidden projections' n parts: h_{t-1}'s (gh0's, then the products') and hd's
            hn = torch.cat([gh0[None, :, 2 * H :], both[:-1, :, M + 2 * H :]])
            ctx.save_for_backward(eps, w_h, w_hd, w_z, w_out, hs, hds, ru, n, hn, rud, nd,
                                  both2[:, :, 2 * H : G], sig, a, out, z)  # fmt: skip
            ctx.gi0_shape = gi0.shape
        return (z.transpose(0, 1), out[..., :L].transpose(0, 1),
                out[..., L:].clamp(lo, hi).transpose(0, 1), hds[1:].transpose(0, 1))  # fmt: skip

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, dz_out, dmean_out, dlogvar_out, dhd_out):
        eps, w_h, w_hd, w_z, w_out, *kept = ctx.saved_tensors
        s = dict(zip(("h", "hd", "ru", "n", "hn", "rud", "nd", "hnd", "sig", "a", "out", "z"),
                     kept, strict=True))  # fmt: skip
        T, B, M = s["a"].shape
        H, L = w_h.shape[-1], w_z.shape[-1]
        G = 3 * H
        lo, hi = LOGVAR_RANGE
        f = {"dtype": s["a"].dtype, "device": s["a"].device}
        # every frame's derivative factors at once
        enc = _gru_factors(s["ru"], s["n"], s["hn"], s["h"][:-1])
        dec = _gru_factors(s["rud"], s["nd"], s["hnd"], s["hd"][:-1])
        silu_grad = torch.addcmul(s["sig"], s["a"], 1 - s["sig"])  # sig + pre sig (1 - sig)
        raw = s["out"][..., L:]
        inside = ((raw >= lo) & (raw <= hi)).to(raw.dtype)
        dz_ext, dhd_ext = dz_out.transpose(0, 1), dhd_out.transpose(0, 1)
        dmean_ext = dmean_out.transpose(0, 1)
        dlogvar_ext = dlogvar_out.transpose(0, 1) * inside
        if eps is not None:  # z's share of logvar's gradient: dz exp(logvar / 2) eps / 2
            z_to_logvar = 0.5 * (0.5 * raw.clamp(lo, hi)).exp() * eps.transpose(0, 1) * inside
        # the gradients of each frame's products: [s | gh'], [hp | s'], [gd | gi'], [mean | raw]
        d1 = torch.empty(T, B, M + G, **f)
        d2 = torch.empty(T, B, G + M, **f)
        d3 = torch.empty(T, B, 2 * G, **f)
        d_out = torch.empty(T, B, 2 * L, **f)
        d1[-1, :, M:] = 0  # the last frame's projections for a next one are not used
        d3[-1, :, G:] = 0
        d_gi0 = torch.empty(B, G, **f)
        d_gh0 = torch.empty(B, G, **f)
        dh_carry = torch.zeros(B, H, **f)
        dhd_carry = torch.zeros(B, H, **f)
        for t in range(T - 1, -1, -1):
            dhd = dhd_ext[t] + dhd_carry
            dhd_prev = _gru_back(dhd, t, dec, d3[t, :, :G], d2[t, :, :G])
            dz = torch.addmm(dz_ext[t], d3[t], w_z)
            torch.add(dmean_ext[t], dz, out=d_out[t, :, :L])
            if eps is None:
                d_out[t, :, L:] = dlogvar_ext[t]
            else:
                torch.addcmul(dlogvar_ext[t], dz, z_to_logvar[t], out=d_out[t, :, L:])
            torch.mul(d_out[t] @ w_out, silu_grad[t], out=d1[t, :, :M])
            d2[t, :, G:] = d1[t, :, :M]
            dhd_carry = torch.addmm(dhd_prev, d2[t], w_hd)
            dh = torch.addmm(dh_carry, d1[t], w_h)
            d_gi = d3[t - 1, :, G:] if t else d_gi0
            d_gh = d1[t - 1, :, M:] if t else d_gh0
            dh_carry = _gru_back(dh, t, enc, d_gi, d_gh)

        def weight(d, x):  # one product over all frames: (T, B, O), (T, B, I) -> (O, I), (O,)
            return d.flatten(0, 1).t() @ x.flatten(0, 1), d.sum((0, 1))

        dw_h, db_h = weight(d1, s["h"][1:])
        dw_hd, db_hd = weight(d2, s["hd"][:-1])
        dw_z, db_z = weight(d3, s["z"])
        dw_out, db_out = weight(d_out, s["a"])
        d_gi0 = d_gi0.sum(0, keepdim=True) if ctx.gi0_shape[0] == 1 else d_gi0
        return (d1[..., :M].transpose(0, 1), None, dh_carry, dhd_carry, d_gi0, d_gh0, dw_h, db_h,
                dw_hd, db_hd, dw_z, db_z, dw_out, db_out, None)  # fmt: skip


def encoder_loop(cell: nn.GRUCell, w_state: torch.Tensor, head_out: nn.Linear, decoder_rnn: nn.GRU,
                 g_part: torch.Tensor, h0: torch.Tensor, hd0: torch.Tensor,
                 eps: torch.Tensor | None):  # fmt: skip
    """The encoder's loop over a window (:class:`EncoderLoop`) from its networks' weights.

    cell: the encoder's GRUCell over z_{t-1}; w_state: (M, 2H) the head's first-layer columns
    for [h_t, hd_{t-1}]; head_out: the head's output layer (M -> 2L); decoder_rnn: the
    decoder's GRU (stepped along, its weights read, not changed); g_part: (B, T, M); h0, hd0:
    (B, H); eps: (B, T, L) or None. -> z, mean, logvar (B, T, L), hd (B, T, H)
    """
    H, M = cell.hidden_size, w_state.shape[0]
    zeros = cell.bias_hh.new_zeros(M)
    w_h = torch.cat([w_state[:, :H], cell.weight_hh])
    b_h = torch.cat([zeros, cell.bias_hh])
    w_hd = torch.cat([decoder_rnn.weight_hh_l0, w_state[:, H:]])
    b_hd = torch.cat([decoder_rnn.bias_hh_l0, zeros])
    w_z = torch.cat([decoder_rnn.weight_ih_l0, cell.weight_ih])
    b_z = torch.cat([decoder_rnn.bias_ih_l0, cell.bias_ih])
    gh0 = nn.functional.linear(h0, cell.weight_hh, cell.bias_hh)
    inputs = (g_part, eps, h0, hd0, cell.bias_ih[None], gh0, w_h, b_h, w_hd, b_hd, w_z, b_z,
              head_out.weight, head_out.bias)  # fmt: skip
    # without a gradient to come (inference), the forward keeps nothing for a backward
    wanted = torch.is_grad_enabled() and any(t is not None and t.requires_grad for t in inputs)
    return EncoderLoop.apply(*inputs, wanted)
