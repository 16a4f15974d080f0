"""Smoke test of benchmarks/denoise_table.py on tiny synthetic clips (no real corpus needed)."""

import json
import math

import numpy as np
import pytest
import torch

from benchmarks.common import (
    add_noise,
    cut_clips,
    evaluate_clips,
    file_to_file,
    machine_description,
    pick_evenly,
    write_section,
)
from benchmarks.denoise_methods import build_table
from benchmarks.denoise_report import report_markdown, table_columns, table_rows
from benchmarks.denoise_rows import (
    ROW_OFFSET,
    ROW_OFFSET_FEET,
    ROWS,
    SECTION_BEGIN,
    SECTION_END,
    TableSettings,
)
from benchmarks.denoise_table import main
from mdvae_cli.body.builtin import builtin_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.formats.npz_io import motion_from_arrays
from mdvae_cli.metrics import evaluate_pair, mean_result
from mdvae_cli.model.denoiser import Denoiser, DenoiserConfig, save_denoiser
from mdvae_cli.model.prior_model import load_prior
from mdvae_cli.train.train_prior import train_prior
from tests.conftest import motion_arrays
from tests.test_prior import tiny_config, write_corpus


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    """Tiny networks run fastest on one thread (and the benchmark's 2 threads would fight
    over a busy CI machine); the previous setting is restored afterwards."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


@pytest.fixture(scope="module")
def tiny_denoiser(tmp_path_factory):
    root = tmp_path_factory.mktemp("bench")
    data = write_corpus(root / "clean", n=2, T=40)
    train_prior(tiny_config(data, epochs=1), root / "run", max_steps=2)
    prior, _ = load_prior(root / "run")
    return Denoiser(prior, DenoiserConfig(hidden_dim=16))


@pytest.fixture(scope="module")
def body():
    return BodyModel(builtin_body_model())


def synthetic_motion(T: int, seed: int):
    arrays = motion_arrays(T=T, width=156, fps=30.0, seed=seed)
    arrays["poses"][:, 0] = np.pi / 2  # upright in z-up
    arrays["dmpls"] = np.ones((T, 8))  # a per-frame extra array
    return motion_from_arrays(arrays)


def test_clips_are_cut_without_overlap_and_picked_evenly():
    clips = cut_clips(synthetic_motion(100, 0), 30, "s01/walk.npz")
    assert [c.name for c in clips] == ["s01/walk.npz#0", "s01/walk.npz#30", "s01/walk.npz#60"]
    assert all(c.motion.num_frames == 30 for c in clips)
    assert clips[1].motion.extras["dmpls"].shape == (30, 8)
    np.testing.assert_array_equal(clips[2].motion.trans, synthetic_motion(100, 0).trans[60:90])
    assert pick_evenly(list(range(10)), 3) == [0, 4, 9] and pick_evenly([1, 2], None) == [1, 2]
    # the noise of a clip depends on its name and sigma only, not on the other clips
    a = add_noise(clips, 0.1, seed=0)
    b = add_noise(clips[1:], 0.1, seed=0)
    np.testing.assert_array_equal(a[1].pose_body, b[0].pose_body)
    assert not np.allclose(a[1].pose_body, add_noise(clips[1:2], 0.2, seed=0)[0].pose_body)


def test_evaluate_clips_matches_evaluate_pair(body):
    clips = cut_clips(synthetic_motion(40, 1), 20, "a.npz")
    gt = [c.motion for c in clips]
    noisy = add_noise(clips, 0.15, seed=3)
    got = evaluate_clips(gt, {"obs": noisy}, body)["obs"]
    want = mean_result([evaluate_pair(g, n, body) for g, n in zip(gt, noisy, strict=True)])
    for name in ("v2v_cm", "v2v_abs_cm", "mpjpe_cm", "accel_gt", "accel_pred", "accel_error"):
        assert getattr(got, name) == pytest.approx(getattr(want, name), rel=1e-9), name


def test_table_builder_on_two_tiny_clips(tiny_denoiser, body, tmp_path):
    test = cut_clips(synthetic_motion(60, 2), 30, "test.npz")
    val = cut_clips(synthetic_motion(60, 3), 30, "val.npz")
    settings = TableSettings(
        gaussian_grid=(1.0, 2.0),
        savgol_grid=((5, 2), (7, 1)),
        optimize_steps=2,
        curve_steps=(0, 1, 2),
        window=20,
        stride=15,
        refine_steps=2,
        single_clip_repeats=1,
    )
    before = {k: v.clone() for k, v in tiny_denoiser.state_dict().items()}
    result = build_table(test, val, tiny_denoiser, body, settings, tmp_path / "work")
    # optimisation mode worked on copies: the denoiser given is unchanged
    for k, v in tiny_denoiser.state_dict().items():
        assert (v == before[k]).all(), k
    assert not any((tmp_path / "work").iterdir())  # scratch files cleaned up

    header, rows = table_columns(settings), table_rows(result)
    assert [r[0] for r in rows] == list(ROWS)
    assert len(header) == 17 and all(len(r) == len(header) for r in rows)
    feet = ["Foot skate σ=0.15 (cm/s)", "Penetration σ=0.15 (cm)", "Float σ=0.15 (cm)"]
    assert header[11:14] == feet
    penetration = [float(r[header.index(feet[1])]) for r in rows]  # on every row, >= 0
    assert all(p >= 0 for p in penetration)
    for sigma in ("0.10", "0.15", "0.20"):
        assert f"V2V σ={sigma} (cm) ↓" in header and f"Accel σ={sigma} (m/s²)" in header
    assert "s/frame ↓" in header and "frames/s ↑" in header and "1 clip, warm (ms)" in header

    def cell(row: str, column: str) -> str:
        return rows[list(ROWS).index(row)][header.index(column)]

    for r in rows[1:]:  # every method has V2V and accelerations at every sigma
        for c in header[5:11]:
            assert math.isfinite(float(r[header.index(c)])), (r[0], c)
    for c in header[8:11]:  # ground truth shows its acceleration only
        assert math.isfinite(float(cell("Ground truth", c)))
    assert cell("Ground truth", header[5]) == "-"
    for row in (
        "Gaussian filter",
        "Savitzky-Golay filter",
        "Regression mode",
        "Regression + mirror",
        ROW_OFFSET,
        ROW_OFFSET_FEET,
    ):
        assert float(cell(row, "s/frame ↓")) > 0 and float(cell(row, "1 clip, warm (ms)")) > 0
    for row in (
        "Optimization mode",
        "Optimization + offset",
        "Latent refinement",
        "Latent refinement + mirror",
    ):
        assert float(cell(row, "frames/s ↑").replace(",", "")) > 0
    assert cell("Observations", "V2V / V2V(obs) σ=0.15") == "1.000"
    # the noise leaves the root clean: the observations' absolute V2V is their root-relative
    absolute = "absolute V2V σ=0.15 (cm)"
    assert cell("Observations", absolute) == cell("Observations", "V2V σ=0.15 (cm) ↓")
    assert cell("Ground truth", absolute) == "-"
    for r in rows[1:]:
        assert math.isfinite(float(r[header.index(absolute)])), r[0]
    best = [cell(r, header[-1]) for r in ("Gaussian filter", "Savitzky-Golay filter")]
    assert "best filter" in best
    # the gain over the best filter is given at every sigma, and matches the V2V columns
    gains = [float(g.strip(" %")) for g in cell("Latent refinement", header[-1]).split(" / ")]
    best_row = "Gaussian filter" if best[0] == "best filter" else "Savitzky-Golay filter"
    for g, c in zip(gains, header[5:8], strict=True):
        ours, theirs = float(cell("Latent refinement", c)), float(cell(best_row, c))
        rounding = 0.05 + 0.5 / theirs * (1 + ours / theirs)  # cells hold 2 decimals
        assert abs(g - 100 * (1 - ours / theirs)) < rounding, (g, ours, theirs)
    # the tuned parameters are reported and come from the grid
    assert result.tuning.gaussian_sigma in (1.0, 2.0)
    assert cell("Gaussian filter", "Parameters") == f"σ = {result.tuning.gaussian_sigma:g} frames"
    assert [p.steps for p in result.curve] == [0, 1, 2, *[None] * 7]
    assert result.curve[-1].label == "Latent refinement + mirror"
    assert all(p.s_per_frame > 0 and math.isfinite(p.v2v_cm) for p in result.curve)

    md = report_markdown(result, machine_description(), {"corpus": "synthetic"}, "plot.png")
    assert md.startswith(SECTION_BEGIN) and md.rstrip().endswith(SECTION_END)
    assert "| Optimization mode |" in md and "](plot.png)" in md and "torch" in md
    doc = tmp_path / "benchmarks.md"
    doc.write_text("# Benchmarks\n\nOther numbers.\n")
    write_section(doc, md, SECTION_BEGIN, SECTION_END)
    write_section(doc, md, SECTION_BEGIN, SECTION_END)  # replaced, not appended twice
    text = doc.read_text()
    assert text.count(SECTION_BEGIN) == 1 and "Other numbers." in text


def test_file_to_file_times_load_process_and_save(tmp_path):
    from benchmarks.common import write_motions

    files = write_motions([synthetic_motion(30, 4), synthetic_motion(30, 5)], tmp_path / "in")
    outs, timing = file_to_file(files, tmp_path / "out", lambda ms: ms)
    assert len(outs) == 2 and timing.frames == 60 and timing.seconds > 0
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [f.name for f in files]


@pytest.mark.slow  # ~23 s on 2 cores
def test_script_main_end_to_end(tiny_denoiser, tmp_path):
    """Both splits' tables (test tuned on val, unseen_test on its own clips) and the short-take
    rows go into their own sections of --out and into --json."""
    corpus = tmp_path / "corpus"
    split = {"train": [], "val": [], "test": [], "unseen_test": []}
    for i, part in enumerate(["test", "val", "unseen_test"]):
        arrays = motion_arrays(T=64, width=156, fps=30.0, seed=20 + i)
        arrays["poses"][:, 0] = np.pi / 2
        (corpus / f"s{i}").mkdir(parents=True)
        np.savez(corpus / f"s{i}" / "take.npz", **arrays)
        split[part].append(f"s{i}/take.npz")
    (corpus / "split.json").write_text(json.dumps({"splits": split}))
    save_denoiser(tmp_path / "den" / "denoiser.npz", tiny_denoiser, {})
    out = tmp_path / "docs" / "benchmarks.md"
    args = ["--corpus", str(corpus), "--denoiser", str(tmp_path / "den"), "--out", str(out)]
    args += ["--quick", "--clip-frames", "30", "--max-clips", "2", "--tune-clips", "2"]
    args += ["--optimize-steps", "1", "--curve-steps", "0,1", "--threads", "1"]
    args += ["--short-lengths", "6,16", "--short-clips", "2"]
    args += ["--json", str(tmp_path / "raw.json")]
    assert main(args) == 0
    text = out.read_text()
    assert "| Regression mode |" in text and "quick subset" in text
    assert text.count("denoise_table:begin") == 2 and "split=unseen_test" in text
    assert "Filters tuned on 2 the same clips" in text and "## Short takes" in text
    raw = json.loads((tmp_path / "raw.json").read_text())
    test, unseen = raw["tables"]
    assert (test["split"], test["tuned_on"]) == ("test", "val")
    assert (unseen["split"], unseen["tuned_on"]) == ("unseen_test", "the same")
    assert test["num_clips"] == 2 and test["clip_frames"] == 30
    assert [p["steps"] for p in unseen["curve"] if p["steps"] is not None] == [0, 1]
    short = raw["short_takes"]
    assert [(r["length"], r["sigma"]) for r in short] == [
        (n, s) for n in (6, 16) for s in (0.1, 0.15, 0.2)
    ]
    assert all(0 <= r["worse_than_noisy"] <= r["clips"] for r in short)
    assert main(["--corpus", str(tmp_path / "nothing")]) == 2  # a clear error, no traceback


def test_do_no_harm_counts_joint_frames_turned_from_the_truth():
    """The clean-and-spiky table's count: a joint turned by 30 degrees on one frame, and by
    10 on another, is one joint-frame past 20 degrees; the sign of a quaternion is no turn."""
    from benchmarks.do_no_harm import MOVED_DEG, turned_degrees
    from mdvae_cli.motion.motion import Motion

    T = 5
    a = Motion(root_orient=np.zeros((T, 3)), pose_body=np.zeros((T, 21, 3)), trans=np.zeros((T, 3)),
               betas=np.zeros(10), fps=30.0)  # fmt: skip
    b = a.with_body(pose_body=a.pose_body.copy())
    b.pose_body[1, 4, 0] = np.radians(30.0)
    b.pose_body[3, 7, 2] = np.radians(10.0)
    turned = turned_degrees(a, b)
    assert turned.shape == (T, 22)
    assert np.isclose(turned[1, 5], 30.0) and np.isclose(turned[3, 8], 10.0)
    assert int((turned > MOVED_DEG).sum()) == 1
    c = a.with_body(root_orient=np.tile([2 * np.pi, 0.0, 0.0], (T, 1)))  # a full turn: none
    assert turned_degrees(a, c).max() < 1e-6


def test_train_speed_times_each_width_and_its_regression_pass(capsys):
    """``benchmarks/train_speed.py --hidden``: a row per width, each with its training step,
    its arithmetic (more for the wider one) and a regression-mode pass; one row's JSON has
    ``s_per_step`` at its top level."""
    from benchmarks.train_speed import main as train_speed

    out = train_speed(["--device", "cpu", "--batch", "2", "--steps", "1", "--hidden", "8,16",
                       "--json"])  # fmt: skip
    rows = out["rows"]
    assert [r["hidden"] for r in rows] == [8, 16]
    assert all(r["s_per_step"] > 0 and r["regression_pass_s"] > 0 for r in rows)
    assert rows[1]["gflop_per_step"] > rows[0]["gflop_per_step"]
    assert json.loads(capsys.readouterr().out)["rows"][0]["hidden"] == 8
    one = train_speed(["--device", "cpu", "--batch", "2", "--steps", "1", "--json"])
    assert one["s_per_step"] == one["rows"][0]["s_per_step"]
    assert one["rows"][0]["regression_pass_s"] is None
