"""SMPL-family linear blend skinning in torch: small pure functions plus one nn.Module.

Math names inside functions follow the SMPL paper: ``J`` joints, ``A`` relative joint
transforms, ``W`` skinning weights. Every function is batched over a leading dim B (frames).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from mdvae_cli.body.data import NUM_BODY_JOINTS, BodyModelData
from mdvae_cli.geometry.rotations import rotvec_to_rotmat


def blend_shapes(coeffs: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """Linear blend offsets.  coeffs: (B, K), dirs: (V, 3, K) -> (B, V, 3)"""
    V, C, K = dirs.shape
    return (coeffs @ dirs.reshape(V * C, K).T).reshape(-1, V, C)


def vertices_to_joints(J_regressor: torch.Tensor, vertices: torch.Tensor) -> torch.Tensor:
    """Regress joints.  J_regressor: (J, V), vertices: (B, V, 3) -> (B, J, 3)"""
    return torch.einsum("jv,bvc->bjc", J_regressor, vertices)


def pose_features(rotmats: torch.Tensor) -> torch.Tensor:
    """SMPL pose-corrective input.  rotmats: (B, J, 3, 3) -> (B, 9 * (J - 1))"""
    eye = torch.eye(3, dtype=rotmats.dtype, device=rotmats.device)
    return (rotmats[:, 1:] - eye).flatten(1)


def batch_rigid_transform(
    rotmats: torch.Tensor, J: torch.Tensor, parents: list[int]
) -> tuple[torch.Tensor, torch.Tensor]:
    """Forward kinematics.

    rotmats: (B, J, 3, 3) local rotations; J: (B, J, 3) rest joint positions; parents: J ints.
    Returns posed joints (B, J, 3) and relative transforms A (B, J, 3, 4) that map rest-pose
    points to posed points for each joint (``[R | t]``: x -> R x + t; the homogeneous row
    [0 0 0 1] is left out).
    """
    B, n = J.shape[:2]
    world_R = [rotmats[:, 0]]
    world_t = [J[:, 0]]
    for j in range(1, n):  # plain indices: a list index is a host copy (no CUDA graph holds it)
        p = parents[j]
        bone = J[:, j] - J[:, p]
        world_R.append(world_R[p] @ rotmats[:, j])
        world_t.append(world_t[p] + (world_R[p] @ bone[..., None])[..., 0])
    R = torch.stack(world_R, dim=1)
    t = torch.stack(world_t, dim=1)
    # A maps a rest point x to R (x - J_rest) + t
    t_rel = t - (R @ J[..., None])[..., 0]
    return t, torch.cat([R, t_rel[..., None]], dim=-1)


def skin_vertices(vertices: torch.Tensor, W: torch.Tensor, A: torch.Tensor) -> torch.Tensor:
    """Linear blend skinning.  vertices: (B, V, 3), W: (V, J), A: (B, J, 3, 4) -> (B, V, 3)

    Each vertex's blended transform ``sum_j W[v, j] A_j``, for every frame at once as one (V, J)
    by (J, 12 B) product, then applied column by column (a batched 3x3 product per vertex and
    its backward cost a training step's body term a fifth more)."""
    B, J = A.shape[:2]
    V = W.shape[0]
    T = (W @ A.reshape(B, J, 12).transpose(0, 1).reshape(J, B * 12)).reshape(V, B, 3, 4)
    t0, t1, t2, t3 = T.unbind(-1)  # (V, B, 3) each: the columns of [R | t]
    x, y, z = vertices.transpose(0, 1)[..., None].unbind(-2)  # (V, B, 1) each
    return (t3 + t0 * x + t1 * y + t2 * z).transpose(0, 1)


@dataclass
class BodyOutput:
    """Result of a body-model forward pass, in world coordinates (metres).

    joints: (B, 22, 3) body joints; markers: (B, M, 3) virtual markers;
    vertices: (B, V, 3) full mesh, or None when not requested.
    """

    joints: torch.Tensor
    markers: torch.Tensor
    vertices: torch.Tensor | None = None


class BodyModel(nn.Module):
    """Differentiable SMPL-family body: parameters -> joints, markers, vertices.

    Built from a :class:`BodyModelData`; joints past the 22 body joints (hands, jaw, eyes) take
    the pose given in ``pose_extra`` or stay at rest.
    """

    def __init__(self, data: BodyModelData, dtype: torch.dtype = torch.float32):
        super().__init__()
        self.data = data
        self.parents = [int(p) for p in data.parents]
        f = lambda a: torch.as_tensor(np.asarray(a), dtype=dtype)  # noqa: E731
        ids = torch.as_tensor(np.asarray(data.marker_vertex_ids), dtype=torch.long)
        self.register_buffer("v_template", f(data.v_template))
        self.register_buffer("shapedirs", f(data.shapedirs))
        self.register_buffer("posedirs", f(data.posedirs))
        self.register_buffer("weights", f(data.weights))
        self.register_buffer("J_regressor", f(data.J_regressor))
        self.register_buffer("marker_ids", ids)
        # joints at rest depend only on betas: pre-regress template and shape directions
        self.register_buffer("J_template", self.J_regressor @ self.v_template)
        self.register_buffer(
            "J_shapedirs", torch.einsum("jv,vck->jck", self.J_regressor, self.shapedirs)
        )

    @property
    def num_betas(self) -> int:
        return int(self.shapedirs.shape[2])

    @property
    def num_joints(self) -> int:
        return int(self.J_regressor.shape[0])

    def fit_betas(self, betas: torch.Tensor) -> torch.Tensor:
        """Pad with zeros or truncate to this model's shape count.  (B, S') -> (B, S)"""
        S = self.num_betas
        if betas.shape[-1] >= S:
            return betas[..., :S]
        pad = torch.zeros(*betas.shape[:-1], S - betas.shape[-1], dtype=betas.dtype,
                          device=betas.device)  # fmt: skip
        return torch.cat([betas, pad], dim=-1)

    def forward(
        self,
        root_orient: torch.Tensor,
        pose_body: torch.Tensor,
        trans: torch.Tensor | None = None,
        betas: torch.Tensor | None = None,
        pose_extra: torch.Tensor | None = None,
        vertices: bool = False,
        vertex_ids: torch.Tensor | None = None,
    ) -> BodyOutput:
        """Pose the body.

        root_orient: (B, 3) axis-angle; pose_body: (B, 21, 3) axis-angle; trans: (B, 3) or None;
        betas: (B, S'), (1, S') or (S',) or None (any length S', padded/truncated);
        pose_extra: (B, J - 22, 3) axis-angle for the remaining joints, or None for rest;
        vertices: also return the full mesh (costly), else only joints and markers;
        vertex_ids: (K,) return only these vertices (plus markers) in ``vertices``.
        Each may be a tensor or a numpy array (read on the model's device).
        """
        dtype, device = self.v_template.dtype, self.v_template.device
        root_orient, pose_body, trans, betas, pose_extra, vertex_ids = (
            x if x is None or isinstance(x, torch.Tensor) else torch.as_tensor(x, device=device)
            for x in (root_orient, pose_body, trans, betas, pose_extra, vertex_ids)
        )
        B = root_orient.shape[0]
        if betas is None:
            betas = torch.zeros(B, self.num_betas, dtype=dtype, device=device)
        betas = self.fit_betas(betas.to(dtype))
        if betas.ndim == 1 or betas.shape[0] == 1:
            betas = betas.reshape(1, -1).expand(B, -1)
        rotvecs = [root_orient.reshape(B, 1, 3), pose_body.reshape(B, NUM_BODY_JOINTS - 1, 3)]
        n_extra = self.num_joints - NUM_BODY_JOINTS
        if n_extra:
            if pose_extra is None:
                pose_extra = torch.zeros(B, n_extra, 3, dtype=dtype, device=device)
            rotvecs.append(pose_extra.reshape(B, n_extra, 3))
        R = rotvec_to_rotmat(torch.cat(rotvecs, dim=1).to(dtype))
        J_rest = self.J_template + torch.einsum("bk,jck->bjc", betas, self.J_shapedirs)
        J_posed, A = batch_rigid_transform(R, J_rest, self.parents)
        feats = pose_features(R)

        n_markers = self.marker_ids.shape[0]
        if vertices:
            ids = slice(None)
        elif vertex_ids is not None:
            ids = torch.cat([self.marker_ids, vertex_ids.to(self.marker_ids.device)])
        else:
            ids = self.marker_ids
        v = self.v_template[ids] + blend_shapes(betas, self.shapedirs[ids])
        v = v + blend_shapes(feats, self.posedirs[ids])
        v = skin_vertices(v, self.weights[ids], A)
        joints = J_posed[:, :NUM_BODY_JOINTS]
        if trans is not None:
            offset = trans.to(dtype).reshape(B, 1, 3)
            joints, v = joints + offset, v + offset
        if vertices:
            return BodyOutput(joints=joints, markers=v[:, self.marker_ids], vertices=v)
        if vertex_ids is not None:
            return BodyOutput(joints=joints, markers=v[:, :n_markers], vertices=v[:, n_markers:])
        return BodyOutput(joints=joints, markers=v)

    def pelvis_rest(self, betas: torch.Tensor) -> torch.Tensor:
        """Rest-pose pelvis joint for each shape.  betas: (B, S') -> (B, 3)"""
        betas = self.fit_betas(betas.to(self.J_template.dtype))
        return self.J_template[0] + betas @ self.J_shapedirs[0].T
