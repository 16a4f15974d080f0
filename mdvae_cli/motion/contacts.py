"""Foot contacts and the floor: when a foot joint stands on the ground, and where the ground is.

One definition, shared by ``mdvae eval`` (foot metrics), ``mdvae denoise --feet lock`` and any
viewer that marks contacts. Pure numpy; positions are z-up, in metres (AMASS convention).

* **Foot joints**: the SMPL body joints 7, 8 (left, right ankle) and 10, 11 (left, right foot,
  at the ball of the foot), in that order: :data:`FOOT_JOINTS`.
* **Contact**: a foot joint is in contact at frame t when it is *low* — less than
  ``height_tol`` (default 5 cm) above its planted level — and *slow* — its speed (3-D, central
  difference) is under ``speed_tol`` (default 0.3 m/s, i.e. 1 cm per frame at 30 Hz).
* **Planted level** (:func:`planted_levels`): the height of an ankle (and of a ball joint) when
  its foot stands on the ground, estimated from the take itself: the 5th percentile of the
  heights of both ankles over the take (and of both ball joints). It adapts to the body's size
  and to a floor that is not at z = 0; a take needs a few frames with a foot down.
* **Sole points** (:func:`foot_vertex_ids`): the mesh vertices of each foot (skinned at least
  half by that side's ankle and foot joints). A foot's *lowest sole point* at a frame is the
  lowest of its vertices, which is the heel, the ball or the toes, whatever the foot's pitch.
* **Floor** (:func:`estimate_floor`): the ground's height, from the lowest sole points: their
  median over the frames where that foot is in contact (the foot is on the ground then), or,
  in a take with no contact at all, their 5th percentile.
"""

from __future__ import annotations

import numpy as np

#: SMPL joint indices of the foot joints: left ankle, right ankle, left foot, right foot.
FOOT_JOINTS: tuple[int, ...] = (7, 8, 10, 11)
#: which foot (0 left, 1 right) each of FOOT_JOINTS belongs to
FOOT_SIDE: tuple[int, ...] = (0, 1, 0, 1)
#: a foot joint is low when it is less than this above its planted level, metres
HEIGHT_TOL = 0.05
#: a foot joint is slow when its speed is under this, m/s
SPEED_TOL = 0.3
#: percentile of the ankles' (balls') heights taken as their planted level
LEVEL_PERCENTILE = 5.0


def _feet(joints: np.ndarray) -> np.ndarray:
    """The foot joints of a (T, 22, 3) body-joint array.  -> (T, 4, 3) float64"""
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[1] < 12 or joints.shape[2] != 3:
        raise ValueError(f"joints must be (T, 22, 3), got {joints.shape}")
    return joints[:, list(FOOT_JOINTS)]


def planted_levels(feet: np.ndarray, percentile: float = LEVEL_PERCENTILE) -> np.ndarray:
    """Each foot joint's height when its foot stands on the ground.  (T, 4, 3) -> (4,)

    feet: the ``FOOT_JOINTS`` of a take (``joints[:, FOOT_JOINTS]``). The ``percentile``-th
    percentile of both ankles' heights (both balls') over the take; left and right share one.
    """
    z = np.asarray(feet, dtype=np.float64)[..., 2]
    ankle = np.percentile(z[:, :2], percentile)
    ball = np.percentile(z[:, 2:], percentile)
    return np.array([ankle, ankle, ball, ball])


def joint_speeds(positions: np.ndarray, fps: float) -> np.ndarray:
    """Speed of each point, central differences (one-sided at the ends), in units/s.

    positions (T, K, 3) -> (T, K); zeros for a one-frame take.
    """
    x = np.asarray(positions, dtype=np.float64)
    if x.shape[0] < 2:
        return np.zeros(x.shape[:2])
    return np.linalg.norm(np.gradient(x, axis=0), axis=-1) * float(fps)


def foot_contacts(
    joints: np.ndarray,
    fps: float,
    levels: np.ndarray | None = None,
    height_tol: float = HEIGHT_TOL,
    speed_tol: float = SPEED_TOL,
) -> np.ndarray:
    """Which foot joint stands on the ground at each frame: low and slow.

    joints: (T, 22, 3) body joints, z-up, metres; fps: frames per second;
    levels: (4,) planted heights of FOOT_JOINTS (or a scalar for all four), default
    :func:`planted_levels` of this take; height_tol (m), speed_tol (m/s): the thresholds.
    -> (T, 4) bool, columns in the order of :data:`FOOT_JOINTS` (left ankle, right ankle,
    left foot, right foot).
    """
    return contacts_of_feet(_feet(joints), fps, levels, height_tol, speed_tol)


def contacts_of_feet(
    feet: np.ndarray,
    fps: float,
    levels: np.ndarray | None = None,
    height_tol: float = HEIGHT_TOL,
    speed_tol: float = SPEED_TOL,
) -> np.ndarray:
    """:func:`foot_contacts` from the foot joints alone.  feet (T, 4, 3) -> (T, 4) bool"""
    feet = np.asarray(feet, dtype=np.float64)
    if feet.ndim != 3 or feet.shape[1:] != (4, 3):
        raise ValueError(f"feet must be (T, 4, 3), got {feet.shape}")
    if fps <= 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    levels = planted_levels(feet) if levels is None else np.broadcast_to(levels, (4,))
    low = feet[..., 2] - levels < height_tol
    slow = joint_speeds(feet, fps) < speed_tol
    return low & slow


def foot_of_joints(contacts: np.ndarray) -> np.ndarray:
    """Per-foot contact: a foot is down when its ankle or its ball joint is.

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
        raise ValueError("the body model has no foot vertices (weights on joints 7, 8, 10, 11)")
    return left, right


def lowest_sole_points(
    vertices: np.ndarray, left_ids: np.ndarray, right_ids: np.ndarray
) -> np.ndarray:
    """Height of each foot's lowest vertex.  vertices (T, V, 3) -> (T, 2) (left, right), z"""
    z = np.asarray(vertices)[..., 2]
    return np.stack([z[:, left_ids].min(1), z[:, right_ids].min(1)], axis=1)


def estimate_floor(soles: np.ndarray, foot_contact: np.ndarray | None = None) -> float:
    """The ground's height from the lowest sole points.

    soles: (T, 2) lowest sole point of each foot (:func:`lowest_sole_points`);
    foot_contact: (T, 2) bool, which foot is down (:func:`foot_of_joints`).
    -> the median of ``soles`` where the foot is down; with no contact given or none found, the
    5th percentile of all of them.
    """
    soles = np.asarray(soles, dtype=np.float64)
    if soles.size == 0:
        raise ValueError("no frames to estimate the floor from")
    if foot_contact is not None and np.any(foot_contact):
        return float(np.median(soles[np.asarray(foot_contact, dtype=bool)]))
    return float(np.percentile(soles, LEVEL_PERCENTILE))
