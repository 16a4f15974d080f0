"""Reading a video pipeline's file for ``eval`` and ``view``: ``--track`` picks a person
(before: eval refused a file of several with "pick one with --track ID", an option it did
not have; view showed its first track only); a frame rate the file stores is read."""

from __future__ import annotations

import json

import numpy as np
import video_files as vf
from click.testing import CliRunner

from mdvae_cli.cli.main import cli
from mdvae_cli.formats.data_files import load_data
from mdvae_cli.formats.data_write import write_data
from mdvae_cli.formats.registry import read, write


def run(*args):
    result = CliRunner().invoke(cli, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


def test_eval_scores_the_named_track_of_files_of_several_people(tmp_path):
    a, b = vf.clip(30, seed=1), vf.clip(20, seed=2)
    src = vf.write_wham(tmp_path / "wham_output.pkl", {3: (a, None), 7: (b, None)})
    loaded = read(src)
    tracks = dict(loaded.tracks)
    moved = tracks["7"].with_body(trans=tracks["7"].trans + [0.0, 0.0, 0.1])
    write(type(loaded)(src, "wham", "video", [("7", moved)], document=loaded.document),
          tmp_path / "pred.pkl")  # fmt: skip
    write(moved, tmp_path / "pred7.npz")
    code, _, err = run("eval", "--gt", src, "--pred", tmp_path / "pred.pkl")
    assert code == 1 and "pick one with --track ID" in err
    for pred, track, frames, abs_cm in ((tmp_path / "pred.pkl", 3, 30, 0.0),
                                        (tmp_path / "pred.pkl", 7, 20, 10.0),
                                        (tmp_path / "pred7.npz", 7, 20, 10.0)):  # fmt: skip
        code, out, err = run("eval", "--gt", src, "--pred", pred, "--track", track, "--json")
        assert code == 0, err
        result = json.loads(out)["files"][0]["result"]
        assert result["num_frames"] == frames
        assert np.isclose(result["v2v_abs_cm"], abs_cm, atol=1e-3)
    code, _, err = run("eval", "--gt", src, "--pred", tmp_path / "pred.pkl", "--track", 5)
    assert code == 1 and "no track '5' (tracks: 3, 7)" in err


def test_view_shows_the_named_track(tmp_path):
    a, b = vf.clip(30, seed=1), vf.clip(20, seed=2)
    src = vf.write_wham(tmp_path / "wham_output.pkl", {3: (a, None), 7: (b, None)})
    code, out, err = run("view", src, "-o", tmp_path / "v.html", "--json", "--no-mesh")
    assert code == 0 and "showing track 3 (--track for 7)" in err
    assert [m["frames"] for m in json.loads(out)["motions"]] == [30]
    code, out, err = run("view", src, "-o", tmp_path / "v.html", "--json", "--track", 7)
    assert code == 0, err
    assert [m["frames"] for m in json.loads(out)["motions"]] == [20]


def test_a_frame_rate_the_file_stores_is_read(tmp_path):
    """A result saved with a frame rate (``fps`` in GVHMR's dict, in a WHAM track) is read
    at it (before: 30 fps assumed, with a note that the file has none); --fps overrides."""
    import torch

    src = vf.write_gvhmr(tmp_path / "hmr4d_results.pt", vf.clip(20, seed=1))
    pred = torch.load(src, weights_only=True)
    pred["fps"] = 25
    torch.save(pred, src)
    assert read(src).single().fps == 25.0
    code, _, err = run("denoise", src, "-o", tmp_path / "clean.npz")
    assert code == 0 and "the file's 'fps' gives 25 fps (--fps overrides it)" in err
    assert "no frame rate in the file" not in err
    assert float(np.load(tmp_path / "clean.npz")["mocap_framerate"]) == 25.0
    code, _, err = run("denoise", src, "-o", tmp_path / "clean.npz", "--fps", 50)
    assert code == 0 and float(np.load(tmp_path / "clean.npz")["mocap_framerate"]) == 50.0
    wham = vf.write_wham(tmp_path / "wham_output.pkl", {0: (vf.clip(20, seed=2), None)})
    data = load_data(wham)
    data[np.int64(0)]["frame_rate"] = np.float64(60)
    write_data(data, wham, "joblib")
    assert read(wham).single().fps == 60.0
