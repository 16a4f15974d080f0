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


def cycle_file(path: Path) -> Path:
    """A 30-frame cycle of a periodic motion (frame 30 would equal frame 0)."""
    from mdvae_cli.formats.npz_io import save_motion
    from mdvae_cli.motion.motion import slice_frames

    T = 30
    t = np.arange(T) / 30.0
    phase = 2 * np.pi * t
    pose = 0.4 * np.sin(phase[:, None, None] + np.arange(21)[None, :, None] * 0.3)
    trans = np.stack([1.0 * t, 0 * t, 0.9 + 0.02 * np.cos(2 * phase)], 1)
    walk = slice_frames(load_motion(REPO / "examples" / "walk.npz"), 0, T)
    root = np.tile([[0.0, 0.0, 1.0]], (T, 1))
    body = np.broadcast_to(pose, (T, 21, 3)).copy()
    cyc = walk.with_body(root_orient=root, pose_body=body, trans=trans)
    save_motion(cyc, path)
    return path


@pytest.mark.parametrize("flag, note, loop", [([], True, True), (["--no-loop"], False, False)])
def test_a_cycle_is_said_once_and_reported(tmp_path, flag, note, loop):
    src = cycle_file(tmp_path / "cycle.npz")
    args = ["denoise", str(src), "-o", str(tmp_path / "out.npz"), "--feet", "off", *flag]
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 0, res.output
    assert res.output.count("looks like a loop") == int(note)
    said = json.loads(CliRunner().invoke(cli, [*args, "--json"]).stdout)
    assert said["files"][0]["result"]["loop"] is loop
