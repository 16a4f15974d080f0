"""The retarget's pose solve (``retarget/pose_solve.py``): its normal equations and block
elimination against dense ones, its float32 early steps, and a high-rate take solved from key
frames."""

import torch

import mdvae_cli.retarget.pose_solve as ps
from mdvae_cli.body.data import SMPL_PARENTS
from mdvae_cli.geometry.kinematics import forward_kinematics
from mdvae_cli.geometry.rotations import rotvec_to_rotmat
from mdvae_cli.retarget.pose_solve import (
    _Tree,
    between_keys,
    key_frames,
    key_stride,
    normal_equations,
    solve_pose,
    tree_solve,
)

parents = list(SMPL_PARENTS[:22])


def random_skeleton(g: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """A 22-joint tree's rest joints (root at 0) drawn from ``g``, and its bones (each joint's
    offset from its parent).  -> (22, 3), (22, 3)"""
    X = 0.15 * torch.randn(22, 3, generator=g, dtype=torch.float64)
    X[0] = 0.0
    bones = X.clone()
    bones[1:] = X[1:] - X[parents[1:]]
    return X, bones


def test_pose_solve_normal_equations_and_tree_solve_match_the_dense_ones():
    """The pose solve's normal equations, built from subtree moments, are J^T J and J^T r of
    the joints' Jacobian (taken here by finite differences of the forward kinematics), and its
    block elimination solves them as a dense solver does."""
    tree = _Tree(parents)
    n, T = len(tree.active), 3
    g0 = torch.Generator().manual_seed(0)
    L = rotvec_to_rotmat(0.5 * torch.randn(T, 22, 3, generator=g0, dtype=torch.float64))
    bones = 0.2 * torch.randn(22, 3, generator=g0, dtype=torch.float64)
    root = torch.randn(T, 3, generator=g0, dtype=torch.float64)
    G, p = forward_kinematics(L, bones, parents, root=root)
    targets = p + 0.05 * torch.randn(T, 22, 3, generator=g0, dtype=torch.float64)
    J = torch.zeros(T, 66, 3 * n + 3, dtype=torch.float64)
    eps = 1e-6
    for i, j in enumerate(tree.active):  # a world-frame turn of joint j's subtree about it
        for b in range(3):
            w = torch.zeros(3, dtype=torch.float64)
            w[b] = eps
            turned = L.clone()
            turned[:, j] = L[:, j] @ rotvec_to_rotmat(G[:, j].transpose(-1, -2) @ w)
            J[:, :, 3 * i + b] = (forward_kinematics(turned, bones, parents, root=root)[1] - p
                                  ).reshape(T, 66) / eps  # fmt: skip
    J[:, :, 3 * n :] = torch.eye(3, dtype=torch.float64).repeat(22, 1)
    r = p - targets
    H, g = normal_equations(p, r, tree)
    dense = torch.zeros(T, 3 * n + 3, 3 * n + 3, dtype=torch.float64)
    for x in range(n + 1):
        for y in range(n + 1):
            k = int(tree.block[x, y])
            if k >= 0:
                dense[:, 3 * x : 3 * x + 3, 3 * y : 3 * y + 3] = H[k].permute(2, 0, 1)
                dense[:, 3 * y : 3 * y + 3, 3 * x : 3 * x + 3] = H[k].permute(2, 1, 0)
    JT = J.transpose(1, 2)
    torch.testing.assert_close(dense, JT @ J, atol=2e-4, rtol=1e-4)
    gd = (JT @ r.reshape(T, 66, 1))[..., 0]
    torch.testing.assert_close(g.permute(2, 0, 1).reshape(T, -1), gd, atol=2e-4, rtol=1e-4)
    # damped as the solve damps it, then solved both ways
    damped = H.clone()
    damped[tree.diagonal] += 1e-3 * torch.eye(3, dtype=torch.float64)[..., None]
    dense += 1e-3 * torch.eye(3 * n + 3, dtype=torch.float64)
    x = tree_solve(damped, g.clone(), tree).permute(2, 0, 1).reshape(T, -1)
    want = torch.linalg.solve(dense, g.permute(2, 0, 1).reshape(T, -1, 1))[..., 0]
    torch.testing.assert_close(x, want, atol=1e-9, rtol=1e-9)  # float64 throughout
    assert want.abs().max() > 0.01  # a real step, not a trivial one


def test_pose_solve_early_steps_in_float32_land_where_float64_steps_do():
    """The pose solve's steps before the last run in float32, the last in float64: the result
    is where float64 throughout lands (far closer than three steps come to the optimum), and
    the fit is as good."""
    g0 = torch.Generator().manual_seed(1)
    T = 200
    X, bones = random_skeleton(g0)
    truth = rotvec_to_rotmat(0.6 * torch.randn(T, 22, 3, generator=g0, dtype=torch.float64))
    root = torch.randn(T, 3, generator=g0, dtype=torch.float64)
    targets = forward_kinematics(truth, bones, parents, root=root)[1]
    turn = 0.1 * torch.randn(T, 22, 3, generator=g0, dtype=torch.float64)
    start = truth @ rotvec_to_rotmat(turn)
    mixed, r_mixed = solve_pose(targets, start, X, parents)
    wide, r_wide = solve_pose(targets, start, X, parents, early_dtype=torch.float64)
    best, _ = solve_pose(targets, start, X, parents, iterations=12, early_dtype=torch.float64)
    assert mixed.dtype == torch.float64
    gap = (mixed - wide).abs().flatten(1).amax(1)  # per frame
    short = (wide - best).abs().flatten(1).amax(1)  # how far three steps stop from the optimum
    assert gap.max() < 1e-3 and gap.median() < 0.1 * short.median()
    assert (r_mixed - r_wide).abs().max().item() < 1e-5

    def error(L, r):
        return (forward_kinematics(L, bones, parents, root=r)[1] - targets).norm(dim=-1).mean()

    assert error(mixed, r_mixed) < 1.001 * error(wide, r_wide)
    assert error(wide, r_wide) < 0.2 * error(start, root)


def test_pose_solve_key_frames_and_stride():
    assert [key_stride(fps, 15.0) for fps in (24, 30, 59.9, 60, 100, 120, 240)] == [
        1, 1, 1, 4, 6, 8, 16,
    ]  # fmt: skip
    assert key_stride(120, 0.0) == 1  # key_rate 0: every frame every step
    assert key_frames(10, 4).tolist() == [0, 4, 8, 9]
    assert key_frames(9, 4).tolist() == [0, 4, 8]


def test_between_key_frames_the_departures_are_interpolated():
    """At a key frame the start is the key frame's solution; between two, a departure turning
    at a steady rate about one axis (and a root moving at a steady speed) is found exactly."""
    g = torch.Generator().manual_seed(3)
    T, active = 21, [0, 1, 3]
    L_init = rotvec_to_rotmat(torch.randn(T, 22, 3, generator=g, dtype=torch.float64))
    root_init = torch.randn(T, 3, generator=g, dtype=torch.float64)
    t = torch.arange(T, dtype=torch.float64)[:, None, None]
    axis = torch.nn.functional.normalize(
        torch.randn(22, 3, generator=g, dtype=torch.float64), dim=-1
    )
    turn = (0.01 * t + 0.2) * axis  # (T, 22, 3): the departure, steady in time
    truth = L_init @ rotvec_to_rotmat(turn)
    moved = root_init + 0.03 * t[:, 0] * torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64)
    key = key_frames(T, 8)  # 0, 8, 16, 20
    L, root, far = between_keys(L_init, root_init, key, truth[key], moved[key], active)
    assert not far.any()  # 0.08 rad between key frames at most
    assert (L[:, active] - truth[:, active]).abs().max() < 1e-12
    assert (root - moved).abs().max() < 1e-12
    others = [j for j in range(22) if j not in active]
    assert torch.equal(L[:, others], L_init[:, others])  # joints without unknowns stay


