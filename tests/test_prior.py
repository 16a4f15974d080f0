"""Motion-DVAE prior: loss terms, a tiny training run, checkpoints, resume, sampling, DDP."""

import json
import math
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.cli.main import cli
from mdvae_cli.errors import InputError
from mdvae_cli.model.config import ModelConfig
from mdvae_cli.model.losses import gaussian_kl, inverse_gamma_expectations, inverse_gamma_kl
from mdvae_cli.model.prior_model import PriorModel, load_prior, widen_state
from mdvae_cli.model.state import VELOCITY_DIMS
from mdvae_cli.train.corpus import WindowSet
from mdvae_cli.train.prior_loss import prior_losses
from mdvae_cli.train.train_config import TrainConfig
from mdvae_cli.train.train_prior import train_prior
from tests.conftest import motion_arrays

TINY = ModelConfig(latent_dim=8, hidden_dim=32, mlp_dim=32)


def write_corpus(folder: Path, n: int = 4, T: int = 90) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        arrays = motion_arrays(T=T, width=156, fps=30.0, seed=i)
        arrays["poses"][:, 0] = np.pi / 2  # upright in z-up
        with open(folder / f"clip{i}.npz", "wb") as fh:
            np.savez(fh, **arrays)
    return folder


def tiny_config(data: Path, **kw) -> TrainConfig:
    base = dict(
        data=[str(data)],
        window=20,
        stride=5,
        batch_size=8,
        epochs=2,
        lr=3e-3,
        kl_warmup_steps=10,
        body_vertices=32,
        model=TINY,
        device="cpu",
    )
    base.update(kw)
    return TrainConfig(**base)


def test_gaussian_kl_matches_monte_carlo():
    g = torch.Generator().manual_seed(0)
    mq, lq, mp, lp = (torch.randn(4, generator=g, dtype=torch.float64) * 0.5 for _ in range(4))
    samples = mq + torch.exp(0.5 * lq) * torch.randn(200000, 4, generator=g, dtype=torch.float64)
    log_q = -0.5 * (lq + (samples - mq) ** 2 / torch.exp(lq))
    log_p = -0.5 * (lp + (samples - mp) ** 2 / torch.exp(lp))
    mc = (log_q - log_p).mean(0).sum()
    assert abs(float(gaussian_kl(mq, lq, mp, lp)) - float(mc)) < 0.02
    assert float(gaussian_kl(mq, lq, mq, lq)) == pytest.approx(0.0, abs=1e-12)


def test_inverse_gamma_expectations_and_kl_match_monte_carlo():
    alpha, beta = torch.tensor(3.5, dtype=torch.float64), torch.tensor(2.0, dtype=torch.float64)
    gamma = torch.distributions.Gamma(alpha, beta)  # 1/v ~ Gamma(alpha, rate beta)
    inv_v = gamma.sample((400000,))
    e_inv, e_log = inverse_gamma_expectations(alpha, beta)
    assert float(e_inv) == pytest.approx(float(inv_v.mean()), rel=5e-3)
    assert float(e_log) == pytest.approx(float((-torch.log(inv_v)).mean()), abs=5e-3)
    prior = torch.distributions.Gamma(
        torch.tensor(5.0, dtype=torch.float64), torch.tensor(5.0, dtype=torch.float64)
    )
    mc = (gamma.log_prob(inv_v) - prior.log_prob(inv_v)).mean()
    assert float(inverse_gamma_kl(alpha, beta, 5.0, 5.0)) == pytest.approx(float(mc), abs=0.01)
    assert float(inverse_gamma_kl(alpha, beta, 3.5, 2.0)) == pytest.approx(0.0, abs=1e-12)


