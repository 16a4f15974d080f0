"""Long holes bridged (``infer.bridge``): where the bridges lie, how a bridge's fill is turned to
meet the pieces, and a noisy take's long hole filled from both sides while the frames it has
come back as its pieces made them."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_holes import clip, rotation_gap

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.geometry.rotations import quat_multiply, quat_to_rotvec, rotvec_to_quat
from mdvae_cli.infer import pieces as pieces_module
from mdvae_cli.infer.bridge import bridge_spans, bridged_holes, meet_ends
from mdvae_cli.infer.denoise import denoise_motions
from mdvae_cli.infer.feet import FootLockConfig
from mdvae_cli.infer.fill import fill_holes
from mdvae_cli.model.denoiser import load_denoiser
from mdvae_cli.motion.holes import with_holes
from mdvae_cli.motion.motion import Motion, slice_frames


def test_bridges_lie_between_two_pieces_with_two_seconds_each_side():
    assert bridged_holes(300, 30.0, [(0, 100), (130, 300)]) == [(40, 100, 130, 190)]
    # clipped to the take; a hole before the first piece or after the last has no bridge
    assert bridged_holes(150, 30.0, [(10, 60), (90, 140)]) == [(0, 60, 90, 150)]
    assert bridged_holes(150, 30.0, [(10, 140)]) == []
    assert bridged_holes(2000, 120.0, [(0, 500), (600, 2000)]) == [(260, 500, 600, 840)]
    holes = bridged_holes(400, 30.0, [(0, 100), (130, 200), (230, 400)])
    assert holes == [(40, 100, 130, 190), (140, 200, 230, 290)]
    assert bridge_spans(holes) == [(40, 290)]  # overlapping bridges denoised as one
    assert bridge_spans([(0, 10, 20, 30), (40, 50, 60, 70)]) == [(0, 30), (40, 70)]


def _turned(z: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """Rotations (..., 3) turned by rotation vectors z (..., 3) put before them."""
    q = quat_multiply(rotvec_to_quat(torch.as_tensor(z)), rotvec_to_quat(torch.as_tensor(rot)))
    return quat_to_rotvec(q).numpy()


def _with(m: Motion, rot: np.ndarray, trans: np.ndarray, mask=None) -> Motion:
    out = m.with_body(root_orient=rot[:, 0], pose_body=rot[:, 1:], trans=trans)
    out.joint_mask = mask
    return out


def test_meet_ends_keeps_the_frames_there_and_turns_the_bridge_onto_them():
    base = clip(40, seed=1)
    rot_b = base.joint_rotations.astype(np.float64)
    mask = np.ones((40, 22), bool)
    mask[15:24] = False
    hole = [(0, 15, 24, 40)]
    # the same turn on both ends: the hole is the bridge turned by it, exactly
    turn = np.zeros((40, 22, 3))
    turn[..., 2] = 0.2
    rot_f = _turned(turn, rot_b)
    rot_f[15:24] = 0.0  # placeholders
    filled = _with(base, rot_f, base.trans + [0.1, 0.0, 0.0], mask)
    out = meet_ends(filled, _with(base, rot_b, base.trans), hole)
    np.testing.assert_array_equal(out.joint_rotations[mask], filled.joint_rotations[mask])
    np.testing.assert_allclose(out.joint_rotations[15:24], _turned(turn, rot_b)[15:24], atol=1e-6)
    np.testing.assert_allclose(out.trans[15:24], base.trans[15:24] + [0.1, 0.0, 0.0], atol=1e-12)
    # 0.2 rad before the hole, 0.4 after: the hole's middle frame (5th of 9) turned by 0.3
    turn[24:, ..., 2] = 0.4
    rot_f = _turned(turn, rot_b)
    out = meet_ends(_with(base, rot_f, base.trans, mask), _with(base, rot_b, base.trans), hole)
    mid = np.zeros((22, 3))
    mid[:, 2] = 0.3
    np.testing.assert_allclose(out.joint_rotations[19], _turned(mid, rot_b[19]), atol=1e-6)


@pytest.fixture(scope="module")
def model():
    den, _ = load_denoiser(None)
    return den, BodyModel(load_body_model(None))


def noisy_take_with_a_long_hole() -> tuple[Motion, Motion, np.ndarray]:
    """A 10 s clip, the same with noise of 0.1 rad and 0.5 s missing, and the hole's frames."""
    src = clip(300, seed=8)
    rng = np.random.default_rng(3)
    noisy = src.with_body(pose_body=src.pose_body + rng.normal(0, 0.1, src.pose_body.shape))
    mask = np.ones((300, 22), bool)
    mask[140:155] = False
    return src, with_holes(noisy, mask), ~mask[:, 0]


