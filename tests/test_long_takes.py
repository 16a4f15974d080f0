"""Long takes: progress inside a take, and the fast paths giving what the plain ones give."""

from pathlib import Path

import numpy as np
import pytest

from mdvae_cli.body.builtin import builtin_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.formats.npz_io import load_motion
from mdvae_cli.infer.denoise_settings import DenoiseSettings, denoise
from mdvae_cli.model.denoiser import load_denoiser

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.fixture(scope="module")
def shipped():
    denoiser, _ = load_denoiser(None)
    return denoiser, BodyModel(builtin_body_model())


@pytest.mark.parametrize(
    "settings, phases",
    [
        (DenoiseSettings(), ["windows denoised", "stitched", "blended", "feet locked"]),
        (DenoiseSettings(feet="off", blend=False), ["windows denoised", "stitched"]),
    ],
)
def test_progress_tells_each_phase_of_a_take(shipped, settings, phases):
    noisy = load_motion(EXAMPLES / "noisy_walk.npz")
    told = []
    denoise([noisy], settings, *shipped, progress=told.append)
    steps = [t for t in told if t["stage"] == "denoise"]
    assert [t["phase"] for t in steps] == phases
    assert [t["step"] for t in steps] == list(range(1, len(phases) + 1))
    assert {t["steps"] for t in steps} == {len(phases)}


def test_sole_heights_and_vertices_match_the_whole_feet():
    """The soles in chunks (heights along a direction, one vertex a frame) are the foot
    vertices skinned all at once, seen the same way (float noise)."""
    import torch

    from mdvae_cli.body.formats import load_body_model
    from mdvae_cli.geometry.rotations import rotvec_to_rotmat
    from mdvae_cli.retarget.fit_shape import BodyJoints
    from mdvae_cli.retarget.soles import _FEET, foot_vertex, lowest_along

    body = BodyJoints(load_body_model(None))
    gen = torch.Generator().manual_seed(0)
    T = 50
    G = rotvec_to_rotmat(torch.randn(T, 22, 3, generator=gen, dtype=torch.float64))
    p = torch.randn(T, 22, 3, generator=gen, dtype=torch.float64)
    betas = torch.randn(body.num_betas, generator=gen, dtype=torch.float64)
    X_all = body.rest_joints(betas)
    rest = body.foot_vertices(betas)  # (F, 3)
    W = body.foot_weights  # (F, 4)
    # every vertex: sum_k W[v, k] (G_k (v - X_k) + p_k)
    arm = rest[None] - X_all[_FEET][:, None]  # (4, F, 3)
    moved = torch.einsum("tkab,kfb->tkfa", G[:, _FEET], arm) + p[:, _FEET][:, :, None]
    feet = torch.einsum("tkfa,fk->tfa", moved, W)  # (T, F, 3)
    up = torch.nn.functional.normalize(torch.tensor([0.1, 1.0, -0.2], dtype=torch.float64), dim=0)
    heights, vertex = lowest_along(G[:, _FEET], p[:, _FEET], body, betas, X_all, up, 7)
    np.testing.assert_allclose(heights.numpy(), (feet @ up).amin(-1).numpy(), atol=1e-12)
    assert torch.equal(vertex, (feet @ up).argmin(-1))
    lowest = feet[..., 1].argmin(-1)
    np.testing.assert_allclose(
        foot_vertex(G[:, _FEET], p[:, _FEET], body, betas, X_all, lowest).numpy(),
        feet[torch.arange(T), lowest].numpy(),
        atol=1e-12,
    )


def test_reading_a_take_tells_its_progress(tmp_path):
    from mdvae_cli.formats.registry import ReadOptions, read
    from tests.test_bvh_out import write_rig

    path = write_rig(tmp_path / "take.bvh", T=90)
    told = []
    loaded = read(path, ReadOptions(progress=lambda done, total: told.append((done, total))))
    assert told and told[-1] == (90, 90) == (loaded.single().num_frames,) * 2


def test_a_batch_hands_each_file_a_progress_of_its_own(tmp_path):
    from mdvae_cli.cli.batch import FileJob, run_batch

    jobs = [FileJob(Path(f"{n}.bvh"), tmp_path / f"{n}.bvh") for n in "ab"]

    def work(job, tell):
        for done in range(0, 101, 50):
            tell(done, 100)
        return job.relpath.stem

    report = run_batch(jobs, work, "reading", quiet=True, within=True)
    assert [o.result for o in report.succeeded] == ["a", "b"]


