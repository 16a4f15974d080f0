"""A video track's skipped frames (gaps in its frame ids) written back as rows of the
pipeline's own file, filled by the cleaning (``formats.video_gap_rows.gap_rows`` and the layouts
that take them: WHAM, VIBE / PARE, ROMP, 4D-Humans / PHALP)."""

from __future__ import annotations

import numpy as np
import pytest
import video_files as vf
from click.testing import CliRunner
from video_files import edited, same_rotations

from mdvae_cli.cli.main import cli
from mdvae_cli.formats.data_files import load_data
from mdvae_cli.formats.data_write import write_data
from mdvae_cli.formats.npz_holes import keep_holes
from mdvae_cli.formats.registry import read, write
from mdvae_cli.geometry.rotations_np import rotmat_to_rotvec, rotvec_to_rotmat


def run(*args):
    result = CliRunner().invoke(cli, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


def test_wham_gaps_get_rows_filled_and_other_tracks_stay_as_they_came(tmp_path):
    """A WHAM track with 5 frames missing from its frame ids: written back with a row for
    each, in frame order, holding the cleaned fill (its camera-frame copy by the nearest
    row's camera, its betas the nearest row's); the rows the file had keep their values where
    the cleaning left them; left unfilled (NaN, --fill off), no rows are added."""
    a, b = vf.clip(30, seed=1), vf.clip(20, seed=2)
    ids = np.r_[0:10, 15:35]  # a gap of 5 frames
    src = vf.write_wham(tmp_path / "wham_output.pkl", {3: (a, ids), 7: (b, None)})
    data = load_data(src)  # a camera that pans: each row's camera-frame root turned about y
    d3 = data[np.int64(3)]
    pan = rotvec_to_rotmat(np.outer(0.05 * np.arange(30), [0.0, 1.0, 0.0]))
    d3["pose"][:, :3] = rotmat_to_rotvec(pan @ rotvec_to_rotmat(d3["pose"][:, :3].astype(float)))
    write_data(data, src, "joblib")
    loaded = read(src)
    cleaned = dict(loaded.tracks)
    assert cleaned["3"].num_frames == 35
    new3, _ = edited(cleaned["3"], every=2)
    notes = write(
        type(loaded)(src, "wham", "video", [("3", new3)], document=loaded.document),
        tmp_path / "clean.pkl",
    )
    assert any("5 frame(s) missing from the file's frame ids added as rows" in n for n in notes)
    assert any("track(s) 7 written as they came" in n for n in notes)
    old, new = load_data(src), load_data(tmp_path / "clean.pkl")
    o3, n3 = old[np.int64(3)], new[np.int64(3)]
    assert n3["pose_world"].shape == (35, 72) and n3["pose_world"].dtype == o3["pose_world"].dtype
    assert np.array_equal(n3["frame_ids"], np.arange(35))
    assert n3["frame_ids"].dtype == o3["frame_ids"].dtype
    assert np.array_equal(n3["betas"][10:15], o3["betas"][[9, 9, 9, 10, 10]])
    for k, v in old[np.int64(7)].items():
        assert np.array_equal(new[np.int64(7)][k], v)
    back = dict(read(tmp_path / "clean.pkl").tracks)["3"]
    assert back.num_frames == 35
    assert same_rotations(back.root_orient, new3.root_orient) < 2e-6
    assert same_rotations(back.pose_body, new3.pose_body) < 2e-6
    assert np.abs(back.trans - new3.trans).max() < 1e-5

    # the camera of an added row is its nearest row's: R_c = R_cam R_world^T holds there
    def camera(d, row):
        return rotvec_to_rotmat(d["pose"][row, :3]) @ rotvec_to_rotmat(d["pose_world"][row, :3]).T

    assert np.abs(camera(n3, 11) - camera(o3, 9)).max() < 1e-5
    assert np.abs(camera(n3, 13) - camera(o3, 10)).max() < 1e-5
    assert np.abs(camera(o3, 9) - camera(o3, 10)).max() > 0.04  # the camera does pan
    assert np.abs(camera(n3, 20) - camera(o3, 15)).max() < 1e-5  # a row the file had
    # holes left unfilled: no rows for them, and a note saying where the filled ones are
    holed = new3.with_body()
    holed.root_orient[10:15] = np.nan
    holed.trans[10:15] = np.nan
    notes = write(type(loaded)(src, "wham", "video", [("3", holed)], document=loaded.document),
                  tmp_path / "holed.pkl")  # fmt: skip
    assert any("5 frame(s) missing" in n and "not written" in n for n in notes)
    assert np.array_equal(load_data(tmp_path / "holed.pkl")[np.int64(3)]["frame_ids"], ids)
    kept = keep_holes(new3)  # --fill off: the holes hold placeholders, to stay as they came
    write(type(loaded)(src, "wham", "video", [("3", kept)], document=loaded.document),
          tmp_path / "kept.pkl")  # fmt: skip
    assert np.array_equal(load_data(tmp_path / "kept.pkl")[np.int64(3)]["frame_ids"], ids)


@pytest.mark.parametrize("matrices", [False, True], ids=["vibe", "pare"])
def test_vibe_and_pare_gaps_get_rows_filled(tmp_path, matrices):
    """A VIBE (axis-angle) or PARE (matrices) track with 4 frames missing from its frame ids:
    written back with a row for each, the cleaned fill in its pose, its other arrays (the
    weak-perspective camera, betas) the nearest row's; the rows the file had keep theirs."""
    m = vf.clip(24, seed=8)
    ids = np.r_[0:8, 12:28]
    name = "pare_output.pkl" if matrices else "vibe_output.pkl"
    src = vf.write_vibe(tmp_path / name, m, matrices=matrices, ids=ids)
    data = load_data(src)
    data[1]["orig_cam"][:, 2] = np.linspace(0.1, 0.2, 24)  # a camera that zooms: rows differ
    write_data(data, src, "joblib")
    loaded = read(src)
    ((label, track),) = loaded.tracks
    assert track.num_frames == 28
    new, _ = edited(track, every=2)
    notes = write(type(loaded)(src, "vibe", "video", [(label, new)], document=loaded.document),
                  tmp_path / "clean.pkl")  # fmt: skip
    assert any("4 frame(s) missing from the file's frame ids added as rows" in n for n in notes)
    old, out = load_data(src)[1], load_data(tmp_path / "clean.pkl")[1]
    assert np.array_equal(out["frame_ids"], np.arange(28))
    assert out["frame_ids"].dtype == old["frame_ids"].dtype
    assert out["pose"].shape[0] == 28 and out["pose"].dtype == old["pose"].dtype
    assert "joints3d" not in out  # made from the old pose: left out, not grown
    # frames 8-11 copy the nearest rows the file has (7, 7, 12, 12 -> rows 7, 7, 8, 8)
    assert np.array_equal(out["orig_cam"][8:12], old["orig_cam"][[7, 7, 8, 8]])
    assert np.array_equal(out["orig_cam"][12:], old["orig_cam"][8:])
    back = dict(read(tmp_path / "clean.pkl").tracks)[label]
    assert back.num_frames == 28
    assert same_rotations(back.root_orient, new.root_orient) < 2e-6
    assert same_rotations(back.pose_body, new.pose_body) < 2e-6


def test_phalp_gaps_get_entries_in_their_frames(tmp_path):
    """A PHALP track missing from 4 frames that hold another person: written back with an
    entry of its own in each of them (its lists as long as the frame's ``tid``), the cleaned
    fill in its ``smpl``, its camera and box the nearest frame's; the other person's entries
    stay as they came; left unfilled (--fill off) no entry is added."""
    a, b = vf.clip(21, seed=3), vf.clip(25, seed=4)
    ids_a = [*range(0, 10), *range(14, 25)]
    src = vf.write_phalp(tmp_path / "demo.pkl", {"1": (a, ids_a), "2": (b, list(range(25)))})
    loaded = read(src)
    tracks = dict(loaded.tracks)
    assert tracks["1"].num_frames == 25
    new, _ = edited(tracks["1"], every=2)
    notes = write(type(loaded)(src, "phalp", "video", [("1", new)], document=loaded.document),
                  tmp_path / "clean.pkl")  # fmt: skip
    assert any("4 frame(s) missing from the file's frame ids added as rows" in n for n in notes)
    old, out = load_data(src), load_data(tmp_path / "clean.pkl")
    for t in range(25):
        f, g = old[f"img/{t:06d}.jpg"], out[f"img/{t:06d}.jpg"]
        assert all(len(g[k]) == len(g["tid"]) for k in ("smpl", "camera", "bbox"))
        assert sorted(g["tid"]) == ["1", "2"]
        i, j = f["tid"].index("2"), g["tid"].index("2")
        assert np.array_equal(g["camera"][j], f["camera"][i])  # the other person as it came
        assert np.array_equal(g["smpl"][j]["body_pose"], f["smpl"][i]["body_pose"])
    nine = old["img/000009.jpg"]
    eleven = out["img/000011.jpg"]  # nearest to frame 9 of the file's
    assert np.array_equal(eleven["bbox"][-1], nine["bbox"][nine["tid"].index("1")])
    back = dict(read(tmp_path / "clean.pkl").tracks)
    assert back["1"].num_frames == 25
    assert same_rotations(back["1"].root_orient, new.root_orient) < 2e-6
    assert same_rotations(back["1"].pose_body, new.pose_body) < 2e-6
    assert np.abs(back["1"].trans - new.trans).max() < 1e-5
    kept = keep_holes(new)  # --fill off
    write(type(loaded)(src, "phalp", "video", [("1", kept)], document=loaded.document),
          tmp_path / "kept.pkl")  # fmt: skip
    assert load_data(tmp_path / "kept.pkl")["img/000011.jpg"]["tid"] == ["2"]


def test_add_noise_gives_a_gappy_track_back_with_its_own_rows(tmp_path):
    """add-noise makes the file's rows noisy and makes up none for the frames it lacks."""
    ids = list(range(0, 40, 2))
    src = vf.write_romp(tmp_path / "video_results.npz", {"0": (vf.clip(20, seed=5), ids)})
    code, _, err = run("add-noise", src, "-o", tmp_path / "noisy.npz", "--sigma", "0.1")
    assert code == 0, err
    noisy = np.load(tmp_path / "noisy.npz", allow_pickle=True)["sequence_results"].item()["0"]
    assert noisy["frame_id"] == ids and len(noisy["body_pose"]) == 20
