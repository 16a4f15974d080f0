"""Smoke test of benchmarks/outliers.py on the bundled example (shipped weights, 2 steps)."""

import math
from pathlib import Path

from benchmarks.common import Clip, cut_clips
from benchmarks.outliers import SECTION_BEGIN, SECTION_END, Scenario, markdown, run
from mdvae_cli.body.builtin import builtin_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.model.denoiser import load_denoiser

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def test_outlier_benchmark_runs_and_renders(tmp_path):
    clips: list[Clip] = cut_clips(load_motion(EXAMPLES / "walk.npz"), 60, "walk.npz")[:1]
    den, _ = load_denoiser(None)
    body = BodyModel(builtin_body_model())
    result = run(clips, den, body, scenarios=(Scenario(0.05, 0.05, 0.5),), steps=2)
    (row,) = result.values()
    assert {"Observations", "Ground truth", "`mdvae denoise`", "`--refine 2 --outliers`"} <= set(
        row
    )
    assert all(math.isfinite(v) and math.isfinite(a) for v, a in row.values())
    assert row["`mdvae denoise`"][0] < row["Observations"][0]  # it does clean the clip
    md = markdown(result, "header")
    assert md.startswith(SECTION_BEGIN) and md.rstrip().endswith(SECTION_END)
    assert "| `--refine 2 --outliers` |" in md and "0.5-rad spikes on 5% + σ = 0.05" in md
