"""Foot locking (infer/feet.py, infer/leg_ik.py) and ``mdvae denoise --feet``."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.cli.main import cli
from mdvae_cli.export import pose_motion_chunks
from mdvae_cli.formats.npz_io import load_motion, save_motion
from mdvae_cli.geometry.rotations_np import rotmat_to_rotvec, rotvec_to_rotmat
from mdvae_cli.infer import leg_ik
from mdvae_cli.infer.contact_runs import (
    clean_contacts,
    contact_runs,
    fade_weights,
    hold_targets,
    run_means,
)
from mdvae_cli.infer.feet import FootLockConfig, for_noise, input_jitter, lock_feet
from mdvae_cli.motion.contacts import foot_vertex_ids
from mdvae_cli.motion.motion import Motion

FPS = 30.0
LEG_ROWS = [0, 1, 3, 4, 6, 7]  # pose_body rows of hips, knees, ankles


@pytest.fixture(scope="module")
def body() -> BodyModel:
    return BodyModel(load_body_model(None))


def crouch(T: int) -> Motion:
    """The built-in body standing z-up, knees a little bent, pelvis still over the origin."""
    pose = np.zeros((T, 21, 3))
    pose[:, [0, 1], 0] = -0.3  # hips flexed
    pose[:, [3, 4], 0] = 0.6  # knees bent
    pose[:, [6, 7], 0] = -0.3  # ankles: feet flat again
    root = np.tile([np.pi / 2, 0.0, 0.0], (T, 1))  # y-up body -> z-up world
    return Motion(root_orient=root, pose_body=pose, trans=np.zeros((T, 3)), betas=np.zeros(10),
                  fps=FPS)  # fmt: skip


def feet_and_soles(motion: Motion, body: BodyModel) -> tuple[np.ndarray, np.ndarray]:
    """Foot joints (T, 4, 3) and lowest foot-vertex heights (T, 2) from the full mesh."""
    left, right = foot_vertex_ids(body.data.weights)
    joints, soles = [], []
    for _, out in pose_motion_chunks(motion, body, 256, vertices=True):
        joints.append(out.joints[:, [7, 8, 10, 11]].double().numpy())
        z = out.vertices[..., 2].double().numpy()
        soles.append(np.stack([z[:, left].min(1), z[:, right].min(1)], 1))
    return np.concatenate(joints), np.concatenate(soles)


def sliding_then_jumping(body: BodyModel) -> Motion:
    """Frames 0-44: standing with both feet sliding along x at 10 cm/s; 45-89: 0.5 m up in
    the air (no contact)."""
    m = crouch(90)
    m.trans[:, 0] = 0.1 / FPS * np.arange(90)
    m.trans[45:, 2] = 0.5
    floor = feet_and_soles(m, body)[1][0].min()
    m.trans[:, 2] -= floor  # soles on z = 0
    return m


# --------------------------------------------------------------------------------------------
# contacts over time, targets


def test_clean_contacts_fills_gaps_drops_short_ones_and_extends():
    c = np.zeros((20, 1), dtype=bool)
    c[2:6] = c[7:10] = True  # a 1-frame gap: filled -> 2..9
    c[14:15] = True  # a 1-frame contact: dropped
    out = clean_contacts(c, min_frames=3, max_gap=2, extend=1)
    assert contact_runs(out[:, 0]) == [(1, 11)]
    assert contact_runs(clean_contacts(c, 3, 0, 0)[:, 0]) == [(2, 6), (7, 10)]


def test_fade_weights_fall_off_around_a_contact():
    c = np.zeros((10, 1), dtype=bool)
    c[3:5] = True
    w = fade_weights(c, blend=2)
    assert np.allclose(w[3:5, 0], 1.0)
    # after the run: smoothstep of 2/3, 1/3, 0; before: the same, mirrored
    assert np.allclose(w[5:8, 0, 0], [20 / 27, 7 / 27, 0.0])
    assert np.allclose(w[0:3, 0, 1], [0.0, 7 / 27, 20 / 27])
    assert np.allclose(w[8:, 0], 0.0) and np.allclose(w[:3, 0, 0], 0.0)


def test_hold_targets_holds_the_goal_and_leaves_far_frames():
    T = 30
    pos = np.zeros((T, 1, 3))
    pos[:, 0, 0] = 0.01 * np.arange(T)  # sliding 1 cm per frame
    c = np.zeros((T, 1), dtype=bool)
    c[10:20] = True
    goals = pos.copy()
    goals[10:20, 0, 0] = 0.145  # the run's mean
    targets = hold_targets(pos, c, goals, fade_weights(c, 3))
    assert np.allclose(targets[10:20, 0, 0], 0.145)
    assert np.array_equal(targets[:6], pos[:6]) and np.array_equal(targets[24:], pos[24:])
    # next to the run the correction is nearly all there, then fades
    shifts = targets[20:24, 0, 0] - pos[20:24, 0, 0]
    assert shifts[0] < 0 and np.all(np.diff(np.abs(shifts)) < 0)


def test_a_pinned_fade_keeps_the_joint_near_its_goal_next_to_the_run():
    T = 30
    pos = np.zeros((T, 1, 3))
    pos[:, 0, 0] = 0.01 * np.arange(T)  # sliding 1 cm per frame, in and out of the run
    pos[:, 0, 2] = 0.002 * np.arange(T)
    c = np.zeros((T, 1), dtype=bool)
    c[10:20] = True
    goals = pos.copy()
    goals[10:20, 0, 0] = 0.145
    w = fade_weights(c, 3)
    shifted, pinned = hold_targets(pos, c, goals, w), hold_targets(pos, c, goals, w, pin=1.0)
    assert np.array_equal(pinned[10:20], shifted[10:20])  # in the run: the goal either way
    assert np.array_equal(pinned[..., 2], shifted[..., 2])  # heights fade as before
    assert np.array_equal(pinned[:6], pos[:6]) and np.array_equal(pinned[24:], pos[24:])
    # the frame after the run (weight 0.84) and the one before it: shifted, the joint moves
    # on with the motion and the fade (1.70 cm); pinned (by the weight squared, 0.71), by
    # 0.99 cm, the rest of the way being made up further out in the swing
    steps = lambda t: np.diff(t[:, 0, 0])  # noqa: E731
    assert steps(shifted)[[19, 9]] == pytest.approx([0.01703125] * 2)
    assert steps(pinned)[[19, 9]] == pytest.approx([0.00991211] * 2, abs=1e-8)
    assert steps(pinned)[20:23] == pytest.approx([0.02758789, 0.02973633, 0.01776367], abs=1e-8)
    assert np.allclose(hold_targets(pos, c, goals, w, pin=0.5), (shifted + pinned) / 2)


def _naive_fades_means_targets(c, blend, values, goals):
    """Per-run loops (the plain reading of the docstrings) for the vectorised helpers."""
    T, K = c.shape
    t = np.arange(T)
    smooth = lambda u: np.clip(u, 0, 1) ** 2 * (3 - 2 * np.clip(u, 0, 1))  # noqa: E731
    w, means = np.zeros((T, K, 2)), values.copy()
    shift = np.where(c[..., None], goals - values, 0.0)
    ends = np.zeros((T, K, 2, 3))
    for k in range(K):
        runs = contact_runs(c[:, k])
        for i, (start, stop) in enumerate(runs):
            w[:, k, 0] = np.maximum(
                w[:, k, 0], smooth(1 - (t - stop + 1) / (blend + 1)) * (t >= stop)
            )
            w[:, k, 1] = np.maximum(w[:, k, 1], smooth(1 - (start - t) / (blend + 1)) * (t < start))
            w[start:stop, k] = 1.0
            means[start:stop, k] = values[start:stop, k].mean(0)
            ends[stop : runs[i + 1][0] if i + 1 < len(runs) else T, k, 0] = shift[stop - 1, k]
            ends[runs[i - 1][1] if i else 0 : start, k, 1] = shift[start, k]
    total = w.sum(-1, keepdims=True)
    w = np.where(~c[..., None] & (total > 1), w / np.maximum(total, 1e-12), w)
    targets = values + np.where(c[..., None], shift, (w[..., None] * ends).sum(-2))
    return w, means, targets


def test_run_helpers_match_per_run_loops_on_a_long_take():
    rng = np.random.default_rng(5)
    T = 5000  # ~1,000 runs per column
    c = rng.random((T, 4)) < 0.6
    values, goals = rng.normal(size=(T, 4, 3)), rng.normal(size=(T, 4, 3))
    w, means, targets = _naive_fades_means_targets(c, 6, values, goals)
    assert np.allclose(fade_weights(c, 6), w, atol=1e-12)
    assert np.allclose(run_means(values, c), means, atol=1e-9)
    assert np.allclose(hold_targets(values, c, goals, w), targets, atol=1e-12)
    cleaned = clean_contacts(c, min_frames=3, max_gap=2, extend=2)
    for k in range(4):  # gaps of <= 2 filled, then runs >= 3 kept and extended by 2
        filled = c[:, k].copy()
        runs = contact_runs(filled)
        for (_, stop), (start, _) in zip(runs[:-1], runs[1:], strict=True):
            filled[stop:start] |= start - stop <= 2
        want = np.zeros(T, dtype=bool)
        for start, stop in contact_runs(filled):
            if stop - start >= 3:
                want[max(start - 2, 0) : stop + 2] = True
        assert np.array_equal(cleaned[:, k], want)


def test_input_jitter_reads_white_noise_and_ignores_still_feet():
    rng = np.random.default_rng(0)
    still = np.zeros((400, 4, 3))
    assert input_jitter(still) == 0.0
    noisy = still + rng.normal(0, 0.01, size=still.shape)
    assert input_jitter(noisy) == pytest.approx(0.01 * 1.538, rel=0.05)  # median of chi(3)


def test_a_noisier_input_gets_wider_contact_thresholds():
    cfg = FootLockConfig()
    assert for_noise(cfg, 0.0) == cfg and for_noise(cfg, cfg.noisy_from) == cfg
    loud = for_noise(cfg, 1.0)
    assert (loud.height_tol, loud.speed_tol, loud.keep) == (
        cfg.noisy_height_tol, cfg.noisy_speed_tol, cfg.noisy_keep
    )  # fmt: skip
    half = for_noise(cfg, (cfg.noisy_from + cfg.noisy_to) / 2)
    assert half.height_tol == pytest.approx((cfg.height_tol + cfg.noisy_height_tol) / 2)
    assert half.keep == pytest.approx((cfg.keep + cfg.noisy_keep) / 2)
    assert half.smooth_s == cfg.smooth_s  # the rest as it was


def test_config_is_checked():
    with pytest.raises(ValueError, match="keep"):
        FootLockConfig(keep=1.5)
    with pytest.raises(ValueError, match="pin"):
        FootLockConfig(pin=-0.5)
    with pytest.raises(ValueError, match="blend_s"):
        FootLockConfig(blend_s=-1)
    with pytest.raises(ValueError, match="distrust_above"):
        FootLockConfig(trust_below=0.1, distrust_above=0.05)
    with pytest.raises(ValueError, match="noisy_to"):
        FootLockConfig(noisy_from=0.2, noisy_to=0.1)


# --------------------------------------------------------------------------------------------
# leg IK


def chain_of(motion: Motion, model: leg_ik.LegModel):
    root = rotvec_to_rotmat(motion.root_orient)
    return root, leg_ik.leg_rotations(motion), motion.trans + model.pelvis


def test_leg_chain_matches_the_body_model(body):
    m = crouch(5)
    m.pose_body += np.random.default_rng(1).normal(0, 0.2, size=m.pose_body.shape)
    model = leg_ik.LegModel.build(body, m.betas)
    pos, soles = leg_ik.pose_legs(m, model)
    feet, mesh_soles = feet_and_soles(m, body)
    assert np.abs(pos[:, :, 2:].transpose(0, 2, 1, 3).reshape(5, 4, 3) - feet).max() < 1e-5
    assert np.abs(soles - mesh_soles).max() < 1e-5


def test_a_free_knee_reaches_reachable_targets_and_changes_nothing_on_the_spot(body):
    """swing_ik with no stiffness: the knee turns as far as the target needs (closed form)."""
    rng = np.random.default_rng(2)
    m = crouch(40)
    m.pose_body += rng.normal(0, 0.15, size=m.pose_body.shape)
    model = leg_ik.LegModel.build(body, m.betas)
    root, legs, pelvis = chain_of(m, model)
    flexion = m.pose_body[:, [3, 4], 0]
    held = np.ones((40, 2, 2), dtype=bool)
    pos, _ = leg_ik.leg_chain(root, legs, pelvis, model.bones)
    same = leg_ik.swing_ik(root, legs, pelvis, model.bones, pos[:, :, 2:], held, flexion, 0.0)
    assert np.abs(same - legs).max() < 1e-12
    # targets from another pose: hips and ankles turned any way, knees about their hinge
    other = m.with_body(pose_body=m.pose_body.copy())
    other.pose_body[:, [0, 1, 6, 7]] += rng.normal(0, 0.1, size=(40, 4, 3))
    other.pose_body[:, [3, 4], 0] += rng.normal(0, 0.1, size=(40, 2))
    goal, _ = leg_ik.leg_chain(root, leg_ik.leg_rotations(other), pelvis, model.bones)
    new = leg_ik.swing_ik(root, legs, pelvis, model.bones, goal[:, :, 2:], held, flexion, 0.0)
    reached, _ = leg_ik.leg_chain(root, new, pelvis, model.bones)
    # the ankle on the midpoint of its goal and where the ball's goal puts the foot as it was
    both = 0.5 * (goal[:, :, 2] + pos[:, :, 2] + goal[:, :, 3] - pos[:, :, 3])
    miss = np.linalg.norm(reached[:, :, 2] - both, axis=-1)
    assert np.median(miss) < 1e-12 and miss.max() < 2e-3  # (a midpoint past a knee's reach)
    # the foot turned with the hip's swing alone: the knee's turn undone at the ankle
    _, G0 = leg_ik.leg_chain(root, legs, pelvis, model.bones)
    _, G = leg_ik.leg_chain(root, new, pelvis, model.bones)
    swing = G[:, :, 0] @ G0[:, :, 0].swapaxes(-1, -2)
    assert np.abs(G[:, :, 2] - swing @ G0[:, :, 2]).max() < 1e-9
    assert np.array_equal(new[:, :, 3], legs[:, :, 3])  # the ball's own rotation is kept


def test_a_free_knee_straightens_toward_a_target_out_of_reach(body):
    m = crouch(1)
    model = leg_ik.LegModel.build(body, m.betas)
    root, legs, pelvis = chain_of(m, model)
    pos, _ = leg_ik.leg_chain(root, legs, pelvis, model.bones)
    far = pos[:, :, 2:] + np.array([0.0, 0.0, -1.0])  # a metre below the feet
    held = np.array([[[True, False], [True, False]]])
    flexion = np.full((1, 2), 0.6)
    new = leg_ik.swing_ik(root, legs, pelvis, model.bones, far, held, flexion, 0.0)
    after, _ = leg_ik.leg_chain(root, new, pelvis, model.bones)
    hip, knee, ankle = after[0, :, 0], after[0, :, 1], after[0, :, 2]
    thigh, shin = np.linalg.norm(knee - hip, axis=-1), np.linalg.norm(ankle - knee, axis=-1)
    # as far as the knee's hinge goes (the rest leg is not quite straight)
    reach = np.linalg.norm(ankle - hip, axis=-1)
    assert np.all(reach > 0.995 * (thigh + shin)) and np.all(reach <= thigh + shin)
    # the miss goes to the height: the ankle stands over its target
    assert np.allclose(ankle[:, :2], far[0, :, 0, :2], atol=1e-9)
    assert np.all(ankle[:, 2] > far[0, :, 0, 2] + 0.5)


# --------------------------------------------------------------------------------------------
# lock_feet


def test_lock_brings_a_sliding_foot_to_rest_and_leaves_the_rest(body):
    m = sliding_then_jumping(body)
    locked = lock_feet(m, body, FootLockConfig(keep=0.0))
    before, soles_before = feet_and_soles(m, body)
    after, soles_after = feet_and_soles(locked, body)
    speed = lambda f: np.linalg.norm(np.diff(f[..., :2], axis=0), axis=-1) * FPS  # noqa: E731
    assert np.allclose(speed(before)[:40], 0.1, atol=1e-4)
    # was 10 cm/s: now still (the balls within 6 mm/s: the foot turns with the leg's swing
    # about the hip, which changes as the body slides over the held ankle)
    assert speed(after)[3:38, :2].max() < 1e-5 and speed(after)[3:38].max() < 0.006
    # kept on the floor (the knee keeps most of its bend: the swing about the hip leaves the
    # soles a little off, the foot keeping its world orientation)
    assert np.abs(soles_after[:40] - soles_before[:40]).max() < 4e-3
    # only hips, knees and ankles change, and only near the contact (fade 0.2 s = 6 frames)
    changed = np.abs(locked.pose_body - m.pose_body).max(axis=2)
    # the hips move over the held ankles on every frame of the contact but where already on
    # anchor (a knee or ankle the solve leaves as it was may stay bit for bit)
    assert (changed[:40][:, LEG_ROWS[:2]] > 1e-6).all(1).sum() >= 38
    assert (changed[:40][:, LEG_ROWS] > 1e-6).sum() >= 0.9 * 40 * len(LEG_ROWS)
    assert not np.delete(changed, LEG_ROWS, axis=1).any()
    assert np.array_equal(locked.root_orient, m.root_orient)
    assert np.array_equal(locked.trans, m.trans)
    last = np.flatnonzero(changed.any(1)).max()
    assert last <= 44 + 1 + 6
    assert np.array_equal(locked.pose_body[last + 1 :], m.pose_body[last + 1 :])  # bit-identical


def test_a_foot_turning_on_the_floor_keeps_its_turn(body):
    """A body turning half a turn on the spot over 2 s, both feet planted and turning with it
    (a pivot): the lock held each foot at its contact's mean place and aimed it there, turning
    it 35 degrees away from the motion's own and twisting the ankles by 38; the feet now turn
    only with the legs' swing about the hips."""
    m = crouch(60)
    turn = rotvec_to_rotmat(np.outer(np.linspace(0, np.pi, 60), [0.0, 0.0, 1.0]))
    m.root_orient = rotmat_to_rotvec(turn @ rotvec_to_rotmat(m.root_orient))
    m.trans[:, 2] -= feet_and_soles(m, body)[1].min()  # soles on z = 0
    locked = lock_feet(m, body, FootLockConfig())
    model = leg_ik.LegModel.build(body, m.betas)
    _, G0 = leg_ik.leg_chain(*chain_of(m, model), model.bones)
    _, G1 = leg_ik.leg_chain(*chain_of(locked, model), model.bones)
    turned = rotmat_to_rotvec(G0[:, :, 2].swapaxes(-1, -2) @ G1[:, :, 2])
    assert np.degrees(np.linalg.norm(turned, axis=-1)).max() < 6.0  # was 35
    ankle = rotmat_to_rotvec(rotvec_to_rotmat(m.pose_body[:, [6, 7]]).swapaxes(-1, -2)
                             @ rotvec_to_rotmat(locked.pose_body[:, [6, 7]]))  # fmt: skip
    assert np.degrees(np.linalg.norm(ankle, axis=-1)).max() < 2.0  # was 38.5


