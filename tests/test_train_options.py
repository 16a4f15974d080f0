"""Options of train-prior and fit-dataset: bad values refused (CLI and config classes) before
anything is written, divergence stopped before a non-finite checkpoint, strict-JSON summaries,
and a plain message when the automatic split leaves nothing to train on."""

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner

import mdvae_cli.train.distill as distill_module
import mdvae_cli.train.prior_step as prior_step_module
import mdvae_cli.train.train_prior as tp
from mdvae_cli.cli.main import cli
from mdvae_cli.errors import InputError
from mdvae_cli.model.config import ModelConfig
from mdvae_cli.model.denoiser import Denoiser, DenoiserConfig
from mdvae_cli.train.distill import DistillConfig
from mdvae_cli.train.fit_dataset import FitConfig, fit_dataset
from mdvae_cli.train.guards import json_safe, pick_device
from mdvae_cli.train.train_config import TrainConfig
from mdvae_cli.train.train_prior import train_prior
from mdvae_cli.weights import default_weights
from tests.test_prior import TINY, tiny_config, write_corpus

NAN = math.nan


def strict_json(text: str):
    """json.loads that refuses NaN/Infinity, as strict JSON parsers do."""

    def refuse(name):
        raise ValueError(f"{name} in JSON")

    return json.loads(text, parse_constant=refuse)


def all_finite_npz(path: Path) -> bool:
    with np.load(path) as z:
        return all(np.isfinite(z[k]).all() for k in z.files if z[k].dtype.kind == "f")


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> Path:
    return write_corpus(tmp_path_factory.mktemp("train_options") / "data", n=3, T=40)


@pytest.fixture(scope="module")
def tiny_prior(corpus) -> Path:
    run = corpus.parent / "prior"
    train_prior(tiny_config(corpus, epochs=1, batch_size=4), run, max_steps=1)
    return run


def tiny_fit_config(data: Path, prior: Path, **kw) -> FitConfig:
    base = dict(
        data=[str(data)],
        prior=str(prior),
        window=20,
        stride=5,
        batch_size=4,
        epochs=1,
        device="cpu",
        denoiser=DenoiserConfig(hidden_dim=16),
    )
    base.update(kw)
    return FitConfig(**base)


# --- the command line refuses bad values at parse time (exit 1) ---------------------------------

TRAIN_BAD = [
    ["--kl-max", "nan"],
    ["--kl-max", "-1"],
    ["--epochs", "-1"],
    ["--epochs", "0"],
    ["--recon-weight", "-1"],
    ["--recon-weight", "0"],
    ["--body-weight", "inf"],
    ["--velocity-weight", "-0.5"],
    ["--velocity-std-scale", "0"],
    ["--batch-size", "0"],
    ["--window", "0"],
    ["--stride", "0"],
    ["--lr", "nan"],
    ["--lr", "0"],
    ["--kl-warmup", "-1"],
    ["--latent-dim", "0"],
    ["--hidden-dim", "-4"],
    ["--threads", "-2"],
    ["--threads", "0"],
    ["--max-steps", "0"],
    ["--seed", "-1"],
]

FIT_BAD = [
    ["--lam", "nan"],
    ["--lam", "-1"],
    ["--lam", "0"],
    ["--obs-unit", "nan"],
    ["--obs-unit", "0"],
    ["--input-window", "-3"],
    ["--window", "0"],
    ["--stride", "0"],
    ["--batch-size", "0"],
    ["--epochs", "-1"],
    ["--lr", "nan"],
    ["--lr", "-1e-3"],
    ["--lr-final", "-1"],
    ["--distill-lr", "0"],
    ["--distill-epochs", "-1"],
    ["--distill-refine-steps", "0"],
    ["--max-steps", "0"],
    ["--threads", "0"],
]


@pytest.mark.parametrize(
    "command, bad", [("train-prior", b) for b in TRAIN_BAD] + [("fit-dataset", b) for b in FIT_BAD]
)
def test_cli_refuses_bad_numbers_before_writing_anything(corpus, tmp_path, command, bad):
    out = tmp_path / "out"
    res = CliRunner().invoke(cli, [command, str(corpus), "-o", str(out), "--device", "cpu", *bad])
    assert res.exit_code == 1, res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and bad[0] in lines[0], res.output
    assert "Traceback" not in res.output
    assert not out.exists()


