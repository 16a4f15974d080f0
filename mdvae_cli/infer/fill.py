"""Holes (frames and joints a take is missing, ``Motion.joint_mask`` False) in the denoised
result: how they are written, and what the later stages read of the input there.

The denoiser reads placeholders in the holes (``motion.holes.fill_gaps``) and its likelihoods
drop them (the joint mask weighs the observations). What ends up in a hole is then one of
:data:`FILLS`:

* ``"curve"``: per joint, a cubic spline through the input's own frames and a cubic Hermite
  curve from the values and velocities of the *result's* frames beside the hole
  (``motion.holes.fill_gaps``), mixed by the input's own noise (:func:`mix_by_noise`): a clean
  take is filled from its own frames, a noisy one from its cleaned frames;
* ``"model"``: the denoiser's own frames (its prior's continuation of the placeholders);
* ``"off"``: the input's values as they came.
"""

from __future__ import annotations

import numpy as np
import torch

from mdvae_cli.geometry.rotations import quat_slerp, quat_to_rotvec, rotvec_to_quat, rotvec_unwrap
from mdvae_cli.infer.fill_choices import FILLS
from mdvae_cli.infer.noise_blend import noise_variance
from mdvae_cli.motion.holes import fill_gaps, observed
from mdvae_cli.motion.motion import Motion


def has_holes(motion: Motion) -> bool:
    """Whether any body joint of any frame is missing."""
    return motion.joint_mask is not None and not np.asarray(motion.joint_mask, bool).all()


def fill_holes(source: Motion, result: Motion, method: str = "curve") -> Motion:
    """``result`` (the denoised ``source``, same frames) with the source's holes written by
    ``method`` (see the module docstring); the result's mask is the source's."""
    if method not in FILLS:
        raise ValueError(f"fill must be one of {', '.join(FILLS)}, got {method!r}")
    if not has_holes(source):
        return result
    mask = observed(source)
    out = result.with_body()
    out.joint_mask = mask
    if method == "curve":
        return mix_by_noise(
            input_curve(source),
            fill_gaps(out, "hermite", RESULT_TANGENT_FRAMES),
            source,
        )
    if method == "off":
        return take_holes(out, source, mask)
    return out


#: the input noise (rad per component, m for the translation) at which a hole's curve reads
#: the input's frames and the result's equally: below it the input's own frames (a clean take,
#: whose result differs from it by the denoiser's hair), above it the cleaned ones
CURVE_NOISE_RAD = 0.01
CURVE_NOISE_M = 0.003
#: the curve from a denoised result holds its end velocities over holes up to this long
#: (frames; ``motion.holes.TANGENT_FRAMES`` for the input's own frames): a denoised velocity
#: is less sure than a clean take's
RESULT_TANGENT_FRAMES = 15
#: the curve through the input's own frames is a cubic spline through all of them for holes
#: up to this long (seconds; a clean take's exact neighbours), the Hermite curve over longer
#: ones (a spline swings over a long hole: the root's turn most)
SPLINE_SECONDS = 1.0


def mix_by_noise(from_input: Motion, from_result: Motion, source: Motion) -> Motion:
    """Per joint, the hole curves drawn from the input's frames and from the result's, mixed
    by the input's own noise s (``infer.noise_blend.noise_variance``): the result's share is
    s^4 / (s^4 + c^4) (sharp: a noisy take's input curve swings far). Outside the holes,
    ``from_result``."""

    rot_in = np.concatenate([from_input.root_orient[:, None], from_input.pose_body], axis=1)
    rot_res = np.concatenate([from_result.root_orient[:, None], from_result.pose_body], axis=1)
    src = np.concatenate([source.root_orient[:, None], source.pose_body], axis=1)
    seen = observed(source)
    s2 = noise_variance(rotvec_unwrap(torch.as_tensor(src, dtype=torch.float64), 0).numpy(), seen)
    w = torch.as_tensor(s2**2 / (s2**2 + CURVE_NOISE_RAD**4))[None].expand(len(src), -1)
    q = quat_slerp(rotvec_to_quat(torch.as_tensor(rot_in, dtype=torch.float64)),
                   rotvec_to_quat(torch.as_tensor(rot_res, dtype=torch.float64)), w)  # fmt: skip
    miss = ~observed(source)
    rot = np.where(miss[..., None], quat_to_rotvec(q).numpy(), rot_res)
    t2 = float(noise_variance(np.asarray(source.trans, float)[:, None, :], seen[:, :1])[0])
    wt = t2**2 / (t2**2 + CURVE_NOISE_M**4)
    trans = (1 - wt) * np.asarray(from_input.trans, float) + wt * np.asarray(
        from_result.trans, float
    )
    trans = np.where(miss[:, :1], trans, from_result.trans)
    return from_result.with_body(
        root_orient=rot[:, 0].astype(from_result.root_orient.dtype),
        pose_body=rot[:, 1:].astype(from_result.pose_body.dtype),
        trans=trans.astype(from_result.trans.dtype),
    )