def test_toes_pointed_under_the_floor_are_not_lifted_by_turning_the_foot(body):
    """A foot pointing its toes 1 cm under the floor (a dancer's point) for 20 frames: the
    lock aimed the foot at the ball's goal on the floor, turning the ankle by 19.5 degrees and
    lifting the toes 4.2 cm; the foot now turns only with the leg's swing about the hip."""
    m = crouch(60)
    m.pose_body[20:40, 7, 0] += 0.3  # the right ankle: toes pointed down
    m.trans[:, 2] -= feet_and_soles(m, body)[1][:20].min()  # the flat feet's soles on z = 0
    locked = lock_feet(m, body, FootLockConfig())
    before, after = feet_and_soles(m, body)[0], feet_and_soles(locked, body)[0]
    assert before[:, 3, 2].min() < -0.009
    assert (after[:, 3, 2] - before[:, 3, 2]).max() < 0.006  # was 0.042
    ankle = rotmat_to_rotvec(rotvec_to_rotmat(m.pose_body[:, 7]).swapaxes(-1, -2)
                             @ rotvec_to_rotmat(locked.pose_body[:, 7]))  # fmt: skip
    assert np.degrees(np.linalg.norm(ankle, axis=-1)).max() < 2.0  # was 19.5 (the knee: 1.3)