@pytest.mark.parametrize(
    "command, args, message",
    [
        ("train-prior", ["--device", "bogus"], "--device must be auto, cpu, cuda or cuda:N"),
        ("train-prior", ["--device", "cuda:x"], "--device must be auto, cpu, cuda or cuda:N"),
        ("fit-dataset", ["--device", "gpu"], "--device must be auto, cpu, cuda or cuda:N"),
        ("fit-dataset", ["--input-window", "4"], "--input-window must be 0 or an odd number"),
    ],
)
def test_cli_library_checks_are_one_error_line(corpus, tmp_path, command, args, message):
    out = tmp_path / "out"
    res = CliRunner().invoke(cli, [command, str(corpus), "-o", str(out), *args])
    assert res.exit_code == 1, res.output
    assert f"error: {message}" in res.output and "Traceback" not in res.output
    assert len([line for line in res.output.splitlines() if "error:" in line]) == 1
    assert not out.exists()


def test_cli_config_file_with_bad_values_is_refused(corpus, tmp_path):
    config = tmp_path / "config.json"
    config.write_text(json.dumps({**TrainConfig().to_dict(), "kl_max": -1.0}))
    out = tmp_path / "out"
    args = ["train-prior", str(corpus), "-o", str(out), "--config", str(config)]
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 1, res.output
    assert "error: --kl-max must be a finite number >= 0, got -1.0" in res.output
    assert "Traceback" not in res.output and not out.exists()


def test_cuda_without_a_gpu_is_one_plain_error(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(InputError, match="no CUDA GPU is available here"):
        pick_device("cuda")
    with pytest.raises(InputError, match="no CUDA GPU is available here"):
        pick_device("cuda:1")
    assert pick_device("auto").type == "cpu" and pick_device("cpu").type == "cpu"


# --- the config classes validate themselves (InputError, the option named) ---------------------


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: TrainConfig(kl_max=NAN), "--kl-max must be a finite number >= 0, got nan"),
        (lambda: TrainConfig(epochs=0), "--epochs must be a whole number >= 1, got 0"),
        (lambda: TrainConfig(epochs=-1), "--epochs must be a whole number >= 1"),
        (lambda: TrainConfig(recon_weight=-1.0), "--recon-weight must be a finite number > 0"),
        (lambda: TrainConfig(lr=0.0), "--lr must be a finite number > 0, got 0.0"),
        (lambda: TrainConfig(lr=math.inf), "--lr must be a finite number > 0, got inf"),
        (lambda: TrainConfig(batch_size=0), "--batch-size must be a whole number >= 1"),
        (lambda: TrainConfig(window=2.5), "--window must be a whole number >= 1, got 2.5"),
        (lambda: TrainConfig(stride=0), "--stride must be a whole number >= 1"),
        (lambda: TrainConfig(body_weight=-0.1), "--body-weight must be a finite number >= 0"),
        (lambda: TrainConfig(grad_clip=NAN), "grad_clip must be a finite number > 0"),
        (lambda: TrainConfig(device="gpu"), "--device must be auto, cpu, cuda or cuda:N"),
        (lambda: TrainConfig(train_only="decoder"), "train_only must be one of all"),
        (lambda: ModelConfig(latent_dim=0), "--latent-dim must be a whole number >= 1, got 0"),
        (lambda: ModelConfig(hidden_dim=-1), "--hidden-dim must be a whole number >= 1"),
        (lambda: TrainConfig.from_dict({"model": {"latent_dim": 0}}), "--latent-dim"),
        (lambda: DenoiserConfig(lam=NAN), "--lam must be a finite number > 0, got nan"),
        (lambda: DenoiserConfig(lam=-1.0), "--lam must be a finite number > 0, got -1.0"),
        (lambda: DenoiserConfig(obs_unit=0.0), "--obs-unit must be a finite number > 0"),
        (lambda: DenoiserConfig(obs_unit=NAN), "--obs-unit must be a finite number > 0"),
        (lambda: DenoiserConfig(input_window=-3), "--input-window must be a whole number >= 0"),
        (lambda: DenoiserConfig(input_window=4), "--input-window must be 0 or an odd number"),
        (lambda: DenoiserConfig(hidden_dim=0), "hidden_dim must be a whole number >= 1"),
        (lambda: FitConfig(epochs=-1), "--epochs must be a whole number >= 0, got -1"),
        (lambda: FitConfig(lr=NAN), "--lr must be a finite number > 0, got nan"),
        (lambda: FitConfig(lr_final=-1.0), "--lr-final must be a finite number >= 0"),
        (lambda: FitConfig(batch_size=0), "--batch-size must be a whole number >= 1"),
        (lambda: FitConfig(device="bogus"), "--device must be auto, cpu, cuda or cuda:N"),
        (lambda: FitConfig.from_dict({"denoiser": {"lam": -2}}), "--lam must be"),
        (lambda: FitConfig.from_dict({"distill": {"lr": NAN}}), "--distill-lr must be"),
        (lambda: DistillConfig(epochs=-1), "--distill-epochs must be a whole number >= 0"),
        (lambda: DistillConfig(refine_steps=0), "--distill-refine-steps must be a whole number"),
        (lambda: DistillConfig(latent_weight=-1.0), "distill latent_weight must be a finite"),
    ],
)
def test_config_classes_refuse_bad_values(make, message):
    with pytest.raises(InputError) as info:
        make()
    assert message in str(info.value) and "\n" not in str(info.value)


