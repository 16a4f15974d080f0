"""Torch LBS: rest pose, gradients, dtypes, subsets of vertices, batching."""

import math

import torch

from mdvae_cli.body.builtin import builtin_body_model
from mdvae_cli.body.skinning import BodyModel


def posed(body, B=4, seed=0, dtype=torch.float32):
    g = torch.Generator().manual_seed(seed)
    root = (torch.randn(B, 3, generator=g) * 0.5).to(dtype)
    pose = (torch.randn(B, 21, 3, generator=g) * 0.3).to(dtype)
    trans = torch.randn(B, 3, generator=g).to(dtype)
    betas = torch.randn(B, 16, generator=g).to(dtype)
    return root, pose, trans, betas


def test_rest_pose_reproduces_template_and_joints():
    data = builtin_body_model()
    body = BodyModel(data, dtype=torch.float64)
    z = torch.zeros(1, 3, dtype=torch.float64)
    out = body(z, torch.zeros(1, 21, 3, dtype=torch.float64), vertices=True)
    torch.testing.assert_close(out.vertices[0], torch.as_tensor(data.v_template))
    J = torch.as_tensor(data.J_regressor @ data.v_template)
    torch.testing.assert_close(out.joints[0], J[:22])
    torch.testing.assert_close(
        out.markers[0], torch.as_tensor(data.v_template[data.marker_vertex_ids])
    )


def test_float32_and_float64_agree_and_subsets_match_full_mesh():
    data = builtin_body_model()
    b32, b64 = BodyModel(data), BodyModel(data, dtype=torch.float64)
    args = posed(b32)
    o32 = b32(*args[:3], betas=args[3], vertices=True)
    o64 = b64(*(a.double() for a in args[:3]), betas=args[3].double(), vertices=True)
    assert (o32.vertices.double() - o64.vertices).abs().max() < 1e-5
    assert (o32.joints.double() - o64.joints).abs().max() < 1e-5
    ids = torch.tensor([0, 10, 500, 7000])
    sub = b64(*(a.double() for a in args[:3]), betas=args[3].double(), vertex_ids=ids)
    torch.testing.assert_close(sub.vertices, o64.vertices[:, ids])
    torch.testing.assert_close(sub.markers, o64.markers)
    # translation moves everything rigidly
    moved = b64(*(a.double() for a in args[:2]), args[2].double() + 1.0, betas=args[3].double())
    torch.testing.assert_close(moved.joints, sub.joints + 1.0)


def test_root_rotation_rotates_about_the_pelvis():
    body = BodyModel(builtin_body_model(), dtype=torch.float64)
    rest = body(torch.zeros(1, 3, dtype=torch.float64), torch.zeros(1, 21, 3, dtype=torch.float64))
    turn = torch.tensor([[0.0, math.pi / 2, 0.0]], dtype=torch.float64)  # 90 deg about y (up)
    out = body(turn, torch.zeros(1, 21, 3, dtype=torch.float64))
    torch.testing.assert_close(out.joints[0, 0], rest.joints[0, 0])  # pelvis fixed
    # the left hip (+x) swings to -z
    d = out.joints[0, 1] - out.joints[0, 0]
    d0 = rest.joints[0, 1] - rest.joints[0, 0]
    torch.testing.assert_close(d, torch.stack([d0[2], d0[1], -d0[0]]), atol=1e-12, rtol=0)


def test_gradients_flow_to_every_input():
    body = BodyModel(builtin_body_model(), dtype=torch.float64)
    args = [a.double().requires_grad_() for a in posed(body, B=2)]
    out = body(*args[:3], betas=args[3], vertex_ids=torch.arange(0, 7000, 50))
    (out.joints.square().sum() + out.markers.sum() + out.vertices.sum()).backward()
    for a in args:
        assert a.grad is not None and torch.isfinite(a.grad).all() and a.grad.abs().sum() > 0
