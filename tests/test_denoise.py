"""Unsupervised denoising: ELBO training, regression/optimisation modes, files in and out."""

import copy
import json
import resource
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from mdvae_cli.body.builtin import builtin_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.cli.main import cli
from mdvae_cli.errors import InputError
from mdvae_cli.filters import savgol_filter_motion
from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.infer.denoise import denoise_motions
from mdvae_cli.infer.settings import RefineConfig
from mdvae_cli.infer.stitch import blend_windows
from mdvae_cli.metrics import evaluate_pair
from mdvae_cli.model.denoiser import Denoiser, DenoiserConfig, load_denoiser
from mdvae_cli.model.prior_model import load_prior
from mdvae_cli.model.state import BodyParams
from mdvae_cli.motion.noise import add_pose_noise
from mdvae_cli.train.fit_dataset import FitConfig, fit_dataset
from mdvae_cli.train.train_prior import train_prior
from tests.test_prior import tiny_config, write_corpus

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.fixture(scope="module")
def tiny_prior(tmp_path_factory):
    root = tmp_path_factory.mktemp("prior")
    data = write_corpus(root / "clean", n=4, T=90)
    train_prior(tiny_config(data, epochs=2), root / "run")
    return root


@pytest.fixture(scope="module")
def noisy_dir(tiny_prior):
    out = tiny_prior / "noisy"
    out.mkdir(exist_ok=True)
    rng = np.random.default_rng(0)
    for f in sorted((tiny_prior / "clean").glob("*.npz")):
        with np.load(f) as z:
            arrays = dict(z)
        arrays["poses"][:, 3:66] += rng.normal(0, 0.15, arrays["poses"][:, 3:66].shape)
        with open(out / f.name, "wb") as fh:
            np.savez(fh, **arrays)
    return out


def tiny_fit(tiny_prior, noisy_dir, epochs: int, lr: float | None = None, **denoiser) -> FitConfig:
    """A fit-dataset config for the tiny prior and noisy clips (``denoiser``: its settings)."""
    extra = {} if lr is None else {"lr": lr}
    return FitConfig(
        data=[str(noisy_dir)],
        prior=str(tiny_prior / "run"),
        window=20,
        stride=5,
        batch_size=8,
        epochs=epochs,
        device="cpu",
        denoiser=DenoiserConfig(hidden_dim=16, **denoiser),
        **extra,
    )


def test_fit_dataset_lowers_its_loss_and_saves_a_loadable_denoiser(tiny_prior, noisy_dir, tmp_path):
    log = []
    cfg = tiny_fit(tiny_prior, noisy_dir, epochs=6, lr=3e-3, lam=20.0, obs_unit=0.05)
    summary = fit_dataset(cfg, tmp_path / "den", progress=lambda d: log.append(d["loss"]))
    assert summary.steps == len(log) > 20
    assert np.mean(log[-5:]) < 0.8 * np.mean(log[:5]), (log[:5], log[-5:])
    den, meta = load_denoiser(tmp_path / "den")
    assert meta["denoiser_config"]["lam"] == 20.0
    # the prior inside is frozen: identical to the one it started from
    prior, _ = load_prior(tiny_prior / "run")
    for a, b in zip(prior.state_dict().values(), den.prior.state_dict().values(), strict=True):
        torch.testing.assert_close(a, b)
    # resume continues the step count
    cfg.epochs = 7
    resumed = fit_dataset(cfg, tmp_path / "den", resume=True)
    assert resumed.steps > summary.steps