def test_shipped_and_default_configs_are_valid():
    for name in ("prior", "denoiser"):
        meta = json.loads(default_weights(name).with_suffix(".json").read_text())
        if "train_config" in meta:
            TrainConfig.from_dict(meta["train_config"])
        if "fit_config" in meta:
            FitConfig.from_dict(meta["fit_config"])
        ModelConfig.from_dict(meta["model_config"])
    TrainConfig(), FitConfig(), ModelConfig(), DenoiserConfig(), DistillConfig()
    recipe = Path(__file__).resolve().parents[1] / "weights_recipe"
    for name in ("prior_config.json", "prior_gpu_config.json"):  # as --config reads them
        cfg = TrainConfig.from_dict(json.loads((recipe / name).read_text()), legacy=False)
        assert cfg.model == ModelConfig()  # today's architecture, the shipped prior's
    gpu = TrainConfig.from_dict(json.loads((recipe / "prior_gpu_config.json").read_text()))
    assert (gpu.batch_size, gpu.lr_warmup_steps, gpu.device) == (1024, 10, "auto")
    assert (gpu.lr, gpu.epochs, gpu.val_every_epochs, gpu.cuda_graph) == (8e-3, 25, 2, True)


def test_fields_changed_after_construction_are_checked_before_anything_is_written(
    corpus, tiny_prior, tmp_path
):
    cfg = tiny_config(corpus, model=replace(TINY))  # its own copy: mutated below
    cfg.recon_weight = -1.0
    with pytest.raises(InputError, match="--recon-weight must be a finite number > 0"):
        train_prior(cfg, tmp_path / "run")
    cfg.recon_weight, cfg.model.latent_dim = 1.0, 0
    with pytest.raises(InputError, match="--latent-dim"):
        train_prior(cfg, tmp_path / "run")
    cfg.model.latent_dim = 8
    with pytest.raises(InputError, match="--max-steps must be a whole number >= 1"):
        train_prior(cfg, tmp_path / "run", max_steps=0)
    assert not (tmp_path / "run").exists()
    fit = tiny_fit_config(corpus, tiny_prior)
    fit.denoiser.lam = NAN
    with pytest.raises(InputError, match="--lam must be a finite number > 0, got nan"):
        fit_dataset(fit, tmp_path / "den")
    fit.denoiser.lam, fit.denoiser.input_window = 10.0, -3
    with pytest.raises(InputError, match="--input-window"):
        fit_dataset(fit, tmp_path / "den")
    assert not (tmp_path / "den").exists()


# --- divergence stops the run before a non-finite checkpoint -----------------------------------


def test_prior_divergence_stops_and_keeps_the_last_good_checkpoint(corpus, tmp_path, monkeypatch):
    real, calls = tp.prior_losses, []

    def nan_from_the_fourth_step(*args, **kwargs):
        terms = real(*args, **kwargs)
        calls.append(torch.is_grad_enabled())  # validation runs without gradients
        if sum(calls) >= 4:
            terms["loss"] = terms["loss"] * NAN
        return terms

    monkeypatch.setattr(tp, "prior_losses", nan_from_the_fourth_step)  # validation
    monkeypatch.setattr(prior_step_module, "prior_losses", nan_from_the_fourth_step)  # steps
    run = tmp_path / "run"
    # 3 clips, 1 held out: 2 x 4 windows of 20 frames, 2 steps of 4 per epoch
    cfg = tiny_config(corpus, epochs=5, batch_size=4)
    with pytest.raises(InputError) as info:
        train_prior(cfg, run)
    message = str(info.value)
    assert message.startswith("training diverged at step 4 (loss nan): lower --lr")
    meta = json.loads((run / "last.json").read_text())
    assert meta["step"] == 2  # epoch 1's checkpoint stays, with finite weights
    assert all_finite_npz(run / "last.npz") and all_finite_npz(run / "best.npz")
    assert not (run / "summary.json").exists()


