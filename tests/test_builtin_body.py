"""The built-in procedural body: layout, surface, skinning, shape directions, markers."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh

from mdvae_cli.body import builtin
from mdvae_cli.body.builtin import SHAPE_NAMES, builtin_body_model
from mdvae_cli.body.data import SMPL_JOINT_NAMES, SMPL_PARENTS
from mdvae_cli.body.markers import MARKER_MIRROR, MARKER_NAMES, marker_targets, place_markers
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError

LEFT_RIGHT = ((1, 2), (4, 5), (7, 8), (10, 11), (13, 14), (16, 17), (18, 19), (20, 21), (22, 23))
# (child, parent) bones whose lengths the shape directions are meant to move
BONES = {
    "thigh": (4, 1), "shin": (7, 4), "upper_arm": (18, 16), "forearm": (20, 18),
    "hand": (22, 20), "spine1": (3, 0), "spine2": (6, 3), "spine3": (9, 6), "neck": (12, 9),
    "head": (15, 12), "collar": (16, 13), "foot": (10, 7),
}  # fmt: skip
SURFACE_ONLY = ("head_size", "girth", "chest_depth", "limb_girth")


@pytest.fixture(scope="module")
def body():
    return builtin_body_model()


@pytest.fixture(scope="module")
def joints(body):
    return body.J_regressor @ body.v_template


def _bone_lengths(J: np.ndarray) -> dict[str, float]:
    out = {name: float(np.linalg.norm(J[c] - J[p])) for name, (c, p) in BONES.items()}
    out["shoulder_width"] = float(J[16, 0] - J[17, 0])
    out["hip_width"] = float(J[1, 0] - J[2, 0])
    return out


def _betas(body, k: int, value: float) -> np.ndarray:
    b = np.zeros(body.num_betas)
    b[k] = value
    return b


def test_layout(body):
    V = body.num_vertices
    assert body.kind == "builtin" and body.name == "builtin"
    assert 3000 <= V <= 8000
    assert body.v_template.shape == (V, 3)
    assert body.num_joints == 24 and body.joint_names == SMPL_JOINT_NAMES
    assert body.parents.dtype == np.int64 and tuple(body.parents) == SMPL_PARENTS
    assert body.faces.dtype == np.int64 and body.faces.min() == 0 and body.faces.max() == V - 1
    assert body.num_betas == len(SHAPE_NAMES) >= 10
    assert body.posedirs.shape == (V, 3, 207) and not body.posedirs.any()
    assert body.marker_vertex_ids.shape == (43,) and body.marker_vertex_ids.dtype == np.int64
    assert body.validate() is body


def test_deterministic(body):
    again = builtin_body_model()
    for field in (
        "v_template",
        "shapedirs",
        "J_regressor",
        "weights",
        "faces",
        "marker_vertex_ids",
    ):
        assert np.array_equal(getattr(body, field), getattr(again, field)), field


def test_mesh_is_closed_and_outward(body):
    mesh = trimesh.Trimesh(body.v_template, body.faces)
    assert mesh.is_watertight and mesh.is_winding_consistent
    parts = mesh.split(only_watertight=False)
    assert len(parts) == 13  # torso, neck+head, nose, 2 x (leg, foot, arm, hand, thumb)
    assert all(p.is_watertight and p.volume > 0 for p in parts)
    # a 70-75 kg body has ~0.07 m^3; the union of overlapping parts is a bit more
    assert 0.055 < mesh.volume < 0.095


def test_skinning_weights(body):
    W = body.weights
    assert W.min() >= 0.0
    np.testing.assert_allclose(W.sum(axis=1), 1.0, atol=1e-12)
    assert (W > 0).sum(axis=1).max() <= 4
    assert W[:, :22].sum(axis=0).min() > 0  # every body joint drives some vertices


def test_joint_regressor_is_convex(body):
    R = body.J_regressor
    assert R.min() >= 0.0
    np.testing.assert_allclose(R.sum(axis=1), 1.0, atol=1e-12)


def test_joints_are_plausible(body, joints):
    J, y = joints, joints[:, 1]
    np.testing.assert_allclose(J[0], [0.0, -0.22, 0.0], atol=0.02)
    height = body.v_template[:, 1].max() - body.v_template[:, 1].min()
    assert 1.6 < height < 1.8
    assert abs(body.v_template[:, 1].min() - (-1.16)) < 0.03  # soles
    assert y[15] > y[12] > y[16] > y[9] > y[6] > y[3] > y[0] > y[1] > y[4] > y[7] > y[10]
    for left, right in LEFT_RIGHT:
        assert J[left, 0] > 0.05
        np.testing.assert_allclose(J[right], J[left] * (-1, 1, 1), atol=1e-12)
    assert np.allclose(J[[0, 3, 6, 9, 12, 15], 0], 0.0)
    lengths = _bone_lengths(J)
    assert 0.07 < J[0, 1] - J[1, 1] < 0.09 and 0.07 < J[1, 0] < 0.09
    assert 0.38 < lengths["thigh"] < 0.47 and 0.38 < lengths["shin"] < 0.45
    assert 0.15 < J[16, 0] < 0.19
    assert 0.24 < lengths["upper_arm"] < 0.30 and 0.22 < lengths["forearm"] < 0.28
    assert J[10, 2] > J[7, 2] + 0.08  # toes point forward
    np.testing.assert_allclose(J[[18, 20, 22], 1], J[16, 1], atol=1e-12)  # T-pose


def test_rest_pose_reproduces_template(body, joints):
    model = BodyModel(body, dtype=torch.float64)
    zeros = torch.zeros(1, 3, dtype=torch.float64)
    out = model(zeros, torch.zeros(1, 21, 3, dtype=torch.float64), vertices=True)
    np.testing.assert_allclose(out.vertices[0].numpy(), body.v_template, atol=1e-5)
    np.testing.assert_allclose(out.joints[0].numpy(), joints[:22], atol=1e-5)
    np.testing.assert_allclose(
        out.markers[0].numpy(), body.v_template[body.marker_vertex_ids], atol=1e-5
    )


def test_left_elbow_bend_moves_only_the_forearm_side(body, joints):
    model = BodyModel(body, dtype=torch.float64)
    pose = torch.zeros(1, 21, 3, dtype=torch.float64)
    pose[0, 18 - 1] = torch.tensor([0.0, -math.pi / 2, 0.0], dtype=torch.float64)  # forward
    zeros = torch.zeros(1, 3, dtype=torch.float64)
    out = model(zeros, pose, vertices=True)
    v = out.vertices[0].numpy()
    moved = np.linalg.norm(v - body.v_template, axis=1)
    free = body.weights[:, [18, 20, 22]].sum(axis=1) == 0
    assert moved[free].max() < 1e-9
    wrist = out.joints[0, 20].numpy()
    forearm = np.linalg.norm(joints[20] - joints[18])
    np.testing.assert_allclose(wrist, joints[18] + [0.0, 0.0, forearm], atol=1e-9)
    # smooth: no edge is stretched or crushed to a sliver by the bend
    e = body.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    rest = np.linalg.norm(body.v_template[e[:, 0]] - body.v_template[e[:, 1]], axis=1)
    bent = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
    ratio = bent / rest
    assert 0.3 < ratio.min() and ratio.max() < 2.5


def test_shape_directions_are_exact_and_linear(body):
    """v(beta) is exactly the body rebuilt from the changed lengths; joints follow vertices."""
    layout = builtin._layout()
    p0 = builtin._base_params()
    for k, delta in enumerate(builtin._shape_deltas(p0)):
        p = {name: v - 2.5 * np.asarray(delta.get(name, 0.0)) for name, v in p0.items()}
        v, landmarks = builtin._vertices(p, layout)
        expected = body.v_template + body.shapedirs @ _betas(body, k, -2.5)
        np.testing.assert_allclose(v, expected, atol=1e-12)
        np.testing.assert_allclose(body.J_regressor @ v, landmarks[:24], atol=1e-12)


@pytest.mark.parametrize("k", range(len(SHAPE_NAMES)))
def test_each_shape_direction_changes_a_bone_and_stays_sane(body, joints, k):
    base = _bone_lengths(joints)
    for value in (-1.0, 1.0):
        v = body.v_template + body.shapedirs @ _betas(body, k, value)
        J = body.J_regressor @ v
        changed = max(abs(a - base[n]) for n, a in _bone_lengths(J).items())
        if SHAPE_NAMES[k] in SURFACE_ONLY:  # soft tissue: joints stay, surface moves
            np.testing.assert_allclose(J, joints, atol=1e-12)
            assert np.abs(v - body.v_template).max() > 0.005
        else:
            assert changed > 0.005, SHAPE_NAMES[k]
        mesh = trimesh.Trimesh(v, body.faces, process=False)
        assert 1.55 < np.ptp(v[:, 1]) < 1.85
        assert 0.05 < mesh.volume < 0.11
        parts = mesh.split(only_watertight=False)
        assert all(p.volume > 0 for p in parts)
        assert (mesh.area_faces > 1e-9).all()
    # each direction is ~unit-std: no vertex moves more than a few cm per unit beta
    assert np.linalg.norm(body.shapedirs[:, :, k], axis=1).max() < 0.08


def test_random_shapes_in_recommended_range_are_sane(body):
    """Any betas in [-3, 3] keep every part closed with positive volume and a human size."""
    rng = np.random.default_rng(0)
    for betas in rng.uniform(-3.0, 3.0, size=(6, body.num_betas)):
        v = body.v_template + body.shapedirs @ betas
        J = body.J_regressor @ v
        assert 1.45 < np.ptp(v[:, 1]) < 1.95
        assert min(_bone_lengths(J).values()) > 0.03
        mesh = trimesh.Trimesh(v, body.faces, process=False)
        assert all(p.volume > 0 for p in mesh.split(only_watertight=False))


def test_bone_lengths_are_adjustable_independently(body, joints):
    """Thigh, shin, upper arm and forearm lengths each follow a 2-beta combination exactly."""
    base = _bone_lengths(joints)
    Jdirs = np.einsum("jv,vck->jck", body.J_regressor, body.shapedirs)
    names = SHAPE_NAMES
    thigh_only = np.zeros(body.num_betas)
    thigh_only[names.index("leg_length")] = 0.01 / 0.024  # +0.5 cm on each of thigh and shin
    thigh_only[names.index("thigh_vs_shin")] = 0.5  # +0.5 cm thigh, -0.5 cm shin
    J = joints + Jdirs @ thigh_only
    after = _bone_lengths(J)
    assert after["thigh"] - base["thigh"] == pytest.approx(0.01, abs=1e-4)
    assert after["shin"] - base["shin"] == pytest.approx(0.0, abs=1e-4)
    assert after["upper_arm"] == pytest.approx(base["upper_arm"], abs=1e-9)


def test_markers(body, joints):
    ids = body.marker_vertex_ids
    assert len(MARKER_NAMES) == len(set(MARKER_NAMES)) == 43
    assert len(set(ids.tolist())) == 43
    pos = body.v_template[ids]
    # every marker sits within 4.5 cm of its anatomical target point
    assert np.linalg.norm(pos - marker_targets(joints), axis=1).max() < 0.045
    for i, name in enumerate(MARKER_NAMES):
        twin = MARKER_MIRROR[i]
        np.testing.assert_allclose(pos[twin], pos[i] * (-1, 1, 1), atol=1e-12)
        if name.startswith("L"):
            assert pos[i, 0] > 0.02, name
        if twin == i:
            assert abs(pos[i, 0]) < 1e-12, name
    by_name = dict(zip(MARKER_NAMES, pos, strict=True))
    assert by_name["ARIEL"][1] == pytest.approx(body.v_template[:, 1].max(), abs=0.01)
    assert by_name["LFHD"][2] > 0.05 > -0.05 > by_name["LBHD"][2]
    assert by_name["LHEE"][2] < joints[7, 2] < by_name["LTOE"][2]
    assert by_name["LELB"][0] == pytest.approx(joints[18, 0], abs=0.02)
    assert by_name["LWRA"][2] > joints[20, 2] > by_name["LWRB"][2]
    assert by_name["LFIN"][1] > joints[22, 1] and abs(by_name["LFIN"][0] - joints[22, 0]) < 0.02


def test_place_markers_on_another_topology(body, joints):
    """The rule works on any SMPL-frame mesh: a finer remesh gives the same spots to within
    the coarse mesh's edge length (~2 cm)."""
    v, _ = trimesh.remesh.subdivide(body.v_template, body.faces)
    v = np.asarray(v) * 1.05  # a slightly bigger body
    ids = place_markers(v, joints * 1.05)
    np.testing.assert_allclose(v[ids], 1.05 * body.v_template[body.marker_vertex_ids], atol=0.025)


def test_place_markers_rejects_bad_input(joints):
    with pytest.raises(InputError):
        place_markers(np.zeros((10, 2)), joints)
    with pytest.raises(InputError):
        place_markers(np.zeros((10, 3)), joints[:20])
    with pytest.raises(InputError):
        place_markers(np.zeros((0, 3)), joints)
    with pytest.raises(InputError):
        place_markers(np.zeros((10, 3)), joints * (1, -1, 1))  # upside down
