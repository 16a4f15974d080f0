"""What the input's own noise does not explain stays as it came (infer.noise_blend), and the
native-rate path around the 30 Hz denoiser (infer.denoise.to_model_rate / to_input_rate)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.cli.main import cli
from mdvae_cli.formats.npz_io import load_motion, save_motion
from mdvae_cli.infer.denoise import denoise_motions
from mdvae_cli.infer.input_noise import noise_variance
from mdvae_cli.infer.native_rate import to_input_rate, to_model_rate
from mdvae_cli.infer.noise_blend import (
    SPIKE_FLOOR_RAD,
    blend_motion,
    blend_rotations,
    spike_frames,
)
from mdvae_cli.infer.settings import RefineConfig
from mdvae_cli.metrics import evaluate_pair, joint_acceleration
from mdvae_cli.model.denoiser import load_denoiser
from mdvae_cli.model.state import BodyParams
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.noise import add_pose_noise
from mdvae_cli.motion.resample import interp_cubic, resample_motion

REPO = Path(__file__).resolve().parents[1]


def smooth_track(T: int, fps: float, channels: int = 22, seed: int = 0) -> np.ndarray:
    """Slow sinusoidal axis-angles (T, channels, 3), amplitude <= 0.4 rad."""
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None, None] / fps
    f = rng.uniform(0.3, 1.2, (1, channels, 3))
    ph = rng.uniform(0, 2 * np.pi, (1, channels, 3))
    return rng.uniform(0.1, 0.4, (1, channels, 3)) * np.sin(2 * np.pi * f * t + ph)


@pytest.mark.parametrize("fps, sigma", [(30.0, 0.05), (120.0, 0.02), (30.0, 0.15)])
def test_the_noise_level_is_measured_from_the_input_alone(fps, sigma):
    rng = np.random.default_rng(1)
    track = smooth_track(300, fps) + rng.normal(0, sigma, (300, 22, 3))
    est = np.sqrt(noise_variance(track))
    assert est.shape == (22,)
    np.testing.assert_allclose(est, sigma, rtol=0.2)


def test_a_clean_track_has_almost_no_noise():
    assert np.sqrt(noise_variance(smooth_track(300, 30.0))).max() < 0.01


def test_a_clean_input_comes_back_as_it_came():
    """The 'denoised' track lost a knee's peak (what a prior does to unseen motion): nothing
    of that loss is explained by the clean input's noise, so the input comes back."""
    src = smooth_track(200, 30.0)
    den = src.copy()
    den[80:100, 4] *= 0.5  # a flattened peak
    out, share, spikes = blend_rotations(src, den, 30.0)
    assert np.abs(out - src).max() < 0.01
    assert share[80:100, 4].mean() > 0.95
    assert not spikes.any()


def test_a_noisy_input_gets_the_denoisers_motion():
    rng = np.random.default_rng(2)
    truth = smooth_track(200, 30.0)
    noisy = truth + rng.normal(0, 0.1, truth.shape)
    den = truth + 0.01 * np.sin(np.arange(200) / 10.0)[:, None, None]  # a good estimate
    out, share, _ = blend_rotations(noisy, den, 30.0)
    err_out = np.sqrt(((out - truth) ** 2).mean())
    err_den = np.sqrt(((den - truth) ** 2).mean())
    assert err_out < 2.0 * err_den
    assert err_out < 0.15 * 0.1  # 15 % of the input's noise at most
    assert share.mean() < 0.2


def test_a_spike_in_the_input_is_replaced_and_a_fast_move_is_not():
    rng = np.random.default_rng(3)
    truth = smooth_track(120, 30.0)
    noisy = truth + rng.normal(0, 0.01, truth.shape)
    noisy[50, 7] += 0.8  # a solver flip on one frame of one joint
    spikes = spike_frames(noisy, noise_variance(noisy), 0.15)
    assert spikes[50, 7] and spikes.sum() == 1
    out, _, got = blend_rotations(noisy, truth, 30.0)
    assert got[50, 7]
    assert np.abs(out[50, 7] - truth[50, 7]).max() < 0.05
    # a clean step (a fast move that does not come back) is no spike
    step = truth.copy()
    step[60:, 3] += 0.5
    assert not spike_frames(step, noise_variance(step), 0.15).any()