def poison_after(module, real_step, at: int):
    """A ``clipped_step`` that takes the real step, then makes the weights nan at call ``at``
    (a finite loss whose step overflowed)."""
    calls = []

    def step(opt, loss, params, max_norm):
        real_step(opt, loss, params, max_norm)
        calls.append(1)
        if len(calls) == at:
            with torch.no_grad():
                next(iter(module().parameters())).fill_(NAN)

    return step


def test_non_finite_weights_are_never_saved(corpus, tiny_prior, tmp_path, monkeypatch):
    import mdvae_cli.infer.elbo_fit as ef
    import mdvae_cli.train.fit_dataset as fd

    models = []
    real_model = tp.PriorModel
    monkeypatch.setattr(tp, "PriorModel", lambda cfg: models.append(real_model(cfg)) or models[-1])
    monkeypatch.setattr(
        prior_step_module,
        "clipped_step",
        poison_after(lambda: models[0], prior_step_module.clipped_step, 2),
    )
    run = tmp_path / "run"
    with pytest.raises(InputError, match=r"^training diverged at step 2 \(weights not finite\)"):
        train_prior(tiny_config(corpus, epochs=2, batch_size=4), run)
    assert not list(run.glob("*.npz"))
    monkeypatch.undo()

    dens = []
    real_den = fd.Denoiser
    monkeypatch.setattr(fd, "Denoiser", lambda *a: dens.append(real_den(*a)) or dens[-1])
    monkeypatch.setattr(  # the ELBO loop's step, where fit-dataset's loop lives
        ef, "clipped_step", poison_after(lambda: dens[0].encoder, ef.clipped_step, 1)
    )
    out = tmp_path / "den"
    with pytest.raises(InputError, match=r"^training diverged at step 1 \(weights not finite\)"):
        fit_dataset(tiny_fit_config(corpus, tiny_prior), out, max_steps=1)
    assert not (out / "denoiser.npz").exists()


def test_prior_divergence_with_a_huge_learning_rate_via_the_cli(corpus, tmp_path):
    out = tmp_path / "run"
    args = ["train-prior", str(corpus), "-o", str(out), "--window", "20", "--batch-size", "4",
            "--epochs", "3", "--latent-dim", "8", "--hidden-dim", "32", "--device", "cpu",
            "--lr", "1e30"]  # fmt: skip
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 1, res.output
    assert "error: training diverged at step" in res.output and "lower --lr" in res.output
    assert "Traceback" not in res.output
    assert all(all_finite_npz(path) for path in out.glob("*.npz"))


def test_summary_and_checkpoint_meta_are_strict_json_when_validation_is_not_finite(
    corpus, tmp_path, monkeypatch
):
    monkeypatch.setattr(tp, "evaluate", lambda *a, **k: {"loss": NAN, "recon": math.inf})
    run = tmp_path / "run"
    summary = train_prior(tiny_config(corpus, epochs=1, batch_size=4), run, max_steps=1)
    assert math.isinf(summary.best_val_loss)
    saved = strict_json((run / "summary.json").read_text())
    assert saved["best_val_loss"] is None
    meta = strict_json((run / "last.json").read_text())
    assert meta["val"] == {"loss": None, "recon": None} and meta["best_val_loss"] is None
    strict_json((run / "log.jsonl").read_text().splitlines()[-1])
    assert json_safe({"a": [1.0, NAN, (math.inf, "x")]}) == {"a": [1.0, None, [None, "x"]]}


def test_denoiser_divergence_stops_before_saving(corpus, tiny_prior, tmp_path, monkeypatch):
    real, calls = Denoiser.elbo, []

    def nan_from_the_second_step(self, *args, **kwargs):
        terms = real(self, *args, **kwargs)
        calls.append(1)
        if len(calls) >= 2:
            terms["loss"] = terms["loss"] * NAN
        return terms

    monkeypatch.setattr(Denoiser, "elbo", nan_from_the_second_step)
    out = tmp_path / "den"
    with pytest.raises(InputError, match=r"^training diverged at step 2 \(loss nan\): lower --lr"):
        fit_dataset(tiny_fit_config(corpus, tiny_prior), out)
    assert not (out / "denoiser.npz").exists()


