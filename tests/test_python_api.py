"""The Python API as a notebook user calls it: the documented snippets run as written, arrays
(numpy or torch) go in, bad ones are refused in one line, and torch's global state (random
stream, thread count, default dtype) and the inputs are left as they were."""

from __future__ import annotations

import contextlib
import io
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from mdvae_cli.errors import InputError
from mdvae_cli.formats.npz_io import load_motion, motion_from_arrays
from mdvae_cli.formats.registry import write
from mdvae_cli.infer.denoise_settings import DenoiseSettings, denoise
from mdvae_cli.motion.motion import Motion
from mdvae_cli.weights import default_weights

REPO = Path(__file__).resolve().parents[1]
NOISY = REPO / "examples" / "noisy_walk.npz"
TRUTH = REPO / "examples" / "walk.npz"


def python_blocks(doc: Path) -> str:
    """Every ```python block of a document, in order, as one script."""
    return "\n".join(re.findall(r"```python\n(.*?)```", doc.read_text(), flags=re.S))


@pytest.mark.parametrize("doc", ["README.md", "docs/architecture.md"])
def test_the_documented_snippets_run_as_written(doc, tmp_path, monkeypatch):
    (tmp_path / "noisy.npz").write_bytes(NOISY.read_bytes())
    (tmp_path / "truth.npz").write_bytes(TRUTH.read_bytes())
    write(load_motion(NOISY), tmp_path / "take.bvh")  # a BVH take for the file snippet
    monkeypatch.chdir(tmp_path)
    torch.set_num_threads(1)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(python_blocks(REPO / doc), doc, "exec"), {})  # noqa: S102
    assert (tmp_path / "clean.npz").is_file()
    assert out.getvalue() == ""  # the library prints nothing


def test_the_readme_denoises_a_video_file_as_the_command_does():
    # DenoiseSettings(input_kind=take.kind): a video file's settings row, as the command picks
    snippet = python_blocks(REPO / "README.md")
    assert "DenoiseSettings(input_kind=take.kind)" in snippet


def test_loading_the_networks_leaves_torchs_random_stream_alone():
    from mdvae_cli.model.denoiser import load_denoiser
    from mdvae_cli.model.prior_model import load_prior

    torch.manual_seed(7)
    expected = torch.rand(4)
    torch.manual_seed(7)
    load_denoiser(None)  # builds networks: their first weights were drawn from the global stream
    load_prior(default_weights("prior"))
    np.testing.assert_array_equal(torch.rand(4).numpy(), expected.numpy())


def test_a_seeded_training_start_draws_what_it_always_drew():
    # training passes keep_rng=False: a seeded run's first weights stay the recipe's
    from mdvae_cli.model.prior_model import load_prior

    torch.manual_seed(7)
    unloaded = torch.rand(4)
    torch.manual_seed(7)
    load_prior(default_weights("prior"), keep_rng=False)
    assert not torch.equal(torch.rand(4), unloaded)


def test_denoise_leaves_global_state_and_inputs_and_repeats_itself(capsys):
    torch.set_num_threads(2)
    torch.manual_seed(3)
    rng_state = torch.get_rng_state()
    motion = load_motion(NOISY)
    before = {k: getattr(motion, k).copy() for k in ("root_orient", "pose_body", "trans")}
    first = denoise([motion], DenoiseSettings(refine_steps=2))[0]
    second = denoise([motion], DenoiseSettings(refine_steps=2))[0]
    assert torch.get_num_threads() == 2
    assert torch.get_default_dtype() == torch.float32
    assert torch.equal(torch.get_rng_state(), rng_state)
    assert capsys.readouterr().out == ""
    for key, value in before.items():
        np.testing.assert_array_equal(getattr(motion, key), value)
        np.testing.assert_array_equal(getattr(first, key), getattr(second, key))
    torch.set_num_threads(1)


def _arrays(**change) -> dict:
    data = dict(np.load(NOISY))
    data.update(change)
    return data


