"""What a user-level sweep over real and broken files turned up: a file without an extension,
another pipeline's pickle read with ``--format wham``, ``--json`` when nothing could be read,
an AIST++ motion saved as ``.npz``, the too-short message, a one-frame sample, folder
outputs that kept neither a take's ``.gz`` nor its name's case, and a video track that is
mostly frames it does not have."""

from __future__ import annotations

import gzip
import json
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest

from mdvae_cli.formats.registry import read
from mdvae_cli.geometry.rotations_np import rotmat_to_rotvec, rotvec_to_rotmat
from tests.conftest import one_error_line, run_cli
from tests.test_bvh_out import write_rig

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


@pytest.mark.parametrize("command", ["denoise", "add-noise"])
def test_an_input_without_an_extension_is_one_clear_line(tmp_path, command):
    src = tmp_path / "take"
    shutil.copy(EXAMPLES / "noisy_walk.npz", src)
    for out in (tmp_path / "out", str(tmp_path / "folder") + "/"):
        line = one_error_line(*run_cli(command, src, "-o", out))
        assert f"{src}: its name says no form mdvae reads" in line, line
        assert ".npz, .bvh or .amc" in line and "StopIteration" not in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["take"]


@pytest.mark.parametrize("fmt", ["wham", "vibe"])
def test_another_pickle_read_as_a_per_track_format_says_so(tmp_path, fmt):
    odd, empty = tmp_path / "odd.pkl", tmp_path / "empty.pkl"
    odd.write_bytes(pickle.dumps({"a": 1}))
    empty.write_bytes(pickle.dumps({}))
    line = one_error_line(*run_cli("denoise", odd, "--format", fmt, "-o", tmp_path / "x.pkl"))
    assert line.endswith("odd.pkl: not a dict of per-track dicts with 'pose' (entry 'a' is of "
                         "type int); check --format"), line  # fmt: skip
    line = one_error_line(*run_cli("denoise", empty, "--format", fmt, "-o", tmp_path / "x.pkl"))
    assert line.endswith("empty.pkl: holds no tracks (an empty dict)"), line
    assert not (tmp_path / "x.pkl").exists()


def test_view_json_says_what_failed_when_nothing_could_be_read(tmp_path):
    bad = tmp_path / "empty.bvh"
    bad.write_text("")
    code, out, err = run_cli("view", bad, "-o", tmp_path / "x.html", "--json")
    assert code == 1 and "not a BVH file" in err
    summary = json.loads(out)
    assert summary["ok"] is False and summary["output"] is None and summary["failed"] == 1
    assert summary["errors"][0]["file"] == str(bad)
    assert "not a BVH file" in summary["errors"][0]["error"]
    assert not (tmp_path / "x.html").exists()


def _aistpp_npz(path: Path, frames: int = 90) -> dict[str, np.ndarray]:
    """An AIST++ motion as ``np.savez`` leaves it: smpl_poses (T, 72), smpl_trans (T, 3) in
    the dancer's scale, smpl_scaling (1,); y up, 60 fps (AIST++ stores no rate)."""
    with np.load(EXAMPLES / "walk.npz") as z:
        poses, trans = z["poses"][:frames, :72].copy(), z["trans"][:frames]
    zup_to_yup = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])
    poses[:, :3] = rotmat_to_rotvec(zup_to_yup @ rotvec_to_rotmat(poses[:, :3]))
    arrays = {
        "smpl_poses": poses.astype(np.float32),
        "smpl_trans": (93.0 * trans @ zup_to_yup.T).astype(np.float32),
        "smpl_scaling": np.array([93.0], np.float32),
    }
    np.savez(path, **arrays)
    return arrays


