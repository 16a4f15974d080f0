"""The built-in body model: a procedurally generated human in SMPL's layout.

Real SMPL files are licensed, so the tool ships this body instead. It is built by code on every
call (no data files, no randomness) in SMPL's canonical frame: **y up, the body faces +z, its
left side is +x**, rest pose a T-pose (arms along +-x, palms down), about 1.70 m tall with the
pelvis joint near (0, -0.22, 0) and the soles near y = -1.16.

How it is made. A handful of body *lengths* (thigh, shin, spine segments, upper arm, ...) place
the 24 SMPL joints and a few extra landmarks (heel, toe tip, finger tip, head top, ...). Each body
part is a closed tube: a chain of elliptical (super-elliptical) cross-sections whose centres sit
at or between landmarks, smoothed along the tube and closed by rounded caps. The 13 parts are
torso, neck+head, nose, and per side leg, foot, arm, hand and thumb; the mesh (7,274 vertices,
14,496 faces) is their union, each part watertight with outward winding. Everything is a
*linear* function of the lengths and radii, so each shape direction is exact:
``v_template + shapedirs @ betas`` is precisely the body built with the changed lengths, and
joints regressed from it are the designed joints.

* ``J_regressor``: each joint is the mean of one cross-section ring centred on it.
* ``weights``: along each tube, a vertex belongs to the bone it lies on, blended with a
  smoothstep across each joint (at most three joints per vertex).
* ``shapedirs``: :data:`SHAPE_NAMES` directions, one unit about one population standard
  deviation of a single measurement; betas in [-3, 3] give plausible bodies.
* ``posedirs``: zeros; this body has no pose-corrective blend shapes.
* ``marker_vertex_ids``: :func:`mdvae_cli.body.markers.place_markers` on the template.

The design tables (landmarks, body lengths, tubes, shape directions) live in
:mod:`mdvae_cli.body.builtin_shapes`; this module builds the mesh from them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mdvae_cli.body.builtin_shapes import (
    _LR_JOINTS,
    _TUBES,
    SHAPE_NAMES,
    _base_params,
    _landmarks,
    _shape_deltas,
    _Tube,
)
from mdvae_cli.body.data import SMPL_JOINT_NAMES, SMPL_PARENTS, BodyModelData
from mdvae_cli.body.markers import place_markers

__all__ = ["SHAPE_NAMES", "builtin_body_model"]


#: Sub-stations inserted between two stations (Catmull-Rom), for a smoother surface.
_REFINE = 3
#: Cap rings at these elevation angles, then a pole.
_CAP_ANGLES = np.deg2rad([22.5, 45.0, 67.5])


def _catmull_rom(n: int, k: int) -> np.ndarray:
    """Weights that insert k - 1 points between each pair of n stations.  -> (k (n-1) + 1, n)"""
    W = np.zeros((k * (n - 1) + 1, n))
    for i in range(n - 1):
        for j in range(k):
            u = j / k
            w = 0.5 * np.array([-u + 2 * u**2 - u**3, 2 - 5 * u**2 + 3 * u**3,
                                u + 4 * u**2 - 3 * u**3, -(u**2) + u**3])  # fmt: skip
            for m, wm in zip((i - 1, i, i + 1, i + 2), w, strict=True):
                W[i * k + j, min(max(m, 0), n - 1)] += wm
    W[-1, -1] = 1.0
    return W


@dataclass(frozen=True)
class _Layout:
    """Constant per-tube data: station smoothing, ring directions, vertex offsets."""

    smooth: tuple[np.ndarray, ...]  # (n_fine, n) per tube
    ring_dirs: tuple[np.ndarray, ...]  # (N, 2) super-ellipse (cos, sin) per tube
    counts: tuple[int, ...]  # vertices per tube (one side)


def _layout() -> _Layout:
    smooth, dirs, counts = [], [], []
    for tube in _TUBES:
        S = _catmull_rom(len(tube.anchors), _REFINE)
        theta = 2.0 * np.pi * np.arange(tube.ring) / tube.ring
        cs = np.stack([np.cos(theta), np.sin(theta)], axis=1)
        cs = np.sign(cs) * np.abs(cs) ** (2.0 / tube.exponent)
        rings = len(S) + 2 * len(_CAP_ANGLES)
        smooth.append(S)
        dirs.append(cs)
        counts.append(rings * tube.ring + 2)
    return _Layout(tuple(smooth), tuple(dirs), tuple(counts))


def _tube_vertices(tube: _Tube, S: np.ndarray, cs: np.ndarray, L: np.ndarray, shape: np.ndarray):
    """Vertices of one tube: rings along the tube, then the two poles.  -> (count, 3)"""
    e1, e2 = np.asarray(tube.frame[0]), np.asarray(tube.frame[1])
    axis = np.cross(e1, e2)
    a = np.array([s[0] for s in tube.anchors])
    b = np.array([s[1] for s in tube.anchors])
    t = np.array([s[2] for s in tube.anchors])[:, None]
    centres = (1.0 - t) * L[a] + t * L[b] + shape[:, 2:5]
    fine = S @ np.concatenate([centres, shape[:, :2]], axis=1)
    C, R = fine[:, :3], fine[:, 3:5]
    sections = R[:, None, 0:1] * cs[None, :, 0:1] * e1 + R[:, None, 1:2] * cs[None, :, 1:2] * e2

    def cap(end: int, sign: float, angles: np.ndarray):
        length = tube.caps[0 if sign < 0 else 1] * R[end].mean()
        rings = [C[end] + sign * length * np.sin(f) * axis + np.cos(f) * sections[end]
                 for f in angles]  # fmt: skip
        return rings, C[end] + sign * length * axis

    start, pole0 = cap(0, -1.0, _CAP_ANGLES[::-1])
    end, pole1 = cap(-1, 1.0, _CAP_ANGLES)
    rings = np.concatenate([np.stack(start), C[:, None] + sections, np.stack(end)])
    return np.concatenate([rings.reshape(-1, 3), pole0[None], pole1[None]])


def _tube_faces(n_rings: int, N: int) -> np.ndarray:
    """Outward-wound triangles of a capped tube with n_rings rings of N vertices."""
    r = np.arange(n_rings - 1)[:, None]
    k = np.arange(N)[None, :]
    a, b = r * N + k, r * N + (k + 1) % N
    c, d = b + N, a + N
    sides = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)]).reshape(-1, 3)
    pole0, pole1 = n_rings * N, n_rings * N + 1
    ring0 = np.arange(N)
    last = (n_rings - 1) * N + ring0
    start = np.stack([np.full(N, pole0), np.roll(ring0, -1), ring0], axis=1)
    end = np.stack([np.full(N, pole1), last, np.roll(last, -1)], axis=1)
    return np.concatenate([sides, start, end]).astype(np.int64)


def _vertices(p: dict[str, np.ndarray], layout: _Layout) -> tuple[np.ndarray, np.ndarray]:
    """All vertices (centre tubes, left tubes, right mirrors) and landmarks from parameters."""
    L = _landmarks(p)
    centre, left = [], []
    for tube, S, cs in zip(_TUBES, layout.smooth, layout.ring_dirs, strict=True):
        v = _tube_vertices(tube, S, cs, L, p[tube.name + "_shape"])
        (centre if tube.side == "centre" else left).append(v)
    left_v = np.concatenate(left)
    return np.concatenate(centre + [left_v, left_v * (-1.0, 1.0, 1.0)]), L


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _chain_weights(s: np.ndarray, tube: _Tube, L: np.ndarray) -> np.ndarray:
    """Bone weights along a tube from the axial coordinate s of its vertices.  -> (n, 24)"""
    axis = np.cross(tube.frame[0], tube.frame[1])
    W = np.zeros((len(s), 24))
    steps = [np.ones_like(s)]
    for _, landmark, width in tube.chain[1:]:
        s_joint = L[landmark] @ axis
        steps.append(_smoothstep((s - s_joint + width) / (2.0 * width)))
    steps.append(np.zeros_like(s))
    for i, (joint, _, _) in enumerate(tube.chain):
        W[:, joint] += np.clip(steps[i] - steps[i + 1], 0.0, None)
    return W


def _torso_collar_blend(v: np.ndarray, W: np.ndarray, L: np.ndarray) -> None:
    """Hand the shoulder-top part of the upper chest from spine3 to the collars, in place."""
    across = _smoothstep((np.abs(v[:, 0]) - 0.06) / 0.08)
    up = _smoothstep((v[:, 1] - L[9, 1] - 0.04) / (L[13, 1] - L[9, 1] - 0.02))
    moved = W[:, 9] * across * up
    W[:, 9] -= moved
    W[:, 13] += np.where(v[:, 0] > 0, moved, 0.0)
    W[:, 14] += np.where(v[:, 0] < 0, moved, 0.0)


def _mirror_joint_columns() -> np.ndarray:
    perm = np.arange(24)
    for left, right in _LR_JOINTS:
        perm[left], perm[right] = right, left
    return perm


def _topology(v: np.ndarray, L: np.ndarray, layout: _Layout):
    """Faces, skinning weights and joint regressor of the template (constant per layout)."""
    faces, weights, rings = [], [], {}
    offset = 0
    left_start = sum(
        c for tube, c in zip(_TUBES, layout.counts, strict=True) if tube.side == "centre"
    )
    n_left = sum(c for tube, c in zip(_TUBES, layout.counts, strict=True) if tube.side == "left")
    for tube, count in zip(_TUBES, layout.counts, strict=True):
        n_rings = (count - 2) // tube.ring
        faces.append(_tube_faces(n_rings, tube.ring) + offset)
        part = v[offset : offset + count]
        axis = np.cross(tube.frame[0], tube.frame[1])
        W = _chain_weights(part @ axis, tube, L)
        if tube.name == "torso":
            _torso_collar_blend(part, W, L)
        weights.append(W)
        for joint, station in tube.rings:
            first = offset + (len(_CAP_ANGLES) + station * _REFINE) * tube.ring
            rings[joint] = np.arange(first, first + tube.ring)
        offset += count
    faces = np.concatenate(faces)
    weights = np.concatenate(weights)
    # right side: mirrored copies of the left tubes, with flipped winding and swapped joints
    left_faces = faces[(faces >= left_start).all(axis=1)]
    faces = np.concatenate([faces, left_faces[:, [0, 2, 1]] + n_left])
    weights = np.concatenate([weights, weights[left_start:][:, _mirror_joint_columns()]])
    for left, right in _LR_JOINTS:
        rings[right] = rings[left] + n_left
    V = len(weights)
    J_regressor = np.zeros((24, V))
    for joint, ids in rings.items():
        J_regressor[joint, ids] = 1.0 / len(ids)
    weights /= weights.sum(axis=1, keepdims=True)
    return faces, weights, J_regressor


def builtin_body_model() -> BodyModelData:
    """The procedurally generated SMPL-layout body (kind ``"builtin"``).

    Returns a validated :class:`BodyModelData` with 7,274 vertices, 24 SMPL joints,
    ``len(SHAPE_NAMES)`` (16) shape directions, zero pose correctives (``posedirs`` is all zeros:
    no pose-dependent blend shapes) and 43 marker vertices (:data:`markers.MARKER_NAMES`).
    Deterministic (two calls give identical arrays); takes well under 0.1 s.
    """
    layout = _layout()
    p0 = _base_params()
    v_template, L = _vertices(p0, layout)
    faces, weights, J_regressor = _topology(v_template, L, layout)
    dirs = []
    for delta in _shape_deltas(p0):
        p = {k: v + delta.get(k, 0.0) for k, v in p0.items()}
        dirs.append(_vertices(p, layout)[0] - v_template)
    shapedirs = np.stack(dirs, axis=-1)
    J = J_regressor @ v_template
    return BodyModelData(
        kind="builtin",
        v_template=v_template,
        shapedirs=shapedirs,
        posedirs=np.zeros((len(v_template), 3, 9 * 23)),
        J_regressor=J_regressor,
        weights=weights,
        parents=np.asarray(SMPL_PARENTS, dtype=np.int64),
        faces=faces,
        joint_names=SMPL_JOINT_NAMES,
        marker_vertex_ids=place_markers(v_template, J),
        name="builtin",
    ).validate()