def test_keep_leaves_that_share_of_the_slide(body):
    m = sliding_then_jumping(body)
    after, _ = feet_and_soles(lock_feet(m, body, FootLockConfig(keep=0.25)), body)
    speed = np.linalg.norm(np.diff(after[..., :2], axis=0), axis=-1) * FPS
    assert np.allclose(speed[5:36, :2], 0.025, atol=0.002)
    assert np.allclose(speed[5:36, 2:], 0.025, atol=0.004)  # balls: the foot turns with the leg


def test_a_foot_under_the_floor_is_lifted_onto_it(body):
    m = crouch(60)
    m.trans[:, 0] = 0.05 * np.arange(60)  # 1.5 m/s: too fast to be a contact
    on_floor = -feet_and_soles(m, body)[1].min()  # the height that puts the soles on z = 0
    m.trans[:, 2] = on_floor + 0.05 * np.sin(np.arange(60) / 5)  # bobbing 5 cm up and down
    m.trans[10:20, 0] = m.trans[10, 0]  # but still for 10 frames, on the floor: a contact
    m.trans[10:20, 2] = on_floor
    cfg = FootLockConfig(sunk_tol=0.02, pin=0.0)  # (a pinned fade holds the foot back: its IK
    locked = lock_feet(m, body, cfg)  # moves the sole by a millimetre or two beside the run)
    _, before = feet_and_soles(m, body)
    _, after = feet_and_soles(locked, body)
    # sunk more than sunk_tol: lifted onto the floor (the knee bends as far as that needs; the
    # foot, turned with the leg's swing and not aimed, within 3 mm of it);
    # less: left within sunk_tol (the knee keeps its bend rather than turn for a few mm)
    assert before.min() < -0.04 and after[before < -cfg.sunk_tol].min() > -0.003
    assert after.min() > -cfg.sunk_tol
    above = before > 0.001  # (next to the contact, its tiny correction fades out)
    assert np.abs(after[above] - before[above]).max() < 1e-4


