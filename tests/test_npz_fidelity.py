"""npz outputs keep the input's layout: keys and their order, dtypes, shapes, compression, and
SMPL-X "stage-ii" split pose arrays (root_orient, pose_body, ...) consistent with ``poses``."""

from __future__ import annotations

import gzip
import zipfile

import numpy as np
import pytest
from click.testing import CliRunner

from mdvae_cli.cli.main import cli
from mdvae_cli.errors import InputError
from mdvae_cli.formats.npz_io import load_motion, save_motion
from mdvae_cli.motion.noise import add_pose_noise
from mdvae_cli.motion.resample import resample_motion

T = 12


def stage_ii_arrays(seed: int = 0, poses_dtype=np.float64) -> dict[str, np.ndarray]:
    """An AMASS SMPL-X stage-ii style file: ``poses`` (T, 165) = root, body, jaw, eyes, hands,
    with split copies of each part; float32 trans and per-frame betas; keys in MoSh++'s order."""
    rng = np.random.default_rng(seed)
    poses = rng.normal(0, 0.3, (T, 165)).astype(poses_dtype)
    return {
        "gender": np.array("female"),
        "surface_model_type": np.array("smplx"),
        "mocap_frame_rate": np.array(120.0),
        "mocap_time_length": np.array(T / 120.0),
        "markers_latent": rng.normal(size=(41, 3)),
        "trans": rng.normal(size=(T, 3)).astype(np.float32),
        "poses": poses,
        "betas": np.tile(rng.normal(size=16), (T, 1)).astype(np.float32),
        "num_betas": np.array(16),
        "root_orient": poses[:, :3].astype(np.float32),
        "pose_body": poses[:, 3:66].astype(np.float32),
        "pose_hand": poses[:, 75:165].astype(np.float32),
        "pose_jaw": poses[:, 66:69].astype(np.float32),
        "pose_eye": poses[:, 69:75].astype(np.float32),
    }


def write(path, arrays, compressed=False):
    (np.savez_compressed if compressed else np.savez)(path, **arrays)
    return path


def read(path) -> dict[str, np.ndarray]:
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def compress_types(path) -> set[int]:
    with zipfile.ZipFile(path) as zf:
        return {i.compress_type for i in zf.infolist()}


def assert_same_layout(out: dict, ref: dict, new_keys: tuple[str, ...] = ()):
    assert list(out) == [*ref, *new_keys]
    for k, v in ref.items():
        assert (out[k].dtype, out[k].shape) == (v.dtype, v.shape), k


def assert_split_consistent(out: dict):
    p = out["poses"].astype(np.float64)
    for key, cols in [("root_orient", slice(0, 3)), ("pose_body", slice(3, 66)),
                      ("pose_jaw", slice(66, 69)), ("pose_eye", slice(69, 75)),
                      ("pose_hand", slice(75, 165))]:  # fmt: skip
        got = out[key].reshape(len(p), -1).astype(np.float64)
        np.testing.assert_allclose(got, p[:, cols], atol=1e-6, err_msg=key)


@pytest.mark.parametrize("compressed", [False, True])
def test_round_trip_keeps_keys_order_dtypes_shapes_and_compression(tmp_path, compressed):
    ref = stage_ii_arrays()
    src = write(tmp_path / "in.npz", ref, compressed)
    before = src.read_bytes()
    m = load_motion(src)
    assert m.betas.shape == (16,) and m.notes == []
    save_motion(m, tmp_path / "out.npz", forbid=(src,))
    out = read(tmp_path / "out.npz")
    assert_same_layout(out, ref)
    for k, v in ref.items():  # nothing changed, so every value comes back exactly
        np.testing.assert_array_equal(out[k], v, err_msg=k)
    want = {zipfile.ZIP_DEFLATED} if compressed else {zipfile.ZIP_STORED}
    assert compress_types(tmp_path / "out.npz") == want
    assert src.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.npz", "out.npz"]  # no temporaries


def test_compressed_output_is_about_the_input_size(tmp_path):
    ref = {**stage_ii_arrays(), "dmpls": np.zeros((2000, 8))}  # compresses well
    src = write(tmp_path / "in.npz", ref, compressed=True)
    save_motion(load_motion(src), tmp_path / "out.npz")
    assert (tmp_path / "out.npz").stat().st_size < 1.2 * src.stat().st_size


