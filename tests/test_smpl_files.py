"""SMPL-family motion files and users' body models as vision researchers bring them.

Axis-angles past pi come back on the file's own branches; hands and face are posed by a body
model of another layout (an SMPL-H take on SMPL-X and back); a motion file given as the body
model, and an AMASS-style pickle, are told apart in one line.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mdvae_cli.formats.npz_io import load_motion, save_motion
from mdvae_cli.geometry.rotations_np import rotmat_to_rotvec, rotvec_nearest, rotvec_to_rotmat


def turning_take(T: int = 60) -> dict[str, np.ndarray]:
    """A root turning 1.5 times about z with its axis-angle kept continuous (a solver's free
    parameters: its length runs past pi up to 3 pi), the body joints small."""
    yaw = np.linspace(0.3, 3 * np.pi, T)
    rng = np.random.default_rng(0)
    poses = np.zeros((T, 156))
    poses[:, 2] = yaw  # about z: one axis, so the continuous branch is the angle itself
    poses[:, 3:66] = rng.normal(size=(T, 63)) * 0.1
    trans = np.stack([np.cos(yaw), np.sin(yaw), np.full(T, 0.9)], axis=1)
    return {"poses": poses, "trans": trans, "betas": np.zeros(16), "mocap_framerate": 30.0}


def test_rotvec_nearest_takes_the_branch_nearest_the_reference():
    z = np.array([0.0, 0.0, 1.0])
    rotvecs = np.stack([z * 3.1414, z * 0.3, z * 0.3, z * 0.0])
    out = rotvec_nearest(rotvecs, np.stack([-z * 3.1407, z * (0.3 + 2 * np.pi), z * np.nan, z * 6]))
    np.testing.assert_allclose(out[0], -z * (2 * np.pi - 3.1414), atol=1e-12)  # the flip
    np.testing.assert_allclose(out[1], z * (0.3 + 2 * np.pi), atol=1e-12)  # a full turn on
    np.testing.assert_array_equal(out[2], z * 0.3)  # a hole's NaN: kept
    np.testing.assert_array_equal(out[3], np.zeros(3))  # no axis: kept
    np.testing.assert_allclose(rotvec_to_rotmat(out), rotvec_to_rotmat(rotvecs), atol=1e-12)


def test_a_root_past_pi_comes_back_on_its_own_branches(tmp_path):
    """Was: every frame past pi rewritten on [0, pi] (up to 2 pi off the file's numbers, the
    root jumping 5.5 rad between frames where the file steps 0.2); the rotations were right."""
    src = tmp_path / "turn.npz"
    np.savez(src, **turning_take())
    motion = load_motion(src)
    # what denoising does to a pose: through rotation matrices, back on [0, pi]
    motion.root_orient = rotmat_to_rotvec(rotvec_to_rotmat(motion.root_orient))
    motion.pose_body = rotmat_to_rotvec(rotvec_to_rotmat(motion.pose_body))
    assert np.linalg.norm(motion.root_orient, axis=1).max() <= np.pi + 1e-9
    save_motion(motion, tmp_path / "out.npz")
    back = np.load(tmp_path / "out.npz")["poses"]
    np.testing.assert_allclose(back, np.load(src)["poses"], atol=1e-9)
    assert np.abs(np.diff(back[:, :3], axis=0)).max() < 0.2


def test_a_file_within_pi_is_written_as_computed(tmp_path):
    arrays = turning_take()
    arrays["poses"][:, 2] = np.linspace(0.1, 2.5, 60)
    np.savez(tmp_path / "in.npz", **arrays)
    motion = load_motion(tmp_path / "in.npz")
    assert motion.layout["branches"] is None  # nothing kept for a file that never nears pi


def synthetic_body(J: int):
    """A small SMPL-H (52 joints) or SMPL-X (55) model, as a loader would build it."""
    from test_body_formats import synthetic

    from mdvae_cli.body.data import BodyModelData
    from mdvae_cli.body.formats import SMPLH_JOINT_NAMES, SMPLX_JOINT_NAMES

    a = synthetic(J)
    parents = a["kintree_table"][0].astype(np.int64)
    parents[0] = -1
    return BodyModelData(
        kind="smplh" if J == 52 else "smplx", v_template=a["v_template"],
        shapedirs=a["shapedirs"], posedirs=a["posedirs"], J_regressor=a["J_regressor"],
        weights=a["weights"], parents=parents, faces=a["f"].astype(np.int64),
        joint_names=SMPLH_JOINT_NAMES if J == 52 else SMPLX_JOINT_NAMES,
        marker_vertex_ids=np.arange(43) % len(a["v_template"]), name=f"model{J}",
    ).validate()  # fmt: skip


def test_extra_pose_takes_the_hands_across_layouts():
    from mdvae_cli.export import extra_pose

    hands = np.arange(2 * 90, dtype=float).reshape(2, 90)
    smplx = np.concatenate([np.full((2, 9), -1.0), hands], axis=1)  # jaw, eyes, then hands
    np.testing.assert_array_equal(
        extra_pose(hands, 33), np.concatenate([np.zeros((2, 9)), hands], 1)
    )
    np.testing.assert_array_equal(extra_pose(smplx, 30), hands)
    np.testing.assert_array_equal(extra_pose(smplx, 33), smplx)
    assert extra_pose(hands, 2) is None and extra_pose(np.zeros((2, 6)), 30) is None
    assert extra_pose(np.zeros((2, 0)), 0) is None


def test_an_smplh_take_keeps_its_hands_on_an_smplx_model_and_back():
    """Was: an SMPL-H take's hands (poses 156) posed at rest by an SMPL-X --body-model and an
    SMPL-X take's (165) by an SMPL-H one: export-mesh and eval dropped them silently."""
    from mdvae_cli.export import pose_motion_chunks
    from mdvae_cli.motion.motion import Motion

    rng = np.random.default_rng(1)
    body, hands = rng.normal(size=(3, 66)) * 0.2, rng.normal(size=(3, 90)) * 0.3
    face = rng.normal(size=(3, 9)) * 0.1
    trans = np.zeros((3, 3))

    def vertices(poses, model):
        motion = Motion.from_poses(poses, trans, np.zeros(10), 30.0)
        return next(pose_motion_chunks(motion, model))[1].vertices.numpy()

    smplx_model, smplh_model = synthetic_body(55), synthetic_body(52)
    smplh_take = np.concatenate([body, hands], axis=1)
    smplx_take = np.concatenate([body, np.zeros((3, 9)), hands], axis=1)
    np.testing.assert_allclose(vertices(smplh_take, smplx_model), vertices(smplx_take, smplx_model))
    at_rest = vertices(np.concatenate([body, np.zeros((3, 90))], axis=1), smplx_model)
    assert np.abs(vertices(smplh_take, smplx_model) - at_rest).max() > 1e-3  # the hands count
    smplx_take[:, 66:75] = face  # SMPL-X's face has no joints on SMPL-H: its hands still do
    np.testing.assert_allclose(vertices(smplx_take, smplh_model), vertices(smplh_take, smplh_model))