def test_arrays_and_tensors_in_any_float_width_give_the_same_motion():
    data = _arrays()
    as_f64 = motion_from_arrays({**data, "poses": data["poses"].astype(np.float64)})
    grad = torch.from_numpy(data["poses"]).requires_grad_()
    as_tensors = motion_from_arrays(
        {**data, "poses": grad, "trans": torch.from_numpy(data["trans"])}
    )
    np.testing.assert_array_equal(as_tensors.pose_body, as_f64.pose_body)
    from_poses = Motion.from_poses(grad, torch.from_numpy(data["trans"]), data["betas"], 30)
    np.testing.assert_array_equal(from_poses.pose_body, as_f64.pose_body)
    np.testing.assert_allclose(from_poses.trans, as_f64.trans)


def _built(**change) -> Motion:
    data = _arrays()
    motion = Motion.from_poses(data["poses"], data["trans"], data["betas"], 30.0)
    for key, value in change.items():
        setattr(motion, key, value(getattr(motion, key)) if callable(value) else value)
    return motion


def _with_nan(a: np.ndarray) -> np.ndarray:
    a = a.copy()
    a[10, 4] = np.nan
    return a


@pytest.mark.parametrize(
    "change, message",
    [
        ({"pose_body": _with_nan}, r"motion 0: pose_body holds NaN or infinite values in 1 frame"),
        ({"trans": lambda t: t[:-3]}, r"motion 0: trans has shape \(76, 3\), expected \(79, 3\)"),
        ({"pose_body": lambda p: p[:, :20]}, r"pose_body has shape \(79, 20, 3\)"),
        ({"fps": 0.0}, r"motion 0: fps: frame rate 0 Hz is implausible"),
        ({"joint_mask": np.ones((79, 24), bool)}, r"joint_mask has shape \(79, 24\)"),
    ],
)
def test_a_bad_motion_is_refused_in_one_line(change, message):
    # before: ValueError("height_tol and speed_tol must be > 0") from the foot lock for a NaN,
    # numpy reshape or broadcast errors for the shapes
    with pytest.raises(InputError, match=message) as err:
        denoise([_built(**change)], DenoiseSettings(feet="lock"))
    assert "\n" not in str(err.value)


def test_one_motion_instead_of_a_list_is_named():
    with pytest.raises(TypeError, match=r"pass \[motion\]"):
        denoise(_built())
    with pytest.raises(InputError, match=r"poses has shape \(79, 60\), expected \(T, 66 \+ K\)"):
        Motion.from_poses(np.zeros((79, 60)), np.zeros((79, 3)), np.zeros(10), 30)


def test_hands_of_the_wrong_length_are_refused_not_zeroed():
    # before: pose_extra of 78 rows for 79 frames became 79 rows of zeros (the hands lost), a
    # (90,) row became (79, 0) (no hands at all), both without a word
    T, body = 79, dict(root_orient=np.zeros((79, 3)), pose_body=np.zeros((79, 21, 3)),
                       trans=np.zeros((79, 3)), betas=np.zeros(10), fps=30.0)  # fmt: skip
    for hands, shape in ((np.ones((T - 1, 90)), r"\(78, 90\)"), (np.ones(90), r"\(90,\)")):
        with pytest.raises(InputError, match=rf"pose_extra has shape {shape}, expected \(79, K\)"):
            Motion(**body, pose_extra=hands)
    assert Motion(**body, pose_extra=np.ones((T, 90))).pose_extra.sum() == T * 90
    assert Motion(**body).pose_extra.shape == (T, 0)  # none given: no hands
    assert Motion(**body, pose_extra=None).pose_extra.shape == (T, 0)
    assert Motion(**body, pose_extra=np.zeros((0, 90))).pose_extra.shape == (T, 90)


