"""Long takes: progress inside a take, and the fast paths giving what the plain ones give."""

from pathlib import Path

import pytest

from mdvae_cli.body.builtin import builtin_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.infer.denoise_settings import DenoiseSettings, denoise
from mdvae_cli.model.denoiser import load_denoiser

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.fixture(scope="module")
def shipped():
    denoiser, _ = load_denoiser(None)
    return denoiser, BodyModel(builtin_body_model())


@pytest.mark.parametrize(
    "settings, phases",
    [
        (DenoiseSettings(), ["windows denoised", "stitched", "blended", "feet locked"]),
        (DenoiseSettings(feet="off", blend=False), ["windows denoised", "stitched"]),
    ],
)
def test_progress_tells_each_phase_of_a_take(shipped, settings, phases):
    noisy = load_motion(EXAMPLES / "noisy_walk.npz")
    told = []
    denoise([noisy], settings, *shipped, progress=told.append)
    steps = [t for t in told if t["stage"] == "denoise"]
    assert [t["phase"] for t in steps] == phases
    assert [t["step"] for t in steps] == list(range(1, len(phases) + 1))
    assert {t["steps"] for t in steps} == {len(phases)}