def test_a_motion_file_given_as_the_body_model_is_named_so(tmp_path):
    """Was: `missing 'v_template', 'shapedirs', 'posedirs', 'J_regressor', 'weights',
    'kintree_table', 'f'` for an AMASS take passed to --body-model by mistake."""
    from click.testing import CliRunner

    from mdvae_cli.cli.main import cli

    take = tmp_path / "take.npz"
    np.savez(take, **turning_take(8))
    other = tmp_path / "other.npz"
    np.savez(other, a=np.zeros(3))
    for model, what in ((take, "a motion file (it holds 'poses', 'trans'), not a body model"),
                        (other, "not a body model (none of 'v_template',")):  # fmt: skip
        result = CliRunner().invoke(
            cli, ["export-mesh", str(take), "-o", str(tmp_path / "m"), "--body-model", str(model)]
        )
        assert result.exit_code == 1
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"error: body model {model.name}: {what}")
        assert "SMPL-X model file" in lines[0] and not (tmp_path / "m").exists()


def test_smpl_arrays_in_a_pickle_are_refused_with_the_way_to_an_npz(tmp_path):
    """Was: `not a motion layout this tool knows (give --format: amass, wham, ...)`, and with
    --format amass `not an .npz archive`."""
    import pickle

    from mdvae_cli.errors import InputError
    from mdvae_cli.formats.registry import ReadOptions, read

    take = turning_take(8)
    dumps = {
        "amass.pkl": (take, "AMASS-style arrays in a pickle: mdvae reads them as an AMASS"),
        "smplify.pkl": (
            {
                "global_orient": take["poses"][:, :3],
                "body_pose": take["poses"][:, 3:72],
                "transl": take["trans"],
                "betas": np.zeros((1, 10)),
            },
            r"SMPL parameters \('global_orient', 'body_pose'\) in a layout mdvae does not know",
        ),  # fmt: skip
        "other.pkl": (
            {"a": 1},
            r"one of wham, gvhmr, .*aistpp: denoise, add-noise and "
            r"import read it with --format\)$",
        ),
    }
    for name, (content, message) in dumps.items():
        path = tmp_path / name
        path.write_bytes(pickle.dumps(content))
        with pytest.raises(InputError, match=message):
            read(path)
        with pytest.raises(InputError, match="--format amass reads AMASS-style .npz files only"):
            read(path, ReadOptions(format="amass"))


