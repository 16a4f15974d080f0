"""``mdvae view``'s page without a browser: the data it embeds decodes back to the posed
joints, the page is self-contained, the mesh is decimated sensibly, and the commands (``view``,
``denoise --view``) answer files and bad input as every command does."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.cli.main import cli
from mdvae_cli.cli.view_cmd import motion_labels
from mdvae_cli.errors import InputError
from mdvae_cli.formats.npz_io import load_motion, motion_from_arrays
from mdvae_cli.formats.registry import ReadOptions, read
from mdvae_cli.geometry.rotations import quat_to_rotmat, rotvec_to_rotmat
from mdvae_cli.motion.contacts import foot_contacts
from mdvae_cli.view.encode import Blob, decode_array, encode_array, quantise, unzigzag, zigzag
from mdvae_cli.view.mesh import decimate_body
from mdvae_cli.view.page import POS_SCALE, ROT_SCALE, build_view_page
from mdvae_cli.view.pose import (
    BODY_PARENTS,
    bend_angles,
    pose_skeleton,
    rotation_angles,
    rotation_channels,
)
from tests.conftest import motion_arrays

REPO = Path(__file__).resolve().parents[1]
DAB = REPO.parent / "shared/data/animated_drawings/fair1_dab.bvh.gz"


def make_motion(T=60, fps=30.0, seed=0, noise=0.0):
    m = motion_from_arrays(motion_arrays(T=T, fps=fps, seed=seed))
    if noise:
        rng = np.random.default_rng(seed + 1)
        m = m.with_body(pose_body=m.pose_body + rng.normal(0, noise, m.pose_body.shape))
    return m


@pytest.fixture(scope="module")
def body(tiny_body):
    return BodyModel(tiny_body)


# --- encoding ---------------------------------------------------------------------------------


@pytest.mark.parametrize("dtype", ["int16", "int32", "uint8", "int8"])
def test_encode_round_trips_exactly_with_wrapping_differences(dtype):
    info = np.iinfo(dtype)
    rng = np.random.default_rng(0)
    values = rng.integers(info.min, info.max, size=(300, 5), endpoint=True).astype(dtype)
    values[:2] = [info.min, info.max, 0, info.max, info.min]  # differences that overflow
    for delta in (True, False):
        blob = encode_array(values, delta=delta)
        assert (decode_array(blob) == values).all()
    for order in (1, 2):  # each order on its own, overflowing sums included
        blob = encode_array(values, orders=(order,))
        assert blob.delta == order and (decode_array(blob) == values).all()


def test_encode_picks_the_difference_order_that_packs_smaller():
    t = np.arange(2000)[:, None]
    smooth = np.rint(3000 * np.sin(t / 400 + np.arange(4))).astype(np.int16)  # a clean take
    rng = np.random.default_rng(1)
    noisy = (smooth + rng.integers(-200, 201, smooth.shape)).astype(np.int16)
    picked = {name: encode_array(v) for name, v in (("smooth", smooth), ("noisy", noisy))}
    assert picked["smooth"].delta == 2 and picked["noisy"].delta == 1
    for name, v in (("smooth", smooth), ("noisy", noisy)):
        sizes = [len(encode_array(v, orders=(o,)).text) for o in (1, 2)]
        assert len(picked[name].text) == min(sizes)
        assert (decode_array(picked[name]) == v).all()
    assert len(picked["smooth"].text) < 0.95 * len(encode_array(smooth, orders=(1,)).text)
    # zigzag: small numbers of either sign stay small (an all-zero high byte)
    signed = np.array([0, -1, 1, -2, 2, -32768, 32767], np.int16)
    assert zigzag(signed).tolist() == [0, 1, 2, 3, 4, 65535, 65534]
    assert (unzigzag(zigzag(signed), "int16") == signed).all()


def test_quantise_rounds_and_clips():
    q = quantise(np.array([0.0004, 0.0006, -0.0016, 40.0, -40.0]), 0.001, "int16")
    assert q.tolist() == [0, 1, -2, 32767, -32768]
    with pytest.raises(ValueError):
        encode_array(np.zeros((3, 2)))  # floats are quantised first


# --- what the page embeds ------------------------------------------------------------------------


def page_arrays(html: str):
    """The page's meta JSON and its decoded arrays: {motion index: {key: (T, C) ints}}."""
    meta = json.loads(re.search(r'id="mdvae-meta">(.*?)</script>', html, re.S).group(1))
    out = {}
    for i, m in enumerate(meta["motions"]):
        out[i] = {}
        for key, d in m["data"].items():
            text = re.search(rf'id="{d["id"]}">(.*?)</script>', html, re.S).group(1)
            blob = Blob(text, d["type"].lower(), d["frames"], d["channels"], d["delta"])
            out[i][key] = decode_array(blob)
    return meta, out


