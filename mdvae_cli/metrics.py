"""Evaluation metrics: V2V, MPJPE, joint acceleration, acceleration error, feet and floor.

The metric functions are pure: they take torch tensors or numpy arrays (and return the same
kind), in whatever length unit they are given, and return per-frame values; a metric over a
clip is the mean of those. :func:`evaluate_pair` poses two motions with a body model and
reduces everything to one :class:`EvalResult` in the units of the paper's tables (cm, m/s^2).

The foot metrics (skate, penetration, float) are in :mod:`mdvae_cli.foot_metrics`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
import torch

from mdvae_cli.body.data import BodyModelData
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError
from mdvae_cli.export import DEFAULT_CHUNK_FRAMES, as_body_model, pose_motion_chunks
from mdvae_cli.foot_metrics import compare_feet
from mdvae_cli.motion.contacts import foot_vertex_ids, lowest_sole_points
from mdvae_cli.motion.holes import observed
from mdvae_cli.motion.motion import Motion, check_motion, slice_frames

Array = torch.Tensor | np.ndarray


def _torch(x: Array) -> torch.Tensor:
    return x if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x))


def _like(result: torch.Tensor, reference: Array) -> Array:
    return result if isinstance(reference, torch.Tensor) else result.numpy()


def mean_point_error(pred: Array, gt: Array) -> Array:
    """Mean Euclidean distance between corresponding points.  (..., N, 3), (..., N, 3) -> (...)"""
    p, g = _torch(pred), _torch(gt)
    return _like(torch.linalg.vector_norm(p - g, dim=-1).mean(dim=-1), pred)


def mpjpe(pred_joints: Array, gt_joints: Array) -> Array:
    """Mean per-joint position error, per frame.  (..., J, 3), (..., J, 3) -> (...)

    In world coordinates (no alignment); the tool uses the 22 body joints.
    """
    return mean_point_error(pred_joints, gt_joints)


def v2v(
    pred_vertices: Array,
    gt_vertices: Array,
    pred_pelvis: Array | None = None,
    gt_pelvis: Array | None = None,
) -> Array:
    """Mean vertex-to-vertex error, per frame.  (..., V, 3), (..., V, 3) -> (...)

    With ``pred_pelvis`` and ``gt_pelvis`` ((..., 3) each), every mesh first has its own
    pelvis joint subtracted (root-relative V2V, as in Motion-DVAE's tables); without them
    the error is absolute.
    """
    if (pred_pelvis is None) != (gt_pelvis is None):
        raise ValueError("give both pred_pelvis and gt_pelvis, or neither")
    p, g = _torch(pred_vertices), _torch(gt_vertices)
    if pred_pelvis is not None:
        p = p - _torch(pred_pelvis).unsqueeze(-2)
        g = g - _torch(gt_pelvis).unsqueeze(-2)
    return _like(torch.linalg.vector_norm(p - g, dim=-1).mean(dim=-1), pred_vertices)


def acceleration(positions: Array, fps: float) -> Array:
    """Central second difference.  positions (..., T, J, 3) -> (..., T - 2, J, 3)

    a[t] = (x[t-1] - 2 x[t] + x[t+1]) * fps^2, for the inner frames t = 1 .. T-2; in
    (position unit)/s^2.
    """
    x = _torch(positions)
    a = (x[..., :-2, :, :] - 2.0 * x[..., 1:-1, :, :] + x[..., 2:, :, :]) * (float(fps) ** 2)
    return _like(a, positions)


def joint_acceleration(joints: Array, fps: float) -> Array:
    """Mean acceleration magnitude over joints, per inner frame.  (..., T, J, 3) -> (..., T - 2)"""
    a = _torch(acceleration(_torch(joints), fps))
    return _like(torch.linalg.vector_norm(a, dim=-1).mean(dim=-1), joints)


def acceleration_error(pred_joints: Array, gt_joints: Array, fps: float) -> Array:
    """Mean norm of the difference of accelerations, per inner frame.

    (..., T, J, 3), (..., T, J, 3) -> (..., T - 2)
    """
    diff = _torch(pred_joints) - _torch(gt_joints)
    return _like(_torch(joint_acceleration(diff, fps)), pred_joints)


@dataclass
class EvalResult:
    """Metrics of one prediction against its ground truth (or a frame-weighted mean of many).

    num_frames: frames compared; fps: their frame rate (None for a mean over mixed rates).
    v2v_cm: root-relative vertex error, cm; v2v_abs_cm: absolute vertex error, cm;
    mpjpe_cm: error of the 22 body joints in world space, cm; mpjpe_root_cm: the same with
    each skeleton's pelvis at the origin (root-relative, the literature's MPJPE), cm;
    accel_gt / accel_pred: mean joint acceleration magnitude, m/s^2;
    accel_error: mean norm of the acceleration difference, m/s^2.
    The acceleration fields are None for clips under 3 frames.
    Feet (ground truth's contacts and floor; ``_gt`` the ground truth's own value):
    foot_skate_*: mean horizontal speed of contacting foot joints, cm/s; foot_slide_*: % of
    them faster than SLIDE_SPEED; penetration_*: mean depth of each foot's lowest sole point
    below the floor, all frames, cm; float_*: its mean height above the floor while that foot
    is down, cm (skate, slide, float: None without contacts); floor_m: the floor's height
    (None in a mean over several clips); contact_pairs, contact_frames: the counts the means
    of skate and float weigh by.
    Frames missing (a hole: some body joint unobserved) in the ground truth or the prediction
    are left out of every score: ``num_frames`` counts those scored, ``unscored_frames`` those
    left out, ``accel_count`` the inner frames whose three frames are all scored.
    """

    num_frames: int
    fps: float | None
    v2v_cm: float
    v2v_abs_cm: float
    mpjpe_cm: float
    accel_gt: float | None
    accel_pred: float | None
    accel_error: float | None
    foot_skate_gt: float | None = None
    foot_skate_pred: float | None = None
    foot_slide_gt: float | None = None
    foot_slide_pred: float | None = None
    penetration_gt: float | None = None
    penetration_pred: float | None = None
    float_gt: float | None = None
    float_pred: float | None = None
    floor_m: float | None = None
    mpjpe_root_cm: float | None = None
    contact_pairs: int = 0
    contact_frames: int = 0
    unscored_frames: int = 0
    accel_count: int | None = None

    @property
    def accel_frames(self) -> int:
        """Number of inner frames the accelerations average over (0 when undefined):
        ``accel_count`` when set, else every inner frame of ``num_frames``."""
        if self.accel_gt is None:
            return 0
        return max(self.num_frames - 2, 0) if self.accel_count is None else self.accel_count

    def to_dict(self) -> dict[str, float | int | None]:
        return asdict(self)


def check_compatible(gt: Motion, pred: Motion) -> None:
    """Raise InputError unless the two motions have the same frame rate and length."""
    if abs(gt.fps - pred.fps) > 1e-6 * max(gt.fps, 1.0):
        raise InputError(
            f"frame rates differ: ground truth {gt.fps:g} fps, prediction {pred.fps:g} fps"
        )
    if gt.num_frames != pred.num_frames:
        raise InputError(
            f"lengths differ: ground truth {gt.num_frames} frames, "
            f"prediction {pred.num_frames} frames"
        )


def common_rate(gt: Motion, pred: Motion) -> tuple[Motion, Motion, str | None]:
    """The two motions at one frame rate, for :func:`evaluate_pair`: where the rates differ,
    the faster one is resampled to the slower one's rate (slerp / lerp; an integer ratio
    takes its own frames) and both are cut to the shorter when the lengths then differ by
    at most one frame (rounding of the durations). -> (gt, pred, a note saying what was
    done, or None when nothing was). InputError when the durations differ by more."""
    if abs(gt.fps - pred.fps) <= 1e-6 * max(gt.fps, 1.0):
        return gt, pred, None
    from mdvae_cli.motion.resample import resample_motion

    rate = min(gt.fps, pred.fps)
    which = "ground truth" if gt.fps > pred.fps else "prediction"
    fast = max(gt.fps, pred.fps)
    end = {
        "ground truth": (gt.num_frames - 1) / gt.fps,
        "prediction": (pred.num_frames - 1) / pred.fps,
    }
    gt, pred = resample_motion(gt, rate), resample_motion(pred, rate)
    if abs(gt.num_frames - pred.num_frames) > 1:
        raise InputError(
            f"durations differ: ground truth {gt.num_frames / rate:.2f} s, prediction "
            f"{pred.num_frames / rate:.2f} s (at {rate:g} fps)"
        )
    n = min(gt.num_frames, pred.num_frames)
    note = f"evaluated at {rate:g} fps: the {which} resampled from {fast:g} fps"
    if gt.num_frames != pred.num_frames:  # one frame past the other's end: said, not scored
        longer, shorter = ("ground truth", "prediction")[:: 1 if gt.num_frames > n else -1]
        note += (f"; the {longer}'s last frame ({n / rate:.3f} s) is past the {shorter}'s "
                 f"end ({end[shorter]:.3f} s): not scored")  # fmt: skip
    gt, pred = slice_frames(gt, 0, n), slice_frames(pred, 0, n)
    return gt, pred, note


def scored_frames(gt: Motion, pred: Motion) -> np.ndarray:
    """(T,) bool: the frames a comparison scores, where every body joint is observed in both
    motions (a hole in either, filled or not, is not a measurement of it)."""
    return observed(gt).all(axis=1) & observed(pred).all(axis=1)


def evaluate_pair(
    gt: Motion,
    pred: Motion,
    body: BodyModel | BodyModelData,
    chunk_frames: int = DEFAULT_CHUNK_FRAMES,
) -> EvalResult:
    """Compare ``pred`` with ``gt`` through ``body`` (both posed with the ground-truth betas).

    Only the frames observed in both are scored (:func:`scored_frames`); accelerations on the
    inner frames whose neighbours are scored too. Meshes are built ``chunk_frames`` at a
    time, so memory does not grow with clip length; the (T, 22, 3) joint tracks are kept
    whole for the accelerations. Raises InputError when the frame rates or lengths differ,
    or when no frame is observed in both, or either is not a motion (``check_motion``).
    """
    for name, motion in (("ground truth", gt), ("prediction", pred)):
        try:
            check_motion(motion)
        except InputError as exc:
            raise InputError(f"{name}: {exc}") from None
    check_compatible(gt, pred)
    scored = scored_frames(gt, pred)
    if not scored.any():
        raise InputError("no frame is observed in both the ground truth and the prediction")
    model = as_body_model(body)
    T = gt.num_frames
    sums = {"v2v": 0.0, "v2v_abs": 0.0, "mpjpe": 0.0, "mpjpe_root": 0.0}
    joints_gt = np.empty((T, 22, 3))
    joints_pred = np.empty((T, 22, 3))
    soles_gt, soles_pred = np.empty((T, 2)), np.empty((T, 2))
    feet = foot_vertex_ids(model.data.weights)
    chunks = zip(
        pose_motion_chunks(gt, model, chunk_frames, vertices=True, betas=gt.betas),
        pose_motion_chunks(pred, model, chunk_frames, vertices=True, betas=gt.betas),
        strict=True,
    )
    for (ids, out_gt), (_, out_pred) in chunks:
        jg, jp = out_gt.joints.double(), out_pred.joints.double()
        vg, vp = out_gt.vertices.double(), out_pred.vertices.double()
        keep = torch.as_tensor(scored[ids], dtype=torch.float64)
        sums["v2v"] += float((v2v(vp, vg, jp[:, 0], jg[:, 0]) * keep).sum())
        sums["v2v_abs"] += float((v2v(vp, vg) * keep).sum())
        sums["mpjpe"] += float((mpjpe(jp, jg) * keep).sum())
        sums["mpjpe_root"] += float((mpjpe(jp - jp[:, :1], jg - jg[:, :1]) * keep).sum())
        joints_gt[ids] = jg.numpy()
        joints_pred[ids] = jp.numpy()
        soles_gt[ids] = lowest_sole_points(vg.numpy(), *feet)
        soles_pred[ids] = lowest_sole_points(vp.numpy(), *feet)

    n = int(scored.sum())
    inner = scored[:-2] & scored[1:-1] & scored[2:] if T >= 3 else np.zeros(0, bool)
    accel_gt = accel_pred = accel_err = None
    if inner.any():
        accel_gt = float(joint_acceleration(joints_gt, gt.fps)[inner].mean())
        accel_pred = float(joint_acceleration(joints_pred, gt.fps)[inner].mean())
        accel_err = float(acceleration_error(joints_pred, joints_gt, gt.fps)[inner].mean())
    return EvalResult(
        num_frames=n,
        fps=float(gt.fps),
        v2v_cm=100.0 * sums["v2v"] / n,
        v2v_abs_cm=100.0 * sums["v2v_abs"] / n,
        mpjpe_cm=100.0 * sums["mpjpe"] / n,
        mpjpe_root_cm=100.0 * sums["mpjpe_root"] / n,
        accel_gt=accel_gt,
        accel_pred=accel_pred,
        accel_error=accel_err,
        unscored_frames=T - n,
        accel_count=int(inner.sum()),
        **compare_feet(joints_gt, soles_gt, joints_pred, soles_pred, gt.fps, scored),
    )


def mean_result(results: Sequence[EvalResult]) -> EvalResult:
    """Frame-weighted mean: every frame of every clip counts once (inner frames for accelerations).

    Equals pooling all frames of all clips, so a long clip weighs more than a short one; foot
    skate pools contact pairs and float contact foot-frames the same way.
    """
    if not results:
        raise ValueError("mean_result needs at least one result")
    n = sum(r.num_frames for r in results)
    n_acc = sum(r.accel_frames for r in results)
    rates = {r.fps for r in results}

    def frames_mean(name: str) -> float:
        return sum(getattr(r, name) * r.num_frames for r in results) / n

    def accel_mean(name: str) -> float | None:
        if n_acc == 0:
            return None
        return sum(getattr(r, name) * r.accel_frames for r in results if r.accel_frames) / n_acc

    def weighted(name: str, weight: str) -> float | None:
        items = [(getattr(r, name), getattr(r, weight)) for r in results]
        items = [(v, w) for v, w in items if v is not None and w]
        total = sum(w for _, w in items)
        return sum(v * w for v, w in items) / total if total else None

    floors = {r.floor_m for r in results}
    return EvalResult(
        num_frames=n,
        fps=rates.pop() if len(rates) == 1 else None,
        v2v_cm=frames_mean("v2v_cm"),
        v2v_abs_cm=frames_mean("v2v_abs_cm"),
        mpjpe_cm=frames_mean("mpjpe_cm"),
        mpjpe_root_cm=weighted("mpjpe_root_cm", "num_frames"),
        accel_gt=accel_mean("accel_gt"),
        accel_pred=accel_mean("accel_pred"),
        accel_error=accel_mean("accel_error"),
        **{
            f"{k}_{w}": weighted(f"{k}_{w}", "contact_pairs")
            for k in ("foot_skate", "foot_slide")
            for w in ("gt", "pred")
        },
        **{f"penetration_{w}": weighted(f"penetration_{w}", "num_frames") for w in ("gt", "pred")},
        **{f"float_{w}": weighted(f"float_{w}", "contact_frames") for w in ("gt", "pred")},
        floor_m=floors.pop() if len(floors) == 1 else None,
        contact_pairs=sum(r.contact_pairs for r in results),
        contact_frames=sum(r.contact_frames for r in results),
        unscored_frames=sum(r.unscored_frames for r in results),
        accel_count=n_acc,
    )