def test_with_body_to_another_frame_count_carries_the_hands_it_is_given():
    hands = Motion(root_orient=np.zeros((5, 3)), pose_body=np.zeros((5, 21, 3)),
                   trans=np.zeros((5, 3)), betas=np.zeros(10), fps=30.0,
                   pose_extra=np.ones((5, 90)))  # fmt: skip
    with pytest.raises(InputError, match=r"changes the frame count \(5 -> 3\).*pose_extra="):
        hands.with_body(np.zeros((3, 3)), np.zeros((3, 21, 3)), np.zeros((3, 3)))
    cut = hands.with_body(np.zeros((3, 3)), np.zeros((3, 21, 3)), np.zeros((3, 3)),
                          np.full((3, 90), 2.0))  # fmt: skip
    assert cut.pose_extra.shape == (3, 90) and cut.pose_extra.sum() == 3 * 90 * 2.0
    bare = Motion(root_orient=np.zeros((5, 3)), pose_body=np.zeros((5, 21, 3)),
                  trans=np.zeros((5, 3)), betas=np.zeros(10), fps=30.0)  # fmt: skip
    longer = bare.with_body(np.zeros((8, 3)), np.zeros((8, 21, 3)), np.zeros((8, 3)))
    assert longer.pose_extra.shape == (8, 0)  # no hands: nothing to carry


def test_the_body_model_poses_numpy_arrays():
    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.body.skinning import BodyModel

    body = BodyModel(load_body_model(None))
    m = load_motion(NOISY)
    mine = body(m.root_orient, m.pose_body, m.trans, m.betas).joints
    as_tensors = body(
        *(torch.from_numpy(a) for a in (m.root_orient, m.pose_body, m.trans, m.betas))
    )
    assert mine.shape == (79, 22, 3)
    torch.testing.assert_close(mine, as_tensors.joints)


def test_an_import_leaves_torchs_thread_count(tmp_path):
    from mdvae_cli.retarget.retarget import RetargetSettings
    from mdvae_cli.run.import_files import FileImporter
    from mdvae_cli.run.jobs import FileJob

    take = tmp_path / "take.bvh"
    write(load_motion(NOISY), take)
    torch.set_num_threads(2)
    importer = FileImporter(None, tmp_path, 30.0, RetargetSettings().validate(), None, None, None)
    row = importer(FileJob(Path("take.bvh"), take, tmp_path / "take.npz"))
    assert row["frames"] == 79
    assert torch.get_num_threads() == 2  # before: 1 from then on
    torch.set_num_threads(1)