def page_fk(meta: dict, i: int, arrays: dict) -> np.ndarray:
    """The joints the page computes (viewer_data.js, Track.pose), in numpy.  -> (T, 22, 3)"""
    rot = arrays["rot"] / np.asarray(meta["motions"][i]["rotation_scales"])
    T = len(rot)
    local = rot[:, 4:].reshape(T, 21, 3)
    w = np.sqrt(np.clip(1 - (local**2).sum(-1, keepdims=True), 0, None))
    quats = np.concatenate([rot[:, None, :4], np.concatenate([w, local], -1)], 1)
    R = quat_to_rotmat(torch.as_tensor(quats / np.linalg.norm(quats, axis=-1, keepdims=True)))
    R = R.numpy()
    rest = np.asarray(meta["motions"][i]["rest_joints"]).reshape(22, 3)
    J = np.zeros((T, 22, 3))
    G = np.zeros((T, 22, 3, 3))
    J[:, 0], G[:, 0] = arrays["root"] / POS_SCALE, R[:, 0]
    for j in range(1, 22):
        p = BODY_PARENTS[j]
        G[:, j] = G[:, p] @ R[:, j]
        J[:, j] = J[:, p] + G[:, p] @ (rest[j] - rest[p])
    return J


def test_page_data_decodes_to_the_posed_joints_within_2_mm(body):
    """Two motions of different rates and lengths, one noisy: what the page rebuilds by forward
    kinematics from the embedded root, rotations and rest joints is the body model's pose,
    within 2 mm (the noisy one, whose noise moves its joints by centimetres, is stored in
    coarser steps: within 8 mm)."""
    motions = [make_motion(T=90, fps=30.0, noise=0.15), make_motion(T=150, fps=60.0, seed=3)]
    page = build_view_page([("a.npz", motions[0]), ("b.npz", motions[1])], body)
    meta, arrays = page_arrays(page.html)
    assert [m["frames"] for m in meta["motions"]] == [90, 150]
    assert [m["fps"] for m in meta["motions"]] == [30.0, 60.0]
    for i, m in enumerate(motions):
        truth = pose_skeleton(m, body).joints
        assert np.abs(page_fk(meta, i, arrays[i]) - truth).max() < (8e-3 if i == 0 else 2e-3)
        bits = arrays[i]["contacts"][:, 0]
        expect = foot_contacts(truth, m.fps)
        assert ((bits[:, None] >> np.arange(4)) & 1).astype(bool).tolist() == expect.tolist()


def test_pose_skeleton_matches_the_body_model(body, tiny_body):
    m = make_motion(T=20)
    t = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
    ref = body(t(m.root_orient), t(m.pose_body), t(m.trans), t(m.betas)).joints.numpy()
    assert np.abs(pose_skeleton(m, body, chunk_frames=7).joints - ref).max() < 1e-5


def test_rotation_channels_give_back_each_local_rotation():
    m = make_motion(T=10, noise=1.0)  # some joints past 180 degrees: w >= 0 is chosen
    ch = rotation_channels(m)
    assert ch.shape == (10, 4 + 63)
    local = ch[:, 4:].reshape(10, 21, 3)
    w = np.sqrt(np.clip(1 - (local**2).sum(-1, keepdims=True), 0, None))
    got = quat_to_rotmat(torch.as_tensor(np.concatenate([w, local], -1))).numpy()
    want = rotvec_to_rotmat(torch.as_tensor(m.pose_body)).numpy()
    assert np.abs(got - want).max() < 1e-9


def test_series_known_values():
    J = np.zeros((1, 22, 3))
    J[0, 1] = [0.1, 0, 1.0]  # left hip
    J[0, 4] = [0.1, 0, 0.5]  # left knee straight below the hip
    J[0, 7] = [0.1, 0.5, 0.5]  # ankle straight forward: a 90-degree bend
    assert abs(bend_angles(J)[0, 4] - 90.0) < 1e-9
    assert np.isnan(bend_angles(J)[0, [0, 10, 11, 15, 20, 21]]).all()
    m = make_motion(T=3)
    m.pose_body[:, 3] = [0, 0, np.pi / 2]
    m.pose_body[:, 4] = [0, 0, 1.5 * np.pi]  # 270 degrees about z is 90 the other way
    assert np.allclose(rotation_angles(m)[:, [4, 5]], 90.0)


