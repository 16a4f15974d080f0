"""NaN / inf in a video pipeline's file (a frame the estimator failed on, a joint it lost) are
holes, read as an npz's are and filled (``formats.video_holes``), written back into every
copy the file keeps of such a frame, with ``--fill off`` leaving them as they came (issue 32).
Before, any NaN refused the whole file: "'pose_world' holds NaN or infinite values"."""

from __future__ import annotations

import json

import numpy as np
import torch
import video_files as vf
from click.testing import CliRunner
from video_files import edited, same_rotations

from mdvae_cli.cli.main import cli
from mdvae_cli.formats.data_files import load_data
from mdvae_cli.formats.data_write import write_data
from mdvae_cli.formats.npz_holes import keep_holes
from mdvae_cli.formats.registry import read, write
from mdvae_cli.formats.video_rows import near, six_d
from mdvae_cli.formats.video_tracks import CAMERA_UP
from mdvae_cli.geometry.rotations_np import rotmat_to_rotvec

HOLE = [10, 11, 12, 13]  # every value NaN in these rows


def run(*args):
    result = CliRunner().invoke(cli, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


def _holed_wham(tmp_path, T=30):
    """A WHAM file (world and camera copies) with rows HOLE NaN in every per-frame float
    array and joint 5 NaN in frame 20 of both poses. -> (path, the file's data)"""
    src = vf.write_wham(tmp_path / "wham_output.pkl", {0: (vf.clip(T, seed=1), None)})
    data = load_data(src)
    d = data[np.int64(0)]
    for k in ("pose", "trans", "pose_world", "trans_world", "betas", "verts"):
        d[k][HOLE] = np.nan
    d["pose"][20, 15:18] = d["pose_world"][20, 15:18] = np.nan
    write_data(data, src, "joblib")
    return src, data


def _put_back(src, tmp_path, name):
    """``src`` read, its track edited as a cleaning would, written back in its own form. ->
    (the cleaned motion, the file written, its notes)"""
    loaded = read(src)
    label, motion = loaded.tracks[0]
    new, _ = edited(motion, every=2)
    out = tmp_path / name
    notes = write(type(loaded)(src, loaded.format, "video", [(label, new)],
                               document=loaded.document), out)  # fmt: skip
    return new, out, notes


def test_wham_nan_rows_are_filled_in_the_world_pose_and_its_camera_copy(tmp_path):
    src, old = _holed_wham(tmp_path)
    motion = read(src).tracks[0][1]
    assert np.isfinite(motion.poses).all() and np.isfinite(motion.trans).all()
    assert np.flatnonzero(~motion.joint_mask.all(1)).tolist() == [*HOLE, 20]
    assert int((~motion.joint_mask).sum()) == 4 * 22 + 1
    assert not motion.joint_mask[20, 5] and motion.joint_mask[20, 4]
    new, out, _ = _put_back(src, tmp_path, "clean.pkl")
    d = load_data(out)[np.int64(0)]
    for k in ("pose", "trans", "pose_world", "trans_world", "betas"):
        assert np.isfinite(d[k]).all(), k
        assert d[k].dtype == old[np.int64(0)][k].dtype
    back = read(out).tracks[0][1]  # the world pose read back: the cleaned one, holes too
    assert back.joint_mask is None
    assert same_rotations(back.root_orient, new.root_orient) < 2e-6
    assert same_rotations(back.pose_body, new.pose_body) < 2e-6
    assert np.abs(back.trans - new.trans).max() < 2e-6
    # the camera-frame copy in the holes: the cleaned body through the file's camera
    root_c, trans_c = vf.to_source(new, CAMERA_UP)
    rows = [*HOLE, 20]
    assert same_rotations(d["pose"][rows, :3], rotmat_to_rotvec(root_c[rows])) < 1e-5
    assert np.abs(d["trans"][HOLE] - trans_c[HOLE]).max() < 1e-5
    assert same_rotations(d["pose"][20, 15:18], new.pose_body[20, 4]) < 1e-5
    # the hands of a hole row: a line between the rows beside it; its shape: the track's mean
    hands = old[np.int64(0)]["pose_world"][:, 66:].astype(float)
    w = (np.array(HOLE) - 9)[:, None] / 5
    assert np.abs(d["pose_world"][HOLE, 66:] - ((1 - w) * hands[9] + w * hands[14])).max() < 1e-6
    assert np.allclose(d["betas"][HOLE], new.betas, atol=1e-6)


def test_wham_nan_rows_counted_and_kept_as_they_came_with_fill_off(tmp_path):
    src, old = _holed_wham(tmp_path)
    code, out, err = run("denoise", src, "-o", tmp_path / "on.pkl", "--json")
    assert code == 0, err
    result = json.loads(out)["files"][0]["result"]
    assert (result["filled_frames"], result["filled_joints"]) == (5, 89)
    assert any("NaN or infinite values in 5 of 30 frame(s) (4 whole, 89 joint" in n
               for n in result["notes"])  # fmt: skip
    d = load_data(tmp_path / "on.pkl")[np.int64(0)]
    assert all(np.isfinite(d[k]).all() for k in ("pose", "trans", "pose_world", "trans_world"))
    code, out, err = run("denoise", src, "-o", tmp_path / "off.pkl", "--fill", "off", "--json")
    assert code == 0, err
    assert json.loads(out)["files"][0]["result"]["unfilled_frames"] == 5
    d, o = load_data(tmp_path / "off.pkl")[np.int64(0)], old[np.int64(0)]
    for k in ("pose", "trans", "pose_world", "trans_world", "betas"):
        assert np.array_equal(np.isnan(d[k]), np.isnan(o[k])), k
    code, _, err = run("denoise", src, "-o", tmp_path / "off.npz", "--fill", "off")
    assert code == 0, err
    z = np.load(tmp_path / "off.npz")
    assert np.flatnonzero(np.isnan(z["poses"]).any(1)).tolist() == [*HOLE, 20]
    assert np.flatnonzero(np.isnan(z["poses"][20])).tolist() == [15, 16, 17]
    assert np.flatnonzero(np.isnan(z["trans"]).any(1)).tolist() == HOLE


def test_hybrik_nan_rows_fill_its_translation_copies_at_their_scales(tmp_path):
    """HybrIK's ``transl_camsys`` is ``transl`` times a per-frame scale: in a hole row the
    filled translation at the scale of the rows beside it."""
    T = 16
    src = vf.write_hybrik(tmp_path / "res.pk", vf.clip(T, seed=2))
    res = load_data(src)
    scale = (1.0 + 0.1 * np.arange(T)).astype(np.float32)
    res["transl_camsys"] = res["transl"] * scale[:, None]
    for k in ("pred_thetas", "transl", "transl_camsys", "pred_cam_root", "pred_betas",
              "pred_xyz_29"):  # fmt: skip
        res[k][HOLE] = np.nan
    res["pred_thetas"][6, 9 * 4 : 9 * 5] = np.inf  # joint 4 lost in frame 6
    write_data(res, src, "pickle")
    new, out, _ = _put_back(src, tmp_path, "clean.pk")
    d = load_data(out)
    for k in ("pred_thetas", "transl", "transl_camsys", "pred_cam_root", "pred_betas"):
        assert np.isfinite(d[k]).all(), k
    assert np.allclose(d["transl_camsys"], d["transl"] * scale[:, None], rtol=1e-5, atol=1e-6)
    assert np.array_equal(d["pred_cam_root"], d["transl"])
    back = read(out).tracks[0][1]
    assert same_rotations(back.pose_body, new.pose_body) < 2e-6
    assert np.abs(back.trans - new.trans).max() < 2e-6
    # the network's own joints in a filled row: placed by the filled pose on the bones of the
    # rows beside (all 0 in this file: 0); before, left NaN (formats.hybrik_holes)
    assert np.array_equal(d["pred_xyz_29"][HOLE], np.zeros((len(HOLE), 29, 3)))


def test_tram_nan_rows_fill_the_6d_copy(tmp_path):
    T = 20
    src = vf.write_tram(tmp_path / "tram", vf.clip(T, seed=3))
    hps = load_data(src).item()
    hps = {k: np.asarray(v) for k, v in hps.items()}
    hps["pred_pose"] = six_d(hps["pred_rotmat"]).reshape(T, -1)
    for k in ("pred_rotmat", "pred_trans", "pred_pose", "pred_shape"):
        hps[k][HOLE] = np.nan
    np.save(src, {k: torch.as_tensor(v) for k, v in hps.items()}, allow_pickle=True)
    new, out, _ = _put_back(src, tmp_path / "tram" / "hps", "clean.npy")
    d = {k: np.asarray(v) for k, v in load_data(out).item().items()}
    for k in ("pred_rotmat", "pred_trans", "pred_pose", "pred_shape"):
        assert np.isfinite(d[k]).all(), k
    assert np.abs(d["pred_pose"] - six_d(d["pred_rotmat"]).reshape(T, -1)).max() < 1e-6
    back = read(out).tracks[0][1]
    assert same_rotations(back.root_orient, new.root_orient) < 2e-6
    assert np.abs(back.trans - new.trans).max() < 2e-6


def test_phalp_nan_entries_are_filled_in_their_frames(tmp_path):
    T = 20
    src = vf.write_phalp(tmp_path / "demo.pkl", {1: (vf.clip(T, seed=4), list(range(T)))})
    data = load_data(src)
    for f in data.values():
        if f["time"] in HOLE:
            f["smpl"][0]["global_orient"] = np.full((1, 3, 3), np.nan, np.float32)
            f["smpl"][0]["body_pose"] = np.full((23, 3, 3), np.nan, np.float32)
            f["smpl"][0]["betas"] = np.full(10, np.nan, np.float32)
            f["camera"][0] = np.full(3, np.nan, np.float32)
    write_data(data, src, "joblib-zlib")
    assert int((~read(src).tracks[0][1].joint_mask).sum()) == 4 * 22
    new, out, _ = _put_back(src, tmp_path, "clean.pkl")
    for f in load_data(out).values():
        smpl = f["smpl"][0]
        for a in (smpl["global_orient"], smpl["body_pose"], smpl["betas"], f["camera"][0]):
            assert np.isfinite(a).all(), f["time"]
    back = read(out).tracks[0][1]
    assert same_rotations(back.root_orient, new.root_orient) < 2e-6
    assert np.abs(back.trans - new.trans).max() < 2e-6


def test_fill_off_writes_no_value_into_a_hole(tmp_path):
    """``keep_holes`` (what ``--fill off`` and ``add-noise`` write): the file's NaN stay, in
    every copy, even where the placeholders under them were changed (noise added)."""
    src, old = _holed_wham(tmp_path)
    loaded = read(src)
    kept = keep_holes(edited(loaded.tracks[0][1], every=2)[0])  # rows 10 and 12 changed
    write(type(loaded)(src, "wham", "video", [(None, kept)], document=loaded.document),
          tmp_path / "off.pkl")  # fmt: skip
    d, o = load_data(tmp_path / "off.pkl")[np.int64(0)], old[np.int64(0)]
    for k in ("pose", "trans", "pose_world", "trans_world", "betas"):
        assert np.array_equal(np.isnan(d[k]), np.isnan(o[k])), k
        assert np.array_equal(d[k][1::2], o[k][1::2], equal_nan=True), k  # rows not edited


def test_a_value_written_into_a_hole_keeps_its_own_branch():
    """``near`` picks the axis-angle branch nearest the file's value; a NaN there made
    ``argmin`` pick the first option, a turn of 2 pi less (3 rad came back as -3.28 rad)."""
    new = np.array([[0.0, 0.0, 3.0], [0.0, 1.0, 0.0]])
    assert np.array_equal(near(new, np.full((2, 3), np.nan)), new)
    assert np.allclose(near(new[:1], np.array([[0.0, 0.0, -3.2]])), [[0.0, 0.0, 3.0 - 2 * np.pi]])