def test_a_toe_snapping_back_on_a_clean_take_is_motion_and_a_glitch_is_not():
    """A clean walk at 24 Hz (a real take's toe, degrees about x): it bends over three frames
    and snaps back in one, which leaves the neighbours' midpoint by 24 degrees but where the
    two frames before it lead; a glitch of the same size on a still channel leads nowhere."""
    toe = np.radians([-8.6, -10.2, -16.5, -32.9, -47.6, -14.7, -11.9, -12.1, -12.0])
    values = np.zeros((len(toe), 2, 3))
    values[:, 0, 0] = toe
    values[:, 1, 0] = np.radians(-12.0)
    values[4, 1, 0] = np.radians(-47.6)
    spikes = spike_frames(values, noise_variance(values), 0.15)
    assert np.argwhere(spikes).tolist() == [[4, 1]]
    # a noisy channel keeps the midpoint's rule alone (the floor does not decide there)
    rng = np.random.default_rng(0)
    noisy = values + rng.normal(0, 0.05, values.shape)
    noisy[4, 0] = values[4, 0] + 2.0
    assert spike_frames(noisy, np.full(2, 0.05**2), 0.15)[4, 0]


def test_a_clean_takes_spike_is_filled_from_its_own_frames_not_the_denoisers():
    truth = smooth_track(120, 30.0)  # (T, 22, 3), clean
    glitch = truth.copy()
    glitch[50, 7] += 0.8  # one frame of one joint flipped
    path = np.stack([np.linspace(0, 2, 120), np.sin(np.arange(120) / 20), np.zeros(120)], 1)
    jumped = path.copy()
    jumped[80, 1] += 0.3  # and the root's translation jumps 30 cm for a frame
    take = Motion.from_poses(glitch.reshape(120, 66), jumped, np.zeros(10), 30.0)
    # a denoiser's output that smooths a fast move away: 0.2 rad and 5 cm off everywhere
    den = take.with_body(
        root_orient=truth[:, 0] + 0.2, pose_body=truth[:, 1:] + 0.2, trans=path + 0.05
    )
    out, report = blend_motion(take, den)
    assert report.spike_share == 1 / 120
    # the glitches: the take's own curve through them (not the denoiser's frame)
    assert np.abs(out.pose_body[50, 6] - truth[50, 7]).max() < 0.01
    assert np.abs(out.trans[80] - path[80]).max() < 0.005
    # the rest comes back as it came (the root's rotation at the jump too)
    rest = np.ones(120, bool)
    rest[50] = False
    np.testing.assert_allclose(out.pose_body[rest], glitch[rest, 1:], atol=5e-3)
    np.testing.assert_allclose(out.root_orient, truth[:, 0], atol=5e-3)


def test_cubic_resampling_passes_through_its_samples_and_carries_on_past_the_end():
    ramp = np.arange(10.0)[:, None] * np.array([[1.0, -2.0]])
    src = np.array([0.0, 2.5, 9.0, 9.5])
    np.testing.assert_allclose(interp_cubic(ramp, src), src[:, None] * np.array([[1.0, -2.0]]))
    wave = np.sin(np.arange(12) / 2.0)[:, None]
    np.testing.assert_allclose(interp_cubic(wave, np.arange(12.0)), wave, atol=1e-12)


def _walk():
    return load_motion(REPO / "examples/walk.npz")