def test_networks_shapes_and_causality():
    torch.manual_seed(0)
    model = PriorModel(TINY)
    x, x0 = torch.randn(3, 12, 138), torch.randn(3, 138)
    x_mean, z, post, prior = model.dvae(x, x0)
    assert x_mean.shape == (3, 12, 138) and z.shape == (3, 12, 8)
    assert post.mean.shape == prior.mean.shape == (3, 12, 8)
    # the decoder is causal in z: changing z_8 leaves x_1..x_7 unchanged
    z2 = z.clone()
    z2[:, 7] += 1.0
    a, _ = model.dvae.decoder(z, x0)
    b, _ = model.dvae.decoder(z2, x0)
    torch.testing.assert_close(a[:, :7], b[:, :7])
    assert (a[:, 7:] - b[:, 7:]).abs().max() > 1e-4
    # the prior at step t only sees z_1..z_{t-1}
    pa, pb = model.dvae.prior(z, x0), model.dvae.prior(z2, x0)
    torch.testing.assert_close(pa.mean[:, :8], pb.mean[:, :8])
    samples = model.sample(torch.randn(2, 138), 15, generator=torch.Generator().manual_seed(1))
    assert samples.shape == (2, 15, 138) and torch.isfinite(samples).all()


def test_tiny_training_lowers_loss_and_resumes(tmp_path):
    data = write_corpus(tmp_path / "data")
    log = []
    run = tmp_path / "run"
    summary = train_prior(
        tiny_config(data, epochs=5, kl_warmup_steps=0, lr=1e-2),
        run,
        progress=lambda d: log.append(d),
    )
    losses = [d["loss"] for d in log if "loss" in d]
    assert len(losses) == summary.steps > 10
    first, last = np.mean(losses[:3]), np.mean(losses[-3:])
    assert last < 0.7 * first, (first, last)
    for name in ("config.json", "best.npz", "best.json", "last.npz", "last.json", "log.jsonl"):
        assert (run / name).exists()
    model, meta = load_prior(run)
    assert meta["model_config"]["latent_dim"] == 8
    assert torch.isfinite(model.normalizer.std).all()
    # resume: two more epochs continue from the saved step count
    cfg = json.loads((run / "config.json").read_text())
    cfg["epochs"] = 7
    (run / "config.json").write_text(json.dumps(cfg))
    resumed = train_prior(TrainConfig.from_dict(cfg), run, resume=True)
    assert resumed.steps == summary.steps + 2 * (summary.steps // 5)
    assert len((run / "log.jsonl").read_text().splitlines()) == 7


def test_interrupted_and_resumed_run_ends_bit_identical(tmp_path):
    """A run stopped after its first epoch (Ctrl-C) and resumed ends with exactly the weights
    of the same run left alone: data order, learning rate, Adam's moments and the random
    draws (posterior samples, the body term's frame phase) all continue where they stopped.
    A summary.json left by an earlier finished run is removed when the resumed run starts."""
    data = write_corpus(tmp_path / "data", n=3, T=60)
    cfg = tiny_config(data, epochs=3)
    whole = train_prior(cfg, tmp_path / "whole")

    def stop_after_first_epoch(d):
        if d.get("epoch_end"):
            raise KeyboardInterrupt

    run = tmp_path / "stopped"
    with pytest.raises(KeyboardInterrupt):
        train_prior(cfg, run, progress=stop_after_first_epoch)
    (run / "summary.json").write_text("{}\n")  # as if an earlier run had finished here
    stale = []
    resumed = train_prior(
        cfg, run, resume=True, progress=lambda d: stale.append((run / "summary.json").exists())
    )
    assert stale and not any(stale)
    assert resumed.steps == whole.steps and resumed.rank_digests == whole.rank_digests
    a, _ = load_prior(tmp_path / "whole" / "last.npz")
    b, _ = load_prior(run / "last.npz")
    for (name, x), y in zip(a.state_dict().items(), b.state_dict().values(), strict=True):
        assert torch.equal(x, y), name
    assert json.loads((run / "summary.json").read_text())["steps"] == whole.steps


def test_a_wall_clock_budget_stops_inside_an_epoch_and_resume_ends_bit_identical(
    tmp_path, monkeypatch
):
    """--max-minutes: the run stops after the first step past its budget (here a clock that
    moves 10 s at every reading), validates and saves; --resume ends with exactly the weights
    of the run left alone."""
    import mdvae_cli.train.train_prior as tp

    data = write_corpus(tmp_path / "data", n=3, T=60)
    cfg = tiny_config(data, epochs=2, batch_size=2)  # 8 steps an epoch
    whole = train_prior(cfg, tmp_path / "whole")

    class Clock:
        now = 1000.0

        def time(self):
            self.now += 10.0
            return self.now

    monkeypatch.setattr(tp, "time", Clock())
    run = tmp_path / "budget"
    stopped = train_prior(cfg, run, max_minutes=0.5)  # 3 readings of the clock
    monkeypatch.undo()
    per_epoch = whole.steps // 2
    assert 0 < stopped.steps < per_epoch  # inside the first epoch
    meta = json.loads((run / "last.json").read_text())
    assert meta["epoch_steps"] == stopped.steps and meta["step"] == stopped.steps
    assert len((run / "log.jsonl").read_text().splitlines()) == 1  # validated once
    resumed = train_prior(cfg, run, resume=True)
    assert resumed.steps == whole.steps and resumed.rank_digests == whole.rank_digests


def test_init_from_widens_an_older_architecture_exactly(tmp_path):
    """A prior without the decoder z-skip / encoder-reads-decoder links fine-tunes into the
    current architecture: the new input columns start at zero, so it computes the same."""
    data = write_corpus(tmp_path / "data", n=2, T=40)
    legacy = replace(TINY, decoder_z_skip=False, encoder_reads_decoder=False, encoder_x_skip=False)
    train_prior(tiny_config(data, epochs=1, model=legacy), tmp_path / "old", max_steps=2)
    old, meta = load_prior(tmp_path / "old")
    assert meta["model_config"]["decoder_z_skip"] is False
    new = PriorModel(TINY)
    new.load_state_dict(widen_state(old.state_dict(), new.state_dict()))
    g = torch.Generator().manual_seed(0)
    x, x0 = torch.randn(2, 9, 138, generator=g), torch.randn(2, 138, generator=g)
    with torch.no_grad():
        z_old, q_old = old.dvae.encoder(x, x0, sample=False)
        z_new, q_new = new.dvae.encoder(x, x0, sample=False, decoder=new.dvae.decoder)
        torch.testing.assert_close(q_new.mean, q_old.mean)
        torch.testing.assert_close(new.dvae.decoder(z_new, x0)[0], old.dvae.decoder(z_old, x0)[0])
    with pytest.raises(ValueError, match="decoder="):
        new.dvae.encoder(x, x0)
    # a fine-tuning run from it, with a sharper decoder likelihood, starts from those weights
    cfg = tiny_config(data, epochs=1, init_from=str(tmp_path / "old" / "best.npz"))
    cfg.recon_weight = 10.0
    log = []
    train_prior(cfg, tmp_path / "new", progress=log.append, max_steps=1)
    first = next(d for d in log if "loss" in d)
    assert first["loss"] > 10.0 * first["recon"] * 0.999  # the weighted term is in the loss
    bad = widen_state(old.state_dict(), new.state_dict())
    bad["dvae.decoder.head.0.weight"] = torch.zeros(3, 3)
    with pytest.raises(ValueError, match="shape"):
        widen_state(bad, new.state_dict())


@pytest.mark.parametrize("which", ["encoder", "prior"])
def test_one_network_training_keeps_the_others_and_lowers_its_loss(tmp_path, which):
    data = write_corpus(tmp_path / "data", n=2, T=60)
    train_prior(tiny_config(data, epochs=1), tmp_path / "base", max_steps=4)
    base, _ = load_prior(tmp_path / "base")
    cfg = tiny_config(
        data, epochs=15, lr=1e-2, kl_warmup_steps=0, init_from=str(tmp_path / "base" / "best.npz")
    )
    cfg.train_only, cfg.recon_weight = which, 30.0
    log = []
    train_prior(cfg, tmp_path / "one", progress=log.append)
    tuned, meta = load_prior(tmp_path / "one")
    assert meta["train_config"]["train_only"] == which
    before, after = base.state_dict(), tuned.state_dict()
    for k in before:
        if f".{which}." in k:
            continue
        assert torch.equal(before[k], after[k]), k  # the other networks, normaliser: untouched
    assert any(not torch.equal(before[k], after[k]) for k in before if f".{which}." in k)
    # the encoder: the frozen, barely trained decoder bounds what it can gain (a few percent);
    # the prior: only the KL term depends on it
    term = "loss" if which == "encoder" else "kl"
    values = [d[term] for d in log if term in d]
    assert np.mean(values[-3:]) < 0.98 * np.mean(values[:3]), values
    cfg.train_only = "decoder"
    with pytest.raises(InputError, match="train_only"):
        train_prior(cfg, tmp_path / "bad")


def test_reconstruction_weights_scale_the_right_columns(tiny_body):
    """recon_w = 1/sigma_x^2 on every column, velocity_w scales the velocity columns only."""
    torch.manual_seed(0)
    model = PriorModel(TINY)
    g = torch.Generator().manual_seed(3)
    batch = WindowSet(
        torch.randn(2, 138, generator=g) * 0.1, torch.randn(2, 6, 138, generator=g) * 0.1,
        torch.zeros(2, 10),
    )  # fmt: skip
    body = BodyModel(tiny_body)
    ids = torch.arange(4)
    args = (model, model.dvae, batch, body, ids, 0.0, 0.0)
    norm = model.normalizer
    with torch.no_grad():
        torch.manual_seed(1)
        base = prior_losses(*args)
        torch.manual_seed(1)
        no_vel = prior_losses(*args, 1, 10.0, 0.0)
        torch.manual_seed(1)
        x_mean = model.dvae(norm.normalize(batch.x), norm.normalize(batch.x0))[0]
    sq = (norm.normalize(batch.x) - x_mean) ** 2
    keep = [d for d in range(138) if d not in VELOCITY_DIMS]
    expected = 10.0 * 0.5 * sq[..., keep].sum(-1).mean()
    assert float(base["loss"]) == pytest.approx(float(base["recon"]), rel=1e-6)
    assert float(no_vel["recon"]) == pytest.approx(float(base["recon"]), rel=1e-6)
    assert float(no_vel["loss"]) == pytest.approx(float(expected), rel=1e-5)
    assert float(no_vel["loss"]) < 10.0 * float(no_vel["recon"])


def test_checkpoints_hold_no_pickles(tmp_path):
    data = write_corpus(tmp_path / "data", n=2, T=40)
    train_prior(tiny_config(data, epochs=1), tmp_path / "run", max_steps=2)
    with np.load(tmp_path / "run" / "last.npz", allow_pickle=False) as z:
        assert all(z[k].dtype != object for k in z.files)


def test_cli_train_prior_and_sample(tmp_path):
    data = write_corpus(tmp_path / "data", n=3, T=60)
    runner = CliRunner()
    res = runner.invoke(
        cli,
        [
            "train-prior",
            str(data),
            "-o",
            str(tmp_path / "run"),
            "--window",
            "20",
            "--batch-size",
            "8",
            "--epochs",
            "1",
            "--latent-dim",
            "8",
            "--hidden-dim",
            "32",
            "--device",
            "cpu",
        ],
    )
    assert res.exit_code == 0, res.output
    res = runner.invoke(
        cli,
        [
            "sample",
            "--from",
            str(data / "clip0.npz"),
            "--frames",
            "45",
            "--prior",
            str(tmp_path / "run"),
            "-o",
            str(tmp_path / "s.npz"),
        ],
    )
    assert res.exit_code == 0, res.output
    with np.load(tmp_path / "s.npz") as z:
        assert z["poses"].shape == (45, 156) and np.isfinite(z["poses"]).all()
        assert float(z["mocap_framerate"]) == 30.0
    res = runner.invoke(cli, ["train-prior", str(tmp_path / "nothing"), "-o", str(tmp_path / "r2")])
    assert res.exit_code == 1 and "error:" in res.output and "Traceback" not in res.output


@pytest.mark.slow  # ~15 s on 2 cores
def test_ddp_two_cpu_processes_end_with_identical_weights(tmp_path):
    data = write_corpus(tmp_path / "data", n=4, T=60)
    run = tmp_path / "run"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--standalone",
        "--nproc_per_node",
        "2",
        "-m",
        "mdvae_cli.cli.main",
        "train-prior",
        str(data),
        "-o",
        str(run),
        "--window",
        "20",
        "--stride",
        "5",
        "--batch-size",
        "4",
        "--epochs",
        "3",
        "--latent-dim",
        "8",
        "--hidden-dim",
        "32",
        "--device",
        "cpu",
        "--max-steps",
        "4",
        "--threads",
        "1",
    ]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads((run / "summary.json").read_text())
    digests = summary["rank_digests"]
    assert len(digests) == 2 and digests[0] == digests[1]
    assert summary["steps"] == 4 and not math.isnan(summary["best_val_loss"])


