"""Copies a pipeline keeps of what the cleaning changes follow it when the file is written
back in its own form (``formats.video_back``): HybrIK's ``transl_camsys`` and
``pred_cam_root``, TRAM's 6D ``pred_pose``."""

from __future__ import annotations

import pickle

import numpy as np
import video_files as vf
from video_files import edited

from mdvae_cli.formats.registry import read, write
from mdvae_cli.formats.video_rows import from_six_d, row_scales, six_d


def test_row_scales_finds_a_per_frame_multiple_and_nothing_else():
    of = np.array([[0.2, -0.1, 8.0], [0.3, 0.0, 9.0]], np.float32)
    s = np.array([0.95, 1.1])
    assert np.allclose(row_scales((of * s[:, None]).astype(np.float32), of), s, rtol=1e-6)
    assert np.array_equal(row_scales(of, of), [1.0, 1.0])
    other = of * s[:, None]
    other[1, 0] += 0.01  # one row is no multiple: no copy
    assert row_scales(other, of) is None
    assert row_scales(np.zeros((3, 3)), of) is None  # another number of rows


def test_hybrik_transl_copies_follow_the_cleaned_translation(tmp_path):
    """HybrIK's demo stores ``transl_camsys = transl * 256 / box width`` and a
    ``pred_cam_root`` equal to ``transl``; written back, both follow the cleaned ``transl``
    by the file's own factor per frame (before: both kept the old values, up to 38 cm away
    from ``transl`` in depth on the shared res.pk)."""
    m = vf.clip(24, seed=3)
    src = vf.write_hybrik(tmp_path / "res.pk", m)
    res = pickle.loads(src.read_bytes())
    T = m.num_frames
    width = np.linspace(180.0, 320.0, T)
    res["bbox"] = np.stack([np.full(T, 50.0), np.full(T, 60.0), 50 + width, 60 + 2 * width], 1)
    res["transl_camsys"] = (res["transl"] * (256 / width)[:, None]).astype(np.float32)
    src.write_bytes(pickle.dumps(res, protocol=4))
    loaded = read(src)
    after, sel = edited(loaded.single())
    notes = write(after, tmp_path / "clean.pk", document=loaded.document)
    assert not any("transl_camsys" in n or "pred_cam_root" in n for n in notes)
    new = pickle.loads((tmp_path / "clean.pk").read_bytes())
    moved = np.abs(new["transl"] - res["transl"]).max(1)
    assert moved[sel].min() > 0.01 and moved[~sel].max() == 0
    assert new["transl_camsys"].dtype == np.float32
    assert np.abs(new["transl_camsys"] - new["transl"] * (256 / width)[:, None]).max() < 1e-5
    assert np.array_equal(new["transl_camsys"][~sel], res["transl_camsys"][~sel])
    assert np.abs(new["pred_cam_root"] - new["transl"]).max() < 1e-6


def test_hybrik_a_camsys_that_is_no_copy_is_kept_with_a_note(tmp_path):
    m = vf.clip(20, seed=4)
    src = vf.write_hybrik(tmp_path / "res.pk", m)
    res = pickle.loads(src.read_bytes())
    res["transl_camsys"] = np.random.default_rng(0).normal(size=(20, 3)).astype(np.float32)
    src.write_bytes(pickle.dumps(res, protocol=4))
    loaded = read(src)
    after, _ = edited(loaded.single())
    notes = write(after, tmp_path / "clean.pk", document=loaded.document)
    assert any("'transl_camsys' is no per-frame multiple of 'transl'" in n for n in notes)
    new = pickle.loads((tmp_path / "clean.pk").read_bytes())
    assert np.array_equal(new["transl_camsys"], res["transl_camsys"])


def test_six_d_reads_back_as_hmr2_reads_it():
    """HMR 2.0 / TRAM's ``rot6d_to_rotmat``: the six numbers taken as two rows of three, each
    a column of the matrix (first, second), Gram-Schmidt, the third column their cross."""
    rng = np.random.default_rng(0)
    mats = vf.np_rotvec_to_rotmat(rng.normal(size=(5, 3)))
    six = six_d(mats)
    assert np.allclose(six[:, :3], mats[:, :, 0]) and np.allclose(six[:, 3:], mats[:, :, 1])
    assert np.abs(from_six_d(six * 1.7) - mats).max() < 1e-12  # the network's are not unit


def test_tram_pred_pose_follows_pred_rotmat(tmp_path):
    """TRAM's ``pred_pose`` (T, 144) holds the network's 6D rotations that ``pred_rotmat``
    is made of; written back, a joint the cleaning turned gets the new matrix's 6D numbers
    and every other joint keeps the file's own (before: all kept, so ``pred_pose`` gave the
    old pose, up to 0.2 rad from ``pred_rotmat``). Not a copy: kept, with a note."""
    import torch

    src = vf.write_tram(tmp_path / "tram", vf.clip(24, seed=3))
    hps = np.load(src, allow_pickle=True).item()
    rng = np.random.default_rng(1)
    mats = hps["pred_rotmat"].numpy()
    raw6 = six_d(mats.astype(np.float64)) * rng.uniform(0.5, 2.0, size=(24, 24, 1))
    hps["pred_pose"] = torch.tensor(raw6.reshape(24, 144), dtype=torch.float32)
    np.save(src, hps, allow_pickle=True)
    loaded = read(src)
    after, sel = edited(loaded.single())
    out = src.parent / "clean.npy"  # TRAM's world comes from ../camera.npy
    notes = write(after, out, document=loaded.document)
    assert not any("pred_pose" in n for n in notes)
    new = np.load(out, allow_pickle=True).item()
    assert isinstance(new["pred_pose"], torch.Tensor) and new["pred_pose"].dtype == torch.float32
    got = from_six_d(new["pred_pose"].numpy().astype(np.float64).reshape(24, 24, 6))
    assert np.abs(got - new["pred_rotmat"].numpy()).max() < 1e-5
    changed = np.any(new["pred_pose"].numpy() != hps["pred_pose"].numpy(), axis=1)
    assert np.array_equal(changed, sel)
    hps["pred_pose"] = torch.zeros(24, 144)  # not the file's rotations
    np.save(src, hps, allow_pickle=True)
    loaded = read(src)
    notes = write(edited(loaded.single())[0], out, document=loaded.document)
    assert any("'pred_pose' (6D rotations, not of 'pred_rotmat') kept" in n for n in notes)
    assert not np.load(out, allow_pickle=True).item()["pred_pose"].numpy().any()