def test_a_high_rate_take_keeps_its_own_motion_between_the_model_samples():
    """The walk at 120 Hz (cubic from 30 Hz), clean: the default gives it back within 0.5 cm
    and with its own acceleration (within 10 %), with no frozen tail."""
    walk = _walk()
    src = np.arange((walk.num_frames - 1) * 4 + 1) / 4.0
    fast = dataclasses.replace(
        walk,
        root_orient=interp_cubic(walk.root_orient, src),
        pose_body=interp_cubic(walk.pose_body, src),
        trans=interp_cubic(walk.trans, src),
        pose_extra=np.zeros((len(src), walk.pose_extra.shape[1])),
        fps=120.0,
    )
    body = BodyModel(load_body_model(None))
    den, _ = load_denoiser(None)
    out = denoise_motions([fast], den, body, refine=RefineConfig(steps=0), blend=True)[0]
    assert out.num_frames == fast.num_frames
    assert evaluate_pair(fast, out, body).v2v_cm < 0.5
    f32 = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
    joints = [body(f32(m.root_orient), f32(m.pose_body), f32(m.trans)).joints for m in (fast, out)]
    acc_in, acc_out = (float(joint_acceleration(j.double(), 120.0).mean()) for j in joints)
    assert abs(acc_out / acc_in - 1) < 0.1
    tail = np.abs(np.diff(out.pose_body[-4:], axis=0)).max()
    assert tail > 0  # the frames after the last 30 Hz sample still move


def test_the_model_reads_a_fast_take_averaged_not_picked():
    """At 120 Hz, white noise seen by the 30 Hz samples is about halved by the averaging."""
    walk = _walk()
    fast = resample_motion(walk, 120.0)
    noisy = add_pose_noise(fast, 0.1, np.random.default_rng(0))
    seen = to_model_rate(noisy)
    clean30 = resample_motion(fast, 30.0)
    err = np.sqrt(((seen.pose_body - clean30.pose_body) ** 2).mean())
    assert err < 0.6 * 0.1


def test_to_input_rate_keeps_a_30_hz_result_as_it_is():
    walk = _walk()
    p = BodyParams(*(torch.as_tensor(a) for a in (walk.root_orient, walk.pose_body, walk.trans)))
    assert to_input_rate(p, walk) is p


def test_blend_motion_reports_what_it_kept():
    walk = _walk()
    out, report = blend_motion(walk, walk.with_body(pose_body=walk.pose_body * 0.9))
    assert 0.9 < report.input_share <= 1.0
    assert report.spike_share < 0.15  # the walk's toes flicker on a few frames
    change = np.abs(out.pose_body - walk.pose_body)
    rot = np.concatenate([walk.root_orient[:, None], walk.pose_body], axis=1)
    flicker = spike_frames(rot, noise_variance(rot), SPIKE_FLOOR_RAD)[:, 1:]
    assert flicker.any()
    # the 10 % was not noise: kept, but where a toe flickers
    assert change.mean() < 0.005 and change[~flicker].max() < 0.06
    # there the flicker is filled from the walk's own frames beside it, not the scaled output
    t, j = np.nonzero(flicker)
    mid = 0.5 * (walk.pose_body[t - 1, j] + walk.pose_body[t + 1, j])
    ratio = np.linalg.norm(out.pose_body[t, j] - mid, axis=-1) / np.linalg.norm(
        walk.pose_body[t, j] - mid, axis=-1
    )
    assert ratio.max() < 0.6 and np.median(ratio) < 0.3  # (some flicker two frames running)


def test_cli_says_how_much_was_kept(tmp_path):
    save_motion(_walk(), tmp_path / "clean.npz")
    args = ["denoise", str(tmp_path / "clean.npz"), "-o", str(tmp_path / "out.npz")]
    res = CliRunner().invoke(cli, [*args, "--json"])
    assert res.exit_code == 0, res.output
    report = json.loads(res.stdout)
    assert report["blend"] is True and report["guard"] is False
    assert report["files"][0]["result"]["input_share"] > 0.5  # a clean take: mostly kept
    res = CliRunner().invoke(cli, args)
    assert "kept as it came" in res.output
    res = CliRunner().invoke(cli, [*args, "--no-blend", "--json"])
    assert json.loads(res.stdout)["files"][0]["result"]["input_share"] is None


