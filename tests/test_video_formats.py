"""Video-pipeline readers (formats/video_formats.py, video_tracks.py, load_any.py): files written
in each pipeline's exact layout read back as the z-up motion they were made from."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import video_files as vf

from mdvae_cli.errors import InputError
from mdvae_cli.formats.registry import ALIASES, FORMATS, ReadOptions, format_name, read
from mdvae_cli.formats.video_formats import READERS
from mdvae_cli.formats.video_tracks import CAMERA_UP, Y_UP, rest_pelvis, up_to_z

REAL = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
TOL = 2e-4  # float32 files


def load_any(path, fmt=None, **options):
    """The registry's read with ``--format`` and other options given by name."""
    return read(path, ReadOptions(format=fmt, **options))


def load_one(path, fmt=None, **options):
    return load_any(path, fmt, **options).single()


def same_body(a, b, tol=TOL, trans=True):
    """Root orientation, body pose and (``trans``) translation agree (as rotations)."""
    ma, mb = vf._mat(a.root_orient), vf._mat(b.root_orient)
    assert np.abs(ma - mb).max() < tol
    assert np.abs(vf._mat(a.pose_body) - vf._mat(b.pose_body)).max() < tol
    if trans:
        assert np.abs(a.trans - b.trans).max() < tol


def test_every_format_has_a_reader():
    assert set(FORMATS) == {"amass", *READERS}
    assert all(v in READERS for v in ALIASES.values())
    assert format_name("PARE") == "vibe" and format_name("bev") == "romp"
    with pytest.raises(InputError, match="unknown --format"):
        format_name("mystery")


def test_up_to_z_known_frames():
    np.testing.assert_allclose(up_to_z(Y_UP) @ [1, 2, 3], [1, -3, 2], atol=1e-12)
    np.testing.assert_allclose(up_to_z(CAMERA_UP) @ [1, 2, 3], [1, 3, -2], atol=1e-12)
    np.testing.assert_allclose(up_to_z((0, 0, 1)), np.eye(3))
    np.testing.assert_allclose(up_to_z((0, 0, -1)) @ [0, 0, -1], [0, 0, 1], atol=1e-12)
    u = np.array([0.3, -0.8, 0.2])
    np.testing.assert_allclose(up_to_z(u) @ (u / np.linalg.norm(u)), [0, 0, 1], atol=1e-12)


def test_wham_world_frame_round_trip(tmp_path):
    m = vf.clip(40, seed=1)
    loaded = load_any(vf.write_wham(tmp_path / "wham_output.pkl", {0: (m, None)}))
    assert loaded.format == "wham" and loaded.kind == "video"
    label, got = loaded.tracks[0]
    assert label is None and got.num_frames == 40 and got.fps == 30.0
    same_body(got, m)
    np.testing.assert_allclose(got.betas, m.betas, atol=1e-6)
    np.testing.assert_allclose(got.pose_extra, m.pose_extra[:, :6], atol=1e-6)
    assert got.poses.shape == (40, 72) and got.gender == "neutral"
    np.testing.assert_array_equal(got.extras["frame_ids"], np.arange(40))
    assert {"cam_root_orient", "cam_trans", "source_format"} <= set(got.extras)
    assert "verts" not in got.extras
    assert any("no frame rate" in n for n in got.notes)


def test_wham_camera_frame_when_no_world(tmp_path):
    m = vf.clip(30, seed=2)
    got = load_one(vf.write_wham(tmp_path / "w.pkl", {0: (m, None)}, world=False))
    same_body(got, m)  # the writer put the body in a level camera: the same frame comes back


def test_several_tracks_gaps_and_track_choice(tmp_path):
    a, b = vf.clip(30, seed=3), vf.clip(20, seed=4)
    ids_b = np.r_[np.arange(5, 15), np.arange(20, 30)]  # a gap of 5 frames
    path = vf.write_wham(tmp_path / "w.pkl", {0: (a, None), 7: (b, ids_b)})
    loaded = load_any(path)
    assert [lab for lab, _ in loaded.tracks] == ["0", "7"]
    got = loaded.tracks[1][1]
    assert got.num_frames == 25
    np.testing.assert_array_equal(got.extras["frame_ids"], np.arange(5, 30))
    observed = got.joint_mask[:, 0]
    assert (
        observed.sum() == 20
        and not observed[10:15].any()
        and observed.all(where=~np.isin(np.arange(25), range(10, 15)))
    )
    # observed frames are exactly the file's; a filled frame lies between its neighbours
    keep = np.flatnonzero(observed)
    np.testing.assert_allclose(got.trans[keep], b.trans, atol=TOL)
    assert np.all(got.trans[10:15, 0] >= got.trans[9, 0] - 1e-9) or np.all(
        got.trans[10:15, 0] <= got.trans[9, 0] + 1e-9
    )
    with pytest.raises(InputError, match="holds 2 tracks"):
        loaded.single()
    one = load_any(path, track="7")
    assert len(one.tracks) == 1 and one.tracks[0][0] is None
    with pytest.raises(InputError, match="no track '5'"):
        load_any(path, track="5")


