"""The built-in body's design tables: landmarks, body lengths, body-part tubes, shape directions.

Everything numeric that makes the body of :mod:`mdvae_cli.body.builtin` what it is: the base
body lengths (:data:`_BASE_LENGTHS`) and the landmarks they place (:func:`_landmarks`: the 24
SMPL joints and a few surface points), the 13 body-part tubes (:data:`_TUBES`, cross-sections
per station) and the shape directions (:data:`SHAPE_NAMES`, :func:`_shape_deltas`: the
parameter change for each unit beta). :mod:`mdvae_cli.body.builtin` turns these into the mesh,
skinning weights and joint regressor.

The two modules are one unit split in two: the tables keep their leading underscore because
they are not part of the package's API; import :data:`SHAPE_NAMES` from
:mod:`mdvae_cli.body.builtin`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# landmarks: the 24 SMPL joints, then extra points that shape the surface (left side)
_HEEL, _TOE_TIP, _FINGER_TIP, _HEAD_TOP, _CROTCH, _SOLE = 24, 25, 26, 27, 28, 29
_THUMB_BASE, _THUMB_TIP, _NOSE_ROOT, _NOSE_TIP = 30, 31, 32, 33
_NUM_LANDMARKS = 34

#: (left, right) SMPL joint pairs.
_LR_JOINTS = ((1, 2), (4, 5), (7, 8), (10, 11), (13, 14), (16, 17), (18, 19), (20, 21), (22, 23))

#: Body lengths in metres (left side; the right is its mirror). Offsets named ``*_d?`` are from
#: the parent joint; the rest are segment lengths along the T-pose bone direction.
_BASE_LENGTHS: dict[str, float] = {
    "pelvis_y": -0.22, "pelvis_z": 0.0,
    "hip_dx": 0.085, "hip_dy": 0.075, "hip_dz": 0.0,
    "thigh": 0.40, "knee_dx": 0.005, "knee_dz": 0.01,
    "shin": 0.40, "ankle_dx": 0.0, "ankle_dz": -0.03, "ankle_h": 0.065,
    "heel_dz": 0.04, "heel_h": 0.04,
    "ball_dx": 0.012, "ball_dz": 0.125, "ball_h": 0.025, "toe_dz": 0.065, "toe_h": 0.018,
    "spine1": 0.11, "spine1_dz": -0.01, "spine2": 0.13, "spine2_dz": 0.0,
    "spine3": 0.06, "spine3_dz": 0.02,
    "neck": 0.21, "neck_dz": -0.03, "head": 0.07, "head_dz": 0.03, "head_top": 0.18,
    "collar_dx": 0.075, "collar_dy": 0.11, "collar_dz": -0.02,
    "shoulder_dx": 0.095, "shoulder_dy": 0.025, "shoulder_dz": -0.01,
    "upper_arm": 0.27, "forearm": 0.25, "palm": 0.085, "finger": 0.10,
    "crotch_dy": 0.02,
    "thumb_dx": 0.02, "thumb_dy": -0.008, "thumb_dz": 0.022, "thumb_len": 0.065,
    "nose_dy": 0.035, "nose_dz": 0.085, "nose_len": 0.04,
}  # fmt: skip


@dataclass(frozen=True)
class _Tube:
    """One closed body part.

    frame: (e1, e2) cross-section axes; the tube runs along e1 x e2.
    anchors: (n, 3) rows (landmark a, landmark b, t): station centre = (1-t) L[a] + t L[b] + offset.
    shape: (n, 5) base rows (r1, r2, offset x, y, z): radii along e1, e2 and centre offset.
    """

    name: str
    frame: tuple[tuple[float, float, float], tuple[float, float, float]]
    anchors: tuple[tuple[int, int, float], ...]
    shape: tuple[tuple[float, float, float, float, float], ...]
    ring: int  # vertices per cross-section
    exponent: float  # super-ellipse exponent (2 = ellipse, larger = boxier)
    caps: tuple[float, float]  # cap length at start/end, as a fraction of the mean end radius
    chain: tuple[tuple[int, int, float], ...]  # (joint, boundary landmark, blend half-width)
    rings: tuple[tuple[int, int], ...]  # (joint, station) whose ring regresses the joint
    side: str  # "centre" or "left" (mirrored to build the right side)


_X, _Y, _Z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)
#: The left thumb points forward, outward and a little down in the T-pose.
_THUMB_DIR = np.array([0.55, -0.2, 0.81]) / np.linalg.norm([0.55, -0.2, 0.81])


def _frame_around(axis: np.ndarray) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Cross-section axes (e1 near +y, e2) with e1 x e2 = axis, for a tube along axis."""
    e1 = np.array(_Y) - (np.array(_Y) @ axis) * axis
    e1 /= np.linalg.norm(e1)
    return tuple(e1.tolist()), tuple(np.cross(axis, e1).tolist())