def test_float64_poses_do_not_widen_float32_trans_and_betas(tmp_path):
    rng = np.random.default_rng(1)
    ref = {
        "poses": rng.normal(0, 0.3, (T, 156)),
        "trans": rng.normal(size=(T, 3)).astype(np.float32),
        "betas": rng.normal(size=(1, 10)).astype(np.float32),
        "mocap_framerate": np.array(30, dtype=np.int64),
        "gender": np.array([b"male"]),
    }
    m = load_motion(write(tmp_path / "in.npz", ref))
    save_motion(m.with_body(trans=m.trans + 1.0), tmp_path / "out.npz")
    out = read(tmp_path / "out.npz")
    assert_same_layout(out, ref)
    np.testing.assert_allclose(out["trans"], ref["trans"] + 1.0, atol=1e-6)
    assert out["mocap_framerate"] == 30 and out["gender"][0] == b"male"


@pytest.mark.parametrize(
    "stored, text", [(np.array("Female "), "Female"), (np.array([b" male\n"]), "male")]
)
def test_a_gender_with_spaces_is_read_stripped_and_written_as_it_came(tmp_path, stored, text):
    ref = {**stage_ii_arrays(), "gender": stored}
    m = load_motion(write(tmp_path / "in.npz", ref))
    assert m.gender == text
    save_motion(m.with_body(trans=m.trans + 1.0), tmp_path / "out.npz")
    out = read(tmp_path / "out.npz")
    assert out["gender"].dtype == stored.dtype and np.array_equal(out["gender"], stored)
    m.gender = "neutral"  # a gender changed is written as it is
    save_motion(m, tmp_path / "changed.npz")
    assert read(tmp_path / "changed.npz")["gender"].reshape(-1)[0] in ("neutral", b"neutral")


def test_per_frame_betas_keep_their_layout(tmp_path):
    ref = stage_ii_arrays()
    ref["betas"] = ref["betas"] + np.linspace(0, 0.1, T, dtype=np.float32)[:, None]
    m = load_motion(write(tmp_path / "in.npz", ref))
    np.testing.assert_allclose(m.betas, ref["betas"].mean(0), atol=1e-6)
    assert any("per-frame 'betas'" in n and "mean" in n for n in m.notes)
    save_motion(m, tmp_path / "out.npz")
    np.testing.assert_array_equal(read(tmp_path / "out.npz")["betas"], ref["betas"])
    # another frame count (resampled): one row per new frame, each the shape used
    save_motion(resample_motion(m, 30.0), tmp_path / "r.npz")
    out = read(tmp_path / "r.npz")
    n = out["poses"].shape[0]
    assert out["betas"].shape == (n, 16) and out["betas"].dtype == np.float32
    np.testing.assert_allclose(out["betas"], np.tile(m.betas, (n, 1)), atol=1e-6)
    assert_split_consistent(out)
    assert out["pose_body"].shape == (n, 63)


@pytest.mark.parametrize("body_shape", [(T, 63), (T, 21, 3)])
def test_split_arrays_follow_a_body_change(tmp_path, body_shape):
    ref = stage_ii_arrays()
    ref["pose_body"] = ref["pose_body"].reshape(body_shape)
    m = load_motion(write(tmp_path / "in.npz", ref, compressed=True))
    changed = m.with_body(root_orient=m.root_orient + 0.2, pose_body=m.pose_body * 0.5)
    save_motion(changed, tmp_path / "out.npz")
    out = read(tmp_path / "out.npz")
    assert_same_layout(out, ref)
    assert_split_consistent(out)
    np.testing.assert_allclose(out["pose_body"].reshape(T, 63), ref["poses"][:, 3:66] * 0.5,
                               atol=1e-6)  # fmt: skip
    for key in ("pose_hand", "pose_jaw", "pose_eye"):
        np.testing.assert_array_equal(out[key], ref[key])


def test_add_noise_cli_noises_the_split_arrays_too(tmp_path):
    ref = stage_ii_arrays()
    src = write(tmp_path / "in.npz", ref, compressed=True)
    before = src.read_bytes()
    result = CliRunner().invoke(
        cli, ["add-noise", str(src), "-o", str(tmp_path / "noisy.npz"), "--sigma", "0.1"]
    )
    assert result.exit_code == 0, result.output
    out = read(tmp_path / "noisy.npz")
    assert_same_layout(out, ref)
    assert_split_consistent(out)
    assert np.abs(out["pose_body"] - ref["pose_body"]).mean() > 0.05
    assert compress_types(tmp_path / "noisy.npz") == {zipfile.ZIP_DEFLATED}
    assert src.read_bytes() == before


