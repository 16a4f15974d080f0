"""benchmarks/video_table.py: the foot-skate measure on known motion, and a run on the bundled
example (filters tuned on a tiny grid, shipped weights, 2 refinement steps)."""

import math
from pathlib import Path

import numpy as np

from benchmarks import video_table as vt
from benchmarks.common import cut_clips
from mdvae_cli.body.builtin import builtin_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.model.denoiser import load_denoiser

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def test_foot_skate_counts_speed_only_where_the_truth_stands():
    T, fps = 31, 30.0
    gt = np.zeros((T, 22, 3))
    gt[:, :, 2] = 0.5
    gt[:, list(vt.FEET), 2] = 0.02  # feet on the floor, still
    gt[15:, 7, 2] = 0.3  # left ankle lifted from frame 15: no contact there
    pred = gt.copy()
    pred[:, list(vt.FEET), 0] += np.arange(T)[:, None] * (0.5 / fps)  # all feet slide at 0.5 m/s
    total, n = vt.foot_skate(gt, pred, fps)
    assert n == 4 * (T - 1) - (T - 15)  # the lifted ankle's pairs from frame 14 on don't count
    assert math.isclose(total / n, 0.5, rel_tol=1e-9)
    assert vt.foot_skate(gt, gt, fps)[0] == 0.0


def test_video_table_runs_and_renders(monkeypatch):
    clips = cut_clips(load_motion(EXAMPLES / "walk.npz"), 36, "walk.npz")[:2]
    monkeypatch.setattr(vt, "GAUSSIAN_GRID", (2.0,))
    monkeypatch.setattr(vt, "SAVGOL_GRID", ((11, 2),))
    monkeypatch.setattr(vt, "ONE_EURO_GRID", ((1.0, 0.3),))
    den, _ = load_denoiser(None)
    body = BodyModel(builtin_body_model())
    result, speed, best = vt.build(clips[:1], clips[1:], den, body, steps=2, seed=0,
                                   log=lambda _: None)  # fmt: skip
    assert set(best) == {"gaussian", "savgol", "one_euro"}
    assert "Noisy input" in result and "`mdvae denoise` (video settings)" in result
    assert all(math.isfinite(v) for r in result.values() for v in r.values())
    noisy = result["Noisy input"]
    assert result["`mdvae denoise` (video settings)"]["accel_error"] < noisy["accel_error"]
    md = vt.markdown(result, speed, best, "header")
    assert md.startswith(vt.SECTION_BEGIN) and md.rstrip().endswith(vt.SECTION_END)
    assert "| One-Euro filter (min cutoff 1.0 Hz, β 0.3) |" in md