_TUBES: tuple[_Tube, ...] = (
    _Tube(
        "torso", (_Z, _X),
        anchors=((_CROTCH, _CROTCH, 0), (0, 0, 0), (0, 0, 0), (0, 3, 0.5), (3, 3, 0),
                 (3, 6, 0.5), (6, 6, 0), (9, 9, 0), (9, 12, 0.35), (9, 12, 0.65),
                 (9, 12, 0.85), (12, 12, 0)),
        shape=((0.085, 0.125, 0, 0, -0.01), (0.105, 0.165, 0, -0.045, -0.015),
               (0.105, 0.168, 0, 0, 0), (0.100, 0.155, 0, 0, 0.005), (0.096, 0.145, 0, 0, 0),
               (0.095, 0.140, 0, 0, 0.01), (0.100, 0.148, 0, 0, 0), (0.108, 0.158, 0, 0, 0),
               (0.110, 0.166, 0, 0, 0.0), (0.098, 0.172, 0, 0, -0.01),
               (0.078, 0.145, 0, 0, -0.015), (0.055, 0.07, 0, -0.01, 0)),
        ring=40, exponent=2.6, caps=(0.45, 0.3),
        chain=((0, 0, 0.0), (3, 3, 0.05), (6, 6, 0.04), (9, 9, 0.03)),
        rings=((0, 2), (3, 4), (6, 6), (9, 7)), side="centre",
    ),
    _Tube(
        "neck_head", (_Z, _X),
        anchors=((9, 12, 0.6), (12, 12, 0), (12, 15, 0.5), (15, 15, 0), (15, _HEAD_TOP, 0.25),
                 (15, _HEAD_TOP, 0.5), (15, _HEAD_TOP, 0.75)),
        shape=((0.05, 0.055, 0, 0, 0), (0.052, 0.056, 0, 0, 0), (0.05, 0.053, 0, 0, 0.005),
               (0.066, 0.062, 0, 0, 0), (0.093, 0.072, 0, 0, 0.015), (0.10, 0.078, 0, 0, 0.01),
               (0.092, 0.072, 0, 0, 0.0)),
        ring=28, exponent=2.2, caps=(0.5, 0.55),
        chain=((9, 9, 0.0), (12, 12, 0.035), (15, 15, 0.03)),
        rings=((12, 1), (15, 3)), side="centre",
    ),
    _Tube(
        "nose", (_X, _Y),
        anchors=((_NOSE_ROOT, _NOSE_ROOT, 0), (_NOSE_ROOT, _NOSE_TIP, 0.55),
                 (_NOSE_ROOT, _NOSE_TIP, 0.85)),
        shape=((0.013, 0.022, 0, 0, 0), (0.014, 0.016, 0, 0, 0), (0.011, 0.01, 0, 0, 0)),
        ring=12, exponent=2.0, caps=(0.5, 0.6),
        chain=((15, 15, 0.0),), rings=(), side="centre",
    ),
    _Tube(
        "leg", (_X, _Z),
        anchors=((1, 1, 0), (1, 1, 0), (1, 4, 0.25), (1, 4, 0.55), (1, 4, 0.82), (4, 4, 0),
                 (4, 7, 0.2), (4, 7, 0.45), (4, 7, 0.75), (7, 7, 0)),
        shape=((0.075, 0.08, 0, 0.07, 0), (0.085, 0.09, 0, 0, 0), (0.080, 0.085, 0, 0, -0.005),
               (0.068, 0.072, 0, 0, 0), (0.055, 0.058, 0, 0, 0), (0.050, 0.052, 0, 0, 0),
               (0.050, 0.056, 0, 0, -0.01), (0.045, 0.050, 0, 0, -0.008),
               (0.034, 0.036, 0, 0, 0), (0.030, 0.033, 0, 0, 0)),
        ring=24, exponent=2.0, caps=(0.8, 1.0),
        chain=((0, 0, 0.0), (1, 1, 0.07), (4, 4, 0.06), (7, 7, 0.035)),
        rings=((1, 1), (4, 5), (7, 9)), side="left",
    ),
    _Tube(
        "foot", (_X, _Y),
        anchors=((_HEEL, _HEEL, 0), (_SOLE, _SOLE, 0), (_SOLE, 10, 0.5), (10, 10, 0),
                 (10, _TOE_TIP, 0.5)),
        shape=((0.030, 0.037, 0, 0, 0), (0.038, 0.045, 0, 0.045, -0.01),
               (0.045, 0.037, 0, 0.025, 0), (0.048, 0.025, 0, 0, 0), (0.044, 0.02, 0, 0, 0)),
        ring=20, exponent=2.8, caps=(1.0, 1.0),
        chain=((7, 7, 0.0), (10, 10, 0.025)),
        rings=((10, 3),), side="left",
    ),
    _Tube(
        "arm", (_Y, _Z),
        anchors=((13, 13, 0), (13, 16, 0.6), (16, 16, 0), (16, 18, 0.2), (16, 18, 0.5),
                 (16, 18, 0.8), (18, 18, 0), (18, 20, 0.2), (18, 20, 0.5), (18, 20, 0.8),
                 (20, 20, 0)),
        shape=((0.045, 0.05, 0, 0, 0), (0.055, 0.055, 0, 0, 0), (0.055, 0.052, 0, 0, 0),
               (0.050, 0.048, 0, 0, 0), (0.045, 0.044, 0, 0, 0), (0.038, 0.040, 0, 0, 0),
               (0.036, 0.038, 0, 0, 0), (0.040, 0.041, 0, 0, 0), (0.034, 0.036, 0, 0, 0),
               (0.026, 0.032, 0, 0, 0), (0.022, 0.030, 0, 0, 0)),
        ring=20, exponent=2.0, caps=(0.5, 0.5),
        chain=((13, 13, 0.0), (16, 16, 0.05), (18, 18, 0.05), (20, 20, 0.03)),
        rings=((13, 0), (16, 2), (18, 6), (20, 10)), side="left",
    ),
    _Tube(
        "hand", (_Y, _Z),
        anchors=((20, 20, 0), (20, 22, 0.4), (22, 22, 0), (22, _FINGER_TIP, 0.4),
                 (22, _FINGER_TIP, 0.75)),
        shape=((0.020, 0.030, -0.01, 0, 0), (0.018, 0.042, 0, 0, 0), (0.015, 0.045, 0, 0, 0),
               (0.011, 0.042, 0, 0, 0), (0.009, 0.036, 0, 0, 0)),
        ring=16, exponent=3.0, caps=(0.5, 0.6),
        chain=((20, 20, 0.0), (22, 22, 0.025)),
        rings=((22, 2),), side="left",
    ),
    _Tube(
        "thumb", _frame_around(_THUMB_DIR),
        anchors=((_THUMB_BASE, _THUMB_BASE, 0), (_THUMB_BASE, _THUMB_TIP, 0.4),
                 (_THUMB_BASE, _THUMB_TIP, 0.8)),
        shape=((0.016, 0.019, 0, 0, 0), (0.012, 0.013, 0, 0, 0), (0.010, 0.011, 0, 0, 0)),
        ring=12, exponent=2.0, caps=(0.6, 1.0),
        chain=((20, 20, 0.0),), rings=(), side="left",
    ),
)  # fmt: skip
# vertex layout: all centre tubes, then the left ones, then the right mirrors of those
_TUBES = tuple(sorted(_TUBES, key=lambda tube: tube.side != "centre"))


