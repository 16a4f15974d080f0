"""Retarget a mocap clip (:class:`SourceMotion`) onto the SMPL skeleton of a body model.

Pipeline, in torch (the per-frame solve a chunk of frames at a time):

1. **Joint map** (:func:`~mdvae_cli.retarget.joint_map.build_joint_map`): source joints are found
   by name for the SMPL joints with a clear anatomical counterpart (*direct* joints: hips,
   knees, ankles, toe bases, shoulders, elbows, wrists); the others (pelvis, spine1-3, neck,
   head, collars) are *attached* points: a fixed offset in the frame of a source joint, taken
   from the body's rest pose.
2. **Canonical axes**: the source world is turned (a signed axis permutation read off the rest
   pose, ``upright.canonical_axes``) so that up is +y, the body's left +x and forward +z,
   SMPL's own frame; a take done lying stays lying.
3. **Betas** (:func:`~mdvae_cli.retarget.fit_shape.fit_betas`): the body's shape is fitted once
   per skeleton so that its rest bone lengths (legs, arms, hip and shoulder widths, torso and
   neck) match the source's.
4. **Solve**: each SMPL joint's rotation starts from its source joint's global rotation,
   corrected by the rest-pose difference of the bone direction; a few damped Gauss-Newton steps
   then fit all 22 joint positions to the targets, with a small penalty that keeps each local
   rotation near its source start (this fixes the twists that positions cannot see).
5. **Output**: SMPL y-up is turned into AMASS z-up, the floor is put at z = 0 (from the soles
   of the body's feet) and the result is a :class:`Motion` with the mean joint error.

Steps 1-2 live in :mod:`mdvae_cli.retarget.joint_map`, step 3 in
:mod:`mdvae_cli.retarget.fit_shape`;
their public names are re-exported here.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from mdvae_cli.errors import InputError
from mdvae_cli.formats.source import SourceMotion, resample_source
from mdvae_cli.geometry.rotations import rotmat_to_rotvec
from mdvae_cli.geometry.rotations_np import rotmat_between
from mdvae_cli.motion.motion import Motion
from mdvae_cli.retarget.fit_shape import BodyJoints, fit_betas, skeleton_key
from mdvae_cli.retarget.joint_map import (
    JointMap,
    attach_offsets,
    build_joint_map,
    canonical_rotation,
    canonicalise,
    normalise_name,
)
from mdvae_cli.retarget.pose_solve import (
    _N,
    frame_chunks,
    rest_corrections,
    solve_frames,
    solve_pose,
)
from mdvae_cli.retarget.soles import _FEET, foot_vertex, lowest_along
from mdvae_cli.retarget.source_file import load_source
from mdvae_cli.retarget.upright import to_smpl_axes
from mdvae_cli.workers import map_in_order

__all__ = [
    "Y_UP_TO_Z_UP",
    "BodyJoints",
    "JointMap",
    "RetargetResult",
    "RetargetSettings",
    "attach_offsets",
    "build_joint_map",
    "canonical_rotation",
    "canonicalise",
    "fit_betas",
    "fit_ground",
    "import_motion",
    "load_source",
    "normalise_name",
    "rest_corrections",
    "retarget",
    "skeleton_key",
    "solve_pose",
    "walking_speed",
]


#: y-up (SMPL) -> z-up (AMASS): x stays, y becomes z, z becomes -y
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


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
    jmap: the joint map itself (source joint indices, rotation sources), for the way back.
    to_output: (3, 3) rotation from the source's world axes to the output's (z up, levelled);
    a source point p (metres) lands at ``to_output @ p - drop``. drop: (3,).
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
    jmap: JointMap | None = None
    to_output: np.ndarray | None = None
    drop: np.ndarray | None = None

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
    measure one), "flat" only shifts heights, "none" keeps the source's heights; key_rate:
    ``pose_solve.key_stride``'s (0: every frame takes every step)."""

    twist_weight: float = 0.02
    iterations: int = 3
    floor: str = "plane"
    max_tilt: float = 0.035  # rise per metre (2 degrees)
    key_rate: float = 15.0  # Hz

    def validate(self) -> RetargetSettings:
        if self.floor not in ("plane", "flat", "none"):
            raise InputError(f"floor must be plane, flat or none, not {self.floor!r}")
        if not (self.twist_weight > 0 and min(self.iterations, self.max_tilt, self.key_rate) >= 0):
            raise InputError("twist_weight must be > 0, iterations, max_tilt and key_rate >= 0")
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