def test_mirror_augment_adds_each_motions_mirror_image(tmp_path, tiny_body):
    """``load_windows(mirror=True)``: the original windows, then the same count cut from the
    mirrored motions; a mirrored window's joint rotations are the original's with left and
    right swapped and (a, b, c) -> (a, -b, -c); the config option reaches the training set."""
    from mdvae_cli.model.state import POSE
    from mdvae_cli.motion.mirror import MIRROR_JOINTS
    from mdvae_cli.train.corpus import load_windows, select_files

    data = write_corpus(tmp_path / "data", n=2)
    files = sorted(data.glob("*.npz"))
    body = BodyModel(tiny_body)
    plain = load_windows(files, body, 20, 5)
    both = load_windows(files, body, 20, 5, mirror=True)
    n = len(plain)
    assert len(both) == 2 * n
    torch.testing.assert_close(both.x[:n], plain.x)
    pose = plain.x[..., POSE].unflatten(-1, (21, 3))
    mirrored = both.x[n:, :, POSE].unflatten(-1, (21, 3))
    partners = [j - 1 for j in MIRROR_JOINTS[1:]]
    expected = pose[:, :, partners] * torch.tensor([1.0, -1.0, -1.0])
    torch.testing.assert_close(mirrored, expected, atol=1e-5, rtol=0)
    assert not torch.allclose(mirrored, pose, atol=1e-2)

    train_files = select_files([data], None, "train")
    summary = train_prior(tiny_config(data, mirror_augment=True), tmp_path / "run", max_steps=1)
    assert summary.train_windows == 2 * len(load_windows(train_files, body, 20, 5))