def input_curve(source: Motion) -> Motion:
    """The holes of ``source`` filled from its own frames: the spline over short holes, the
    Hermite curve over long ones (:data:`SPLINE_SECONDS`), joint by joint."""
    spline, hermite = (
        fill_gaps(source.with_body(), "spline"),
        fill_gaps(source.with_body(), "hermite"),
    )
    longest = max(2, int(round(SPLINE_SECONDS * source.fps)))
    missing = ~observed(source)
    long = np.zeros_like(missing)
    for j in np.flatnonzero(missing.any(axis=0)):
        edges = np.diff(np.concatenate([[0], missing[:, j].astype(int), [0]]))
        for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
            long[a:b, j] = b - a > longest
    return take_holes(spline, hermite, ~long)


def take_holes(motion: Motion, other: Motion, mask: np.ndarray) -> Motion:
    """``motion`` with its entries where ``mask`` (T, 22) is False taken from ``other`` (the
    root translation follows the pelvis)."""
    miss = ~np.asarray(mask, bool)
    rot = np.concatenate([motion.root_orient[:, None], motion.pose_body], axis=1)
    rot_other = np.concatenate([other.root_orient[:, None], other.pose_body], axis=1)
    rot = np.where(miss[..., None], rot_other.astype(rot.dtype), rot)
    trans = np.where(miss[:, :1], np.asarray(other.trans, motion.trans.dtype), motion.trans)
    return motion.with_body(root_orient=rot[:, 0], pose_body=rot[:, 1:], trans=trans)


def holes_from(source: Motion, result: Motion) -> Motion:
    """``source`` with its holes taken from ``result`` (what a later stage reads as the input
    there: the foot lock finds contacts on the filled motion); ``source`` itself when whole."""
    return take_holes(source, result, observed(source)) if has_holes(source) else source


#: a run of frames missing every joint this long (seconds) or longer splits the take: the
#: pieces either side are denoised on their own, never reading the placeholders between them
SPLIT_SECONDS = 0.3


def observed_pieces(motion: Motion, least: int) -> list[tuple[int, int]] | None:
    """[start, end) of the runs of frames between the motion's long whole-frame holes (at
    least :data:`SPLIT_SECONDS`) that hold ``least`` frames at 30 Hz or more; None when it has
    no such hole (nothing to split)."""
    min_frames = int(np.ceil((least - 1) * motion.fps / 30.0)) + 1
    if not has_holes(motion):
        return None
    gone = ~observed(motion).any(axis=1)
    long_gap = max(2, int(round(SPLIT_SECONDS * motion.fps)))
    edges = np.diff(np.concatenate([[0], gone.astype(int), [0]]))
    gaps = [(a, b) for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1),
                                   strict=True) if b - a >= long_gap]  # fmt: skip
    if not gaps:
        return None
    bounds = [0, *[x for gap in gaps for x in gap], motion.num_frames]
    pieces = list(zip(bounds[::2], bounds[1::2], strict=True))
    return [(a, b) for a, b in pieces if b - a >= min_frames]


def join_pieces(source: Motion, pieces: list[tuple[int, int]], results: list[Motion]) -> Motion:
    """``source`` with each piece's frames [a, b) taken from its result (the rest, holes and
    pieces too short to denoise, as they came)."""
    rot = np.concatenate([source.root_orient[:, None], source.pose_body], axis=1).copy()
    trans = np.array(source.trans, dtype=np.float64)
    for (a, b), r in zip(pieces, results, strict=True):
        rot[a:b] = np.concatenate([r.root_orient[:, None], r.pose_body], axis=1)
        trans[a:b] = r.trans
    out = source.with_body(root_orient=rot[:, 0], pose_body=rot[:, 1:], trans=trans)
    out.notes = [*source.notes, *(n for r in results for n in r.notes if n not in source.notes)]
    return out