def test_an_aistpp_npz_is_read_without_format_and_goes_back_as_one(tmp_path):
    src = tmp_path / "gWA_dance.npz"
    arrays = _aistpp_npz(src)
    loaded = read(src)
    assert loaded.format == "aistpp" and loaded.tracks[0][1].fps == 60.0
    out = tmp_path / "clean.npz"
    code, stdout, stderr = run_cli("denoise", src, "-o", out)
    assert code == 0, stdout + stderr
    with np.load(out) as z:
        assert sorted(z.files) == sorted(arrays)
        for key, a in arrays.items():
            assert z[key].shape == a.shape and z[key].dtype == a.dtype
        assert z["smpl_scaling"][0] == 93.0
        # the clean walk comes back as it went in, in the dancer's scale (the example walk's
        # few one-frame spikes filled)
        assert np.median(np.abs(z["smpl_poses"] - arrays["smpl_poses"])) < 0.005
        assert np.median(np.abs(z["smpl_trans"] - arrays["smpl_trans"])) < 0.01 * 93.0
    code, stdout, stderr = run_cli("view", src, out, "-o", tmp_path / "v.html", "--no-mesh")
    assert code == 0, stdout + stderr


def test_too_short_says_the_files_own_frames_and_rate(tmp_path, make_motion_file):
    src = make_motion_file("short.npz", T=5, fps=120.0)
    line = one_error_line(*run_cli("denoise", src, "-o", tmp_path / "o.npz"))
    assert "too short to denoise: 5 frame(s) at 120 Hz (0.0333 s)" in line, line
    assert "needs 0.17 s or more (6 frames at 30 Hz)" in line


def test_sample_writes_no_one_frame_motion(tmp_path):
    code, out, err = run_cli("sample", "--frames", "1", "-o", tmp_path / "s.bvh")
    line = one_error_line(code, out, err)
    assert "Invalid value for '--frames': 1 is not in the range 2<=x<=1080000" in line
    assert not (tmp_path / "s.bvh").exists()