def test_a_clean_input_keeps_its_own_feet(body):
    m = sliding_then_jumping(body)
    locked = lock_feet(m, body, source=m)  # trust the (clean) input: its feet are the goal
    before, _ = feet_and_soles(m, body)
    after, _ = feet_and_soles(locked, body)
    # its feet do not shake: they are the goal as they came (not smoothed, not lifted)
    # (they were smoothed over 0.05 s, which rounded the jump by centimetres)
    assert np.abs(after - before).max() < 1e-6
    noisy = m.with_body(
        pose_body=m.pose_body + np.random.default_rng(3).normal(0, 0.1, (90, 21, 3))
    )
    distrusted = lock_feet(m, body, source=noisy)
    assert np.array_equal(distrusted.pose_body, lock_feet(m, body).pose_body)
    with pytest.raises(ValueError, match="frames"):
        lock_feet(m, body, source=crouch(10))


def test_no_contact_gives_the_motion_back(body):
    m = crouch(30)
    m.trans[:, 0] = 0.1 * np.arange(30)  # 3 m/s
    out = lock_feet(m, body)
    assert np.array_equal(out.pose_body, m.pose_body) and out is not m


# --------------------------------------------------------------------------------------------
# the command


def test_cli_feet_lock_and_off(body, tmp_path):
    src = tmp_path / "take.npz"
    save_motion(sliding_then_jumping(body), src)
    outs = {}
    for mode in ("lock", "off"):
        res = CliRunner().invoke(
            cli, ["denoise", str(src), "-o", str(tmp_path / f"{mode}.npz"), "--feet", mode,
                  "--json"],
        )  # fmt: skip
        assert res.exit_code == 0, res.output
        assert json.loads(res.stdout)["feet"] == mode
        outs[mode] = load_motion(tmp_path / f"{mode}.npz")
    lock, off = outs["lock"], outs["off"]
    assert np.array_equal(lock.root_orient, off.root_orient)
    assert np.array_equal(lock.trans, off.trans)
    changed = np.abs(lock.pose_body - off.pose_body).max(axis=(0, 2)) > 0
    assert changed[LEG_ROWS].all() and not np.delete(changed, LEG_ROWS).any()
    res = CliRunner().invoke(cli, ["denoise", str(src), "-o", str(tmp_path / "x.npz"),
                                   "--feet", "glue"])  # fmt: skip
    assert res.exit_code == 1 and "glue" in res.output


