"""The way back keeps a take's constant rotation channels (a hinge's other axes, feet a video
estimate never turns) as they came, and solves the joint's other channels for the cleaned
rotation (``retarget/held_channels.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.formats.bvh import load_bvh
from mdvae_cli.formats.bvh_write import write_bvh
from mdvae_cli.geometry.euler import euler_to_rotmat
from mdvae_cli.retarget import way_back
from mdvae_cli.retarget.fit_shape import BodyJoints
from mdvae_cli.retarget.held_channels import angle_between, constant_channels, hold_channels
from mdvae_cli.retarget.take import read_take
from mdvae_cli.retarget.way_back import file_pose, write_back_data
from tests.test_bvh_out import write_rig

#: joint -> {axis: the value held through the take (degrees)}
HELD = {
    "Calf_L": {"y": 0.0, "z": 0.0},  # a hinge about x
    "LowerArm_R": {"z": 5.0},  # one axis held
    "Foot_R": {"z": 0.0, "x": 0.0, "y": 0.0},  # no rotation at all (a video estimate's feet)
}


@pytest.fixture(scope="module")
def joints():
    return BodyJoints(load_body_model(None))


def held_rig(tmp_path):
    """The generated rig with the HELD channels constant. -> (path, {(joint, axis): column})"""
    path = write_rig(tmp_path / "rig.bvh", T=60)
    src = load_bvh(path)
    data = src.layout.data.copy()
    cols = {}
    for c, (j, kind, axis) in enumerate(src.layout.channels):
        if kind == "r" and axis in HELD.get(src.names[j], {}):
            data[:, c] = HELD[src.names[j]][axis]
            cols[(src.names[j], axis)] = c
    out = tmp_path / "held.bvh"
    write_bvh(src.layout, data, out)
    return out, cols


def cleaned_of(take):
    """The take's SMPL motion with a smooth change on every body joint (about 3 degrees)."""
    m = take.motion
    t = np.arange(m.num_frames)[:, None] / m.fps
    body = np.asarray(m.pose_body)
    phase = np.linspace(0, 1, body[0].size).reshape(body.shape[1:])
    wave = 0.05 * np.sin(2 * np.pi * (0.7 * t[..., None] + phase))
    return m.with_body(pose_body=body + wave)


def local_rotations(take, data):
    return file_pose(take.source, take.source.layout, data)[0]


def test_constant_channels_are_found_to_the_last_written_digit():
    data = np.array([[0.0, 1.0, 1e-14, 3.0], [0.0, 1.0, -6e-15, 3.1], [0.0, 1.0, 0.0, 3.0]])
    np.testing.assert_array_equal(constant_channels(data), [True, True, True, False])
    assert not constant_channels(data[:1]).any()


def test_constant_channels_read_the_rows_asked_for_a_block_at_a_time(monkeypatch):
    """Of the rows asked for alone, read a block at a time: the same columns as numpy's
    peak-to-peak of those rows gathered at once; a NaN column holds no one value."""
    from mdvae_cli.retarget import held_channels

    rng = np.random.default_rng(1)
    data = rng.normal(size=(50, 6))
    data[1:, 2] = 4.0  # constant but for the first row
    data[:, 4] = -2.0
    data[7, 5] = np.nan
    rows = np.arange(1, 50)
    want = np.ptp(data[rows], axis=0) < held_channels.SPREAD
    monkeypatch.setattr(held_channels, "_BLOCK", 8)
    got = constant_channels(data, rows)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(got, [False, False, True, False, True, False])
    assert not constant_channels(data, rows[:1]).any()


def test_held_channels_solve_the_others_exactly_when_the_rotation_allows():
    rng = np.random.default_rng(0)
    for axes in ("zxy", "xyz", "yzx"):
        for k in range(3):
            theta = rng.uniform(-1.2, 1.2, (50, 3))
            theta[:, k] = 0.3
            R = euler_to_rotmat(theta, axes)
            held = np.arange(3) == k
            start = theta + rng.normal(0, 0.05, theta.shape)  # the way back's own solution
            got, Rw = hold_channels(R, axes, start, held, np.full(3, 0.3))
            assert (got[:, k] == 0.3).all()
            assert np.degrees(angle_between(Rw, R)).max() < 1e-5  # arccos: ~1e-6 at best
            np.testing.assert_allclose(euler_to_rotmat(got, axes), Rw, atol=1e-12)


