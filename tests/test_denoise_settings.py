"""DenoiseSettings: the command's choices and defaults in one place; denoise() applies them as
``mdvae denoise`` does."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mdvae_cli.cli.main import cli
from mdvae_cli.errors import InputError
from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.infer.denoise_settings import DenoiseSettings, denoise

REPO = Path(__file__).resolve().parents[1]
NOISY = REPO / "examples" / "noisy_walk.npz"


@pytest.mark.parametrize(
    "flags, settings",
    [
        ([], DenoiseSettings()),
        (["--feet", "off", "--no-blend"], DenoiseSettings(feet="off", blend=False)),
        (["--no-offset"], DenoiseSettings(offset=False)),
    ],
)
def test_the_python_api_gives_what_the_command_writes(tmp_path, flags, settings):
    out = tmp_path / "clean.npz"
    res = CliRunner().invoke(cli, ["denoise", str(NOISY), "-o", str(out), *flags])
    assert res.exit_code == 0, res.output
    written = load_motion(out)
    mine = denoise([load_motion(NOISY)], settings)[0]
    np.testing.assert_allclose(mine.pose_body, written.pose_body, atol=1e-6)
    np.testing.assert_allclose(mine.trans, written.trans, atol=1e-6)


def test_the_paper_mode_has_no_blend_or_guard():
    assert DenoiseSettings(offset=False).untouched
    assert not DenoiseSettings().untouched
    assert DenoiseSettings(offset=False, refine_steps=5).refine().steps == 5


@pytest.mark.parametrize(
    "bad", [{"feet": "glue"}, {"overlap": 60}, {"window": 10, "overlap": 12}, {"refine_steps": -1}]
)
def test_bad_settings_are_refused_in_words(bad):
    with pytest.raises(InputError):
        DenoiseSettings(**bad)
