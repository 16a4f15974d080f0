"""The side files video pipelines write beside their results: skipped in a folder run with a
note (``fileio.pipeline_side_file``), TRAM's ``camera.npy`` copied beside a cleaned track
written back in TRAM's layout (``formats.video_side``), and a pickle of a bare array said to
be no motion layout (it was "damaged: The truth value of an array ... is ambiguous")."""

from __future__ import annotations

import pickle

import numpy as np
import video_files as vf
from click.testing import CliRunner

from mdvae_cli.cli.main import cli
from mdvae_cli.formats.registry import read


def run(*args):
    result = CliRunner().invoke(cli, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


def test_tram_results_folder_is_cleaned_with_its_camera(tmp_path):
    """Before: camera.npy (and boxes.npy) failed the run (exit 1), and the cleaned track,
    read back without camera.npy, came out in the camera frame: 4.5 m from the input's world
    on a real WHAM take put in TRAM's layout."""
    m = vf.clip(30, seed=2)
    src = vf.write_tram(tmp_path / "results" / "vid", m)
    np.save(tmp_path / "results" / "vid" / "boxes.npy", np.zeros((30, 4)))
    code, _, err = run("denoise", tmp_path / "results", "-o", tmp_path / "clean")
    assert code == 0, err
    assert "vid/camera.npy: TRAM's camera.npy beside hps, not a motion; skipped" in err
    assert "vid/boxes.npy: TRAM's boxes.npy beside hps, not a motion; skipped" in err
    assert "camera.npy copied to" in err
    copy = tmp_path / "clean" / "vid" / "camera.npy"
    assert copy.read_bytes() == (src.parent.parent / "camera.npy").read_bytes()
    assert not (tmp_path / "clean" / "vid" / "boxes.npy").exists()
    before = read(src).single()
    after = read(tmp_path / "clean" / "vid" / "hps" / "hps_track_0.npy").single()
    assert np.abs(after.trans - before.trans).max() < 0.05  # the same world, cleaned
    code, _, err = run("denoise", src, "-o", tmp_path / "one.npy")  # not TRAM's layout
    assert code == 0 and "looks for it at" in err and not (tmp_path / "camera.npy").exists()


def test_wham_side_files_are_skipped_in_a_folder(tmp_path):
    folder = tmp_path / "demo"
    folder.mkdir()
    vf.write_wham(folder / "wham_output.pkl", {0: (vf.clip(20, seed=1), None)})
    (folder / "slam_results.pth").write_bytes(vf.joblib_dumps(np.zeros((20, 7), np.float32)))
    (folder / "tracking_results.pth").write_bytes(
        vf.joblib_dumps({0: {"frame_id": np.arange(20), "bbox": np.zeros((20, 3))}})
    )
    code, _, err = run("denoise", folder, "-o", tmp_path / "clean")
    assert code == 0, err
    assert "slam_results.pth: WHAM's slam_results.pth beside wham_output.pkl" in err
    assert sorted(p.name for p in (tmp_path / "clean").iterdir()) == ["wham_output.pkl"]
    code, _, err = run("denoise", folder / "slam_results.pth", "-o", tmp_path / "x.npz")
    assert code == 1 and "not a motion layout this tool knows" in err  # named: refused


def test_a_pickle_of_a_bare_array_is_no_motion_layout(tmp_path):
    src = tmp_path / "poses.pkl"
    src.write_bytes(pickle.dumps(np.zeros((40, 72))))
    code, _, err = run("denoise", src, "-o", tmp_path / "x.npz")
    assert code == 1 and "damaged" not in err and "ambiguous" not in err
    assert "not a motion layout this tool knows" in err
