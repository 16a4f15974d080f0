"""A GVHMR result converted to an AMASS-style npz ("gvhmr-npz"): written back cleaned, its
camera-frame copies (``smpl_params_incam_*``) follow the cleaned world motion by the file's own
per-frame camera, as a GVHMR ``.pt``'s do (``test_video_back``); ``net_outputs_*`` are left out.
Also: ``--missing`` on inputs it does not apply to says so."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import video_files as vf
from conftest import run_cli
from video_files import edited, same_rotations

from mdvae_cli.formats.registry import ReadOptions, read, write
from mdvae_cli.geometry.rotations_np import rotmat_to_rotvec, rotvec_to_rotmat

J0 = np.array([0.002, -0.22, 0.03])  # a rest pelvis: the copies' meaning of transl
REAL = Path("/work/shared/data/real/smpl/gvhmr_npz/tennis_hmr4d_results.npz")


def camera(T: int) -> tuple[np.ndarray, np.ndarray]:
    """A camera that turns and moves: world -> camera rotation (T, 3, 3), offset (T, 3)."""
    t = np.linspace(0, 1, T)[:, None]
    rv = np.concatenate([0.3 + 0.2 * t, -0.8 + 0.5 * t, 0.1 * np.sin(6 * t)], 1)
    return rotvec_to_rotmat(rv), np.concatenate([0.1 * t, 0.2 + 0 * t, 4.0 - t], 1)


def in_camera(root: np.ndarray, trans: np.ndarray, T: int) -> tuple[np.ndarray, np.ndarray]:
    """The camera-frame copy of a world pose: root (T, 3), SMPL transl (T, 3)."""
    Rc, c = camera(T)
    cam_root = rotmat_to_rotvec(Rc @ rotvec_to_rotmat(root))
    cam_transl = np.einsum("tij,tj->ti", Rc, J0 + trans) + c - J0
    return cam_root, cam_transl


def write_gvhmr_npz(path: Path, T: int = 24) -> Path:
    """The downstream conversion's layout: poses (T, 72), trans, betas, its keys flattened."""
    m = vf.clip(T, seed=3)
    poses = np.concatenate([m.root_orient, m.pose_body.reshape(T, 63), np.zeros((T, 6))], 1)
    cam_root, cam_transl = in_camera(m.root_orient, m.trans, T)
    np.savez(
        path,
        poses=poses.astype(np.float32),
        trans=m.trans.astype(np.float32),
        betas=m.betas[:10].astype(np.float32),
        gender=np.array("neutral"),
        mocap_framerate=np.array(30),
        K_fullimg=np.tile(np.eye(3, dtype=np.float32), (T, 1, 1)),
        smpl_params_incam_body_pose=m.pose_body.reshape(T, 63).astype(np.float32),
        smpl_params_incam_betas=np.tile(m.betas[:10], (T, 1)).astype(np.float32),
        smpl_params_incam_global_orient=cam_root.astype(np.float32),
        smpl_params_incam_transl=cam_transl.astype(np.float32),
        net_outputs_model_output_pred_x=np.zeros((1, T, 151), np.float32),
        net_outputs_static_conf_logits=np.zeros((1, T, 6), np.float32),
    )
    return path


def test_camera_copies_follow_the_cleaned_world_motion(tmp_path):
    src = write_gvhmr_npz(tmp_path / "tennis.npz")
    loaded = read(src)
    assert loaded.format == "gvhmr-npz"
    after, sel = edited(loaded.single())
    out = tmp_path / "clean.npz"
    notes = write(after, out)
    assert notes == ["2 'net_outputs_*' arrays left out (the network's internals for the old pose)"]
    with np.load(src) as a, np.load(out) as b:
        assert not any(k.startswith("net_outputs_") for k in b.files)
        assert "gvhmr_world_as_read" not in b.files
        T = len(b["poses"])
        ref_root, ref_transl = in_camera(after.root_orient, after.trans, T)
        go, tr = b["smpl_params_incam_global_orient"], b["smpl_params_incam_transl"]
        assert go.dtype == tr.dtype == np.float32
        assert same_rotations(go[sel], ref_root[sel]) < 2e-6
        assert np.abs(tr[sel] - ref_transl[sel]).max() < 1e-5
        body = b["smpl_params_incam_body_pose"]
        assert np.allclose(body[sel], after.pose_body[sel].reshape(-1, 63))
        for k in ("global_orient", "transl", "body_pose", "betas"):  # untouched rows: same bits
            key = f"smpl_params_incam_{k}"
            assert np.array_equal(a[key][~sel], b[key][~sel]), key
        assert np.array_equal(a["smpl_params_incam_betas"], b["smpl_params_incam_betas"])