def test_new_keys_go_last(tmp_path):
    ref = stage_ii_arrays()
    m = load_motion(write(tmp_path / "in.npz", ref))
    noisy = add_pose_noise(m, 0.1, np.random.default_rng(0), drop_frac=0.1)
    save_motion(noisy, tmp_path / "out.npz")
    out = read(tmp_path / "out.npz")
    assert_same_layout(out, ref, new_keys=("joint_mask",))
    assert_split_consistent(out)


def test_disagreeing_split_arrays_poses_wins_and_it_is_noted(tmp_path):
    ref = stage_ii_arrays()
    ref["pose_body"] = ref["pose_body"] + np.float32(0.59)
    ref["pose_hand"] = ref["pose_hand"] + np.float32(0.3)  # another hand layout: kept as is
    m = load_motion(write(tmp_path / "in.npz", ref))
    np.testing.assert_allclose(m.pose_body.reshape(T, 63), ref["poses"][:, 3:66])
    assert any("'pose_body' differs" in n and "0.59" in n for n in m.notes)
    assert any("'pose_hand' differs" in n and "kept" in n for n in m.notes)
    save_motion(m, tmp_path / "out.npz")
    out = read(tmp_path / "out.npz")
    assert_same_layout(out, ref)
    np.testing.assert_allclose(out["pose_body"], ref["poses"][:, 3:66], atol=1e-6)
    np.testing.assert_array_equal(out["pose_hand"], ref["pose_hand"])


@pytest.mark.parametrize("hands", [True, False])
def test_file_with_split_arrays_only(tmp_path, hands):
    ref = stage_ii_arrays()
    del ref["poses"]
    if not hands:
        for key in ("pose_hand", "pose_jaw", "pose_eye"):
            del ref[key]
    m = load_motion(write(tmp_path / "in.npz", ref))
    assert m.poses.shape == (T, 165 if hands else 66)
    np.testing.assert_allclose(m.pose_body.reshape(T, 63), ref["pose_body"])
    np.testing.assert_allclose(m.root_orient, ref["root_orient"])
    save_motion(m.with_body(pose_body=m.pose_body + 0.1), tmp_path / "out.npz")
    out = read(tmp_path / "out.npz")
    assert_same_layout(out, ref)  # no 'poses' added
    np.testing.assert_allclose(out["pose_body"], ref["pose_body"] + 0.1, atol=1e-6)
    if hands:
        np.testing.assert_array_equal(out["pose_hand"], ref["pose_hand"])


def test_split_only_file_missing_body_array_is_an_input_error(tmp_path):
    ref = stage_ii_arrays()
    del ref["poses"], ref["pose_body"]
    with pytest.raises(InputError, match="no 'poses' array, nor 'root_orient' and 'pose_body'"):
        load_motion(write(tmp_path / "in.npz", ref))


def test_a_gzipped_npz_a_folder_yields_is_read_and_written_without_gz(tmp_path):
    ref = stage_ii_arrays()
    plain = write(tmp_path / "plain.npz", ref, compressed=True)
    folder = tmp_path / "takes"
    folder.mkdir()
    gz = folder / "take.npz.gz"
    gz.write_bytes(gzip.compress(plain.read_bytes()))
    before = gz.read_bytes()
    a, b = load_motion(plain), load_motion(gz)
    np.testing.assert_array_equal(a.poses, b.poses)
    np.testing.assert_array_equal(a.trans, b.trans)
    assert (b.fps, b.layout["compressed"]) == (120.0, True)
    out = tmp_path / "out"
    res = CliRunner().invoke(cli, ["add-noise", str(folder), "-o", str(out), "--sigma", "0"])
    assert res.exit_code == 0, res.output
    assert [p.name for p in out.iterdir()] == ["take.npz"] and gz.read_bytes() == before
    assert_same_layout(read(out / "take.npz"), ref)
    res = CliRunner().invoke(cli, ["eval", "--gt", str(folder), "--pred", str(out), "--json"])
    assert res.exit_code == 0 and '"failed": 0' in res.output  # take.npz.gz pairs take.npz
    (folder / "bad.npz.gz").write_bytes(b"not gzip data")
    with pytest.raises(InputError, match=r"bad\.npz\.gz: not a readable \.gz file"):
        load_motion(folder / "bad.npz.gz")
