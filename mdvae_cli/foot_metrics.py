"""Feet and floor metrics: foot skate, penetration and float (pure numpy).

They are scored where the *ground truth* has its feet down (:mod:`mdvae_cli.motion.contacts`:
a foot joint low and slow), against the ground truth's floor, for the ground truth and the
prediction alike:

* **foot skate**: the horizontal speed of each foot joint in contact at two consecutive frames
  (cm/s), and the share of those over :data:`SLIDE_SPEED` (0.6 m/s = 2 cm per frame at 30 Hz);
* **penetration**: how far each foot's lowest sole point is below the floor, every frame and
  both feet, 0 when above (cm);
* **float**: how far it is above the floor while that foot is down, 0 when below (cm).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mdvae_cli.motion.contacts import FOOT_JOINTS, estimate_floor, foot_contacts, foot_of_joints

#: a contacting foot joint faster than this slides, m/s: 2 cm per frame at 30 Hz
SLIDE_SPEED = 0.6


def contact_slide_speeds(joints: np.ndarray, contacts: np.ndarray, fps: float) -> np.ndarray:
    """Horizontal speeds of the foot joints while they are in contact.

    joints: (T, 22, 3) z-up; contacts: (T, 4) bool in ``FOOT_JOINTS`` order. For every joint
    in contact at both frames t-1 and t, |xy[t] - xy[t-1]| * fps.  -> (N,) in (unit)/s
    """
    xy = np.asarray(joints, dtype=np.float64)[:, list(FOOT_JOINTS), :2]
    c = np.asarray(contacts, dtype=bool)
    both = c[1:] & c[:-1]  # (T-1, 4)
    step = np.linalg.norm(np.diff(xy, axis=0), axis=-1) * float(fps)
    return step[both]


def penetration_depths(soles: np.ndarray, floor: float) -> np.ndarray:
    """How far each foot's lowest sole point is below the floor (0 when above).  (T, 2) -> (T, 2)"""
    return np.maximum(float(floor) - np.asarray(soles, dtype=np.float64), 0.0)


def float_heights(soles: np.ndarray, floor: float, foot_contact: np.ndarray) -> np.ndarray:
    """Height of each lowest sole point above the floor (0 when below), where that foot is down.

    soles: (T, 2); foot_contact: (T, 2) bool.  -> (N,)
    """
    up = np.maximum(np.asarray(soles, dtype=np.float64) - float(floor), 0.0)
    return up[np.asarray(foot_contact, dtype=bool)]


@dataclass
class FootScores:
    """Feet and floor of one motion, as sums and counts (means: :meth:`means`).

    skate_sum: sum of contact slide speeds (m/s); slides: how many exceed SLIDE_SPEED;
    contact_pairs: their count; penetration_sum: sum of depths over frames x 2 feet (m);
    float_sum: sum of float heights over foot-frames in contact (m); contact_frames: their count.
    """

    skate_sum: float
    slides: int
    contact_pairs: int
    penetration_sum: float
    float_sum: float
    contact_frames: int
    num_frames: int

    def means(self) -> dict[str, float | None]:
        """skate (cm/s), slide (% of contact pairs), penetration (cm), float (cm)."""
        pairs, down = self.contact_pairs, self.contact_frames
        return {
            "skate": 100.0 * self.skate_sum / pairs if pairs else None,
            "slide": 100.0 * self.slides / pairs if pairs else None,
            "penetration": 100.0 * self.penetration_sum / (2 * self.num_frames),
            "float": 100.0 * self.float_sum / down if down else None,
        }


def foot_scores(
    joints: np.ndarray,
    soles: np.ndarray,
    contacts: np.ndarray,
    floor: float,
    fps: float,
    scored: np.ndarray | None = None,
) -> FootScores:
    """Foot skate, penetration and float of one motion, given where the feet are down.

    joints: (T, 22, 3) and soles: (T, 2) lowest sole points, of the motion scored; contacts:
    (T, 4) bool (``FOOT_JOINTS`` order) and floor (z, m), usually the ground truth's;
    scored: (T,) bool, the frames that count (all when None): contacts elsewhere are
    ignored, and penetration averages over these frames only.
    """
    soles = np.asarray(soles, dtype=np.float64)
    keep = np.ones(len(soles), bool) if scored is None else np.asarray(scored, bool)
    contacts = np.asarray(contacts, bool) & keep[:, None]
    speeds = contact_slide_speeds(joints, contacts, fps)
    soles = soles[keep]
    heights = float_heights(soles, floor, foot_of_joints(contacts)[keep])
    return FootScores(
        skate_sum=float(speeds.sum()),
        slides=int((speeds > SLIDE_SPEED).sum()),
        contact_pairs=int(speeds.size),
        penetration_sum=float(penetration_depths(soles, floor).sum()),
        float_sum=float(heights.sum()),
        contact_frames=int(heights.size),
        num_frames=int(soles.shape[0]),
    )


def foot_fields(gt: FootScores, pred: FootScores, floor: float | None) -> dict:
    """The foot fields of an ``EvalResult`` from the two motions' scores."""
    g, p = gt.means(), pred.means()
    return {
        "foot_skate_gt": g["skate"],
        "foot_skate_pred": p["skate"],
        "foot_slide_gt": g["slide"],
        "foot_slide_pred": p["slide"],
        "penetration_gt": g["penetration"],
        "penetration_pred": p["penetration"],
        "float_gt": g["float"],
        "float_pred": p["float"],
        "floor_m": floor,
        "contact_pairs": gt.contact_pairs,
        "contact_frames": gt.contact_frames,
    }


def compare_feet(
    gt_joints: np.ndarray,
    gt_soles: np.ndarray,
    pred_joints: np.ndarray,
    pred_soles: np.ndarray,
    fps: float,
    scored: np.ndarray | None = None,
) -> dict:
    """The foot fields of an ``EvalResult``: contacts and floor from the ground truth.

    joints (T, 22, 3), soles (T, 2) lowest sole points, z-up metres; scored (T,) bool: the
    frames that count (all when None; see :func:`foot_scores`).
    """
    keep = np.ones(len(gt_soles), bool) if scored is None else np.asarray(scored, bool)
    contacts = foot_contacts(gt_joints, fps) & keep[:, None]
    floor = estimate_floor(np.asarray(gt_soles)[keep], foot_of_joints(contacts)[keep])
    return foot_fields(
        foot_scores(gt_joints, gt_soles, contacts, floor, fps, scored),
        foot_scores(pred_joints, pred_soles, contacts, floor, fps, scored),
        floor,
    )
