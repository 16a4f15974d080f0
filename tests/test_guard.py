"""The guard: no denoised window ends further from its input than the input's noise explains."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from mdvae_cli.body.builtin import builtin_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.cli.main import cli
from mdvae_cli.formats.npz_io import load_motion, save_motion
from mdvae_cli.infer.denoise import denoise_motions
from mdvae_cli.infer.guard import (
    fallback_states,
    guard,
    input_noise_variance,
    moved,
    past_guard,
)
from mdvae_cli.infer.settings import RefineConfig
from mdvae_cli.metrics import evaluate_pair
from mdvae_cli.model.denoiser import Denoiser, DenoiserConfig
from mdvae_cli.model.prior_model import load_prior
from mdvae_cli.model.state import POSE
from mdvae_cli.motion.motion import slice_frames
from mdvae_cli.motion.noise import add_pose_noise
from tests.test_denoise import tiny_prior  # noqa: F401 (fixture)

REPO = Path(__file__).resolve().parents[1]


def smooth_states(N=3, T=40, seed=0) -> torch.Tensor:
    """Slowly varying states (N, T, 138): sines of 0.5-1.5 Hz at 30 Hz."""
    g = torch.Generator().manual_seed(seed)
    t = torch.arange(T, dtype=torch.float64)[None, :, None] / 30.0
    freq = 0.5 + torch.rand(N, 1, 138, generator=g, dtype=torch.float64)
    return (0.3 * torch.sin(2 * torch.pi * freq * t)).float()


def test_the_noise_estimate_finds_white_noise_under_slow_motion():
    clean = smooth_states()
    g = torch.Generator().manual_seed(1)
    for sigma in (0.05, 0.1, 0.2):
        noisy = clean + sigma * torch.randn(clean.shape, generator=g)
        est = input_noise_variance(noisy).sqrt()
        assert torch.allclose(est, torch.full_like(est, sigma), rtol=0.12), (sigma, est)
    assert torch.isnan(input_noise_variance(clean[:, :2])).all()  # 2 frames: no estimate


def test_a_window_falls_back_only_when_it_moved_further_than_the_noise():
    clean = smooth_states()
    g = torch.Generator().manual_seed(2)
    noisy = clean + 0.1 * torch.randn(clean.shape, generator=g)
    good = clean + 0.03 * torch.randn(clean.shape, generator=g)  # within the noise
    bad = clean + 0.25 * torch.randn(clean.shape, generator=g)  # worse than the input
    assert not past_guard(good, noisy).any() and not past_guard(clean, noisy).any()
    assert past_guard(bad, noisy).all()
    mixed = torch.stack([good[0], bad[1], good[2]])
    out, which = guard(mixed, noisy)
    assert which.tolist() == [False, True, False]
    torch.testing.assert_close(out[0], mixed[0]) and torch.testing.assert_close(out[2], mixed[2])
    # the fallback is the smoothed input: closer to the truth than the input, near it
    rot = slice(POSE.start, POSE.stop)
    assert moved(out[1:2], clean[1:2]) < 0.5 * moved(noisy[1:2], clean[1:2])
    torch.testing.assert_close(out[1], fallback_states(noisy[1:2])[0])
    assert (out[1, :, rot] - noisy[1, :, rot]).abs().mean() < 0.1
    # nearly clean input: a small correction is not a reason to fall back (the floor)
    quiet = clean + 1e-4 * torch.randn(clean.shape, generator=g)
    assert not past_guard(clean + 0.01, quiet).any()


def test_a_broken_denoiser_never_makes_a_short_take_worse(tiny_prior):  # noqa: F811
    """An untrained denoiser on the bundled walk cut to 16 frames answers with nonsense: the
    guard falls back and the output ends closer to the clean take than the noisy input; the
    fallback is said in the notes and through the callback."""
    prior, _ = load_prior(tiny_prior / "run")
    torch.manual_seed(0)
    den = Denoiser(prior, DenoiserConfig(hidden_dim=16)).eval()
    body = BodyModel(builtin_body_model())
    clean = slice_frames(load_motion(REPO / "examples/walk.npz"), 0, 16)
    noisy = add_pose_noise(clean, 0.1, np.random.default_rng(0))
    calls = []
    bare = RefineConfig(steps=0, offset_std=0.0, trans_offset_std=0.0)  # the networks alone
    out = denoise_motions([noisy], den, body, refine=bare, guard=True,
                          on_fallback=lambda *a: calls.append(a))[0]  # fmt: skip
    unguarded = denoise_motions([noisy], den, body, refine=bare)[0]
    v2v = lambda m: evaluate_pair(clean, m, body).v2v_cm  # noqa: E731
    assert v2v(unguarded) > v2v(noisy)  # the network alone makes it worse ...
    assert v2v(out) < v2v(noisy)  # ... the guard does not
    assert len(calls) == 1 and calls[0][0] == 0 and calls[0][1] == 0.0
    assert any("input smoothed instead" in n for n in out.notes)
    assert not any("input smoothed instead" in n for n in noisy.notes)


def test_the_shipped_denoiser_does_not_make_short_noisy_takes_worse():
    """The bundled walk cut into takes of 6, 10 and 16 frames with noise at 0.10 rad: every
    take comes out closer to the clean one than the noisy input was (mdvae denoise's default)."""
    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.model.denoiser import load_denoiser

    den, _ = load_denoiser(None)
    body = BodyModel(load_body_model(None))
    walk = load_motion(REPO / "examples/walk.npz")
    for n in (6, 10, 16):
        for start in range(0, 60, 20):
            clean = slice_frames(walk, start, start + n)
            noisy = add_pose_noise(clean, 0.1, np.random.default_rng(start + n))
            out = denoise_motions([noisy], den, body, refine=RefineConfig(steps=0), guard=True)
            before = evaluate_pair(clean, noisy, body).v2v_cm
            after = evaluate_pair(clean, out[0], body).v2v_cm
            assert after < before, (n, start, before, after)


@pytest.mark.parametrize("flag, expected", [(["--guard"], True), ([], False)])
def test_cli_reports_fallbacks_in_json(tmp_path, flag, expected):
    walk = load_motion(REPO / "examples/walk.npz")
    noisy = add_pose_noise(slice_frames(walk, 0, 12), 0.15, np.random.default_rng(3))
    save_motion(noisy, tmp_path / "short.npz")
    args = ["denoise", str(tmp_path / "short.npz"), "-o", str(tmp_path / "out.npz"), "--json"]
    res = CliRunner().invoke(cli, [*args, *flag])
    assert res.exit_code == 0, res.output
    report = json.loads(res.stdout)
    assert report["guard"] is expected
    (row,) = report["files"]
    assert isinstance(row["result"]["fallbacks"], list)
    res = CliRunner().invoke(cli, [*args, "--no-offset"])
    assert json.loads(res.stdout)["guard"] is False


def test_a_loop_is_detected_and_denoised_as_a_cycle(tiny_prior):  # noqa: F811
    """A cycle cut from a periodic motion is detected (a take cut mid-stride is not); tiling
    moves the root on by the cycle's displacement; the denoised cycle's seam (last frame ->
    first) is no larger a step than its other frame-to-frame steps."""
    from mdvae_cli.infer.loop import displacement, looks_like_loop, tile, untile

    T = 30
    t = np.arange(T) / 30.0
    phase = 2 * np.pi * t  # exactly one period over 30 frames: frame 30 would equal frame 0
    walk = load_motion(REPO / "examples/walk.npz")
    cyc = slice_frames(walk, 0, T)
    pose = 0.4 * np.sin(phase[:, None, None] + np.arange(21)[None, :, None] * 0.3)
    root = np.tile([[0.0, 0.0, 1.0]], (T, 1))
    trans = np.stack([1.0 * t, 0 * t, 0.9 + 0.02 * np.cos(2 * phase)], 1)
    cyc = cyc.with_body(root_orient=root, pose_body=np.broadcast_to(pose, (T, 21, 3)).copy(),
                        trans=trans)  # fmt: skip
    assert looks_like_loop(cyc)
    assert not looks_like_loop(slice_frames(cyc, 0, 20))
    tiled = tile(cyc)
    assert tiled.num_frames == 3 * T
    np.testing.assert_allclose(tiled.trans[T] - tiled.trans[0], displacement(cyc))
    back = untile(tiled, cyc)
    np.testing.assert_allclose(back.pose_body, cyc.pose_body, atol=1e-9)
    np.testing.assert_allclose(back.trans, cyc.trans, atol=1e-9)

    prior, _ = load_prior(tiny_prior / "run")
    den = Denoiser(prior, DenoiserConfig(hidden_dim=16)).eval()
    body = BodyModel(builtin_body_model())
    noisy = add_pose_noise(cyc, 0.05, np.random.default_rng(1))
    out = denoise_motions([noisy], den, body, refine=RefineConfig(steps=0), loops=[True])[0]
    assert out.num_frames == T and out.fps == cyc.fps
    assert np.abs(out.trans - cyc.trans).max() < 0.1  # the path kept, not a cycle further on
    step = np.abs(np.diff(out.pose_body, axis=0)).mean(axis=(1, 2))
    seam = np.abs(out.pose_body[0] - out.pose_body[-1]).mean()
    assert seam <= 1.5 * np.percentile(step, 90), (seam, step)
