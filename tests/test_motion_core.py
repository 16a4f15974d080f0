"""Motion files, resampling, the state vector and canonical windows."""

import datetime
import math

import numpy as np
import pytest
import torch

from mdvae_cli.errors import InputError
from mdvae_cli.formats.npz_io import load_motion, save_motion
from mdvae_cli.geometry.rotations import rotvec_slerp
from mdvae_cli.model.state import (
    POSE_VEL,
    STATE_DIM,
    TRANS_VEL,
    BodyParams,
    params_to_state,
    state_to_params,
)
from mdvae_cli.model.windows import canonicalize, heading, uncanonicalize, window_starts
from mdvae_cli.motion.motion import Motion
from mdvae_cli.motion.resample import interp_rotvec, resample_motion


def write_npz(path, **arrays):
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)
    return path


@pytest.mark.parametrize("width", [156, 165, 72, 66])
def test_npz_round_trip_keeps_layout_and_extras(tmp_path, width):
    rng = np.random.default_rng(0)
    T = 12
    poses = rng.normal(0, 0.3, (T, width)).astype(np.float32)
    src = write_npz(
        tmp_path / "in.npz",
        poses=poses,
        trans=rng.normal(size=(T, 3)),
        betas=np.arange(16.0),
        gender=np.array(b"female"),
        mocap_frame_rate=np.array(60.0),
        dmpls=np.ones((T, 8)),
        surface_model_type=np.array("smplh"),
    )
    m = load_motion(src)
    assert m.num_frames == T and m.fps == 60.0 and m.gender == "female"
    assert m.pose_body.shape == (T, 21, 3) and m.pose_extra.shape == (T, width - 66)
    np.testing.assert_allclose(m.poses, poses, atol=1e-7)
    out = tmp_path / "out.npz"
    save_motion(m, out)
    with np.load(out) as z:
        assert set(z.files) == {
            "poses",
            "trans",
            "betas",
            "gender",
            "mocap_frame_rate",
            "dmpls",
            "surface_model_type",
        }
        assert z["poses"].dtype == np.float32 and z["poses"].shape == (T, width)
        assert z["gender"].item() == b"female"
        np.testing.assert_array_equal(z["dmpls"], np.ones((T, 8)))
        assert str(z["surface_model_type"]) == "smplh"
    assert not list(tmp_path.glob(".*"))  # no temporary left behind


def test_save_refuses_to_overwrite_input(tmp_path):
    src = write_npz(tmp_path / "a.npz", poses=np.zeros((3, 66)), mocap_framerate=30.0)
    before = src.read_bytes()
    with pytest.raises(InputError, match="overwrite"):
        save_motion(load_motion(src), src, forbid=(src,))
    assert src.read_bytes() == before


@pytest.mark.parametrize(
    "arrays, message",
    [
        ({"trans": np.zeros((3, 3)), "mocap_framerate": 30.0}, "no 'poses'"),
        ({"poses": np.zeros((3, 70)), "mocap_framerate": 30.0}, "expected"),
        ({"poses": np.zeros((0, 66)), "mocap_framerate": 30.0}, "has no frames"),
        ({"poses": np.full((3, 66), np.nan), "mocap_framerate": 30.0}, "NaN"),
        ({"poses": np.zeros((3, 66)), "mocap_framerate": 0.0}, "> 0"),
        ({"poses": np.zeros((3, 66)), "mocap_framerate": -5.0}, "> 0"),
        ({"poses": np.zeros((3, 66))}, "frame rate"),
        ({"poses": np.zeros((3, 66)), "trans": np.zeros((4, 3)), "mocap_framerate": 30.0}, "trans"),
    ],
)
def test_bad_files_raise_one_line_errors(tmp_path, arrays, message):
    f = write_npz(tmp_path / "bad.npz", **arrays)
    with pytest.raises(InputError, match=message) as exc:
        load_motion(f)
    assert "\n" not in str(exc.value)


def test_not_npz_truncated_and_missing(tmp_path):
    (tmp_path / "text.npz").write_text("hello")
    good = write_npz(tmp_path / "good.npz", poses=np.zeros((50, 156)), mocap_framerate=30.0)
    (tmp_path / "cut.npz").write_bytes(good.read_bytes()[:300])
    for name in ("text.npz", "cut.npz", "missing.npz"):
        with pytest.raises(InputError):
            load_motion(tmp_path / name)