def test_distillation_divergence_keeps_the_finite_denoiser(
    corpus, tiny_prior, tmp_path, monkeypatch
):
    real = distill_module.distill_loss

    def nan_loss(*args, **kwargs):
        terms = real(*args, **kwargs)
        terms["loss"] = terms["loss"] * NAN
        return terms

    monkeypatch.setattr(distill_module, "distill_loss", nan_loss)
    cfg = tiny_fit_config(
        corpus, tiny_prior, epochs=0, distill=DistillConfig(epochs=1, batch_size=4, refine_steps=1)
    )
    out = tmp_path / "den"
    with pytest.raises(InputError, match=r"^distillation diverged at step 1 .*--distill-lr"):
        fit_dataset(cfg, out)
    meta = json.loads((out / "denoiser.json").read_text())
    assert meta["distill_steps"] == 0 and all_finite_npz(out / "denoiser.npz")


# --- nothing to train on ------------------------------------------------------------------------


def test_a_single_file_says_the_automatic_split_held_it_out(corpus, tmp_path):
    out = tmp_path / "run"
    res = CliRunner().invoke(cli, ["train-prior", str(corpus / "clip0.npz"), "-o", str(out)])
    assert res.exit_code == 1, res.output
    assert "error: found 1 motion file and the automatic split put it into validation" in (
        res.output
    )
    assert "--split" in res.output and "Traceback" not in res.output
    assert not out.exists()
    split = tmp_path / "split.json"
    split.write_text(json.dumps({"train": ["elsewhere.npz"], "val": []}))
    with pytest.raises(InputError, match=r'none of the 3 motion files found is in the "train"'):
        train_prior(tiny_config(corpus, split_file=str(split)), tmp_path / "run2")
    # a split file that names the one file for training makes it trainable
    split.write_text(json.dumps({"train": [str(corpus / "clip0.npz")], "val": []}))
    cfg = tiny_config(corpus / "clip0.npz", split_file=str(split), epochs=1, batch_size=4)
    assert train_prior(cfg, tmp_path / "run3", max_steps=1).steps == 1


# --- second QA pass: configs a user writes, run folders, checkpoints of the wrong kind ---------


def test_a_partial_config_file_takes_todays_defaults_and_a_run_s_own_its_history():
    user = TrainConfig.from_dict({"epochs": 3}, legacy=False)
    assert user.model.decoder_z_skip and user.model.encoder_x_skip
    assert user.model.encoder_reads_decoder
    old = TrainConfig.from_dict({"epochs": 3})  # a checkpoint written before the options
    assert not old.model.decoder_z_skip
    assert DenoiserConfig.from_dict({}, legacy=False).input_window == DenoiserConfig().input_window
    assert DenoiserConfig.from_dict({}).input_window == 0