def test_feet_benchmark_runs_on_two_clips(body):
    from benchmarks.common import cut_clips
    from benchmarks.feet import markdown, parse_variant, run_sigma
    from mdvae_cli.model.denoiser import load_denoiser
    from mdvae_cli.motion.contacts import foot_contacts

    m = crouch(60)
    m.trans[:, 0] = 0.3 * np.sin(np.arange(60) / 10)  # swaying: still at the turns
    m.trans[:, 2] -= feet_and_soles(m, body)[1].min()
    clips = cut_clips(m, 30, "sway.npz")
    truth = [foot_contacts(_joints(c.motion, body), FPS) for c in clips]
    assert all(t.any() for t in truth)
    denoiser, _ = load_denoiser(None)
    result = run_sigma(clips, denoiser, body, 0.1, FootLockConfig(), truth)
    assert result.frames == 60 and result.lock_s > 0 and result.denoise_s > 0
    assert result.off.v2v_cm > 0 and result.lock.penetration_pred is not None
    assert set(result.detection) == {
        "denoised motion (what `--feet lock` uses)", "noisy input, same settings"
    }  # fmt: skip
    assert result.knee_lock[0] >= 0 and 0 <= result.knee_off[1] <= 1
    md = markdown({"sway": [result]}, "header")
    assert "| 0.10 | `--feet lock` |" in md and "skate / GT skate" in md
    assert "| sway | 0.10 |" in md and "stance knee error" in md
    cfg, use_input = parse_variant("keep=0,passes=1,input=0")
    assert cfg.keep == 0 and cfg.passes == 1 and not use_input


