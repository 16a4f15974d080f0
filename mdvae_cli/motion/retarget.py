"""Retarget a mocap clip (:class:`SourceMotion`) onto the SMPL skeleton of a body model.

Pipeline, all frames at once in torch:

1. **Joint map** (:func:`build_joint_map`): source joints are found by name for the SMPL joints
   with a clear anatomical counterpart (*direct* joints: hips, knees, ankles, toe bases,
   shoulders, elbows, wrists); the others (pelvis, spine1-3, neck, head, collars) are *attached*
   points: a fixed offset in the frame of a source joint, taken from the body's rest pose.
2. **Canonical axes**: the source world is turned (a signed axis permutation read off the rest
   pose) so that up is +y, the body's left +x and forward +z, SMPL's own frame.
3. **Betas** (:func:`fit_betas`): the body's shape is fitted once per skeleton so that its rest
   bone lengths (legs, arms, hip and shoulder widths, torso and neck) match the source's.
4. **Solve**: each SMPL joint's rotation starts from its source joint's global rotation,
   corrected by the rest-pose difference of the bone direction; a few damped Gauss-Newton steps
   then fit all 22 joint positions to the targets, with a small penalty that keeps each local
   rotation near its source start (this fixes the twists that positions cannot see).
5. **Output**: SMPL y-up is turned into AMASS z-up, the floor is put at z = 0 (from the soles
   of the body's feet) and the result is a :class:`Motion` with the mean joint error.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from mdvae_cli.body.data import NUM_BODY_JOINTS, SMPL_JOINT_NAMES, SMPL_PARENTS, BodyModelData
from mdvae_cli.errors import InputError
from mdvae_cli.geometry.rotations import rotmat_to_rotvec, rotvec_to_rotmat, skew
from mdvae_cli.motion.asfamc import AsfSkeleton, load_amc
from mdvae_cli.motion.bvh import SourceMotion, load_bvh, resample_source
from mdvae_cli.motion.motion import Motion

_N = NUM_BODY_JOINTS
_IDX = {name: i for i, name in enumerate(SMPL_JOINT_NAMES)}

#: source joint names (normalised: lower case, no namespace, no ``_ - . space``) per SMPL joint;
#: the first that exists wins. Left side only; the right is derived.
_ALIASES: dict[str, tuple[str, ...]] = {
    "pelvis": ("root", "hips", "pelvis", "hip"),
    "left_hip": ("lfemur", "leftupleg", "leftthigh", "lefthip", "lthigh", "lhip", "leftupperleg",
                 "lupleg"),
    "left_knee": ("ltibia", "leftleg", "leftshin", "leftknee", "lshin", "lknee", "leftlowerleg"),
    "left_ankle": ("lfoot", "leftfoot", "leftankle", "lankle"),
    "left_foot": ("ltoes", "lefttoebase", "lefttoe", "lefttoes", "ltoe", "lefttoebase"),
    "left_shoulder": ("lhumerus", "leftarm", "leftupperarm", "leftuparm", "lshldr", "lshoulder",
                      "leftshoulder"),
    "left_collar": ("lclavicle", "leftshoulder", "leftcollar", "lcollar", "leftclavicle",
                    "lclav"),
    "left_elbow": ("lradius", "leftforearm", "leftlowerarm", "leftelbow", "lforearm", "lelbow"),
    "left_wrist": ("lhand", "lefthand", "leftwrist", "lwrist"),
    "head": ("head",),
}  # fmt: skip

#: SMPL joints that must be found in the source
_REQUIRED = ("pelvis", "left_hip", "left_knee", "left_ankle", "left_shoulder", "left_elbow",
             "left_wrist", "head")  # fmt: skip
_DIRECT = ("left_hip", "left_knee", "left_ankle", "left_foot", "left_shoulder", "left_elbow",
           "left_wrist")  # fmt: skip
_SPINE = ("spine1", "spine2", "spine3", "neck", "head")
_PARENTS = SMPL_PARENTS[:_N]

#: y-up (SMPL) -> z-up (AMASS): x stays, y becomes z, z becomes -y
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def _sides(name: str) -> list[str]:
    return [name, "right" + name[4:]] if name.startswith("left") else [name]


def _right_alias(alias: str) -> str:
    if alias.startswith("left"):
        return "right" + alias[4:]
    if alias[0] == "l":
        return "r" + alias[1:]
    return alias


def normalise_name(name: str) -> str:
    """``mixamorig:Left_Up-Leg`` -> ``leftupleg``."""
    name = re.split(r"[:|]", name)[-1]
    return re.sub(r"[\s_.\-]", "", name).lower()


@dataclass
class JointMap:
    """How the 22 SMPL body joints read a source skeleton.  Indices are source joint indices.

    anchor: SMPL joint name -> source joint found by name (direct joints, pelvis, head, collars).
    attach: (22,) source joint carrying each SMPL joint's target; offset: (22, 3) the target's
    offset in that joint's frame (zero for direct joints; set by :func:`attach_offsets`).
    rot_source: (22,) source joint whose global rotation starts each SMPL joint's rotation.
    direct: (22,) bool. chain: source joints from the pelvis to the head anchor.
    """

    anchor: dict[str, int]
    attach: np.ndarray
    rot_source: np.ndarray
    direct: np.ndarray
    chain: list[int]
    offset: np.ndarray = field(default_factory=lambda: np.zeros((_N, 3)))

    def describe(self, names: tuple[str, ...]) -> dict[str, str]:
        """SMPL joint -> the source joint it follows (``~`` marks an attached point)."""
        return {
            SMPL_JOINT_NAMES[j]: ("" if self.direct[j] else "~") + names[self.attach[j]]
            for j in range(_N)
        }


def _path(parents: np.ndarray, a: int, b: int) -> list[int]:
    """Source joints from ancestor a down to b (both included); [] if a is not an ancestor."""
    out = [b]
    while out[-1] != a:
        p = int(parents[out[-1]])
        if p < 0:
            return []
        out.append(p)
    return out[::-1]


def _find_anchors(src: SourceMotion) -> dict[str, int]:
    """SMPL joint name -> source joint, by name; InputError when a required one is missing."""
    norm: dict[str, int] = {}
    for i, n in enumerate(src.names):
        if not src.end_site[i]:
            norm.setdefault(normalise_name(n), i)
    anchor: dict[str, int] = {}
    for smpl, aliases in _ALIASES.items():
        for side, name in zip(("l", "r"), _sides(smpl), strict=False):
            names = aliases if side == "l" else tuple(_right_alias(a) for a in aliases)
            taken = set(anchor.values())
            hit = next((norm[a] for a in names if a in norm and norm[a] not in taken), None)
            if hit is not None:
                anchor[name] = hit
    for smpl in _REQUIRED:
        for name in _sides(smpl):
            if name not in anchor:
                more = ", ..." if len(src.names) > 12 else ""
                raise InputError(
                    f"cannot map the skeleton onto SMPL: no joint for {name} (looked for "
                    f"{', '.join(_ALIASES[smpl][:4])}, ...; joints: {', '.join(src.names[:12])}"
                    f"{more})"
                )
    return anchor


def _through_zero_offsets(src: SourceMotion, j: int) -> int:
    """Follow zero-length, non-thumb children down from j (cmuconvert's hands start so)."""
    while True:
        kids = [
            k
            for k in np.flatnonzero(src.parents == j)
            if not src.end_site[k]
            and np.linalg.norm(src.offsets[k]) < 1e-6
            and "thumb" not in src.names[k].lower()
        ]
        if not kids:
            return int(j)
        j = kids[0]


def build_joint_map(src: SourceMotion) -> JointMap:
    """Find the SMPL joints in ``src`` by name (CMU ASF, CMU/MotionBuilder/Mixamo BVH, ...).

    Spine joints (and collars the source lacks) are left for :func:`attach_offsets`, which
    places them once the body's shape is known. Raises InputError naming the first SMPL joint
    that cannot be found.
    """
    anchor = _find_anchors(src)
    parents = src.parents
    chain = _path(parents, anchor["pelvis"], anchor["head"])
    if not chain:
        raise InputError("cannot map the skeleton onto SMPL: the head is not below the pelvis")
    attach = np.full(_N, -1, dtype=np.int64)
    rot = np.full(_N, -1, dtype=np.int64)
    direct = np.zeros(_N, dtype=bool)
    for smpl in _DIRECT:
        for name in _sides(smpl):
            if name in anchor:
                attach[_IDX[name]] = anchor[name]
                direct[_IDX[name]] = True
    if src.info.get("cmuconvert"):
        # cmuconvert drops CMU's wrist segment: its hand joint sits ~9 cm short of the wrist,
        # so the body's wrist becomes a point further along the forearm (attach_offsets)
        direct[[_IDX["left_wrist"], _IDX["right_wrist"]]] = False
    attach[0] = rot[0] = anchor["pelvis"]
    for side in ("left", "right"):
        if f"{side}_foot" not in anchor:  # no toes: a point in the ankle's frame
            attach[_IDX[f"{side}_foot"]] = anchor[f"{side}_ankle"]
        collar = anchor.get(f"{side}_collar")
        path = _path(parents, collar, anchor[f"{side}_shoulder"]) if collar is not None else []
        if len(path) >= 2:
            attach[_IDX[f"{side}_collar"]], rot[_IDX[f"{side}_collar"]] = collar, path[-2]
        # rotation sources: the last source joint before the next anchor down the limb
        for a, b in (("hip", "knee"), ("knee", "ankle"), ("ankle", "foot"),
                     ("shoulder", "elbow"), ("elbow", "wrist")):  # fmt: skip
            ja, jb = anchor[f"{side}_{a}"], anchor.get(f"{side}_{b}")
            path = _path(parents, ja, jb) if jb is not None else []
            rot[_IDX[f"{side}_{a}"]] = path[-2] if len(path) >= 2 else ja
        for leaf in ("foot", "wrist"):  # leaves: their own frame (past zero-length joints)
            j = _IDX[f"{side}_{leaf}"]
            rot[j] = _through_zero_offsets(src, attach[j])
    return JointMap(anchor=anchor, attach=attach, rot_source=rot, direct=direct, chain=chain)


def canonical_rotation(src: SourceMotion, jmap: JointMap) -> np.ndarray:
    """The signed axis permutation S (det +1) taking the source world to SMPL's: up +y, the
    body's left +x, forward +z, read off the rest pose.  -> (3, 3)"""
    rest = src.rest_positions()
    up = rest[jmap.anchor["head"]] - rest[jmap.anchor["pelvis"]]
    left = rest[jmap.anchor["left_hip"]] - rest[jmap.anchor["right_hip"]]
    iu = int(np.argmax(np.abs(up)))
    left = left.copy()
    left[iu] = 0.0
    il = int(np.argmax(np.abs(left)))
    if np.linalg.norm(left) < 1e-9 or il == iu:
        raise InputError("cannot tell left from right in the source rest pose")
    S = np.zeros((3, 3))
    S[1, iu] = np.sign(up[iu])
    S[0, il] = np.sign(left[il])
    S[2] = np.cross(S[0], S[1])
    return S


def canonicalise(src: SourceMotion, S: np.ndarray) -> SourceMotion:
    """``src`` expressed in the world turned by S (positions S p, rotations S R S^T)."""
    if np.allclose(S, np.eye(3)):
        return src
    rot = np.einsum("ab,tjbc,dc->tjad", S, src.rotations, S)
    return replace(src, offsets=src.offsets @ S.T, root_positions=src.root_positions @ S.T,
                   rotations=rot, info=dict(src.info), notes=list(src.notes))  # fmt: skip


# --- the body ----------------------------------------------------------------------------------


class BodyJoints:
    """What retargeting needs from a body model: rest joints as a function of betas, and the
    feet (for the floor). Built once, reused for every file."""

    def __init__(self, data: BodyModelData):
        dt = torch.float64
        self.data = data
        self.parents = [int(p) for p in data.parents[:_N]]
        reg = torch.as_tensor(data.J_regressor, dtype=dt)
        self.J_template = reg @ torch.as_tensor(data.v_template, dtype=dt)
        dirs = torch.as_tensor(data.shapedirs, dtype=dt)
        self.J_shapedirs = torch.einsum("jv,vck->jck", reg, dirs)
        W = np.asarray(data.weights)
        feet = np.flatnonzero(W[:, [7, 8, 10, 11]].sum(1) >= 0.5)
        self.foot_ids = feet
        self.foot_weights = torch.as_tensor(W[feet][:, [7, 8, 10, 11]], dtype=dt)
        self.foot_weights = self.foot_weights / self.foot_weights.sum(1, keepdim=True)
        self.foot_template = torch.as_tensor(data.v_template[feet], dtype=dt)
        self.foot_shapedirs = torch.as_tensor(data.shapedirs[feet], dtype=dt)

    @property
    def num_betas(self) -> int:
        return int(self.J_shapedirs.shape[2])

    def rest_joints(self, betas: torch.Tensor) -> torch.Tensor:
        """betas: (S,) -> (J, 3) rest joints of the whole model (SMPL frame, y up)"""
        return self.J_template + torch.einsum("k,jck->jc", betas, self.J_shapedirs)

    def foot_vertices(self, betas: torch.Tensor) -> torch.Tensor:
        """betas: (S,) -> (F, 3) rest positions of the foot vertices"""
        return self.foot_template + torch.einsum("k,vck->vc", betas, self.foot_shapedirs)


def _length_pairs(jmap: JointMap) -> list[tuple[tuple[int, ...], tuple[int, ...], float]]:
    """(SMPL joints a, SMPL joints b, weight): the distance between the means of a and b."""
    pairs = []
    for side in ("left", "right"):
        chain = [f"{side}_{n}" for n in ("hip", "knee", "ankle", "foot")]
        arm = [f"{side}_{n}" for n in ("shoulder", "elbow", "wrist")]
        for seq in (chain, arm):
            for a, b in zip(seq[:-1], seq[1:], strict=True):
                if jmap.direct[_IDX[a]] and jmap.direct[_IDX[b]]:
                    pairs.append(((_IDX[a],), (_IDX[b],), 1.0))
    pairs.append(((1,), (2,), 1.0))  # hip width
    pairs.append(((16,), (17,), 1.0))  # shoulder width
    pairs.append(((1, 2), (16, 17), 1.0))  # torso: hips to shoulders
    pairs.append(((16, 17), (15,), 0.5))  # neck: shoulders to head
    return pairs


def fit_betas(
    src: SourceMotion, body: BodyJoints, jmap: JointMap | None = None, prior: float = 1e-5
) -> np.ndarray:
    """Body shape whose rest bone lengths match the source's.  -> (S,)

    Minimises the sum of squared length differences (metres) over legs, arms, hip and shoulder
    width, hips-to-shoulders and shoulders-to-head, plus ``prior * |betas|^2``, by Gauss-Newton
    (lengths are nearly linear in betas). Only lengths matter, so ``src`` may use any axes.
    """
    jmap = jmap or build_joint_map(src)
    rest = src.rest_positions()
    target = {_IDX[name]: rest[i] for name, i in jmap.anchor.items()}
    target[15] = rest[jmap.anchor["head"]]
    pairs = [p for p in _length_pairs(jmap) if all(j in target for j in p[0] + p[1])]
    # each pair's vector is linear in betas: d(b) = d0 + M b
    J0 = body.J_template.numpy()
    Js = body.J_shapedirs.numpy()
    d0 = np.stack([J0[list(b)].mean(0) - J0[list(a)].mean(0) for a, b, _ in pairs])
    M = np.stack([Js[list(b)].mean(0) - Js[list(a)].mean(0) for a, b, _ in pairs])  # (P, 3, S)
    ell = np.array(
        [
            np.linalg.norm(np.mean([target[j] for j in b], 0) - np.mean([target[j] for j in a], 0))
            for a, b, _ in pairs
        ]
    )
    w = np.array([wt for _, _, wt in pairs])
    S = M.shape[2]
    betas = np.zeros(S)
    for _ in range(20):
        d = d0 + M @ betas
        n = np.linalg.norm(d, axis=1)
        r = n - ell
        Jac = np.einsum("pc,pcs->ps", d / n[:, None], M)
        H = Jac.T @ (w[:, None] * Jac) + prior * np.eye(S)
        g = Jac.T @ (w * r) + prior * betas
        step = np.linalg.solve(H, -g)
        betas = betas + step
        if np.abs(step).max() < 1e-9:
            break
    return betas


def _last_below(heights: np.ndarray, chain: list[int], h: float) -> int:
    """The last chain joint whose rest height is at most h (the first joint if none is)."""
    below = [c for c, hc in zip(chain, heights, strict=True) if hc <= h + 1e-3]
    return below[-1] if below else chain[0]


def attach_offsets(src: SourceMotion, jmap: JointMap, rest_joints: np.ndarray) -> JointMap:
    """Place the attached (non-direct) SMPL joints on the source skeleton.

    The body's rest joints ``rest_joints`` (J, 3) are moved so that its hip centre meets the
    source's; spine joints and missing collars then ride on the last source spine joint below
    them, and every attached joint keeps its rest offset from its carrier.  Fills in
    ``attach``, ``rot_source`` and ``offset`` of a copy of ``jmap``.
    """
    rest = src.rest_positions()
    X = np.asarray(rest_joints)[:_N]
    hips = (rest[jmap.anchor["left_hip"]] + rest[jmap.anchor["right_hip"]]) / 2
    X = X + (hips - (X[1] + X[2]) / 2)
    chain = jmap.chain
    heights = rest[chain, 1]
    attach, rot = jmap.attach.copy(), jmap.rot_source.copy()
    for name, child in zip(_SPINE, ("spine2", "spine3", "neck", "head", None), strict=True):
        j = _IDX[name]
        attach[j] = _last_below(heights, chain, X[j, 1])
        if child is None:
            rot[j] = _through_zero_offsets(src, jmap.anchor["head"])
        else:
            rot[j] = _last_below(heights, chain, (X[j, 1] + X[_IDX[child], 1]) / 2)
    for side in ("left", "right"):  # collars the source lacks ride on the spine
        j = _IDX[f"{side}_collar"]
        if attach[j] < 0:
            attach[j] = rot[j] = _last_below(heights, chain, X[j, 1])
    offset = np.where(jmap.direct[:, None], 0.0, X - rest[attach])
    for side in ("left", "right"):
        j, e = _IDX[f"{side}_wrist"], _IDX[f"{side}_elbow"]
        if not jmap.direct[j]:  # further along the source forearm, to the body's forearm length
            d = rest[attach[j]] - rest[attach[e]]
            n = np.linalg.norm(d)
            offset[j] = d / n * (np.linalg.norm(X[j] - X[e]) - n)
    return JointMap(anchor=dict(jmap.anchor), attach=attach, rot_source=rot,
                    direct=jmap.direct.copy(), chain=list(chain), offset=offset)  # fmt: skip


def _min_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking direction a to direction b.  -> (3, 3)"""
    a = a / max(np.linalg.norm(a), 1e-12)
    b = b / max(np.linalg.norm(b), 1e-12)
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(a @ b)
    if s < 1e-9:  # parallel, or opposite: half a turn about any perpendicular axis
        if c > 0:
            return np.eye(3)
        perp = np.cross(a, np.eye(3)[int(np.argmin(np.abs(a)))])
        return rotvec_to_rotmat(torch.as_tensor(perp / np.linalg.norm(perp) * np.pi)).numpy()
    return rotvec_to_rotmat(torch.as_tensor(axis / s * np.arctan2(s, c))).numpy()


def rest_corrections(jmap: JointMap, src_rest: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Per SMPL joint, the rotation C_j with ``G_smpl = G_source @ C_j`` in the rest pose:
    it turns the body's rest bone direction onto the source's.  -> (22, 3, 3)"""
    Y = src_rest[jmap.attach] + jmap.offset
    parents = _PARENTS
    C = np.tile(np.eye(3), (_N, 1, 1))
    for j in range(_N):
        kids = [k for k in range(_N) if parents[k] == j]
        if len(kids) == 1:
            C[j] = _min_rotation(X[kids[0]] - X[j], Y[kids[0]] - Y[j])
    for j in range(_N):  # leaves continue their parent's correction
        if not any(parents[k] == j for k in range(_N)):
            C[j] = C[parents[j]]
    return C


# --- the solve ---------------------------------------------------------------------------------


def _fk(L: torch.Tensor, bones: torch.Tensor, root: torch.Tensor, parents: list[int]):
    """Body FK.  L: (T, 22, 3, 3) local rotations; bones: (22, 3) rest offsets from the parent;
    root: (T, 3) pelvis position -> global rotations (T, 22, 3, 3), positions (T, 22, 3)"""
    G = [L[:, 0]]
    p = [root]
    for j in range(1, _N):
        q = parents[j]
        G.append(G[q] @ L[:, j])
        p.append(p[q] + G[q] @ bones[j])
    return torch.stack(G, 1), torch.stack(p, 1)


def _ancestors(parents: list[int]) -> torch.Tensor:
    """(22, 22) bool: A[k, j] when j is k or one of its ancestors."""
    A = torch.zeros(_N, _N, dtype=torch.bool)
    for k in range(_N):
        j = k
        while j >= 0:
            A[k, j] = True
            j = parents[j]
    return A


def solve_pose(
    targets: torch.Tensor,
    L_init: torch.Tensor,
    X: torch.Tensor,
    parents: list[int],
    twist_weight: float = 0.02,
    iterations: int = 3,
    damping: float = 1e-6,
    chunk: int = 256,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Fit local rotations and the root to joint targets, all frames at once.

    Minimises ``sum_j |p_j - y_j|^2 + twist_weight^2 sum_j |log(L_init_j^T L_j)|^2`` (metres,
    radians) by damped Gauss-Newton. Parameters per frame: a world-frame rotation increment for
    each joint that has children (turning its subtree about it) and the root position; joints
    without children (feet, wrists, head) keep their start rotation, which positions cannot see.

    targets: (T, 22, 3); L_init: (T, 22, 3, 3); X: (22, 3) rest joints; -> L (T, 22, 3, 3),
    root position (T, 3)
    """
    if targets.shape[0] > chunk:  # frames are independent: small chunks stay in cache
        parts = [solve_pose(targets[i : i + chunk], L_init[i : i + chunk], X, parents,
                            twist_weight, iterations, damping, chunk)
                 for i in range(0, targets.shape[0], chunk)]  # fmt: skip
        return torch.cat([a for a, _ in parts]), torch.cat([b for _, b in parts])
    T = targets.shape[0]
    dt = targets.dtype
    bones = X.clone()
    bones[1:] = X[1:] - X[parents[1:]]
    active = [j for j in range(_N) if j in parents[1:]]
    n = len(active)
    lin = torch.float32  # the normal equations: float32 is plenty for a Gauss-Newton step
    A = _ancestors(parents)[:, active].to(lin)  # (22, n)
    L = L_init.clone()
    root = targets[:, 0].clone()
    w2 = twist_weight**2
    Jt = torch.eye(3, dtype=lin).repeat(_N, 1).expand(T, 3 * _N, 3)
    diag = torch.full((3 * n + 3,), damping, dtype=lin)
    diag[: 3 * n] += w2
    for _ in range(iterations):
        G, p = _fk(L, bones, root, parents)
        r = (p - targets).reshape(T, 3 * _N, 1).to(lin)
        pl = p.to(lin)
        diff = pl[:, :, None, :] - pl[:, None, active, :]  # (T, 22, n, 3): p_k - p_j
        Jr = -skew(diff) * A[None, :, :, None, None]  # (T, 22, n, 3, 3)
        Jr = Jr.permute(0, 1, 3, 2, 4).reshape(T, 3 * _N, 3 * n)
        Jac = torch.cat([Jr, Jt], dim=2)  # (T, 66, 3n + 3)
        JT = Jac.transpose(1, 2)
        H = torch.baddbmm(torch.diag(diag).expand(T, -1, -1), JT, Jac)
        g = (JT @ r)[..., 0]
        Ga = G[:, active]
        delta = rotmat_to_rotvec(L_init[:, active].transpose(-1, -2) @ L[:, active])
        g[:, : 3 * n] += w2 * (Ga @ delta[..., None])[..., 0].reshape(T, 3 * n).to(lin)
        chol, _ = torch.linalg.cholesky_ex(H)
        step = -torch.cholesky_solve(g[..., None], chol)[..., 0].to(dt)
        omega = step[:, : 3 * n].reshape(T, n, 3)
        local = (Ga.transpose(-1, -2) @ omega[..., None])[..., 0]
        L[:, active] = L[:, active] @ rotvec_to_rotmat(local)
        root = root + step[:, 3 * n :]
    return L, root


# --- driver ------------------------------------------------------------------------------------


@dataclass
class RetargetResult:
    """A retargeted clip and how well it fits.

    motion: the AMASS-style Motion (z-up, floor at z = 0).
    joints, targets: (T, 22, 3) the body's joints and the source points they fit (z-up, metres).
    joint_error: (22,) mean distance per SMPL joint, metres. betas: (S,) the fitted shape.
    floor_shift: metres the clip was lowered to put the soles on z = 0; floor_tilt_deg: how
    much the source's ground was tilted (and levelled).
    sole_height: (T,) lowest foot-vertex height per frame after the shift, metres.
    joint_map: SMPL joint -> source joint (``~`` = attached point).
    """

    motion: Motion
    joints: np.ndarray
    targets: np.ndarray
    joint_error: np.ndarray
    betas: np.ndarray
    floor_shift: float
    floor_tilt_deg: float
    sole_height: np.ndarray
    joint_map: dict[str, str]
    direct: np.ndarray

    @property
    def mean_error(self) -> float:
        """Mean joint position error over frames and the 22 joints, metres."""
        return float(self.joint_error.mean())

    @property
    def direct_error(self) -> float:
        """Mean error over the direct joints only (legs and arms), metres."""
        return float(self.joint_error[self.direct].mean())


@dataclass
class RetargetSettings:
    """twist_weight: metres of joint error that one radian of departure from the source's local
    rotation costs; iterations: Gauss-Newton steps; floor: "plane" puts the ground under the
    soles at z = 0 and levels it (tilts up to ``max_tilt`` where the clip travels far enough to
    measure one), "flat" only shifts heights, "none" keeps the source's heights."""

    twist_weight: float = 0.02
    iterations: int = 3
    floor: str = "plane"
    max_tilt: float = 0.035  # rise per metre (2 degrees)

    def validate(self) -> RetargetSettings:
        if self.floor not in ("plane", "flat", "none"):
            raise InputError(f"floor must be plane, flat or none, not {self.floor!r}")
        if not (self.twist_weight > 0 and self.iterations >= 0 and self.max_tilt >= 0):
            raise InputError("twist_weight must be > 0, iterations and max_tilt >= 0")
        return self


def _envelope(F: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least squares through the lower envelope of h (rounds of keeping the lowest 30 %)."""
    keep = np.ones(len(h), dtype=bool)
    for _ in range(6):
        coef = np.linalg.lstsq(F[keep], h[keep], rcond=None)[0]
        res = h - F @ coef
        keep = res <= np.percentile(res, 30)
    return coef, h - F @ coef


def fit_ground(contacts: np.ndarray, max_tilt: float, tilt: bool = True) -> np.ndarray:
    """The ground under a clip's lowest foot points, as the plane ``h = c + g . (x, z)``.

    contacts: (T, 3) each frame's lowest foot point, y up. The plane fits the lower envelope
    of these points (frames in flight or on a step lie above it). It may tilt only along
    directions the clip covers widely (std > 0.4 m), and the tilt is kept only when it is
    small (<= ``max_tilt`` rise per metre) and the lower half of the points lies within ~1 cm
    of it: a floor walked on, not stairs, jumps or rough ground. Returns (c, g_x, g_z).
    """
    xz, h = contacts[:, [0, 2]], contacts[:, 1]
    centre = np.median(xz, axis=0)
    d = xz - centre
    evals, evecs = np.linalg.eigh(d.T @ d / len(d))
    dirs = [evecs[:, k] for k in range(2) if tilt and evals[k] > 0.4**2]
    if dirs:
        F = np.column_stack([np.ones(len(h))] + [d @ u for u in dirs])
        coef, res = _envelope(F, h)
        lower = res[res <= np.median(res)]
        if np.abs(coef[1:]).max() <= max_tilt and lower.std() <= 0.01:
            g = sum((s * u for s, u in zip(coef[1:], dirs, strict=True)), np.zeros(2))
            return np.array([coef[0] - g @ centre, g[0], g[1]])
    coef, _ = _envelope(np.ones((len(h), 1)), h)
    return np.array([coef[0], 0.0, 0.0])


def retarget(
    src: SourceMotion,
    body: BodyJoints,
    betas: np.ndarray | None = None,
    settings: RetargetSettings | None = None,
    metadata: dict | None = None,
) -> RetargetResult:
    """Retarget ``src`` (any axes, any frame rate: resample it first) onto ``body``.

    betas: the body shape to use (e.g. fitted once per subject with :func:`fit_betas`); None
    fits it here. metadata: extra entries for the output's ``source`` record.
    """
    settings = (settings or RetargetSettings()).validate()
    if src.num_frames < 2:
        raise InputError(f"a motion needs at least 2 frames, this one has {src.num_frames}")
    jmap = build_joint_map(src)
    src = canonicalise(src, canonical_rotation(src, jmap))
    if betas is None:
        betas = fit_betas(src, body, jmap)
    b = torch.as_tensor(np.asarray(betas, dtype=np.float64))
    X_all = body.rest_joints(b)
    X = X_all[:_N]
    jmap = attach_offsets(src, jmap, X_all.numpy())
    C = torch.as_tensor(rest_corrections(jmap, src.rest_positions(), X.numpy()))

    G_src, P_src = (torch.as_tensor(a) for a in src.forward_kinematics())
    attach, offset = torch.as_tensor(jmap.attach), torch.as_tensor(jmap.offset)
    targets = P_src[:, attach] + (G_src[:, attach] @ offset[..., None])[..., 0]
    G0 = G_src[:, torch.as_tensor(jmap.rot_source)] @ C
    parents = body.parents
    L0 = G0.clone()
    L0[:, 1:] = G0[:, parents[1:]].transpose(-1, -2) @ G0[:, 1:]
    del G_src, P_src, G0
    L, root = solve_pose(targets, L0, X, parents, settings.twist_weight, settings.iterations)
    bones = X.clone()
    bones[1:] = X[1:] - X[parents[1:]]
    G, p = _fk(L, bones, root, parents)
    err = (p - targets).norm(dim=-1)

    # the soles: foot vertices skinned by the ankle and foot joints (y up)
    fj = [7, 8, 10, 11]
    w = body.foot_weights.T[..., None]  # (4, F, 1)
    local = w * (body.foot_vertices(b)[None] - X_all[fj][:, None])  # (4, F, 3), weighted
    T = src.num_frames
    Gf = G[:, fj].permute(0, 2, 1, 3).reshape(T, 3, 12)  # [a, (k, b)]
    feet = (Gf @ local.permute(0, 2, 1).reshape(12, -1)).reshape(T, 3, -1).transpose(1, 2)
    feet = feet + torch.einsum("tka,fk->tfa", p[:, fj], body.foot_weights)
    lowest = feet[..., 1].argmin(-1)
    contacts = feet[torch.arange(len(feet)), lowest].numpy()
    plane = np.zeros(3)
    if settings.floor != "none":
        plane = fit_ground(contacts, settings.max_tilt, tilt=settings.floor == "plane")
    normal = np.array([-plane[1], 1.0, -plane[2]])
    level = torch.as_tensor(_min_rotation(normal, np.array([0.0, 1.0, 0.0])))
    floor = float((level @ torch.tensor([0.0, plane[0], 0.0], dtype=torch.float64))[1])
    soles = (feet @ level[1]).amin(-1) - floor  # (T,)
    tilt_deg = float(np.degrees(np.arctan(np.hypot(plane[1], plane[2]))))

    Q = torch.as_tensor(Y_UP_TO_Z_UP) @ level
    drop = torch.tensor([0.0, 0.0, floor], dtype=torch.float64)
    trans = root @ Q.T - drop - X[0]
    root_orient = rotmat_to_rotvec(Q @ G[:, 0])
    pose_body = rotmat_to_rotvec(L[:, 1:])
    joints = p @ Q.T - drop
    targets_z = targets @ Q.T - drop

    direct = torch.as_tensor(jmap.direct)
    record = {
        "format": src.info.get("format"),
        "source_fps": src.info.get("fps_in_file"),
        "unit": src.info.get("unit"),
        "metres_per_unit": src.info.get("metres_per_unit"),
        "retarget_error_m": round(float(err.mean()), 6),
        "retarget_error_direct_m": round(float(err[:, direct].mean()), 6),
        "floor_shift_m": round(floor, 6),
        "floor_tilt_deg": round(tilt_deg, 3),
        "joint_map": jmap.describe(src.names),
        "notes": list(src.notes),
        **(metadata or {}),
    }
    motion = Motion(
        root_orient=root_orient.numpy(),
        pose_body=pose_body.numpy(),
        trans=trans.numpy(),
        betas=np.asarray(betas, dtype=np.float64),
        fps=float(src.fps),
        pose_extra=np.zeros((T, 90)),
        gender="neutral",
        extras={"source": np.array(json.dumps(record, sort_keys=True))},
        layout={
            "fps_key": "mocap_framerate",
            "gender_bytes": False,
            "has_gender": True,
            "poses_dtype": "float32",
        },  # fmt: skip
        notes=list(src.notes),
    )
    return RetargetResult(
        motion=motion,
        joints=joints.numpy(),
        targets=targets_z.numpy(),
        joint_error=err.mean(0).numpy(),
        betas=np.asarray(betas, dtype=np.float64),
        floor_shift=floor,
        floor_tilt_deg=tilt_deg,
        sole_height=soles.numpy(),
        joint_map=jmap.describe(src.names),
        direct=jmap.direct.copy(),
    )


def walking_speed(trans: np.ndarray, fps: float, window_s: float = 1.0) -> float:
    """Mean horizontal speed of a z-up root path, m/s, after a moving average over
    ``window_s`` (removes the sway of each step).  trans: (T, 3)"""
    xy = np.asarray(trans)[:, :2]
    k = max(1, min(len(xy), int(round(window_s * fps))))
    if len(xy) - k < 1:
        return 0.0
    c = np.cumsum(np.vstack([np.zeros((1, 2)), xy]), axis=0)
    smooth = (c[k:] - c[:-k]) / k
    path = np.linalg.norm(np.diff(smooth, axis=0), axis=1).sum()
    return float(path / ((len(smooth) - 1) / fps)) if len(smooth) > 1 else 0.0


# --- files -------------------------------------------------------------------------------------


def load_source(
    path: Path | str,
    skeleton: Path | str | AsfSkeleton | None = None,
    fps: float | None = None,
    scale: float | None = None,
    max_frames: int | None = None,
) -> SourceMotion:
    """Read a ``.bvh`` or ``.amc`` file (``.gz`` too) into a :class:`SourceMotion`.

    skeleton: the ``.asf`` an AMC motion needs. fps: the true frame rate when the file's is
    wrong (AMC files have none: 120 is assumed). scale: metres per file unit.
    """
    name = Path(path).name.lower().removesuffix(".gz")
    if name.endswith(".bvh"):
        src = load_bvh(path, scale=scale, max_frames=max_frames)
    elif name.endswith(".amc"):
        if skeleton is None:
            raise InputError(f"{path}: an AMC motion needs its ASF skeleton (pass --asf)")
        src = load_amc(path, skeleton, scale=scale, max_frames=max_frames)
    else:
        raise InputError(f"{path}: not a .bvh or .amc file")
    if fps is not None and abs(fps - src.fps) > 1e-9:
        src = src.with_fps(fps)
        src.notes.append(f"frame rate {src.info.get('fps_in_file'):g} in the file, {fps:g} used")
    return src


def skeleton_key(src: SourceMotion) -> str:
    """Identifies a skeleton (names and rest offsets to 0.1 mm), to fit betas once per skeleton."""
    digest = hashlib.sha256("|".join(src.names).encode())
    digest.update(np.round(src.offsets * 1e4).astype(np.int64).tobytes())
    return digest.hexdigest()[:16]


def import_motion(
    src: SourceMotion,
    body: BodyJoints,
    fps: float | None = 30.0,
    betas: np.ndarray | None = None,
    settings: RetargetSettings | None = None,
    metadata: dict | None = None,
) -> RetargetResult:
    """Resample ``src`` to ``fps`` (None keeps its rate), then :func:`retarget` it."""
    if fps is not None:
        if not fps > 0:
            raise InputError(f"the output frame rate must be > 0, got {fps:g}")
        src = resample_source(src, fps)
    return retarget(src, body, betas=betas, settings=settings, metadata=metadata)