def test_gvhmr_torch_file(tmp_path):
    m = vf.clip(35, seed=5)
    loaded = load_any(vf.write_gvhmr(tmp_path / "hmr4d_results.pt", m))
    assert loaded.format == "gvhmr"
    got = loaded.single()
    same_body(got, m)
    assert got.poses.shape == (35, 66) and str(got.extras["surface_model_type"]) == "smplx"
    assert got.extras["cam_K"].shape == (35, 3, 3)


def test_hybrik_pelvis_translation(tmp_path):
    m = vf.clip(25, seed=6)
    got = load_one(vf.write_hybrik(tmp_path / "res.pk", m))
    same_body(got, m, tol=1e-3)  # float32 rotation matrices
    assert got.extras["img_path"][3] == "img_000003.png"


@pytest.mark.parametrize("with_camera", [True, False])
def test_tram_track_and_camera(tmp_path, with_camera):
    m = vf.clip(25, seed=7)
    path = vf.write_tram(tmp_path / "results" / "clip", m, with_camera)
    loaded = load_any(path)
    assert loaded.format == "tram"
    got = loaded.single()
    same_body(got, m, tol=1e-3)
    assert any(
        ("world frame from camera.npy" if with_camera else "no camera.npy") in n for n in got.notes
    )
    if with_camera:
        with pytest.raises(InputError, match="TRAM's camera file"):
            load_any(path.parent.parent / "camera.npy")  # fmt: skip


def test_phalp_compressed_joblib_grouped_by_track(tmp_path):
    a, b = vf.clip(12, seed=8), vf.clip(6, seed=9)
    path = vf.write_phalp(tmp_path / "demo_clip.pkl", {2: (a, list(range(12))),
                                                       5: (b, list(range(4, 10)))})  # fmt: skip
    loaded = load_any(path)
    assert loaded.format == "phalp"
    (la, ga), (lb, gb) = loaded.tracks
    assert (la, lb) == ("2", "5") and ga.num_frames == 12 and gb.num_frames == 6
    same_body(ga, a, tol=1e-3)
    same_body(gb, b, tol=1e-3)
    np.testing.assert_array_equal(gb.extras["frame_ids"], np.arange(4, 10))


@pytest.mark.parametrize("matrices", [False, True])
def test_vibe_and_pare(tmp_path, matrices):
    m = vf.clip(20, seed=10)
    got = load_one(vf.write_vibe(tmp_path / "vibe_output.pkl", m, matrices))
    same_body(got, m, tol=1e-3, trans=False)  # no translation stored: placed from orig_cam
    assert np.ptp(got.trans, axis=0).max() < 1e-6  # a constant camera: the body stays put
    assert any("weak-perspective" in n for n in got.notes)


def test_romp_video_results(tmp_path):
    a, b = vf.clip(10, seed=11), vf.clip(8, seed=12)
    path = vf.write_romp(tmp_path / "video_results.npz", {0: (a, list(range(10))),
                                                          1: (b, list(range(2, 10)))})  # fmt: skip
    loaded = load_any(path)
    assert loaded.format == "romp" and len(loaded.tracks) == 2
    same_body(loaded.tracks[0][1], a)
    same_body(loaded.tracks[1][1], b)


def test_slahmr_world_results(tmp_path):
    a, b = vf.clip(15, seed=13), vf.clip(15, seed=14)
    loaded = load_any(vf.write_slahmr(tmp_path / "clip_000060_world_results.npz", [a, b]))
    assert loaded.format == "slahmr"
    for (_, got), m in zip(loaded.tracks, (a, b), strict=True):
        same_body(got, m)
        assert got.poses.shape == (15, 156)  # SMPL-H: root, body, hands


@pytest.mark.parametrize("plane", [[[0.0, -1.0, 0.0, 1.2]], [[0.0, -1.2, 0.0]] * 2, [0, 1.2, 0]])
def test_slahmr_floor_plane_as_abcd_or_per_track_gives_the_same_bodies(tmp_path, plane):
    """A plane's (a, b, c, d), one normal per track, or the normal flipped: the same up."""
    a = vf.clip(15, seed=13)
    path = vf.write_slahmr(tmp_path / "clip_000060_world_results.npz", [a])
    data = dict(np.load(path))
    np.savez(path, **{**data, "floor_plane": np.asarray(plane, np.float32)})
    same_body(load_any(path).single(), a)