def test_fit_dataset_stopped_and_resumed_ends_bit_identical(tiny_prior, noisy_dir, tmp_path):
    """A fit stopped part way (here after 7 of its steps) and resumed ends with exactly the
    networks of the whole run: the learning-rate schedule, the batch order, Adam's state and
    the Monte-Carlo draws all carry on (resume.npz beside denoiser.npz)."""
    cfg = tiny_fit(tiny_prior, noisy_dir, epochs=2)
    whole = fit_dataset(cfg, tmp_path / "whole")
    part = fit_dataset(cfg, tmp_path / "part", max_steps=7)
    assert part.steps == 7 < whole.steps and (tmp_path / "part" / "resume.npz").exists()
    resumed = fit_dataset(cfg, tmp_path / "part", resume=True)
    assert resumed.steps == whole.steps
    a, _ = load_denoiser(tmp_path / "whole")
    b, _ = load_denoiser(tmp_path / "part")
    for (name, x), y in zip(a.state_dict().items(), b.state_dict().values(), strict=True):
        assert torch.equal(x, y), name
    # without the saved state (a run from an older version) it still resumes, not identically
    fit_dataset(cfg, tmp_path / "old", max_steps=7)
    (tmp_path / "old" / "resume.npz").unlink()
    fit_dataset(cfg, tmp_path / "old", resume=True)
    c, _ = load_denoiser(tmp_path / "old")
    pairs = zip(a.state_dict().values(), c.state_dict().values(), strict=True)
    assert not all(torch.equal(x, y) for x, y in pairs)


def test_a_sigterm_stops_fit_dataset_after_its_step_and_resume_ends_bit_identical(
    tiny_prior, noisy_dir, tmp_path, monkeypatch
):
    """The first SIGTERM (or Ctrl-C) saves the networks after the step it came in and exits
    143, the second would stop at once; --resume then ends with exactly the networks of the
    whole run. Before: the signal stopped the run at once, the steps since the last save
    (every 200) lost."""
    import os
    import signal

    cfg = tiny_fit(tiny_prior, noisy_dir, epochs=2)
    whole = fit_dataset(cfg, tmp_path / "whole")
    config = tmp_path / "fit.json"
    config.write_text(json.dumps(cfg.to_dict()))
    real, calls = Denoiser.elbo, []

    def signalled_at_the_third_step(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            os.kill(os.getpid(), signal.SIGTERM)
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Denoiser, "elbo", signalled_at_the_third_step)
    out = tmp_path / "den"
    args = ["fit-dataset", str(noisy_dir), "-o", str(out), "--config", str(config)]
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 143, res.output
    assert "stopped at step 3; the run's denoiser.npz continues it with --resume" in res.output
    assert json.loads((out / "denoiser.json").read_text())["steps"] == 3
    assert json.loads((out / "log.jsonl").read_text())["interrupted"] is True
    monkeypatch.setattr(Denoiser, "elbo", real)
    res = CliRunner().invoke(cli, ["fit-dataset", str(noisy_dir), "-o", str(out), "--resume"])
    assert res.exit_code == 0, res.output
    a, _ = load_denoiser(tmp_path / "whole")
    b, meta = load_denoiser(out)
    assert meta["steps"] == whole.steps > 3
    for (name, x), y in zip(a.state_dict().items(), b.state_dict().values(), strict=True):
        assert torch.equal(x, y), name


def test_optimization_mode_changes_only_the_inference_networks(tiny_prior, noisy_dir):
    prior, _ = load_prior(tiny_prior / "run")
    den = Denoiser(prior, DenoiserConfig(hidden_dim=16))
    before = {k: v.clone() for k, v in den.state_dict().items()}
    body = BodyModel(builtin_body_model())
    motion = load_motion(noisy_dir / "clip0.npz")
    out = denoise_motions([motion], den, body, window=20, stride=15, optimize_steps=3)
    assert out[0].num_frames == motion.num_frames
    after = den.state_dict()
    changed = {k for k in before if not torch.equal(before[k], after[k])}
    assert changed and all(not k.startswith("prior.") for k in changed)
    assert any(k.startswith("encoder.") for k in changed)
    assert any(k.startswith("x0_predictor.") for k in changed)