def test_cli_partial_config_file_keeps_the_default_architecture(corpus, tmp_path):
    cfg = tmp_path / "cfg.json"
    tiny = {"latent_dim": 8, "hidden_dim": 32, "mlp_dim": 32}  # a partial model section
    cfg.write_text(json.dumps({"epochs": 1, "batch_size": 4, "window": 20, "model": tiny}))
    res = CliRunner().invoke(
        cli, ["train-prior", str(corpus), "-o", str(tmp_path / "run"), "--config", str(cfg),
              "--max-steps", "1"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    saved = json.loads((tmp_path / "run" / "config.json").read_text())
    assert saved["model"]["decoder_z_skip"] is True
    # --json: the run's summary as one JSON document on stdout (issue 33)
    res = CliRunner().invoke(
        cli, ["train-prior", str(corpus), "-o", str(tmp_path / "run2"), "--config", str(cfg),
              "--max-steps", "1", "--json"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    assert summary["steps"] == 1 and summary["run_dir"] == str(tmp_path / "run2")


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: TrainConfig(mirror_augment="no"), "--mirror-augment must be true or false"),
        (lambda: ModelConfig(decoder_z_skip="no"), "decoder_z_skip must be true or false"),
        (lambda: DenoiserConfig(x0_bidirectional=1), "x0_bidirectional must be true or false"),
    ],
)
def test_switches_must_be_booleans(make, message):
    with pytest.raises(InputError, match=message):
        make()


def test_threads_has_an_upper_bound(corpus, tmp_path):
    res = CliRunner().invoke(
        cli, ["train-prior", str(corpus), "-o", str(tmp_path / "r"), "--threads", "100000"]
    )
    assert res.exit_code == 1 and "Invalid value for '--threads'" in res.output
    assert not (tmp_path / "r").exists()


def test_a_new_prior_run_never_lands_on_an_old_one(corpus, tiny_prior, tmp_path):
    before = sorted(p.name for p in tiny_prior.iterdir())
    with pytest.raises(InputError, match="already holds a run .* add --resume"):
        train_prior(tiny_config(corpus, epochs=1, batch_size=4), tiny_prior, max_steps=1)
    assert sorted(p.name for p in tiny_prior.iterdir()) == before


def test_resuming_refuses_inputs_it_would_ignore(corpus, tiny_prior, tmp_path):
    split = tmp_path / "split.json"
    split.write_text('{"train": [], "val": []}')
    res = CliRunner().invoke(
        cli, ["train-prior", str(corpus), "-o", str(tiny_prior), "--resume", "--split", str(split)]
    )
    assert res.exit_code == 1 and "--split cannot change when resuming" in res.output
    res = CliRunner().invoke(
        cli,
        ["fit-dataset", str(corpus), "-o", str(tmp_path / "d"), "--init-from", str(tiny_prior),
         "--lam", "5"],
    )  # fmt: skip
    assert res.exit_code == 1 and "--lam: the denoiser --init-from starts from" in res.output


def test_checkpoints_of_the_wrong_kind_are_named(tiny_prior, tmp_path):
    from mdvae_cli.model.denoiser import load_denoiser, save_denoiser
    from mdvae_cli.model.prior_model import load_prior

    prior, _ = load_prior(tiny_prior)
    den = tmp_path / "den"
    save_denoiser(den / "denoiser.npz", Denoiser(prior, DenoiserConfig(hidden_dim=8)), {})
    with pytest.raises(InputError, match="is a denoiser \\(fit-dataset\\), not a prior"):
        load_prior(den / "denoiser.npz")
    with pytest.raises(InputError, match="is a denoiser \\(fit-dataset\\) folder, not a prior"):
        load_prior(den)
    with pytest.raises(InputError, match="is a train-prior run \\(a prior\\), not a denoiser"):
        load_denoiser(tiny_prior)


@pytest.mark.parametrize(
    "content, message",
    [
        ("[1, 2]", "must be a JSON object"),
        ('{"splits": 5}', "must be a JSON object"),
        ('{"train": [1]}', '"train" must be a list of file paths'),
        ('{"train": "a.npz"}', '"train" must be a list of file paths'),
    ],
)
def test_bad_split_files_are_one_plain_error(tmp_path, content, message):
    from mdvae_cli.train.corpus import read_split

    split = tmp_path / "split.json"
    split.write_text(content)
    with pytest.raises(InputError, match=message):
        read_split(split)


def test_train_only_part_needs_a_trained_prior_to_start_from():
    with pytest.raises(InputError, match="--train-only encoder trains part of a trained prior"):
        TrainConfig(train_only="encoder")


def test_resuming_a_run_that_never_saved_says_so(corpus, tiny_prior, tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps(tiny_config(corpus).to_dict()))
    with pytest.raises(InputError, match="nothing to resume in .*no last.npz yet"):
        train_prior(tiny_config(corpus), run, resume=True)
    with pytest.raises(InputError, match="nothing to resume in .*no denoiser.npz yet"):
        fit_dataset(tiny_fit_config(corpus, tiny_prior), tmp_path / "den", resume=True)


def test_a_run_folder_inside_the_data_folder_is_not_read_as_motion(tmp_path):
    data = write_corpus(tmp_path / "data", n=3, T=40)
    run = data / "run"
    train_prior(tiny_config(data, epochs=1, batch_size=4), run, max_steps=1)
    summary = train_prior(tiny_config(data, epochs=2, batch_size=4), run, resume=True, max_steps=2)
    assert summary.steps >= 1 and (run / "last.npz").exists()


def _copy_run(src: Path, dst: Path) -> Path:
    dst.mkdir()
    for f in src.iterdir():
        (dst / f.name).write_bytes(f.read_bytes())
    return dst


def test_a_truncated_checkpoint_is_one_plain_error(corpus, tiny_prior, tmp_path):
    from mdvae_cli.model.checkpoint import load_checkpoint

    run = _copy_run(tiny_prior, tmp_path / "run")
    (run / "last.npz").write_bytes((tiny_prior / "last.npz").read_bytes()[:1000])
    with pytest.raises(InputError, match="checkpoint .*last.npz: truncated or corrupt .npz"):
        load_checkpoint(run / "last.npz")
    res = CliRunner().invoke(cli, ["train-prior", str(corpus), "-o", str(run), "--resume"])
    assert res.exit_code == 1, res.output
    assert "error: checkpoint" in res.output and "truncated or corrupt" in res.output
    assert "Traceback" not in res.output and "BadZipFile" not in res.output
    start = str(next(corpus.glob("*.npz")))
    args = ["sample", "--from", start, "--prior", str(run / "last.npz"), "-o", str(tmp_path / "s")]
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 1 and "truncated or corrupt" in res.output, res.output


def test_a_last_checkpoint_without_optimizer_state_cannot_be_resumed(corpus, tiny_prior, tmp_path):
    run = _copy_run(tiny_prior, tmp_path / "run")
    (run / "last.json").write_text((run / "best.json").read_text())  # no Adam state in it
    with pytest.raises(InputError, match="last.npz cannot be resumed: last.json lacks"):
        train_prior(tiny_config(corpus, epochs=2, batch_size=4), run, resume=True)


def test_resuming_the_other_command_s_folder_says_so(corpus, tiny_prior, tmp_path):
    den = tmp_path / "den"
    den.mkdir()
    (den / "config.json").write_text(json.dumps(tiny_fit_config(corpus, tiny_prior).to_dict()))
    for command, folder, key in [
        ("train-prior", den, "'denoiser'"),
        ("fit-dataset", tiny_prior, "'body_frame_stride'"),
    ]:
        res = CliRunner().invoke(cli, [command, str(corpus), "-o", str(folder), "--resume"])
        assert res.exit_code == 1, res.output
        assert f"error: {folder} is not a run of this command" in res.output
        assert key in res.output and "unexpected keyword" not in res.output


@pytest.mark.parametrize(
    "command, content, message",
    [
        ("train-prior", "[1, 2]", "it must be a JSON object"),
        ("train-prior", "null", "it must be a JSON object"),
        ("train-prior", '{"bogus": 1}', 'unknown key "bogus"'),
        ("train-prior", '{"model": [8]}', '"model" must be a JSON object'),
        ("train-prior", '{"model": null}', '"model" must be a JSON object'),
        ("train-prior", '{"model": {"latent_dimm": 8}}', 'unknown key "model.latent_dimm"'),
        ("train-prior", '{"split_file": 5}', '"split_file" must be a string or null, got 5'),
        ("train-prior", '{"body_model": 5}', '"body_model" must be a string or null, got 5'),
        ("train-prior", '{"data": "d"}', "\"data\" must be a list of paths, got 'd'"),
        ("fit-dataset", '{"prior": 3}', '"prior" must be a string or null, got 3'),
        ("fit-dataset", '{"distill": 3}', '"distill" must be a JSON object'),
        ("fit-dataset", '{"denoiser": {"lamm": 1}}', 'unknown key "denoiser.lamm"'),
    ],
)
def test_config_files_of_the_wrong_shape_name_the_key(corpus, tmp_path, command, content, message):
    config = tmp_path / "c.json"
    config.write_text(content)
    out = tmp_path / "out"
    res = CliRunner().invoke(cli, [command, str(corpus), "-o", str(out), "--config", str(config)])
    assert res.exit_code == 1, res.output
    assert f"error: config {config}: {message}" in res.output, res.output
    assert "Traceback" not in res.output and "Error:" not in res.output and not out.exists()


@pytest.mark.parametrize(
    "make, d, message",
    [
        (TrainConfig.from_dict, {"model": {"latent_dimm": 8}}, 'unknown key "model.latent_dimm"'),
        (TrainConfig.from_dict, {"split_file": 5}, '"split_file" must be a string or null'),
        (TrainConfig.from_dict, {"lr": -1.0}, "--lr must be a finite number > 0"),
        (FitConfig.from_dict, {"denoiser": {"lamm": 1}}, 'unknown key "denoiser.lamm"'),
        (FitConfig.from_dict, {"distill": 3}, '"distill" must be a JSON object'),
    ],
)
def test_a_library_caller_of_from_dict_gets_the_same_checks(make, d, message):
    with pytest.raises(InputError) as err:
        make(d, legacy=False, source="my settings")
    assert str(err.value).startswith("my settings") or message.startswith("--")
    assert message in str(err.value)


def test_a_run_stopped_inside_an_epoch_by_max_steps_resumes_to_the_same_weights(tmp_path):
    data = write_corpus(tmp_path / "data", n=3, T=40)
    cfg = tiny_config(data, epochs=2, batch_size=4, body_vertices=8)
    whole = train_prior(cfg, tmp_path / "whole")
    assert whole.steps >= 4
    run = tmp_path / "run"
    assert train_prior(cfg, run, max_steps=1).steps == 1  # inside the first epoch
    resumed = train_prior(cfg, run, resume=True)
    assert resumed.steps == whole.steps and resumed.rank_digests == whole.rank_digests


def test_ctrl_c_while_a_checkpoint_is_written_leaves_its_two_files_matched(tmp_path, monkeypatch):
    import signal

    import mdvae_cli.model.checkpoint as ck

    path = tmp_path / "last.npz"
    ck.save_checkpoint(path, {"w": torch.zeros(2)}, {"step": 1})
    real = ck.write_atomic

    def interrupted(target, write):
        real(target, write)
        if target.suffix == ".npz":  # Ctrl-C between the weights and their metadata
            signal.raise_signal(signal.SIGINT)

    monkeypatch.setattr(ck, "write_atomic", interrupted)
    # a shell's background job starts with SIGINT ignored: give it Python's usual handler
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            ck.save_checkpoint(path, {"w": torch.ones(2)}, {"step": 2})
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, previous)
    tensors, meta = ck.load_checkpoint(path)
    assert meta["step"] == 2 and torch.equal(tensors["w"], torch.ones(2))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["last.json", "last.npz"]