def test_copies_whose_frames_are_not_the_motion_s_are_left_with_a_note(tmp_path):
    from mdvae_cli.motion.motion import slice_frames

    loaded = read(write_gvhmr_npz(tmp_path / "t.npz"))
    part = slice_frames(loaded.single(), 0, 10)
    notes = write(part, tmp_path / "part.npz")
    assert any("'smpl_params_incam_*') are left as they came" in n for n in notes)


def test_a_plain_npz_writes_as_before(tmp_path, make_motion_file):
    m = read(make_motion_file("plain.npz", T=12)).single()
    assert write(m, tmp_path / "o.npz") == []


def test_denoise_moves_the_camera_copies_with_the_world(tmp_path):
    src = write_gvhmr_npz(tmp_path / "tennis.npz", T=40)
    out = tmp_path / "clean.npz"
    code, _, err = run_cli("denoise", src, "-o", out)
    assert code == 0, err
    assert "'net_outputs_*' arrays left out" in err
    with np.load(out) as b:
        ref_root, ref_transl = in_camera(b["poses"][:, :3].astype(float), b["trans"], 40)
        assert same_rotations(b["smpl_params_incam_global_orient"], ref_root) < 1e-5
        assert np.abs(b["smpl_params_incam_transl"] - ref_transl).max() < 1e-4


@pytest.mark.skipif(not REAL.is_file(), reason="the shared GVHMR npz is not here")
def test_the_real_take_keeps_its_camera(tmp_path):
    out = tmp_path / "clean.npz"
    code, _, err = run_cli("denoise", REAL, "-o", out)
    assert code == 0, err
    with np.load(REAL) as a, np.load(out) as b:
        assert not np.array_equal(a["smpl_params_incam_transl"], b["smpl_params_incam_transl"])

        def cam(z):
            world = rotvec_to_rotmat(z["poses"][:, :3].astype(float))
            return rotvec_to_rotmat(z["smpl_params_incam_global_orient"].astype(float)) @ (
                world.transpose(0, 2, 1)
            )

        Rc = cam(a)
        assert np.abs(cam(b) - Rc).max() < 1e-5
        moved = np.einsum("tij,tj->ti", Rc, (b["trans"] - a["trans"]).astype(float))
        change = (b["smpl_params_incam_transl"] - a["smpl_params_incam_transl"]).astype(float)
        assert np.abs(change - moved).max() < 1e-5


def test_missing_rules_on_an_npz_or_a_video_file_say_they_are_ignored(tmp_path, make_motion_file):
    npz = make_motion_file("take.npz", T=30)
    rules = ReadOptions(missing=("frozen", "zeros"))
    said = "--missing applies to BVH and AMC takes (an npz marks its holes as NaN rows); ignored"
    assert said in read(npz, rules).notes
    assert not any("--missing" in n for n in read(npz).notes)
    pt = vf.write_gvhmr(tmp_path / "hmr4d_results.pt", vf.clip(20))
    assert "--missing applies to BVH and AMC takes; ignored" in read(pt, rules).notes
    code, _, err = run_cli("denoise", npz, "-o", tmp_path / "c.npz", "--missing", "frozen,zeros")
    assert code == 0, err
    assert f"note: take.npz: {said}" in " ".join(err.split())
    code, _, err = run_cli("import", pt, "-o", tmp_path / "i.npz", "--missing", "zeros")
    assert code == 0, err
    assert "--missing applies to BVH and AMC takes; ignored" in " ".join(err.split())


def test_denoise_help_says_how_short_a_take_may_be():
    from mdvae_cli.infer.denoise import MIN_FRAMES
    from mdvae_cli.model.chunks import MODEL_FPS

    code, out, _ = run_cli("denoise", "--help")
    text = " ".join(out.split())
    assert code == 0 and "any length," not in text
    assert f"any length from {(MIN_FRAMES - 1) / MODEL_FPS:.2g} s, {MIN_FRAMES} frames at" in text


def test_add_noise_and_import_say_what_they_leave_out(tmp_path):
    src = write_gvhmr_npz(tmp_path / "tennis.npz")
    for cmd in ("add-noise", "import"):
        code, _, err = run_cli(cmd, src, "-o", tmp_path / f"{cmd}.npz")
        assert code == 0, err
        assert "2 'net_outputs_*' arrays left out" in err, cmd
        with np.load(tmp_path / f"{cmd}.npz") as b:
            assert not any(k.startswith("net_outputs_") for k in b.files)
