"""Amortised refinement: refined targets, distillation into the inference networks, and
``fit-dataset --distill-epochs``."""

import json
import threading
from dataclasses import replace

import pytest
import torch
from click.testing import CliRunner

from mdvae_cli.body.builtin import builtin_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.cli.main import cli
from mdvae_cli.errors import InputError
from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.infer.refine import refine_posterior, window_batches
from mdvae_cli.infer.settings import RefineConfig
from mdvae_cli.infer.window_groups import make_windows
from mdvae_cli.model.checkpoint import load_checkpoint
from mdvae_cli.model.denoiser import Denoiser, DenoiserConfig, load_denoiser
from mdvae_cli.model.prior_model import load_prior
from mdvae_cli.motion.mirror import mirror_motion
from mdvae_cli.motion.resample import resample_motion
from mdvae_cli.train import distill as dist
from mdvae_cli.train import distill_targets as dt
from mdvae_cli.train.distill import DistillConfig, distill, refine_targets
from mdvae_cli.train.fit_dataset import FitConfig, fit_dataset, load_noisy_windows
from tests.test_denoise import noisy_dir, tiny_prior, write_denoiser  # noqa: F401 (fixtures)


@pytest.fixture(scope="module")
def windows(tiny_prior, noisy_dir):  # noqa: F811
    prior, _ = load_prior(tiny_prior / "run")
    torch.manual_seed(0)
    den = Denoiser(prior, DenoiserConfig(hidden_dim=16)).eval()
    body = BodyModel(builtin_body_model())
    files = sorted(noisy_dir.glob("*.npz"))
    return den, load_noisy_windows(files, den, body, 20, 5)[0]


def test_refine_targets_are_what_refinement_finds(windows):
    den, group = windows
    targets = refine_targets(den, group, steps=5)
    assert targets.z.shape == (len(group), 20, den.prior.cfg.latent_dim)
    assert targets.x0.shape == (len(group), 138)
    direct = refine_posterior(den, group.yn, group.obs, None, RefineConfig(steps=5))
    torch.testing.assert_close(targets.z, direct.z)
    torch.testing.assert_close(targets.x0, direct.x0)

    # refinement moved the posterior away from the encoder's answer
    start = den.infer(group.yn, with_prior=False)["q_z"].mean
    assert (targets.z - start).abs().mean() > 1e-3


def test_targets_made_in_parts_are_the_targets_made_at_once(windows):
    """A stop after a batch returns the first windows' targets; refinement started from them
    makes the rest, and the whole is what one pass makes (each window's steps are its own)."""
    den, group = windows
    whole = refine_targets(den, group, steps=3, batch=4)
    asked, kept = [], []
    first = refine_targets(
        den, group, steps=3, batch=4, stop_requested=lambda: asked.append(1) or len(asked) == 2,
        keep=lambda so_far: kept.append(len(so_far())),
    )  # fmt: skip
    assert len(group) > 8 and len(first) == 8 and kept == [4]
    rest = refine_targets(den, group, steps=3, batch=4, start=first)
    assert len(rest) == len(group)
    for name in ("z", "x0", "z_logvar"):
        torch.testing.assert_close(getattr(rest, name), getattr(whole, name))
    # other batch sizes give the same targets
    torch.testing.assert_close(refine_targets(den, group, steps=3, batch=5).z, whole.z)