def test_reading_files_does_not_import_torch():
    code = (
        "import sys, mdvae_cli, mdvae_cli.formats.registry, mdvae_cli.motion.motion;"
        "print('torch' in sys.modules)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "False"


def test_noise_takes_a_seed_as_well_as_a_generator():
    from mdvae_cli.motion.noise import VideoNoise, add_pose_noise, add_video_noise

    m = load_motion(TRUTH)
    by_seed = add_pose_noise(m, 0.1, 5, drop_frac=0.1)  # before: AttributeError: 'int' ... spawn
    by_rng = add_pose_noise(m, 0.1, np.random.default_rng(5), drop_frac=0.1)
    np.testing.assert_array_equal(by_seed.pose_body, by_rng.pose_body)
    np.testing.assert_array_equal(by_seed.joint_mask, by_rng.joint_mask)
    video = add_video_noise(m, VideoNoise(), 5).trans
    np.testing.assert_array_equal(
        video, add_video_noise(m, VideoNoise(), np.random.default_rng(5)).trans
    )


def test_training_leaves_the_callers_random_stream(tmp_path):
    from mdvae_cli.train.fit_dataset import FitConfig, fit_dataset
    from mdvae_cli.train.train_prior import train_prior
    from tests.test_prior import tiny_config, write_corpus

    data = write_corpus(tmp_path / "clean", n=2, T=40)
    torch.manual_seed(11)
    expected = torch.rand(4)
    torch.manual_seed(11)
    train_prior(tiny_config(data, epochs=1, seed=3), tmp_path / "prior", max_steps=1)
    cfg = FitConfig(data=[str(data)], prior=str(tmp_path / "prior"), window=20, stride=5,
                    batch_size=8, epochs=1, device="cpu", seed=3)  # fmt: skip
    fit_dataset(cfg, tmp_path / "den", max_steps=1)
    np.testing.assert_array_equal(torch.rand(4).numpy(), expected.numpy())  # before: reseeded


def test_training_leaves_the_callers_gpu_streams(tmp_path, monkeypatch):
    # CUDA as the library sees it, two devices whose generator states are numbers; before: a
    # run seeded every GPU's generator (torch.manual_seed) and gave back only the CPU's
    from types import SimpleNamespace

    from mdvae_cli.train.fit_dataset import FitConfig, fit_dataset
    from mdvae_cli.train.run_state import seeded_run
    from mdvae_cli.train.train_prior import train_prior
    from tests.test_prior import tiny_config, write_corpus

    data = write_corpus(tmp_path / "clean", n=2, T=40)
    states = {0: 5, 1: 6}
    for name, fake in {
        "is_available": lambda: True,
        "is_initialized": lambda: True,  # the caller has been using its GPU
        "device_count": lambda: 2,
        "get_rng_state": lambda device: states[device],
        "set_rng_state": lambda state, device: states.__setitem__(device, state),
        "manual_seed_all": lambda seed: states.update({0: seed, 1: seed}),
    }.items():
        monkeypatch.setattr(torch.cuda, name, fake)
    seen = []

    @seeded_run
    def on_a_gpu(cfg):
        seen.append(dict(states))
        states[0] = 99  # the run's draws

    on_a_gpu(SimpleNamespace(device="cuda", seed=3, validate=lambda: None))
    assert seen == [{0: 3, 1: 3}] and states == {0: 5, 1: 6}
    # runs on the CPU: the GPUs' generators are neither seeded nor moved
    train_prior(tiny_config(data, epochs=1, seed=3, device="cpu"), tmp_path / "prior", max_steps=1)
    cfg = FitConfig(data=[str(data)], prior=str(tmp_path / "prior"), window=20, stride=5,
                    batch_size=8, epochs=1, device="cpu", seed=3)  # fmt: skip
    fit_dataset(cfg, tmp_path / "den", max_steps=1)
    assert states == {0: 5, 1: 6}


def test_changing_a_result_in_place_leaves_its_input():
    motion = load_motion(NOISY)
    hands, betas = motion.pose_extra.copy(), motion.betas.copy()
    clean = denoise([motion], DenoiseSettings(feet="off"))[0]
    clean.pose_extra[:] = 0.0  # before: the input's hands, the very same array (now a copy)
    clean.betas[:] = 0.0
    np.testing.assert_array_equal(motion.pose_extra, hands)
    np.testing.assert_array_equal(motion.betas, betas)


def test_denoise_takes_a_weights_path_and_body_data():
    from mdvae_cli.body.formats import load_body_model

    motion = load_motion(NOISY)
    by_default = denoise([motion], DenoiseSettings(feet="off"))[0]
    # before: AttributeError 'BodyModelData' object has no attribute 'fit_betas' / 'str' ... 'cfg'
    by_path = denoise(
        [motion], DenoiseSettings(feet="off"), str(default_weights("denoiser")), load_body_model()
    )[0]
    np.testing.assert_array_equal(by_path.pose_body, by_default.pose_body)


def test_evaluate_refuses_a_motion_that_is_not_one_in_one_line():
    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.metrics import evaluate_pair

    truth, pred = load_motion(TRUTH), load_motion(NOISY)
    pose_body = pred.pose_body.copy()
    pose_body[5, 3] = np.nan  # before: v2v_cm nan, returned as a score
    with pytest.raises(InputError, match=r"prediction: pose_body holds NaN .* the first 5;"):
        evaluate_pair(truth, pred.with_body(pose_body=pose_body), load_body_model())
    with pytest.raises(InputError, match=r"ground truth: trans has shape \(79, 2\)"):
        evaluate_pair(truth.with_body(trans=truth.trans[:, :2]), pred, load_body_model())


def test_a_long_takes_shared_arrays_are_read_only_views_not_copies():
    from dataclasses import replace

    from mdvae_cli.motion.motion import unshared

    motion = load_motion(NOISY)
    T = 20000  # hands of 20,000 frames: 14 MB, over the size that is copied
    big = Motion.from_poses(np.zeros((T, 156)), np.zeros((T, 3)), motion.betas, 30.0)
    out = unshared(replace(big, trans=np.ones((T, 3))), big)
    assert np.shares_memory(out.pose_extra, big.pose_extra) and not out.pose_extra.flags.writeable
    with pytest.raises(ValueError, match="read-only"):
        out.pose_extra[:] = 1.0
    assert not np.shares_memory(out.betas, big.betas) and out.betas.flags.writeable  # copied
