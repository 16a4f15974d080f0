"""Networks that read where a take's holes are (``DenoiserConfig.reads_holes``): the hole
reader's offset, its checkpoints, the ELBO's gradient into it, the training copies with random
holes (``fit-dataset --holes``) and where such networks split a take."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from mdvae_cli.body.builtin import builtin_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.cli.main import cli
from mdvae_cli.infer.fill import observed_pieces
from mdvae_cli.infer.window_groups import make_windows
from mdvae_cli.model.denoiser import Denoiser, DenoiserConfig, load_denoiser, save_denoiser
from mdvae_cli.model.prior_model import load_prior
from mdvae_cli.motion.holes import (
    RANDOM_FRAME_HOLES,
    observed,
    random_holes,
    with_holes,
)
from mdvae_cli.motion.motion import Motion
from mdvae_cli.train.noisy_windows import holed_copies
from tests.test_denoise import noisy_dir, tiny_prior  # noqa: F401 (fixtures)
from tests.test_holes import clip


def runs_of(missing: np.ndarray) -> list[int]:
    """Lengths of the runs of True in a (T,) bool array."""
    edges = np.diff(np.concatenate([[0], missing.astype(int), [0]]))
    return (np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)).tolist()


def test_random_holes_are_frames_or_limbs_of_the_drawn_lengths_and_seeded():
    masks = [random_holes(600, np.random.default_rng(s)) for s in range(20)]
    np.testing.assert_array_equal(masks[3], random_holes(600, np.random.default_rng(3)))
    kinds = set()
    for m in masks:
        assert m.shape == (600, 22) and m[:2].all() and m[-2:].all()
        whole = ~m.any(axis=1)
        for n in runs_of(whole):  # (two drawn holes may overlap into one)
            assert RANDOM_FRAME_HOLES[0] <= n <= 5 * RANDOM_FRAME_HOLES[1]
            kinds.add("frames")
        part = ~m.all(axis=1) & ~whole
        if part.any():
            kinds.add("limb")
            assert (~m[part]).sum(axis=1).max() <= 3 * 5  # limbs, overlapping at most
            assert min(runs_of(part)) >= 1
        assert 1 <= len(runs_of(~m.all(axis=1))) <= 600 // 120
        assert (~m).any(axis=1).sum() >= RANDOM_FRAME_HOLES[0]
    assert kinds == {"frames", "limb"}
    # a short take still gets its hole
    assert not random_holes(70, np.random.default_rng(0)).all()


def test_holed_copies_take_the_share_asked_with_holes_and_placeholders():
    takes = [clip(150, seed=s) for s in range(6)]
    copies, sources = holed_copies(takes, 0.5, seed=0)
    assert len(copies) == len(sources) == 3
    assert len(holed_copies(takes, 1.5, seed=0)[0]) == 9
    for c, src in zip(copies, sources, strict=True):
        assert c.joint_mask is not None and not c.joint_mask.all()
        assert np.isfinite(c.pose_body).all()
        seen = c.joint_mask
        np.testing.assert_array_equal(c.pose_body[seen[:, 1:]], src.pose_body[seen[:, 1:]])
        assert src.joint_mask is None and any(src is t for t in takes)
    again = holed_copies(takes, 0.5, seed=0)[0]
    for a, b in zip(copies, again, strict=True):
        np.testing.assert_array_equal(a.joint_mask, b.joint_mask)
    other = holed_copies(takes, 0.5, seed=1)[0]
    pairs = zip(copies, other, strict=True)
    assert any(not np.array_equal(a.joint_mask, b.joint_mask) for a, b in pairs)
    # the takes themselves are untouched
    assert all(t.joint_mask is None for t in takes)


@pytest.fixture(scope="module")
def den_and_body(tiny_prior):  # noqa: F811
    prior, _ = load_prior(tiny_prior / "run")
    torch.manual_seed(0)
    return Denoiser(prior, DenoiserConfig(hidden_dim=16)).eval(), BodyModel(builtin_body_model())


def holed_group(den: Denoiser, body: BodyModel):
    m = clip(40, seed=2)
    mask = np.ones((40, 22), bool)
    mask[10:20] = False
    mask[25:35, [4, 7, 10]] = False
    return make_windows([with_holes(m, mask)], den, body, window=39, stride=10)[0]


def test_the_hole_reader_starts_at_zero_offsets_only_missing_frames_and_round_trips(
    den_and_body, tmp_path
):
    den, body = den_and_body
    g = holed_group(den, body)
    before = den.infer(g.yn, with_prior=False)["x_hat"]
    assert den.read_holes(g.yn, g.weight) is g.yn  # no reader: the input as it is
    reader = Denoiser(den.prior, DenoiserConfig(hidden_dim=16, reads_holes=True)).eval()
    reader.load_state_dict(den.state_dict(), strict=False)
    read = reader.read_holes(g.yn, g.weight)
    torch.testing.assert_close(read, g.yn)  # zero at first: the same networks
    torch.testing.assert_close(reader.infer(read, with_prior=False)["x_hat"], before)

    with torch.no_grad():
        reader.hole_reader.weight.normal_()
    read = reader.read_holes(g.yn, g.weight)
    seen = g.weight[0, :, :22].bool().all(-1)
    torch.testing.assert_close(read[0, seen], g.yn[0, seen])
    assert (read[0, ~seen] - g.yn[0, ~seen]).abs().min(-1).values.gt(0).any()
    # a joint missing moves the input by that joint's column
    col = reader.hole_reader.weight[:, 4]
    limb_only = ~seen & g.weight[0, :, 0].bool()
    torch.testing.assert_close(
        (read - g.yn)[0, limb_only][0], reader.hole_reader.weight[:, [4, 7, 10]].sum(-1)
    )
    assert col.abs().sum() > 0

    save_denoiser(tmp_path / "d.npz", reader, {})
    back, _ = load_denoiser(tmp_path / "d.npz")
    assert back.cfg.reads_holes
    torch.testing.assert_close(back.hole_reader.weight, reader.hole_reader.weight)
    save_denoiser(tmp_path / "plain.npz", den, {})
    plain, _ = load_denoiser(tmp_path / "plain.npz")
    assert plain.hole_reader is None and not plain.cfg.reads_holes


def test_the_elbo_trains_the_hole_reader_from_takes_with_holes(den_and_body):
    den, body = den_and_body
    reader = Denoiser(den.prior, DenoiserConfig(hidden_dim=16, reads_holes=True))
    g = holed_group(reader, body)
    terms = reader.elbo(g.yn, g.y3d, g.betas, body, g.weight)
    terms["loss"].backward()
    assert reader.hole_reader.weight.grad.abs().sum() > 0
    assert any(p is reader.hole_reader.weight for p in reader.trainable_parameters())
    reader.zero_grad()
    whole = reader.elbo(g.yn, g.y3d, g.betas, body, None)
    whole["loss"].backward()  # a take without holes: nothing for the reader to learn
    assert reader.hole_reader.weight.grad is None


def test_networks_that_read_holes_keep_a_1_s_hole_in_the_take():
    m = clip(150, seed=6)
    mask = np.ones((150, 22), bool)
    mask[60:90] = False  # 1 s
    holed = with_holes(m, mask)
    assert observed_pieces(holed, 6) == [(0, 60), (90, 150)]
    assert observed_pieces(holed, 6, reads_holes=True) is None
    mask[60:110] = False  # 1.7 s: split either way
    assert observed_pieces(with_holes(m, mask), 6, reads_holes=True) == [(0, 60), (110, 150)]
    assert isinstance(holed, Motion) and not observed(holed).all()


@pytest.mark.slow  # ~15 s on 2 cores
def test_fit_dataset_with_holes_makes_networks_that_read_them(noisy_dir, tiny_prior, tmp_path):  # noqa: F811
    out = tmp_path / "run"
    args = ["fit-dataset", str(noisy_dir), "--prior", str(tiny_prior / "run"), "-o", str(out),
            "--holes", "1", "--epochs", "1", "--window", "20", "--stride", "5",
            "--max-steps", "4", "--threads", "1"]  # fmt: skip
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 0, res.output
    den, meta = load_denoiser(out)
    assert den.cfg.reads_holes and meta["fit_config"]["holes"] == 1
    assert den.hole_reader.weight.abs().sum() > 0  # trained away from zero
    bad = CliRunner().invoke(cli, [*args[:-2], "--holes", "-1"])
    assert bad.exit_code != 0 and "Traceback" not in bad.output


def test_holed_training_windows_hide_frames_from_the_networks_not_the_likelihood(
    noisy_dir,  # noqa: F811
    den_and_body,  # noqa: F811
):
    from mdvae_cli.train.noisy_windows import load_noisy_windows

    den, body = den_and_body
    files = sorted(noisy_dir.glob("*.npz"))
    plain = load_noisy_windows(files, den, body, 20, 5)
    groups = load_noisy_windows(files, den, body, 20, 5, holes=1.0)
    assert len(plain) == 1 and len(groups) == 2
    full, hidden = groups
    torch.testing.assert_close(full.yn, plain[0].yn)
    assert len(hidden) == len(full)  # every take once more, cut the same way
    assert hidden.weight is None and hidden.seen is not None  # the likelihood scores all
    assert hidden.read_weight is hidden.seen and full.read_weight is None
    whole = hidden.seen.bool().all(-1).all(-1)
    assert whole.any() and (~whole).any()
    # a window without a hole is the take's own (unless one lies within the input filter's
    # reach); one with a hole reads placeholders there but scores the take's own noisy frames
    same = (hidden.yn - full.yn).abs().amax((1, 2)) < 1e-5
    assert same[whole].float().mean() > 0.5 and not same[~whole].any()
    torch.testing.assert_close(hidden.y3d[same], full.y3d[same])
    i = int(torch.nonzero(~whole)[0])
    gone = ~hidden.seen[i].bool().all(-1)
    assert (hidden.yn[i, gone] - full.yn[i, gone]).abs().max() > 1e-3
    pelvis = hidden.y3d[i, :, 0] - hidden.y3d[i, :1, 0]
    truth = full.y3d[i, :, 0] - full.y3d[i, :1, 0]
    assert (pelvis - truth).norm(dim=-1).max() < 0.05  # the same frames, scored


def test_the_elbo_scores_hidden_frames_while_the_networks_read_holes(den_and_body):
    den, body = den_and_body
    reader = Denoiser(den.prior, DenoiserConfig(hidden_dim=16, reads_holes=True))
    g = holed_group(reader, body)
    seen = g.weight[..., :22]
    hidden = reader.elbo(g.yn, g.y3d, g.betas, body, None, torch.Generator().manual_seed(0), seen)
    dropped = reader.elbo(g.yn, g.y3d, g.betas, body, g.weight, torch.Generator().manual_seed(0))
    assert hidden["rec"] > dropped["rec"]  # the hidden frames are scored
    hidden["loss"].backward()
    assert reader.hole_reader.weight.grad.abs().sum() > 0


def test_the_learned_fill_takes_a_clean_takes_own_curve_and_a_noisy_takes_networks():
    from mdvae_cli.infer.fill import fill_holes, input_curve
    from mdvae_cli.infer.fill_choices import fill_for

    assert fill_for("curve", True) == "learned" and fill_for("curve", False) == "curve"
    assert fill_for("off", True) == "off" and fill_for("model", True) == "model"

    src = clip(120, seed=3)
    mask = np.ones((120, 22), bool)
    mask[50:62] = False
    miss = ~mask[:, 0]
    result = src.with_body(pose_body=src.pose_body + 0.02)
    # clean: the take's own curve in the hole, the result elsewhere
    clean = with_holes(src, mask)
    learned = fill_holes(clean, result, "learned")
    np.testing.assert_allclose(
        learned.pose_body[miss], input_curve(clean).pose_body[miss], atol=1e-3
    )
    np.testing.assert_array_equal(learned.pose_body[~miss], result.pose_body[~miss])
    # noisy: the networks' own frames in the hole (not the curve from the result's frames)
    rng = np.random.default_rng(0)
    noisy = src.with_body(pose_body=src.pose_body + rng.normal(0, 0.1, src.pose_body.shape))
    holed = with_holes(noisy, mask)
    learned = fill_holes(holed, result, "learned")
    np.testing.assert_allclose(learned.pose_body[miss], result.pose_body[miss], atol=1e-3)
    curve = fill_holes(holed, result, "curve")
    assert np.abs(curve.pose_body[miss] - result.pose_body[miss]).max() > 1e-3
