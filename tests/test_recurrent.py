"""The encoder's loop with its backward written out (``model.recurrent``), and the loop autograd
records for larger batches, against the equations differentiated by autograd."""

import pytest
import torch

from mdvae_cli.model.config import ModelConfig
from mdvae_cli.model.dvae import FUSED_MAX_BATCH, MotionDVAE
from mdvae_cli.model.recurrent import EncoderLoop, encoder_loop


def _reference(enc, dec, x, x0, eps):
    """The encoder as the paper's equations read, one module call at a time (autograd
    differentiates it): h_t from z_{t-1}, the head on [g_t, h_t, hd_{t-1}, x_t], hd_t from z_t.
    x: (B, T, D), x0: (B, D), eps: (B, T, L) or None -> z, mean, logvar, hd"""
    g, _ = enc.backward_rnn(x.flip(1), enc.backward_init(x0)[None])
    g = g.flip(1)
    rnn = dec.rnn
    h, hd = enc.init(x0), dec.init(x0)
    z = x.new_zeros(x.shape[0], enc.cell.input_size)
    out = {k: [] for k in ("z", "mean", "logvar", "hd")}
    for t in range(x.shape[1]):
        h = enc.cell(z, h)
        mean, logvar = enc.head(torch.cat([g[:, t], h, hd, x[:, t]], -1)).chunk(2, -1)
        logvar = logvar.clamp(-12.0, 6.0)
        z = mean if eps is None else mean + torch.exp(0.5 * logvar) * eps[:, t]
        hd = torch.gru_cell(z, hd, rnn.weight_ih_l0, rnn.weight_hh_l0, rnn.bias_ih_l0,
                            rnn.bias_hh_l0)  # fmt: skip
        for k, v in (("z", z), ("mean", mean), ("logvar", logvar), ("hd", hd)):
            out[k].append(v)
    return [torch.stack(out[k], 1) for k in ("z", "mean", "logvar", "hd")]


def _model(seed=0):
    torch.manual_seed(seed)
    cfg = ModelConfig(latent_dim=6, hidden_dim=10, mlp_dim=12)
    m = MotionDVAE(cfg).double()
    # some latents' log-variances beyond the clamp (their gradient stops there)
    with torch.no_grad():
        m.encoder.head[2].bias[cfg.latent_dim : cfg.latent_dim + 2] = 9.0
    return m, cfg


def _grads(m, outputs):
    """Parameter gradients of a fixed random weighting of the outputs."""
    m.zero_grad()
    g = torch.Generator().manual_seed(7)
    loss = sum((o * torch.randn(o.shape, generator=g, dtype=o.dtype)).sum() for o in outputs)
    loss.backward()
    return {n: p.grad.clone() for n, p in m.named_parameters() if p.grad is not None}


@pytest.mark.parametrize("sample", [True, False])
@pytest.mark.parametrize("batch", [4, FUSED_MAX_BATCH + 1])
def test_loop_matches_autograd_through_the_equations(sample, batch):
    m, cfg = _model()
    enc, dec = m.encoder, m.decoder
    B, T = batch, 9
    x = torch.randn(B, T, cfg.state_dim, dtype=torch.float64)
    x0 = torch.randn(B, cfg.state_dim, dtype=torch.float64)
    # the fused loop (small batches) draws its noise for all frames at once, time first; the
    # loop autograd records (larger ones), a frame at a time
    g = torch.Generator().manual_seed(3)
    if B <= FUSED_MAX_BATCH:
        eps = torch.randn((T, B, cfg.latent_dim), generator=g, dtype=x.dtype).transpose(0, 1)
    else:
        eps = torch.stack([torch.randn((B, cfg.latent_dim), generator=g, dtype=x.dtype)
                           for _ in range(T)], dim=1)  # fmt: skip
    want = _reference(enc, dec, x, x0, eps if sample else None)
    want_grads = _grads(m, want)
    z, post, hd = enc(x, x0, sample=sample, generator=torch.Generator().manual_seed(3),
                      decoder=dec, decoder_states=True)  # fmt: skip
    got = [z, post.mean, post.logvar, hd]
    for a, b in zip(got, want, strict=True):
        assert torch.allclose(a, b, rtol=0, atol=1e-12)
    assert (post.logvar[..., :2] == 6.0).all()  # the clamped ones
    got_grads = _grads(m, got)
    assert set(got_grads) == set(want_grads)
    # every encoder weight and the decoder's GRU (stepped along) and initial state get theirs
    assert {"encoder.cell.weight_ih", "decoder.rnn.weight_hh_l0", "decoder.init.0.weight"} <= set(
        got_grads
    )
    for name, want_g in want_grads.items():
        err = (got_grads[name] - want_g).abs().max() / want_g.abs().max().clamp_min(1e-300)
        assert err < 1e-10, name


def test_each_input_gradient_passes_gradcheck():
    torch.manual_seed(1)
    B, T, M, H, L = 2, 3, 4, 2, 2
    G = 3 * H

    def make(*shape):
        return (0.5 * torch.randn(*shape, dtype=torch.float64)).requires_grad_()

    args = [make(B, T, M), torch.randn(B, T, L, dtype=torch.float64), make(B, H), make(B, H),
            make(1, G), make(B, G), make(M + G, H), make(M + G), make(G + M, H), make(G + M),
            make(2 * G, L), make(2 * G), make(2 * L, M), make(2 * L)]  # fmt: skip
    for i, a in enumerate(args):
        if i == 1:  # the noise: drawn, no gradient asked
            continue

        def f(v, i=i):
            return EncoderLoop.apply(*args[:i], v, *args[i + 1 :])

        assert torch.autograd.gradcheck(f, (a,)), i


def test_inference_runs_the_recorded_loop_and_gives_the_same_states():
    m, cfg = _model(2)
    x = torch.randn(3, 7, cfg.state_dim, dtype=torch.float64)
    x0 = torch.randn(3, cfg.state_dim, dtype=torch.float64)
    kw = {"sample": False, "decoder": m.decoder, "decoder_states": True}
    z, post, hd = m.encoder(x, x0, **kw)
    with torch.no_grad():  # inference: the loop run unrecorded (its forward is the faster one)
        z2, post2, hd2 = m.encoder(x, x0, **kw)
    assert "EncoderLoop" in type(z.grad_fn).__name__ and z2.grad_fn is None
    for a, b in ((z, z2), (post.logvar, post2.logvar), (hd, hd2)):
        assert torch.allclose(a.detach(), b, rtol=0, atol=1e-12)


def test_the_function_without_a_gradient_to_come_keeps_nothing():
    m, cfg = _model(3)
    enc, dec = m.encoder, m.decoder
    B, T, H = 2, 5, enc.cell.hidden_size
    g_part = torch.randn(B, T, enc.head[0].out_features, dtype=torch.float64)
    h0, hd0 = torch.randn(B, H, dtype=torch.float64), torch.randn(B, H, dtype=torch.float64)
    w_state = enc.head[0].weight[:, H : 3 * H]
    with_grad = encoder_loop(enc.cell, w_state, enc.head[2], dec.rnn, g_part, h0, hd0, None)
    with torch.no_grad():
        without = encoder_loop(enc.cell, w_state, enc.head[2], dec.rnn, g_part, h0, hd0, None)
    assert with_grad[0].grad_fn is not None and without[0].grad_fn is None
    for a, b in zip(with_grad, without, strict=True):
        assert torch.equal(a.detach(), b)