def test_a_folder_run_keeps_each_takes_name_and_compression(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    take = write_rig(tmp_path / "rig.bvh", T=40)
    shutil.copy(take, src / "UP.BVH")
    (src / "zipped.bvh.gz").write_bytes(gzip.compress(take.read_bytes()))
    shutil.copy(take, src / "zipped.bvh")  # beside its gzipped copy: no clash now
    (src / "walk.npz.gz").write_bytes(gzip.compress((EXAMPLES / "noisy_walk.npz").read_bytes()))
    code, out, err = run_cli("denoise", src, "-o", tmp_path / "out")
    assert code == 0, out + err
    names = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert names == ["UP.BVH", "walk.npz", "zipped.bvh", "zipped.bvh.gz"]
    text = gzip.decompress((tmp_path / "out" / "zipped.bvh.gz").read_bytes()).decode()
    assert text.startswith("HIERARCHY") and "Frames: 40" in text
    assert (tmp_path / "out" / "zipped.bvh").read_text() == text


def wham_track(ids: np.ndarray) -> dict:
    """A WHAM ``wham_output.pkl`` of one track: the example walk's first frames at the frame
    numbers ``ids`` (T,)."""
    T = len(ids)
    with np.load(EXAMPLES / "walk.npz") as z:
        pose, trans = z["poses"][:T, :72].astype(np.float32), z["trans"][:T].astype(np.float32)
    track = {"pose": pose, "trans": trans, "pose_world": pose, "trans_world": trans,
             "betas": np.zeros((T, 10), np.float32), "frame_ids": np.asarray(ids)}  # fmt: skip
    return {0: track}


def test_a_track_that_is_mostly_frames_it_lacks_says_so(tmp_path):
    data = wham_track(np.arange(6) * 10)
    path = tmp_path / "sparse.pkl"
    path.write_bytes(pickle.dumps(data))
    ((_, motion),) = read(path).tracks
    assert motion.num_frames == 51
    assert any("holds 6 of the 51 frames its ids span: most of what is written for it will be "
               "filled, not measured" in n for n in motion.notes), motion.notes  # fmt: skip
    dense = tmp_path / "dense.pkl"
    dense.write_bytes(pickle.dumps(wham_track(np.array([0, 1, 2, 4, 5, 6]))))
    ((_, motion),) = read(dense).tracks
    assert not any("most of what is written" in n for n in motion.notes)


def test_a_ctrl_c_while_the_mesh_library_loads_stops_the_export(tmp_path, monkeypatch):
    """trimesh's optional imports catch BaseException: a Ctrl-C that landed while it loaded
    was swallowed and the export ran on to exit 0. A stand-in that swallows one the same way
    (the signal sent to this process while it "loads")."""
    import os
    import signal
    import sys
    import types

    from mdvae_cli.body.builtin import builtin_body_model
    from mdvae_cli.export import export_mesh_sequence
    from mdvae_cli.formats.npz_io import load_motion

    def loading(name, *args, **kwargs):
        if name != "trimesh":
            return real_import(name, *args, **kwargs)
        try:  # as trimesh guards its optional extras
            os.kill(os.getpid(), signal.SIGINT)
        except BaseException:  # noqa: BLE001 - what the library does
            pass
        return types.ModuleType("trimesh")

    import builtins

    real_import = builtins.__import__
    monkeypatch.delitem(sys.modules, "trimesh", raising=False)
    monkeypatch.setattr(builtins, "__import__", loading)
    motion = load_motion(EXAMPLES / "walk.npz")
    with pytest.raises(KeyboardInterrupt):
        export_mesh_sequence(motion, builtin_body_model(), tmp_path / "meshes")
    monkeypatch.undo()
    assert not (tmp_path / "meshes").exists() or not any((tmp_path / "meshes").iterdir())


def test_the_library_denoises_a_take_under_a_float64_default(tmp_path):
    """``torch.set_default_dtype(torch.float64)`` in the caller had left the networks in
    float64 beside windows made in float32 (BVH and AMC takes failed); the default is the
    caller's again after, and the result is the one made under float32."""
    import torch

    from mdvae_cli.infer.denoise_settings import DenoiseSettings, denoise

    take = read(write_rig(tmp_path / "take.bvh", T=60))
    settings = DenoiseSettings(input_kind=take.kind)
    plain = denoise([take.single()], settings)[0]
    torch.set_default_dtype(torch.float64)
    try:
        wide = denoise([take.single()], settings)[0]
        assert torch.get_default_dtype() == torch.float64
    finally:
        torch.set_default_dtype(torch.float32)
    np.testing.assert_array_equal(wide.pose_body, plain.pose_body)
    np.testing.assert_array_equal(wide.trans, plain.trans)


def test_spike_rad_without_spikes_is_refused(tmp_path):
    src = EXAMPLES / "walk.npz"
    line = one_error_line(*run_cli("add-noise", "--spike-rad", "2", src, "-o", tmp_path / "x.npz"))
    assert line.endswith("--spike-rad only applies with --spike-frac F (the spikes it sizes)")
    code, out, err = run_cli("add-noise", "--spike-frac", "0.01", "--spike-rad", "2", src,
                             "-o", tmp_path / "x.npz")  # fmt: skip
    assert code == 0, out + err


def _page_meta(path: Path) -> dict:
    import re

    text = path.read_text()
    raw = re.search(r'id="mdvae-meta">(.*?)</script>', text, re.S)
    return json.loads(raw.group(1))


def test_view_names_the_track_it_shows_and_refuses_one_a_file_lacks(tmp_path):
    one = tmp_path / "one.pkl"
    one.write_bytes(pickle.dumps(wham_track(np.arange(40))))
    line = one_error_line(*run_cli("view", "--track", "7", one, "-o", tmp_path / "p.html"))
    assert line.endswith("one.pkl: no track '7' (tracks: 0)"), line
    two = tmp_path / "two.pkl"
    data = {**wham_track(np.arange(40)), 3: wham_track(np.arange(40))[0]}
    two.write_bytes(pickle.dumps(data))
    code, out, err = run_cli("view", "--track", "3", two, "-o", tmp_path / "p.html", "--no-mesh")
    assert code == 0, out + err
    assert [m["name"] for m in _page_meta(tmp_path / "p.html")["motions"]] == ["two.pkl track 3"]


def test_view_tells_holes_the_file_lacks_from_frames_a_denoise_filled(tmp_path):
    with np.load(EXAMPLES / "noisy_walk.npz") as z:
        arrays = dict(z)
    arrays["poses"][10:20] = np.nan
    holes, clean = tmp_path / "holes.npz", tmp_path / "clean.npz"
    np.savez(holes, **arrays)
    assert run_cli("denoise", holes, "-o", clean)[0] == 0
    code, out, err = run_cli("view", holes, clean, "-o", tmp_path / "p.html", "--no-mesh")
    assert code == 0, out + err
    motions = _page_meta(tmp_path / "p.html")["motions"]
    assert [m["filled"] for m in motions] == [[[10, 20]], [[10, 20]]]
    assert [m["missing_in_file"] for m in motions] == [True, False]


def test_a_one_frame_take_is_a_pose_that_opens(tmp_path):
    """A single-pose BVH (a rig's reference pose) was refused by every command ("a motion
    needs at least 2 frames"), while a one-frame npz opened: it imports and views now, and
    denoise says it is too short."""
    take = write_rig(tmp_path / "pose.bvh", T=1)
    code, out, err = run_cli("import", take, "-o", tmp_path / "pose.npz")
    assert code == 0, out + err
    assert np.load(tmp_path / "pose.npz")["poses"].shape[0] == 1
    code, out, err = run_cli("view", take, "-o", tmp_path / "pose.html", "--no-mesh")
    assert code == 0 and "1 motion(s), 1 frame, skeleton only)" in err, out + err
    line = one_error_line(*run_cli("denoise", take, "-o", tmp_path / "clean.bvh"))
    assert "too short to denoise: 1 frame(s) at 30 Hz" in line, line


HAND_BVH = """HIERARCHY
ROOT lHand
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT finger2-1.l
  {
    OFFSET 0 3 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 2 0
    }
  }
  JOINT finger3-1.l
  {
    OFFSET 1 3 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 2 0
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.04
0 0 0 0 0 0 0 0 0 5 0 0
0 0 0 1 0 0 2 0 0 6 0 0
0 0 0 2 0 0 4 0 0 7 0 0
"""


def test_a_hand_rig_is_told_it_is_no_whole_body(tmp_path):
    """A hand-only take (MocapNET's hand rig) was told to name hips and knees in a joint map."""
    path = tmp_path / "hand.bvh"
    path.write_text(HAND_BVH)
    line = one_error_line(*run_cli("import", path, "-o", tmp_path / "hand.npz"))
    assert "no joint found for left_hip" in line
    assert line.endswith("; a hand, a face or a prop is no body to retarget")


def _headless_rig(path: Path) -> Path:
    """The generated rig with its Head joint gone: the neck ends in an End Site, as in the
    Poser / DAZ figures ``hip, abdomen, chest, neck`` (three.js's pirouette.bvh)."""
    text = write_rig(path, T=40).read_text()
    head, motion = text.split("MOTION\n")
    start = head.index("JOINT Head")
    start = head.rindex("\n", 0, start) + 1
    depth, opened = 0, head.index("{", start)
    for end in range(opened, len(head)):  # the Head block, to its closing brace
        depth += {"{": 1, "}": -1}.get(head[end], 0)
        if depth == 0:
            break
    pad = head[start : head.index("JOINT Head")]
    site = f"{pad}End Site\n{pad}{{\n{pad}  OFFSET 0 0 10\n{pad}}}"
    head = head[:start] + site + head[end + 1 :]
    lines = motion.splitlines()
    rows = [" ".join(v for i, v in enumerate(r.split()) if not 18 <= i < 21) for r in lines[2:]]
    path.write_text(head + "MOTION\n" + "\n".join(lines[:2] + rows) + "\n")
    return path


def test_a_rig_without_a_head_joint_takes_its_necks_end(tmp_path):
    """A neck whose only child is an End Site: the head is there (it was refused: "no joint
    found for head"), said in a note; the take comes back on its own skeleton."""
    path = _headless_rig(tmp_path / "figure.bvh")
    out = tmp_path / "clean.bvh"
    code, stdout, stderr = run_cli("denoise", path, "-o", out)
    assert code == 0, stdout + stderr
    assert "no head joint: the head is at the end of Neck" in stderr.replace("\n", " ")
    before, after = path.read_text(), out.read_text()
    assert after.split("MOTION")[0] == before.split("MOTION")[0]
    assert "Frames: 40" in after
