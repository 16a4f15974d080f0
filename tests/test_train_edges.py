"""What researchers hand the training commands: a validation file too short for a window, a
folder of studio takes not yet imported, a resumed run given other data, a prior where a
denoiser is read."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from mdvae_cli.cli.main import cli
from mdvae_cli.errors import InputError
from mdvae_cli.model.denoiser import load_denoiser
from mdvae_cli.train.fit_dataset import fit_dataset
from mdvae_cli.train.train_prior import train_prior
from tests.conftest import motion_arrays
from tests.test_prior import tiny_config, write_corpus

TINY_ARGS = ["--window", "20", "--stride", "5", "--batch-size", "8", "--epochs", "1",
             "--latent-dim", "8", "--hidden-dim", "32", "--device", "cpu"]  # fmt: skip


def short_val_corpus(folder):
    """Two 60-frame clips and, first in order (the automatic split's validation file), one
    of 15 frames: shorter than a 20-frame window."""
    write_corpus(folder, n=2, T=60)
    arrays = motion_arrays(T=15, width=156, fps=30.0, seed=9)
    arrays["poses"][:, 0] = np.pi / 2
    with open(folder / "a_short.npz", "wb") as fh:
        np.savez(fh, **arrays)
    return folder


def test_a_validation_file_too_short_leaves_the_run_to_its_training_loss(tmp_path):
    data = short_val_corpus(tmp_path / "data")
    log = []
    summary = train_prior(tiny_config(data, epochs=2), tmp_path / "run", progress=log.append)
    # it used to refuse the run: "no motion of at least 21 frames at 30 Hz found"
    assert summary.val_windows == 0 and summary.train_windows == 16
    notes = [d["note"] for d in log if "note" in d]
    assert notes == [
        "the 1 validation file is shorter than a window (21 frames at 30 Hz): the best "
        "checkpoint is chosen by the training loss"
    ]
    ends = [d for d in log if d.get("epoch_end")]
    assert len(ends) == 2 and all(d["val"] == {} for d in ends)
    assert summary.best_val_loss == min(d["train_loss"] for d in ends)
    assert (tmp_path / "run" / "best.npz").exists()


def test_cli_says_which_loss_chose_the_checkpoint(tmp_path):
    data = short_val_corpus(tmp_path / "data")
    res = CliRunner().invoke(cli, ["train-prior", str(data), "-o", str(tmp_path / "r"), *TINY_ARGS])
    assert res.exit_code == 0, res.output
    out = " ".join(res.output.split())
    assert "note: the 1 validation file is shorter than a window (21 frames" in out
    assert "epoch 1: val none; train loss" in out and "best train loss" in out


def test_a_folder_of_takes_says_to_import_them(tmp_path):
    takes = tmp_path / "takes"
    takes.mkdir()
    (takes / "walk.bvh").write_text("HIERARCHY\n")
    (takes / "run.amc").write_text(":DEGREES\n")
    res = CliRunner().invoke(cli, ["train-prior", str(takes), "-o", str(tmp_path / "r")])
    assert res.exit_code == 1
    msg = " ".join(res.output.split())
    assert "only 2 BVH/AMC takes: convert them first with `mdvae import" in msg, msg
    assert not (tmp_path / "r").exists()


def test_files_of_other_formats_in_a_data_folder_are_said_to_be_left_out(tmp_path):
    # before: a folder of npz takes and a studio's BVH and video files trained on the npz
    # alone without a word (fit-dataset: "no noisy .npz files" when there were none)
    takes = tmp_path / "takes"
    takes.mkdir()
    for name in ("walk.bvh", "run.BVH.gz", "wham_output.pkl"):
        (takes / name).write_text("x")
    note = ("note: 3 file(s) of other formats (bvh, pkl) left out: training reads AMASS-style "
            f".npz; `mdvae import {takes} -o imported/` converts them")  # fmt: skip
    for command in ("fit-dataset", "train-prior"):
        res = CliRunner().invoke(cli, [command, str(takes), "-o", str(tmp_path / "r")])
        assert res.exit_code == 1 and note in res.stderr, res.output
        assert not (tmp_path / "r").exists()


def test_resuming_with_other_data_is_refused(tmp_path):
    data = write_corpus(tmp_path / "data", n=3, T=40)
    other = write_corpus(tmp_path / "other", n=3, T=40)
    run = tmp_path / "run"
    res = CliRunner().invoke(cli, ["train-prior", str(data), "-o", str(run), *TINY_ARGS,
                                   "--max-steps", "1"])  # fmt: skip
    assert res.exit_code == 0, res.output
    before = {p.name: p.read_bytes() for p in run.iterdir()}
    # it used to train on data/ (its config.json) without a word about other/
    res = CliRunner().invoke(cli, ["train-prior", str(other), "-o", str(run), "--resume"])
    assert res.exit_code == 1
    assert "the data paths cannot change when resuming" in " ".join(res.output.split())
    # as an --init-from was: written into config.json, the run going on from its last.npz
    res = CliRunner().invoke(cli, ["train-prior", str(data), "-o", str(run), "--resume",
                                   "--init-from", str(run / "best.npz")])  # fmt: skip
    assert res.exit_code == 1 and "--init-from cannot change when resuming" in res.output
    res = CliRunner().invoke(cli, ["train-prior", str(data), "-o", str(run), "--resume",
                                   "--velocity-std-scale", "3"])  # fmt: skip
    assert res.exit_code == 1  # the checkpoint's normaliser has its scale
    assert "--velocity-std-scale cannot change when resuming" in res.output
    assert {p.name: p.read_bytes() for p in run.iterdir()} == before
    res = CliRunner().invoke(cli, ["fit-dataset", str(other), "-o", str(run), "--resume"])
    assert res.exit_code == 1  # not a fit-dataset run: said before its data are looked at
    # the same folder spelled another way resumes
    res = CliRunner().invoke(cli, ["train-prior", f"{data}/", "-o", str(run), "--resume",
                                   "--epochs", "2", "--json"])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["epochs"] == 2


def test_a_prior_read_as_a_denoiser_says_how_to_fit_one(tmp_path):
    data = write_corpus(tmp_path / "data", n=3, T=40)
    train_prior(tiny_config(data, epochs=1), tmp_path / "prior", max_steps=1)
    for path in (tmp_path / "prior", tmp_path / "prior" / "best.npz"):
        with pytest.raises(InputError) as err:
            load_denoiser(path)
        # it used to say "pass it as --prior", an option mdvae denoise does not have
        assert "--prior" in str(err.value) and "pass it as" not in str(err.value)
        assert f"mdvae fit-dataset NOISY --prior {path} -o DENOISER" in str(err.value)


def test_a_val_split_the_split_file_lacks_is_refused(tmp_path):
    data = write_corpus(tmp_path / "data", n=3, T=40)
    split = data / "split.json"
    split.write_text('{"train": ["clip0.npz", "clip1.npz"], "val": [], "unseen_val": []}')
    cfg = tiny_config(data, split_file=str(split), val_splits=["unseen_vla"])
    # it used to train without validation, choosing checkpoints by the training loss
    with pytest.raises(InputError, match='--val-split unseen_vla: the split file .* has no "unse'):
        train_prior(cfg, tmp_path / "run", max_steps=1)
    assert not (tmp_path / "run").exists()
    log = []
    cfg.val_splits = ["unseen_val"]  # there, but empty: the run says so
    summary = train_prior(cfg, tmp_path / "run", progress=log.append, max_steps=1)
    assert summary.val_windows == 0
    assert [d["note"] for d in log if "note" in d] == [
        "no validation files found: the best checkpoint is chosen by the training loss"
    ]


def test_init_from_a_prior_of_other_sizes_names_them(tmp_path):
    from mdvae_cli.model.config import ModelConfig

    data = write_corpus(tmp_path / "data", n=3, T=40)
    train_prior(tiny_config(data, epochs=1), tmp_path / "small", max_steps=1)  # 8 / 32 / 32
    cfg = tiny_config(data, epochs=1, init_from=str(tmp_path / "small"))
    cfg.model = ModelConfig(latent_dim=4, hidden_dim=32, mlp_dim=32)
    # it used to name one tensor: "dvae.prior.mlp... has shape (8, ...), this network (4, ...)"
    with pytest.raises(InputError) as err:
        train_prior(cfg, tmp_path / "run", max_steps=1)
    assert str(err.value) == (
        f"--init-from {tmp_path / 'small'}: its networks have latent_dim 8, this run's 4: give "
        "--latent-dim 8, or --config with the config.json of the run it comes from"
    )
    cfg.model = ModelConfig(latent_dim=8, hidden_dim=32, mlp_dim=64)
    with pytest.raises(InputError, match="have mlp_dim 32, this run's 64: give --config with"):
        train_prior(cfg, tmp_path / "run", max_steps=1)
    assert not (tmp_path / "run").exists()


def _fitted(tmp_path):
    """A tiny corpus, a prior of one step and a denoiser fitted on it for one step: the data
    folder, the denoiser's folder and its files' bytes."""
    from tests.test_train_options import tiny_fit_config

    data = write_corpus(tmp_path / "data", n=3, T=40)
    train_prior(tiny_config(data, epochs=1), tmp_path / "prior", max_steps=1)
    den = tmp_path / "den"
    fit_dataset(tiny_fit_config(data, tmp_path / "prior", epochs=2), den, max_steps=1)
    before = {p.name: p.read_bytes() for p in den.iterdir()}
    return data, den, before


def test_resuming_a_fit_refuses_settings_its_denoiser_keeps(tmp_path):
    data, den, before = _fitted(tmp_path)
    # they used to be written into config.json while the networks went on with lam 10
    # --holes 1 added a hole reader Adam's saved state has no room for: "error: ValueError:
    # loaded state dict contains a parameter group ...", config.json left saying holes 1.0,
    # so that every later --resume failed the same way
    options = (["--lam", "2"], ["--input-window", "0"], ["--obs-unit", "0.1"], ["--holes", "1"])
    for option in options:
        res = CliRunner().invoke(cli, ["fit-dataset", str(data), "-o", str(den), "--resume",
                                       *option])  # fmt: skip
        assert res.exit_code == 1
        assert f"error: {option[0]} cannot change when resuming a run" in res.output
    assert {p.name: p.read_bytes() for p in den.iterdir()} == before
    res = CliRunner().invoke(cli, ["fit-dataset", str(data), "-o", str(den), "--resume",
                                   "--lam", "10", "--json"])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert json.loads((den / "config.json").read_text())["denoiser"]["lam"] == 10.0


def test_a_new_fit_into_a_denoisers_folder_is_refused_unless_overwrite(tmp_path):
    # before: `fit-dataset -o den` over a fitted denoiser replaced it without a word
    data, den, before = _fitted(tmp_path)
    args = ["fit-dataset", str(data), "--prior", str(tmp_path / "prior"), "-o", str(den),
            "--window", "20", "--stride", "5", "--batch-size", "8", "--device", "cpu",
            "--max-steps", "1"]  # fmt: skip
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 1 and res.output.count("\n") == 1
    assert res.output == (
        f"error: {den} already holds a run (denoiser.npz): add --resume to continue it, "
        "--overwrite to replace it, or give another folder\n"
    )
    res = CliRunner().invoke(cli, ["fit-dataset", str(data), "-o", str(den), "--resume",
                                   "--overwrite"])  # fmt: skip
    assert res.exit_code == 1 and "give one" in res.output
    assert {p.name: p.read_bytes() for p in den.iterdir()} == before
    res = CliRunner().invoke(cli, [*args, "--overwrite", "--seed", "5"])
    assert res.exit_code == 0, res.output
    assert json.loads((den / "config.json").read_text())["seed"] == 5
    assert (den / "denoiser.npz").read_bytes() != before["denoiser.npz"]
    # another command's run is never written over (its config.json would go): before, a
    # denoiser fitted into the prior's folder left `train-prior --resume` refusing it
    prior = tmp_path / "prior"
    kept = {p.name: p.read_bytes() for p in prior.iterdir()}
    res = CliRunner().invoke(cli, ["fit-dataset", str(data), "-o", str(prior), "--overwrite"])
    assert res.exit_code == 1
    assert (
        f"error: {prior} holds a train-prior run (last.npz, best.npz): give another" in res.output
    )
    res = CliRunner().invoke(cli, ["train-prior", str(data), "-o", str(den)])
    assert (
        res.exit_code == 1 and f"error: {den} holds a fit-dataset run (denoiser.npz)" in res.output
    )
    assert {p.name: p.read_bytes() for p in prior.iterdir()} == kept


def test_resuming_with_fewer_epochs_than_taken_is_refused(tmp_path):
    data = write_corpus(tmp_path / "data", n=3, T=40)
    run = tmp_path / "run"
    train_prior(tiny_config(data, epochs=3), run)
    before = {p.name: p.read_bytes() for p in run.iterdir()}
    # it used to do nothing and write "epochs": 1 into the config.json of a 3-epoch run
    with pytest.raises(InputError, match="--epochs 1: the run in .* has already reached epoch 3"):
        train_prior(tiny_config(data, epochs=1), run, resume=True)
    assert {p.name: p.read_bytes() for p in run.iterdir()} == before
    assert train_prior(tiny_config(data, epochs=3), run, resume=True).epochs == 3


def test_a_take_too_short_for_the_import_rate_says_so(tmp_path):
    from tests.test_bvh_out import write_rig

    take = write_rig(tmp_path / "blip.bvh", T=4, fps=120.0)  # 25 ms: one frame at 30 fps
    res = CliRunner().invoke(cli, ["import", str(take), "-o", str(tmp_path / "a.npz")])
    assert res.exit_code == 1
    # it used to say "a motion needs at least 2 frames, this one has 1" of a 4-frame take
    assert " ".join(res.output.split()) == (
        f"error: {take}: 4 frames at 120 fps make 1 at 30 fps; a motion needs at least 2 "
        "(import it at its own rate with --fps 0)"
    )
    res = CliRunner().invoke(cli, ["import", str(take), "-o", str(tmp_path / "b.npz"),
                                   "--fps", "0"])  # fmt: skip
    assert res.exit_code == 0, res.output
    with np.load(tmp_path / "b.npz") as z:
        assert z["poses"].shape[0] == 4 and float(z["mocap_framerate"]) == 120.0


def test_an_output_that_cannot_be_a_run_folder_is_said_before_the_data_are_read(
    tmp_path, monkeypatch
):
    import mdvae_cli.train.guards as guards
    import mdvae_cli.train.train_prior as tp
    from tests.test_train_options import tiny_fit_config

    data = write_corpus(tmp_path / "data", n=3, T=40)
    train_prior(tiny_config(data, epochs=1), tmp_path / "prior", max_steps=1)
    afile = tmp_path / "afile"
    afile.write_text("")

    def no_reading(*args, **kwargs):
        raise AssertionError("the data were read first")

    # it used to read the whole corpus (minutes), then fail with "afile: File exists"
    monkeypatch.setattr(tp, "load_windows", no_reading)
    with pytest.raises(InputError, match=f"^{afile} is a file, not a folder$"):
        train_prior(tiny_config(data), afile)
    with pytest.raises(InputError, match=f"^{afile / 'a' / 'b'}: {afile} is a file, not a "):
        fit_dataset(tiny_fit_config(data, tmp_path / "prior"), afile / "a" / "b")
    monkeypatch.setattr(guards.os, "access", lambda *a: False)  # a read-only disk
    with pytest.raises(InputError, match="run: .* cannot be written in \\(read-only or not"):
        train_prior(tiny_config(data), tmp_path / "run")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "data", "prior"]


def test_a_run_folder_inside_the_data_is_named_as_such(tmp_path):
    from tests.test_train_options import tiny_fit_config

    data = write_corpus(tmp_path / "data", n=3, T=40)
    train_prior(tiny_config(data, epochs=1), data / "old_run", max_steps=1)  # kept in the data
    # it used to list the checkpoint's 40-odd weight names as the keys a motion lacks
    with pytest.raises(InputError) as err:
        train_prior(tiny_config(data, epochs=1), tmp_path / "new_run", max_steps=1)
    assert str(err.value) == (
        f"{data / 'old_run' / 'best.npz'}: a checkpoint of an mdvae run, not motion: keep run "
        "folders out of the data folders"
    )
    with pytest.raises(InputError, match="old_run/best.npz: a checkpoint of an mdvae run"):
        fit_dataset(tiny_fit_config(data, data / "old_run"), tmp_path / "den")


def test_resuming_with_the_command_as_first_run_goes_on(tmp_path):
    """The README's "add --resume to the command you ran": --split, --config (and on
    fit-dataset --prior) given again with the run's own values used to be refused as
    changes; another value still is."""
    data = write_corpus(tmp_path / "data", n=3, T=70)
    split = data / "split.json"
    names = sorted(p.name for p in data.glob("*.npz"))
    split.write_text(json.dumps({"train": names[:2], "val": names[2:]}))
    config = tmp_path / "pc.json"
    config.write_text(json.dumps({"window": 20, "stride": 5, "batch_size": 8, "epochs": 1}))
    run = tmp_path / "run"
    first = ["train-prior", str(data), "--split", str(split), "-o", str(run), "--config",
             str(config), "--latent-dim", "8", "--hidden-dim", "32", "--device", "cpu"]  # fmt: skip
    res = CliRunner().invoke(cli, [*first, "--max-steps", "1"])
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(cli, [*first, "--resume", "--max-steps", "2"])
    assert res.exit_code == 0, res.output
    assert json.loads((run / "config.json").read_text())["split_file"] == str(split)
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"window": 20, "stride": 5, "batch_size": 4, "epochs": 1}))
    res = CliRunner().invoke(cli, [*first[:7], str(other), *first[8:], "--resume"])
    assert res.exit_code == 1 and "--config cannot change when resuming" in res.output
    # an option given now wins over the file's value: the file itself is unchanged
    res = CliRunner().invoke(cli, [*first, "--resume", "--epochs", "2", "--max-steps", "3"])
    assert res.exit_code == 0, res.output

    den = tmp_path / "den"
    fit = ["fit-dataset", str(data), "-o", str(den), "--prior", str(run), "--epochs", "1",
           "--batch-size", "4", "--device", "cpu"]  # fmt: skip
    res = CliRunner().invoke(cli, [*fit, "--max-steps", "1"])
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(cli, [*fit, "--resume", "--max-steps", "2"])
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(cli, [*fit[:5], str(tmp_path / "elsewhere"), *fit[6:], "--resume"])
    assert res.exit_code == 1 and "--prior cannot change when resuming" in res.output