def test_page_is_self_contained_and_escapes_names(body):
    name = 'x</script><img src="http://evil/">.npz'
    page = build_view_page([(name, make_motion(T=30))], body, mesh=False)
    html = page.html
    assert "Content-Security-Policy" in html and "default-src 'none'" in html
    # nothing is fetched: no external address anywhere but the name, which is escaped
    assert "http" not in html.replace("http://evil/", "").replace("http-equiv", "")
    assert html.count("</script>") == html.count("<script")
    assert "<img" not in html
    meta, _ = page_arrays(html)
    assert meta["motions"][0]["name"] == name and meta["mesh"] is None
    with pytest.raises(InputError):
        build_view_page([], body)


def test_decimated_builtin_mesh_has_a_few_hundred_vertices_skinned_to_body_joints():
    from mdvae_cli.body.formats import load_body_model

    data = load_body_model(None)
    skin = decimate_body(data, target=400)
    assert 400 <= skin.num_vertices <= 440
    assert skin.faces.max() < skin.num_vertices and (skin.faces >= 0).all()
    f = skin.faces
    assert ((f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])).all()
    assert 1.5 * skin.num_vertices < len(f) < 3 * skin.num_vertices
    assert np.allclose(skin.joint_weights.sum(1), 1.0) and skin.joint_ids.max() < 22
    rest = skin.rest_vertices(data, np.zeros(10))
    assert np.allclose(rest.min(0), data.v_template.min(0), atol=0.05)  # same extent
    assert np.allclose(rest.max(0), data.v_template.max(0), atol=0.05)


def test_small_mesh_is_kept_whole(tiny_body):
    skin = decimate_body(tiny_body, target=10_000)
    assert skin.num_vertices == tiny_body.num_vertices and len(skin.faces) == len(tiny_body.faces)


def test_ten_minutes_of_noisy_motion_fit_well_under_20_mb(body):
    """Bytes per frame of a noisy take (the hardest to compress), scaled to 10 minutes at 30 Hz
    (benchmarks/view_page.py measures a real one)."""
    T = 3000
    page = build_view_page([("noisy", make_motion(T=T, noise=0.15))], body, mesh=False)
    per_frame = page.num_bytes / T
    assert per_frame * 18_000 < 5e6  # one noisy motion: under 5 MB for 10 minutes


# --- reading any file ------------------------------------------------------------------------


def test_the_registry_reads_npz_and_refuses_the_rest_in_one_line(tmp_path, make_motion_file):
    path = make_motion_file("a.npz", T=12)
    assert read(path).single().num_frames == 12
    assert read(path, ReadOptions(resample=15.0)).single().fps == 15.0
    (tmp_path / "x.txt").write_text("hello")
    with pytest.raises(InputError, match="x.txt: not a pickle"):
        read(tmp_path / "x.txt")
    with pytest.raises(InputError, match="no such file"):
        read(tmp_path / "missing.npz")
    (tmp_path / "x.c3d").write_bytes(b"\x01P")
    with pytest.raises(InputError, match="C3D marker files are not supported"):
        read(tmp_path / "x.c3d")


def test_amc_without_skeleton_is_refused(tmp_path):
    (tmp_path / "07_01.amc").write_text(":FULLY-SPECIFIED\n:DEGREES\n1\nroot 0 0 0 0 0 0\n")
    with pytest.raises(InputError, match="no .asf skeleton"):
        read(tmp_path / "07_01.amc", ReadOptions())


def test_motion_labels_tell_files_apart():
    assert motion_labels([Path("a/take.npz"), Path("b/take.npz")]) == ["a/take.npz", "b/take.npz"]
    assert motion_labels([Path("x/noisy.npz"), Path("clean.npz")]) == ["noisy.npz", "clean.npz"]


# --- the commands ----------------------------------------------------------------------------


def test_view_command_writes_one_page(tmp_path, make_motion_file, hash_tree):
    a = make_motion_file("in/noisy.npz", T=40)
    b = make_motion_file("in/clean.npz", T=80, fps=60.0, seed=2)
    before = hash_tree(tmp_path / "in")
    out = tmp_path / "page.html"
    result = CliRunner().invoke(cli, ["view", str(a), str(b), "-o", str(out), "--json"])
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    assert summary["mesh"] and summary["bytes"] == out.stat().st_size
    assert [m["frames"] for m in summary["motions"]] == [40, 80]
    assert hash_tree(tmp_path / "in") == before  # inputs untouched
    meta, _ = page_arrays(out.read_text())
    assert [m["name"] for m in meta["motions"]] == ["noisy.npz", "clean.npz"]


