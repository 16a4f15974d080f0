"""Holes in files (issue 32): NaN / inf in an npz read as missing joints, `denoise --fill`,
`add-noise --drop-frames / --drop-joints`."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mdvae_cli.errors import InputError
from mdvae_cli.formats.npz_holes import keep_holes
from mdvae_cli.formats.npz_io import load_motion, save_motion
from mdvae_cli.infer.denoise_settings import DenoiseSettings
from mdvae_cli.motion.holes import unfilled
from tests.conftest import file_digest
from tests.conftest import one_error_line as one_error
from tests.conftest import run_cli as run


@pytest.fixture
def holey(make_motion_file):
    """A 60-frame SMPL-H take with frames 10-19 NaN, the left elbow inf in 30-34, the
    translation NaN in frame 40 and one hand value NaN in frame 50."""

    def make(name="holes.npz", **arrays):
        from tests.conftest import motion_arrays

        data = motion_arrays(T=60, width=156)
        data["poses"][10:20] = np.nan
        data["poses"][30:35, 3 * 18 : 3 * 18 + 3] = np.inf
        data["trans"][40, 1] = np.nan
        data["poses"][50, 100] = np.nan
        data.update(arrays)
        return make_motion_file(name, poses=data["poses"], trans=data["trans"])

    return make


def test_nan_rows_and_joints_read_as_holes(holey):
    path = holey()
    m = load_motion(path)
    expect = np.ones((60, 22), bool)
    expect[10:20] = False
    expect[30:35, 18] = False
    expect[40] = False
    assert np.array_equal(m.joint_mask, expect)
    for arr in (m.root_orient, m.pose_body, m.trans, m.pose_extra):
        assert np.isfinite(arr).all()
    raw = np.load(path)
    # observed values unchanged; the pelvis placeholder lies between its neighbours
    assert np.allclose(m.poses[25], raw["poses"][25])
    assert np.allclose(m.trans[40, [0, 2]], raw["trans"][40, [0, 2]], atol=0.05)
    assert np.allclose(m.trans[5], raw["trans"][5])
    note = [n for n in m.notes if "NaN" in n]
    assert len(note) == 1 and "16 of 60 frame(s)" in note[0] and "247 joint entries" in note[0]


def test_file_mask_and_nan_combine(make_motion_file):
    from tests.conftest import motion_arrays

    given = np.ones((60, 22), bool)
    given[0:3, 7] = False
    data = motion_arrays(T=60, width=156)
    data["poses"][5, :3] = np.nan
    m = load_motion(make_motion_file("both.npz", poses=data["poses"], joint_mask=given))
    assert not m.joint_mask[5, 0] and m.joint_mask[5, 1:].all() and not m.joint_mask[0:3, 7].any()
    assert m.joint_mask.sum() == 60 * 22 - 1 - 3


def test_fill_off_writes_the_files_values_back(holey, tmp_path):
    path = holey()
    m = load_motion(path)
    save_motion(m, tmp_path / "filled.npz")
    filled = np.load(tmp_path / "filled.npz")
    assert np.isfinite(filled["poses"]).all() and "joint_mask" in filled
    save_motion(keep_holes(m), tmp_path / "as_read.npz")
    back, raw = np.load(tmp_path / "as_read.npz"), np.load(path)
    for key in ("poses", "trans"):
        assert np.array_equal(back[key], raw[key], equal_nan=True)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: d["poses"].fill(np.nan), "'poses' contains NaN or infinite values in every"),
        (lambda d: d["trans"].fill(np.inf), "'trans' contains NaN or infinite values in every"),
        (lambda d: d["poses"][:, 3 * 15].fill(np.nan), "joint 15 (head) in all 20 frames"),
        (lambda d: d["betas"].__setitem__(0, np.nan), "'betas' contains NaN"),
    ],
)
def test_holes_with_nothing_to_fill_from_refused(make_motion_file, change, message):
    from tests.conftest import motion_arrays

    data = motion_arrays(T=20, width=156)
    change(data)
    path = make_motion_file("bad.npz", **data)
    with pytest.raises(InputError) as exc:
        load_motion(path)
    assert message in str(exc.value) and "\n" not in str(exc.value)
    code, out, err = run("add-noise", path, "-o", path.with_name("out.npz"))
    assert message in one_error(code, out, err)


def test_unfilled_puts_the_inputs_values_back(holey):
    m = load_motion(holey())
    moved = m.with_body(pose_body=m.pose_body + 0.1, trans=m.trans + 1.0)
    out = unfilled(moved, m)
    hole = ~m.joint_mask
    assert np.allclose(out.pose_body[hole[:, 1:]], m.pose_body[hole[:, 1:]])
    assert np.allclose(out.pose_body[~hole[:, 1:]], m.pose_body[~hole[:, 1:]] + 0.1)
    assert np.allclose(out.trans[hole[:, 0]], m.trans[hole[:, 0]])


def test_denoise_fills_holes_and_fill_off_gives_nan_back(holey, tmp_path):
    path = holey()
    before = file_digest(path)
    code, out, err = run("denoise", path, "-o", tmp_path / "clean.npz", "--json")
    assert code == 0, err
    result = json.loads(out)["files"][0]["result"]
    assert (result["filled_frames"], result["filled_joints"]) == (16, 247)
    assert (
        result["tracks"][0]["filled_frames"] == 16
        and json.loads(out)["fill"] == DenoiseSettings.fill
    )
    clean = np.load(tmp_path / "clean.npz")
    assert np.isfinite(clean["poses"]).all() and np.isfinite(clean["trans"]).all()
    assert clean["joint_mask"].sum() == 60 * 22 - 247

    code, out, err = run("denoise", path, "-o", tmp_path / "off.npz", "--fill", "off")
    assert code == 0, err
    assert "16 frame(s) with holes left as they came" in " ".join((out + err).split())
    off, raw = np.load(tmp_path / "off.npz"), np.load(path)
    assert np.array_equal(np.isnan(off["poses"]), np.isnan(raw["poses"]))
    assert np.array_equal(np.isnan(off["trans"]), np.isnan(raw["trans"]))
    assert file_digest(path) == before


def test_add_noise_drop_frames_reproducible(make_motion_file, tmp_path):
    path = make_motion_file("clean.npz", T=90, width=72)
    outs = []
    for name, seed in (("a.npz", 0), ("b.npz", 0), ("c.npz", 1)):
        code, out, err = run("add-noise", path, "-o", tmp_path / name, "--sigma", "0.05",
                             "--drop-frames", "15x2", "--seed", seed, "--json")  # fmt: skip
        assert code == 0, err
        assert json.loads(out)["files"][0]["result"]["dropped_frames"] == 30
        outs.append(np.load(tmp_path / name))
    a, b, c = outs
    assert np.array_equal(a["poses"], b["poses"], equal_nan=True)
    assert np.isnan(a["poses"]).all(axis=1).sum() == 30 and np.isnan(a["trans"]).any(1).sum() == 30
    assert not np.array_equal(np.isnan(a["trans"]), np.isnan(c["trans"]))
    assert "joint_mask" not in a
    back = load_motion(tmp_path / "a.npz")
    assert (~back.joint_mask).all(axis=1).sum() == 30


def test_add_noise_drop_joints_one_limb(make_motion_file, tmp_path):
    from mdvae_cli.motion.holes import LIMBS

    path = make_motion_file("clean.npz", T=90, width=66)
    code, out, err = run("add-noise", path, "-o", tmp_path / "l.npz", "--drop-joints", "20")
    assert code == 0, err
    poses = np.load(tmp_path / "l.npz")["poses"].reshape(90, 22, 3)
    missing = np.isnan(poses).any(axis=(0, 2))
    assert tuple(np.flatnonzero(missing)) in LIMBS.values()
    assert np.isnan(poses).any(axis=(1, 2)).sum() == 20
    assert np.isfinite(np.load(tmp_path / "l.npz")["trans"]).all()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--drop-frames", "0x2"], "expected LENGTH[xCOUNT]"),
        (["--drop-joints", "ten"], "expected LENGTH[xCOUNT]"),
        (["--drop-frames", "95"], "hold no hole of 95 frames"),
        (["--fill", "maybe"], None),
    ],
)
def test_bad_hole_options_one_line(make_motion_file, tmp_path, args, message):
    path = make_motion_file("clean.npz", T=90, width=66)
    command = "denoise" if args[0] == "--fill" else "add-noise"
    line = one_error(*run(command, path, "-o", tmp_path / "o.npz", *args))
    assert message is None or message in line
    assert not (tmp_path / "o.npz").exists()


def test_video_track_gaps_filled_in_the_videos_numbering(tmp_path):
    from tests import video_files as vf

    ids = np.r_[np.arange(105, 120), np.arange(125, 140)]  # frames 120-124: person not found
    path = vf.write_wham(tmp_path / "w.pkl", {3: (vf.clip(30, seed=4), ids)})
    code, out, err = run("denoise", path, "-o", tmp_path / "clean.npz", "--json")
    assert code == 0, err
    result = json.loads(out)["files"][0]["result"]
    assert (result["filled_frames"], result["filled_joints"]) == (5, 5 * 22)
    clean = np.load(tmp_path / "clean.npz")
    assert np.array_equal(clean["frame_ids"], np.arange(105, 140))
    assert np.isfinite(clean["poses"]).all() and not clean["joint_mask"][15:20].any()


def test_add_noise_keeps_the_inputs_nan_and_adds_its_own(holey, tmp_path):
    path = holey()
    code, out, err = run("add-noise", path, "-o", tmp_path / "n.npz", "--sigma", "0.1")
    assert code == 0, err
    raw, noisy = np.load(path), np.load(tmp_path / "n.npz")
    assert np.array_equal(np.isnan(noisy["poses"]), np.isnan(raw["poses"]))
    assert np.array_equal(np.isnan(noisy["trans"]), np.isnan(raw["trans"]))
    code, out, err = run("add-noise", path, "-o", tmp_path / "d.npz", "--drop-frames", "5")
    assert code == 0, err
    both = np.load(tmp_path / "d.npz")
    assert np.isnan(both["poses"][np.isnan(raw["poses"])]).all()
    assert np.isnan(both["trans"]).any(axis=1).sum() == 1 + 5


def test_video_track_keeps_its_own_unobserved_frames_across_gaps(tiny_body):
    """A track whose pipeline marks frames it filled itself (observed False) and skips frame
    ids: both kinds of frame are holes, each where its frame id lands."""
    from mdvae_cli.formats.video_tracks import Z_UP, RawTrack, track_to_motion

    T = 12
    ids = np.r_[np.arange(100, 106), np.arange(109, 115)][::-1]  # out of order, 106-108 skipped
    observed = np.ones(T, bool)
    observed[ids == 102] = False
    raw = RawTrack(root=np.tile(np.eye(3), (T, 1, 1)), body=np.zeros((T, 21, 3)),
                   transl=np.zeros((T, 3)), betas=np.zeros(10), up=Z_UP, frame_ids=ids,
                   observed=observed)  # fmt: skip
    m = track_to_motion(raw, 30.0, tiny_body, "track.pkl")
    assert np.array_equal(m.extras["frame_ids"], np.arange(100, 115))
    assert np.flatnonzero(~m.joint_mask[:, 0]).tolist() == [2, 6, 7, 8]


def test_prior_training_refuses_a_take_with_holes(holey, tiny_body):
    from mdvae_cli.body.skinning import BodyModel
    from mdvae_cli.train.corpus import load_windows

    with pytest.raises(InputError, match="16 frame\\(s\\) with missing joints"):
        load_windows([holey()], BodyModel(tiny_body), 20, 5)


def test_filled_spikes_are_counted_in_the_summary_and_json(tmp_path):
    """A take with one frame of the left elbow flicked by 1 rad and back has one more frame
    with a spike filled than the take without it (CMU 07_01's wrists and ankles flick on a
    few frames too), said in ``--json`` (``spike_frames``) and on the summary line."""
    from pathlib import Path

    walk = load_motion(Path(__file__).resolve().parents[1] / "examples" / "walk.npz")
    spiky = walk.with_body(pose_body=walk.pose_body.copy())
    spiky.pose_body[40, 17] += [1.0, 0.0, 0.0]  # body joint 18, the left elbow
    counts = []
    for name, motion in (("clean.npz", walk), ("spiky.npz", spiky)):
        save_motion(motion, tmp_path / name)
        code, out, err = run("denoise", tmp_path / name, "-o", tmp_path / f"out_{name}", "--json")
        assert code == 0, err
        result = json.loads(out)["files"][0]["result"]
        assert result["spike_frames"] == result["tracks"][0]["spike_frames"]
        counts.append(result["spike_frames"])
        code, out, err = run("denoise", tmp_path / name, "-o", tmp_path / f"again_{name}")
        n = counts[-1]
        assert code == 0 and f"filled {n} frame(s) with a spike" in " ".join(err.split()), err
    assert counts[1] == counts[0] + 1