def _base_params() -> dict[str, np.ndarray]:
    p = {k: np.float64(v) for k, v in _BASE_LENGTHS.items()}
    for tube in _TUBES:
        p[tube.name + "_shape"] = np.array(tube.shape, dtype=np.float64)
    return p


def _landmarks(p: dict[str, np.ndarray]) -> np.ndarray:
    """Joints and surface landmarks from body lengths (linear).  -> (34, 3)"""
    L = np.zeros((_NUM_LANDMARKS, 3))
    L[0] = (0.0, p["pelvis_y"], p["pelvis_z"])
    L[1] = L[0] + (p["hip_dx"], -p["hip_dy"], p["hip_dz"])
    L[4] = L[1] + (p["knee_dx"], -p["thigh"], p["knee_dz"])
    L[7] = L[4] + (p["ankle_dx"], -p["shin"], p["ankle_dz"])
    sole_y = L[7, 1] - p["ankle_h"]
    L[10] = (L[7, 0] + p["ball_dx"], sole_y + p["ball_h"], L[7, 2] + p["ball_dz"])
    L[3] = L[0] + (0.0, p["spine1"], p["spine1_dz"])
    L[6] = L[3] + (0.0, p["spine2"], p["spine2_dz"])
    L[9] = L[6] + (0.0, p["spine3"], p["spine3_dz"])
    L[12] = L[9] + (0.0, p["neck"], p["neck_dz"])
    L[15] = L[12] + (0.0, p["head"], p["head_dz"])
    L[13] = L[9] + (p["collar_dx"], p["collar_dy"], p["collar_dz"])
    L[16] = L[13] + (p["shoulder_dx"], p["shoulder_dy"], p["shoulder_dz"])
    L[18] = L[16] + (p["upper_arm"], 0.0, 0.0)
    L[20] = L[18] + (p["forearm"], 0.0, 0.0)
    L[22] = L[20] + (p["palm"], 0.0, 0.0)
    for left, right in _LR_JOINTS:
        L[right] = L[left] * (-1.0, 1.0, 1.0)
    L[_HEEL] = (L[7, 0], sole_y + p["heel_h"], L[7, 2] - p["heel_dz"])
    L[_TOE_TIP] = (L[10, 0], sole_y + p["toe_h"], L[10, 2] + p["toe_dz"])
    L[_FINGER_TIP] = L[22] + (p["finger"], 0.0, 0.0)
    L[_HEAD_TOP] = L[15] + (0.0, p["head_top"], 0.0)
    L[_CROTCH] = (0.0, L[1, 1] - p["crotch_dy"], L[0, 2])
    L[_SOLE] = (L[7, 0], sole_y, L[7, 2])
    L[_THUMB_BASE] = L[20] + (p["thumb_dx"], p["thumb_dy"], p["thumb_dz"])
    L[_THUMB_TIP] = L[_THUMB_BASE] + p["thumb_len"] * _THUMB_DIR
    L[_NOSE_ROOT] = L[15] + (0.0, p["nose_dy"], p["nose_dz"])
    L[_NOSE_TIP] = L[_NOSE_ROOT] + (0.0, -0.3 * p["nose_len"], p["nose_len"])
    return L


