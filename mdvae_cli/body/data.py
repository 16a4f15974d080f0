"""The one in-memory form of every body model (SMPL, SMPL-H, SMPL-X, built-in)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mdvae_cli.errors import InputError

#: SMPL's 24 joint names, in SMPL order. The first 22 are the body joints the tool works with.
SMPL_JOINT_NAMES: tuple[str, ...] = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2",
    "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot", "neck",
    "left_collar", "right_collar", "head", "left_shoulder", "right_shoulder",
    "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hand", "right_hand",
)  # fmt: skip

#: SMPL's kinematic tree: parent of each of the 24 joints (-1 for the root).
SMPL_PARENTS: tuple[int, ...] = (
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21,
)  # fmt: skip

#: Number of body joints used throughout the tool (pelvis + 21 articulated body joints).
NUM_BODY_JOINTS = 22

#: The standard 43 virtual-marker vertices on SMPL-topology meshes (6890 vertices).
SMPL_MARKER_VERTEX_IDS: tuple[int, ...] = (
    4404, 920, 3076, 3169, 823, 4310, 1010, 1085, 4495, 4569, 6615, 3217, 3313, 6713, 6785,
    3383, 6607, 3207, 1241, 1508, 4797, 4122, 1618, 1569, 5135, 5040, 5691, 5636, 5404, 2230,
    2173, 2108, 134, 3645, 6543, 3123, 3024, 4194, 1306, 182, 3694, 4294, 744,
)  # fmt: skip

BODY_KINDS = ("smpl", "smplh", "smplx", "builtin")


@dataclass(frozen=True, eq=False)
class BodyModelData:
    """Arrays of an SMPL-family body model, as plain numpy (float64 unless stated).

    V vertices, J joints (24 SMPL, 52 SMPL-H, 55 SMPL-X), S shape directions, F faces.

    Attributes:
        kind: one of ``BODY_KINDS``.
        v_template: (V, 3) rest-pose, mean-shape vertices, metres.
        shapedirs: (V, 3, S) shape blend directions.
        posedirs: (V, 3, 9 * (J - 1)) pose blend directions, fed with ``(R_j - I)`` flattened
            row-major for joints 1..J-1 (SMPL's convention).
        J_regressor: (J, V) dense joint regressor.
        weights: (V, J) skinning weights, rows sum to 1.
        parents: (J,) int64 parent index, -1 for the root.
        faces: (F, 3) int64 triangle indices.
        joint_names: J names.
        marker_vertex_ids: (43,) int64 vertices used as virtual markers.
        name: a short human-readable id (file name or ``builtin``) recorded in checkpoints.
    """

    kind: str
    v_template: np.ndarray
    shapedirs: np.ndarray
    posedirs: np.ndarray
    J_regressor: np.ndarray
    weights: np.ndarray
    parents: np.ndarray
    faces: np.ndarray
    joint_names: tuple[str, ...]
    marker_vertex_ids: np.ndarray
    name: str = ""

    @property
    def num_vertices(self) -> int:
        return int(self.v_template.shape[0])

    @property
    def num_joints(self) -> int:
        return int(self.J_regressor.shape[0])

    @property
    def num_betas(self) -> int:
        return int(self.shapedirs.shape[2])

    def validate(self) -> BodyModelData:
        """Check array shapes agree; raise InputError naming the first inconsistency."""
        V, J = self.num_vertices, self.num_joints
        checks = [
            (self.kind in BODY_KINDS, f"unknown body-model kind {self.kind!r}"),
            (self.v_template.shape == (V, 3), "v_template must be (V, 3)"),
            (self.shapedirs.ndim == 3 and self.shapedirs.shape[:2] == (V, 3),
             f"shapedirs must be ({V}, 3, S), got {self.shapedirs.shape}"),
            (self.posedirs.shape == (V, 3, 9 * (J - 1)),
             f"posedirs must be ({V}, 3, {9 * (J - 1)}), got {self.posedirs.shape}"),
            (self.J_regressor.shape == (J, V),
             f"J_regressor must be ({J}, {V}), got {self.J_regressor.shape}"),
            (self.weights.shape == (V, J), f"weights must be ({V}, {J}), got {self.weights.shape}"),
            (self.parents.shape == (J,), f"parents must be ({J},), got {self.parents.shape}"),
            (J >= NUM_BODY_JOINTS, f"needs at least {NUM_BODY_JOINTS} joints, has {J}"),
            (self.faces.ndim == 2 and self.faces.shape[1] == 3, "faces must be (F, 3)"),
            (len(self.joint_names) == J, f"{len(self.joint_names)} joint names for {J} joints"),
            (self.marker_vertex_ids.ndim == 1 and len(self.marker_vertex_ids) > 0
             and int(self.marker_vertex_ids.max()) < V, "marker vertex ids out of range"),
        ]  # fmt: skip
        for ok, message in checks:
            if not ok:
                raise InputError(f"body model {self.name or self.kind}: {message}")
        if self.parents[0] != -1 or np.any(self.parents[1:] >= np.arange(1, J)):
            raise InputError(f"body model {self.name or self.kind}: parents must precede children")
        return self