def test_writing_a_take_back_tells_its_progress(tmp_path):
    from mdvae_cli.formats.registry import read, write
    from tests.test_bvh_out import write_rig

    loaded = read(write_rig(tmp_path / "take.bvh", T=90))
    told = []
    write(loaded, tmp_path / "back.bvh", progress=lambda done, total: told.append((done, total)))
    assert told and told[-1] == (90, 90)


def test_a_file_run_tells_its_progress_and_counts_the_time_waited(tmp_path, shipped):
    """``run.denoise_files`` (what ``mdvae denoise`` calls): a take's progress inside it while
    it is read and written back, and its seconds the time the user waited (reading, its share
    of the denoising, writing)."""
    from mdvae_cli.formats.registry import ReadOptions
    from mdvae_cli.run.denoise_files import denoise_files, read_file, write_file
    from tests.test_bvh_out import write_rig

    path = write_rig(tmp_path / "take.bvh", T=90)
    read_told, write_told = [], []
    options = ReadOptions(progress=lambda done, total: read_told.append((done, total)))
    run = read_file(path, tmp_path / "clean.bvh", options)
    assert read_told[-1] == (90, 90)
    times = [run.seconds]
    denoise_files([run], DenoiseSettings(), *shipped)
    times.append(run.seconds)
    write_file(run, shipped[1], progress=lambda done, total: write_told.append((done, total)))
    times.append(run.seconds)
    assert write_told[-1] == (90, 90) and (tmp_path / "clean.bvh").is_file()
    assert 0 < times[0] < times[1] < times[2] and run.to_dict()["seconds"] == round(times[2], 4)