def test_optimization_mode_is_reproducible_whatever_ran_before(tiny_prior, noisy_dir):
    """The ELBO's Monte-Carlo draws come from the given seed, not torch's global generator:
    two runs with other random work in between give the same motion; another seed does not."""
    prior, _ = load_prior(tiny_prior / "run")
    torch.manual_seed(0)
    den = Denoiser(prior, DenoiserConfig(hidden_dim=16))
    body = BodyModel(builtin_body_model())
    motion = load_motion(noisy_dir / "clip0.npz")

    def run(seed: int):
        model = copy.deepcopy(den)
        out = denoise_motions([motion], model, body, 20, 15, optimize_steps=3, seed=seed)
        return out[0].pose_body

    first = run(0)
    torch.rand(1000)  # moves the global generator
    np.testing.assert_array_equal(run(0), first)
    assert not np.allclose(run(1), first)


def test_blend_windows_reproduces_a_consistent_sequence():
    T, L = 50, 20
    g = torch.Generator().manual_seed(0)
    full = BodyParams(
        torch.randn(T, 3, generator=g) * 0.5,
        torch.randn(T, 21, 3, generator=g) * 0.3,
        torch.randn(T, 3, generator=g),
    )
    starts = [0, 15, 30]
    windows = [
        BodyParams(full.root_orient[s : s + L], full.pose_body[s : s + L], full.trans[s : s + L])
        for s in starts
    ]
    out = blend_windows(T, starts, windows)
    torch.testing.assert_close(out.trans, full.trans)
    torch.testing.assert_close(out.pose_body, full.pose_body, atol=1e-5, rtol=0)
    # two different windows: the overlap cross-fades from the first to the second
    a = BodyParams(torch.zeros(L, 3), torch.zeros(L, 21, 3), torch.zeros(L, 3))
    b = BodyParams(torch.zeros(L, 3), torch.zeros(L, 21, 3), torch.ones(L, 3))
    mix = blend_windows(30, [0, 10], [a, b])
    ramp = mix.trans[10:20, 0]
    assert torch.all(ramp[1:] > ramp[:-1]) and 0 < ramp[0] < 0.2 and 0.8 < ramp[-1] < 1
    assert float(mix.trans[25, 0]) == 1.0 and float(mix.trans[5, 0]) == 0.0


def write_denoiser(tiny_prior: Path, out: Path) -> Path:
    prior, _ = load_prior(tiny_prior / "run")
    from mdvae_cli.model.denoiser import save_denoiser

    save_denoiser(out / "denoiser.npz", Denoiser(prior, DenoiserConfig(hidden_dim=16)), {})
    return out


def test_cli_denoise_keeps_layout_frames_and_extras(tiny_prior, make_motion_file, tmp_path):
    den = write_denoiser(tiny_prior, tmp_path / "den")
    src = make_motion_file(
        "take.npz",
        T=97,
        width=165,
        fps=60.0,
        dmpls=np.ones((97, 8)),
        mocap_framerate=None,
        mocap_frame_rate=np.array(60.0),
    )
    before = src.read_bytes()
    out = tmp_path / "clean.npz"
    res = CliRunner().invoke(
        cli,
        [
            "denoise",
            str(src),
            "-o",
            str(out),
            "--denoiser",
            str(den),
            "--window",
            "20",
            "--overlap",
            "5",
            "--json",
        ],
    )
    assert res.exit_code == 0, res.output
    report = json.loads(res.stdout)
    assert (
        report["succeeded"] == 1 and report["mode"] == "regression+offset"
    )  # the default: offset on
    # the run's seconds are what the user waited: each file's reading, denoising and writing,
    # and the command's start-up (the networks loaded)
    assert report["seconds"] > report["files"][0]["result"]["seconds"] > 0
    assert src.read_bytes() == before
    with np.load(src) as a, np.load(out) as b:
        assert set(a.files) == set(b.files)
        assert b["poses"].shape == (97, 165) and np.isfinite(b["poses"]).all()
        np.testing.assert_array_equal(a["poses"][:, 66:], b["poses"][:, 66:])  # hands, face
        np.testing.assert_array_equal(a["dmpls"], b["dmpls"])
        np.testing.assert_array_equal(a["betas"], b["betas"])
        assert float(b["mocap_frame_rate"]) == 60.0