@pytest.mark.parametrize(
    "args, message",
    [(["missing.npz", "-o", "p.html"], "no such file"), (["a.npz", "-o", "p.png"], "must end in"),
     (["a.npz", "-o", "a.npz"], "must end in"), (["a.npz", "-o", "dir/"], "must end in")],
)  # fmt: skip
def test_view_command_bad_input_is_one_line_error(tmp_path, make_motion_file, args, message):
    make_motion_file("a.npz", T=10)
    args = [a if a.startswith("-") else str(tmp_path / a) for a in args]
    result = CliRunner().invoke(cli, ["view", *args])
    assert result.exit_code == 1
    assert result.output.startswith("error:") and message in result.output
    assert len(result.output.strip().splitlines()) == 1


def test_view_reads_bvh(tmp_path):
    """A real BVH take (its first 30 frames), retargeted onto the body, next to an .npz."""
    if not DAB.exists():
        pytest.skip(f"real data not found: {DAB}")
    import gzip

    head, motion = gzip.open(DAB, "rt").read().split("MOTION", 1)
    rows = motion.strip().splitlines()
    (tmp_path / "dab.bvh").write_text(
        head + "MOTION\nFrames: 30\n" + rows[1] + "\n" + "\n".join(rows[2:32]) + "\n"
    )
    shutil.copy(REPO / "examples/walk.npz", tmp_path / "walk.npz")
    out = tmp_path / "p.html"
    args = ["view", str(tmp_path / "dab.bvh"), str(tmp_path / "walk.npz"), "-o", str(out)]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    meta, _ = page_arrays(out.read_text())
    assert meta["motions"][0]["frames"] == 30 and meta["motions"][0]["fps"] == 30.0
    # denoise --view on a BVH take: the page shows the take and the BVH written back
    pages = tmp_path / "pages"
    args = ["denoise", str(tmp_path / "dab.bvh"), "-o", str(tmp_path / "clean.bvh")]
    result = CliRunner().invoke(cli, [*args, "--view", str(pages)])
    assert result.exit_code == 0, result.output
    meta, _ = page_arrays((pages / "dab.html").read_text())
    assert [m["name"] for m in meta["motions"]] == ["dab.bvh (input)", "clean.bvh (cleaned)"]
    assert [m["frames"] for m in meta["motions"]] == [30, 30]


def test_denoise_view_writes_a_page_per_file(tmp_path, make_motion_file):
    make_motion_file("in/a.npz", T=40)
    make_motion_file("in/sub/b.npz", T=45, seed=1)
    pages = tmp_path / "pages"
    args = ["denoise", str(tmp_path / "in"), "-o", str(tmp_path / "out"), "--view", str(pages)]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert sorted(p.relative_to(pages).as_posix() for p in pages.rglob("*.html")) == [
        "a.html",
        "sub/b.html",
    ]
    meta, arrays = page_arrays((pages / "sub/b.html").read_text())
    assert [m["name"] for m in meta["motions"]] == ["b.npz (input)", "b.npz (cleaned)"]
    cleaned = load_motion(tmp_path / "out/sub/b.npz")
    assert meta["motions"][1]["frames"] == cleaned.num_frames == 45
    (tmp_path / "file").write_text("")
    args[-1] = str(tmp_path / "file")
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 1 and "is a file" in result.output


def test_view_benchmark_builds_a_continuous_long_take_and_its_section():
    from benchmarks.view_page import SECTION_BEGIN, SECTION_END, concatenate, long_take, markdown

    a, b = make_motion(T=40), make_motion(T=30, fps=60.0, seed=1)
    take = concatenate([a, b, a], 70)
    assert take.num_frames == 70 and take.fps == 30.0
    steps = np.linalg.norm(np.diff(take.trans[:, :2], axis=0), axis=1)
    assert steps.max() < 0.1  # each take starts where the one before ended
    walk, source = long_take(500, None)
    assert walk.num_frames == 500 and "walk" in source
    rows = [{"page": "noisy + clean", "frames": 500, "mb": 0.1, "build_s": 1.0}]
    md = markdown(rows, "python benchmarks/view_page.py", 0.3, source, 1)
    assert md.startswith(SECTION_BEGIN) and SECTION_END in md and "| 2 x 500 | 0.10 |" in md


