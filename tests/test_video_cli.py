"""The commands on video-pipeline files: denoise (video settings, one output per track), import,
add-noise --preset video, eval; bad and malicious files in one line."""

from __future__ import annotations

import json
import os
import pickle

import numpy as np
import pytest
import video_files as vf
from click.testing import CliRunner

from mdvae_cli.cli.main import cli
from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.formats.registry import read
from mdvae_cli.infer.input_kinds import INPUT_KINDS, refine_config


def run(*args):
    result = CliRunner().invoke(cli, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


def one_error(err: str) -> str:
    lines = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_denoise_a_wham_file_uses_the_video_settings(tmp_path):
    m = vf.clip(40, seed=1)
    src = vf.write_wham(tmp_path / "wham_output.pkl", {0: (m, None)})
    code, out, err = run("denoise", src, "-o", tmp_path / "clean.npz", "--json")
    assert code == 0, err
    doc = json.loads(out)
    result = doc["files"][0]["result"]
    assert result["format"] == "wham" and result["input_kind"] == "video"
    assert doc["settings"]["video"]["lam"] == INPUT_KINDS["video"].lam
    clean = load_motion(tmp_path / "clean.npz")
    assert clean.num_frames == 40 and clean.fps == 30.0
    assert set(clean.extras) >= {"frame_ids", "cam_root_orient", "source_format"}
    # options override the row
    code, out, _ = run("denoise", src, "-o", tmp_path / "c2.npz", "--json", "--lam", "0",
                       "--refine-offset", "0.05")  # fmt: skip
    assert code == 0
    chosen = json.loads(out)["settings"]["video"]
    assert chosen["lam"] == 0.0 and chosen["offset_std"] == 0.05


def test_denoise_writes_one_file_per_track_or_the_chosen_one(tmp_path):
    a, b = vf.clip(30, seed=2), vf.clip(3, seed=3)  # track 4 too short to denoise
    c = vf.clip(25, seed=4)
    src = vf.write_wham(tmp_path / "w.pkl", {1: (a, None), 4: (b, None), 9: (c, None)})
    code, out, err = run("denoise", src, "-o", tmp_path / "out.npz", "--json")
    assert code == 0, err
    tracks = json.loads(out)["files"][0]["result"]["tracks"]
    assert [t["track"] for t in tracks] == ["1", "9"]
    assert (tmp_path / "out.track1.npz").is_file() and (tmp_path / "out.track9.npz").is_file()
    assert not (tmp_path / "out.npz").exists() and not (tmp_path / "out.track4.npz").exists()
    assert "track 4" in err and "skipped" in err
    code, _, err = run("denoise", src, "-o", tmp_path / "nine.npz", "--track", "9")
    assert code == 0, err
    assert load_motion(tmp_path / "nine.npz").num_frames == 25


def test_a_folder_of_pipeline_outputs_is_mirrored(tmp_path):
    folder = tmp_path / "in"
    (folder / "b").mkdir(parents=True)
    vf.write_hybrik(folder / "res.pk", vf.clip(20, seed=5))
    vf.write_gvhmr(folder / "b" / "hmr4d_results.pt", vf.clip(20, seed=6))
    (folder / "notes.txt").write_text("not motion")
    code, _, err = run("add-noise", folder, "-o", tmp_path / "noisy", "--preset", "video")
    assert code == 0, err
    # each in its own form: HybrIK's pickle, GVHMR's torch file
    assert read(tmp_path / "noisy" / "res.pk").format == "hybrik"
    assert read(tmp_path / "noisy" / "b" / "hmr4d_results.pt").format == "gvhmr"
    assert not list((tmp_path / "noisy").rglob("*.npz"))


def test_import_of_a_folder_finds_the_npz_outputs_of_pipelines(tmp_path):
    """SLAHMR and ROMP write .npz: a folder holding them is imported like one of pickles."""
    folder = tmp_path / "in"
    (folder / "seq").mkdir(parents=True)
    vf.write_slahmr(folder / "seq" / "seq_000300_world_results.npz", [vf.clip(20, seed=8)])
    vf.write_hybrik(folder / "res.pk", vf.clip(20, seed=5))
    code, out, err = run("import", folder, "-o", tmp_path / "out", "--json", "--fps", "30")
    assert code == 0, err
    doc = json.loads(out)
    assert doc["by_format"]["slahmr"]["files"] == 1 and doc["by_format"]["hybrik"]["files"] == 1
    assert load_motion(tmp_path / "out" / "seq" / "seq_000300_world_results.npz").num_frames == 20
    assert load_motion(tmp_path / "out" / "res.npz").num_frames == 20


def test_malicious_pickle_is_refused_by_every_command(tmp_path):
    marker = tmp_path / "ran"

    class Evil:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    src = tmp_path / "wham_output.pkl"
    src.write_bytes(pickle.dumps({0: {"pose": Evil()}}))
    for args in (("denoise", src, "-o", tmp_path / "o.npz"),
                 ("add-noise", src, "-o", tmp_path / "o.npz"),
                 ("import", src, "-o", tmp_path / "o.npz")):  # fmt: skip
        code, _, err = run(*args)
        assert code == 1
        assert "refusing to load 'posix.system'" in one_error(err)
    assert not marker.exists() and not (tmp_path / "o.npz").exists()


def test_add_noise_video_preset_and_its_errors(tmp_path, make_motion_file):
    src = make_motion_file("clean.npz", T=60)
    code, _, err = run("add-noise", src, "-o", tmp_path / "v.npz", "--preset", "video",
                       "--set", "swap_rate=0", "--set", "pose_slow=0.2")  # fmt: skip
    assert code == 0, err
    noisy, clean = load_motion(tmp_path / "v.npz"), load_motion(src)
    assert noisy.num_frames == 60 and not np.allclose(noisy.pose_body, clean.pose_body)
    assert not np.allclose(noisy.trans, clean.trans)  # depth jitter
    for args, message in (
        (("--set", "pose_slow=0.1"), "give --preset too"),
        (("--preset", "video", "--sigma", "0.1"), "change its parameters with --set"),
        (("--preset", "video", "--set", "wobble=1"), "unknown video noise parameter"),
        (("--preset", "video", "--set", "pose_slow"), "NAME=NUMBER"),
        (("--preset", "video", "--set", "swap_frames=1.5"), "whole number"),
    ):
        code, _, err = run("add-noise", src, "-o", tmp_path / "x.npz", *args)
        assert code == 1 and message in one_error(err), (args, err)


def test_import_a_pipeline_file_with_floor_puts_it_on_the_floor(tmp_path):
    src = vf.write_wham(tmp_path / "wham_output.pkl", {0: (vf.clip(30, seed=7), None)})
    code, out, err = run("import", src, "-o", tmp_path / "take.npz", "--json", "--fps", "30",
                         "--floor", "plane")  # fmt: skip
    assert code == 0, err
    doc = json.loads(out)
    assert doc["by_format"]["wham"]["files"] == 1
    take = load_motion(tmp_path / "take.npz")
    from mdvae_cli.export import pose_motion_chunks

    low = min(float(o.vertices[..., 2].min()) for _, o in pose_motion_chunks(take, vf.BODY))
    assert abs(low) < 0.03  # the lowest foot point of the take at z = 0


def lowest_point(motion) -> float:
    from mdvae_cli.export import pose_motion_chunks

    return min(float(o.vertices[..., 2].min()) for _, o in pose_motion_chunks(motion, vf.BODY))


def test_a_gvhmr_file_keeps_its_heights_and_frames_by_every_path(tmp_path):
    """``import`` then ``denoise``, or ``denoise`` of the file itself: the same heights and
    frames, those the pipeline wrote (a body floating 25 cm up stays there); ``--floor`` on
    either puts it on the floor."""
    m = vf.clip(40, seed=5, fps=25.0)
    m.trans[:, 2] += 0.25
    src = vf.write_gvhmr(tmp_path / "hmr4d_results.pt", m)
    code, _, err = run("import", src, "-o", tmp_path / "take.npz", "--source-fps", "25")
    assert code == 0, err
    imported = load_motion(tmp_path / "take.npz")
    assert imported.num_frames == 40 and imported.fps == 25.0  # the file's own frames
    np.testing.assert_allclose(imported.trans, m.trans, atol=1e-4)  # the file's own heights
    paths = {"import": tmp_path / "take.npz", "direct": src}
    for name, path in paths.items():
        code, out, err = run("denoise", path, "-o", tmp_path / f"{name}.npz", "--fps", "25",
                             "--json")  # fmt: skip
        assert code == 0, err
        assert json.loads(out)["files"][0]["result"]["input_kind"] == "video"
    a, b = load_motion(tmp_path / "import.npz"), load_motion(tmp_path / "direct.npz")
    assert a.num_frames == b.num_frames == 40 and a.fps == b.fps == 25.0
    np.testing.assert_allclose(a.trans, b.trans, atol=1e-3)  # within 1 mm
    assert abs(a.trans[:, 2].mean() - m.trans[:, 2].mean()) < 0.02
    assert lowest_point(b) > 0.15  # floating as the file has it
    for name, path in paths.items():
        code, _, err = run("denoise", path, "-o", tmp_path / f"{name}_floor.npz", "--fps", "25",
                           "--floor")  # fmt: skip
        assert code == 0, err
    a, b = load_motion(tmp_path / "import_floor.npz"), load_motion(tmp_path / "direct_floor.npz")
    np.testing.assert_allclose(a.trans, b.trans, atol=1e-3)
    assert abs(lowest_point(b)) < 0.05


def test_eval_reads_a_pipeline_file_as_ground_truth(tmp_path):
    m = vf.clip(30, seed=8)
    src = vf.write_wham(tmp_path / "w.pkl", {0: (m, None)})
    code, _, err = run("denoise", src, "-o", tmp_path / "d.npz")
    assert code == 0, err
    code, out, err = run("eval", "--gt", src, "--pred", tmp_path / "d.npz", "--json")
    assert code == 0, err
    assert json.loads(out)["mean"]["mpjpe_cm"] > 0


def test_outliers_without_offset_or_refine_is_refused(tmp_path, make_motion_file):
    src = make_motion_file("a.npz")
    code, _, err = run("denoise", src, "-o", tmp_path / "o.npz", "--outliers", "--no-offset")
    assert code == 1 and "--outliers / --lam" in one_error(err)
    code, _, err = run("denoise", src, "-o", tmp_path / "o.npz", "--outliers", "--lam", "3")
    assert code == 1 and "--outliers is --lam 10" in one_error(err)


def test_refine_config_follows_the_kind_row_and_overrides():
    cfg, chosen = refine_config("video")
    row = INPUT_KINDS["video"]
    assert cfg.outlier_dof == row.lam and cfg.offset_std == row.offset_std
    assert cfg.offset_terms == row.offset_terms and chosen["input_kind"] == "video"
    cfg, _ = refine_config("mocap", lam=5.0, offset_std=0.1, steps=3)
    assert cfg.outlier_dof == 5.0 and cfg.offset_std == 0.1 and cfg.steps == 3
    assert refine_config("mocap", offset=False)[0] is None
    with pytest.raises(Exception, match="unknown input kind"):
        refine_config("film")
