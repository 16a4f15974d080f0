"""Sampling from the prior: the particle filter that conditions samples on a constraint, the
floor constraint, and `mdvae sample` with the shipped prior."""

from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.cli.main import cli
from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.infer.sample import (
    FOOT_JOINTS,
    PARTICLES,
    SPEED_LIMIT,
    motion_floor,
    plausibility_log_weight,
    sample_motion,
)
from mdvae_cli.model.config import ModelConfig
from mdvae_cli.model.dvae import MotionDVAE
from mdvae_cli.model.prior_model import load_prior
from mdvae_cli.model.state import ROOT, STATE_DIM, TRANS
from mdvae_cli.weights import default_weights

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "walk.npz"
TINY = ModelConfig(latent_dim=8, hidden_dim=32, mlp_dim=32)


@pytest.fixture(scope="module")
def body():
    return BodyModel(load_body_model(None))


def tiny_dvae(seed: int = 0) -> MotionDVAE:
    torch.manual_seed(seed)
    return MotionDVAE(TINY).eval()


def test_one_particle_is_the_plain_prior_sample():
    """With one particle the filter draws the same latents as plain sampling and decodes them
    frame by frame: the same motion (the step-wise decoding equals the decoder's)."""
    model, x0 = tiny_dvae(), torch.randn(3, STATE_DIM)
    g = lambda: torch.Generator().manual_seed(5)  # noqa: E731
    plain = model.sample(x0, 20, g(), temperature=0.7)
    ones = lambda x, prev: x.new_zeros(x.shape[:2])  # noqa: E731
    filtered = model.sample(x0, 20, g(), temperature=0.7, particles=1, log_weight=ones)
    torch.testing.assert_close(filtered, plain, rtol=1e-5, atol=1e-5)


def test_particle_filter_enforces_a_constraint():
    """Conditioning on "coordinate 0 stays above c" moves the samples above c, where plain
    samples cross it in about half of the frames."""
    model, x0 = tiny_dvae(1), torch.zeros(8, STATE_DIM)
    plain = model.sample(x0, 30, torch.Generator().manual_seed(0), temperature=1.0)
    c = float(plain[..., 0].median())

    def above(x, prev):  # (B, M, D) twice -> (B, M)
        return -0.5 * (torch.clamp(c - x[..., 0], min=0.0) / 0.01) ** 2

    cond = model.sample(x0, 30, torch.Generator().manual_seed(0), 1.0, 64, above)
    assert cond.shape == plain.shape and torch.isfinite(cond).all()
    below_plain = (plain[..., 0] < c - 0.02).float().mean()
    below_cond = (cond[..., 0] < c - 0.02).float().mean()
    assert below_plain > 0.3
    assert below_cond < 0.05


def test_plausibility_log_weight_hand_numbers(body):
    """A standing body whose lowest foot joint sits 4 cm below the floor weighs
    -0.5 (4 / 2)^2 = -2 at a 2 cm tolerance; one above the floor weighs 0. A body that moved
    0.5 m since the frame before (15 m/s at 30 Hz) exceeds a 10 m/s limit by 5 m/s: -0.5 (5 /
    2)^2 = -3.125 at a 2 m/s tolerance; at 0.2 m (6 m/s) it weighs 0."""
    x = torch.zeros(1, 2, STATE_DIM)  # rest pose at the origin, upright in a z-up file
    x[..., ROOT] = torch.tensor([np.pi / 2, 0.0, 0.0])
    betas = torch.zeros(1, body.num_betas)
    out = body(x[0, :, ROOT], torch.zeros(2, 21, 3), torch.zeros(2, 3), betas)
    lowest = float(out.joints[0, FOOT_JOINTS, 2].min())
    weigh = lambda x, prev, floor, limit: plausibility_log_weight(  # noqa: E731
        body, x, prev, betas, floor, 0.02, limit, 2.0
    )
    w = weigh(x, x, lowest + 0.04, None)
    torch.testing.assert_close(w, torch.full((1, 2), -2.0), rtol=1e-4, atol=1e-4)
    assert weigh(x, x, lowest - 0.01, None).abs().max() == 0
    prev = x.clone()
    prev[..., TRANS] = torch.tensor([0.5, 0.0, 0.0])
    torch.testing.assert_close(weigh(x, prev, None, 10.0), torch.full((1, 2), -3.125))
    prev[..., TRANS] = torch.tensor([0.0, 0.2, 0.0])
    assert weigh(x, prev, None, 10.0).abs().max() == 0
    torch.testing.assert_close(weigh(x, x, None, None), torch.zeros(1, 2))


def test_motion_floor_follows_the_motion(body):
    m = load_motion(EXAMPLE)
    floor = motion_floor(body, m)
    m.trans[:, 2] += 0.1
    assert motion_floor(body, m) == pytest.approx(floor + 0.1, abs=1e-5)