def test_page_marks_the_frames_filled(tmp_path, tiny_body):
    """Frames with a joint missing in the file (NaN in an npz) are embedded as runs."""
    data = motion_arrays(T=40, width=66)
    data["poses"][5:9] = np.nan
    data["poses"][20:22, 3 * 16 : 3 * 16 + 3] = np.nan
    np.savez(tmp_path / "holes.npz", **data)
    motion = load_motion(tmp_path / "holes.npz")
    page = build_view_page([("holes", motion), ("plain", motion_from_arrays(motion_arrays(T=40)))],
                           BodyModel(tiny_body), mesh=False)  # fmt: skip
    meta, _ = page_arrays(page.html)
    assert meta["motions"][0]["filled"] == [[5, 9], [20, 22]]
    assert meta["motions"][1]["filled"] == []
    assert [m["filled_frames"] for m in page.motions] == [6, 0]


def test_a_noisy_channel_is_stored_in_coarser_steps_than_its_noise_and_a_clean_one_is_not():
    from mdvae_cli.view.page import MIN_ROT_SCALE, NOISE_STEPS, rotation_scales

    T = 3000
    t = np.arange(T) / 120.0
    smooth = 0.3 * np.sin(2 * np.pi * 0.7 * t)[:, None] * np.ones((1, 4))
    noise = np.random.default_rng(0).normal(size=(T, 4)) * [0.0, 0.002, 0.02, 0.5]
    scales = rotation_scales(smooth + noise)
    assert scales.tolist() == [ROT_SCALE, ROT_SCALE, 1024, MIN_ROT_SCALE]
    # every step under 1/NOISE_STEPS of the channel's own noise, unless it is the finest
    for sd, k in zip([0.0, 0.002, 0.02, 0.5], scales, strict=True):
        assert k == ROT_SCALE or 1 / k <= sd / NOISE_STEPS


def test_a_noisy_track_embeds_its_coarser_units_and_the_page_still_poses_it(body):
    noisy = make_motion(T=240, noise=0.1)
    page = build_view_page([("noisy", noisy), ("clean", make_motion(T=240))], body, mesh=False)
    meta, arrays = page_arrays(page.html)
    assert min(meta["motions"][0]["rotation_scales"][4:]) < ROT_SCALE
    assert set(meta["motions"][1]["rotation_scales"]) == {ROT_SCALE}
    joints = pose_skeleton(noisy, body).joints
    np.testing.assert_allclose(page_fk(meta, 0, arrays[0]), joints, atol=0.01)


def test_each_motion_carries_its_own_floor_for_its_contact_marks(body):
    """A take 0.6 m higher than another (a video estimate's heights as the pipeline wrote
    them): the grid is at the lower floor, and each take's planted feet are marked at its
    own floor, under its feet (before: every mark at the grid, 0.6 m under the higher one)."""
    low = make_motion(T=60)
    high = low.with_body(trans=low.trans + np.array([0.0, 0.0, 0.6]))
    meta, _ = page_arrays(build_view_page([("low", low), ("high", high)], body, mesh=False).html)
    floors = [m["floor"] for m in meta["motions"]]
    assert meta["floor"] == floors[0]
    assert abs(floors[1] - floors[0] - 0.6) < 1e-3


def test_one_missing_file_of_several_fails_alone(tmp_path, make_motion_file):
    """As every command: a page of the files there, one error line for the one that is not,
    exit 1 (before: no page at all); every file missing: refused, no page."""
    a = make_motion_file("a.npz", T=20)
    out = tmp_path / "p.html"
    args = ["view", str(a), str(tmp_path / "gone.npz"), "-o", str(out), "--no-mesh", "--json"]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 1
    summary = json.loads(result.stdout)
    assert [m["name"] for m in summary["motions"]] == ["a.npz"] and summary["failed"] == 1
    assert "no such file or folder" in summary["errors"][0]["error"]
    meta, _ = page_arrays(out.read_text())
    assert [m["frames"] for m in meta["motions"]] == [20]
    gone = [str(tmp_path / "gone.npz"), str(tmp_path / "gone2.npz")]
    result = CliRunner().invoke(cli, ["view", *gone, "-o", str(tmp_path / "q.html")])
    assert result.exit_code == 1 and "no such file or folder" in result.output
    assert not (tmp_path / "q.html").exists()