@pytest.mark.slow  # ~13 s on 2 cores
def test_cli_denoise_optimize_folder_meshes_and_failures(tiny_prior, noisy_dir, tmp_path):
    den = write_denoiser(tiny_prior, tmp_path / "den")
    inputs = tmp_path / "in"
    inputs.mkdir()
    for f in sorted(noisy_dir.glob("*.npz"))[:2]:
        (inputs / f.name).write_bytes(f.read_bytes())
    (inputs / "broken.npz").write_text("not a zip")
    out = tmp_path / "out"
    res = CliRunner().invoke(
        cli,
        [
            "denoise",
            str(inputs),
            "-o",
            str(out),
            "--denoiser",
            str(den),
            "--window",
            "20",
            "--overlap",
            "5",
            "--optimize",
            "2",
            "--per-file",
            "--mesh-dir",
            str(tmp_path / "mesh"),
            "--mesh-format",
            "obj",
        ],
    )
    assert res.exit_code == 1  # one file failed, the others were written
    assert "broken.npz" in res.output and "Traceback" not in res.output
    assert sorted(p.name for p in out.glob("*.npz")) == ["clip0.npz", "clip1.npz"]
    assert not (out / "broken.npz").exists()
    assert len(list((tmp_path / "mesh" / "clip0").glob("*.obj"))) == 90


def test_cli_denoise_refuses_a_too_short_file_and_goes_on(tmp_path):
    # a 0.1-s take among good ones: one error line naming it, no output for it, the rest written
    src = tmp_path / "in"
    src.mkdir()
    with np.load(EXAMPLES / "noisy_walk.npz") as z:
        data = dict(z)
    np.savez(src / "short.npz", **{**data, "poses": data["poses"][:4], "trans": data["trans"][:4]})
    (src / "walk.npz").write_bytes((EXAMPLES / "noisy_walk.npz").read_bytes())
    out = tmp_path / "out"
    res = CliRunner().invoke(cli, ["denoise", str(src), "-o", str(out)])
    assert res.exit_code == 1 and "Traceback" not in res.output
    assert "short.npz: too short to denoise: 4 frame(s) at 30 Hz (0.1 s)" in " ".join(
        res.output.split()
    )
    assert sorted(p.name for p in out.glob("*.npz")) == ["walk.npz"]


@pytest.mark.parametrize(
    "args, message",
    [
        (["missing.npz"], "no such file"),
        (["{bad}"], "not an .npz"),
        (["{bvh}"], "no MOTION section"),  # a BVH take is read now: a broken one says why
    ],
)
def test_cli_denoise_bad_inputs_write_nothing(tmp_path, args, message):
    bad = tmp_path / "bad.npz"
    bad.write_text("garbage")
    bvh = tmp_path / "take.bvh"
    bvh.write_text("HIERARCHY\nROOT Hips\n{\n")
    args = [a.replace("{bad}", str(bad)).replace("{bvh}", str(bvh)) for a in args]
    out = tmp_path / "o.npz"
    res = CliRunner().invoke(cli, ["denoise", *args, "-o", str(out)])
    assert res.exit_code != 0 and message in res.output and "Traceback" not in res.output
    assert not out.exists()


def test_shipped_denoiser_lowers_the_error_of_a_noisy_clip():
    clean = load_motion(EXAMPLES / "walk.npz")
    noisy = add_pose_noise(clean, 0.15, np.random.default_rng(7))
    den, _ = load_denoiser(None)
    body = BodyModel(builtin_body_model())
    out = denoise_motions([noisy], den, body)[0]
    before = evaluate_pair(clean, noisy, body)
    after = evaluate_pair(clean, out, body)
    # measured with the shipped weights: 11.0 -> 5.0 cm V2V, 215 -> 5.3 m/s^2 (GT 6.2)
    assert after.v2v_cm < 0.55 * before.v2v_cm, (before.v2v_cm, after.v2v_cm)
    assert abs(after.accel_pred - after.accel_gt) < 0.3 * after.accel_gt, after.accel_pred