#: Names of the shape directions, in betas order. Per unit beta (about one population std):
#: height: every length and radius +4 % (about the origin; ~6.8 cm taller);
#: leg_length: thigh and shin +1.2 cm each; thigh_vs_shin: thigh +1 cm, shin -1 cm;
#: torso_length: pelvis->neck +2.3 cm spread over the spine; arm_length: upper arm +8 mm,
#: forearm +7.5 mm, hand +5.5 mm; upper_arm_vs_forearm: +8 mm / -8 mm;
#: shoulder_width: shoulder joints +1.4 cm each side; hip_width: hip joints +8 mm each side;
#: neck_length: neck->head +1.2 cm; head_size: head +5 % (surface only);
#: foot_length: +1.1 cm; girth: torso/head +10 %, limbs +6 % (surface only);
#: chest_depth: chest +10 % deep (surface only); hand_size: palm +6 mm, fingers +8 mm;
#: lower_vs_upper_spine: spine2/spine3 joints up ~1 cm with shoulders and neck fixed;
#: limb_girth: legs and arms +10 % (surface only). Joints move with vertices (exactly).
SHAPE_NAMES: tuple[str, ...] = (
    "height", "leg_length", "thigh_vs_shin", "torso_length", "arm_length",
    "upper_arm_vs_forearm", "shoulder_width", "hip_width", "neck_length", "head_size",
    "foot_length", "girth", "chest_depth", "hand_size", "lower_vs_upper_spine", "limb_girth",
)  # fmt: skip