def test_held_channels_never_leave_the_joint_further_than_the_way_back_did():
    """Off the held value by ~3 degrees: the others cannot take a held axis's turn up (the
    three axes are independent), so the way back's channels stay - except near gimbal lock,
    where the held axis nearly meets a free one and the solve takes most of it up."""
    rng = np.random.default_rng(1)
    values = np.array([0.0, 0.1, -0.2])
    for held, middle, most in ((1, 0.5, 1.0), (2, 0.5, 1.0), (0, 1.5, 0.1)):
        theta = rng.uniform(-1.0, 1.0, (200, 3))
        theta[:, 1] = middle + rng.normal(0, 0.05, 200)
        theta[:, held] = values[held] + rng.normal(0, 0.05, 200)
        R = euler_to_rotmat(theta, "zxy")
        keep = np.arange(3) == held
        got, Rw = hold_channels(R, "zxy", theta, keep, values)
        left = theta.copy()
        left[:, held] = values[held]
        before = angle_between(euler_to_rotmat(left, "zxy"), R)
        after = angle_between(Rw, R)
        assert (after <= before + 1e-12).all() and after.mean() <= most * before.mean()


def test_a_hinge_and_a_still_foot_come_back_as_they_came(tmp_path, joints, monkeypatch):
    path, cols = held_rig(tmp_path)
    take = read_take(path, joints)
    cleaned = cleaned_of(take)
    layout = take.source.layout
    args = (take.source, take.retarget, take.motion, cleaned, joints)
    data = write_back_data(*args)
    for c in cols.values():  # the held channels: identical, every frame
        np.testing.assert_array_equal(data[:, c], layout.data[:, c])
    # the way back without holding them: the rotation the cleaning asked for
    none_held = lambda d, rows=None: np.zeros(d.shape[1], bool)  # noqa: E731
    monkeypatch.setattr(way_back, "constant_channels", none_held)
    free = write_back_data(*args)
    assert max(np.abs(free[:, c] - layout.data[:, c]).max() for c in cols.values()) > 0.5
    names = list(take.source.names)
    L_held, L_free = local_rotations(take, data), local_rotations(take, free)
    deg = {n: np.degrees(angle_between(L_held[:, names.index(n)], L_free[:, names.index(n)]))
           for n in HELD}  # fmt: skip
    moved = {n: max(np.abs(free[:, c] - layout.data[:, c]).max() for (m, _), c in cols.items()
                    if m == n) for n in HELD}  # fmt: skip
    # off the cleaned rotation by no more than the held channels' own turn (the others cannot
    # take a held axis's turn up away from gimbal lock): 2.94 of 2.94, 4.03 and 4.94 degrees
    assert deg["LowerArm_R"].max() <= moved["LowerArm_R"] + 1e-3 < 3.0
    assert moved["Calf_L"] < deg["Calf_L"].max() < 4.1
    assert moved["Foot_R"] < deg["Foot_R"].max() < 5.0
    # the joints below turn as the cleaning asked: world rotations as without holding
    G_held = file_pose(take.source, layout, data)[2]
    G_free = file_pose(take.source, layout, free)[2]
    for child in ("Foot_L", "Hand_R"):
        j = names.index(child)
        assert np.degrees(angle_between(G_held[:, j], G_free[:, j])).max() < 1e-4


def test_a_take_left_alone_comes_back_unchanged_with_held_channels(tmp_path, joints):
    path, _ = held_rig(tmp_path)
    take = read_take(path, joints)
    data = write_back_data(take.source, take.retarget, take.motion, take.motion, joints)
    np.testing.assert_allclose(data, take.source.layout.data, atol=1e-6)