def test_time_warp_plays_the_same_path_at_another_speed(make_motion_file):
    """A motion at 1.25x covers the same path in 1/1.25 of the time: frame k of the warped
    motion is the original at time 1.25 k / fps; the root's mean speed scales by 1.25."""
    from mdvae_cli.formats.npz_io import load_motion
    from mdvae_cli.motion.resample import resample_motion, time_warp

    motion = resample_motion(load_motion(make_motion_file(T=121, fps=60.0)), 30.0)
    fast = time_warp(motion, 1.25, 30.0)
    slow = time_warp(motion, 0.8, 30.0)
    assert fast.fps == slow.fps == 30.0
    assert fast.num_frames == 49 and slow.num_frames == 76  # 2 s -> 1.6 s and 2.5 s
    np.testing.assert_allclose(fast.trans[4], motion.trans[5], atol=1e-9)  # t = 5/30 s
    np.testing.assert_allclose(slow.pose_body[5], motion.pose_body[4], atol=1e-9)
    speed = lambda m: np.linalg.norm(np.diff(m.trans, axis=0), axis=1).mean() * m.fps  # noqa: E731
    assert speed(fast) == pytest.approx(1.25 * speed(motion), rel=0.02)
    with pytest.raises(ValueError):
        time_warp(motion, 0.0, 30.0)