CMU_BVH = Path(__file__).resolve().parents[2] / "shared" / "data" / "cmu" / "bvh" / "05_08.bvh.gz"


@pytest.mark.skipif(not CMU_BVH.is_file(), reason=f"no CMU BVH at {CMU_BVH}")
def test_import_names_the_body_model_its_betas_belong_to():
    """Was: an import onto --body-model wrote its betas (300 for SMPL-X) with no word of whose
    shape space they are in."""
    import dataclasses

    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.formats.registry import ReadOptions, read

    body = dataclasses.replace(load_body_model(None), name="SMPLX_NEUTRAL.npz")
    for given, name in ((None, "builtin"), (body, "SMPLX_NEUTRAL.npz")):
        motion = read(CMU_BVH, ReadOptions(resample=30.0, body=given)).single()
        assert json.loads(str(motion.extras["source"]))["body_model"] == name


def test_an_smpl_pickle_saved_as_npz_keeps_its_sparse_regressor(tmp_path, monkeypatch):
    """Was: `'J_regressor' holds pickled Python objects; they are never loaded` for an SMPL
    .pkl converted with np.savez(**model) (its scipy.sparse regressor pickled in the .npy),
    which the .pkl itself loads; the pickle is read as the .pkl's is, nothing run."""
    import os
    import pickle

    sparse = pytest.importorskip("scipy.sparse")
    from test_body_formats import synthetic

    import mdvae_cli.body.markers as markers
    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.errors import InputError

    monkeypatch.setattr(markers, "place_markers", lambda v, j: np.arange(43) % len(v))
    arrays = synthetic(24)
    model = {**arrays, "J_regressor": sparse.csc_matrix(arrays["J_regressor"]), "bs_style": "lbs"}
    (tmp_path / "SMPL_NEUTRAL.pkl").write_bytes(pickle.dumps(model, protocol=2))
    np.savez(tmp_path / "SMPL_NEUTRAL.npz", **model)  # J_regressor: a 0-d object array
    from_npz = load_body_model(tmp_path / "SMPL_NEUTRAL.npz")
    from_pkl = load_body_model(tmp_path / "SMPL_NEUTRAL.pkl")
    np.testing.assert_array_equal(from_npz.J_regressor, arrays["J_regressor"])
    np.testing.assert_array_equal(from_npz.J_regressor, from_pkl.J_regressor)

    class Runs:
        def __reduce__(self):
            return (os.remove, (str(tmp_path / "SMPL_NEUTRAL.pkl"),))

    np.savez(tmp_path / "evil.npz", **{**model, "J_regressor": np.array(Runs(), dtype=object)})
    with pytest.raises(InputError, match=r"evil.npz: 'J_regressor': refusing to load 'posix"):
        load_body_model(tmp_path / "evil.npz")
    assert (tmp_path / "SMPL_NEUTRAL.pkl").exists()


def test_an_npz_without_a_frame_rate_is_read_at_the_fps_given(tmp_path):
    """Was: `no frame rate ('mocap_framerate' or 'mocap_frame_rate')` with --fps 120 given too:
    such a file (research code saving poses, trans, betas alone) could not be read at all."""
    from mdvae_cli.errors import InputError
    from mdvae_cli.formats.registry import ReadOptions, read, write

    arrays = turning_take(12)
    del arrays["mocap_framerate"]
    np.savez(tmp_path / "take.npz", **arrays)
    with pytest.raises(InputError, match=r"no frame rate .*; give it with --fps"):
        read(tmp_path / "take.npz")
    motion = read(tmp_path / "take.npz", ReadOptions(fps=120)).single()
    assert motion.fps == 120.0 and not [n for n in motion.notes if "frame rate" in n]
    write(motion, tmp_path / "out.npz")
    out = np.load(tmp_path / "out.npz")
    assert list(out) == ["poses", "trans", "betas", "mocap_framerate"]  # the new key last
    assert float(out["mocap_framerate"]) == 120.0


