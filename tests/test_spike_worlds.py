"""A spike filled in one joint leaves the joints below it where the input had them: in the
blend (infer.spike_worlds), on the way back to the file's own skeleton (retarget.steady) and
in the foot lock's reference (infer.feet.without_spikes). Together they kept CMU 01_08's
chest and arms and 01_03's legs from popping for a frame where the input was smooth."""

from __future__ import annotations

import numpy as np
from click.testing import CliRunner
from test_amc_out import write_take_files
from test_bvh_out import write_rig
from test_noise_blend import smooth_track

from mdvae_cli.body.data import SMPL_PARENTS
from mdvae_cli.body.formats import load_body_model
from mdvae_cli.cli.main import cli
from mdvae_cli.formats.asf import load_asf
from mdvae_cli.formats.bvh import load_bvh
from mdvae_cli.formats.bvh_write import write_bvh
from mdvae_cli.geometry.euler import rotmat_to_euler
from mdvae_cli.geometry.kinematics import world_rotations
from mdvae_cli.geometry.rotations_np import rotmat_to_rotvec, rotvec_to_rotmat
from mdvae_cli.infer.feet import FOOT_CHAIN, without_spikes
from mdvae_cli.infer.noise_blend import blend_motion
from mdvae_cli.infer.spike_worlds import followed_share, keep_worlds_below_spikes, world_jumps
from mdvae_cli.motion.motion import Motion
from mdvae_cli.retarget.fit_shape import BodyJoints
from mdvae_cli.retarget.source_file import load_source
from mdvae_cli.retarget.steady import (
    kept_below_brief_turn,
    lasting,
    offset_jumps,
    turn_reading,
)
from mdvae_cli.retarget.take import read_take, write_take

PARENTS = [int(p) for p in SMPL_PARENTS[:22]]
SPINE1, SPINE2, SPINE3 = 3, 6, 9
AXIS = np.array([0.6, 0.0, 0.8])