def test_a_long_hole_is_filled_from_both_sides_and_the_rest_comes_as_its_pieces_made_it(
    model, monkeypatch
):
    den, body = model
    src, holed, miss = noisy_take_with_a_long_hole()
    feet = FootLockConfig()
    run = lambda ms: denoise_motions(ms, den, body, blend=True, feet=feet)  # noqa: E731
    out = run([holed])[0]
    before, after = run([slice_frames(holed, 0, 140), slice_frames(holed, 155, 300)])
    np.testing.assert_allclose(out.pose_body[:140], before.pose_body, atol=1e-6)
    np.testing.assert_allclose(out.pose_body[155:], after.pose_body, atol=1e-6)
    np.testing.assert_allclose(out.trans[:140], before.trans, atol=1e-9)
    # the fill meets the pieces: no step into or out of the hole beyond the take's own
    steps = rotation_gap(out.pose_body[1:], out.pose_body[:-1]).mean(axis=1)
    assert max(steps[139], steps[154]) < 2.5 * np.median(steps)
    # without bridges (each side's own ends drawn over the hole) the fill is further away
    monkeypatch.setattr(
        pieces_module, "bridge_fills",
        lambda ms, pieces, joined, method, _, spline: [fill_holes(m, j, method, spline)
                                                       for m, j in zip(ms, joined, strict=True)],
    )  # fmt: skip
    plain = run([holed])[0]
    err = lambda m: rotation_gap(m.pose_body[miss], src.pose_body[miss]).mean()  # noqa: E731
    print(f"hole error: bridged {err(out):.4f} rad, ends only {err(plain):.4f}")
    assert err(out) < 0.92 * err(plain)  # 0.217 against 0.248 rad when written


def test_fill_off_denoises_no_bridge_and_the_frames_it_has_come_as_with_a_fill(model, monkeypatch):
    den, body = model
    _, holed, miss = noisy_take_with_a_long_hole()
    phases: list[str] = []

    def run(fill: str) -> Motion:
        tell = lambda info: phases.append(info.get("phase"))  # noqa: E731
        return denoise_motions([holed], den, body, blend=True, feet=FootLockConfig(),
                               fill=fill, progress=tell)[0]  # fmt: skip

    curve = run("curve")
    assert [p for p in phases if p] == [
        "windows denoised", "stitched", "blended", "holes filled", "feet locked"
    ]  # fmt: skip

    def no_bridges(*_):
        raise AssertionError("a bridge denoised for --fill off")

    monkeypatch.setattr(pieces_module, "bridge_fills", no_bridges)
    monkeypatch.setattr(pieces_module, "lock_bridged", no_bridges)
    phases.clear()
    off = run("off")
    assert [p for p in phases if p] == ["windows denoised", "stitched", "blended", "feet locked"]
    # the frames it has: its pieces', locked piece by piece, as the curve's fill has them
    np.testing.assert_array_equal(off.pose_body[~miss], curve.pose_body[~miss])
    np.testing.assert_array_equal(off.trans[~miss], curve.trans[~miss])
    # the hole: as it came, and still marked missing
    np.testing.assert_array_equal(off.pose_body[miss], holed.pose_body[miss])
    np.testing.assert_array_equal(off.joint_mask, holed.joint_mask)
    assert not np.allclose(curve.pose_body[miss], holed.pose_body[miss])