def test_pickled_arrays_of_plain_data_load_and_others_need_allow_pickle(tmp_path):
    # AMASS SMPL-X files hold a dict of marker names to vertex ids as a pickled object array
    vids = {"C7": 3832, "LFHD": 9135, "RFWT": 6544}
    f = write_npz(
        tmp_path / "p.npz",
        poses=np.zeros((3, 66)),
        mocap_framerate=30.0,
        markers_latent_vids=np.array(vids, dtype=object),
        meta=np.array([{"a": [1, 2.5, "x"]}, None], dtype=object),
    )
    m = load_motion(f)
    assert m.extras["markers_latent_vids"].item() == vids
    assert m.extras["meta"].tolist() == [{"a": [1, 2.5, "x"]}, None]
    out = tmp_path / "out.npz"
    save_motion(m, out)
    with np.load(out, allow_pickle=True) as z:  # written back as it was
        assert z["markers_latent_vids"].item() == vids
    # a pickle that builds anything but data is never run without --allow-pickle
    g = write_npz(tmp_path / "q.npz", poses=np.zeros((3, 66)), mocap_framerate=30.0,
                  meta=np.array([datetime.date(2020, 1, 1)], dtype=object))  # fmt: skip
    with pytest.raises(InputError, match="not plain data.*allow-pickle"):
        load_motion(g)
    assert load_motion(g, allow_pickle=True).num_frames == 3


def test_resample_constant_speed_rotation_and_translation():
    T, fps = 121, 120.0
    t = np.arange(T) / fps
    pose_body = np.zeros((T, 21, 3))
    pose_body[:, 3, 2] = 1.5 * t  # 1.5 rad/s about z
    m = Motion(
        root_orient=np.zeros((T, 3)),
        pose_body=pose_body,
        trans=np.stack([2.0 * t, 0 * t, 0 * t], 1),
        betas=np.zeros(10),
        fps=fps,
    )
    r = resample_motion(m, 30.0)
    assert r.num_frames == 31 and r.fps == 30.0
    t30 = np.arange(31) / 30.0
    np.testing.assert_allclose(r.pose_body[:, 3, 2], 1.5 * t30, atol=1e-9)
    np.testing.assert_allclose(r.trans[:, 0], 2.0 * t30, atol=1e-9)
    back = resample_motion(r, 120.0)
    np.testing.assert_allclose(back.pose_body[:, 3, 2], 1.5 * t, atol=1e-9)


def test_interp_rotvec_on_frames_is_the_slerp_without_working_it_out():
    """Times on a frame (a 120 Hz take read at 30 Hz) take the frame as the slerp gives it
    back, wrapped to at most half a turn; times between frames are slerped."""
    rng = np.random.default_rng(0)
    r = rng.normal(size=(40, 5, 3)) * 2.0  # about half of them past half a turn
    assert (np.linalg.norm(r, axis=-1) > np.pi).mean() > 0.3
    at = np.concatenate([np.arange(0, 40, 4.0), [0.5, 2.25, 38.9, 39.0, -0.5]])
    i0 = np.clip(np.floor(at).astype(int), 0, 39)  # before the first frame: extrapolated
    i1 = np.minimum(i0 + 1, 39)
    R = torch.as_tensor(r)
    w = torch.as_tensor(at - i0)[:, None].expand(len(at), 5)
    want = rotvec_slerp(R[i0], R[i1], w).numpy()
    got = interp_rotvec(r, at)
    np.testing.assert_allclose(got, want, atol=1e-12)
    assert np.linalg.norm(got, axis=-1).max() <= np.pi + 1e-12


def test_state_round_trip_and_velocities():
    T, fps = 20, 30.0
    g = torch.Generator().manual_seed(0)
    p = BodyParams(
        torch.randn(T, 3, generator=g, dtype=torch.float64),
        torch.randn(T, 21, 3, generator=g, dtype=torch.float64),
        torch.randn(T, 3, generator=g, dtype=torch.float64),
    )
    x = params_to_state(p, fps)
    assert x.shape == (T, STATE_DIM)
    back = state_to_params(x)
    for a, b in (
        (p.root_orient, back.root_orient),
        (p.pose_body, back.pose_body),
        (p.trans, back.trans),
    ):
        torch.testing.assert_close(a, b)
    torch.testing.assert_close(x[3, TRANS_VEL], (p.trans[3] - p.trans[2]) * fps)
    torch.testing.assert_close(x[0, POSE_VEL], x[1, POSE_VEL])  # forward difference at t=0
    # linear motion: constant velocity
    lin = BodyParams(
        p.root_orient * 0,
        p.pose_body * 0,
        torch.arange(T, dtype=torch.float64)[:, None] * torch.tensor([0.1, 0, 0]),
    )
    v = params_to_state(lin, fps)[:, TRANS_VEL]
    torch.testing.assert_close(v, torch.tensor([3.0, 0, 0], dtype=torch.float64).expand(T, 3))