def _angle(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Angle (rad) between rotation matrices (..., 3, 3)."""
    cos = (np.trace(np.swapaxes(A, -1, -2) @ B, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.arccos(np.clip(cos, -1.0, 1.0))


def _worlds(rotvecs: np.ndarray) -> np.ndarray:
    return world_rotations(rotvec_to_rotmat(rotvecs), PARENTS)


def _split_jump(truth: np.ndarray, t: int, a: float) -> np.ndarray:
    """``truth`` (T, 22, 3) with, at frame t, spine1's world turned by ``a`` about AXIS,
    spine2's by a/2 and spine3's not at all (a retarget's spine split: local jumps of a,
    a/2 and a/2 that cancel by spine3)."""
    G = _worlds(truth[t])
    turned = G.copy()
    for j, share in ((SPINE1, 1.0), (SPINE2, 0.5)):
        turned[j] = rotvec_to_rotmat(share * a * AXIS) @ G[j]
    L = np.swapaxes(turned[PARENTS[1:]], -1, -2) @ turned[1:]
    out = truth.copy()
    out[t, 1:] = rotmat_to_rotvec(L)
    return out


def test_a_world_jump_is_read_against_the_neighbours_midpoint():
    R0, R2 = (
        rotvec_to_rotmat(np.array([0.0, 0.0, 0.1])),
        rotvec_to_rotmat(np.array([0.0, 0.0, 0.3])),
    )
    mid = rotvec_to_rotmat(np.array([0.0, 0.0, 0.2]))
    jump = rotvec_to_rotmat(np.array([0.05, 0.0, 0.0]))
    np.testing.assert_allclose(world_jumps(R0, jump @ mid, R2), [0.05, 0.0, 0.0], atol=1e-12)
    u = np.array([[-0.2, 0, 0], [-0.2, 0, 0], [0.2, 0, 0], [0, 0, 0], [-0.2, 0, 0], [-0.2, 0, 0]])
    jumps = np.array(
        [[0.2, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [0.1, 0, 0], [0.19, 0.1, 0], [0.01, 0, 0]]
    )
    # undone wholly, half, not at all (the joint jumped the other way), no correction at all;
    # within the edge of whole and of nothing: whole, nothing
    np.testing.assert_allclose(followed_share(u, jumps), [1.0, 0.5, 0.0, 1.0, 1.0, 0.0])
    # near half a turn the axis of a rotation vector flips: a correction that large is
    # followed whole, whatever the joint's jump reads
    assert followed_share(np.array([3.0, 0, 0]), np.array([-3.0, 0, 0])) == 1.0
    assert followed_share(np.array([3.0, 0, 0]), np.array([3.0, 0, 0])) == 1.0


def test_a_jump_the_joints_below_undid_leaves_them_where_the_input_had_them():
    T, t = 120, 60
    truth = smooth_track(T, 30.0)
    take_rot = _split_jump(truth, t, 0.25)
    take = Motion.from_poses(take_rot.reshape(T, 66), np.zeros((T, 3)), np.zeros(10), 30.0)
    den = take.with_body(root_orient=truth[:, 0], pose_body=truth[:, 1:])
    out, report = blend_motion(take, den)
    assert report.spike_share == 1 / T  # spine1's local jump alone reads as a spike
    G_in, G_out, G_true = (_worlds(r[t]) for r in (take_rot, out.joint_rotations, truth))
    # spine3 and everything above it: where the input had them (and the truth: they never
    # moved); spine1 and spine2 filled back onto their course
    below = [j for j in range(22) if j not in (0, 1, 2, 4, 5, 7, 8, 10, 11, SPINE1, SPINE2)]
    assert _angle(G_out[below], G_in[below]).max() < 1e-3
    assert _angle(G_out[[SPINE1, SPINE2]], G_true[[SPINE1, SPINE2]]).max() < 0.01
    # had spine2 and spine3 kept their local jumps under a filled spine1, spine3's world
    # rotation would have turned by the whole jump back
    follow = _worlds(np.concatenate([out.joint_rotations[t, :SPINE2], take_rot[t, SPINE2:]]))
    assert _angle(follow[SPINE3], G_in[SPINE3]) > 0.2
    # the other frames as they came
    rest = np.arange(T) != t
    np.testing.assert_allclose(out.joint_rotations[rest], take_rot[rest], atol=5e-3)


def test_a_glitch_of_one_joint_is_filled_below_it_too():
    T, t = 120, 50
    truth = smooth_track(T, 30.0)
    glitch = truth.copy()
    glitch[t, 4] += 0.6  # the left knee flips for a frame; the ankle below turns with it
    take = Motion.from_poses(glitch.reshape(T, 66), np.zeros((T, 3)), np.zeros(10), 30.0)
    out, _ = blend_motion(take, take.with_body())
    G_out, G_true = (_worlds(r[t]) for r in (out.joint_rotations, truth))
    assert _angle(G_out[[4, 7, 10]], G_true[[4, 7, 10]]).max() < 0.01
    np.testing.assert_allclose(out.pose_body[t, 6], glitch[t, 7], atol=1e-9)  # its own local


def test_a_partly_kept_pelvis_spike_the_spine_undid_leaves_the_spine_steady():
    """A pelvis that jumps for a frame while the spine above it holds its world rotation (a
    retarget's pelvis spike, CMU 01_08), on a take whose pelvis the blend keeps only half of:
    the spine's world rotation goes on as the blend turned it on the frames either side, with
    no jump of its own (before, it took half the pelvis's fill: a pop of ~3 degrees)."""
    T, t = 9, 4
    source = np.zeros((T, 22, 3))
    spike = rotvec_to_rotmat(np.array([0.0, 0.0, 0.1]))  # 5.7 degrees for one frame
    source[t, 0] = rotmat_to_rotvec(spike)
    source[t, SPINE1] = rotmat_to_rotvec(spike.T)  # the spine held its world rotation
    source[t, [1, 2]] = rotmat_to_rotvec(spike.T)  # and the hips
    lean = np.array([0.04, 0.0, 0.0])  # the denoiser leans the pelvis by 2.3 degrees
    denoised = np.zeros((T, 22, 3))
    denoised[:, 0] = lean
    filled = source.copy()
    filled[:, 0] = 0.5 * lean  # the blend kept half of the input's pelvis ...
    filled[t, 0] = lean  # ... and filled its spike with the denoiser's
    spikes = np.zeros((T, 22), bool)
    spikes[t, 0] = True
    out = keep_worlds_below_spikes(source, denoised, filled, spikes)
    G_out = _worlds(out)
    steady = rotvec_to_rotmat(0.5 * lean)  # the spine's world turn on the frames beside
    for j in (SPINE1, SPINE2, SPINE3, 12, 15, 1, 2, 4, 7):
        jump = np.linalg.norm(world_jumps(G_out[t - 1, j], G_out[t, j], G_out[t + 1, j]))
        assert jump < 1e-6, (j, jump)
        assert _angle(G_out[t, j], steady) < 1e-6
    np.testing.assert_allclose(out[t, 0], lean, atol=1e-12)  # the filled pelvis as it was
    rest = np.arange(T) != t
    np.testing.assert_allclose(out[rest], filled[rest], atol=1e-12)


def test_inside_a_run_of_spikes_the_joints_below_follow_the_fill():
    """A shoulder that spikes four frames running and its elbow three (CMU 01_03's left arm):
    where the chain has spikes on both frames beside, the joints below follow the fill, as it
    left them. A share read frame by frame along a run is no steady course: read there, the
    elbow and wrist jumped 12-15 degrees for two frames where the input's moved 3."""
    T, shoulder, elbow, wrist = 10, 16, 18, 20
    rng = np.random.default_rng(1)
    source = np.zeros((T, 22, 3))
    for t in range(3, 7):
        d = rng.normal(0, 0.15, 3)
        source[t, shoulder] = d
        if t <= 5:
            source[t, elbow] = -0.5 * d + rng.normal(0, 0.03, 3)  # undone in part, askew
    denoised = np.zeros((T, 22, 3))
    denoised[:, :, 0] = 0.02  # the denoiser: a little off the input everywhere
    filled = source.copy()
    filled[3:7, shoulder] = denoised[3:7, shoulder]
    filled[3:6, elbow] = denoised[3:6, elbow]
    spikes = np.zeros((T, 22), bool)
    spikes[3:7, shoulder] = True
    spikes[3:6, elbow] = True
    out = keep_worlds_below_spikes(source, denoised, filled, spikes)
    # frame 5: the elbow's run ends there, the shoulder's goes on; read as a share, the
    # wrist below turned by 0.05 rad
    np.testing.assert_allclose(out[4:6, [elbow, wrist]], filled[4:6, [elbow, wrist]], atol=1e-12)


def test_on_a_noisy_take_nothing_is_moved_back_toward_the_input():
    T = 100
    rng = np.random.default_rng(3)
    source = smooth_track(T, 30.0) + rng.normal(0, 0.05, (T, 22, 3))
    filled = smooth_track(T, 30.0, seed=1)
    spikes = np.zeros((T, 22), bool)
    spikes[[20, 40, 70], [0, 3, 16]] = True
    out = keep_worlds_below_spikes(source, filled, filled, spikes)  # the denoiser's, wholly
    np.testing.assert_allclose(out, filled, atol=1e-9)


def test_a_turn_of_a_frame_or_two_is_no_lasting_turn():
    x = np.zeros((40, 2))
    x[10, 0] = 5.0  # one frame
    x[20:22, 0] = 5.0  # two
    x[5:35, 1] = 3.0  # thirty
    x[15, 1] = 0.0  # a dip in it
    y = lasting(x, 1)
    assert y[:, 0].max() == 0.0
    np.testing.assert_array_equal(y[:, 1], x[:, 1])
    turn = np.tile(np.eye(3), (120, 1, 1))
    turn[60] = rotvec_to_rotmat(np.array([0.0, 0.1, 0.0]))  # a spike filled at 120 Hz
    assert turn_reading(turn, 120.0)[0].max() == 0.0
    turn[30:50] = rotvec_to_rotmat(np.array([0.0, 0.1, 0.0]))  # a sixth of a second turned
    w = turn_reading(turn, 120.0)[0]
    assert w[30:50].min() == 1.0 and w[:30].max() == 0.0


def test_an_offset_that_jumps_for_a_frame_is_the_retargets_miss():
    a, b = (
        rotvec_to_rotmat(np.array([[0.0, 0.0, 0.1]])),
        rotvec_to_rotmat(np.array([[0.0, 0.0, 0.14]])),
    )
    mid = rotvec_to_rotmat(np.array([[0.0, 0.0, 0.12]]))
    jumped = rotvec_to_rotmat(np.array([[0.3, 0.0, 0.0]])) @ mid
    hit, midpoint = offset_jumps(a, jumped, b)
    assert hit.tolist() == [True]
    np.testing.assert_allclose(midpoint, mid, atol=1e-12)
    assert offset_jumps(a, mid, b)[0].tolist() == [False]  # on its course
    c = rotvec_to_rotmat(np.array([[0.0, 0.0, 0.9]]))  # a fast move: across is larger
    assert offset_jumps(a, rotvec_to_rotmat(np.array([[0.0, 0.0, 0.5]])), c)[0].tolist() == [False]


def test_a_driven_joint_keeps_its_neighbours_offset_where_the_turn_is_read_in_part():
    """The retarget's driver jumped for a frame where the file's joint did not, the cleaning
    filled it, and the turn reads partly smoothed there (a weight between 0 and 1): the joint
    goes on with its neighbours' offset. Before, the partial smoothing read the raw offset
    again and the file's joint jumped by the miss (CMU 01_10's upper neck: 12 degrees for a
    frame where the file's moved 2)."""
    from mdvae_cli.retarget.way_back import SmplChange, driven_rotations

    T, t = 9, 4
    eye = np.broadcast_to(np.eye(3), (T, 22, 3, 3)).copy()
    before = eye.copy()
    before[t, 0] = rotvec_to_rotmat(np.array([0.0, 0.0, 0.2]))  # the retarget's miss
    after = eye.copy()  # the cleaning filled it
    turn = after @ np.swapaxes(before, -1, -2)
    weight = np.zeros((T, 22))
    weight[t - 2 : t + 3, 0] = 0.3  # the turn reads partly smoothed about the frame
    brief = np.zeros((T, 22), bool)
    brief[t, 0] = True
    change = SmplChange(turn, before, after, np.zeros((T, 3)), weight, brief)
    G = np.broadcast_to(np.eye(3), (T, 1, 3, 3)).copy()  # the file's joint: steady
    R = driven_rotations(change, G, np.array([0]), 120.0)
    assert _angle(R[:, 0], G[:, 0]).max() < 1e-9


def test_the_neighbours_offset_is_taken_only_where_it_leaves_the_joint_steadier():
    """Where the cleaning kept most of its driver's jump (the blend held the spine's world
    rotation there), ``after`` jumps too, and the neighbours' offset would make the file's
    steady joint jump with it: its own offset keeps it nearer where the file had it."""
    from mdvae_cli.retarget.steady import brief_jumps

    T, t = 9, 4
    miss = np.array([0.0, 0.0, 0.2])
    before = np.broadcast_to(np.eye(3), (T, 1, 3, 3)).copy()
    before[t, 0] = rotvec_to_rotmat(miss)  # the retarget's miss, over OFFSET_JUMP_RAD
    Gj = np.broadcast_to(np.eye(3), (T, 1, 3, 3)).copy()  # the file's joint: steady
    brief = np.zeros((T, 1), bool)
    brief[t] = True
    for kept, taken in ((0.0, True), (0.7, False)):
        after = before.copy()
        after[t, 0] = rotvec_to_rotmat(kept * miss)  # the cleaning kept this much of it
        R = after @ np.swapaxes(before, -1, -2) @ Gj
        own = R[t, 0].copy()
        frames, _, _ = brief_jumps(R, before, after, Gj, brief)
        assert (len(frames) == 1) == taken
        jump = np.linalg.norm(world_jumps(R[t - 1, 0], R[t, 0], R[t + 1, 0]))
        assert jump <= np.linalg.norm(world_jumps(R[t - 1, 0], own, R[t + 1, 0])) + 1e-12
        assert jump < 0.07


def test_an_undriven_joint_keeps_its_world_under_a_brief_turn_it_did_not_follow():
    T, t = 9, 4
    rng = np.random.default_rng(0)
    Gp = rotvec_to_rotmat(0.02 * np.arange(T)[:, None] * np.array([1.0, 0.5, 0.0]))
    glitch = rotvec_to_rotmat(np.array([0.0, 0.4, 0.0]))
    Gp[t] = glitch @ Gp[t]  # the parent jumped in the file ...
    G2p = Gp.copy()
    G2p[t] = np.swapaxes(glitch, -1, -2) @ Gp[t]  # ... and the cleaning took the jump out
    Lj = rotvec_to_rotmat(rng.normal(0, 0.3, 3))
    brief = np.zeros(T, bool)
    brief[t] = True
    steady = rotvec_to_rotmat(0.03 * np.arange(T)[:, None] * np.array([0.0, 0.0, 1.0]))
    at, Lt = kept_below_brief_turn(G2p, Gp, steady, brief)  # it stayed put: kept
    assert at.tolist() == [t]
    np.testing.assert_allclose(G2p[t] @ Lt[0], steady[t], atol=1e-9)
    at, Lt = kept_below_brief_turn(G2p, Gp, Gp @ Lj, brief)  # it jumped with it: follows
    np.testing.assert_allclose(Lt[0], Lj, atol=1e-9)


def test_an_arm_glitch_the_hand_undid_leaves_the_hand_where_the_file_had_it(tmp_path):
    path = write_rig(tmp_path / "rig.bvh", T=120, fps=30.0)
    take = load_bvh(path)
    lay, names, t = take.layout, list(take.names), 60
    data = lay.data[lay.rows].copy()
    upper, lower, hand = (names.index(n) for n in ("UpperArm_L", "LowerArm_L", "Hand_L"))
    # the upper arm's world turned by 0.25 rad for a frame, the forearm's by half, the hand's
    # not at all: local jumps of 0.25 (a spike), 0.125 and 0.125 (under the spike floor)
    G = world_rotations(np.asarray(take.rotations[t : t + 1]), take.parents)[0]
    G2 = G.copy()
    for j, share in ((upper, 1.0), (lower, 0.5)):
        G2[j] = rotvec_to_rotmat(share * 0.25 * AXIS) @ G[j]
    for j in (upper, lower, hand):
        rot = lay.joint_columns(j, "r")
        cols, axes = [c for c, _ in rot], "".join(a for _, a in rot)
        L = G2[take.parents[j]].T @ G2[j]
        data[t, cols] = np.rad2deg(rotmat_to_euler(L, axes, np.deg2rad(data[t, cols])))
    glitched = tmp_path / "glitched.bvh"
    write_bvh(lay, data, glitched)
    r = CliRunner().invoke(cli, ["denoise", str(glitched), "-o", str(tmp_path / "out.bvh")])
    assert r.exit_code == 0, r.output
    G_true, G_in, G_out = (
        world_rotations(np.asarray(m.rotations), m.parents)
        for m in (take, load_bvh(glitched), load_bvh(tmp_path / "out.bvh"))
    )
    assert _angle(G_in[t, upper], G_true[t, upper]) > 0.24  # the glitch is in the file
    assert _angle(G_out[t, upper], G_true[t, upper]) < 0.03  # and out of the result
    for j in (hand, names.index("Index1_L"), names.index("Index2_L")):  # below: as they came
        assert _angle(G_out[t, j], G_in[t, j]) < 0.01, names[j]


def test_the_foot_locks_reference_reads_the_legs_below_a_pelvis_spike_as_cleaned():
    T, t = 120, 60
    rot = smooth_track(T, 30.0)
    rot[t, 0] += 0.5  # the pelvis flips for a frame; its hips keep their own rotations
    take = Motion.from_poses(rot.reshape(T, 66), np.zeros((T, 3)), np.zeros(10), 30.0)
    seen = without_spikes(take).joint_mask
    assert not seen[t, FOOT_CHAIN].any()  # the pelvis and every leg joint below it
    assert seen[t, [3, 6, 9, 16, 20]].all()  # the spine and arms are no goal of the feet
    assert seen[np.arange(T) != t].all()


def _amc_turned_for_a_frame(tmp_path, t: int, turned):
    """A generated AMC take written back with ``turned(motion)`` as its cleaned SMPL motion
    (one joint turned on frame t): the file's world rotations before and after (T, J, 3, 3)
    and its bone names."""
    path, asf = write_take_files(tmp_path / "in", T=240)
    skeleton = load_asf(asf)
    take = read_take(path, BodyJoints(load_body_model(None)), source=load_source(path, skeleton))
    write_take(take, turned(take.motion), tmp_path / "out" / "out.amc")
    before, after = (load_source(p, skeleton) for p in (path, tmp_path / "out" / "out.amc"))
    G0, G1 = (world_rotations(np.asarray(m.rotations), m.parents) for m in (before, after))
    return G0, G1, list(before.names)


def _turned_at(x: np.ndarray, t: int, rotvec) -> np.ndarray:
    """``x`` (T, 3) axis-angles with frame t turned by ``rotvec`` (in the world)."""
    out = x.copy()
    out[t] = rotmat_to_rotvec(rotvec_to_rotmat(np.array(rotvec)) @ rotvec_to_rotmat(x[t]))
    return out


def test_an_amc_bone_without_a_driver_keeps_its_world_under_a_one_frame_turn(tmp_path):
    def turned(m):  # the left elbow, for one frame
        pose = m.pose_body.copy()
        pose[:, 17] = _turned_at(pose[:, 17], t, [0.0, 0.25, 0.1])
        return m.with_body(pose_body=pose)

    t = 120
    G0, G1, names = _amc_turned_for_a_frame(tmp_path, t, turned)
    wrist, thumb = names.index("lwrist"), names.index("lthumb")  # lthumb: rx rz, undriven
    moved = _angle(G1[t, wrist], G0[t, wrist])
    assert moved > 0.1  # the driven wrist turned with the elbow for the frame ...
    assert _angle(G1[t, thumb], G0[t, thumb]) < 0.5 * moved  # ... its thumb stayed near
    rest = np.arange(len(G0)) != t
    assert _angle(G1[rest, thumb], G0[rest, thumb]).max() < 1e-3  # the other frames as they came


def test_an_amc_bone_that_carries_a_point_keeps_its_world_under_a_one_frame_turn(tmp_path):
    """CMU's lowerback drives no SMPL joint but carries spine1's point; a pelvis spike filled
    for a frame moved that point by the retarget's miss of it, and the lowerback turned to
    follow it: a pop where the file's lower back was steady (CMU 01_08: 12 of its 45)."""
    t = 120
    G0, G1, names = _amc_turned_for_a_frame(  # the pelvis, for one frame
        tmp_path, t, lambda m: m.with_body(root_orient=_turned_at(m.root_orient, t, [0, 0, 0.1]))
    )
    pelvis, back = names.index("root"), names.index("lowerback")
    moved = _angle(G1[t, pelvis], G0[t, pelvis])
    assert moved > 0.09  # the root turned with the pelvis for the frame ...
    assert _angle(G1[t, back], G0[t, back]) < 0.1 * moved  # ... its lower back stayed put
    rest = np.arange(len(G0)) != t
    assert _angle(G1[rest, back], G0[rest, back]).max() < 1e-3  # the other frames as they came