def test_the_default_keeps_the_file_s_root_path():
    """Noise on the joint rotations only: the default's slow offsets (rotations and root
    translation, fitted in closed form) keep the root within a few cm of the file's path,
    where the decoded translation alone drifts off it (14 cm by the end of this walk)."""
    clean = load_motion(EXAMPLES / "walk.npz")
    noisy = add_pose_noise(clean, 0.15, np.random.default_rng(7))
    den, _ = load_denoiser(None)
    body = BodyModel(builtin_body_model())

    def root_error(cfg: RefineConfig) -> np.ndarray:
        out = denoise_motions([noisy], den, body, refine=cfg)[0]
        return np.linalg.norm(out.trans - clean.trans, axis=1)

    kept = root_error(RefineConfig(steps=0))
    drifted = root_error(RefineConfig(steps=0, trans_offset_std=0.0))
    # measured: mean 0.55 cm, worst 4.3 cm, against 2.2 and 14.5 cm without the offset
    assert kept.mean() < 0.01 and kept.max() < 0.06, (kept.mean(), kept.max())
    assert drifted.mean() > 3 * kept.mean() and drifted.max() > 2 * kept.max()


@pytest.mark.slow  # ~22 s on 2 cores
def test_ten_minute_file_denoises_in_bounded_memory(tmp_path):
    T = 10 * 60 * 30
    t = np.arange(T)[:, None] / 30.0
    poses = np.zeros((T, 156))
    poses[:, 0] = np.pi / 2
    poses[:, 3:66] = 0.3 * np.sin(2 * np.pi * 0.7 * t + np.arange(63)[None])
    trans = np.concatenate([np.cos(t / 10), np.sin(t / 10), 0.9 + 0 * t], 1)
    src = tmp_path / "long.npz"
    np.savez(src, poses=poses, trans=trans, betas=np.zeros(16), mocap_framerate=30.0)
    code = (
        "import resource, sys; from mdvae_cli.cli.main import cli\n"
        "try:\n cli(sys.argv[1:])\nexcept SystemExit as e:\n code = e.code\n"
        "print('MAXRSS', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\nsys.exit(code)\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code, "denoise", str(src), "-o", str(tmp_path / "out.npz")],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-1500:]
    maxrss_mb = int(proc.stdout.split("MAXRSS")[1]) / 1024
    assert maxrss_mb < 1500, maxrss_mb
    with np.load(tmp_path / "out.npz") as z:
        assert z["poses"].shape == (T, 156)
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss > 0


def write_smplh_layout_body(path: Path) -> Path:
    """An SMPL-H-layout model.npz (52 joints, 16 betas, as AMASS uses) built from the built-in
    body: hand joints chain off the wrists; the built-in hand weights go to the first knuckles."""
    b = builtin_body_model()
    V = b.num_vertices
    parents = list(b.parents[:22])
    for wrist in (20, 21):
        for _finger in range(5):
            first = len(parents)
            parents += [wrist, first, first + 1]
    J = np.zeros((52, V))
    J[:22] = b.J_regressor[:22]
    J[22:37] = b.J_regressor[22]
    J[37:52] = b.J_regressor[23]
    W = np.zeros((V, 52))
    W[:, :22] = b.weights[:, :22]
    W[:, 22] += b.weights[:, 22]
    W[:, 37] += b.weights[:, 23]
    kintree = np.array([[2**32 - 1, *parents[1:]], list(range(52))], dtype=np.int64)
    np.savez(
        path,
        v_template=b.v_template,
        shapedirs=b.shapedirs,
        posedirs=np.zeros((V, 3, 51 * 9)),
        J_regressor=J,
        weights=W,
        kintree_table=kintree,
        f=b.faces,
    )
    return path


def test_cli_denoise_with_an_smplh_layout_body_model(tmp_path, make_motion_file):
    body_file = write_smplh_layout_body(tmp_path / "model.npz")
    src = make_motion_file("take.npz", T=75, width=156, fps=30.0)
    out = tmp_path / "clean.npz"
    res = CliRunner().invoke(
        cli,
        [
            "denoise",
            str(src),
            "-o",
            str(out),
            "--body-model",
            str(body_file),
            "--optimize",
            "2",
            "--json",
        ],
    )
    assert res.exit_code == 0, res.output
    with np.load(out) as z:
        assert z["poses"].shape == (75, 156) and np.isfinite(z["poses"]).all()
    res = CliRunner().invoke(
        cli,
        ["eval", "--gt", str(src), "--pred", str(out), "--body-model", str(body_file), "--json"],
    )
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["mean"]["v2v_cm"] > 0


def test_x0_line_base_recovers_a_linear_trend():
    from mdvae_cli.model.denoiser import line_start_weights

    c = line_start_weights(9)
    y = 5.0 + 2.0 * torch.arange(9.0)
    assert float(c.sum()) == pytest.approx(1.0) and float(c @ y) == pytest.approx(5.0, abs=1e-5)
    assert line_start_weights(1).tolist() == [1.0]


def test_x0_predictor_reads_the_whole_window_and_old_configs_keep_their_layout():
    from mdvae_cli.model.denoiser import X0Predictor

    assert DenoiserConfig().x0_bidirectional is False
    assert DenoiserConfig.from_dict({"lam": 10.0}).x0_bidirectional is True  # older files
    torch.manual_seed(0)
    for bidirectional in (False, True):
        pred = X0Predictor(138, 16, base_window=3, bidirectional=bidirectional)
        torch.nn.init.normal_(pred.head[-1].weight, std=0.1)
        y = torch.randn(2, 12, 138)
        y2 = y.clone()
        y2[:, -1] += 5.0  # the last frame changes the estimate of frame 0
        a, b = pred(y), pred(y2)
        assert a.mean.shape == (2, 138)
        assert (a.mean - b.mean).abs().max() > 1e-5


def test_input_filter_smooths_what_the_networks_read_but_not_the_observations(tiny_prior):
    from mdvae_cli.infer.window_groups import make_windows, smooth_inputs
    from mdvae_cli.model.state import POSE
    from mdvae_cli.motion.motion import slice_frames

    assert DenoiserConfig().input_window == 11
    assert DenoiserConfig.from_dict({"lam": 10.0}).input_window == 0  # older files: raw input
    for bad in ({"input_window": 4}, {"input_window": -1}, {"input_window": 3, "input_order": 3}):
        with pytest.raises(InputError):
            DenoiserConfig(**bad)
    clean = load_motion(EXAMPLES / "walk.npz")
    noisy = add_pose_noise(clean, 0.15, np.random.default_rng(3))
    prior, _ = load_prior(tiny_prior / "run")
    body = BodyModel(builtin_body_model())
    raw = Denoiser(prior, DenoiserConfig(input_window=0))
    filt = Denoiser(prior, DenoiserConfig(input_window=11))
    (g_raw,) = make_windows([noisy], raw, body, window=40, stride=40)
    (g_filt,) = make_windows([noisy], filt, body, window=40, stride=40)
    # the networks' input is smoother: frame-to-frame changes of the pose columns shrink
    jump = lambda yn: (yn[:, 1:, POSE] - yn[:, :-1, POSE]).abs().mean()  # noqa: E731
    assert jump(g_filt.yn) < 0.5 * jump(g_raw.yn)
    # the observations stay the raw noisy points: same shape up to each window's rigid move
    dist = lambda y: (y[:, :, :, None] - y[:, :, None]).norm(dim=-1)  # noqa: E731
    assert torch.allclose(dist(g_raw.y3d), dist(g_filt.y3d), atol=1e-5)
    # short motions: the window shrinks to fit; 2 frames or fewer pass through unchanged
    two, five = slice_frames(noisy, 0, 2), slice_frames(noisy, 0, 5)
    other = add_pose_noise(clean, 0.15, np.random.default_rng(4))
    batch = smooth_inputs([noisy, two, five, other], DenoiserConfig())
    assert batch[1] is two
    assert batch[2].num_frames == 5 and not np.allclose(batch[2].pose_body, five.pose_body)
    # filtered side by side = filtered one by one
    for got, m in zip(batch, [noisy, two, five, other], strict=True):
        (alone,) = smooth_inputs([m], DenoiserConfig())
        np.testing.assert_allclose(got.pose_body, alone.pose_body, atol=1e-9)
        np.testing.assert_allclose(got.trans, alone.trans, atol=1e-9)
    expected = savgol_filter_motion(other, 11, 1)
    np.testing.assert_allclose(batch[3].pose_body, expected.pose_body, atol=1e-9)


def test_small_batch_numpy_path_matches_the_torch_networks(tiny_prior):
    from mdvae_cli.infer.denoise import predict_windows
    from mdvae_cli.infer.window_groups import make_windows
    from mdvae_cli.model.small_batch import SmallBatchRegressor

    prior, _ = load_prior(tiny_prior / "run")
    den = Denoiser(prior, DenoiserConfig())
    torch.manual_seed(0)
    for p in den.trainable_parameters():  # away from the zero-initialised heads
        p.data += 0.05 * torch.randn_like(p)
    den.eval()
    assert SmallBatchRegressor.supports(den)
    for B, T1 in ((1, 61), (3, 17), (2, 2)):
        yn = torch.randn(B, T1, 138)
        with torch.no_grad():
            want = den.infer(yn, with_prior=False)["x_hat"].numpy()
        got = SmallBatchRegressor(den)(yn.numpy())
        assert got.shape == want.shape and got.dtype == np.float32
        np.testing.assert_allclose(got, want, atol=2e-4 * (1 + np.abs(want).max()))
    # predict_windows takes the numpy path for a handful of windows: same result as torch
    import mdvae_cli.infer.denoise as denoise_module

    body = BodyModel(builtin_body_model())
    noisy = add_pose_noise(load_motion(EXAMPLES / "walk.npz"), 0.15, np.random.default_rng(1))
    (group,) = make_windows([noisy], den, body, window=40, stride=30, observations=False)
    assert len(group) <= denoise_module.SMALL_BATCH
    fast = predict_windows(den, group)
    small, denoise_module.SMALL_BATCH = denoise_module.SMALL_BATCH, 0
    try:
        slow = predict_windows(den, group)
    finally:
        denoise_module.SMALL_BATCH = small
    for k in ("root_orient", "pose_body", "trans"):
        torch.testing.assert_close(getattr(fast, k), getattr(slow, k), atol=1e-4, rtol=0)
    # the regressor kept on the denoiser follows its weights: an optimiser step, a copy
    from mdvae_cli.model.small_batch import small_batch_regressor

    yn = torch.randn(1, 21, 138)
    kept = small_batch_regressor(den)
    assert small_batch_regressor(den) is kept
    opt = torch.optim.Adam(den.trainable_parameters(), lr=1e-2)
    den.train()
    den.infer(yn)["x_hat"].square().mean().backward()
    opt.step()
    den.eval()
    updated = small_batch_regressor(den)
    assert updated is not kept
    with torch.no_grad():
        want = den.infer(yn, with_prior=False)["x_hat"].numpy()
    np.testing.assert_allclose(updated(yn.numpy()), want, atol=2e-4 * (1 + np.abs(want).max()))
    assert np.abs(kept(yn.numpy()) - want).max() > 1e-3  # the old weights give other states
    twin = copy.deepcopy(den)
    assert small_batch_regressor(twin) is not updated
    assert small_batch_regressor(den) is updated
    # layouts it does not cover are refused (callers fall back to torch)
    old = Denoiser(prior, DenoiserConfig(x0_bidirectional=True))
    assert not SmallBatchRegressor.supports(old)
    with pytest.raises(ValueError):
        SmallBatchRegressor(old)
