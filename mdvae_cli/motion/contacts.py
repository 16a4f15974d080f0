"""Foot contact: which foot joints are planted on the floor in each frame.

One definition, shared by whatever needs it (the viewer marks contacts, foot-skating metrics
measure how far a foot slides while it is in contact): a foot joint is *in contact* in a frame
when it is **low** (within ``height_tol`` of its own floor level) and **slow** (moving at less
than ``speed_max``). Each joint's floor level is a low quantile of its own height over the take
(the ankle sits ~8 cm above the sole, the toe base ~3 cm: one common floor would never find the
ankle low), so the rule needs no known floor and ignores a few frames of noise below it.

Feet and floor, for the foot metrics and foot locking (docs/model.md, "Feet and floor"):

* **Sole points** (:func:`foot_vertex_ids`): the mesh vertices of each foot (skinned at least
  half by that side's ankle and foot joints). A foot's *lowest sole point* at a frame is the
  lowest of them: the heel, the ball or the toes, whatever the foot's pitch.
* **Floor** (:func:`estimate_floor`): the ground's height, the median of the lowest sole points
  over the frames where that foot is in contact (its ankle or its toe base is), or, in a take
  with no contact at all, their 5th percentile.
"""

from __future__ import annotations

import numpy as np

from mdvae_cli.errors import InputError

#: the SMPL foot joints, in the order of :func:`foot_contacts`' columns
FOOT_JOINTS: tuple[int, ...] = (7, 8, 10, 11)
FOOT_JOINT_NAMES: tuple[str, ...] = ("left_ankle", "right_ankle", "left_foot", "right_foot")
#: metres above the joint's floor level within which a foot joint counts as low
HEIGHT_TOL = 0.05
#: m/s below which a foot joint counts as still
SPEED_MAX = 0.2
#: the quantile of a joint's height over the take taken as its floor level: low enough to be
#: a frame of stance in any take with contact, high enough that 2 % of noisy frames below the
#: floor do not set it
FLOOR_QUANTILE = 0.02


def joint_speeds(points: np.ndarray, fps: float) -> np.ndarray:
    """Speed of every point, m/s, by central differences (one-sided at the ends).

    points: (T, J, 3) metres -> (T, J); zeros for a single frame.
    """
    points = np.asarray(points, dtype=np.float64)
    if points.shape[0] < 2:
        return np.zeros(points.shape[:2])
    velocity = np.gradient(points, axis=0) * fps
    return np.linalg.norm(velocity, axis=-1)


def foot_floor_levels(joints: np.ndarray, up: int = 2, quantile: float = FLOOR_QUANTILE):
    """Each foot joint's floor level: the ``quantile`` of its height over the take.

    joints: (T, J >= 12, 3) metres -> (4,) metres, in FOOT_JOINTS order.
    """
    heights = np.asarray(joints, dtype=np.float64)[:, list(FOOT_JOINTS), up]
    return np.quantile(heights, quantile, axis=0)


def foot_contacts(
    joints: np.ndarray,
    fps: float,
    height_tol: float = HEIGHT_TOL,
    speed_max: float = SPEED_MAX,
    up: int = 2,
    floor: np.ndarray | float | None = None,
) -> np.ndarray:
    """Which foot joints touch the floor in each frame: low and slow.

    joints: (T, J, 3) joint positions in metres, SMPL order (J >= 12: the 22 body joints or
        more), ``up`` the vertical axis (2: z-up, AMASS; 1: y-up).
    fps: frames per second (> 0), for the speed.
    height_tol: a joint is low when its height is at most its floor level + this (m).
    speed_max: a joint is still when its speed (3-D, central differences) is below this (m/s).
    floor: the floor level of each foot joint (4,) or one for all, metres; default
        :func:`foot_floor_levels` of this take.
    Returns (T, 4) bool, columns FOOT_JOINTS: left ankle, right ankle, left foot (toe base),
    right foot. A single frame has no speed: it counts as still.
    """
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[1] < 12 or joints.shape[2] != 3:
        raise InputError(f"foot_contacts needs joints of shape (T, J >= 12, 3), got {joints.shape}")
    if not fps > 0:
        raise InputError(f"foot_contacts needs a frame rate > 0, got {fps}")
    return contacts_of_feet(joints[:, list(FOOT_JOINTS)], fps, height_tol, speed_max, up, floor)