def _joints(motion: Motion, body: BodyModel) -> np.ndarray:
    return np.concatenate([o.joints.double().numpy() for _, o in pose_motion_chunks(motion, body)])


# --------------------------------------------------------------------------------------------
# knees that keep their bend, long takes


def knee_bend_degrees(motion: Motion, body: BodyModel) -> np.ndarray:
    """Each knee's bend (angle between thigh and shank), degrees.  -> (T, 2)"""
    pos, _ = leg_ik.pose_legs(motion, leg_ik.LegModel.build(body, motion.betas), soles=False)
    thigh, shank = pos[:, :, 1] - pos[:, :, 0], pos[:, :, 2] - pos[:, :, 1]
    cos = (thigh * shank).sum(-1) / np.linalg.norm(thigh, axis=-1) / np.linalg.norm(shank, axis=-1)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def test_a_bent_stance_knee_stays_bent_while_the_foot_stops_sliding(body):
    # a denoised-looking stance: knees bent ~23 degrees, feet sliding at 10 cm/s, the pelvis
    # bobbing 1 cm (the height goal asks each frame for a slightly longer or shorter leg)
    m = crouch(60)
    m.pose_body[:, [0, 1], 0] = -0.15
    m.pose_body[:, [3, 4], 0] = 0.3
    m.pose_body[:, [6, 7], 0] = -0.15
    m.trans[:, 0] = 0.1 / FPS * np.arange(60)
    m.trans[:, 2] = 0.01 * np.sin(np.arange(60) / 3)
    m.trans[:, 2] -= feet_and_soles(m, body)[1].min()
    locked = lock_feet(m, body, FootLockConfig(keep=0.0))
    before, after = knee_bend_degrees(m, body), knee_bend_degrees(locked, body)
    assert np.allclose(before, 22.9, atol=0.1)  # (the rest leg bends ~6 degrees)
    # within 0.5 degrees of its bend (the two-bone turn used before, meeting every height
    # goal exactly, turned it by up to 13.6 degrees here, down to a 9.3-degree bend)
    assert np.abs(after - before).max() < 0.5 and after.min() > 22.3
    twice = knee_bend_degrees(lock_feet(m, body, FootLockConfig(keep=0.0, passes=2)), body)
    assert np.abs(twice - before).max() < 0.5
    feet_before, _ = feet_and_soles(m, body)
    feet_after, _ = feet_and_soles(locked, body)
    speed = lambda f: np.linalg.norm(np.diff(f[..., :2], axis=0), axis=-1) * FPS  # noqa: E731
    assert speed(feet_before)[5:55].min() > 0.09
    # ankles nailed; the balls, the foot aimed from an ankle that the knee lets ride ~1 cm up
    # and down with the pelvis, slide at under a third of their speed before
    assert speed(feet_after)[5:55, :2].max() < 1e-4 and speed(feet_after)[5:55].max() < 0.035