def test_an_amc_bone_whose_dofs_hold_still_comes_back_as_it_came(tmp_path):
    """A CMU clavicle's two dofs at 0 through a take: asked to turn, the way back leaves them
    and the bone below (the humerus) takes the turn; a moving clavicle still turns."""
    from mdvae_cli.formats.asf import load_asf
    from mdvae_cli.formats.asfamc import load_amc
    from mdvae_cli.retarget.retarget import load_source
    from mdvae_cli.retarget.way_back_amc import write_back_amc
    from tests.test_amc_out import _turned, amc_file, asf_text, motion_values

    joints = BodyJoints(load_body_model(None))
    values = motion_values(120, seed=3)
    still = {**values, "lclavicle": np.zeros_like(values["lclavicle"])}
    (tmp_path / "gen.asf").write_text(asf_text())
    changes = {}
    for name, vals in (("moving", values), ("still", still)):
        path = tmp_path / f"{name}.amc"
        path.write_text(amc_file(vals))
        src = load_source(path, load_asf(tmp_path / "gen.asf"))
        take = read_take(path, joints, source=src)
        turned = _turned(take.motion, 13, 2, 10.0)  # the left collar, 10 degrees about z
        out = write_back_amc(take.source, take.retarget, take.motion, turned, joints)
        layout = load_amc(path, load_asf(tmp_path / "gen.asf")).layout
        changes[name] = {b: float(np.abs(out[b] - layout.values[b]).max())
                         for b in ("lclavicle", "lhumerus")}  # fmt: skip
    assert changes["moving"]["lclavicle"] > 3.0, changes
    assert changes["still"]["lclavicle"] == 0.0, changes
    assert changes["still"]["lhumerus"] > 3.0, changes


@pytest.mark.parametrize(
    ("bone", "column", "joint", "axis"), [("lhumerus", 1, 16, 0), ("lfemur", 2, 1, 2)]
)
def test_an_amc_dof_that_holds_still_keeps_its_value_the_others_turn(
    tmp_path, bone, column, joint, axis
):
    """One dof of a three-dof bone constant through the take (a solver's locked axis): asked
    to turn the joint, the way back keeps that dof as it came and turns the other two; with the
    dof moving, all three turn."""
    from mdvae_cli.formats.asf import load_asf
    from mdvae_cli.formats.asfamc import load_amc
    from mdvae_cli.retarget.retarget import load_source
    from mdvae_cli.retarget.way_back_amc import write_back_amc
    from tests.test_amc_out import _turned, amc_file, asf_text, motion_values

    joints = BodyJoints(load_body_model(None))
    values = motion_values(120, seed=5)
    locked = {b: v.copy() for b, v in values.items()}
    locked[bone][:, column] = 5.0
    (tmp_path / "gen.asf").write_text(asf_text())
    changes = {}
    for name, vals in (("moving", values), ("locked", locked)):
        path = tmp_path / f"{name}.amc"
        path.write_text(amc_file(vals))
        take = read_take(path, joints, source=load_source(path, load_asf(tmp_path / "gen.asf")))
        turned = _turned(take.motion, joint, axis, 12.0)
        out = write_back_amc(take.source, take.retarget, take.motion, turned, joints)
        layout = load_amc(path, load_asf(tmp_path / "gen.asf")).layout
        changes[name] = np.abs(out[bone] - layout.values[bone]).max(axis=0)
    assert changes["moving"][column] > 1.0, changes
    assert changes["locked"][column] == 0.0, changes
    assert np.delete(changes["locked"], column).max() > 1.0, changes


def test_an_amc_root_without_position_dofs_notes_the_move_it_cannot_hold(tmp_path):
    from mdvae_cli.formats.asf import load_asf
    from mdvae_cli.formats.registry import write
    from mdvae_cli.retarget.retarget import load_source
    from tests.test_amc_out import amc_file, asf_text, motion_values

    joints = BodyJoints(load_body_model(None))
    values = motion_values(60, seed=2)
    values["root"] = values["root"][:, 3:]  # angles only
    asf = tmp_path / "gen.asf"
    asf.write_text(asf_text().replace("order TX TY TZ RX RY RZ", "order RX RY RZ"))
    path = tmp_path / "rot_only.amc"
    path.write_text(amc_file(values))
    take = read_take(path, joints, source=load_source(path, load_asf(asf)))
    moved = take.motion.with_body(trans=np.asarray(take.motion.trans) + [0.0, 0.0, 0.1])
    notes = write(moved, tmp_path / "out.amc", take=take)
    assert len(notes) == 1 and "10.0 cm" in notes[0], notes
    assert write(take.motion, tmp_path / "same.amc", take=take) == []
