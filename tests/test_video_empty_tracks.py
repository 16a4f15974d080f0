"""What a detector or tracker leaves in a video pipeline's file: an empty track (no frames) in
a file of several people, skipped with a note and written back as it came, the other tracks
cleaned (``video_layout.tracks_with_frames``); NaN everywhere (nothing to fill a hole from),
refused in one line that says which; a frame id listed twice, refused."""

from __future__ import annotations

import numpy as np
import video_files as vf
from click.testing import CliRunner

from mdvae_cli.cli.main import cli
from mdvae_cli.formats.data_files import load_data
from mdvae_cli.formats.data_write import write_data


def run(*args):
    result = CliRunner().invoke(cli, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


def _with_empty_track(src, tid):
    data = load_data(src)
    first = next(iter(data.values()))
    data[np.int64(tid)] = {k: np.asarray(v)[:0] for k, v in first.items()}
    write_data(data, src, "joblib")
    return data


def test_wham_empty_track_is_skipped_and_written_back_as_it_came(tmp_path):
    """Before: `error: ... track 9: 'pose' has no frames`, exit 1, the whole file lost."""
    src = vf.write_wham(tmp_path / "wham_output.pkl", {0: (vf.clip(30, seed=1), None)})
    data = _with_empty_track(src, 9)
    code, _, err = run("denoise", src, "-o", tmp_path / "clean.pkl")
    assert code == 0, err
    assert "track(s) 9 hold no frames: skipped (written back as they came)" in err
    new = load_data(tmp_path / "clean.pkl")
    assert [int(k) for k in new] == [0, 9]
    for k, v in data[np.int64(9)].items():
        assert new[np.int64(9)][k].shape == v.shape and new[np.int64(9)][k].dtype == v.dtype
    assert not np.array_equal(new[np.int64(0)]["pose_world"], data[np.int64(0)]["pose_world"])


def test_vibe_file_of_empty_tracks_only_is_one_error_line(tmp_path):
    src = vf.write_vibe(tmp_path / "vibe_output.pkl", vf.clip(20, seed=2))
    data = load_data(src)
    data = {k: {kk: np.asarray(vv)[:0] for kk, vv in v.items()} for k, v in data.items()}
    write_data(data, src, "joblib")
    code, _, err = run("denoise", src, "-o", tmp_path / "clean.pkl")
    assert code == 1
    assert "every track is empty (no frames in 'pose')" in err and "Traceback" not in err


def test_nothing_to_fill_from_is_refused_naming_it(tmp_path):
    """NaN rows are holes, filled (``test_video_holes``); a pose with no finite value, a
    translation with none, or a joint never observed leaves nothing to fill them from: one
    line that says which."""
    src = vf.write_wham(tmp_path / "wham_output.pkl", {0: (vf.clip(30, seed=1), None)})
    data = load_data(src)
    good = data[np.int64(0)]["pose_world"].copy()
    data[np.int64(0)]["pose_world"][:] = np.nan
    write_data(data, src, "joblib")
    code, _, err = run("denoise", src, "-o", tmp_path / "clean.pkl")
    assert code == 1 and len(err.strip().splitlines()) == 1
    assert "'pose_world' holds NaN or infinite values in 30 of 30 frame(s)" in err
    assert "nothing observed to fill them from" in err
    data[np.int64(0)]["pose_world"] = good
    data[np.int64(0)]["pose_world"][:, 15:18] = np.nan  # joint 5 in every frame
    write_data(data, src, "joblib")
    code, _, err = run("denoise", src, "-o", tmp_path / "clean.pkl")
    assert code == 1 and len(err.strip().splitlines()) == 1
    assert "joint 5 (right_knee) in all 30 frames; a joint never observed cannot be filled" in err
    src = vf.write_hybrik(tmp_path / "res.pk", vf.clip(12, seed=2))
    res = load_data(src)
    res["transl"][:] = np.inf
    write_data(res, src, "pickle")
    code, _, err = run("denoise", src, "-o", tmp_path / "clean.pk")
    assert code == 1 and len(err.strip().splitlines()) == 1
    assert "'translation' contains NaN or infinite values in every frame" in err


def test_a_frame_id_listed_twice_is_refused_naming_the_rows(tmp_path):
    """Before: the first row was read, and written back both rows got that frame's cleaned
    joints over the second row's own (a mixed pose), or with a gap the second row was
    dropped, without a note."""
    ids = np.r_[0:10, 9, 11:30]
    src = vf.write_wham(tmp_path / "wham_output.pkl", {0: (vf.clip(30, seed=1), ids)})
    code, _, err = run("denoise", src, "-o", tmp_path / "clean.pkl")
    assert code == 1 and len(err.strip().splitlines()) == 1
    assert "frame id 9 is listed twice (rows 9 and 10); a track lists each frame once" in err


def test_a_track_that_holds_nothing_is_an_empty_track_even_first(tmp_path):
    """A WHAM ``defaultdict(dict)`` can hold a track id with an empty dict; first in the file
    it made the file's layout unknown (before: "not a motion layout this tool knows")."""
    src = vf.write_wham(tmp_path / "wham_output.pkl", {0: (vf.clip(30, seed=1), None)})
    data = load_data(src)
    write_data({np.int64(12): {}, **data}, src, "joblib")
    code, _, err = run("denoise", src, "-o", tmp_path / "clean.pkl")
    assert code == 0, err
    assert "track(s) 12 hold no frames" in err
    new = load_data(tmp_path / "clean.pkl")
    assert new[np.int64(12)] == {} and set(new) == {np.int64(0), np.int64(12)}