def test_one_seed_bound_for_every_command_and_the_largest_seed_trains(corpus, tmp_path):
    """Options and configs take seeds 0..MAX_SEED (torch's 64 bits); the largest one trains
    (the epoch order's seed is taken mod 2^64; it used to overflow for seeds over ~1.8e16)."""
    from mdvae_cli.cli.common import SEED
    from mdvae_cli.model.config import MAX_SEED

    assert (SEED.min, SEED.max) == (0, MAX_SEED)
    for make in (lambda s: TrainConfig(seed=s), lambda s: FitConfig(seed=s)):
        with pytest.raises(InputError, match="--seed must be at most"):
            make(MAX_SEED + 1)
    summary = train_prior(tiny_config(corpus, seed=MAX_SEED), tmp_path / "run", max_steps=2)
    assert summary.steps == 2
    res = CliRunner().invoke(cli, ["train-prior", str(corpus), "-o", str(tmp_path / "r2"),
                                   "--seed", str(MAX_SEED + 1)])  # fmt: skip
    assert res.exit_code == 1 and "--seed" in res.output


def test_fit_dataset_answers_json(corpus, tiny_prior, tmp_path):
    res = CliRunner().invoke(
        cli, ["fit-dataset", str(corpus), "-o", str(tmp_path / "d"), "--prior", str(tiny_prior),
              "--max-steps", "1", "--batch-size", "4", "--window", "20", "--stride", "10",
              "--json"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    assert summary["steps"] == 1 and summary["out_dir"] == str(tmp_path / "d")


def test_learning_rate_warm_up_then_the_cosine():
    from mdvae_cli.model.optim import cosine_lr, warmup_cosine_lr

    rates = [warmup_cosine_lr(s, 110, 4e-3, 1e-4, 10) for s in range(110)]
    assert rates[:10] == pytest.approx([4e-3 * (s + 1) / 10 for s in range(10)])
    assert rates[10] == pytest.approx(4e-3)  # the cosine starts at the full rate
    assert rates[60] == pytest.approx(0.5 * (4e-3 + 1e-4))  # half-way through the decay
    assert rates[-1] == pytest.approx(cosine_lr(99, 100, 4e-3, 1e-4))
    # no warm-up is exactly the plain cosine
    assert [warmup_cosine_lr(s, 50, 1e-3, 5e-5, 0) for s in range(50)] == [
        cosine_lr(s, 50, 1e-3, 5e-5) for s in range(50)
    ]
    with pytest.raises(InputError, match="--lr-warmup"):
        TrainConfig(lr_warmup_steps=-1)


def test_cli_lr_warmup_is_saved_with_the_run(corpus, tmp_path):
    out = tmp_path / "run"
    res = CliRunner().invoke(
        cli,
        ["train-prior", str(corpus), "-o", str(out), "--epochs", "1", "--max-steps", "2",
         "--batch-size", "4", "--lr-warmup", "3", "--latent-dim", "4", "--hidden-dim", "8",
         "--window", "20", "--stride", "10"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert json.loads((out / "config.json").read_text())["lr_warmup_steps"] == 3