def test_canonicalize_round_trip_and_canonical_pose():
    B, T = 3, 10
    g = torch.Generator().manual_seed(1)
    root = torch.randn(B, T, 3, generator=g, dtype=torch.float64)
    p = BodyParams(
        root,
        0.3 * torch.randn(B, T, 21, 3, generator=g, dtype=torch.float64),
        torch.randn(B, T, 3, generator=g, dtype=torch.float64),
    )
    pelvis = torch.randn(B, 3, generator=g, dtype=torch.float64) * 0.2
    canon, frame = canonicalize(p, pelvis)
    torch.testing.assert_close(
        heading(canon.root_orient[:, 0]), torch.zeros(B, dtype=torch.float64), atol=1e-9, rtol=0
    )
    world_pelvis0 = canon.trans[:, 0] + pelvis
    torch.testing.assert_close(
        world_pelvis0[:, :2], torch.zeros(B, 2, dtype=torch.float64), atol=1e-9, rtol=0
    )
    # height kept
    torch.testing.assert_close(world_pelvis0[:, 2], (p.trans[:, 0] + pelvis)[:, 2])
    back = uncanonicalize(canon, frame, pelvis)
    torch.testing.assert_close(back.trans, p.trans)
    from mdvae_cli.geometry.rotations import rotvec_to_rotmat

    torch.testing.assert_close(rotvec_to_rotmat(back.root_orient), rotvec_to_rotmat(p.root_orient))
    torch.testing.assert_close(rotvec_to_rotmat(back.pose_body), rotvec_to_rotmat(p.pose_body))


def test_chunk_state_pair_matches_two_separate_passes(tiny_body):
    """Canonicalising the inputs and the raw chunks together (one pass) gives what two passes
    give: the inputs in their own frames, the raw chunks in the inputs' frames, plain
    differences for the raw velocities."""
    from mdvae_cli.body.skinning import BodyModel
    from mdvae_cli.model.chunks import chunk_state_pair, chunk_states

    body = BodyModel(tiny_body)
    B, T = 3, 12
    g = torch.Generator().manual_seed(4)
    raw = BodyParams(
        torch.randn(B, T, 3, generator=g),
        0.3 * torch.randn(B, T, 21, 3, generator=g),
        torch.randn(B, T, 3, generator=g),
    )
    smooth = lambda a: (a + a.roll(1, dims=1) + a.roll(-1, dims=1)) / 3  # noqa: E731
    inputs = BodyParams(smooth(raw.root_orient), smooth(raw.pose_body), smooth(raw.trans))
    betas = 0.5 * torch.randn(B, 10, generator=g)
    states, raw_states, frame = chunk_state_pair(inputs, raw, betas, body, velocity_window=5)
    want, want_frame = chunk_states(inputs, betas, body, velocity_window=5)
    want_raw, _ = chunk_states(raw, betas, body, frame=want_frame)
    torch.testing.assert_close(states, want)
    torch.testing.assert_close(raw_states, want_raw)
    torch.testing.assert_close(frame.yaw, want_frame.yaw)
    torch.testing.assert_close(frame.origin, want_frame.origin)
    assert not torch.allclose(raw_states, states)


def test_window_starts_cover_every_frame():
    assert window_starts(50, 61, 30) == [0]
    starts = window_starts(200, 61, 40)
    assert starts[0] == 0 and starts[-1] == 200 - 61
    covered = set()
    for s in starts:
        covered.update(range(s, s + 61))
    assert covered == set(range(200))
    assert math.isclose(len(starts), 5)


def test_smoothed_difference_is_exact_on_lines_and_damps_noise():
    from mdvae_cli.model.state import finite_difference, smoothed_difference

    t = torch.arange(25, dtype=torch.float64)[:, None] * torch.tensor([0.5, -1.0])
    v = smoothed_difference(t, 30.0, 9)
    torch.testing.assert_close(v, torch.tensor([15.0, -30.0], dtype=torch.float64).expand(25, 2))
    noise = torch.randn(2000, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    ratio = smoothed_difference(noise, 30.0, 9).std() / finite_difference(noise, 30.0).std()
    assert ratio < 0.15  # theory: sqrt(1 / (2 * sum k^2)) = 0.13 for 9 frames
    torch.testing.assert_close(smoothed_difference(noise, 30.0, 1), finite_difference(noise, 30.0))