def test_slahmr_floor_plane_of_another_shape_is_one_error(tmp_path):
    path = vf.write_slahmr(tmp_path / "clip_000060_world_results.npz", [vf.clip(15, seed=13)])
    np.savez(path, **{**dict(np.load(path)), "floor_plane": np.ones((1, 5), np.float32)})
    with pytest.raises(InputError, match=r"'floor_plane' has shape \(1, 5\): expected"):
        load_any(path)


def test_aistpp_pickle(tmp_path):
    m = vf.clip(30, seed=15)
    loaded = load_any(vf.write_aistpp(tmp_path / "gBR_sBM_cAll_d04_mBR0_ch01.pkl", m))
    assert loaded.format == "aistpp" and loaded.kind == "mocap"
    got = loaded.single()
    assert got.fps == 60.0
    same_body(got, m, trans=False)
    d = rest_pelvis(vf.BODY, m.betas) - rest_pelvis(vf.BODY, np.zeros(10))  # no betas in file
    np.testing.assert_allclose(got.trans, m.trans + d - d @ up_to_z(Y_UP).T, atol=TOL)


def test_fps_override_and_refusals(tmp_path):
    m = vf.clip(20, seed=16)
    path = vf.write_wham(tmp_path / "w.pkl", {0: (m, None)})
    assert load_one(path, fps=25).fps == 25.0
    with pytest.raises(InputError, match="frame rate"):
        load_one(path, fps=0.01)
    (tmp_path / "x.fbx").write_text("Kaydara FBX")
    with pytest.raises(InputError, match="FBX is not supported: export the take as BVH"):
        load_any(tmp_path / "x.fbx")
    (tmp_path / "other.pkl").write_bytes(__import__("pickle").dumps({"a": np.zeros(2)}))
    with pytest.raises(InputError, match="not a motion layout"):
        load_any(tmp_path / "other.pkl")
    with pytest.raises(InputError, match="no 'pred_thetas'|no 'smpl_poses'"):
        load_any(path, fmt="hybrik")


def test_amass_files_still_read_as_before(make_motion_file):
    path = make_motion_file("take.npz")
    loaded = load_any(path)
    assert loaded.format == "amass" and loaded.kind == "mocap"
    from mdvae_cli.formats.npz_io import load_motion

    ref = load_motion(path)
    np.testing.assert_array_equal(loaded.single().poses, ref.poses)


def _real(name):
    path = REAL / name
    if not path.is_file():
        pytest.skip("shared real data not present")
    return path


def test_real_gvhmr_pt_and_its_npz_conversion_agree():
    pt = load_any(_real("real/video/gvhmr/tennis_hmr4d_results.pt")).single()
    conv = load_any(_real("real/smpl/gvhmr_npz/tennis_hmr4d_results.npz"))
    assert conv.format == "gvhmr-npz" and conv.kind == "video"
    npz = conv.single()
    same_body(pt, npz, tol=1e-5, trans=False)
    # the converter rotated transl without the pelvis offset: a constant difference
    J0 = rest_pelvis(vf.BODY, pt.betas)
    np.testing.assert_allclose(pt.trans - npz.trans, np.tile(up_to_z(Y_UP) @ J0 - J0, (312, 1)),
                               atol=1e-5)  # fmt: skip


def test_real_aistpp_pickle_matches_the_converted_npz():
    pkl = load_one(_real("real/smpl/aistpp/gWA_sFM_cAll_d27_mWA5_ch20.pkl"))
    ref = np.load(_real("aistpp/gWA_sFM_cAll_d27_mWA5_ch20.npz"))
    assert pkl.num_frames == 720 and pkl.fps == 60.0
    np.testing.assert_allclose(pkl.pose_body.reshape(720, 63), ref["smpl_poses"][:, 3:66],
                               atol=1e-6)  # fmt: skip


@pytest.mark.parametrize(
    "name,fmt,frames",
    [("real/video/wham/wham_output.pkl", "wham", 42),
     ("real/video/gvhmr/tennis_hmr4d_results.pt", "gvhmr", 312),
     ("real/video/hybrik/res.pk", "hybrik", 135)],
)  # fmt: skip
def test_real_video_files_come_out_upright(name, fmt, frames):
    loaded = load_any(_real(name))
    assert loaded.format == fmt
    m = loaded.single()
    assert m.num_frames == frames and m.fps == 30.0
    up = vf._mat(m.root_orient)[:, :, 1]  # the pelvis's up axis (the rest body's +y)
    assert up[:, 2].mean() > 0.9
