"""Feet and floor: contacts on a synthetic walk, sole points and the floor (motion/contacts.py),
and the foot metrics (foot_metrics.py, mdvae eval)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import motion_arrays

from mdvae_cli.body.builtin import builtin_body_model
from mdvae_cli.errors import InputError
from mdvae_cli.foot_metrics import (
    SLIDE_SPEED,
    compare_feet,
    contact_slide_speeds,
    foot_scores,
    penetration_depths,
)
from mdvae_cli.formats.npz_io import motion_from_arrays
from mdvae_cli.metrics import evaluate_pair, mean_result
from mdvae_cli.motion.contacts import (
    SPEED_MAX,
    contacts_of_feet,
    estimate_floor,
    foot_contacts,
    foot_of_joints,
    foot_vertex_ids,
)

FPS = 30.0
T = 60
# left foot: stance 0-19, swing 20-39, stance 40-59; right foot: swing 0-9, stance 10-49, swing
LEFT_STANCE = [(0, 20), (40, 60)]
RIGHT_STANCE = [(10, 50)]
ANKLE_Z, BALL_Z = 0.08, 0.03


def _foot_track(stances: list[tuple[int, int]], y: float) -> np.ndarray:
    """Ankle and ball positions (T, 2, 3) of one foot: still in each stance, then a 0.7 m step
    lifted 15 cm at its middle (sin^2 profiles, so it leaves and lands with zero speed)."""
    out = np.zeros((T, 2, 3))
    x = 0.0
    for t in range(T):
        swing = next(((a, b) for a, b in _swings(stances) if a <= t < b), None)
        if swing is None:
            out[t, :, 0] = x + np.array([0.0, 0.15])
            out[t, :, 2] = (ANKLE_Z, BALL_Z)
            continue
        a, b = swing
        u = (t - a + 1) / (b - a + 1)
        out[t, :, 0] = x + 0.7 * np.sin(0.5 * np.pi * u) ** 2 + np.array([0.0, 0.15])
        out[t, :, 2] = np.array([ANKLE_Z, BALL_Z]) + 0.15 * np.sin(np.pi * u)
        if t == b - 1:
            x += 0.7
    out[..., 1] = y
    return out


def _swings(stances):
    ends = [0] + [s for pair in stances for s in pair] + [T]
    gaps = list(zip(ends[::2], ends[1::2], strict=True))
    return [(a, b) for a, b in gaps if b > a]


def walk_joints() -> np.ndarray:
    """(T, 22, 3) joints whose feet walk as described above (other joints at the pelvis)."""
    joints = np.zeros((T, 22, 3))
    joints[:, :, 2] = 0.9
    left, right = _foot_track(LEFT_STANCE, 0.1), _foot_track(RIGHT_STANCE, -0.1)
    joints[:, [7, 10]] = left
    joints[:, [8, 11]] = right
    return joints


def stance_mask(stances) -> np.ndarray:
    m = np.zeros(T, dtype=bool)
    for a, b in stances:
        m[a:b] = True
    return m


def test_contacts_of_a_synthetic_walk():
    contacts = foot_contacts(walk_joints(), FPS)
    assert contacts.shape == (T, 4) and contacts.dtype == bool
    for col, stances in ((0, LEFT_STANCE), (2, LEFT_STANCE), (1, RIGHT_STANCE), (3, RIGHT_STANCE)):
        stance = stance_mask(stances)
        # every stance frame but the one next to a swing (its central difference sees the
        # step) is a contact, and no swing frame is
        inner = stance & np.r_[True, stance[:-1]] & np.r_[stance[1:], True]
        assert contacts[inner, col].all()
        assert not contacts[~stance, col].any()
        assert (stance & ~inner).sum() == 2  # two stance-swing boundaries per foot
    feet = foot_of_joints(contacts)
    assert feet.shape == (T, 2) and np.array_equal(feet[:, 0], contacts[:, 0] | contacts[:, 2])


def test_contacts_adapt_to_the_floor_and_can_be_given_it():
    joints = walk_joints()
    raised = joints + np.array([0.0, 0.0, 1.0])  # the same walk on a floor 1 m higher
    assert np.array_equal(foot_contacts(raised, FPS), foot_contacts(joints, FPS))
    # the levels of the floor below: nothing is low any more
    assert not foot_contacts(raised, FPS, floor=np.array([0.08, 0.08, 0.03, 0.03])).any()
    feet = joints[:, [7, 8, 10, 11]]
    assert np.array_equal(contacts_of_feet(feet, FPS), foot_contacts(joints, FPS))


def test_thresholds_are_the_documented_ones():
    joints = walk_joints()
    slow = joints.copy()
    slow[:, 7, 0] += 0.9 * SPEED_MAX / FPS * np.arange(T)  # the left ankle creeping: still slow
    assert foot_contacts(slow, FPS)[:19, 0].all()  # (frame 19 sees the step)
    fast = joints.copy()
    fast[:, 7, 0] += 1.1 * SPEED_MAX / FPS * np.arange(T)
    assert not foot_contacts(fast, FPS)[:, 0].any()
    high = joints.copy()
    high[:20, 7, 2] += 0.06  # 6 cm above its level (the other stance keeps it): not low
    assert not foot_contacts(high, FPS)[:20, 0].any()


def test_bad_shapes_are_refused():
    with pytest.raises(InputError, match="4, 3"):
        contacts_of_feet(np.zeros((5, 22, 3)), FPS)
    with pytest.raises(InputError, match="frame rate"):
        contacts_of_feet(np.zeros((5, 4, 3)), 0.0)


def test_floor_is_the_median_sole_where_the_feet_are_down():
    soles = np.array([[0.01, 0.5], [0.02, 0.5], [0.03, 0.5], [0.5, 0.04]])
    down = np.array([[True, False], [True, False], [True, False], [False, True]])
    assert estimate_floor(soles, down) == pytest.approx(0.025)  # median of .01 .02 .03 .04
    assert estimate_floor(soles, np.zeros_like(down)) == pytest.approx(
        np.percentile(soles, 5)
    )  # no contact: a low percentile


def test_foot_vertices_of_the_builtin_body():
    data = builtin_body_model()
    left, right = foot_vertex_ids(data.weights)
    assert len(left) == len(right) > 100
    # rest pose: y up, the body's left is +x; the feet are the lowest part of the body
    assert (data.v_template[left, 0] > 0).all() and (data.v_template[right, 0] < 0).all()
    assert data.v_template[left, 1].min() == pytest.approx(data.v_template[:, 1].min())


# --------------------------------------------------------------------------------------------
# metrics


def test_a_foot_sliding_at_known_speed_gives_that_skate():
    joints = walk_joints()
    contacts = np.zeros((T, 4), dtype=bool)
    contacts[:20, 0] = True  # the left ankle only, frames 0-19: 19 pairs
    pred = joints.copy()
    pred[:, 7, 0] += 0.2 / FPS * np.arange(T)  # sliding along x at 0.2 m/s
    speeds = contact_slide_speeds(pred, contacts, FPS)
    assert speeds.shape == (19,) and np.allclose(speeds, 0.2)
    soles = np.zeros((T, 2))
    score = foot_scores(pred, soles, contacts, 0.0, FPS).means()
    assert score["skate"] == pytest.approx(20.0) and score["slide"] == 0.0
    pred[:, 7, 1] += 0.9 / FPS * np.arange(T)  # now 0.92 m/s: every pair slides
    score = foot_scores(pred, soles, contacts, 0.0, FPS).means()
    assert score["skate"] == pytest.approx(100 * np.hypot(0.2, 0.9)) and score["slide"] == 100
    assert SLIDE_SPEED == pytest.approx(0.02 * 30)  # 2 cm per frame at 30 Hz


def test_a_foot_at_known_depth_gives_that_penetration_and_float():
    joints = walk_joints()
    contacts = foot_contacts(joints, FPS)
    soles = np.zeros((T, 2))
    soles[:, 0] = -0.02  # the left foot 2 cm under the floor all the time, the right on it
    assert np.allclose(penetration_depths(soles, 0.0)[:, 0], 0.02)
    score = foot_scores(joints, soles, contacts, 0.0, FPS).means()
    assert score["penetration"] == pytest.approx(1.0)  # mean over both feet, cm
    assert score["float"] == 0.0
    soles[:, 0] = 0.01  # 1 cm above: floats 1 cm wherever the left foot is down
    down = foot_of_joints(contacts)
    score = foot_scores(joints, soles, contacts, 0.0, FPS).means()
    assert score["penetration"] == 0.0
    assert score["float"] == pytest.approx(1.0 * down[:, 0].sum() / down.sum())


def test_compare_feet_scores_prediction_on_the_ground_truths_contacts():
    joints = walk_joints()
    soles = np.full((T, 2), 0.003)
    fields = compare_feet(joints, soles, joints, soles, FPS)
    assert fields["floor_m"] == pytest.approx(0.003)
    assert fields["foot_skate_gt"] == fields["foot_skate_pred"] == pytest.approx(0.0, abs=1e-9)
    assert fields["penetration_pred"] == 0 and fields["float_pred"] == 0
    assert fields["contact_pairs"] > 100 and fields["contact_frames"] > 60
    sunk = soles - 0.01  # the prediction 1 cm lower: penetrates 1 cm, the truth does not
    fields = compare_feet(joints, soles, joints, sunk, FPS)
    assert fields["penetration_pred"] == pytest.approx(1.0) and fields["penetration_gt"] == 0


def test_evaluate_pair_reports_feet_and_means_weigh_by_contacts(tiny_body):
    arrays = motion_arrays(T=40, seed=1)
    arrays["poses"] *= 0.1  # standing nearly still: the feet are down
    arrays["trans"][:] = arrays["trans"][0]
    gt = motion_from_arrays(arrays, "gt.npz")
    same = evaluate_pair(gt, gt, tiny_body)
    assert same.contact_pairs > 0 and same.floor_m is not None
    assert same.foot_skate_pred == pytest.approx(same.foot_skate_gt)
    assert same.penetration_pred == pytest.approx(same.penetration_gt)
    pred = gt.with_body(trans=gt.trans + np.array([0.0, 0.0, -0.05]))  # 5 cm lower
    low = evaluate_pair(gt, pred, tiny_body)
    assert low.penetration_pred > same.penetration_gt + 1.0  # cm
    a = same.__class__(**{**same.to_dict(), "foot_skate_pred": 10.0, "contact_pairs": 1})
    b = same.__class__(**{**same.to_dict(), "foot_skate_pred": 40.0, "contact_pairs": 3})
    assert mean_result([a, b]).foot_skate_pred == pytest.approx(32.5)  # (10 + 3 * 40) / 4
    assert mean_result([a, b]).contact_pairs == 4


def test_eval_and_the_view_page_find_contacts_by_one_rule():
    """``mdvae eval`` scores the feet where ``mdvae view`` and ``mdvae plot`` mark contacts:
    one function, and its numbers are what ``mdvae eval --help`` states."""
    from click.testing import CliRunner

    from mdvae_cli import foot_metrics
    from mdvae_cli.cli.main import cli
    from mdvae_cli.motion import contacts
    from mdvae_cli.view import figure, page

    assert foot_metrics.foot_contacts is contacts.foot_contacts is page.foot_contacts
    assert figure.foot_contacts is contacts.foot_contacts
    text = " ".join(CliRunner().invoke(cli, ["eval", "--help"]).output.split())
    assert f"less than {100 * contacts.HEIGHT_TOL:g} cm above its own floor level" in text
    assert f"the {100 * contacts.FLOOR_QUANTILE:g} % quantile of its height" in text
    assert f"slower than {contacts.SPEED_MAX:g} m/s" in text
    assert f"faster than {foot_metrics.SLIDE_SPEED:g} m/s" in text
