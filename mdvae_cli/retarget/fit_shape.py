"""The body side of retargeting: a body model's rest joints as a function of betas, and the
betas that match a source skeleton's bone lengths.

:class:`BodyJoints` is built once per body model; :func:`fit_betas` fits the body's shape once
per source skeleton (:func:`skeleton_key` tells skeletons apart) so that its rest bone lengths
(legs, arms, hip and shoulder widths, torso and neck) match the source's.
"""

from __future__ import annotations

import hashlib

import numpy as np
import torch

from mdvae_cli.body.data import NUM_BODY_JOINTS, SMPL_JOINT_NAMES, BodyModelData
from mdvae_cli.formats.source import SourceMotion
from mdvae_cli.retarget.joint_map import JointMap, build_joint_map

_N = NUM_BODY_JOINTS
_IDX = {name: i for i, name in enumerate(SMPL_JOINT_NAMES)}


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


def skeleton_key(src: SourceMotion) -> str:
    """Identifies a skeleton (names and rest offsets to 0.1 mm), to fit betas once per skeleton.
    Names keep a file's bytes that are not UTF-8 as the readers kept them ("surrogateescape")."""
    digest = hashlib.sha256("|".join(src.names).encode("utf-8", errors="surrogateescape"))
    digest.update(np.round(src.offsets * 1e4).astype(np.int64).tobytes())
    return digest.hexdigest()[:16]