def test_swing_ik_keeps_the_knee_for_a_horizontal_move_and_lands_on_the_target(body):
    m = crouch(20)
    model = leg_ik.LegModel.build(body, m.betas)
    root, legs, pelvis = chain_of(m, model)
    pos, _ = leg_ik.leg_chain(root, legs, pelvis, model.bones)
    shift = np.zeros((20, 1, 1, 3))
    shift[..., 0] = np.linspace(-0.08, 0.08, 20)[:, None, None]  # up to 8 cm forward or back
    targets = pos[:, :, 2:] + shift
    held = np.ones((20, 2, 2), dtype=bool)
    new = leg_ik.swing_ik(root, legs, pelvis, model.bones, targets, held, m.pose_body[:, [3, 4], 0],
                          stiffness=0.5, bend_stiffness=0.5)  # fmt: skip
    after, _ = leg_ik.leg_chain(root, new, pelvis, model.bones)
    # the knee's own rotation turns by the damped step only: the ankle moves on (nearly) a
    # sphere about the hip, so the step is small; horizontally the ankle is on its target
    knee_turn = np.abs(rotmat_to_rotvec(legs[:, :, 1].swapaxes(-1, -2) @ new[:, :, 1]))
    assert knee_turn.max() < np.radians(1.0)
    assert np.abs(after[:, :, 2, :2] - targets[:, :, 0, :2]).max() < 1e-6
    assert np.abs(after[:, :, 2, 2] - targets[:, :, 0, 2]).max() < 0.005  # the miss: height