def test_speeds_and_data_fraction_reach_the_training_windows(tmp_path, tiny_body):
    """``load_windows(speeds=...)`` adds every motion played at each speed (the captured
    windows first, untouched); ``fraction`` keeps a seeded, nested subset of whole files."""
    from mdvae_cli.train.corpus import load_windows, select_files

    data = write_corpus(tmp_path / "data", n=4, T=90)
    files = sorted(data.glob("*.npz"))
    body = BodyModel(tiny_body)
    plain = load_windows(files, body, 20, 5)
    warped = load_windows(files, body, 20, 5, speeds=(1.0, 0.8, 1.25))
    per_file = {s: len(range(0, round(89 / s) + 1 - 20, 5)) for s in (0.8, 1.25)}
    assert len(warped) == len(plain) + 4 * (per_file[0.8] + per_file[1.25])
    torch.testing.assert_close(warped.x[: len(plain)], plain.x)
    half = load_windows(files, body, 20, 5, fraction=0.5, fraction_seed=3)
    quarter = load_windows(files, body, 20, 5, fraction=0.25, fraction_seed=3)
    assert len(quarter) < len(half) < len(plain) and len(half) == len(plain) // 2
    train_files = select_files([data], None, "train")  # 3 of the 4 equal files
    cfg = tiny_config(data, speeds=[1.0, 1.25], data_fraction=0.5)
    summary = train_prior(cfg, tmp_path / "run", max_steps=1)
    kept = 2  # whole files until half the frames: 2 of 3
    assert summary.train_windows == kept * (len(plain) // 4 + per_file[1.25])
    assert len(train_files) == 3
    with pytest.raises(InputError, match="--speeds"):
        tiny_config(data, speeds=[0.1])
    with pytest.raises(InputError, match="--data-fraction"):
        tiny_config(data, data_fraction=0.0)


def test_a_stop_asked_for_saves_at_once_and_resume_ends_bit_identical(tmp_path):
    """A Ctrl-C or SIGTERM the command caught (``stop_requested``): the run stops after the
    step it is in, saves a checkpoint without validating (none is a best), and --resume ends
    with exactly the weights of the run left alone."""
    data = write_corpus(tmp_path / "data", n=3, T=60)
    cfg = tiny_config(data, epochs=2, batch_size=2)  # 8 steps an epoch
    whole = train_prior(cfg, tmp_path / "whole")
    seen = []

    def asked():
        seen.append(1)
        return len(seen) >= 3

    run = tmp_path / "asked"
    stopped = train_prior(cfg, run, stop_requested=asked)
    assert stopped.interrupted and stopped.steps == 3
    meta = json.loads((run / "last.json").read_text())
    assert meta["epoch_steps"] == 3 and meta["val"] == {} and meta["best_val_loss"] is None
    assert not (run / "best.npz").exists()  # nothing was measured
    assert json.loads((run / "log.jsonl").read_text())["interrupted"] is True
    resumed = train_prior(cfg, run, resume=True)
    assert not resumed.interrupted
    assert resumed.steps == whole.steps and resumed.rank_digests == whole.rank_digests


def test_the_first_signal_asks_for_a_stop_the_second_stops_at_once():
    import signal

    from mdvae_cli.cli.train_shared import StopAfterStep
    from mdvae_cli.errors import Terminated

    before = signal.getsignal(signal.SIGTERM)
    with StopAfterStep() as stop:
        assert not stop()
        os.kill(os.getpid(), signal.SIGTERM)
        assert stop() and stop.signal == signal.SIGTERM  # asked, nothing raised
        with pytest.raises(Terminated):
            os.kill(os.getpid(), signal.SIGTERM)
    assert signal.getsignal(signal.SIGTERM) is before  # put back
    with pytest.raises(Terminated):
        stop.raise_stop(3)
    StopAfterStep().raise_stop(3)  # no signal: nothing
