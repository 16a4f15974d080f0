"""The video row's smoothing of the result (``KindSettings.smooth_s``, ``--smooth``): how much
of it a take gets from how noisy its input reads, that a clean-reading take comes back as
without it, that a noisy one comes back smoother, and the options around it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mdvae_cli.cli.main import cli
from mdvae_cli.errors import InputError
from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.infer.denoise_settings import (
    DenoiseSettings,
    denoise,
    smoothed,
    smoothing_share,
)
from mdvae_cli.infer.fill import TAKE_NOISE_RAD
from mdvae_cli.infer.input_kinds import INPUT_KINDS
from mdvae_cli.infer.noise_blend import noise_level

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def walk():
    return load_motion(EXAMPLES / "walk.npz")


def with_rotation_noise(motion, std: float, seed: int = 0):
    """``motion`` with white noise of ``std`` rad on every rotation component."""
    rng = np.random.default_rng(seed)
    rot = motion.joint_rotations + rng.normal(0.0, std, motion.joint_rotations.shape)
    return motion.with_body(root_orient=rot[:, 0], pose_body=rot[:, 1:])


def jerk(motion) -> float:
    """Mean absolute second difference of the joint rotations (rad per frame^2)."""
    return float(np.abs(np.diff(motion.joint_rotations, 2, axis=0)).mean())


def test_smoothing_follows_the_kind_row_and_the_option():
    assert INPUT_KINDS["mocap"].smooth_s == 0.0 and INPUT_KINDS["video"].smooth_s == 0.05
    assert DenoiseSettings().smoothing() == 0.0
    assert DenoiseSettings(input_kind="video").smoothing() == 0.05
    assert DenoiseSettings(input_kind="video", smooth_s=0.1).smoothing() == 0.1
    assert DenoiseSettings(input_kind="mocap", smooth_s=0.1).smoothing() == 0.1
    assert DenoiseSettings(input_kind="video", smooth_s=0.0).smoothing() == 0.0
    # the paper's regression mode stays untouched
    assert DenoiseSettings(input_kind="video", offset=False).smoothing() == 0.0
    # the report says what was used
    assert DenoiseSettings(input_kind="video").refine_row()[1]["smooth_s"] == 0.05
    with pytest.raises(InputError, match="smooth_s"):
        DenoiseSettings(smooth_s=-0.1)


def test_the_share_of_smoothing_rises_with_the_inputs_noise():
    half = 0.5 * TAKE_NOISE_RAD
    assert smoothing_share(0.0) == 0.0 and smoothing_share(half) == 0.0
    assert smoothing_share(1.5 * half) == pytest.approx(0.5)
    assert smoothing_share(TAKE_NOISE_RAD) == 1.0 and smoothing_share(0.2) == 1.0


def test_noise_level_reads_white_rotation_noise():
    clean = walk()
    assert noise_level(clean) < 0.5 * TAKE_NOISE_RAD  # a clean take: no smoothing
    for std in (0.02, 0.05):
        assert noise_level(with_rotation_noise(clean, std)) == pytest.approx(std, rel=0.2)


def test_a_noisy_video_take_comes_back_smoother_and_a_clean_one_as_without_it():
    noisy = with_rotation_noise(walk(), 0.03)
    got = {}
    on = denoise([noisy], DenoiseSettings(input_kind="video", feet="off"),
                 on_smooth=got.__setitem__)[0]  # fmt: skip
    off = denoise([noisy], DenoiseSettings(input_kind="video", feet="off", smooth_s=0.0))[0]
    assert got == {0: 0.05}  # it reads noisy: all of the row's smoothing
    assert jerk(on) < 0.85 * jerk(off)
    # the same motion, its rotations within the smoothing's reach of each other
    assert np.abs(on.joint_rotations - off.joint_rotations).mean() < 0.02
    clean = walk()
    on = denoise([clean], DenoiseSettings(input_kind="video", feet="off"))[0]
    off = denoise([clean], DenoiseSettings(input_kind="video", feet="off", smooth_s=0.0))[0]
    assert np.array_equal(on.joint_rotations, off.joint_rotations)
    assert np.array_equal(on.trans, off.trans)


def test_smoothing_keeps_cycles_and_holes_left_as_they_came():
    source = with_rotation_noise(walk(), 0.03)
    mask = np.ones((source.num_frames, 22), bool)
    mask[30:36] = False  # a hole of every joint
    source.joint_mask = mask
    result = with_rotation_noise(walk(), 0.01, seed=1)
    out = smoothed([result], [source], [False], 0.05, "off")[0]
    np.testing.assert_array_equal(out.joint_rotations[30:36], source.joint_rotations[30:36])
    assert not np.array_equal(out.joint_rotations[:30], result.joint_rotations[:30])
    # a cycle is left as it is (a Gaussian with ends would open its seam)
    assert smoothed([result], [source], [True], 0.05, "curve")[0] is result
    assert smoothed([result], [source], [False], 0.0, "curve")[0] is result


def test_the_smooth_option(tmp_path):
    src = tmp_path / "noisy.npz"
    src.write_bytes((EXAMPLES / "noisy_walk.npz").read_bytes())
    runner = CliRunner()
    res = runner.invoke(cli, ["denoise", str(src), "-o", str(tmp_path / "a.npz"),
                              "--input-kind", "video", "--smooth", "0.1", "--json"])  # fmt: skip
    assert res.exit_code == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["settings"]["video"]["smooth_s"] == 0.1
    # what each take got: all of it, its input reading noisy; none for a clean one
    assert doc["files"][0]["result"]["tracks"][0]["smoothed_s"] == 0.1
    clean = tmp_path / "clean.npz"
    clean.write_bytes((EXAMPLES / "walk.npz").read_bytes())
    res = runner.invoke(cli, ["denoise", str(clean), "-o", str(tmp_path / "d.npz"),
                              "--input-kind", "video", "--json"])  # fmt: skip
    assert res.exit_code == 0, res.stderr
    assert json.loads(res.stdout)["files"][0]["result"]["tracks"][0]["smoothed_s"] == 0.0
    res = runner.invoke(cli, ["denoise", str(src), "-o", str(tmp_path / "b.npz"),
                              "--smooth", "0.1", "--no-offset"])  # fmt: skip
    errors = [line for line in res.stderr.splitlines() if line.startswith("error:")]
    assert res.exit_code == 1 and len(errors) == 1 and "--smooth" in errors[0]
    res = runner.invoke(cli, ["denoise", str(src), "-o", str(tmp_path / "c.npz"),
                              "--smooth", "-1"])  # fmt: skip
    errors = [line for line in res.stderr.splitlines() if line.startswith("error:")]
    assert res.exit_code == 1 and len(errors) == 1 and "--smooth" in errors[0]
    assert not (tmp_path / "b.npz").exists() and not (tmp_path / "c.npz").exists()
