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


def test_jacobian_blocks_are_minus_skew():
    """The pose solve writes -skew(d) straight into its Jacobian's rows and columns."""
    import torch

    from mdvae_cli.geometry.rotations import skew
    from mdvae_cli.retarget.pose_solve import _minus_skew_into

    d = torch.randn(4, 22, 17, 3, generator=torch.Generator().manual_seed(0))
    out = torch.zeros(4, 22, 3, 17, 3)
    _minus_skew_into(out, d)
    assert torch.equal(out, -skew(d).permute(0, 1, 3, 2, 4) + 0.0)


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
