"""A video pipeline's file written back in its own form (``formats.video_back``, through
``formats.registry.write`` and ``mdvae denoise`` / ``add-noise``)."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch
import video_files as vf
from click.testing import CliRunner
from video_files import edited, same_rotations

from mdvae_cli.cli.main import cli
from mdvae_cli.errors import InputError
from mdvae_cli.formats.data_files import load_data
from mdvae_cli.formats.registry import read, write
from mdvae_cli.formats.video_rows import near
from mdvae_cli.geometry.rotations_np import rotmat_to_rotvec
from mdvae_cli.motion.motion import Motion, slice_frames

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "video"


def run(*args):
    result = CliRunner().invoke(cli, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


def write_file(kind: str, folder: Path, m: Motion) -> Path:
    makers = {
        "wham": lambda: vf.write_wham(folder / "wham_output.pkl", {0: (m, None)}),
        "vibe": lambda: vf.write_vibe(folder / "vibe_output.pkl", m),
        "pare": lambda: vf.write_vibe(folder / "pare_output.pkl", m, matrices=True),
        "hybrik": lambda: vf.write_hybrik(folder / "res.pk", m),
        "gvhmr": lambda: vf.write_gvhmr(folder / "hmr4d_results.pt", m),
        "tram": lambda: vf.write_tram(folder / "tram", m),
        "aistpp": lambda: vf.write_aistpp(folder / "aist.pkl", m),
        "phalp": lambda: vf.write_phalp(folder / "demo.pkl", {"4": (m, list(range(m.num_frames)))}),
        "romp": lambda: vf.write_romp(
            folder / "video_results.npz", {"0": (m, list(range(m.num_frames)))}
        ),  # fmt: skip
        "slahmr": lambda: vf.write_slahmr(folder / "seq_world_results.npz", [m]),
    }
    return makers[kind]()


KINDS = ["wham", "vibe", "pare", "hybrik", "gvhmr", "tram", "aistpp", "phalp", "romp", "slahmr"]


@pytest.mark.parametrize("kind", KINDS)
def test_a_cleaned_track_goes_back_in_the_files_own_form(tmp_path, kind):
    src = write_file(kind, tmp_path, vf.clip(24, seed=3))
    loaded = read(src)
    before = loaded.single()
    after, sel = edited(before)
    out = src.parent / f"clean{src.suffix}"  # TRAM's world comes from ../camera.npy
    as_read = pickle.dumps(loaded.document.data)
    write(after, out, document=loaded.document)
    assert pickle.dumps(loaded.document.data) == as_read  # the file as read is not touched
    back = read(out)
    assert back.format == loaded.format
    got = back.single()
    # what the cleaning changed, read back from the pipeline's own file (float32 in the file)
    assert same_rotations(got.root_orient, after.root_orient) < 2e-6
    assert same_rotations(got.pose_body, after.pose_body) < 2e-6
    if kind not in ("vibe", "pare"):  # VIBE / PARE store no translation
        assert np.abs(got.trans - after.trans).max() < 1e-5
    # every frame the cleaning left alone is the file's own, bit for bit
    old, new = load_data(src), load_data(out)
    old = old.item() if isinstance(old, np.ndarray) else old
    new = new.item() if isinstance(new, np.ndarray) else new
    key = {"wham": "pose_world", "vibe": "pose", "pare": "pose", "hybrik": "pred_thetas",
           "tram": "pred_rotmat", "aistpp": "smpl_poses"}.get(kind)  # fmt: skip
    if key is not None:
        where = {"wham": 0, "vibe": 1, "pare": 1}.get(kind)
        o, n = (old[key], new[key]) if where is None else (old[where][key], new[where][key])
        assert n.dtype == o.dtype and n.shape == o.shape
        assert np.array_equal(n[~sel], o[~sel])
        assert not np.array_equal(n[sel], o[sel])


def test_denoise_json_says_the_write_back_notes_on_stderr(tmp_path):
    # before: with --json the notes of writing a file back ('verts' left out) were in the JSON
    # only, so that a pipeline's log and a user at a terminal never saw them
    src = vf.write_wham(tmp_path / "wham_output.pkl", {0: (vf.clip(40, seed=4), None)})
    code, out, err = run("denoise", src, "-o", tmp_path / "clean.pkl", "--json")
    assert code == 0, err
    (row,) = json.loads(out)["files"]  # stdout: the JSON alone
    note = "'verts' left out (vertices of the old pose; any SMPL tool makes them from the new)"
    assert note in row["result"]["notes"]
    assert f"note: wham_output.pkl: {note}" in err
    assert "note: video input: λ = 10" in err


@pytest.mark.parametrize("command", [("denoise",), ("add-noise", "--sigma", "0.05")])
def test_the_verts_note_is_said_once_whatever_the_output(tmp_path, command):
    # before: add-noise back into WHAM's own form said both the reader's "'verts' ... not
    # carried" (what an .npz leaves out) and the writer's "'verts' left out": one thing twice
    src = vf.write_wham(tmp_path / "wham_output.pkl", {0: (vf.clip(40, seed=4), None)})
    said = {}
    for out in ("back.pkl", "back.npz"):
        code, _, err = run(*command, src, "-o", tmp_path / out)
        assert code == 0, err
        said[out] = [ln for ln in err.splitlines() if "'verts'" in ln]
    assert said == {
        "back.pkl": ["note: wham_output.pkl: 'verts' left out (vertices of the old pose; any "
                     "SMPL tool makes them from the new)"],
        "back.npz": ["note: wham_output.pkl: 'verts' (made from the pose by any SMPL tool) not "
                     "carried"],
    }  # fmt: skip


def test_wham_camera_copy_follows_the_world_pose_and_verts_are_left_out(tmp_path):
    m = vf.clip(24, seed=4)
    src = vf.write_wham(tmp_path / "wham_output.pkl", {0: (m, None)})
    loaded = read(src)
    after, sel = edited(loaded.single())
    out = tmp_path / "clean.pkl"
    notes = write(after, out, document=loaded.document)
    assert any("'verts' left out" in n for n in notes)
    d = load_data(out)[np.int64(0)]
    assert "verts" not in d and set(d) == {"pose", "trans", "betas", "frame_ids",
                                           "pose_world", "trans_world"}  # fmt: skip
    # the file's camera copy is what the writer of the test file makes of the cleaned motion
    ref_root, ref_trans = vf.to_source(after, vf.CAMERA_UP)
    assert same_rotations(d["pose"][:, :3], rotmat_to_rotvec(ref_root)) < 2e-6
    assert np.abs(d["trans"] - ref_trans).max() < 1e-5
    assert np.abs(d["pose"][:, 3:66] - d["pose_world"][:, 3:66]).max() == 0


def test_gvhmr_incam_follows_tensors_and_net_outputs_left_out(tmp_path):
    m = vf.clip(20, seed=5)
    src = vf.write_gvhmr(tmp_path / "hmr4d_results.pt", m)
    loaded = read(src)
    after, _ = edited(loaded.single())
    out = tmp_path / "clean.pt"
    notes = write(after, out, document=loaded.document)
    assert any("'net_outputs' left out" in n for n in notes)
    pred = torch.load(out, weights_only=True)  # as GVHMR's own code opens it
    assert set(pred) == {"smpl_params_global", "smpl_params_incam", "K_fullimg"}
    incam = pred["smpl_params_incam"]
    assert isinstance(incam["transl"], torch.Tensor) and incam["transl"].dtype == torch.float32
    ref_root, ref_transl = vf.to_source(after, vf.CAMERA_UP)
    assert same_rotations(incam["global_orient"].numpy(), rotmat_to_rotvec(ref_root)) < 2e-6
    assert np.abs(incam["transl"].numpy() - ref_transl).max() < 1e-5


def test_nearest_axis_angle_keeps_a_half_turn_from_jumping():
    old = np.array([[0.0, 0.0, np.pi - 0.01]])
    new = np.array([[0.0, 0.0, -(np.pi - 0.02)]])  # nearly the same rotation, the other way
    got = near(new, old)
    assert np.allclose(got, [[0.0, 0.0, np.pi + 0.02]])
    assert same_rotations(got, new) < 1e-9
    assert np.array_equal(near(np.array([[0.1, 0.2, 0.3]]), np.zeros((1, 3))), [[0.1, 0.2, 0.3]])


def test_a_pickle_names_numpy_as_every_numpy_loads_it(tmp_path):
    src = vf.write_hybrik(tmp_path / "res.pk", vf.clip(12, seed=6))
    loaded = read(src)
    write(loaded.single(), tmp_path / "clean.pkl", document=loaded.document)
    raw = (tmp_path / "clean.pkl").read_bytes()
    assert b"numpy.core.multiarray\n_reconstruct" in raw and b"numpy._core" not in raw
    res = pickle.loads(raw)  # HybrIK's own reader: a plain pickle
    assert res["pred_thetas"].shape == (12, 216) and res["img_path"][3] == "img_000003.png"


def test_joblib_loads_a_wham_file_written_back(tmp_path):
    joblib = pytest.importorskip("joblib")
    src = vf.write_wham(tmp_path / "wham_output.pkl", {0: (vf.clip(16, seed=7), None)})
    loaded = read(src)
    write(edited(loaded.single())[0], tmp_path / "clean.pkl", document=loaded.document)
    d = joblib.load(tmp_path / "clean.pkl")
    assert type(d).__name__ == "defaultdict" and list(d) == [0]
    assert d[0]["pose_world"].dtype == np.float32 and d[0]["pose_world"].shape == (16, 72)


def test_writing_a_video_form_without_its_file_is_refused(tmp_path):
    src = vf.write_hybrik(tmp_path / "res.pk", vf.clip(12, seed=6))
    loaded = read(src)
    with pytest.raises(InputError, match="written only back from the file"):
        write(loaded.single(), tmp_path / "x.pkl")
    with pytest.raises(InputError, match="written back as .pkl"):
        write(loaded.single(), tmp_path / "x.pt", document=loaded.document)
    with pytest.raises(InputError, match="cannot go back"):
        write(slice_frames(loaded.single(), 0, 8), tmp_path / "y.pkl", document=loaded.document)
    assert not list(tmp_path.glob("[xy].p*"))


# --------------------------------------------------------------------------------------------
# the commands


def test_denoise_gives_each_pipeline_file_back_in_its_form(tmp_path):
    folder = tmp_path / "in"
    folder.mkdir()
    vf.write_wham(folder / "wham_output.pkl", {0: (vf.clip(40, seed=1), None)})
    vf.write_gvhmr(folder / "hmr4d_results.pt", vf.clip(40, seed=2))
    vf.write_phalp(folder / "demo_clip.pkl", {"1": (vf.clip(40, seed=3), list(range(40)))})
    vf.write_gvhmr(folder / "renamed.pkl", vf.clip(40, seed=4))  # a torch file under .pkl
    code, _, err = run("denoise", folder, "-o", tmp_path / "out")
    assert code == 0, err
    assert read(tmp_path / "out" / "wham_output.pkl").format == "wham"
    assert read(tmp_path / "out" / "hmr4d_results.pt").format == "gvhmr"
    assert read(tmp_path / "out" / "demo_clip.pkl").format == "phalp"
    # a form the name cannot hold: the .npz, with a note saying so
    assert not (tmp_path / "out" / "renamed.pkl").exists()
    assert read(tmp_path / "out" / "renamed.npz").format == "amass"
    assert "written as renamed.npz (a gvhmr result is written back as .pt / .pth)" in err
    # a named output of the file's own form, and of another family refused before reading
    code, _, err = run("denoise", folder / "wham_output.pkl", "-o", tmp_path / "one.pkl")
    assert code == 0, err
    assert (tmp_path / "one.pkl").is_file()
    code, _, err = run("denoise", folder / "wham_output.pkl", "-o", tmp_path / "one.pt")
    assert code == 1 and "write it as .pkl or .npz" in err
    code, _, err = run("denoise", folder / "wham_output.pkl", "-o", tmp_path / "one.pkl.gz")
    assert code == 1 and "not .gz" in err
    # --json carries the notes the console shows
    code, out, err = run("denoise", folder / "wham_output.pkl", "-o", tmp_path / "j.pkl", "--json")
    assert code == 0, err
    notes = json.loads(out)["files"][0]["result"]["notes"]
    assert any("'verts' left out" in n for n in notes)
    assert any("no frame rate in the file" in n for n in notes)
    # the .npz form is still there for the asking
    code, _, err = run("denoise", folder / "hmr4d_results.pt", "-o", tmp_path / "one.npz")
    assert code == 0, err
    assert read(tmp_path / "one.npz").format == "amass"


def test_add_noise_writes_a_pipeline_file_back_noisy_and_holes_as_npz(tmp_path):
    src = vf.write_hybrik(tmp_path / "res.pk", vf.clip(40, seed=4))
    code, _, err = run("add-noise", src, "-o", tmp_path / "noisy.pk", "--sigma", "0.1")
    assert code == 0, err
    clean, noisy = read(src).single(), read(tmp_path / "noisy.pk").single()
    assert 0.02 < same_rotations(clean.pose_body, noisy.pose_body) < 1.5
    code, _, err = run("add-noise", src, "-o", tmp_path / "holes.pk", "--drop-frames", "5x1")
    assert code == 1 and "name an .npz output" in err


@pytest.mark.skipif(not REAL.is_dir(), reason="the shared real files are not here")
@pytest.mark.parametrize("name", ["wham/wham_output.pkl", "gvhmr/tennis_hmr4d_results.pt",
                                  "hybrik/res.pk"])  # fmt: skip
def test_real_pipeline_files_come_back_in_their_form_as_the_npz_says(tmp_path, name):
    src = REAL / name
    own = tmp_path / f"clean{src.suffix}"
    for out in (own, tmp_path / "clean.npz"):
        code, _, err = run("denoise", src, "-o", out)
        assert code == 0, err
    a, b = read(own).single(), read(tmp_path / "clean.npz").single()
    assert read(own).format == read(src).format
    assert same_rotations(a.pose_body, b.pose_body) < 1e-5
    assert same_rotations(a.root_orient, b.root_orient) < 1e-5
    assert np.abs(a.trans - b.trans).max() < 1e-4


def test_romp_goes_back_as_its_own_npz_of_per_frame_lists(tmp_path):
    """ROMP / BEV: each track's per-frame lists stay lists of arrays of their dtypes; the
    edited frames change, the others and the hand joints keep their bits; a track with gaps
    in its frame ids gets an entry for each (the nearest entry's betas), a track not given
    and the per-image 'results' stay as they came."""
    a, b, c = vf.clip(24, seed=6), vf.clip(20, seed=7), vf.clip(10, seed=8)
    src = vf.write_romp(tmp_path / "video_results.npz",
                        {"0": (a, list(range(24))), "1": (b, list(range(0, 40, 2))),
                         "2": (c, list(range(10)))})  # fmt: skip
    loaded = read(src)
    tracks = dict(loaded.tracks)
    after, sel = edited(tracks["0"])
    gappy, _ = edited(tracks["1"])
    loaded.tracks = [("0", after), ("1", gappy)]
    out = tmp_path / "clean.npz"
    notes = write(loaded, out)
    assert any("track 1: 19 frame(s) missing" in n and "added" in n for n in notes)
    assert "'results' (the per-image estimates) kept as they came" in notes
    assert read(out).format == "romp"
    old, new = (np.load(p, allow_pickle=True) for p in (src, out))
    assert set(new.files) == set(old.files) and new["results"].item() == old["results"].item()
    o0, n0 = old["sequence_results"].item()["0"], new["sequence_results"].item()["0"]
    assert isinstance(n0["body_pose"], list) and n0["frame_id"] == o0["frame_id"]
    assert n0["cam_trans"][0].dtype == np.float32 and n0["body_pose"][0].shape == (69,)
    ob, nb = np.stack(o0["body_pose"]), np.stack(n0["body_pose"])
    assert np.array_equal(nb[~sel], ob[~sel]) and not np.array_equal(nb[sel], ob[sel])
    assert np.array_equal(nb[:, 63:], ob[:, 63:])  # the hand joints
    assert np.array_equal(np.stack(n0["cam_trans"])[~sel], np.stack(o0["cam_trans"])[~sel])
    o1, n1 = old["sequence_results"].item()["1"], new["sequence_results"].item()["1"]
    assert n1["frame_id"] == list(range(39)) and all(type(i) is int for i in n1["frame_id"])
    assert all(isinstance(n1[k], list) and len(n1[k]) == 39 for k in o1)
    assert np.array_equal(n1["smpl_betas"][1], o1["smpl_betas"][0])  # frame 1: as frame 0
    o2, n2 = old["sequence_results"].item()["2"], new["sequence_results"].item()["2"]
    assert all(np.array_equal(np.stack(n2[k]), np.stack(o2[k])) for k in o2)
    back = dict(read(out).tracks)
    assert same_rotations(back["0"].pose_body, after.pose_body) < 2e-6
    assert np.abs(back["0"].trans - after.trans).max() < 1e-5
    assert same_rotations(back["1"].pose_body, gappy.pose_body) < 2e-6
    assert np.abs(back["1"].trans - gappy.trans).max() < 1e-5


def test_romp_joints_made_from_the_old_pose_are_kept_with_a_note(tmp_path):
    src = vf.write_romp(
        tmp_path / "video_results.npz", {"0": (vf.clip(12, seed=3), list(range(12)))}
    )
    z = dict(np.load(src, allow_pickle=True))
    seq = z.pop("sequence_results").item()
    seq["0"]["j3d_all54"] = list(np.zeros((12, 54, 3), np.float32))
    np.savez(src, **z, sequence_results=seq)
    loaded = read(src)
    notes = write(loaded, tmp_path / "clean.npz")
    assert "j3d_all54 (made from the old pose) kept as they came" in notes
    kept = np.load(tmp_path / "clean.npz", allow_pickle=True)["sequence_results"].item()["0"]
    assert np.array_equal(np.stack(kept["j3d_all54"]), np.zeros((12, 54, 3)))


def test_slahmr_goes_back_as_a_plain_npz_with_its_other_tracks_and_arrays(tmp_path):
    a, b = vf.clip(30, seed=8), vf.clip(30, seed=9)
    src = vf.write_slahmr(tmp_path / "seq_000300_world_results.npz", [a, b])
    loaded = read(src)
    after, sel = edited(loaded.tracks[1][1])
    loaded.tracks = [loaded.tracks[0], (loaded.tracks[1][0], after)]
    write(loaded, tmp_path / "clean.npz")
    old, new = np.load(src), np.load(tmp_path / "clean.npz")  # plain arrays: no pickles
    assert set(new.files) == set(old.files)
    for k in old.files:
        assert new[k].dtype == old[k].dtype and new[k].shape == old[k].shape
        if k not in ("root_orient", "pose_body", "trans"):
            assert np.array_equal(new[k], old[k]), k
    for k in ("root_orient", "pose_body", "trans"):
        assert np.array_equal(new[k][0], old[k][0])  # the track left alone
        assert np.array_equal(new[k][1][~sel], old[k][1][~sel])
        assert not np.array_equal(new[k][1][sel], old[k][1][sel])
    got = read(tmp_path / "clean.npz").tracks[1][1]
    assert same_rotations(got.root_orient, after.root_orient) < 2e-6
    assert np.abs(got.trans - after.trans).max() < 1e-5


def test_commands_give_a_romp_npz_back_as_romp_and_holes_or_import_as_amass(tmp_path):
    src = vf.write_romp(
        tmp_path / "video_results.npz", {"0": (vf.clip(40, seed=2), list(range(40)))}
    )
    code, _, err = run("denoise", src, "-o", tmp_path / "clean.npz")
    assert code == 0, err
    assert read(tmp_path / "clean.npz").format == "romp"
    code, _, err = run("add-noise", src, "-o", tmp_path / "noisy.npz", "--sigma", "0.1")
    assert code == 0, err
    assert read(tmp_path / "noisy.npz").format == "romp"
    code, _, err = run("add-noise", src, "-o", tmp_path / "holes.npz", "--drop-frames", "5x1")
    assert code == 0, err
    holed = read(tmp_path / "holes.npz")
    assert holed.format != "romp" and not holed.single().joint_mask.all()
    code, _, err = run("import", src, "-o", tmp_path / "amass.npz")
    assert code == 0, err
    assert read(tmp_path / "amass.npz").format != "romp"