def test_a_high_rate_take_solved_from_key_frames_lands_nearer_the_optimum():
    """A smooth 120-frame take: every 8th frame takes the three steps, every frame one more
    from their departures; that lands nearer the optimum than three steps on every frame, and
    fits the joints as well."""
    g = torch.Generator().manual_seed(2)
    T = 120
    X, bones = random_skeleton(g)
    t = torch.arange(T, dtype=torch.float64)[:, None, None] / 120.0
    amp, freq, phase = (torch.randn(22, 3, generator=g, dtype=torch.float64) for _ in "afp")
    truth = rotvec_to_rotmat(0.5 * amp * torch.sin(2 * torch.pi * (0.5 + freq.abs()) * t + phase))
    root = 0.3 * torch.sin(2 * torch.pi * t[:, 0] + torch.tensor([0.0, 1.0, 2.0]))
    # another skeleton's targets: the truth's joints with a bone-length change of a few %
    targets = forward_kinematics(truth, bones * 1.04, parents, root=root)[1]
    start = truth @ rotvec_to_rotmat(0.1 * torch.sin(2 * torch.pi * t + phase))
    plain, r_plain = solve_pose(targets, start, X, parents)
    keyed, r_keyed = solve_pose(targets, start, X, parents, stride=8)
    best, r_best = solve_pose(targets, start, X, parents, iterations=12, early_dtype=torch.float64)

    def off(L):  # how far from the optimum, per frame
        return (L - best).abs().flatten(1).amax(1)

    assert off(keyed).median() < 0.85 * off(plain).median()  # 3.3e-4 against 4.3e-4
    assert off(keyed).max() < off(plain).max()

    def error(L, r):
        return (forward_kinematics(L, bones, parents, root=r)[1] - targets).norm(dim=-1).mean()

    assert error(keyed, r_keyed) < 1.001 * error(best, r_best)


def test_frames_between_key_frames_far_apart_take_every_step(monkeypatch):
    """Where a joint's departure from its start changes by over KEY_TURN between two key
    frames, the frames between them are solved as without key frames (a line between two
    far departures is no start to trust); the others keep the key frames' start."""

    g = torch.Generator().manual_seed(4)
    T = 41
    X, bones = random_skeleton(g)
    truth = rotvec_to_rotmat(0.3 * torch.randn(T, 22, 3, generator=g, dtype=torch.float64))
    targets = forward_kinematics(truth, bones * 1.04, parents, root=torch.zeros(T, 3))[1]
    turn = torch.full((T, 22, 3), 0.02, dtype=torch.float64)
    turn[16] = 0.6  # key frame 16 starts far off: its departure jumps from both neighbours'
    start = truth @ rotvec_to_rotmat(turn)
    key = key_frames(T, 8)
    L_key, r_key = solve_pose(targets[key], start[key], X, parents)
    far = between_keys(start, targets[:, 0], key, L_key, r_key, _Tree(parents).active)[2]
    idx = list(range(8, 24))
    assert far.nonzero()[:, 0].tolist() == idx
    keyed, _ = solve_pose(targets, start, X, parents, stride=8)
    alone, _ = solve_pose(targets[idx], start[idx], X, parents)
    assert torch.equal(keyed[idx], alone)
    monkeypatch.setattr(ps, "KEY_TURN", float("inf"))
    lined, _ = solve_pose(targets, start, X, parents, stride=8)
    rest = [t for t in range(T) if t not in idx]
    assert torch.equal(keyed[rest], lined[rest]) and not torch.equal(keyed[idx], lined[idx])
