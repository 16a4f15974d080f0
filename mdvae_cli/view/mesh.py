"""A small skinned mesh to draw in the viewer: the body model's mesh, decimated by vertex
clustering to a few hundred vertices, each bound to at most three of the 22 body joints.

Clustering works per body part (the joint each vertex follows most), so that fingers, thighs
and arms are never merged with each other: every cluster becomes one vertex at its members'
mean, with their mean skinning weights; faces whose corners fall into fewer than three
clusters disappear. The viewer skins it with the per-frame joint rotations (linear blend
skinning without pose correctives: a picture, not a measurement).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mdvae_cli.body.data import NUM_BODY_JOINTS, BodyModelData

#: joints each drawn vertex follows
MAX_INFLUENCES = 3
#: vertices the decimated mesh aims for
TARGET_VERTICES = 450


@dataclass(frozen=True)
class SkinMesh:
    """A decimated body mesh.

    members: (V,) int64: the cluster (new vertex) each original vertex belongs to.
    faces: (F, 3) int64 triangles over the new vertices, the original winding kept.
    joint_ids: (N, MAX_INFLUENCES) int64 body joints (0..21) each new vertex follows.
    joint_weights: (N, MAX_INFLUENCES) float64 their weights, rows summing to 1.
    """

    members: np.ndarray
    faces: np.ndarray
    joint_ids: np.ndarray
    joint_weights: np.ndarray

    @property
    def num_vertices(self) -> int:
        return int(self.joint_ids.shape[0])

    def rest_vertices(self, data: BodyModelData, betas: np.ndarray) -> np.ndarray:
        """The decimated rest mesh for a body shape.  betas: (S',) -> (N, 3) metres"""
        S = data.shapedirs.shape[2]
        b = np.zeros(S)
        n = min(S, len(betas))
        b[:n] = np.asarray(betas, dtype=np.float64)[:n]
        verts = data.v_template + np.einsum("vck,k->vc", data.shapedirs, b)
        return cluster_means(verts, self.members, self.num_vertices)


def body_weights(data: BodyModelData) -> np.ndarray:
    """Skinning weights on the 22 body joints: a hand, jaw or eye joint's weight goes to its
    nearest ancestor among them.  -> (V, 22)"""
    W = np.asarray(data.weights, dtype=np.float64)
    out = W[:, :NUM_BODY_JOINTS].copy()
    for j in range(NUM_BODY_JOINTS, W.shape[1]):
        a = int(data.parents[j])
        while a >= NUM_BODY_JOINTS:
            a = int(data.parents[a])
        out[:, a] += W[:, j]
    return out


def cluster_means(points: np.ndarray, members: np.ndarray, n: int) -> np.ndarray:
    """Mean of the points in each cluster.  points: (V, C), members: (V,) -> (n, C)"""
    sums = np.zeros((n, points.shape[1]))
    np.add.at(sums, members, points)
    counts = np.bincount(members, minlength=n)[:, None]
    return sums / np.maximum(counts, 1)


def cluster_vertices(points: np.ndarray, part: np.ndarray, cell: float) -> np.ndarray:
    """Group points by (part, grid cell of size ``cell``).  -> (V,) cluster ids 0..n-1"""
    keys = np.concatenate([part[:, None], np.floor(points / cell).astype(np.int64)], axis=1)
    _, members = np.unique(keys, axis=0, return_inverse=True)
    return members.reshape(-1)


def decimate_body(data: BodyModelData, target: int = TARGET_VERTICES) -> SkinMesh:
    """Decimate ``data``'s mesh to about ``target`` vertices (bisection on the cell size).
    A mesh with fewer vertices than ``target`` is kept whole."""
    verts = np.asarray(data.v_template, dtype=np.float64)
    W = body_weights(data)
    part = W.argmax(axis=1)
    if len(verts) <= target:
        members = np.arange(len(verts))
    else:
        low, high = 1e-4, float(np.ptp(verts, axis=0).max())
        members = cluster_vertices(verts, part, high)
        for _ in range(30):  # the coarsest cell with at least `target` clusters
            mid = 0.5 * (low + high)
            found = cluster_vertices(verts, part, mid)
            if found.max() + 1 >= target:
                low, members = mid, found
            else:
                high = mid
            if (members.max() + 1) <= 1.05 * target and members.max() + 1 >= target:
                break
    n = int(members.max()) + 1
    faces = members[np.asarray(data.faces, dtype=np.int64)]
    distinct = (
        (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    )
    faces = faces[distinct]
    _, first = np.unique(np.sort(faces, axis=1), axis=0, return_index=True)
    faces = faces[np.sort(first)]
    weights = cluster_means(W, members, n)
    ids = np.argsort(-weights, axis=1)[:, :MAX_INFLUENCES]
    top = np.take_along_axis(weights, ids, axis=1)
    top = top / np.maximum(top.sum(axis=1, keepdims=True), 1e-12)
    return SkinMesh(members=members, faces=faces, joint_ids=ids, joint_weights=top)