def _turn_in_place(x: torch.Tensor, Q: torch.Tensor, drop: torch.Tensor) -> torch.Tensor:
    """``x @ Q^T - drop`` written over x a chunk of frames at a time (a second array of a
    30-minute 120 Hz take's joints is 114 MB).  x: (T, J, 3) -> x"""
    for frames in frame_chunks(x.shape[0]):
        x[frames] = x[frames] @ Q.T - drop
    return x


def retarget(
    src: SourceMotion,
    body: BodyJoints,
    betas: np.ndarray | None = None,
    settings: RetargetSettings | None = None,
    metadata: dict | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> RetargetResult:
    """Retarget ``src`` (any axes, any frame rate: resample it first) onto ``body``.

    betas: the body shape to use (e.g. fitted once per subject with :func:`fit_betas`); None
    fits it here. metadata: extra entries for the output's ``source`` record. progress:
    called with (frames solved, frames) as each chunk of a take's frames is solved.
    """
    settings = (settings or RetargetSettings()).validate()
    if src.num_frames < 1:
        raise InputError("the take holds no frame")
    jmap = build_joint_map(src)
    src, S_world = to_smpl_axes(src, jmap)
    if betas is None:
        betas = fit_betas(src, body, jmap)
    b = torch.as_tensor(np.asarray(betas, dtype=np.float64))
    X_all = body.rest_joints(b)
    X = X_all[:_N]
    jmap = attach_offsets(src, jmap, X_all.numpy())
    C = torch.as_tensor(rest_corrections(jmap, src.rest_positions(), X.numpy()))

    # each chunk's results go straight into the take's arrays (keeping the chunks and joining
    # them at the end held every result twice: 840 MB on a 30-minute 120 Hz take)
    solved: list[torch.Tensor] = []
    chunks = frame_chunks(src.num_frames)
    parts = map_in_order(
        lambda frames: solve_frames(src, frames, jmap, C, X, body.parents, settings), chunks
    )
    for frames, part in zip(chunks, parts, strict=True):  # the chunks side by side
        if not solved:
            solved = [x.new_empty((src.num_frames, *x.shape[1:])) for x in part]
        for whole, x in zip(solved, part, strict=True):
            whole[frames] = x
        del part
        if progress is not None:
            progress(frames.stop, src.num_frames)
    targets, root, p, G_root, G_feet, pose_body = solved
    del solved
    err = (p - targets).norm(dim=-1)

    # the soles: each frame's lowest foot vertex (y up), heights a chunk of frames at a time
    # (a thousand vertices a frame: 1.7 GB of points on a 10-minute 120 Hz take at once)
    T = src.num_frames
    y = torch.tensor([0.0, 1.0, 0.0], dtype=G_feet.dtype)
    p_feet = p[:, _FEET]
    _, lowest = lowest_along(G_feet, p_feet, body, b, X_all, y)
    contacts = foot_vertex(G_feet, p_feet, body, b, X_all, lowest).numpy()
    plane = np.zeros(3)
    if settings.floor != "none":
        plane = fit_ground(contacts, settings.max_tilt, tilt=settings.floor == "plane")
    normal = np.array([-plane[1], 1.0, -plane[2]])
    level = torch.as_tensor(rotmat_between(normal, np.array([0.0, 1.0, 0.0])))
    floor = float((level @ torch.tensor([0.0, plane[0], 0.0], dtype=torch.float64))[1])
    soles, _ = lowest_along(G_feet, p_feet, body, b, X_all, level[1])
    soles = soles - floor  # (T,)
    tilt_deg = float(np.degrees(np.arctan(np.hypot(plane[1], plane[2]))))

    Q = torch.as_tensor(Y_UP_TO_Z_UP) @ level
    drop = torch.tensor([0.0, 0.0, floor], dtype=torch.float64)
    trans = root @ Q.T - drop - X[0]
    root_orient = rotmat_to_rotvec(Q @ G_root)
    joints = _turn_in_place(p, Q, drop)
    targets_z = _turn_in_place(targets, Q, drop)

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
        "body_model": body.data.name or body.data.kind,  # whose shape space the betas are in
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
        jmap=jmap,
        to_output=Q.numpy() @ S_world,
        drop=drop.numpy(),
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


def import_motion(
    src: SourceMotion,
    body: BodyJoints,
    fps: float | None = 30.0,
    betas: np.ndarray | None = None,
    settings: RetargetSettings | None = None,
    metadata: dict | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> RetargetResult:
    """Resample ``src`` to ``fps`` (None keeps its rate), then :func:`retarget` it."""
    if fps is not None:
        if not fps > 0:
            raise InputError(f"the output frame rate must be > 0, got {fps:g}")
        src = resample_source(src, fps)
    return retarget(src, body, betas=betas, settings=settings, metadata=metadata,
                    progress=progress)  # fmt: skip
