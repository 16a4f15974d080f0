"""Solving SMPL joint rotations from a source skeleton's posed joint positions: rest-pose
corrections between the two skeletons, and the per-frame pose solve that
``retarget.retarget`` runs, a chunk of a take's frames at a time (:func:`solve_frames`)."""

from __future__ import annotations

import numpy as np
import torch

from mdvae_cli.body.data import NUM_BODY_JOINTS, SMPL_PARENTS
from mdvae_cli.formats.source import SourceMotion
from mdvae_cli.geometry import frames_last as fl
from mdvae_cli.geometry.rotations import skew
from mdvae_cli.geometry.rotations_np import rotmat_between
from mdvae_cli.retarget.joint_map import (
    JointMap,
)
from mdvae_cli.retarget.soles import _FEET

_N = NUM_BODY_JOINTS
_PARENTS = SMPL_PARENTS[:_N]


def rest_corrections(jmap: JointMap, src_rest: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Per SMPL joint, the rotation C_j with ``G_smpl = G_source @ C_j`` in the rest pose:
    it turns the body's rest bone direction onto the source's.  -> (22, 3, 3)"""
    Y = src_rest[jmap.attach] + jmap.offset
    parents = _PARENTS
    C = np.tile(np.eye(3), (_N, 1, 1))
    for j in range(_N):
        kids = [k for k in range(_N) if parents[k] == j]
        if len(kids) == 1:
            C[j] = rotmat_between(X[kids[0]] - X[j], Y[kids[0]] - Y[j])
    for j in range(_N):  # leaves continue their parent's correction
        if not any(parents[k] == j for k in range(_N)):
            C[j] = C[parents[j]]
    return C


def _ancestors(parents: list[int]) -> torch.Tensor:
    """(22, 22) bool: A[k, j] when j is k or one of its ancestors."""
    A = torch.zeros(_N, _N, dtype=torch.bool)
    for k in range(_N):
        j = k
        while j >= 0:
            A[k, j] = True
            j = parents[j]
    return A


class _Tree:
    """The pose solve's index tables for one joint tree. Unknowns: a rotation for each joint
    with children ("active", in the tree's order, 0 .. n-1) and the root's translation (n,
    above every joint). The normal equations' 3x3 blocks are kept only where they can be
    non-zero, between a joint and itself or one of its ancestors: ``block[deep, high]`` is
    the place of the block H[deep, high] in the list of kept blocks."""

    def __init__(self, parents: list[int]):
        anc = _ancestors(parents)
        self.active = [j for j in range(_N) if j in parents[1:]]
        act = torch.as_tensor(self.active)
        n = len(self.active)
        self.subtree = anc[:, act].T.to(torch.float64)  # (n, 22): k in the subtree of active j
        A = anc[act][:, act]  # (n, n): active j' is active j or one of its ancestors
        pairs = [(i, a) for i in range(n) for a in range(n) if A[i, a]]
        self.deep, self.high = (torch.as_tensor(v) for v in zip(*pairs, strict=True))
        pairs += [(i, n) for i in range(n)] + [(n, n)]
        self.block = torch.full((n + 1, n + 1), -1, dtype=torch.long)
        for k, (i, a) in enumerate(pairs):
            self.block[i, a] = k
        # the diagonal blocks' places, as ints: H[k] with an int is a view, not a copy
        self.diagonal = self.block[range(n + 1), range(n + 1)].tolist()
        # each joint's neighbours when it is eliminated (children before their parents):
        # the translation, then its active ancestors from the root down, each "deeper" than
        # the one before; and the kept blocks among them (x deeper than or equal to y)
        self.above, self.updates = [], []
        for i in range(n):
            nb = [n] + [a for a in range(i) if A[i, a]]
            xy = [(x, y) for x in range(len(nb)) for y in range(x + 1)]
            px, py = (torch.as_tensor(v) for v in zip(*xy, strict=True))
            nb = torch.as_tensor(nb)
            self.above.append(nb)
            self.updates.append((px, py, self.block[nb[px], nb[py]]))


def normal_equations(p, r, tree: _Tree):
    """The Gauss-Newton normal equations of joint positions in the rotation increments of
    the joints with children (world frame, each turning its subtree about it) and the root's
    translation, built from subtree moments without the Jacobian. Frames go last, so that
    every operation, and the blocks' elimination (:func:`tree_solve`), moves whole rows of
    frames.

    p: (T, 22, 3) joint positions; r: (T, 22, 3) residuals p - target.
    -> H (blocks, 3, 3, T): the kept 3x3 blocks of J^T J (``tree.block``); g (n + 1, 3, T) =
    J^T r
    """
    p, r = (a.permute(1, 2, 0).contiguous() for a in (p, r))
    return _normal_equations(p, r, tree)


def _normal_equations(p, r, tree: _Tree):
    """:func:`normal_equations` of frames-last positions and residuals (22, 3, T)."""
    T, n = p.shape[-1], len(tree.active)
    q = p - p[:1]  # centred on the root joint, in the positions' own dtype
    S = tree.subtree.to(q.dtype)  # (n, 22)
    count = S.sum(1)  # (n,)
    s = (S @ q.reshape(_N, -1)).reshape(n, 3, T)  # sum of q_k over each subtree
    qq = (q[:, :, None] * q[:, None]).reshape(_N, -1)
    Q = (S @ qq).reshape(n, 3, 3, T)  # sum of q_k q_k^T over each subtree
    qa = q[tree.active]  # (n, 3, T) the active joints themselves
    # blocks H[m, a] (m deep, a one of its ancestors or m itself): the sum over the subtree
    # of m of (d_m . d_a) I - d_a d_m^T, with d_m = q_k - q_m, d_a = q_k - q_a
    m, a = tree.deep, tree.high
    sm, pm, pa, cm = (
        s.index_select(0, m),
        qa.index_select(0, m),
        qa.index_select(0, a),
        count[m, None],
    )
    pairs = len(m)
    H = q.new_empty((pairs + n + 1, 3, 3, T))
    outer = torch.index_select(Q, 0, m, out=H[:pairs])  # Q of the subtree of m, then the blocks
    dot = (outer[:, 0, 0] + outer[:, 1, 1] + outer[:, 2, 2]
           - (sm * (pm + pa)).sum(1) + cm * (pm * pa).sum(1))  # fmt: skip
    outer.addcmul_(sm[:, :, None], pm[:, None], value=-1)
    outer.addcmul_(pa[:, :, None], sm[:, None], value=-1)
    outer.addcmul_((cm[..., None] * pa)[:, :, None], pm[:, None])
    outer.neg_().diagonal(dim1=1, dim2=2).add_(dot[..., None])  # dot I - outer
    # the translation's column: the sum of skew(q_k - q_j) over the subtree of j
    H[pairs:-1] = skew((s - count[:, None, None] * qa).transpose(1, 2)).permute(0, 2, 3, 1)
    H[-1] = _N * torch.eye(3, dtype=q.dtype)[..., None]
    # the gradient: the sum over the subtree of (q_k - q_j) x r_k, and of r_k
    qxr = (S @ torch.linalg.cross(q, r, dim=1).reshape(_N, -1)).reshape(n, 3, T)
    R = (S @ r.reshape(_N, -1)).reshape(n, 3, T)
    g = torch.cat([qxr - torch.linalg.cross(qa, R, dim=1), r.sum(0, keepdim=True)])
    return H, g


def tree_solve(H: torch.Tensor, g: torch.Tensor, tree: _Tree) -> torch.Tensor:
    """Solve H x = g, H as :func:`normal_equations` lays it out (positive definite), by block
    elimination from the leaves up: joints are eliminated before their ancestors, so the
    elimination fills no block that was zero (the tree's joints that are not each other's
    ancestors stay uncoupled). H and g are overwritten.

    H: (blocks, 3, 3, T); g: (n + 1, 3, T) -> x (n + 1, 3, T)
    """
    n = len(tree.active)
    inverses, rows = [None] * n, [None] * n
    for j in reversed(range(n)):
        nb = tree.above[j]
        px, py, kept = tree.updates[j]
        Dinv = _inverse3(H[tree.diagonal[j]])
        V = H.index_select(0, tree.block[j, nb])  # (m, 3, 3, T): H[j, a] for each neighbour a
        Z = fl.matmul3(Dinv, V)  # Dinv @ H[j, a]
        # H[x, y] -= H[j, x]^T Dinv H[j, y]
        update = fl.matmul3(V.index_select(0, px).transpose(1, 2), Z.index_select(0, py))
        H.index_add_(0, kept, update, alpha=-1)
        u = (Dinv * g[j]).sum(1)
        g.index_add_(0, nb, (V * u[:, None]).sum(1), alpha=-1)
        inverses[j], rows[j] = Dinv, V
    x = torch.empty_like(g)
    x[n] = (_inverse3(H[tree.diagonal[n]]) * g[n]).sum(1)
    for j in range(n):
        # H[j, a] x[a] (one axis summed at a time: torch's sum over two is several times slower)
        rest = (rows[j] * x.index_select(0, tree.above[j])[:, None]).sum(2).sum(0)
        x[j] = (inverses[j] * (g[j] - rest)).sum(1)
    return x


def _inverse3(M: torch.Tensor) -> torch.Tensor:
    """Inverse of invertible 3x3 matrices by their cofactors, frames last.
    (3, 3, T) -> (3, 3, T)"""
    r0, r1, r2 = M
    c = torch.stack([torch.linalg.cross(r1, r2, dim=0), torch.linalg.cross(r2, r0, dim=0),
                     torch.linalg.cross(r0, r1, dim=0)], dim=1)  # fmt: skip
    det = (r0 * c[:, 0]).sum(0)
    return c / det


def solve_pose(
    targets: torch.Tensor,
    L_init: torch.Tensor,
    X: torch.Tensor,
    parents: list[int],
    twist_weight: float = 0.02,
    iterations: int = 3,
    damping: float = 1e-6,
    chunk: int = 1024,
    early_dtype: torch.dtype = torch.float32,
    stride: int = 1,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Fit local rotations and the root to joint targets, all frames at once.

    Minimises ``sum_j |p_j - y_j|^2 + twist_weight^2 sum_j |log(L_init_j^T L_j)|^2`` (metres,
    radians) by damped Gauss-Newton. Parameters per frame: a world-frame rotation increment for
    each joint that has children (turning its subtree about it) and the root position; joints
    without children (feet, wrists, head) keep their start rotation, which positions cannot see.
    Each step's normal equations are built from subtree sums (:func:`normal_equations`) and
    solved by block elimination along the tree (:func:`tree_solve`), not from a dense
    Jacobian and a dense factorisation. The steps before the last run in ``early_dtype`` and
    the last in float64: on ten real rigs that lands within 2e-4 of float64 throughout (whose
    own three steps stop 4e-3 to 0.1 short of the optimum), in 0.75 of its time.

    stride > 1 (a high-rate take): only every ``stride``-th frame (and the last) takes the
    ``iterations`` steps; every frame then starts from those key frames' departures from
    ``L_init`` (and the root's from its target) interpolated in time, and takes one last
    step in float64. On five real rigs at 100-120 Hz that lands as near the optimum as four
    plain steps, in 0.7 of three steps' time at a stride of 8 (docs/benchmarks.md).

    targets: (T, 22, 3); L_init: (T, 22, 3, 3); X: (22, 3) rest joints; -> L (T, 22, 3, 3),
    root position (T, 3)
    """
    tree = _Tree(parents)
    T, start, steps = targets.shape[0], None, iterations
    if stride > 1 and iterations > 0 and T > 2 * stride:
        key = key_frames(T, stride)
        L_key, root_key = solve_pose(targets[key], L_init[key], X, parents, twist_weight,
                                     iterations, damping, chunk, early_dtype)  # fmt: skip
        start = between_keys(L_init, targets[:, 0], key, L_key, root_key, tree.active)
        steps = 1
    # frames are independent: a chunk at a time stays in cache
    parts = [_solve_chunk(targets[i : i + chunk], L_init[i : i + chunk], X, parents, tree,
                          twist_weight, steps, damping, early_dtype,
                          None if start is None else (start[0][i : i + chunk],
                                                      start[1][i : i + chunk]))
             for i in range(0, T, chunk)]  # fmt: skip
    L, root = torch.cat([a for a, _ in parts]), torch.cat([b for _, b in parts])
    if start is not None and start[2].any():  # between keys too far apart: every step there
        far = start[2].nonzero()[:, 0]
        L[far], root[far] = solve_pose(targets[far], L_init[far], X, parents, twist_weight,
                                       iterations, damping, chunk, early_dtype)  # fmt: skip
    return L, root


#: radians a joint's departure may change between two key frames for the frames between them
#: to start from the line joining them (the real rigs' largest: 0.39, jesse_dance at 100 Hz)
KEY_TURN = 0.5


def key_stride(fps: float, key_rate: float) -> int:
    """The pose solve's stride for a take at ``fps``: a take at four times ``key_rate`` (Hz)
    or more takes every step on ``key_rate`` frames a second (1: every frame, as at 30 Hz)."""
    return 1 if key_rate <= 0 or fps < 4 * key_rate else int(fps // key_rate)


def key_frames(num_frames: int, stride: int) -> torch.Tensor:
    """Every ``stride``-th frame of a take and its last.  -> (K,) long"""
    key = torch.arange(0, num_frames, stride)
    return key if key[-1] == num_frames - 1 else torch.cat([key, key.new_tensor([num_frames - 1])])


def between_keys(
    L_init: torch.Tensor,
    root_init: torch.Tensor,
    key: torch.Tensor,
    L_key: torch.Tensor,
    root_key: torch.Tensor,
    active: list[int],
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Start rotations and root for every frame from the key frames' solutions: each active
    joint's departure from its start (a rotation vector in the joint's own frame) and the
    root's from its start, interpolated linearly in time between key frames.

    L_init: (T, 22, 3, 3); root_init: (T, 3); key: (K,) increasing frame numbers, the first
    0 and the last T - 1; L_key: (K, 22, 3, 3); root_key: (K, 3) -> L (T, 22, 3, 3), root
    (T, 3), and which frames lie between key frames whose departures differ by over
    :data:`KEY_TURN` rad in a joint (T,) bool: a line between those is no start to trust.
    """
    act = torch.as_tensor(active)
    turn = fl.turn_vector(L_init[key][:, act].transpose(-1, -2) @ L_key[:, act])  # (K, n, 3)
    t = torch.arange(L_init.shape[0], dtype=L_init.dtype)
    after = torch.searchsorted(key.to(t.dtype), t, right=True).clamp(1, len(key) - 1)
    k0, k1 = key[after - 1], key[after]
    u = ((t - k0) / (k1 - k0))[:, None]  # (T, 1): 0 at the key before, 1 at the one after
    L = L_init.clone()
    between = turn[after - 1] * (1 - u[..., None]) + turn[after] * u[..., None]
    L[:, act] = L_init[:, act] @ fl.turn_matrix(between)
    moved = root_key - root_init[key]
    far = (turn[1:] - turn[:-1]).norm(dim=-1).amax(-1) > KEY_TURN  # (K - 1,) per interval
    return L, root_init + moved[after - 1] * (1 - u) + moved[after] * u, far[after - 1]


def _solve_chunk(
    targets,
    L_init,
    X,
    parents,
    tree: _Tree,
    twist_weight,
    iterations,
    damping,
    early_dtype,
    start=None,
):
    """:func:`solve_pose` on one chunk of frames, worked on with the frames last
    (``geometry.frames_last``); ``start``: (L (T, 22, 3, 3), root (T, 3)) to begin from
    instead of ``L_init`` and the root's target (the twist term still pulls to ``L_init``)."""
    active, n = torch.as_tensor(tree.active), len(tree.active)
    bones = X.clone()
    bones[1:] = X[1:] - X[parents[1:]]
    anchor = L_init.permute(1, 2, 3, 0)[active]  # (n, 3, 3, T)
    L = (L_init if start is None else start[0]).permute(1, 2, 3, 0).contiguous()  # (22, 3, 3, T)
    y = targets.permute(1, 2, 0).contiguous()  # (22, 3, T)
    root = y[0].clone() if start is None else start[1].T.contiguous()
    w2 = twist_weight**2
    eye = torch.eye(3, dtype=early_dtype)[..., None]
    for step_number in range(iterations):
        # the last step's pose and miss in float64 (float32 throughout is up to 1e-3 off on a
        # rig whose twists only the twist weight holds: ill-conditioned blocks); the normal
        # equations of that miss in early_dtype (their rounding slows the step, moves no optimum)
        dtype = torch.float64 if step_number == iterations - 1 else early_dtype
        Lw = L.to(dtype)
        G, p = fl.forward_kinematics(Lw, bones.to(dtype), parents[:_N], root.to(dtype))
        r = p - y.to(dtype)
        H, g = _normal_equations((p - p[:1]).to(early_dtype), r.to(early_dtype), tree)
        H[tree.diagonal[:n]] += (w2 + damping) * eye
        H[tree.diagonal[n]] += damping * eye
        Ga = G[active]
        if step_number > 0 or start is not None:  # at L_init: no departure to pull back
            delta = fl.turn_vector(fl.matmul3(anchor.to(dtype).transpose(1, 2), Lw[active]), -2)
            g[:n] += (w2 * fl.matvec3(Ga, delta)).to(early_dtype)
        step = tree_solve(H, g, tree).neg_().to(dtype)
        local = fl.matTvec3(Ga, step[:n])
        L[active] = fl.matmul3(L[active], fl.turn_matrix(local.to(L.dtype), -2))
        root = root + step[n].to(root.dtype)
    return L.permute(3, 0, 1, 2), root.T


CHUNK_FRAMES = 4096  # frames solved at once (a multiple of solve_pose's own chunks)


def frame_chunks(num_frames: int, chunk: int = CHUNK_FRAMES) -> list[slice]:
    """A take's frames ``chunk`` at a time."""
    return [slice(i, min(i + chunk, num_frames)) for i in range(0, num_frames, chunk)]


def solve_frames(src: SourceMotion, frames: slice, jmap, C, X, parents, settings) -> tuple:
    """The pose solve on some of the take's frames (each frame is solved on its own, so a
    long take goes a chunk at a time in flat memory). -> (targets (n, 22, 3), root (n, 3),
    joints (n, 22, 3), the pelvis's world rotation (n, 3, 3), the ankles' and feet's
    (n, 4, 3, 3), pose_body (n, 21, 3))"""
    G_src, P_src = (torch.as_tensor(a) for a in src.forward_kinematics(frames))
    attach, offset = torch.as_tensor(jmap.attach), torch.as_tensor(jmap.offset)
    targets = P_src[:, attach] + (G_src[:, attach] @ offset[..., None])[..., 0]
    G0 = G_src[:, torch.as_tensor(jmap.rot_source)] @ C
    L0 = G0.clone()
    L0[:, 1:] = G0[:, parents[1:]].transpose(-1, -2) @ G0[:, 1:]
    del G_src, P_src, G0
    L, root = solve_pose(targets, L0, X, parents, settings.twist_weight, settings.iterations,
                         stride=key_stride(src.fps, settings.key_rate))  # fmt: skip
    bones = X.clone()
    bones[1:] = X[1:] - X[parents[1:]]
    G, p = fl.forward_kinematics(L.permute(1, 2, 3, 0).contiguous(), bones, parents[:_N],
                                 root.T.contiguous())  # fmt: skip
    feet = G[_FEET].permute(3, 0, 1, 2).contiguous()
    return (
        targets,
        root,
        p.permute(2, 0, 1).contiguous(),
        G[0].permute(2, 0, 1).contiguous(),
        feet,
        fl.turn_vector(L[:, 1:]),
    )