def lowest_foot(body, motion) -> float:
    t = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
    out = body(t(motion.root_orient), t(motion.pose_body), t(motion.trans), t(motion.betas)[None])
    return float(out.joints[:, FOOT_JOINTS, 2].min())


def test_shipped_prior_samples_stay_on_the_floor(body):
    """The shipped prior's raw samples from the example walk sink below its floor (here by 8 to
    51 cm); conditioned on the floor they stay within twice the 1 cm tolerance (0.9 to 1.1 cm
    below), at the same temperature and seeds."""
    prior, _ = load_prior(default_weights("prior"))
    start = load_motion(EXAMPLE)
    floor = motion_floor(body, start)
    sinks, kept = [], []
    for seed in range(3):
        raw = sample_motion(prior, body, start, 120, seed=seed, temperature=0.5)
        held = sample_motion(prior, body, start, 120, seed=seed, temperature=0.5, floor=floor)
        sinks.append(lowest_foot(body, raw) - floor)
        kept.append(lowest_foot(body, held) - floor)
    assert min(sinks) < -0.2 and max(sinks) < -0.05
    assert min(kept) > -0.02


def max_joint_speed(body, motion) -> float:
    t = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
    out = body(t(motion.root_orient), t(motion.pose_body), t(motion.trans), t(motion.betas)[None])
    return float((out.joints[1:] - out.joints[:-1]).norm(dim=-1).max()) * motion.fps


def test_speed_limit_stops_a_joint_flying_off(body):
    """Exact samples (temperature 1) kept on the floor from the example walk: with seed 2 a
    joint reaches 81 m/s; under a 10 m/s limit the same draw stays below 10 (measured 7.6)
    and on the floor."""
    prior, _ = load_prior(default_weights("prior"))
    start = load_motion(EXAMPLE)
    floor = motion_floor(body, start)
    kw = dict(seed=2, temperature=1.0, floor=floor)
    wild = sample_motion(prior, body, start, 150, **kw)
    held = sample_motion(prior, body, start, 150, speed_limit=10.0, **kw)
    assert max_joint_speed(body, wild) > 40
    assert max_joint_speed(body, held) < 10
    assert lowest_foot(body, held) > floor - 0.02


def test_cli_sample_keeps_the_floor_by_default(tmp_path, body):
    runner = CliRunner()
    out, raw = tmp_path / "s.npz", tmp_path / "raw.npz"
    args = ["sample", "--from", str(EXAMPLE), "--frames", "40", "--seed", "1"]
    res = runner.invoke(cli, [*args, "-o", str(out)])
    assert res.exit_code == 0, res.output
    res = runner.invoke(cli, [*args, "--no-floor", "-o", str(raw)])
    assert res.exit_code == 0, res.output
    a, b = load_motion(out), load_motion(raw)
    assert a.num_frames == b.num_frames == 40
    assert not np.allclose(a.pose_body, b.pose_body)
    assert lowest_foot(body, a) > motion_floor(body, load_motion(EXAMPLE)) - 0.02
    res = runner.invoke(cli, [*args, "--particles", "0", "-o", str(tmp_path / "bad.npz")])
    assert res.exit_code == 1 and "particles" in res.output
    assert not (tmp_path / "bad.npz").exists()
    res = runner.invoke(cli, ["sample", "--help"])
    assert "--no-floor" in res.output and "0.5" in res.output
    # the CLI keeps literal defaults (a fast --help); they are the library's
    params = {p.name: p.default for p in cli.commands["sample"].params}
    assert params["speed_limit"] == SPEED_LIMIT and params["particles"] == PARTICLES


def test_progress_is_told_per_window_and_leaves_the_sample_as_it_is(body):
    """sample_motion reports each 60-frame window to ``progress``; the sample is the same with
    and without it (fixed seed). `mdvae sample --frames` stops at 10 hours (1,080,000)."""
    prior, _ = load_prior(default_weights("prior"))
    start = load_motion(EXAMPLE)
    kw = dict(seed=3, temperature=0.5, floor=motion_floor(body, start), particles=2)
    plain = sample_motion(prior, body, start, 130, **kw)
    told: list[dict] = []
    watched = sample_motion(prior, body, start, 130, progress=told.append, **kw)
    assert told == [
        {"step": 1, "steps": 3, "frames": 60},
        {"step": 2, "steps": 3, "frames": 120},
        {"step": 3, "steps": 3, "frames": 130},
    ]
    for key in ("root_orient", "pose_body", "trans"):
        np.testing.assert_array_equal(getattr(watched, key), getattr(plain, key))
    runner = CliRunner()
    res = runner.invoke(cli, ["sample", "--from", str(EXAMPLE), "--frames", "1080001", "-o", "x"])
    assert res.exit_code == 1 and "1080001 is not in the range 2<=x<=1080000" in res.output
    help_text = " ".join(runner.invoke(cli, ["sample", "--help"]).output.split())
    assert "Frames to generate at 30 Hz (2 to 1,080,000: a motion, up to 10 hours)." in help_text