def test_video_estimates_get_the_slow_band_alone():
    """A residual of pure frame-to-frame jitter (nothing slow): the slow-band-only blend puts
    none of it back, the full blend (mocap) some, where the noise level is underestimated."""
    from mdvae_cli.infer.input_kinds import kind_settings
    from mdvae_cli.infer.noise_blend import keep_unexplained

    assert kind_settings("mocap").blend_fast and not kind_settings("video").blend_fast
    rng = np.random.default_rng(0)
    jitter = rng.normal(0, 0.05, (300, 2, 3))
    jitter -= np.concatenate([jitter[:1], jitter[:-1]])  # differenced: no slow content
    quiet = np.full(2, 1e-6)  # a noise estimate far too low: every bit looks unexplained
    none = np.zeros((300, 2), dtype=bool)
    slow_only, _ = keep_unexplained(jitter, quiet, none, 30.0, fast_margin=None)
    both, _ = keep_unexplained(jitter, quiet, none, 30.0)
    assert np.abs(slow_only).mean() < 0.3 * np.abs(both).mean()
    assert np.abs(both - jitter).mean() < 0.01 * np.abs(jitter).mean()  # nearly all of it


def test_the_blend_a_chunk_of_frames_at_a_time_is_the_blend_of_the_whole(monkeypatch):
    """The blend's per-frame and local steps go a chunk of frames at a time (in cache on long
    takes): the same result, bit for bit, as in one piece, with the input's unwrapping carried
    across the chunks (tracks that turn past half a turn many times) and holes."""
    import mdvae_cli.infer.noise_blend as nb

    rng = np.random.default_rng(5)
    T = 2500
    src = np.cumsum(rng.normal(0, 0.08, (T, 22, 3)), 0)
    den = src + rng.normal(0, 0.02, src.shape)
    missing = rng.random((T, 22)) < 0.01
    monkeypatch.setattr(nb, "CACHE_FRAMES", 10**9)
    whole = nb.blend_rotations(src, den, 120.0, True, missing)
    assert np.abs(whole[0] - src).max() > 0.01  # something was blended
    for chunk in (997, 128):
        monkeypatch.setattr(nb, "CACHE_FRAMES", chunk)
        parts = nb.blend_rotations(src, den, 120.0, True, missing)
        for a, b in zip(parts, whole, strict=True):
            np.testing.assert_array_equal(a, b)
        x = rng.normal(size=(T, 5))
        kernel = nb.gaussian_coefficients(3.0)
        monkeypatch.setattr(nb, "CACHE_FRAMES", 10**9)
        one = nb.smooth_in_time(x, kernel)
        monkeypatch.setattr(nb, "CACHE_FRAMES", chunk)
        np.testing.assert_array_equal(nb.smooth_in_time(x, kernel), one)


def test_video_blend_puts_the_fast_band_back_where_the_denoiser_went_wrong():
    """With the fast band not blended (video), jitter of the noise's size stays the
    denoiser's; a stretch where the fast residual is ten times the noise's spread and more
    (the denoiser's output gone wrong, not the tracker) comes back from the input."""
    from mdvae_cli.infer.noise_blend import GONE_MARGIN, keep_unexplained

    rng = np.random.default_rng(1)
    T, std = 600, 0.01
    jitter = rng.normal(0, std, (T, 2, 3))
    residual = jitter.copy()
    residual[300:360, 0] += rng.normal(0, 30 * std, (60, 3))  # joint 0 goes wrong for 2 s
    noise = np.full(2, std**2)
    none = np.zeros((T, 2), dtype=bool)
    dropped, _ = keep_unexplained(residual, noise, none, 30.0, fast_margin=None)
    kept, _ = keep_unexplained(residual, noise, none, 30.0, GONE_MARGIN)
    fast = residual - dropped  # what the slow band alone leaves out
    gone = slice(310, 350)
    # where it went wrong, most of the fast band comes back ...
    assert np.abs(residual[gone, 0] - kept[gone, 0]).mean() < 0.2 * np.abs(fast[gone, 0]).mean()
    # ... and where it is noise, none of it (joint 1 throughout, joint 0 far from the stretch)
    np.testing.assert_allclose(kept[:, 1], dropped[:, 1], atol=1e-12)
    np.testing.assert_allclose(kept[:200, 0], dropped[:200, 0], atol=1e-12)