def tiled(piece: Motion, n: int) -> Motion:
    return Motion(root_orient=np.tile(piece.root_orient, (n, 1)),
                  pose_body=np.tile(piece.pose_body, (n, 1, 1)),
                  trans=np.tile(piece.trans, (n, 1)), betas=piece.betas, fps=piece.fps)  # fmt: skip


def test_a_long_take_is_locked_as_its_pieces_are(body):
    # 230 copies of a 3 s piece (a sliding contact, then a jump): 20,700 frames, more than two
    # chunks of the leg solve and a jitter read on samples; each copy locked as in a short take
    piece = sliding_then_jumping(body)
    short, long = tiled(piece, 3), tiled(piece, 230)
    assert long.num_frames > 2 * leg_ik.CHUNK_FRAMES
    ref = lock_feet(short, body, source=short).pose_body[90:180]
    out = lock_feet(long, body, source=long).pose_body
    for k in (1, 45, 91, 182, 228):  # 91 and 182 hold the chunks' edges (8192, 16384)
        assert np.abs(out[90 * k : 90 * (k + 1)] - ref).max() < 1e-9, k


def test_a_video_takes_feet_are_smoothed_whatever_their_jitter_reads():
    from mdvae_cli.infer.denoise_settings import DenoiseSettings, lock_config

    assert lock_config(DenoiseSettings()).clean_jitter == FootLockConfig().clean_jitter > 0
    assert lock_config(DenoiseSettings(input_kind="video")).clean_jitter == 0
    assert lock_config(DenoiseSettings(feet="off")) is None