def _thicker(p: dict, names: tuple[str, ...], scale: tuple[float, float], rows=slice(None)):
    """Parameter change that scales the cross-section radii of tubes (selected stations)."""
    out = {}
    for name in names:
        d = np.zeros_like(p[name + "_shape"])
        d[rows, :2] = np.multiply(scale, p[name + "_shape"][rows, :2])
        out[name + "_shape"] = d
    return out


def _shape_deltas(p: dict[str, np.ndarray]) -> list[dict[str, np.ndarray]]:
    """Parameter change for beta_k = +1, per shape direction (see SHAPE_NAMES)."""
    limbs = ("leg", "foot", "arm", "hand", "thumb")
    return [
        {k: 0.04 * v for k, v in p.items()},  # height: uniform 4 % scale about the origin
        {"thigh": 0.012, "shin": 0.012},
        {"thigh": 0.01, "shin": -0.01},
        {"spine1": 0.005, "spine2": 0.006, "spine3": 0.003, "neck": 0.009, "collar_dy": 0.005},
        {"upper_arm": 0.008, "forearm": 0.0075, "palm": 0.0025, "finger": 0.003,
         "thumb_len": 0.002},
        {"upper_arm": 0.008, "forearm": -0.008},
        {"collar_dx": 0.006, "shoulder_dx": 0.008}
        | _thicker(p, ("torso",), (0.0, 0.08), slice(8, 11)),
        {"hip_dx": 0.008} | _thicker(p, ("torso",), (0.0, 0.06), slice(0, 4)),
        {"head": 0.012},
        {"head_top": 0.008, "nose_dy": 0.002, "nose_dz": 0.005}
        | _thicker(p, ("neck_head",), (0.05, 0.05), slice(3, 7)),
        {"ball_dz": 0.006, "toe_dz": 0.003, "heel_dz": 0.002},
        {"nose_dz": 0.009} | _thicker(p, ("torso", "neck_head"), (0.1, 0.1))
        | _thicker(p, limbs, (0.06, 0.06)),
        _thicker(p, ("torso",), (0.10, 0.0), slice(6, 10)),
        {"palm": 0.006, "finger": 0.008, "thumb_len": 0.005, "thumb_dx": 0.002,
         "thumb_dz": 0.002} | _thicker(p, ("hand",), (0.06, 0.06)),
        {"spine1": 0.008, "spine2": 0.004, "spine3": -0.004, "neck": -0.008, "collar_dy": -0.008},
        _thicker(p, ("leg", "arm"), (0.1, 0.1)),
    ]  # fmt: skip