def contacts_of_feet(
    feet: np.ndarray,
    fps: float,
    height_tol: float = HEIGHT_TOL,
    speed_max: float = SPEED_MAX,
    up: int = 2,
    floor: np.ndarray | float | None = None,
) -> np.ndarray:
    """:func:`foot_contacts` from the foot joints alone.  feet: (T, 4, 3), FOOT_JOINTS order
    -> (T, 4) bool"""
    feet = np.asarray(feet, dtype=np.float64)
    if feet.ndim != 3 or feet.shape[1:] != (len(FOOT_JOINTS), 3):
        raise InputError(f"contacts_of_feet needs feet of shape (T, 4, 3), got {feet.shape}")
    if not fps > 0:
        raise InputError(f"contacts_of_feet needs a frame rate > 0, got {fps}")
    if feet.shape[0] == 0:
        return np.zeros((0, len(FOOT_JOINTS)), dtype=bool)
    if floor is None:
        level = np.quantile(feet[..., up], FLOOR_QUANTILE, axis=0)
    else:
        level = np.broadcast_to(floor, (4,))
    low = feet[..., up] <= np.asarray(level)[None, :] + height_tol
    still = joint_speeds(feet, fps) < speed_max
    return low & still


#: which foot (0 left, 1 right) each of FOOT_JOINTS belongs to
FOOT_SIDE: tuple[int, ...] = (0, 1, 0, 1)
#: the percentile of the lowest sole points taken as the floor of a take with no contact
FLOOR_PERCENTILE = 5.0


def foot_of_joints(contacts: np.ndarray) -> np.ndarray:
    """Per-foot contact: a foot is down when its ankle or its toe base is.

    contacts (T, 4) in FOOT_JOINTS order -> (T, 2) bool (left, right)
    """
    c = np.asarray(contacts, dtype=bool)
    return c[:, :2] | c[:, 2:]


def foot_vertex_ids(weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The vertices of each foot: skinned at least half by that side's ankle and foot joints.

    weights: (V, J) skinning weights of an SMPL-layout body -> (left ids, right ids)
    """
    W = np.asarray(weights)
    left = np.flatnonzero(W[:, [7, 10]].sum(1) >= 0.5)
    right = np.flatnonzero(W[:, [8, 11]].sum(1) >= 0.5)
    if not len(left) or not len(right):
        raise InputError("the body model has no foot vertices (weights on joints 7, 8, 10, 11)")
    return left, right


def lowest_sole_points(
    vertices: np.ndarray, left_ids: np.ndarray, right_ids: np.ndarray, up: int = 2
) -> np.ndarray:
    """Height of each foot's lowest vertex.  vertices (T, V, 3) -> (T, 2) (left, right)"""
    h = np.asarray(vertices)[..., up]
    return np.stack([h[:, left_ids].min(1), h[:, right_ids].min(1)], axis=1)


def estimate_floor(soles: np.ndarray, foot_contact: np.ndarray | None = None) -> float:
    """The ground's height from the lowest sole points.

    soles: (T, 2) lowest sole point of each foot (:func:`lowest_sole_points`);
    foot_contact: (T, 2) bool, which foot is down (:func:`foot_of_joints`).
    -> the median of ``soles`` where the foot is down; with no contact given or none found, the
    FLOOR_PERCENTILE-th percentile of all of them.
    """
    soles = np.asarray(soles, dtype=np.float64)
    if soles.size == 0:
        raise InputError("no frames to estimate the floor from")
    if foot_contact is not None and np.any(foot_contact):
        return float(np.median(soles[np.asarray(foot_contact, dtype=bool)]))
    return float(np.percentile(soles, FLOOR_PERCENTILE))
