"""TRAM's ``pred_cam`` and PHALP's ``camera_bbox`` (the weak-perspective crop cameras their
translations are made from with the row's box and focal length) follow the cleaned translation
(``video_rows.crop_camera_follows``). Before, both were kept as they came, with no note: the
camera a TRAM or PHALP tool reads the body's place from stayed where the body was before."""

from __future__ import annotations

import numpy as np
import torch
import video_files as vf
from video_files import edited

from mdvae_cli.formats.data_files import load_data
from mdvae_cli.formats.data_write import write_data
from mdvae_cli.formats.registry import read, write
from mdvae_cli.formats.video_rows import crop_camera_follows

FOCAL, CENTER = 1000.0, np.array([640.0, 360.0])


def _boxes(T: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-row box centres (T, 2) and sizes (T,), drifting as a tracker's do."""
    t = np.arange(T)
    return np.stack([500 + 8.0 * t, 300 + 3.0 * np.sin(t)], 1), 300 + 5.0 * np.cos(t)


def full_translation(cam: np.ndarray, centre: np.ndarray, size: np.ndarray) -> np.ndarray:
    """TRAM's ``get_trans`` / PHALP's full-image camera from a crop camera [s, tx, ty].
    (T, 3), (T, 2), (T,) -> (T, 3)"""
    bs = size * cam[:, 0]
    x = cam[:, 1] + 2 * (centre[:, 0] - CENTER[0]) / bs
    return np.stack([x, cam[:, 2] + 2 * (centre[:, 1] - CENTER[1]) / bs, 2 * FOCAL / bs], 1)


def crop_camera(trans: np.ndarray, centre: np.ndarray, size: np.ndarray) -> np.ndarray:
    """The crop camera that gives ``trans`` (the inverse of :func:`full_translation`)."""
    s = 2 * FOCAL / (size * trans[:, 2])
    bs = size * s
    return np.stack([s, trans[:, 0] - 2 * (centre[:, 0] - CENTER[0]) / bs,
                     trans[:, 1] - 2 * (centre[:, 1] - CENTER[1]) / bs], 1)  # fmt: skip


def test_crop_camera_follows_solves_the_camera_of_the_new_translation():
    T = 12
    centre, size = _boxes(T)
    old = np.stack([0.1 * np.arange(T), np.full(T, 0.3), 4.0 + 0.05 * np.arange(T)], 1)
    cam = crop_camera(old, centre, size)
    new = old.copy()
    new[::2] += [0.05, -0.03, 0.2]
    new[5] = old[5]
    out = crop_camera_follows(cam.astype(np.float32), old, new)
    assert out.dtype == np.float32
    assert np.abs(full_translation(out.astype(float), centre, size) - new).max() < 1e-4
    assert np.array_equal(out[1::2], cam[1::2].astype(np.float32))  # unmoved rows: same bits
    holed = cam.copy()
    holed[4] = np.nan  # a hole: K, c from the rows beside it (their boxes: 1 % off in size)
    out = crop_camera_follows(holed, old, new)
    assert np.abs(full_translation(out, centre, size)[4] - new[4]).max() < 0.01 * new[4, 2]
    assert crop_camera_follows(np.zeros((T, 3)), old, new) is None  # TRAM's zeros: none


def test_tram_pred_cam_follows_the_cleaned_pred_trans(tmp_path):
    T = 20
    src = vf.write_tram(tmp_path / "tram", vf.clip(T, seed=3))
    hps = {k: np.asarray(v) for k, v in load_data(src).item().items()}
    centre, size = _boxes(T)
    trans = hps["pred_trans"].reshape(T, 3).astype(float) + [0.0, 0.0, 5.0]  # in front
    hps["pred_trans"] = trans[:, None].astype(np.float32)
    hps["pred_cam"] = crop_camera(trans, centre, size).astype(np.float32)
    np.save(src, {k: torch.as_tensor(v) for k, v in hps.items()}, allow_pickle=True)
    loaded = read(src)
    new, moved = edited(loaded.tracks[0][1], every=2)
    out = tmp_path / "tram" / "hps" / "clean.npy"
    write(type(loaded)(src, "tram", "video", [(None, new)], document=loaded.document), out)
    d = {k: np.asarray(v) for k, v in load_data(out).item().items()}
    made = full_translation(d["pred_cam"].astype(float), centre, size)
    assert np.abs(made - d["pred_trans"].reshape(T, 3)).max() < 1e-4  # before: 6.1 cm
    assert np.abs(d["pred_trans"].reshape(T, 3) - trans)[moved].max() > 0.01
    assert np.array_equal(d["pred_cam"][~moved], hps["pred_cam"][~moved])


def test_phalp_camera_bbox_follows_the_cleaned_camera(tmp_path):
    T = 16
    src = vf.write_phalp(tmp_path / "demo.pkl", {1: (vf.clip(T, seed=4), list(range(T)))})
    data = load_data(src)
    centre, size = _boxes(T)
    frames = sorted(data.values(), key=lambda f: f["time"])
    for f in frames:
        t = f["time"]
        f["camera"][0] = f["camera"][0] + np.float32([0.0, 0.0, 5.0])
        cam = crop_camera(f["camera"][0][None].astype(float), centre[t : t + 1], size[t : t + 1])
        f["camera_bbox"] = [cam[0].astype(np.float32)]
    write_data(data, src, "joblib-zlib")
    loaded = read(src)
    new, moved = edited(loaded.tracks[0][1], every=2)
    write(type(loaded)(src, "phalp", "video", [(loaded.tracks[0][0], new)],
                       document=loaded.document), tmp_path / "clean.pkl")  # fmt: skip
    frames = sorted(load_data(tmp_path / "clean.pkl").values(), key=lambda f: f["time"])
    bbox = np.stack([f["camera_bbox"][0] for f in frames]).astype(float)
    camera = np.stack([f["camera"][0] for f in frames]).astype(float)
    assert np.abs(full_translation(bbox, centre, size) - camera).max() < 1e-4  # before: 5.0 cm
    before = sorted(data.values(), key=lambda f: f["time"])
    assert np.abs(camera - np.stack([f["camera"][0] for f in before]))[moved].max() > 0.01
    old = np.stack([f["camera_bbox"][0] for f in before])
    assert np.array_equal(bbox[~moved].astype(np.float32), old[~moved])