def test_targets_made_side_by_side_are_the_targets_made_one_batch_at_a_time(windows):
    """Two workers: batches of at most 4 // 2 windows, two at a time on their own threads; the
    same targets, told in the windows' order, and a stop after a batch keeps the windows
    before it."""
    den, group = windows
    whole = refine_targets(den, group, steps=3, batch=4)
    batches = window_batches(len(group), RefineConfig(steps=3, batch_windows=4), workers=2)
    assert max(len(b) for b in batches) == 2 and len(batches) % 2 == 0
    told: list[int] = []
    threads: set[str] = set()
    real = dist.refine_posterior

    def traced(*args, **kwargs):
        threads.add(threading.current_thread().name)
        return real(*args, **kwargs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(dist, "refine_posterior", traced)
        both = refine_targets(
            den, group, steps=3, batch=4, workers=2, progress=lambda i: told.append(i["step"])
        )
    assert len(threads) == 2 and "MainThread" not in threads
    for name in ("z", "x0", "z_logvar"):
        # batches of 2 round the products otherwise than batches of 4: up to 4e-5 after
        # Adam's steps here (on the shipped model's 10-minute take, no difference at all)
        torch.testing.assert_close(getattr(both, name), getattr(whole, name), rtol=1e-4, atol=1e-4)
    assert told == [int(b[-1]) + 1 for b in batches] and told[-1] == len(group)
    asked: list[int] = []

    def stop() -> bool:
        asked.append(1)
        return len(asked) == 3

    first = refine_targets(den, group, steps=3, batch=4, workers=2, stop_requested=stop)
    assert len(first) == sum(len(b) for b in batches[:3])
    torch.testing.assert_close(first.z, whole.z[: len(first)], rtol=1e-4, atol=1e-4)


def test_targets_are_saved_as_they_are_made(windows, tmp_path, monkeypatch):
    """A run killed outright while refining keeps what its last save held (every
    ``keep_seconds``); a run reading the file goes on after those windows."""
    den, group = windows
    real, saved = dt.save_targets, []

    def spy(path, groups, steps, digest, targets):
        saved.append(len(targets[0]))
        real(path, groups, steps, digest, targets)

    monkeypatch.setattr(dt, "save_targets", spy)
    # one batch of 4 at a time (side by side, the batches and so the saves would follow the cores)
    monkeypatch.setattr(
        dt, "refine_targets", lambda *a, **k: refine_targets(*a, **{**k, "workers": 1}, batch=4)
    )
    made = dt.distill_targets(den, [group], 2, tmp_path, False, False, keep_seconds=0.0)
    n = len(group)
    assert saved == [*range(4, n, 4), n] and dt.complete(made, [group])
    digest = dt.parameter_digest(den)
    stored = dt.stored_targets(tmp_path / dt.TARGETS_FILE, [group], 2, digest, False)
    torch.testing.assert_close(stored[0].z, made[0].z)
    assert dt.stored_targets(tmp_path / dt.TARGETS_FILE, [group], 3, digest, False) is None
    assert dt.stored_targets(tmp_path / dt.TARGETS_FILE, [group], 2, "other", False) is None


@pytest.mark.slow  # ~18 s on 2 cores
def test_distillation_brings_one_pass_output_to_the_refined_states(windows):
    den, group = windows
    den = Denoiser(den.prior, den.cfg)
    den.load_state_dict(windows[0].state_dict())
    targets = refine_targets(den, group, steps=20)
    with torch.no_grad():
        x_mean, _ = den.prior.dvae.decoder(targets.z, targets.x0)
        refined = torch.cat([targets.x0[:, None], x_mean], dim=1)

    @torch.no_grad()
    def gap() -> float:
        return float(((den.infer(group.yn, with_prior=False)["x_hat_n"] - refined) ** 2).mean())

    before_gap = gap()
    before = {k: v.clone() for k, v in den.state_dict().items()}
    cfg = DistillConfig(epochs=30, batch_size=8, lr=3e-3, lr_final=1e-3)
    losses = distill(den, group, targets, cfg, seed=0)
    assert len(losses) == 30 * (len(group) // 8)
    assert sum(losses[-5:]) < 0.7 * sum(losses[:5]), (losses[:5], losses[-5:])
    assert gap() < 0.7 * before_gap
    # the posterior variances stay near the encoder's (refinement reads them through the KL);
    # without the latent terms they drift further
    loose = Denoiser(den.prior, den.cfg)
    loose.load_state_dict(windows[0].state_dict())
    distill(loose, group, targets, replace(cfg, latent_weight=0.0), seed=0)

    @torch.no_grad()
    def drift(model: Denoiser) -> float:
        logvar = model.infer(group.yn, with_prior=False)["q_z"].logvar
        return float((logvar - targets.z_logvar).abs().mean())

    assert drift(den) < 0.5 * drift(loose), (drift(den), drift(loose))
    changed = {k for k, v in den.state_dict().items() if not torch.equal(before[k], v)}
    assert changed and all(k.startswith(("encoder.", "x0_predictor.")) for k in changed)


def test_mirror_augment_adds_the_mirror_image_of_every_window(windows, noisy_dir):  # noqa: F811
    den, group = windows
    body = BodyModel(builtin_body_model())
    files = sorted(noisy_dir.glob("*.npz"))
    both = load_noisy_windows(files, den, body, 20, 5, mirror=True)[0]
    assert len(both) == 2 * len(group)
    torch.testing.assert_close(both.yn[: len(group)], group.yn)
    torch.testing.assert_close(both.obs[: len(group)], group.obs)
    mirror_files = [mirror_motion(resample_motion(load_motion(f), 30), body) for f in files]
    mirrored = make_windows(mirror_files, den, body, 20, 5)
    torch.testing.assert_close(both.yn[len(group) :], mirrored[-1].yn)


def test_distill_config_is_validated():
    with pytest.raises(InputError):
        DistillConfig(epochs=-1)
    with pytest.raises(InputError):
        DistillConfig(lr=0)
    with pytest.raises(InputError):
        DistillConfig(refine_steps=0)


def test_fit_dataset_distils_and_a_resumed_run_reuses_its_targets(
    tiny_prior,  # noqa: F811
    noisy_dir,  # noqa: F811
    tmp_path,
    monkeypatch,
):
    start = write_denoiser(tiny_prior, tmp_path / "start")
    cfg = FitConfig(
        data=[str(noisy_dir)], init_from=str(start), window=20, stride=5, batch_size=8,
        epochs=0, device="cpu", distill=DistillConfig(epochs=2, batch_size=8, refine_steps=3),
    )  # fmt: skip
    stages = []
    summary = fit_dataset(cfg, tmp_path / "den", progress=lambda d: stages.append(d["stage"]))
    assert summary.steps == 0 and summary.distill_steps > 0
    assert set(stages) == {"targets", "distill"}
    den, meta = load_denoiser(tmp_path / "den")
    assert meta["distill_steps"] == summary.distill_steps
    assert meta["started_from"]["path"] == str(start)
    assert (tmp_path / "den" / dt.TARGETS_FILE).exists()
    saved = json.loads((tmp_path / "den" / "config.json").read_text())
    assert saved["distill"]["epochs"] == 2 and saved["init_from"] == str(start)
    # the networks it started from are not the ones it ends with
    first, _ = load_denoiser(start)
    assert not torch.equal(first.encoder.head[0].weight, den.encoder.head[0].weight)

    def no_refining(*args, **kwargs):
        raise AssertionError("targets recomputed")

    with monkeypatch.context() as patch:
        patch.setattr(dt, "refine_targets", no_refining)
        cfg.distill.epochs = 3
        resumed = fit_dataset(cfg, tmp_path / "den", resume=True)
        assert resumed.distill_steps == summary.distill_steps * 3 // 2
        # a new run from the same networks into the same folder may reuse them too
        fit_dataset(cfg, tmp_path / "den", overwrite=True)
    # but not a run from other networks
    cfg.init_from = str(tmp_path / "den")
    calls = []
    real = dt.refine_targets
    monkeypatch.setattr(dt, "refine_targets", lambda *a, **k: calls.append(1) or real(*a, **k))
    fit_dataset(cfg, tmp_path / "den", overwrite=True)
    assert calls == [1]


def test_a_sigterm_while_refining_targets_keeps_them_and_resume_refines_the_rest(
    tiny_prior,  # noqa: F811
    noisy_dir,  # noqa: F811
    tmp_path,
    monkeypatch,
):
    """The first SIGTERM while the distillation targets are refined stops after the batch it
    came in, saves the targets made so far and exits 143; --resume refines the rest only and
    ends with the networks of a run never stopped. Before: the stop waited for every window's
    refinement (most of an hour on the real corpus), or a second signal lost all of it."""
    import os
    import signal

    start = write_denoiser(tiny_prior, tmp_path / "start")
    cfg = FitConfig(
        data=[str(noisy_dir)], init_from=str(start), window=20, stride=5, batch_size=8,
        epochs=0, device="cpu", distill=DistillConfig(epochs=1, batch_size=8, refine_steps=2),
    )  # fmt: skip
    real, batches = dt.refine_targets, []

    def in_batches_of_4(*args, **kwargs):  # one at a time, whatever the cores
        return real(*args, **{**kwargs, "workers": 1}, batch=4)

    monkeypatch.setattr(dt, "refine_targets", in_batches_of_4)
    whole = fit_dataset(cfg, tmp_path / "whole")
    config = tmp_path / "fit.json"
    config.write_text(json.dumps(cfg.to_dict()))

    def signalled_in_the_second_batch(info):
        batches.append(info["step"])
        if len(batches) == 2:
            os.kill(os.getpid(), signal.SIGTERM)

    def refining(*args, **kwargs):
        return real(
            *args[:3], signalled_in_the_second_batch, **{**kwargs, "batch": 4, "workers": 1}
        )

    monkeypatch.setattr(dt, "refine_targets", refining)
    out = tmp_path / "den"
    args = ["fit-dataset", str(noisy_dir), "-o", str(out), "--config", str(config)]
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 143, res.output
    assert "windows' targets still to refine" in res.output and "--resume" in res.output
    tensors, meta = load_checkpoint(out / dt.TARGETS_FILE)
    assert tensors["z"].shape[0] == 8 < meta["windows"] == whole.windows
    assert json.loads((out / "log.jsonl").read_text())["interrupted"] is True
    assert json.loads((out / "denoiser.json").read_text())["distill_steps"] == 0

    made = []
    monkeypatch.setattr(
        dt, "refine_targets", lambda *a, **k: made.append(k["start"]) or in_batches_of_4(*a, **k)
    )
    res = CliRunner().invoke(cli, ["fit-dataset", str(noisy_dir), "-o", str(out), "--resume"])
    assert res.exit_code == 0, res.output
    assert len(made) == 1 and len(made[0]) == 8  # it went on after the kept windows
    a, _ = load_denoiser(tmp_path / "whole")
    b, meta = load_denoiser(out)
    assert meta["distill_steps"] == whole.distill_steps > 0
    for (name, x), y in zip(a.state_dict().items(), b.state_dict().values(), strict=True):
        torch.testing.assert_close(x, y, msg=name)


def test_cli_fit_dataset_distill_options(tiny_prior, noisy_dir, tmp_path):  # noqa: F811
    start = write_denoiser(tiny_prior, tmp_path / "start")
    out = tmp_path / "den"
    args = ["fit-dataset", str(noisy_dir), "-o", str(out), "--init-from", str(start),
            "--epochs", "0", "--window", "20", "--stride", "5", "--batch-size", "8",
            "--distill-epochs", "1", "--distill-refine-steps", "2",
            "--distill-lr", "1e-3"]  # fmt: skip
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 0, res.output
    assert "amortised refinement" in res.output
    assert "no ELBO steps in this run" in res.output and "nan" not in res.output
    assert "refining targets" in res.output and "distilling" in res.output  # batch-job log lines
    saved = json.loads((out / "config.json").read_text())
    assert saved["distill"] == {**saved["distill"], "epochs": 1, "refine_steps": 2, "lr": 1e-3}
    res = CliRunner().invoke(cli, [*args, "--prior", str(tiny_prior / "run")])
    assert res.exit_code == 1 and "--init-from brings its own prior" in res.output
    assert "Traceback" not in res.output


def test_short_takes_join_the_fit_and_the_distillation(
    tiny_prior,  # noqa: F811
    noisy_dir,  # noqa: F811
    tmp_path,
):
    """``short_windows``: one group of short clips per length after the full windows, about
    ``short_share`` x the full windows in all; ELBO and distillation steps count every group,
    and the targets file keeps each group's tensors (g0/, g1/, ...)."""
    prior, _ = load_prior(tiny_prior / "run")
    den = Denoiser(prior, DenoiserConfig(hidden_dim=16)).eval()
    body = BodyModel(builtin_body_model())
    files = sorted(noisy_dir.glob("*.npz"))
    plain = load_noisy_windows(files, den, body, 20, 5)
    groups = load_noisy_windows(files, den, body, 20, 5, short_windows=(6, 10), short_share=0.5)
    assert len(groups) == 3 and groups[0].yn.shape == plain[0].yn.shape
    assert [g.yn.shape[1] for g in groups[1:]] == [6, 10]
    for g in groups[1:]:
        assert abs(len(g) - round(0.5 * len(plain[0]) / 2)) <= 1
    again = load_noisy_windows(files, den, body, 20, 5, short_windows=(6, 10), short_share=0.5)
    torch.testing.assert_close(again[1].yn, groups[1].yn)  # seeded

    start = write_denoiser(tiny_prior, tmp_path / "start")
    cfg = FitConfig(
        data=[str(noisy_dir)], init_from=str(start), window=20, stride=5, batch_size=8,
        epochs=1, device="cpu", short_windows=[6, 10], short_share=0.5,
        distill=DistillConfig(epochs=1, batch_size=8, refine_steps=2),
    )  # fmt: skip
    summary = fit_dataset(cfg, tmp_path / "den")
    total = sum(len(g) for g in groups)
    assert summary.windows == total and summary.steps == -(-total // 8)
    assert summary.distill_steps == total // 8

    tensors, meta = load_checkpoint(tmp_path / "den" / dt.TARGETS_FILE)
    assert meta["windows"] == [len(g) for g in groups]
    assert tensors["g1/z"].shape[:2] == (len(groups[1]), 5)
    with pytest.raises(InputError, match="--short-windows 30 is not shorter"):
        FitConfig(window=20, short_windows=[30])