def _chain_bvh(path: Path, a_positions: np.ndarray, root_x: np.ndarray) -> Path:
    """root (6 channels) -> A (6 channels, its positions ``a_positions`` (T, 3)) -> B -> end;
    the root moves along x by ``root_x`` (T,), no rotation."""
    T = len(root_x)
    rows = [[x, 90.0, 0.0, 0.0, 0.0, 0.0, *a, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
            for x, a in zip(root_x, a_positions, strict=True)]  # fmt: skip
    text = (
        "HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n"
        " CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n"
        " JOINT A\n {\n  OFFSET 0 -40 0\n"
        "  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n"
        "  JOINT B\n  {\n   OFFSET 0 -40 0\n   CHANNELS 3 Zrotation Xrotation Yrotation\n"
        "   End Site\n   {\n    OFFSET 0 -10 0\n   }\n  }\n }\n}\n"
        f"MOTION\nFrames: {T}\nFrame Time: 0.0333333\n"
        + "\n".join(" ".join(f"{v:.6f}" for v in r) for r in rows)
        + "\n"
    )
    path.write_text(text)
    return path


@pytest.mark.parametrize("kind", ["fixed", "moving", "world"])
def test_position_channels_of_a_joint_are_sorted_as_fixed_moving_or_world(tmp_path, kind):
    """The reader makes joints' world poses only when a non-root joint's position channels
    move: a fixed one's value becomes its offset, a moving one is kept per frame, one that
    holds world positions is ignored (its OFFSET used)."""
    from mdvae_cli.formats.bvh import load_bvh

    T = 40
    root_x = np.linspace(0.0, 300.0, T)
    wobble = np.stack([3.0 * np.sin(np.arange(T) / 3.0), np.zeros(T), np.zeros(T)], axis=1)
    a = {"fixed": np.tile([1.0, -38.0, 2.0], (T, 1)),
         "moving": np.array([0.0, -40.0, 0.0]) + wobble,
         "world": np.stack([root_x, np.full(T, 50.0), np.zeros(T)], axis=1)}[kind]  # fmt: skip
    src = load_bvh(_chain_bvh(tmp_path / "chain.bvh", a, root_x), scale=0.01)
    layout = src.layout
    assert layout.moving == ((1,) if kind == "moving" else ())
    assert layout.world_channels == ((1,) if kind == "world" else ())
    want_offset = {"fixed": [1.0, -38.0, 2.0], "moving": [0.0, -40.0, 0.0],
                   "world": [0.0, -40.0, 0.0]}[kind]  # fmt: skip
    assert np.allclose(src.offsets[1], np.array(want_offset) * 0.01)
    if kind == "moving":
        assert np.allclose(src.local_positions[:, 1], a * 0.01)
    else:
        assert src.local_positions is None


def test_the_blend_in_pieces_is_the_blend_at_once(monkeypatch):
    """A long take's bands and shares go a piece at a time, each with the frames either side
    that it reads: the same values as the take at once (to the rounding of a running sum),
    with and without holes, at 30 and 120 Hz."""
    import mdvae_cli.infer.noise_blend as nb

    rng = np.random.default_rng(1)
    T = 2000
    residual = np.cumsum(rng.normal(size=(T, 5, 3)) * 0.01, axis=0)
    residual += rng.normal(size=(T, 5, 3)) * 0.02
    noise = np.full(5, 0.02**2)
    spikes = rng.random((T, 5)) < 0.01
    for fps in (30.0, 120.0):
        for missing in (None, rng.random((T, 5)) < 0.05):
            monkeypatch.setattr(nb, "BLEND_PIECE", 10**9)
            whole = nb.keep_unexplained(residual, noise, spikes, fps, nb.FAST_MARGIN, missing)
            monkeypatch.setattr(nb, "BLEND_PIECE", 173)
            pieces = nb.keep_unexplained(residual, noise, spikes, fps, nb.FAST_MARGIN, missing)
            for w, p in zip(whole, pieces, strict=True):
                assert w.shape == p.shape
                assert np.abs(w - p).max() < 1e-12
            assert np.abs(whole[0]).max() > 0.01  # something was kept


def test_the_noise_is_each_channels_median_over_the_take():
    """The noise estimate a channel at a time is the median of the third differences over the
    whole take (the components pooled), with the differences that reach a hole left out."""
    from mdvae_cli.infer.input_noise import CHI2_MEDIAN, noise_variance

    rng = np.random.default_rng(2)
    values = rng.normal(size=(300, 4, 3)) * np.array([0.01, 0.02, 0.05, 0.1])[:, None]
    d3 = np.diff(values, n=3, axis=0) ** 2
    want = np.median(np.moveaxis(d3, -1, 1).reshape(-1, 4), axis=0) / (20 * CHI2_MEDIAN)
    assert np.array_equal(noise_variance(values), want)
    assert np.allclose(np.sqrt(noise_variance(values)), [0.01, 0.02, 0.05, 0.1], rtol=0.15)
    seen = np.ones((300, 4), bool)
    seen[100:150, 2] = False
    ok = np.ones(297, bool)
    for k in range(4):
        ok &= seen[k : k + 297, 2]
    want_2 = np.median(d3[ok, 2].ravel()) / (20 * CHI2_MEDIAN)
    got = noise_variance(values, seen)
    assert got[2] == want_2 and np.array_equal(got[[0, 1, 3]], want[[0, 1, 3]])


@pytest.mark.parametrize("name", ["back.bvh", "back.bvh.gz"])
@pytest.mark.parametrize("side_by_side", [False, True])
def test_a_bvh_is_written_in_pieces_as_one_text(tmp_path, monkeypatch, name, side_by_side):
    """The writer formats and writes a few thousand rows at a time, in order, also when the
    pieces are formatted side by side on two threads (``workers.map_in_order``, as the way
    back writes a take): the file is byte for byte the text made at once."""
    import gzip

    import mdvae_cli.formats.bvh_write as bw
    from mdvae_cli.formats.bvh import load_bvh
    from mdvae_cli.workers import map_in_order
    from tests.test_bvh_out import write_rig

    layout = load_bvh(write_rig(tmp_path / "take.bvh", T=90)).layout
    monkeypatch.setattr(bw, "ROWS_PER_PIECE", 7)
    assert len(list(bw.motion_pieces(layout.header, layout.data, layout.frame_time))) == 14
    rows_map = (lambda fn, items: map_in_order(fn, items, workers=2)) if side_by_side else map
    bw.write_bvh(layout, layout.data, tmp_path / name, rows_map=rows_map)
    raw = (tmp_path / name).read_bytes()
    raw = gzip.decompress(raw) if name.endswith(".gz") else raw
    monkeypatch.setattr(bw, "ROWS_PER_PIECE", 10**6)
    assert raw == bw.motion_text(layout.header, layout.data, layout.frame_time).encode()
