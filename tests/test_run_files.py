"""``run.denoise_files``: what ``mdvae denoise`` does to files, called from Python."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.cli.main import cli
from mdvae_cli.errors import InputError
from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.formats.registry import ReadOptions
from mdvae_cli.infer.denoise_settings import DenoiseSettings
from mdvae_cli.model.denoiser import load_denoiser
from mdvae_cli.run.denoise_files import denoise_files, read_file, write_file

REPO = Path(__file__).resolve().parents[1]
NOISY = REPO / "examples" / "noisy_walk.npz"


def test_the_python_api_writes_and_reports_what_the_command_does(tmp_path):
    res = CliRunner().invoke(
        cli, ["denoise", str(NOISY), "-o", str(tmp_path / "cli.npz"), "--json"]
    )
    assert res.exit_code == 0, res.output
    said = json.loads(res.stdout)
    body_data = load_body_model(None)
    run = read_file(NOISY, tmp_path / "api.npz", ReadOptions(body=body_data))
    assert (run.format, run.input_kind, len(run.tracks)) == ("amass", "mocap", 1)
    settings = DenoiseSettings()
    denoise_files([run], settings, load_denoiser(None)[0], BodyModel(body_data))
    write_file(run, BodyModel(body_data))
    a, b = load_motion(tmp_path / "cli.npz"), load_motion(tmp_path / "api.npz")
    np.testing.assert_allclose(a.pose_body, b.pose_body, atol=1e-6)
    np.testing.assert_allclose(a.trans, b.trans, atol=1e-6)
    mine, theirs = run.to_dict(), said["files"][0]["result"]
    assert run.seconds > 0 and run.frames == load_motion(NOISY).num_frames
    for d in (mine, theirs, *mine["tracks"], *theirs["tracks"]):
        d.pop("seconds", None), d.pop("output", None)
    assert mine == theirs
    assert said["mode"] == settings.mode == "regression+offset"


def test_a_file_not_denoised_is_not_written(tmp_path):
    run = read_file(NOISY, tmp_path / "x.npz", ReadOptions())
    with pytest.raises(InputError, match="not denoised"):
        write_file(run, BodyModel(load_body_model(None)))
    assert not (tmp_path / "x.npz").exists()


@pytest.mark.parametrize(
    "settings, mode",
    [
        (DenoiseSettings(offset=False), "regression"),
        (DenoiseSettings(refine_steps=3), "refinement"),
        (DenoiseSettings(optimize_steps=2, refine_steps=3), "optimization"),
    ],
)
def test_the_mode_names_what_runs_after_the_networks_pass(settings, mode):
    assert settings.mode == mode