@pytest.mark.parametrize(
    "key, scale, message",
    [
        ("J_regressor", 0, r"'J_regressor' rows must each sum to about 1; joint 0's sums to 0 "),
        ("weights", 0, r"'weights' rows must each sum to about 1; vertex 0's sums to 0 "),
        ("weights", 2, r"'weights' rows must each sum to about 1; vertex 0's sums to 2 "),
        ("v_template", 1000, r"the rest mesh spans [0-9.]+ m; .* \(is it in another unit\?\)"),
    ],
)
def test_a_model_with_no_body_values_is_refused(tmp_path, monkeypatch, key, scale, message):
    """Was: a zeroed regressor (every joint at the origin), zeroed or doubled skinning weights
    (the mesh collapsed or scaled) and a mesh in millimetres loaded silently; every command
    then posed garbage."""
    from test_body_formats import synthetic

    import mdvae_cli.body.markers as markers
    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.errors import InputError

    monkeypatch.setattr(markers, "place_markers", lambda v, j: np.arange(43) % len(v))
    arrays = synthetic(52, S=16)
    np.savez(tmp_path / "model.npz", **arrays)
    assert load_body_model(tmp_path / "model.npz").kind == "smplh"
    np.savez(tmp_path / "bad.npz", **{**arrays, key: arrays[key] * scale})
    with pytest.raises(InputError, match=f"body model bad.npz: {message}"):
        load_body_model(tmp_path / "bad.npz")


def test_trans_or_betas_a_file_lacks_are_added_only_when_not_zero(tmp_path):
    """Was: a file without 'betas' came back with betas = zeros(10), and one without 'trans'
    with zeros (T, 3), though nothing had set them."""
    from mdvae_cli.formats.npz_io import load_motion, save_motion

    arrays = turning_take(10)
    del arrays["betas"], arrays["trans"]
    np.savez(tmp_path / "take.npz", **arrays)
    motion = load_motion(tmp_path / "take.npz")
    motion.pose_body = motion.pose_body + 0.01  # the pose cleaned, shape and place untouched
    save_motion(motion, tmp_path / "out.npz")
    assert list(np.load(tmp_path / "out.npz")) == ["poses", "mocap_framerate"]
    motion.trans = motion.trans + [0.0, 0.0, 0.01]  # the root moved: written, last
    save_motion(motion, tmp_path / "out.npz")
    out = np.load(tmp_path / "out.npz")
    assert list(out) == ["poses", "mocap_framerate", "trans"]
    np.testing.assert_allclose(out["trans"][:, 2], 0.01)


def test_hands_a_tracker_never_saw_do_not_refuse_the_take(tmp_path):
    """Was: `'poses' contains NaN or infinite values in every frame of a hand/face column`,
    the whole take refused for hands it does not clean; and NaN in hand columns alone gave
    `NaN or infinite values in 0 of 20 frame(s) ... marked missing in joint_mask` and an
    all-True 'joint_mask' the file did not have."""
    from mdvae_cli.formats.npz_holes import keep_holes

    arrays = turning_take(20)
    arrays["poses"][:, 66:111] = np.nan  # the left hand never seen
    np.savez(tmp_path / "no_left_hand.npz", **arrays)
    motion = load_motion(tmp_path / "no_left_hand.npz")
    assert motion.notes == ["45 hand/face column(s) NaN or infinite in every frame: at rest (0)"]
    assert motion.joint_mask is None and np.all(motion.pose_extra[:, :45] == 0)
    np.testing.assert_array_equal(motion.pose_extra[:, 45:], arrays["poses"][:, 111:])
    save_motion(keep_holes(motion), tmp_path / "off.npz")  # --fill off: the NaN as they came
    np.testing.assert_array_equal(np.load(tmp_path / "off.npz")["poses"], arrays["poses"])

    arrays = turning_take(20)
    arrays["poses"][5:9, 66:] = np.nan  # hands lost for four frames
    np.savez(tmp_path / "hands_lost.npz", **arrays)
    motion = load_motion(tmp_path / "hands_lost.npz")
    assert motion.notes == ["NaN or infinite values in 90 hand/face column(s) interpolated"]
    save_motion(motion, tmp_path / "out.npz")
    assert "joint_mask" not in np.load(tmp_path / "out.npz")


def test_a_batch_of_motions_is_refused_saying_so(tmp_path):
    """Was: `'poses' has shape (2, 12, 156), expected (T, 156/165/72/66)` alone."""
    from mdvae_cli.errors import InputError

    take = turning_take(12)
    np.savez(tmp_path / "batch.npz", **{**take, "poses": np.stack([take["poses"]] * 2)})
    with pytest.raises(InputError, match=r"\(2, 12, 156\), expected .*: a batch of 2; save each"):
        load_motion(tmp_path / "batch.npz")
